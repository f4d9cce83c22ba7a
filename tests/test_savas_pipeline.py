"""The noisy-consensus-filter family in the pipeline: declared keys, the design stage, the tables
(against the independent computations the claims use), the metrics sweeps plot, the cost estimate,
and streaming Monte Carlo (identical whatever the memory budget; bounded memory over long horizons)."""
from __future__ import annotations

import re
import subprocess
import sys
import time
import tomllib
from pathlib import Path

import numpy as np
import pytest

import dse.estimators.consensus_covariance as cc
import dse.estimators.gain_tuning as gt
import dse.registry
from dse import api
from dse.contract.options import RunOptions
from dse.contract.context import StageContext
from dse.engine.cache import MemoryCache
from dse.errors import ScenarioError
from dse.families.savas import cells
from dse.families.savas import design as savas_design
from dse.families.savas import monte_carlo
from dse.families.savas.claims.common import eval_traces
from dse.families.savas.scenario import NoisyConsensusFile
from dse.scenario.declare import parse, reference_rows
from dse.sweeps.run import network_metrics

ROOT = Path(__file__).resolve().parents[1]
PAPER = ROOT / "dse" / "families" / "savas" / "paper.toml"

SMALL = {"family": "noisy-consensus-filter", "name": "small", "graph": {"kind": "ring", "n": 4},
         "consensus": {"weights": "laplacian", "eps": 0.3}, "model": {"q": 0.7, "r": 9.0, "sigma0": 1.5},
         "sweep": {"rounds": [0, 2], "sigma_c": [0.0, 1.5], "n_steps": 30, "eval_step": 3, "recorded_steps": 12},
         "gains": {"grid": [41, 41]}, "monte_carlo": {"trials": 2500, "sample_paths": 2, "sample_steps": 6}}


# -- declared keys -------------------------------------------------------------------------------------

def test_every_key_is_declared_with_a_meaning():
    rows = [(path, r) for path, table, _ in reference_rows(NoisyConsensusFile) for r in table]
    assert len(rows) > 25
    for path, r in rows:
        assert r["meaning"].strip(), f"{path}.{r['key']} has no meaning"
    # an undocumented key cannot even be declared
    from dse.scenario.declare import key

    with pytest.raises(ValueError, match="meaning"):
        key(1, doc=" ")


def test_the_paper_file_comments_every_key():
    for line in PAPER.read_text().splitlines():
        if re.match(r"^\s*[A-Za-z_][\w.]*\s*=", line):
            assert "#" in line, f"paper.toml: no comment on {line.strip()!r}"
    data = tomllib.loads(PAPER.read_text())
    data.pop("family")
    parse(NoisyConsensusFile, data)


@pytest.mark.parametrize("change, field, words", [
    ({"graph": {"kind": "line", "n": 1}}, "graph.n", "must be >= 2"),
    ({"graph": {"kind": "edges", "n": 4, "edges": [[0, 1], [2, 3]]}}, "graph", "not connected"),
    ({"graph": {"kind": "edges", "n": 3, "edges": [[0, 1], [1, 2], [2, 1]]}}, "graph.edges[2]", "repeats"),
    ({"graph": {"kind": "ring", "n": 1001}}, "graph.n", "at most 1000"),
    ({"sweep": {"n_steps": 100_001}}, "sweep.n_steps", "<= 100000"),
    ({"sweep": {"rounds": [0, 2], "sigma_c": [0.0], "n_steps": 5, "eval_step": 5}}, "sweep.eval_step", "< n_steps"),
    ({"carli": {"ell": 1.5}}, "carli.ell", "<= 1"),
    ({"reinjection": {"gains": "fixed", "ell": 0.3}}, "reinjection.zeta", "missing"),
    ({"reinjection": {"zeta": 0.3}}, "reinjection.zeta", "only allowed"),
    ({"consensus": {"weights": "metropolis", "eps": 0.2}}, "consensus.eps", "only with"),
    ({"gains": {"rounds_max": 1}}, "gains.rounds_max", ">= max(sweep.rounds)"),
    ({"gains": {"grid": [41]}}, "gains.grid", "at least 2"),
    ({"name": "a\u202eb"}, "name", "must match"),
    ({"monte_carlo": {"trials": 10**9}}, "monte_carlo.trials", "<= 100000000"),
])
def test_invalid_input_names_its_field(change, field, words):
    data = {**SMALL, **change}
    with pytest.raises(ScenarioError) as err:
        dse.registry.from_dict(data)
    assert err.value.field == field and words in err.value.reason, str(err.value)


# -- the run and its tables ------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def small_run():
    return api.run(SMALL, quick=True, seed=3)


def test_design_is_the_runs_design_and_hypotheses_are_decided_on_it(small_run):
    repro = small_run.reproduction
    d = repro.design(RunOptions(quick=True, seed=3), StageContext(MemoryCache()))
    same = small_run.computed.design
    assert d.arrays.keys() == same.arrays.keys()
    for k in d.arrays:
        np.testing.assert_array_equal(d.arrays[k], same.arrays[k], err_msg=k)
    assert [h.evaluate(d) for h in repro.hypotheses()] == small_run.evaluation.hypotheses
    check = api.check(SMALL, quick=True, seed=3)
    assert {"consensus_matrix", "spectrum", "references", "gains", "cells", "steady_covariance"} <= set(check.tables)
    assert check.estimate["seconds"] > 0 and check.estimate["peak_memory_mib"] > 250
    for name in check.tables:   # design tables are the run's
        assert check.tables[name].equals(small_run.tables[name]), name


def test_no_claim_fails_or_errs_and_steps_are_decimated(small_run):
    bad = [(r["id"], r["verdict"]) for r in small_run.evaluation.claims if r["verdict"] in ("fail", "error")]
    assert not bad
    res = small_run.results
    assert len(res.design.steps) == 12 and res.design.steps[-1] == 29 and 3 in res.design.steps
    assert "12 recorded steps" in next(r["detail"] for r in small_run.evaluation.claims if r["id"] == "small.mc.trace")


def test_nodes_table_equals_the_independent_computations(small_run):
    res, t = small_run.results, small_run.tables
    sc = res.scenario
    nodes = t["nodes"]
    q, r, sigma0, n_steps, eval_step = sc.model.q, sc.model.r, sc.model.sigma0, sc.sweep.n_steps, sc.sweep.eval_step
    Pc = gt.optimal_gain_no_communication(q, r / sc.n, sc.n)[1] / sc.n
    kf = np.array([sigma0])
    for _ in range(n_steps - 1):
        kf = np.append(kf, kf[-1] * (r / sc.n) / (kf[-1] + r / sc.n) + q)
    for c in res.cells:
        rows = nodes[(nodes["alg"] == c.alg) & (nodes["m"] == c.m) & (nodes["sigma_c"] == c.sigma_c)
                     & (nodes["n_steps"] == c.n_steps)].sort_values("node")
        kw = dict(ell=c.ell, m=c.m, sigma_c=c.sigma_c, q=q, r=r, reinjection=c.reinjection, zeta=c.zeta)
        P_inf = cc.asymptotic_covariance_lyapunov(sc.Q, **kw)   # as the claims' steady state
        np.testing.assert_allclose(rows["P_steady"], np.diag(P_inf), rtol=1e-11)
        seq = cc.predictive_covariance_sequence(sc.Q, sigma0=sigma0, n_steps=c.n_steps, **kw)   # (22) iterated
        np.testing.assert_allclose(rows["P_final_exact"], np.diag(seq[-1]), rtol=1e-11)
        np.testing.assert_allclose(rows["P_eval_exact"], np.diag(seq[eval_step]), rtol=1e-11)
        mom = res.moments(c)
        np.testing.assert_array_equal(rows["P_final_mc"], mom.variance[-1])
        np.testing.assert_array_equal(rows["P_final_mc_se"], mom.variance_se[-1])
        np.testing.assert_allclose(rows["kf_final"], kf[-1], rtol=1e-13)
        np.testing.assert_allclose(rows["kf_steady"], Pc, rtol=1e-13)
        np.testing.assert_allclose(rows["gap_steady"], np.diag(P_inf) - Pc, rtol=1e-9, atol=1e-12)
    cells = t["cells"]
    for c in res.cells:
        row = cells[(cells["alg"] == c.alg) & (cells["m"] == c.m) & (cells["sigma_c"] == c.sigma_c)
                    & (cells["n_steps"] == c.n_steps)].iloc[0]
        P_inf = cc.asymptotic_covariance_lyapunov(sc.Q, ell=c.ell, m=c.m, sigma_c=c.sigma_c, q=q, r=r,
                                                  reinjection=c.reinjection, zeta=c.zeta)
        assert row["loewner_gap_steady"] == pytest.approx(np.linalg.eigvalsh(P_inf - Pc * np.ones((sc.n, sc.n))).min(),
                                                          rel=1e-9, abs=1e-12)
        assert row["loewner_gap_steady"] >= -1e-12


def test_series_gains_and_thresholds_are_what_the_claims_use(small_run):
    res, t = small_run.results, small_run.tables
    sc = res.scenario
    for alg in ("carli", "reinjection"):
        traces = eval_traces(res, alg)
        ts = t["trace_series"]
        ts = ts[(ts["alg"] == alg) & (ts["k"] == sc.sweep.eval_step) & (ts["n_steps"] == sc.sweep.n_steps)]
        exact = ts.pivot(index="sigma_c", columns="m", values="trP_exact").to_numpy()
        np.testing.assert_array_equal(exact, traces)
    g = t["gains"]
    corrected = g[g["objective"] == "corrected"].pivot(index="sigma_c", columns="m", values="ell")
    np.testing.assert_array_equal(corrected.loc[:, : sc.rounds_max].to_numpy(), res.bounds["corrected_ell"])
    np.testing.assert_array_equal(corrected.loc[:, cells.LARGE_M].to_numpy(), res.bounds["large_m_ell"])
    thr = t["carli_thresholds"]["sigma_c_threshold"].to_numpy()
    np.testing.assert_array_equal(thr, savas_design.carli_thresholds(sc, sc.sweep.rounds)[0])
    ns = t["node_series"]
    assert len(ns) == len(res.design.cells) * 12 * sc.n + 60 * sc.n   # the cells' recorded steps and the long run
    paths = t["sample_paths"]
    assert paths["k"].max() == sc.monte_carlo.sample_steps - 1 and paths["trial"].max() == sc.monte_carlo.sample_paths - 1


def test_metrics_have_the_cell_in_columns_and_the_sweeps_names():
    sweep = tomllib.loads((ROOT / "dse" / "families" / "sweeps" / "savas_noise_rounds_size.toml").read_text())
    point = {**SMALL, "sweep": {**SMALL["sweep"], "rounds": [2], "sigma_c": [1.5]}}
    run = api.run(point, quick=True, trials=200)
    m = run.tables["metrics"]
    assert str(m["node"].dtype) == "Int64" and str(m["m"].dtype) == "Int64"
    assert not m[m["alg"] != "centralized"][["m", "sigma_c"]].isna().any().any()
    network = network_metrics(m)
    for name in sweep["plot"]["metrics"]:
        assert name in network, name
    assert network["reinjection_trP_exact"] == pytest.approx(eval_traces(run.results, "reinjection")[0, 0],
                                                             rel=0, abs=0)
    per_node = m[(m["metric"] == "carli_P_exact")]
    assert sorted(per_node["node"].tolist()) == list(range(4))


# -- streaming -------------------------------------------------------------------------------------------

def _design(sc):
    """The design stage computed directly (no cache), with the quick gain grid."""
    return savas_design.Design.of(sc, savas_design.design_arrays(sc, cells.QUICK_GRID))


def test_monte_carlo_is_identical_whatever_the_memory_budget():
    sc = dse.registry.from_dict({**SMALL, "monte_carlo": {"trials": 2500, "sample_paths": 2}}).scenario
    d = _design(sc)
    group = tuple(c for c in d.cells if c.alg == "reinjection" and c.m == 2)
    steps = d.steps
    tiny = monte_carlo.simulate_group(sc, 5, 2500, steps, 1.0, group)            # one unit of 1,000 trials at a time
    large = monte_carlo.simulate_group(sc, 5, 2500, steps, 2.0**30, group)       # every unit together
    assert tiny.keys() == large.keys()
    for k in tiny:
        np.testing.assert_array_equal(tiny[k], large[k], err_msg=k)


def _peak_of(args, tmp_path) -> tuple[int, float, str, int]:
    # VmHWM: this process's own high-water mark (ru_maxrss would keep the forking test process's size across exec)
    code = ("import re, sys; from dse.cli import main; rc = main(sys.argv[1:]); "
            "print('PEAK', re.search(r'VmHWM:\\s*(\\d+)', open('/proc/self/status').read()).group(1)); sys.exit(rc)")
    start = time.perf_counter()
    proc = subprocess.run([sys.executable, "-c", code, *args], cwd=tmp_path, capture_output=True, text=True, timeout=600,
                          env={"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin", "DSE_PROGRESS": "0",
                               "OPENBLAS_NUM_THREADS": "1"})
    peak = int(next(line.split()[1] for line in proc.stdout.splitlines() if line.startswith("PEAK")))
    return proc.returncode, time.perf_counter() - start, proc.stderr + proc.stdout, peak


def test_long_horizon_runs_in_bounded_memory(tmp_path):
    """5,000 steps x 1,000 trials: the stored errors would take 3 x 5,000 x 1,000 x 16 bytes = 240 MB per cell besides
    about 300 MiB of libraries; streamed over time and trials the run stays within a 400 MiB budget."""
    text = """family = "noisy-consensus-filter"
name = "long"
[graph]
kind = "line"
n = 3
[consensus]
weights = "laplacian"
eps = 0.4
[model]
q = 1.0
r = 25.0
[sweep]
rounds = [1]
sigma_c = [2.0]
n_steps = 5000
"""
    (tmp_path / "long.toml").write_text(text)
    rc, seconds, out, peak_kib = _peak_of(["run", "long.toml", "--trials", "1000", "--quick", "--workers", "1",
                                           "--max-memory", "400M", "--out", "out"], tmp_path)
    assert rc == 0, out
    assert peak_kib / 1024 < 400, f"peak {peak_kib / 1024:.0f} MiB"
    import pandas as pd

    ts = pd.read_parquet(tmp_path / "out" / "run" / "long" / "tables" / "trace_series.parquet")
    assert ts["k"].max() == 4_999 and ts["k"].nunique() == 1000


def test_unstreamable_outputs_beyond_the_budget_are_refused_before_running(tmp_path):
    data = {**SMALL, "graph": {"kind": "ring", "n": 300}, "consensus": {"weights": "metropolis"},
            "sweep": {"rounds": [0, 1, 2, 3], "sigma_c": [0.0, 0.5, 1.0, 2.0], "n_steps": 100_000,
                      "recorded_steps": 100_000}}
    repro = dse.registry.from_dict(data)
    opts = RunOptions(quick=True, max_memory_mib=2000)
    cost = repro.cost(opts)
    assert cost.sized_by == "sweep.recorded_steps" and cost.kept_mib > 2000
    with pytest.raises(ScenarioError) as err:     # by the driver, before any stage runs
        api.execute(repro, opts)
    assert err.value.field == "sweep.recorded_steps" and "MiB" in err.value.reason


def test_estimate_of_the_monte_carlo_is_within_a_factor_of_two_of_its_cost():
    """The cost model's Monte Carlo part against the CPU time of the same groups (factor 2 stated)."""
    run = dse.registry.from_dict({**SMALL, "sweep": {**SMALL["sweep"], "n_steps": 200, "recorded_steps": 50},
                                  "monte_carlo": {"trials": 3000, "sample_paths": 0}})
    sc = run.scenario
    opts = RunOptions(quick=True, workers=1, trials=3000)
    d = _design(sc)
    start = time.process_time()
    for group in monte_carlo.cell_groups(d.all_cells()):
        monte_carlo.simulate_group(sc, 0, 3000, d.steps_of(group[0]), opts.chunk_budget_bytes(), group)
    measured = time.process_time() - start
    predicted = run.cost(opts).detail
    mc = float(re.search(r"Monte Carlo ([\d.e+]+) s", predicted).group(1))
    assert 0.5 < mc / measured < 2.0, (mc, measured)
