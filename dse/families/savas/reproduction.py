"""The noisy-communication paper as a `pipeline` reproduction, and the same family for
users' own scenario files (`dse run FILE.toml` with `family = "noisy-consensus-filter"`)."""
from __future__ import annotations

from pathlib import Path
from typing import Any

from dse.engine.cache import StageCache
from dse.engine.driver import RunOptions
from dse.families.legacy import FamilyReproduction

from .scenario import NoisyConsensusFile, NoisyConsensusScenario, paper_scenario

# compute, claims and outputs (scipy, matplotlib, rerun) are imported when first needed, so
# that validating a scenario file and reporting its errors stays fast.

TITLE = "Savas, Srivastava & Leonard: On distributed linear filtering with noisy communication"

#: the whole scenario file, declared (docs/scenarios.md is generated from it)
SCENARIO_MODEL = NoisyConsensusFile

FAMILY_INTRO = """A scalar random walk x(k+1) = x(k) + w(k) measured by N agents, y_i(k) = x(k) + n_i(k), who
average their estimates over a doubly stochastic consensus matrix Q for m rounds between two measurements,
each round adding independent N(0, σ_c²) noise at every agent. Two filters are simulated and checked in
every cell (m, σ_c): Carli et al.'s two-stage filter (7)+(9) with a fixed gain, and the paper's filter
with re-injection (11)-(13) with optimal or fixed gains (ℓ, ζ); the exact covariances of (22), the
steady state of Theorem 1 and the centralized Kalman filter are the references. Tables: `consensus_matrix`,
`spectrum`, `references`, `gains`, `carli_thresholds`, `cells`, `steady_covariance` (design; also from
`dse check`), `nodes`, `trace_series`, `node_series`, `sample_paths`, `consensus_rounds` and `metrics`.
Networks are connected, of 2 to 1,000 agents; horizons up to 100,000 steps (the Monte Carlo streams
over trials and time; statistics are kept at `sweep.recorded_steps` steps)."""

NOTES = """Reconstructions (values the paper does not give; our choices): σ_c grid {0, 0.25, 0.5, 1, 1.5, 2, 3}, X₀
variance σ = 1, Fig. 2 range m = 0..20, optimiser = dense grid, finer local grids and a box-constrained Newton method
from the lowest local minima. Fig. 3 uses the gains that are optimal for the corrected (16); the gains from the printed
(16) are in Fig. 2 (dashed). Monte Carlo: independent seeded streams per unit of 1,000 trials and per (m, horizon);
the metric is the ddof = 1 sample variance summed over agents. Statistical verdicts use exact laws of the simulated
errors (χ², normal, conservative Chernoff bounds for the trace) under the report's family-wise confidence. See
docs/papers/savas.md."""

FAMILY_NOTES = """Statistical verdicts use exact laws of the simulated errors given the gains (χ² for per-agent mean squares,
normal for sums, conservative Chernoff bounds for the trace), valid at any number of trials, under the report's
family-wise confidence."""


class NoisyConsensusReproduction(FamilyReproduction):
    def __init__(self, scenario: NoisyConsensusScenario, *, paper: bool):
        self.scenario = scenario
        self.is_paper = paper
        self.paper_id = "savas" if paper else scenario.name
        self.title = TITLE if paper else f"noisy-consensus-filter scenario '{scenario.name}'"

    def trials(self, opts: RunOptions) -> int:
        from . import compute

        return compute.trial_count(self.scenario, opts)

    def design(self, opts: RunOptions):
        """The deterministic design stage (gains, spectra, exact covariances, references), no Monte Carlo."""
        from . import compute

        return compute.design(self.scenario, opts.quick)

    def estimate(self, opts: RunOptions) -> dict[str, Any]:
        from . import cost

        c = cost.estimate(self.scenario, opts)
        return {"seconds": c.seconds, "peak_memory_mib": c.peak_mib, "detail": c.detail}

    def compute(self, opts: RunOptions, cache: StageCache):
        from . import compute

        return compute.compute(self.scenario, opts, cache)

    def write_outputs(self, results, out_dir: Path, claims: list[dict], prov: dict, tables=None) -> None:
        from . import outputs

        tables = self.table_set(results, tables)
        outputs.write_outputs(results, tables, out_dir, claims, prov, paper=self.is_paper)

    def notes(self) -> str:
        return NOTES if self.is_paper else FAMILY_NOTES


def paper() -> NoisyConsensusReproduction:
    return NoisyConsensusReproduction(paper_scenario(), paper=True)


def from_dict(data: dict[str, Any]) -> NoisyConsensusReproduction:
    return NoisyConsensusReproduction(NoisyConsensusScenario.from_dict(data), paper=False)
