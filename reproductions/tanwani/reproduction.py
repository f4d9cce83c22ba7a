"""The random-communication filtering paper as a `pipeline` reproduction, and the same family
for users' own scenario files (`dse run FILE.toml` with `family = "random-comm-filter"`)."""
from __future__ import annotations

from pathlib import Path
from typing import Any

from pipeline.cache import StageCache
from pipeline.reproduction import RunOptions

from . import claims as claims_mod
from . import compute as compute_mod
from . import outputs
from .scenario import FilterNetworkScenario, paper_scenarios

TITLE = "Tanwani: Suboptimal filtering over sensor networks with random communication (IEEE TAC 2022)"

NOTES = """The paper has no numerical example, no simulation and no table (its Fig. 1 is a schematic): every scenario
here (S1a-c, S2, S3, the topology sweep S4) is the spec's proposal (shared/specs/000_tanwani.md §5), and every
plot and number is labelled as such. Choices (spec §2, §6): x(0) ~ N(0, P0), x̂_i(0) = 0, one Poisson clock per
undirected edge with both endpoints updating from pre-jump values (per ordered pair is available as
`communication.mode = "ordered"`), α = min(1/2, 1/d_max), gains = the centralized Kalman–Bucy gain split by
columns (L_i = N K_i) unless given. E[e eᵀ] is the second moment (1/K Σ e eᵀ). The exact mean joint covariance
ODE (D1), the per-path quantities, the critical rates, S_true and the explicit constants of (12) are DERIVED in the
spec, not in the paper. Monte Carlo: an exact event-driven simulator (per-trial Poisson events, exact Gaussian
transitions between events via an eigendecomposition of the block-diagonal error dynamics, per-path exact
covariances) and a gridded one (exact flow over h/2, Poisson(λh) rings per clock per step in alternating clock
order, flow over h/2; its own exact mean covariance shows an O(h²) bias, checked by `sim.gridded_bias`), both
batched over trials; statistical verdicts use a family-wise confidence of 0.999 (Bonferroni).
Typos found by the spec that numbers cannot show (no claim): (13a) reads '(A − L_iH_i) de_i' (the corrected form
is used and checked by `prop3_2.flow_equality`); the interval in (5); lost minus signs in the problem statement;
'v_i standard' with covariance V_i; Lemma III.3's garbled text; Ũ† = Ũ."""


class RandomCommReproduction:
    def __init__(self, scenarios: list[FilterNetworkScenario], *, paper: bool):
        self.scenarios = scenarios
        self.is_paper = paper
        self.paper_id = "tanwani" if paper else scenarios[0].name
        self.title = TITLE if paper else f"random-comm-filter scenario '{scenarios[0].name}'"
        self.main = "s2" if paper else scenarios[0].name

    def scenario_ids(self) -> list[str]:
        return [sc.name for sc in self.scenarios]

    def claims(self):
        return claims_mod.catalogue(self.paper_id, self.scenario_ids(), self.main, paper=self.is_paper)

    def hypotheses(self):
        return []

    def trials(self, opts: RunOptions) -> int:
        return max(compute_mod.trial_counts(sc, opts)[0] for sc in self.scenarios)

    def compute(self, opts: RunOptions, cache: StageCache):
        return compute_mod.compute(self.scenarios, opts, cache, is_paper=self.is_paper)

    def write_outputs(self, results, out_dir: Path, claims: list[dict], prov: dict) -> None:
        outputs.write_outputs(results, out_dir, claims, prov, main=self.main)

    def notes(self) -> str:
        return NOTES


def paper() -> RandomCommReproduction:
    return RandomCommReproduction(paper_scenarios(), paper=True)


def from_dict(data: dict[str, Any]) -> RandomCommReproduction:
    return RandomCommReproduction([FilterNetworkScenario.from_dict(data)], paper=False)
