"""What the generated-scenario test files share (not a test module): the cases of a set of families (every edge
case of each family's generator once, plus a few unbiased draws) and the check of one case (no claim `fail` or
`error`, no hypothesis that raised). The cases are split over several test files so that `make test`'s workers
(one test file each) share them; `tests/test_generated_scenarios.py` takes every family not named in
`SPLIT_FAMILIES`, so a new family is never left out."""
from __future__ import annotations

import pytest

from dse import registry
from dse.contract.context import StageContext
from dse.contract.options import RunOptions
from dse.engine.cache import StageCache
from dse.engine.driver import evaluate_claims

RANDOM_DRAWS = 2
#: the families whose generated cases run in a test file of their own (file -> families)
SPLIT_FAMILIES = {"test_generated_random_comm.py": ("random-comm-filter",),
                  "test_generated_gossip_coestimation.py": ("gossip-kalman", "coestimation")}


def cases(families) -> list:
    """pytest parameters (family, seed, edge) of the given families."""
    out = []
    for family, fam in registry.families().items():
        if family not in families:
            continue
        out += [pytest.param(family, seed, edge, id=f"{family}-{edge}") for seed, edge in enumerate(fam.edges)]
        out += [pytest.param(family, 1000 + s, None, id=f"{family}-random{s}") for s in range(RANDOM_DRAWS)]
    return out


def unsplit_families() -> list[str]:
    """The families whose cases run in tests/test_generated_scenarios.py."""
    split = {f for fams in SPLIT_FAMILIES.values() for f in fams}
    return [f for f in registry.families() if f not in split]


def check_generated(family: str, seed: int, edge: str | None, tmp_path) -> None:
    """One generated scenario, computed (`--quick`, one worker) and checked: no `fail`, no `error`."""
    data = registry.family(family).generate(seed, edge)
    assert data["family"] == family
    repro = registry.from_dict(data)
    computed = repro.compute(RunOptions(seed=seed, quick=True, workers=1), StageContext(StageCache(tmp_path / "cache")))
    ev = evaluate_claims(repro, computed)
    bad = [f"{r['id']}: {r['verdict']}: {str(r.get('detail'))[:400]}" for r in ev.claims if r["verdict"] in ("fail", "error")]
    bad += [f"hypothesis {h['id']}: {h['error'][:400]}" for h in ev.hypotheses if h["error"]]
    assert not bad, f"{family} edge={edge} seed={seed}:\n" + "\n".join(bad)
    assert ev.claims, "no claim was evaluated"
