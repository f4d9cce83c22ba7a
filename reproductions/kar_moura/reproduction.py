"""Kar & Moura's GIKF paper as a `pipeline` reproduction (our scenarios E1-E9), and the same family
for users' own scenario files (`dse run FILE.toml` with `family = "gossip-kalman"`)."""
from __future__ import annotations

from pathlib import Path
from typing import Any

from pipeline.cache import StageCache
from pipeline.reproduction import RunOptions

from . import claims as claims_mod
from . import compute as compute_mod
from . import outputs
from .scenario import GossipKalmanScenario, paper_scenarios

PAPER_ID = "kar-moura"
FULL_CHECKS = ("e1", "e2")
TITLE = "Kar & Moura: Gossip and distributed Kalman filtering — weak consensus under weak detectability (GIKF)"

NOTES = """The paper has no numerical example; every scenario is ours: E1 (core, ring of 10, single-edge gossip), E2 (rotations,
actuators with C = 0, 3x4 grid, node-initiated gossip), E3 (Remark 9: two protocols with one Ā), negative controls E5 (D.1
violated), E6 (C.1 and D.1 violated), E6b (C.1 only), E7 (periodic Ā), E8 (singular F: D.1 fails, filter bounded) and E9
(scale-up: 30 nodes on a random geometric graph, M = 6, greedy maximal matching with link failures; Ā has no closed form, so
it is estimated by Monte Carlo for the report and the Theorem-8 chains are driven by an independent copy of the protocol;
the claims that need the exact Ā are not checkable there). Every theorem's conclusion names its hypotheses (C.1, D.1,
S.1, a recorded witness walk, the exact Ā): on the negative controls those conclusions are not checkable, and what is
predicted instead (divergence bounded below by a class's centralized filter, Theorem 26(a), E7's failure of (25)) is
checked. Implementation: covariances in Joseph form (symmetrised) batched over runs, with a first-order round-off bound
carried along every compared matrix; square-root (array) form where iterates can be huge (starts at c·I, unseen modes);
estimates through the error recursion (common w); token indexing corrected; the Theorem-8 process with a stationary
Ā-chain. D.1 is read as "some Ā-walk has an invertible Gramian" and decided three ways (witness, certificate of failure,
undecided); the covering reading is reported. Statistical tests use one sample per independent run and are exact or
conservative at any sample size (exact KS p-values, binomial, χ², Clopper-Pearson, Hoeffding, DKW), Bonferroni within
each claim at its share of the report's family-wise confidence; quantiles, never means (E_μ tr X = ∞ in E1). Tail
statistics and Loewner margins of the GIKF runs are evaluated every 5th slot (plus every record time); Loewner margins
on the first 1000 runs."""


class GossipKalmanReproduction:
    def __init__(self, scenarios: list[GossipKalmanScenario], *, paper: bool):
        self.scenarios = scenarios
        self.is_paper = paper
        self.paper_id = PAPER_ID if paper else scenarios[0].name
        self.title = TITLE if paper else f"gossip-kalman scenario '{scenarios[0].name}'"
        # in the paper, the structural checks (maps, tokens, indexing, constants) run on E1 and E2 only;
        # a user's scenario gets all of them
        self._roles = [(sc.name, {**compute_mod.roles(sc), "full": (not paper) or sc.name in FULL_CHECKS})
                       for sc in scenarios]

    def scenario_ids(self) -> list[str]:
        return [sc.name for sc in self.scenarios]

    def claims(self):
        return claims_mod.catalogue(self._roles)

    def hypotheses(self):
        return claims_mod.hypotheses(self._roles)

    def trials(self, opts: RunOptions) -> int:
        return compute_mod.sizes(self.scenarios[0], opts)[0]

    def compute(self, opts: RunOptions, cache: StageCache) -> compute_mod.Results:
        self._workers = opts.workers
        return compute_mod.compute(self.scenarios, opts, cache)

    def write_outputs(self, results, out_dir: Path, claims: list[dict], prov: dict) -> None:
        outputs.write_outputs(results, out_dir, claims, prov, PAPER_ID, workers=getattr(self, "_workers", 1))

    def notes(self) -> str:
        return NOTES if self.is_paper else ""


def paper() -> GossipKalmanReproduction:
    return GossipKalmanReproduction(paper_scenarios(), paper=True)


def from_dict(data: dict[str, Any]) -> GossipKalmanReproduction:
    return GossipKalmanReproduction([GossipKalmanScenario.from_dict(data)], paper=False)
