"""The hypotheses and claims of Kar & Moura's GIKF paper, in the order they are reported.

Each is registered on its check in the module of its topic; this one joins them. Per-scenario entries
(ids ending in the scenario's name) come first, scenario by scenario, then the run's own. Every scenario
gets every claim of the family but those its gates leave out: the structural checks on the role "full"
(E1 and E2 in the paper, every user scenario), Remark 9 on the role "comparison", the examples' claims
on the paper's E1, E7 and E8. A theorem's conclusion names the hypotheses it rests on (C.1, D.1, S.1, a
recorded witness walk, the exact Ā, i.i.d. matchings) and is not checkable where one does not hold; the
identities of the swap structure (weak consensus at every finite t, the per-sensor laws, the token
recursion, domination by the centralized filter) need none.
"""
from __future__ import annotations

from dse.contract.claims import ClaimSet

from . import claims_bounds, claims_examples, claims_identities, claims_maps, claims_theorems, hypotheses


def _scenario(results, name: str):
    """A scenario's results (or design): what a per-scenario check receives."""
    return results.get(name)


claims = ClaimSet(select=_scenario, select_design=_scenario, hypotheses=list(hypotheses.claims.hypotheses),
                  claims=[entry for module in (claims_identities, claims_maps, claims_theorems, claims_bounds,
                                               claims_examples) for entry in module.claims.claims])
