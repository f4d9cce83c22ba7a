"""Bad plug-in filters (tests/plugins/bad.py): each gets one clear line, never damages the others' results.

A filter that breaks the protocol while the scenario runs is dropped by the harness (`dse.plugin.harness`): the
run completes, its `faults` table has one row naming the filter and what it did, `dse run` prints one line per
failed filter on stderr and exits 4, and every other estimator's numbers are the same bits as in a run without
it. A filter that is declared wrong is refused before anything runs: one ScenarioError line naming the key,
exit 2.
"""
from __future__ import annotations

import json

import numpy as np
import pytest

import dse
from dse import cli, registry
from dse.contract.context import StageContext
from dse.contract.options import RunOptions
from dse.engine.cache import MemoryCache
from dse.errors import ScenarioError
from dse.estimators.network_comparison import TRUE_STATE

from test_compare_family import tiny
from test_plugin_protocol import assert_same_bits, stage_arrays

BAD = "tests.plugins.bad"
TRIALS, SEED = 200, 5
#: the built-ins beside the bad filters: one that sends nothing, one that sends messages, one that swaps states
#: (the token law), and the centralized reference (always); and a well-behaved plug-in
BASE = {"include": ["local", "diffusion", "gikf"], "good": {"factory": "tests.plugins.twins:LocalTwin"}}


def scenario(model: str = "reliable", **bad) -> dict:
    """The tiny compare scenario (noisy links) with the well-behaved filters and the `bad` tables."""
    data = tiny(model=model, **({"rate": 0.7, "rounds": 1} if model == "poisson" else {}))
    data["estimators"] = {**BASE, **bad}
    return data


def toml(data: dict) -> str:
    """A scenario dict as a TOML file (tables and sub-tables; lists of tables inline)."""
    def value(v):
        if isinstance(v, dict):
            return "{ " + ", ".join(f"{k} = {value(x)}" for k, x in v.items()) + " }"
        if isinstance(v, (list, tuple)):
            return "[" + ", ".join(value(x) for x in v) + "]"
        if isinstance(v, bool):
            return "true" if v else "false"
        return json.dumps(v)

    def table(name, d):
        lines = [f"[{name}]"] + [f"{k} = {value(v)}" for k, v in d.items() if not isinstance(v, dict)]
        return "\n".join(lines + [table(f"{name}.{k}", v) for k, v in d.items() if isinstance(v, dict)])

    head = [f"{k} = {value(v)}" for k, v in data.items() if not isinstance(v, dict)]
    return "\n".join(head + [table(k, v) for k, v in data.items() if isinstance(v, dict)]) + "\n"


def run_cli(data: dict, tmp_path, capsys) -> tuple[int, list[str]]:
    """`dse run` on `data` (in this process): the exit code and the lines it wrote on stderr."""
    f = tmp_path / "s.toml"
    f.write_text(toml(data))
    capsys.readouterr()
    rc = cli.main(["run", str(f), "--out", str(tmp_path / "out"), "--trials", str(TRIALS), "--seed", str(SEED),
                   "--workers", "1", "--no-figures"])
    return rc, capsys.readouterr().err.splitlines()


@pytest.fixture(scope="module")
def baselines():
    """model -> the results of the scenario without a bad filter."""
    cache = {}

    def get(model):
        if model not in cache:
            repro = registry.from_dict(scenario(model))
            cache[model] = repro.compute(RunOptions(seed=SEED, trials=TRIALS, workers=1),
                                         StageContext(MemoryCache())).results
        return cache[model]
    return get


def assert_others_unchanged(res, base) -> None:
    """Every estimator of the baseline run has the same stage arrays, to the bit."""
    for name in base.design.running:
        assert_same_bits(stage_arrays(base, name), stage_arrays(res, name), name)
    assert np.array_equal(base.paths[TRUE_STATE], res.paths[TRUE_STATE])


# (class, what the line says, table keys): every misbehaviour of the list
FAULTS = [
    ("RaisesInInit", "failed when constructed: raised RuntimeError: cannot build", {}),
    ("RaisesInStep", "failed at step 3: raised RuntimeError: boom", {}),
    ("RaisesInCovariance", "failed in covariance(): raised KeyError: 'no covariance'", {}),
    ("SingularCovariance", "returned a singular covariance()", {}),
    ("CovarianceWrongShape", "covariance() returned shape (5, 2, 2); expected (N, n, n)", {}),
    ("ReturnsNaN", "returned NaN at step 3 (its estimates were finite before)", {}),
    ("WrongShape", f"returned shape (4, 3, {TRIALS}) at step 0; expected (N, n, B) = (4, 2, {TRIALS})", {}),
    ("NotAnArray", "returned NoneType at step 0; expected (N, n, B)", {}),
    ("IntegerEstimates", "returned int64 estimates at step 0; expected floats", {}),
    ("WritesY", "failed at step 0: wrote into its inputs", {}),
    ("UnlocksY", "failed at step 0: wrote into its inputs", {}),
    ("WritesProblem", "failed at step 0: wrote into its inputs", {}),
    ("WritesInbox", "failed at step 0: wrote into its inputs", {}),
    ("WiderMessage", "sent more than it declared at step 0: messages of 2 numbers (declared: messages of 1 number, "
                     "1 per step)", {}),
    ("ExtraExchange", "sent more than it declared at step 3: exchange number 2 of a step that allows 1", {}),
    ("UndeclaredSender", "sent more than it declared at step 0: exchange number 1 of a step that allows 0 (it "
                         "declared that it sends nothing)", {}),
    ("TooSlow", "is too slow: ", {"time_limit": 1e-3}),
    ("NotUnbiased", "declares linear matrices that are not unbiased at step 0", {}),
    ("MatricesWrongShape", "matrices(0) gave A (8, 8) and B (8, 3); expected (8, 8) and (8, 4)", {}),
    ("MatricesNotALinearStep", "matrices(0) returned tuple, not a LinearStep", {}),
]


@pytest.mark.parametrize("cls,what,keys", FAULTS, ids=[f[0] for f in FAULTS])
def test_a_bad_filter_gets_one_line_and_the_others_are_unchanged(cls, what, keys, baselines, tmp_path, capsys):
    data = scenario(bad={"factory": f"{BAD}:{cls}", **keys})
    rc, err = run_cli(data, tmp_path, capsys)
    lines = [line for line in err if line.startswith("dse: estimator ")]
    assert rc == 4 and len(lines) == 1 and lines == err, err
    assert lines[0].startswith("dse: estimator 'bad' ") and what in lines[0], lines[0]
    run = dse.run(data, trials=TRIALS, seed=SEED, workers=1, cache_dir=tmp_path / "out" / ".cache")
    faults = run.tables["faults"]
    assert list(faults["estimator"]) == ["bad"] and what in faults["what"].item(), faults
    assert run.faults == [faults["what"].item()]
    assert_others_unchanged(run.results, baselines("reliable"))
    claims = {c["id"]: c for c in run.evaluation.claims}
    assert not any(c["verdict"] == "error" for c in claims.values())
    exact = claims["compare.plugin.bad.exact_moments"]        # not checkable, saying why
    assert exact["verdict"] == "not-checkable" and what in exact["detail"], exact["detail"]


@pytest.mark.parametrize("model", ["failures", "poisson"])
def test_two_bad_filters_each_get_their_own_line(model, baselines, tmp_path, capsys):
    data = scenario(model, raises={"factory": f"{BAD}:RaisesInStep"}, wide={"factory": f"{BAD}:WiderMessage"},
                    extra={"factory": f"{BAD}:ExtraExchange"})
    rc, err = run_cli(data, tmp_path, capsys)
    assert rc == 4 and len(err) == 3, err
    assert sorted(line.split("'")[1] for line in err) == ["extra", "raises", "wide"]
    assert all(line.startswith("dse: estimator '") and line.endswith(
        "; left out, the other estimators' results are unchanged") for line in err), err
    repro = registry.from_dict(data)
    res = repro.compute(RunOptions(seed=SEED, trials=TRIALS, workers=2), StageContext(MemoryCache())).results
    assert set(res.faults) == {"raises", "wide", "extra"}
    assert_others_unchanged(res, baselines(model))


def test_a_bad_filter_in_a_later_chunk_is_dropped_from_every_chunk(baselines):
    """With one RNG unit per memory chunk, the filter fails in the first chunk and is not built again; the
    others' numbers do not depend on the chunking."""
    repro = registry.from_dict(scenario(bad={"factory": f"{BAD}:RaisesInStep"}))
    res = repro.compute(RunOptions(seed=SEED, trials=TRIALS, workers=1, max_memory_mib=16.0),
                        StageContext(MemoryCache())).results
    assert list(res.faults) == ["bad"]
    assert_others_unchanged(res, baselines("reliable"))


def test_the_measurements_a_filter_unlocks_are_not_the_others():
    """`UnlocksY` sets the writeable flag of its measurements back to True and zeroes them: numpy allows that on
    a plain read-only view of a writeable array, so every filter stepping after it saw zero measurements."""
    from dse.plugin.harness import read_only

    shared = np.ones((2, 3))
    view = read_only(shared)
    with pytest.raises(ValueError):
        view.flags.writeable = True
    with pytest.raises(ValueError):
        view[0, 0] = 0.0
    assert (shared == 1).all() and np.shares_memory(view, shared)


# -- declarations refused before anything runs ----------------------------------------------------------------

DECLARATIONS = [
    ({"factory": "tests.plugins.no_such_module:X"}, "estimators.bad.factory", "cannot load"),
    ({"factory": f"{BAD}:NoSuchClass"}, "estimators.bad.factory", "cannot load"),
    ({"factory": BAD}, "estimators.bad.factory", "must be 'package.module:Class'"),
    ({"factory": f"{BAD}:NotAFilter"}, "estimators.bad.factory", "is not a subclass of dse.plugin.NetworkFilter"),
    ({"factory": f"{BAD}:NoStep"}, "estimators.bad.factory", "does not implement step"),
    ({"factory": f"{BAD}:EquivariantWithoutShift"}, "estimators.bad.factory", "equivariant = True but has no shift"),
    ({"factory": f"{BAD}:LinearWithoutMatrices"}, "estimators.bad.factory", "linear = True but has no matrices"),
    ({"factory": f"{BAD}:BadCovarianceLaw"}, "estimators.bad.factory", "covariance_law must be None"),
    ({"factory": f"{BAD}:Tuned", "gain": 2.0}, "estimators.bad.gain", "less than or equal to 1"),
    ({"factory": f"{BAD}:Tuned", "gian": 0.5}, "estimators.bad.gian", "unknown key (the parameters of Tuned: gain)"),
    ({"factory": "tests.plugins.twins:LocalTwin", "gain": 0.5}, "estimators.bad.gain", "unknown key"),
    ({"factory": "tests.plugins.twins:LocalTwin", "time_limit": 0}, "estimators.bad.time_limit", "must be > 0"),
    ({"factory": f"{BAD}:BadSends"}, "estimators.bad", "BadSends.sends raised ValueError"),
    ({"factory": f"{BAD}:SendsNotMessages"}, "estimators.bad", "sends must return Messages or None"),
]


def _refusal(data: dict, tmp_path, capsys) -> tuple[str, int, list[str]]:
    with pytest.raises(ScenarioError) as exc:
        registry.from_dict(data).compute(RunOptions(seed=SEED, trials=TRIALS, workers=1), StageContext(MemoryCache()))
    rc, err = run_cli(data, tmp_path, capsys)
    return str(exc.value), rc, err


@pytest.mark.parametrize("table,key,what", DECLARATIONS, ids=[d[0].get("factory", "").split(":")[-1] + "-" + d[1]
                                                               for d in DECLARATIONS])
def test_a_bad_declaration_is_one_line_naming_the_key(table, key, what, tmp_path, capsys):
    message, rc, err = _refusal(scenario(bad=table), tmp_path, capsys)
    assert message.startswith(f"{key}: ") and what in message, message
    assert rc == 2 and err == [f"dse: error: {message}"], err
    assert not (tmp_path / "out" / "s").exists()


@pytest.mark.parametrize("name,table,what", [
    ("local", {"factory": "tests.plugins.twins:LocalTwin"}, "'local' is a built-in estimator's id"),
    ("no-such-filter", {}, "no filter named 'no-such-filter' is installed (entry point group dse.estimators"),
    ("token", {"factory": "tests.plugins.twins:LocalTwin"}, "'token' is reserved"),
    ("my__filter", {"factory": "tests.plugins.twins:LocalTwin"}, "has no '__'"),
])
def test_a_bad_plugin_name_is_one_line_naming_it(name, table, what, tmp_path, capsys):
    data = scenario()
    data["estimators"][name] = table
    message, rc, err = _refusal(data, tmp_path, capsys)
    assert message.startswith(f"estimators.{name}: ") and what in message, message
    assert rc == 2 and err == [f"dse: error: {message}"], err


def test_exit_code_4_is_documented():
    from pathlib import Path

    doc = (Path(__file__).resolve().parents[1] / "docs" / "output.md").read_text()
    assert "| 4 | `dse run`, `dse arena`: the run completed, but a plug-in filter" in doc
    assert "\n  4    a plug-in filter broke its protocol" in cli.EXIT_CODES


def test_a_filter_whose_estimates_overflowed_may_return_nan():
    repro = registry.from_dict(scenario(model="failures", bad={"factory": f"{BAD}:DivergesThenNaN"}))
    res = repro.compute(RunOptions(seed=SEED, trials=TRIALS, workers=1), StageContext(MemoryCache())).results
    assert not res.faults and "bad" in res.mc
    assert not np.isfinite(res.mc["bad"]["sq"]).all()
