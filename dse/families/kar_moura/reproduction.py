"""Kar & Moura's GIKF paper as a `pipeline` reproduction (our scenarios E1-E9), and the same family
for users' own scenario files (`dse run FILE.toml` with `family = "gossip-kalman"`)."""
from __future__ import annotations

from pathlib import Path
from typing import Any

from dse.engine.cache import StageCache
from dse.engine.driver import RunOptions
from dse.families.legacy import FamilyReproduction

from . import claims as claims_mod
from . import compute as compute_mod
from .scenario import GossipKalmanFile, GossipKalmanScenario, paper_scenarios

PAPER_ID = "kar-moura"
FULL_CHECKS = ("e1", "e2")
TITLE = "Kar & Moura: Gossip and distributed Kalman filtering — weak consensus under weak detectability (GIKF)"

#: the whole scenario file, declared (docs/scenarios.md is generated from it)
SCENARIO_MODEL = GossipKalmanFile

FAMILY_INTRO = """N sensors observe a linear Gaussian signal x(t+1) = F x(t) + w(t) through their own y_n = C_n x + v_n (none
need see the whole state; C_n = [] is a node that observes nothing). At every slot a random matching of the graph
decides which pairs swap their (estimate, covariance) pairs; each sensor then updates what it received with its own
observation and predicts (Kar & Moura's gossip interactive Kalman filter, GIKF). Protocols: one random edge per slot,
node-initiated gossip, a given law over matchings, random greedy maximal matchings with link failures, or a given
matching sequence replayed in every run (a protocol or a trace; the theorems, which assume i.i.d. matchings, are then
not checkable and the pathwise statements still are). A disconnected graph is accepted: C.1 (Ā irreducible and
aperiodic) then fails and is reported as a hypothesis that does not hold, like D.1 (a walk of Ā with an invertible
observability Gramian). At most 1,000 sensors (Ā is dense). Monte Carlo runs are streamed in units of 1,000 (the numbers do not depend on the memory
budget); per-slot statistics are kept at a bounded set of slots, so horizons up to 20,000 slots fit. Tables: design
(`design`, `f_eigenvalues`, `abar`, `abar_spectrum`, `sensors`, `classes`, `witness_walks`, `matrices`,
`tail_bounds`, `tv_decay`, `reference_series`; also from `dse check`) and run (`nodes`, `node_entries`,
`quantiles`, `laws`, `tails`, `margins`, `sample_paths`, `matchings`, `nees`, `tokens`, `metrics`). See
docs/papers/kar-moura.md."""

NOTES = """The paper has no numerical example; every scenario is ours: E1 (core, ring of 10, single-edge gossip), E2 (rotations,
actuators with C = 0, 3x4 grid, node-initiated gossip), E3 (Remark 9: two protocols with one Ā), negative controls E5 (D.1
violated), E6 (C.1 and D.1 violated), E6b (C.1 only), E7 (periodic Ā), E8 (singular F: D.1 fails, filter bounded) and E9
(scale-up: 30 nodes on a random geometric graph, M = 6, greedy maximal matching with link failures; Ā has no closed form, so
it is estimated by Monte Carlo for the report and the Theorem-8 chains are driven by an independent copy of the protocol;
the claims that need the exact Ā are not checkable there). Every theorem's conclusion names its hypotheses (C.1, D.1,
S.1, a recorded witness walk, the exact Ā, i.i.d. matchings): on the negative controls those conclusions are not
checkable, and what is predicted instead (divergence bounded below by a class's centralized filter, Theorem 26(a), E7's
failure of (25)) is checked. Implementation: covariances in Joseph form (symmetrised) batched over runs, with a
first-order round-off bound carried along every compared matrix; square-root (array) form where iterates can be huge
(starts at c·I, unseen modes); estimates through the error recursion (common w); token indexing corrected; the
Theorem-8 process with a stationary Ā-chain; the Lyapunov envelope f_0^t(P0) carried rescaled (finite over any
horizon). D.1 is read as "some Ā-walk has an invertible Gramian" and decided three ways (witness, certificate of
failure, undecided); the covering reading is reported. Statistical tests use one sample per independent run and are
exact or conservative at any sample size (exact KS p-values, binomial, χ², Clopper-Pearson, Hoeffding, DKW),
Bonferroni within each claim at its share of the report's family-wise confidence; quantiles, never means (E_μ tr X = ∞
in E1). GIKF runs are simulated in RNG units of 1,000; tail statistics, quantiles and Loewner margins are evaluated at
every 5th slot (at most 250 slots, plus every record time); Loewner margins on the first unit of 1,000 runs.
Reconstruction notes: docs/papers/kar-moura.md."""


class GossipKalmanReproduction(FamilyReproduction):
    def __init__(self, scenarios: list[GossipKalmanScenario], *, paper: bool):
        self.scenarios = scenarios
        self.is_paper = paper
        self.paper_id = PAPER_ID if paper else scenarios[0].name
        self.title = TITLE if paper else f"gossip-kalman scenario '{scenarios[0].name}'"
        # in the paper, the structural checks (maps, tokens, indexing, constants) run on E1 and E2 only;
        # a user's scenario gets all of them
        self._roles = [(sc.name, {**compute_mod.roles(sc), "full": (not paper) or sc.name in FULL_CHECKS})
                       for sc in scenarios]

    def claims(self):
        return claims_mod.catalogue(self._roles)

    def hypotheses(self):
        return claims_mod.hypotheses(self._roles)

    def trials(self, opts: RunOptions) -> int:
        return compute_mod.sizes(self.scenarios[0], opts)[0]

    def compute(self, opts: RunOptions, cache: StageCache) -> compute_mod.Results:
        from .cost import refuse_beyond_budget

        costs = refuse_beyond_budget(self.scenarios, opts)
        return compute_mod.compute(self.scenarios, opts, cache,
                                   structural=[name for name, roles in self._roles if roles["full"]], costs=costs)

    # -- the design stage (`dse check`) --------------------------------------------------------------
    def design(self, opts: RunOptions) -> compute_mod.Design:
        """Every scenario's deterministic quantities, without Monte Carlo (in memory; a run caches them)."""
        return compute_mod.design(self.scenarios, opts)

    @staticmethod
    def design_of(results: compute_mod.Results) -> compute_mod.Design:
        return results.design()

    def estimate(self, opts: RunOptions) -> dict[str, Any]:
        from . import cost

        return cost.estimate(self.scenarios, opts)

    def write_outputs(self, results, out_dir: Path, claims: list[dict], prov: dict, tables=None) -> None:
        from . import outputs

        tables = self.table_set(results, tables)
        outputs.write_outputs(results, tables, out_dir, claims, prov, PAPER_ID, workers=int(prov.get("workers") or 1))

    def notes(self) -> str:
        return NOTES if self.is_paper else ""


def paper() -> GossipKalmanReproduction:
    return GossipKalmanReproduction(paper_scenarios(), paper=True)


def from_dict(data: dict[str, Any]) -> GossipKalmanReproduction:
    return GossipKalmanReproduction([GossipKalmanScenario.from_dict(data)], paper=False)
