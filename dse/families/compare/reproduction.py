"""The `compare` family as a `pipeline` reproduction (`dse run FILE.toml` with `family = "compare"`).

Not a paper: one plant, one graph and one link model given to every estimator that applies, on
common random numbers, with the field's standard baselines beside the five papers' algorithms.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

from dse.engine.cache import StageCache
from dse.engine.driver import RunOptions
from dse.families.legacy import FamilyReproduction

from .scenario import CompareFile, CompareScenario

#: the whole scenario file, declared (docs/scenarios.md is generated from it)
SCENARIO_MODEL = CompareFile

FAMILY_INTRO = """One discrete-time linear-Gaussian plant x(k+1) = F x(k) + w(k) seen by sensors y_i(k) = H_i x(k) +
v_i(k) at the nodes of a graph, one link model (reliable links, independent link failures, random matchings or
Poisson-clocked pairwise exchanges, each with optional additive communication noise), and every estimator that
applies, on common random numbers: the centralized Kalman filter (the reference), local Kalman filters without
communication (the floor), the GIKF (Kar & Moura), Carli et al.'s two-stage consensus filter and Savas et al.'s
re-injection filter in vector form, Tanwani's constant-gain filters with pairwise averaging in discrete time, the
Kalman-consensus filter (Olfati-Saber), the diffusion Kalman filter in adapt-then-combine form (Cattivelli & Sayed)
and the consensus-on-information filter (Battistelli & Chisci). An estimator that does not apply to the link model
is reported as not applicable, with the reason. Exact second-moment recursions where they exist (linear filters
with gains that do not depend on the data; the mean over link patterns where it is exact), Monte Carlo with
confidence intervals otherwise. Tables: `applicability`, `gains`, `edge_weights`, `detectability` (design; also
from `dse check`), `estimators` (error against communication), `nodes`, `series`, `token_law` and `metrics`.
See docs/papers/compare.md."""

NOTES = """Not a paper: a comparison on one scenario. Statistical verdicts use exact χ² laws where an error is Gaussian
with a known covariance given the link draws (every filter on reliable links against its exact recursion; the
centralized, local and GIKF filters against their own covariances), a one-sided χ² bound for the consistency of
CI, the two-sample Kolmogorov-Smirnov test for the GIKF's token law, and normal z-tests of means of independent
trials only above an effective-sample-size gate, under the report's family-wise confidence. Constant gains are
tuned on the exact steady state of their mean recursion. See docs/papers/compare.md for what each estimator is,
its generalisation to this setting and what it sends."""


class CompareReproduction(FamilyReproduction):
    is_paper = False

    def __init__(self, scenario: CompareScenario):
        self.scenario = scenario
        self.paper_id = scenario.name
        self.title = f"compare scenario '{scenario.name}': one network, every estimator"

    def trials(self, opts: RunOptions) -> int:
        from . import compute

        return compute.trial_count(self.scenario, opts)

    def design(self, opts: RunOptions):
        from . import compute

        return compute.compute_design(self.scenario, opts)

    def estimate(self, opts: RunOptions) -> dict[str, Any]:
        from . import cost

        return cost.estimate(self.scenario, opts)

    def compute(self, opts: RunOptions, cache: StageCache):
        from . import compute

        return compute.compute(self.scenario, opts, cache)

    def write_outputs(self, results, out_dir: Path, claims: list[dict], prov: dict, tables=None) -> None:
        from . import outputs

        tables = self.table_set(results, tables)
        outputs.write_outputs(results, tables, out_dir, claims, prov)

    def notes(self) -> str:
        return NOTES


def from_dict(data: dict[str, Any]) -> CompareReproduction:
    return CompareReproduction(CompareScenario.from_dict(data))
