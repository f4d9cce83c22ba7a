"""The noisy-communication paper as a `pipeline` reproduction, and the same family for
users' own scenario files (`dse run FILE.toml` with `family = "noisy-consensus-filter"`)."""
from __future__ import annotations

from pathlib import Path
from typing import Any

from pipeline.cache import StageCache
from pipeline.reproduction import RunOptions

from .scenario import NoisyConsensusScenario, paper_scenario

# compute, claims and outputs (scipy, matplotlib, rerun) are imported when first needed, so
# that validating a scenario file and reporting its errors stays fast.

TITLE = "Savas, Srivastava & Leonard: On distributed linear filtering with noisy communication"

NOTES = """Reconstructions (values the paper does not give; our choices): σ_c grid {0, 0.25, 0.5, 1, 1.5, 2, 3}, X₀
variance σ = 1, Fig. 2 range m = 0..20, optimiser = dense grid + multi-start L-BFGS-B. Fig. 3 uses the gains that
are optimal for the corrected (16); the gains from the printed (16) are in Fig. 2 (dashed). Monte Carlo: independent
seeded streams per (algorithm, m, σ_c) cell; the metric is the ddof = 1 sample variance summed over agents.
Statistical verdicts use exact laws of the simulated errors (χ², normal, conservative Chernoff bounds for the trace)
under the report's family-wise confidence."""

FAMILY_NOTES = """Statistical verdicts use exact laws of the simulated errors given the gains (χ² for per-agent mean squares,
normal for sums, conservative Chernoff bounds for the trace), valid at any number of trials, under the report's
family-wise confidence."""


class NoisyConsensusReproduction:
    def __init__(self, scenario: NoisyConsensusScenario, *, paper: bool):
        self.scenario = scenario
        self.is_paper = paper
        self.paper_id = "savas" if paper else scenario.name
        self.title = TITLE if paper else f"noisy-consensus-filter scenario '{scenario.name}'"

    def scenario_ids(self) -> list[str]:
        return [self.scenario.name]

    def claims(self):
        from . import claims

        return claims.catalogue()

    def hypotheses(self):
        from . import hypotheses

        return hypotheses.catalogue()

    def trials(self, opts: RunOptions) -> int:
        from . import compute

        return compute.trial_count(self.scenario, opts)

    def compute(self, opts: RunOptions, cache: StageCache):
        from . import compute

        return compute.compute(self.scenario, opts, cache)

    def write_outputs(self, results, out_dir: Path, claims: list[dict], prov: dict) -> None:
        from . import outputs

        outputs.write_outputs(results, out_dir, claims, prov, paper=self.is_paper)

    def notes(self) -> str:
        return NOTES if self.is_paper else FAMILY_NOTES


def paper() -> NoisyConsensusReproduction:
    return NoisyConsensusReproduction(paper_scenario(), paper=True)


def from_dict(data: dict[str, Any]) -> NoisyConsensusReproduction:
    return NoisyConsensusReproduction(NoisyConsensusScenario.from_dict(data), paper=False)
