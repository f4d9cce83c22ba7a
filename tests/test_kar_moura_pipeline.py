"""The gossip-kalman family on the pipeline: declared keys, the design stage (dse check) and the
hypotheses on it, the tables against the quantities the claims use, streaming identity whatever the
memory budget, long horizons in bounded memory, refusal before running, the cost estimate, singular
P0, a prior mean and a replayed matching sequence."""
from __future__ import annotations

import copy
import math
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import dse.estimators.gossip_kalman as gk
import dse.families as families
from dse.api import check, execute
from dse.contract.cost import refuse_if_too_large
from dse.contract.options import RunOptions
from dse.contract.context import StageContext
from dse.engine.cache import MemoryCache
from dse.errors import ScenarioError
from dse.families.kar_moura.cost import gikf_bytes_per_run
from dse.families.kar_moura.gikf import gikf
from dse.families.kar_moura.scenario import SCENARIO_DIR, GossipKalmanFile
from dse.scenario.declare import reference_rows

ROOT = Path(__file__).resolve().parent.parent

SMALL = {"family": "gossip-kalman", "name": "small",
         "model": {"F": [[1.2, 0.0], [0.0, 1.1]], "Q": [[0.1, 0.0], [0.0, 0.1]], "P0": [[1.0, 0.0], [0.0, 1.0]]},
         "sensors": {"pattern": [0, 1], "C": [[[1.0, 0.0]], [[0.0, 1.0]]], "R": [[[1.0]], [[1.0]]]},
         "graph": {"kind": "ring", "n": 4},
         "protocol": {"kind": "single-edge", "edge_prob": 0.2},
         "simulation": {"slots": 40, "runs": 300, "reference_runs": 600, "quick_slots": 40,
                        "record_times": [1, 2, 5, 20, 40]}}


def small(**changes) -> dict:
    data = copy.deepcopy(SMALL)
    for path, value in changes.items():
        *head, last = path.split("__")
        d = data
        for h in head:
            d = d[h]
        if value is None:
            d.pop(last, None)
        else:
            d[last] = value
    return data


# -- declared keys --------------------------------------------------------------------------------------------

def test_every_key_is_declared_with_a_meaning():
    rows = [(p, r) for p, rs, _ in reference_rows(GossipKalmanFile) for r in rs]
    assert len(rows) > 30
    for path, row in rows:
        assert row["meaning"].strip(), f"{path}.{row['key']} has no meaning"


def test_shipped_files_comment_every_key():
    for f in sorted(SCENARIO_DIR.glob("*.toml")):
        lines = f.read_text().splitlines()
        for i, line in enumerate(lines):
            if line and line[0].isalpha() and "=" in line:
                key = line.split("=")[0].strip()
                assert lines[i - 1].startswith(f"# {key}:") or (key == "kind" and lines[i - 1].startswith("# kind")), \
                    f"{f.name}: {key} has no comment"


@pytest.mark.parametrize("changes, field, words", [
    ({"model__Q": [[0.1, 0.0], [0.0, 0.0]]}, "model.Q", "positive definite"),
    ({"model__P0": [[1.0, 0.0], [0.0, -1e-3]]}, "model.P0", "positive semidefinite"),
    ({"model__x0": [1.0]}, "model.x0", "2 entries"),
    ({"graph__n": 1, "graph__kind": "line"}, "graph.n", "must be >= 2"),
    ({"graph__kind": "edges", "graph__edges": [[0, 1], [1, 0]]}, "graph.edges[1]", "repeats"),
    ({"graph__kind": "edges", "graph__edges": [[0, 0]]}, "graph.edges[0]", "self-loop"),
    ({"graph__kind": "complete", "graph__n": 1001}, "graph.n", "at most 1000"),
    ({"protocol": {"kind": "sequence", "sequence": [[[0, 2]]]}}, "protocol.sequence[0][0]", "not an edge"),
    ({"protocol": {"kind": "sequence", "sequence": [[[0, 1], [1, 2]]]}}, "protocol.sequence[0][1]", "matched twice"),
    ({"protocol": {"kind": "sequence"}}, "protocol.sequence", "missing"),
    ({"protocol": {"kind": "single-edge", "edge_prob": 0.2, "p_link": 0.5}}, "protocol.p_link", "not a key"),
    ({"comparison_protocol": {"kind": "sequence", "sequence": [[[0, 1]]]}}, "comparison_protocol.kind", "Remark 9"),
    ({"simulation__quick_slots": 50}, "simulation.quick_slots", "<= 40"),
    ({"simulation__record_times": [5, 2]}, "simulation.record_times", "increasing"),
    ({"name": "bad\u202ename"}, "name", "must match"),
])
def test_invalid_input_names_its_field(changes, field, words):
    with pytest.raises(ScenarioError) as err:
        families.from_dict(small(**changes))
    assert err.value.field == field and words in err.value.reason, (err.value.field, err.value.reason)


def test_singular_p0_runs_and_a_disconnected_graph_is_a_hypothesis(tmp_path):
    """A P0 that is only positive semidefinite (a zero eigenvalue, or −1e-12 within the shared tolerance) is
    accepted and runs: nothing takes a Cholesky factor of it. Two disconnected rings: C.1 fails as a hypothesis."""
    for P0 in ([[1.0, 1.0], [1.0, 1.0]], [[0.0, 0.0], [0.0, 0.0]], [[1.0, 0.0], [0.0, -1e-12]]):
        repro = families.from_dict(small(model__P0=P0, simulation={"slots": 12, "runs": 100,
                                                                                "reference_runs": 200}))
        run = execute(repro, RunOptions(quick=True, seed=2))
        assert run.counts["fail"] == 0 and run.counts["error"] == 0, run.claims[run.claims.verdict == "fail"]
    repro = families.from_dict(small(graph={"kind": "edges", "n": 4, "edges": [[0, 1], [2, 3]]}))
    hyp = {h["id"]: h for h in check(repro).hypotheses}
    assert hyp["small.hyp.c1"]["holds"] is False


# -- design ---------------------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def small_run():
    repro = families.from_dict(small(model__x0=[3.0, -1.0]))
    return repro, execute(repro, RunOptions(quick=True, seed=4))


def test_design_is_the_runs_design_and_hypotheses_are_decided_on_it(small_run):
    repro, run = small_run
    d = repro.design(RunOptions(quick=True, seed=4), StageContext(MemoryCache()))
    d_run = run.computed.design
    for name, sd in d.scenarios.items():
        rd = d_run.scenarios[name]
        for k, v in sd.bounds.items():
            np.testing.assert_array_equal(v, rd.bounds[k], err_msg=k)
    hyp_check = [h.evaluate(d) for h in repro.hypotheses()]
    assert [(h["id"], h["holds"], h["value"]) for h in hyp_check] == \
        [(h["id"], h["holds"], h["value"]) for h in run.evaluation.hypotheses]
    tables = dict(repro.design_tables(d))
    design = tables[next(s for s in tables if s.name == "design")]
    assert design.loc[design.quantity == "slem", "value"].item() == pytest.approx(float(d_run.scenarios["small"].bounds["slem"]), abs=0)


def test_check_is_fast_on_the_paper_example():
    start = time.process_time()          # CPU time: not the machine's load (make test runs 2 processes per core)
    c = check(str(SCENARIO_DIR / "e1.toml"))
    assert time.process_time() - start < 10
    assert {"design", "f_eigenvalues", "abar", "witness_walks", "tail_bounds", "reference_series"} <= set(c.tables)
    d = c.tables["design"].set_index("quantity")["value"]
    assert d["witness_length"] == 2 and d["witness_walks"] == 20 and d["observability_rank"] == 2
    assert c.estimate["seconds"] > 0 and c.estimate["peak_memory_mib"] > 0


# -- tables -----------------------------------------------------------------------------------------------

def test_tables_equal_the_quantities_the_claims_use(small_run):
    repro, run = small_run
    r = run.results.scenarios["small"]
    g, b, ref = r.gikf, r.bounds, r.reference
    nodes = run.tables["nodes"].set_index("node")
    tr_T = np.exp(g["feat_n"][-1][gk.FEATURES.index("log_trace")])
    np.testing.assert_allclose(nodes["median_trace"], np.median(tr_T, axis=0), rtol=1e-14)
    assert (nodes["central_trace"] == np.trace(b["P_central"][-1])).all()
    assert nodes["loewner_margin"].min() >= 0 or (nodes["loewner_slack"] >= 0).all()
    assert (nodes["floor_trace"] <= nodes["q05_trace"] * (1 + 1e-12)).all()          # domination, pathwise
    entries = run.tables["node_entries"]
    mean = entries[(entries.row == 0) & (entries.col == 0)].set_index("node")["mean"]
    np.testing.assert_allclose(mean, g["final_sum"][:, 0, 0] / r.runs, rtol=0)
    q = run.tables["quantiles"]
    med = q[(q.probability == 0.5) & (q.t == r.slots)].set_index("node")["log_trace"]
    np.testing.assert_array_equal(med.to_numpy(), g["quantiles"][-1, :, gk.QUANTILES.index(0.5)])
    m = run.tables["metrics"]
    net = m[m.node.isna()].set_index("metric")["value"]
    assert {"median_log_trP", "q90_log_trP", "central_log_trP", "slem"} <= set(net.index)   # the shipped sweep's names
    assert net["slem"] == float(b["slem"])
    paths = run.tables["sample_paths"]
    est = paths[(paths.t == 0) & paths.node.notna()]
    np.testing.assert_allclose((est.state - est.error).to_numpy(), est.estimate.to_numpy())
    first = paths[(paths.t == 0) & (paths.node == 0) & (paths.run == 0)]
    np.testing.assert_allclose(first.estimate.to_numpy(), [3.0, -1.0], atol=1e-12)       # x̂(0) = the prior mean
    laws = run.tables["laws"]
    mu = laws[(laws.law == "theorem8") & (laws.t == r.slots)]
    np.testing.assert_allclose(mu.log_trace, np.quantile(ref["features"][-1][0], mu.probability), rtol=0)
    env = run.tables["reference_series"]
    env = env[env.series == "envelope"]
    np.testing.assert_allclose(env.trace.to_numpy()[:5], [np.trace(_lyap(t)) for t in range(5)], rtol=1e-13)
    for name in run.tables:
        assert list(run.tables[name].columns) == run.tables.specs[name].column_names


def _lyap(t: int) -> np.ndarray:
    F, Q, X = np.diag([1.2, 1.1]), 0.1 * np.eye(2), np.eye(2)
    for _ in range(t):
        X = F @ X @ F.T + Q
    return X


# -- streaming ----------------------------------------------------------------------------------------------

def test_monte_carlo_is_identical_whatever_the_memory_budget():
    repro = families.from_dict(small(simulation={"slots": 30, "runs": 2500, "reference_runs": 200}))
    sc, d = repro.scenario, repro.design(RunOptions(), StageContext(MemoryCache())).scenarios["small"]
    per_run = gikf_bytes_per_run(sc, 30)
    tiny = gikf(sc, d.bounds, 3, 2500, 30, "protocol", budget_bytes=1.0, bytes_per_run=per_run)   # one unit at a time
    large = gikf(sc, d.bounds, 3, 2500, 30, "protocol", budget_bytes=2.0**32, bytes_per_run=per_run)   # all together
    assert tiny.keys() == large.keys()
    for k in tiny:
        np.testing.assert_array_equal(tiny[k], large[k], err_msg=k)


def _peak_of(args, tmp_path) -> tuple[int, str, int]:
    # VmHWM: the child's own high-water mark (ru_maxrss keeps the forking parent's size across exec, so a large
    # pytest process would be measured instead of the run)
    code = ("import sys; from dse.cli import main; rc = main(sys.argv[1:]); "
            "print('PEAK', next(l.split()[1] for l in open('/proc/self/status') if l.startswith('VmHWM'))); "
            "sys.exit(rc)")
    proc = subprocess.run([sys.executable, "-c", code, *args], cwd=tmp_path, capture_output=True, text=True, timeout=600,
                          env={"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin", "DSE_PROGRESS": "0",
                               "OPENBLAS_NUM_THREADS": "1"})
    peak = int(next(line.split()[1] for line in proc.stdout.splitlines() if line.startswith("PEAK")))
    return proc.returncode, proc.stderr + proc.stdout, peak


def test_long_horizon_runs_in_bounded_memory(tmp_path):
    """The Lyapunov envelope f_0^t(P0) grows like ρ(F)^(2t) and leaves float64 (E1's F near slot 1,950; F = diag(2,
    1.5) here near slot 512); it is carried rescaled, chains are drawn slot by slot and per-slot statistics kept at a
    bounded set of slots, so the run works past that slot within a 400 MiB budget (E1 over 2,000 and 20,000 slots works
    the same way, only longer)."""
    data = small(model__F=[[2.0, 0.0], [0.0, 1.5]], graph={"kind": "edges", "n": 2, "edges": [[0, 1]]},
                 protocol={"kind": "single-edge", "edge_prob": 0.5},
                 simulation={"slots": 700, "runs": 100, "reference_runs": 100, "record_times": [1, 700]})
    (tmp_path / "long.toml").write_text(_toml(data))
    rc, out, peak_kib = _peak_of(["run", "long.toml", "--workers", "1", "--max-memory", "400M", "--out", "out"], tmp_path)
    assert rc == 0, out[-3000:]
    assert peak_kib / 1024 < 400, f"peak {peak_kib / 1024:.0f} MiB"
    ref = pd.read_parquet(tmp_path / "out" / "run" / "small" / "tables" / "reference_series.parquet")
    env = ref[ref.series == "envelope"]
    assert env.t.max() == 700 and np.isfinite(env.log_trace).all() and np.isinf(env.trace).any()
    nodes = pd.read_parquet(tmp_path / "out" / "run" / "small" / "tables" / "nodes.parquet")
    assert (nodes["T"] == 700).all() and np.isfinite(nodes["median_trace"]).all()


def _toml(data: dict) -> str:
    """A scenario dict as TOML (JSON arrays and strings are TOML too)."""
    import json

    top = [f"{k} = {json.dumps(v)}" for k, v in data.items() if not isinstance(v, dict)]
    tables = [f"[{k}]\n" + "\n".join(f"{kk} = {json.dumps(vv)}" for kk, vv in v.items())
              for k, v in data.items() if isinstance(v, dict)]
    return "\n".join(top + tables) + "\n"


def test_beyond_the_budget_is_refused_before_running():
    repro = families.from_dict(small(graph={"kind": "ring", "n": 300}, protocol={"kind": "node-initiated"},
                                                 simulation={"slots": 300, "runs": 100000, "reference_runs": 1000}))
    opts = RunOptions(max_memory_mib=4000)
    with pytest.raises(ScenarioError) as err:
        refuse_if_too_large(repro.cost(opts), opts)
    assert err.value.field == "simulation.runs" and "MiB" in err.value.reason
    with pytest.raises(ScenarioError):                               # the driver refuses before computing
        execute(repro, opts)
    greedy = families.from_dict(small(graph={"kind": "complete", "n": 400},
                                                  protocol={"kind": "greedy-matching", "p_link": 0.5}))
    opts = RunOptions(max_memory_mib=2000)
    with pytest.raises(ScenarioError) as err:                       # 79,800 edge priorities per run
        refuse_if_too_large(greedy.cost(opts), opts)
    assert err.value.field == "protocol.kind" and "edges" in err.value.reason


# -- a replayed matching sequence -------------------------------------------------------------------------------

def test_a_replayed_sequence_checks_the_pathwise_claims_only():
    data = small(protocol={"kind": "sequence", "sequence": [[[0, 1], [2, 3]], [], [[1, 2], [3, 0]]]},
                 simulation={"slots": 30, "runs": 200, "reference_runs": 400})
    repro = families.from_dict(data)
    run = execute(repro, RunOptions(quick=True))
    v = run.claims.set_index("id")["verdict"]
    assert run.counts["fail"] == 0 and run.counts["error"] == 0
    for cid in ("centralized.domination", "lemma16.support", "prop7-ii.pathwise", "nees.consistency"):
        assert v[f"small.{cid}"] in ("pass", "erratum"), cid
    for cid in ("thm10-i.weak-consensus", "thm10-iii.bounded", "prop6.token-chain"):
        assert v[f"small.{cid}"] == "not-checkable", cid
    hyp = run.hypotheses.set_index("id")["holds"]
    assert hyp["small.hyp.random-protocol"] == False  # noqa: E712
    m = run.tables["matchings"]
    m = m[(m.run == 0) & (m.node == 0)].sort_values("t")["partner"].to_numpy()
    assert list(m[:7]) == [0, 1, 0, 3, 1, 0, 3]                        # A(0) = I, then the cycle of three slots
    tr = run.tables["sample_paths"]
    tr = tr[(tr.node == 0) & (tr.component == 0) & (tr.t == 30)]
    assert tr.trace.nunique() == 1                                     # the same matchings in every run
    a = run.tables["abar"]
    assert math.isclose(a[(a.row == 0) & (a.col == 1)].value.item(), 1 / 3)
