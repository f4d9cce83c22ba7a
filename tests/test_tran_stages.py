"""The coestimation stages' cache keys are derived from their arguments and from the source of every
module they import, transitively: editing such a module (the RNG streams of `dse.simulate.seeding`, the
linear flows behind the Kalman-Bucy reference, which hand-written module lists once missed) changes
the key, editing a module the stage does not import (the claims, the views) does not. No stage module
imports the claims."""
from __future__ import annotations

import pytest

from dse import registry
from dse.contract import stages
from dse.contract.stages import StageResult, code_closure
from dse.engine.cache import MemoryCache
from dse.families.tran import design, law, reference, runs

STAGE_MODULES = ("design", "law", "runs", "reference")


@pytest.fixture(scope="module")
def scenario():
    return registry.paper("tran").scenario


@pytest.fixture
def fresh_hashes():
    """Module sources are hashed once per process: forget them before and after a test that edits one."""
    def clear():
        for f in (stages.code_hash, stages.code_closure, stages.direct_imports):
            f.cache_clear()
    clear()
    yield
    clear()


def _upstream(name: str) -> StageResult:
    out = StageResult()
    out.key = name
    return out


def _keys(sc) -> dict[str, str]:
    """The key of one call of each kind of stage (upstream results stand in by their keys)."""
    core, lw = _upstream("design-0"), _upstream("law-0")
    calls = {"design": (design.design_core, (sc,)), "law": (law.fixed_law, (sc, core, 0, True)),
             "det": (runs.deterministic_run, (sc, core, "coest")),
             "monte-carlo": (runs.monte_carlo, (sc, core, lw, True, 40, 0, 20.0, 0.005, 1e6)),
             "central": (reference.central_deterministic, (sc, _upstream("det-0")))}
    cache = MemoryCache()
    return {name: cache.key(st.name, st.params(st.bound(args, {}))) for name, (st, args) in calls.items()}


def _edited(monkeypatch, tmp_path, module: str) -> None:
    """`module`'s source as if edited (a comment appended), for the code hashes."""
    original = stages.module_file(module)
    copy = tmp_path / f"{module}.py"
    copy.write_text(original.read_text() + "\n# edited\n")
    real = stages.module_file
    monkeypatch.setattr(stages, "module_file", lambda name: copy if name == module else real(name))


@pytest.mark.parametrize("module, changed", [
    ("dse.simulate.seeding", {"law", "det", "monte-carlo", "central"}),
    ("dse.estimators.linear_flows", {"law", "det", "monte-carlo", "central"}),
    ("dse.estimators.observer_network_simulation", {"design", "law", "det", "monte-carlo", "central"}),
    ("dse.families.tran.runs", {"det", "monte-carlo"}),
    ("dse.families.tran.claims", set()),
    ("dse.families.tran.hypotheses", set()),
    ("dse.families.tran.views", set()),
    ("dse.families.savas.claims", set()),
])
def test_editing_an_imported_module_changes_the_key_and_only_then(module, changed, scenario, monkeypatch, tmp_path,
                                                                  fresh_hashes):
    before = _keys(scenario)
    _edited(monkeypatch, tmp_path, module)
    for f in (stages.code_hash, stages.code_closure, stages.direct_imports):
        f.cache_clear()
    after = _keys(scenario)
    assert {name for name in before if before[name] != after[name]} == changed


def test_keys_follow_the_arguments(scenario):
    a = _keys(scenario)
    assert len(set(a.values())) == len(a)
    data = registry.family("coestimation").generate(0)
    other = registry.from_dict(data).scenario
    assert _keys(other)["design"] != a["design"]
    name_only = registry.from_dict({**data, "name": "renamed", "stochastic": {**data["stochastic"], "trials": 30}})
    assert _keys(name_only.scenario) == _keys(other)      # the name and the trial counts change no number


def test_no_stage_imports_the_claims():
    for m in STAGE_MODULES:
        closure = code_closure(f"dse.families.tran.{m}")
        assert not {"dse.families.tran.claims", "dse.families.tran.hypotheses"} & closure, m


def test_design_then_simulate_is_the_run():
    """The contract's two steps (design, then simulate on it: `dse check`'s design reused) give the run's
    hypotheses and claims, as the family's one-pool `compute` does."""
    from dse.contract.family import Family
    from dse.contract.options import RunOptions
    from dse.contract.context import StageContext
    from dse.engine.driver import evaluate_claims

    fam = registry.family("coestimation")
    run, opts = registry.from_dict(fam.generate(3)), RunOptions(quick=True, seed=3)
    one = evaluate_claims(run, fam.compute(run, opts, StageContext(MemoryCache())))
    two = evaluate_claims(run, Family.compute(fam, run, opts, StageContext(MemoryCache())))
    assert one.claims == two.claims and one.hypotheses == two.hypotheses
