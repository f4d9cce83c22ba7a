"""The random-communication filtering paper as a `pipeline` reproduction, and the same family
for users' own scenario files (`dse run FILE.toml` with `family = "random-comm-filter"`)."""
from __future__ import annotations

from pathlib import Path
from typing import Any

from dse.engine.cache import StageCache
from dse.engine.driver import RunOptions
from dse.families.legacy import FamilyReproduction

from .scenario import PAPER_SCENARIOS, FilterNetworkScenario, RandomCommFile, paper_scenarios, scenario_from_dict

# compute, claims, tables and outputs (scipy, matplotlib, rerun) are imported when first needed, so that
# validating a scenario file and reporting its errors stays fast.

TITLE = "Tanwani: Suboptimal filtering over sensor networks with random communication (IEEE TAC 2022)"

#: the whole scenario file, declared (docs/scenarios.md is generated from it)
SCENARIO_MODEL = RandomCommFile

FAMILY_INTRO = """A continuous-time plant dx = Ax dt + B dω observed by N sensor nodes, dy_i = H_i x dt + dv_i; every node
runs a constant-gain filter (5) and, at the rings of independent Poisson clocks of rate λ on the edges of a graph,
moves its estimate towards a neighbour's (6) (Tanwani's distributed filter with random communication). Computed
exactly: the mean bound (9) and the exact mean joint error covariance (transients and steady states per node), the
critical rates of both, Ā, R of (10), S of (11), the true large-rate limit S_true, the explicit constants of (12),
the centralized Kalman–Bucy reference. Simulated: an exact event-driven Monte Carlo (per-path covariances and the
bound (14) along every clock path), a gridded one at every simulated rate, and one frozen clock path. A disconnected
graph is accepted (item 1 of Theorem III.1 holds on any graph; item 2 then rests on the hypothesis `connected`,
reported as failing); each node may start its bound at its own P_i(0) (`sensors[].P_init`, the hypothesis `initial`
says whether it dominates the initial error). The gridded step is chosen from the rates when not given. Monte Carlo
is streamed over trials (units of 1,000) and time (moments per output time only), so horizons up to 1,000 s and
10⁷ gridded trials fit the memory budget. Tables: design (`design`, `spectra`, `matrices`, `rates`, `steady_states`,
`sweep`, `sweep_nodes`, `series`, `graph_nodes`, `graph_edges`, `node_entries`; also from `dse check`) and run
(`nodes`, `mc_series`, `sample_paths`, `path_series`, `path_events`, `cells`, `frozen`, `poisson`, `references`,
`scheme_bias`, `metrics`, and for the paper `topology`, `topology_rates`, `topology_graphs`). See
docs/papers/tanwani.md."""

NOTES = """The paper has no numerical example, no simulation and no table (its Fig. 1 is a schematic): the scenarios
here (S1a-c, S2, S3 and the topology sweep S4) were designed for this reproduction, and their reference numbers
were computed independently. """

FAMILY_NOTES = """Model choices: x(0) ~ N(m0, P0), x̂_i(0) = m0, one Poisson clock per undirected edge with both endpoints
updating from pre-jump values (per ordered pair with `communication.mode = "ordered"`), α = min(1/2, 1/d_max) unless
given, gains = the centralized Kalman–Bucy gain split by columns (L_i = N K_i) unless given, P_i(0) = P0 unless given
per node. E[e eᵀ] is the second moment. Derived here, not in the paper: the exact mean joint covariance ODE, the
per-path quantities, the second moments of the P-process over clock paths, the critical rates, the limit S_true, the
first-order rate of (9) and explicit constants for (12). Monte Carlo: an exact event-driven simulator (exact Poisson
events, exact Gaussian transitions between events, exact per-path covariances) and a gridded one (exact flow over h/2,
Poisson(λh) rings per clock per step in alternating clock order, flow over h/2; its own exact mean covariance gives
its O(h²) bias). Statistical verdicts use exact laws (χ² of whitened Gaussian errors given the clocks, Poisson and
binomial counts, Efron's bound for paired symmetric differences) or, for means over random clock paths, Bernstein's
inequality with the exact variance for low means and a Student plus known-variance test for high means. Typos that
numbers cannot show (no claim): (13a) reads '(A − L_iH_i) de_i' (the corrected form is used and checked by
`prop3_2.flow_equality`); the interval in (5); lost minus signs in the problem statement; 'v_i standard' with
covariance V_i; Lemma III.3's garbled text; Ũ† = Ũ. Reconstruction notes: docs/papers/tanwani.md."""


class RandomCommReproduction(FamilyReproduction):
    def __init__(self, scenarios: list[FilterNetworkScenario] | None, *, paper: bool):
        """`scenarios` None: the paper's, built from their files when first needed (`dse list` does not)."""
        self._scenarios = scenarios
        self.is_paper = paper
        self.paper_id = "tanwani" if paper else scenarios[0].name
        self.title = TITLE if paper else f"random-comm-filter scenario '{scenarios[0].name}'"
        self.main = "s2" if paper else scenarios[0].name

    @property
    def scenarios(self) -> list[FilterNetworkScenario]:
        if self._scenarios is None:
            self._scenarios = paper_scenarios()
        return self._scenarios

    def scenario_ids(self) -> list[str]:
        return list(PAPER_SCENARIOS) if self._scenarios is None else [sc.name for sc in self._scenarios]

    def claims(self):
        from . import claims

        return claims.catalogue(self.paper_id, self.scenario_ids(), self.main)

    def hypotheses(self):
        from . import claims

        return claims.hypotheses(self.paper_id, self.scenario_ids())

    def trials(self, opts: RunOptions) -> int:
        from . import compute

        return max(compute.trial_counts(sc, opts)[0] for sc in self.scenarios)

    # -- the design stage (`dse check`) --------------------------------------------------------------
    def design(self, opts: RunOptions):
        """Every scenario's deterministic quantities, without Monte Carlo (in memory; a run caches them)."""
        from . import compute

        return compute.design(self.scenarios, opts)

    @staticmethod
    def design_of(results):
        return results.design()

    def estimate(self, opts: RunOptions) -> dict[str, Any]:
        from . import cost

        c = cost.estimate(self.scenarios, opts, paper=self.is_paper)
        return {"seconds": c.seconds, "peak_memory_mib": c.peak_mib, "detail": c.detail}

    def compute(self, opts: RunOptions, cache: StageCache):
        from . import compute, cost

        cost.refuse_if_too_large(self.scenarios, opts, paper=self.is_paper)
        return compute.compute(self.scenarios, opts, cache, is_paper=self.is_paper)

    def write_outputs(self, results, out_dir: Path, claims: list[dict], prov: dict, tables=None) -> None:
        from . import outputs

        tables = self.table_set(results, tables)
        outputs.write_outputs(results, tables, out_dir, claims, prov, main=self.main, paper=self.is_paper)

    def notes(self) -> str:
        return (NOTES + FAMILY_NOTES) if self.is_paper else FAMILY_NOTES


def paper() -> RandomCommReproduction:
    return RandomCommReproduction(None, paper=True)


def from_dict(data: dict[str, Any]) -> RandomCommReproduction:
    return RandomCommReproduction([scenario_from_dict(data)], paper=False)
