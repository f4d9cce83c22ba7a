"""The random-comm-filter family in the pipeline: declared keys and the shared policy for degenerate
input, the design stage and `dse check`, the tables against independent computations, the scenario
fields a researcher needs (P_i(0) per node, the automatic gridded step), the cost estimate, and
streaming (identical whatever the memory budget; bounded memory over a long horizon; refusal of what
cannot be streamed)."""
from __future__ import annotations

import copy
import dataclasses
import re
import subprocess
import sys
import time
import tomllib
from pathlib import Path

import numpy as np
import pytest
import scipy.linalg as sla

from dse import api, registry
from dse.contract import stages as stage_mod
from dse.contract.options import RunOptions
from dse.contract.stages import code_closure, code_hash
from dse.errors import ScenarioError
from dse.families.tanwani import cost, design, monte_carlo
from dse.families.tanwani.scenario import RandomCommFile
from dse.scenario.declare import reference_rows
from dse.sweeps.run import network_metrics

ROOT = Path(__file__).resolve().parents[1]
FAMILY_DIR = ROOT / "dse" / "families" / "tanwani"
EXAMPLE = tomllib.loads((FAMILY_DIR / "example.toml").read_text())


def with_(data=EXAMPLE, **changes) -> dict:
    """A copy of `data` with `section__key=value` changes (sensors__2__P_init indexes the list)."""
    out = copy.deepcopy(data)
    for path, value in changes.items():
        node = out
        *head, last = path.split("__")
        for k in head:
            node = node[int(k)] if isinstance(node, list) else node.setdefault(k, {})
        if isinstance(node, list):
            node[int(last)] = value
        elif value is None:
            node.pop(last, None)
        else:
            node[last] = value
    return out


def hypotheses(check) -> dict[str, dict]:
    return {h["id"].rsplit(".", 1)[1]: h for h in check.hypotheses}


# -- declared keys and degenerate input --------------------------------------------------------------------

def test_every_key_is_declared_with_a_meaning():
    rows = [(path, r) for path, table, _ in reference_rows(RandomCommFile) for r in table]
    paths = {f"{path}.{r['key']}" for path, r in rows}
    assert {"sensors[].P_init", "simulation.grid_step", "communication.rates", "system.P0", "graph.edges"} <= paths
    for path, r in rows:
        assert r["meaning"].strip(), f"{path}.{r['key']} has no meaning"
    from dse.scenario.declare import key

    with pytest.raises(ValueError, match="meaning"):
        key(1, doc="")


def test_every_shipped_file_comments_every_key():
    for path in [FAMILY_DIR / "example.toml", *sorted((FAMILY_DIR / "scenarios").glob("*.toml"))]:
        for line in path.read_text().splitlines():
            if re.match(r"^\s*[A-Za-z_][\w.]*\s*=", line):
                assert "#" in line, f"{path.name}: no comment on {line.strip()!r}"
        registry.from_dict(tomllib.loads(path.read_text()))


@pytest.mark.parametrize("change, field, words", [
    ({"graph": {"kind": "line", "n": 1}}, "graph.n", "must be >= 2"),
    ({"graph": {"kind": "edges", "n": 3, "edges": [[0, 1], [1, 1]]}}, "graph.edges[1]", "self-loop"),
    ({"graph": {"kind": "edges", "n": 3, "edges": [[0, 1], [1, 2], [2, 1]]}}, "graph.edges[2]", "repeats"),
    ({"system__P0": [[1.0, 1.0], [1.0, 0.9999999995]]}, "system.P0", "positive semidefinite"),   # eigenvalue −2.5e-10
    ({"system__P0": [[1.0, 0.1], [0.0, 1.0]]}, "system.P0", "symmetric"),
    ({"sensors__2__P_init": [[1.0, 0.0], [0.0, -1e-3]]}, "sensors[2].P_init", "positive semidefinite"),
    ({"sensors__0__V": [[0.0]]}, "sensors[0].V", "positive definite"),
    ({"sensors__1__L": [[1.0], [0.0]]}, "sensors[1].L", "only allowed"),
    ({"simulation__grid_step": 0.03}, "simulation.grid_step", "divide"),
    ({"communication__rates": [30.0], "simulation__grid_step": 0.01}, "simulation.grid_step", "leave grid_step out"),
    ({"communication__rates": [2.0, 2.0]}, "communication.rates", "repeat"),
    ({"communication__sweep": [1.0, 0.5, 10]}, "communication.sweep", "λ_min < λ_max"),
    ({"communication__alpha": 0.75}, "communication.alpha", "1/d_max"),
    ({"title": "a\u202eb"}, "title", "control or format"),
    ({"name": "a\u0000b"}, "name", "must match"),
    ({"graph": {"kind": "complete", "n": 21}}, "graph.n", "N·n = 42"),
])
def test_invalid_input_names_its_field(change, field, words):
    with pytest.raises(ScenarioError) as err:
        registry.from_dict(with_(**change))
    assert err.value.field == field and words in err.value.reason, str(err.value)


def test_disconnected_graph_is_accepted_and_reported():
    data = with_(graph={"kind": "edges", "n": 3, "edges": [[0, 1]]}, communication__mode="edge")
    hyp = hypotheses(api.check(data, quick=True))
    assert hyp["connected"]["holds"] is False and hyp["connected"]["value"] == pytest.approx(0.0, abs=1e-12)
    assert hyp["alpha"]["holds"] is True and hyp["initial"]["holds"] is True


# -- scenario fields a researcher needs ----------------------------------------------------------------------

def test_a_rate_of_20_on_a_star_gets_a_gridded_step_and_says_which():
    data = with_(graph={"kind": "edges", "n": 3, "edges": [[0, 1], [0, 2]]}, communication__rates=[20.0])
    check = api.check(data, quick=True)
    design = check.tables["design"].set_index("quantity")
    h = design.loc["grid_step", "value"]
    assert design.loc["grid_step_automatic", "value"] == 1 and "automatic" in design.loc["grid_step", "definition"]
    assert 20.0 * h * 2 <= 0.5 and np.isclose(0.1 / h, round(0.1 / h))          # λhd_max ≤ 1/2, divides the output step
    assert hypotheses(check)["grid_asymptotic"]["holds"] is True
    # the same step given by hand is what the rule chose; a larger one is rejected with a hint
    registry.from_dict(with_(data, simulation__grid_step=float(h)))


def test_each_node_starts_its_bound_at_its_own_P_init():
    check = api.check(EXAMPLE, quick=True)
    series = check.tables["series"]
    t0 = series[series["t"] == 0.0].set_index("node")
    assert t0.loc[2, "trP_bound"] == pytest.approx(4.5) and t0.loc[0, "trP_bound"] == pytest.approx(3.0)
    assert t0["trP_exact"].tolist() == pytest.approx([3.0] * 3)      # the errors start from x(0) − m0 at every node
    assert hypotheses(check)["initial"]["holds"] is True
    below = hypotheses(api.check(with_(sensors__2__P_init=[[1.0, 0.0], [0.0, 1.0]]), quick=True))["initial"]
    assert below["holds"] is False and below["value"] == pytest.approx(-1.0)


# -- the run, the design and the tables ----------------------------------------------------------------------

@pytest.fixture(scope="module")
def small_run(tmp_path_factory):
    """The example in quick mode with its outputs written, and its CPU time."""
    start = time.process_time()
    run = api.run(EXAMPLE, quick=True, seed=2)
    run.write(tmp_path_factory.mktemp("tanwani") / "damped3")
    return run, time.process_time() - start


def test_design_is_the_runs_design_and_hypotheses_are_decided_on_it(small_run):
    run, _ = small_run
    check = api.check(EXAMPLE, quick=True, seed=2)
    assert [(h["id"], h["holds"], h["value"]) for h in check.hypotheses] == \
        [(h["id"], h["holds"], h["value"]) for h in run.evaluation.hypotheses]
    assert all(h["holds"] is True for h in check.hypotheses)
    for name in check.tables:
        a, b = check.tables[name], run.tables[name]
        b = b.iloc[:len(a)] if name == "node_entries" else b          # the run adds the Monte Carlo entries
        assert a.equals(b.reset_index(drop=True)), name
    assert check.estimate["seconds"] > 0 and check.estimate["peak_memory_mib"] > cost.BASE_MIB


def _independent_steady_states(s, lam):
    """(9) and the exact mean covariance at steady state, from their definitions (not the estimators' generators)."""
    N, n = s.N, s.n
    I = np.eye(n * n)
    M9 = sla.block_diag(*[np.kron(np.eye(n), A) + np.kron(A, np.eye(n)) for A in s.Ai]) \
        - lam * s.alpha * np.kron(s.laplacian, I)
    P = -np.linalg.solve(M9, np.concatenate([G.ravel(order="F") for G in s.Gi]))
    P = np.array([P[i * n * n:(i + 1) * n * n].reshape(n, n, order="F") for i in range(N)])
    D = N * n
    Ab = sla.block_diag(*s.Ai)
    MS = np.kron(np.eye(D), Ab) + np.kron(Ab, np.eye(D))
    for i, j in s.clocks:
        E = np.zeros((N, N))
        E[i, i], E[i, j] = 1.0, -1.0
        if s.mode == "edge":
            E[j, j], E[j, i] = 1.0, -1.0
        Jz = np.kron(np.eye(N) - s.alpha * E, np.eye(n))
        MS += lam * (np.kron(Jz, Jz) - np.eye(D * D))
    S = -np.linalg.solve(MS, s.joint_noise[n:, n:].ravel(order="F")).reshape(D, D, order="F")
    return P, np.array([S[i * n:(i + 1) * n, i * n:(i + 1) * n] for i in range(N)])


def test_nodes_table_equals_the_independent_computations(small_run):
    run, _ = small_run
    r = run.results.scenarios["damped3"]
    s, sc = r.sys, r.scenario
    nodes = run.tables["nodes"].set_index("node")
    P, J = _independent_steady_states(s, sc.main_rate)
    Hs, Vs = np.vstack(s.H), sla.block_diag(*s.V)
    P_kb = sla.solve_continuous_are(s.A.T, Hs.T, s.B @ s.B.T, Vs)
    S = sla.solve_continuous_lyapunov(s.Abar, -s.Gbar)
    for i in range(s.N):
        row = nodes.loc[i]
        assert row["trP_bound_steady"] == pytest.approx(np.trace(P[i]), rel=1e-10)
        assert row["trP_exact_steady"] == pytest.approx(np.trace(J[i]), rel=1e-10)
        assert row["trP_kb_steady"] == pytest.approx(np.trace(P_kb), rel=1e-9)
        assert row["trS"] == pytest.approx(np.trace(S), rel=1e-10)
        assert row["gap_bound_exact_steady"] == pytest.approx(np.linalg.eigvalsh(P[i] - J[i])[0], abs=1e-10)
        assert row["ratio_steady"] == pytest.approx(np.trace(J[i]) / np.trace(P_kb), rel=1e-9)
        # the Monte Carlo columns are the stage's moments, and they agree with the exact final covariance
        e = r.grid_moments(sc.main_rate).mean[-1, i]
        assert row["trP_mc_final"] == np.trace(e)
        assert abs(row["trP_mc_final"] - row["trP_exact_final"]) < 5 * row["trP_mc_final_se"]
    entries = run.tables["node_entries"]
    exact = entries[(entries["quantity"] == "exact_steady") & (entries["node"] == 1)].sort_values(["row", "col"])
    np.testing.assert_allclose(exact["value"].to_numpy(), J[1].ravel(), rtol=1e-10)


def test_cells_and_series_are_what_the_claims_use(small_run):
    run, _ = small_run
    r = run.results.scenarios["damped3"]
    cells = run.tables["cells"]
    np.testing.assert_array_equal(cells["bound"].to_numpy(), r.bounds["cell_bound"].ravel())
    np.testing.assert_array_equal(cells["P_second"].to_numpy(), r.bounds["cell_P_second"].ravel())
    np.testing.assert_array_equal(cells["mc_P_mean"].to_numpy(), (r.event["qP1"] / int(r.event["n"])).ravel())
    series = run.tables["series"]
    np.testing.assert_array_equal(series["trP_bound"].to_numpy(), np.trace(r.bound(r.scenario.main_rate), axis1=2,
                                                                            axis2=3).ravel())
    steady = run.tables["steady_states"]
    assert (steady["gap_bound_exact"] >= 0).all() and (steady["gap_exact_kb"] >= 0).all()


def test_metrics_are_tidy(small_run):
    run, _ = small_run
    m = run.tables["metrics"]
    net = network_metrics(m)
    for k in ("mse_final_mean", "mse_final_max", "bound_final_mean", "mse_time_avg", "kb_trP", "crit_bound"):
        assert k in net and np.isfinite(net[k]), k
    per_node = m[m["metric"] == "mse_final"]
    assert sorted(per_node["node"].tolist()) == [0, 1, 2] and (per_node["rate"] == 3.0).all()


# -- cost, streaming, refusal ---------------------------------------------------------------------------------

def test_monte_carlo_is_identical_whatever_the_memory_budget():
    sc = registry.from_dict(with_(simulation__horizon=1.0)).scenario
    for stage in (lambda b: monte_carlo.simulate_gridded_rate(sc, 4, 2500, 3.0, 60, budget_bytes=b),
                  lambda b: monte_carlo.simulate_event_rate(sc, 4, 2100, budget_bytes=b),
                  lambda b: monte_carlo.simulate_frozen(sc, 4, 2100, budget_bytes=b)):
        one, all_ = stage(1.0), stage(2.0**30)            # one unit of 1,000 trials at a time, or all together
        assert one.keys() == all_.keys()
        for k in one:
            np.testing.assert_array_equal(one[k], all_[k], err_msg=k)


def test_unstreamable_paths_beyond_the_budget_are_refused_before_running():
    data = with_(graph={"kind": "complete", "n": 8}, sensors=[EXAMPLE["sensors"][0]] * 8, communication__rates=[1e4],
                 communication__alpha=0.1, simulation__horizon=1000.0, simulation__output_step=0.5,
                 simulation__grid_step=None)
    repro = registry.from_dict(data)
    start = time.process_time()
    with pytest.raises(ScenarioError) as err:
        api.execute(repro, RunOptions(quick=True, max_memory_mib=4000))      # the driver refuses before computing
    assert err.value.field == "communication.rates" and "MiB" in err.value.reason
    assert time.process_time() - start < 5


LONG = """
import re, sys, tempfile, tomllib
from dse import registry
from dse.contract.options import RunOptions
from dse.contract.context import StageContext
from dse.engine.cache import StageCache
from dse.families.tanwani import claims, design, monte_carlo  # noqa: F401  (the libraries a run loads, before the baseline)

def hwm():
    return int(re.search(r"VmHWM:\\s*(\\d+)", open("/proc/self/status").read()).group(1)) / 1024

data = tomllib.loads(open(sys.argv[1]).read())
data["simulation"].update(horizon=200.0, output_step=0.1, grid_step=0.1, quick_trials=2000, quick_event_trials=50)
data["communication"]["rates"] = [1.0]
repro = registry.from_dict(data)
print("BASE", hwm())
with tempfile.TemporaryDirectory() as tmp:
    res = repro.compute(RunOptions(quick=True, max_memory_mib=float(sys.argv[2])), StageContext(StageCache(tmp))).results
mom = res.scenarios["damped3"].grid_moments(1.0)
print("T", mom.mean.shape[0])
print("K", mom.count)
print("PEAK", hwm())
"""


def test_long_horizon_runs_in_bounded_memory():
    """200 s on 2,001 output times with 2,000 gridded trials (and 50 event-driven paths of about 2,800 rings
    and output times each): every gridded trajectory kept would take 2,000 × 2,001 × 8 values (256 MB), the
    event-driven ones 50 × 2,001 × 32 more; the run streams (moments per output time only) and stays within a
    500 MiB budget, less than 100 MiB above what the libraries take."""
    proc = subprocess.run([sys.executable, "-c", LONG, str(FAMILY_DIR / "example.toml"), "500"], cwd=ROOT,
                          capture_output=True, text=True, timeout=600,
                          env={"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin", "DSE_PROGRESS": "0",
                               "OPENBLAS_NUM_THREADS": "1"})
    assert proc.returncode == 0, proc.stderr[-2000:]
    out = {k: float(v) for k, v in (line.split() for line in proc.stdout.splitlines())}
    assert (out["T"], out["K"]) == (2001, 2000)
    assert out["PEAK"] < 500 and out["PEAK"] - out["BASE"] < 100, out


# -- stage keys follow the code the stages run ------------------------------------------------------------------

def test_a_stage_key_changes_with_the_code_it_imports_and_only_with_it(tmp_path, monkeypatch):
    """The gridded stage imports the simulator, which imports the exact flows (`linear_flows`): a faked edit of
    that module changes the stage's key; an edit of the figures (which no stage imports) does not. No stage
    imports a claims module."""
    sc = registry.from_dict(EXAMPLE).scenario
    st = monte_carlo.simulate_gridded_rate
    for stage in (st, monte_carlo.simulate_event_rate, design.scenario_design):
        assert not [m for m in code_closure(stage.module) if m.rpartition(".")[2].startswith(("claims", "hypotheses"))]
    key = lambda: st.params(st.bound((sc, 0, 1000, 3.0), {}))                  # noqa: E731
    before, real = key(), stage_mod.module_file
    assert before["code"] == code_hash("dse.families.tanwani.monte_carlo")
    for target, changes in (("dse.estimators.linear_flows", True), ("dse.families.tanwani.figures", False)):
        edited = tmp_path / f"{target}.py"
        edited.write_bytes(real(target).read_bytes() + b"\n# an edit\n")
        monkeypatch.setattr(stage_mod, "module_file", lambda name, t=target, e=edited: e if name == t else real(name))
        code_hash.cache_clear()
        try:
            assert (key() != before) is changes, target
        finally:
            monkeypatch.setattr(stage_mod, "module_file", real)
            code_hash.cache_clear()


def test_listing_the_papers_claims_parses_no_scenario_file(monkeypatch):
    """`dse list` reads the paper's claims and hypotheses from its declared scenario ids, without the files."""
    from dse.families.tanwani import family

    monkeypatch.setattr(family, "load_scenario", lambda name: pytest.fail(f"{name}.toml was parsed"))
    run = registry.paper("tanwani")
    assert len(run.claims()) == 133 and len(run.hypotheses()) == 45
    assert run.claims()[-4].id == "tanwani.errata.inverse_transform"


def test_claims_on_oracles_computed_in_the_stage_or_by_themselves_agree(small_run):
    """python-control's care/lqe/lyap and the Radau integration are computed in the references stage; a claim
    without them (the oracle raised there) calls the same function: both give the same verdict, to the bit."""
    from dse.families.tanwani import claims_references, claims_theorem, references

    run, _ = small_run
    r = next(iter(run.results.scenarios.values()))
    assert all(k in r.bounds for k in references.KB_ORACLES + references.LYAPUNOV_ORACLES)
    stripped = dataclasses.replace(r, bounds={k: v for k, v in r.bounds.items() if not k.startswith("oracle_")})
    for check in (claims_references.check_kb_reference, claims_theorem.check_lyapunov):
        assert check(stripped) == check(r), check.__name__
