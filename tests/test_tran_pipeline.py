"""The coestimation family in the pipeline: declared keys, the design stage and `dse check`, the
tables against independent computations, the new scenario fields (initial estimates, Q_i of (10)),
the cost estimate, and streaming (identical whatever the memory budget; bounded memory over a long
horizon; refusal of what cannot be streamed)."""
from __future__ import annotations

import copy
import re
import subprocess
import sys
import time
import tomllib
from pathlib import Path

import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.linalg import solve_continuous_are, solve_continuous_lyapunov

import dse.estimators.input_state_coestimation as ce
from dse import registry as reproductions
from dse import api
from dse.contract.cost import refuse_if_too_large
from dse.contract.options import RunOptions
from dse.contract.context import StageContext
from dse.engine.cache import MemoryCache
from dse.errors import ScenarioError
from dse.families.tran import claims as tran_claims
from dse.families.tran import cost, design, hypotheses, law, runs
from dse.families.tran.runs import mc_moments
from dse.families.tran.scenario import CoestimationFile as SCENARIO_MODEL
from dse.scenario.declare import reference_rows

ROOT = Path(__file__).resolve().parents[1]
PAPER = ROOT / "dse" / "families" / "tran" / "paper.toml"

SMALL = {
    "family": "coestimation", "name": "small",
    "process": {"A": [[0.0, 1.0], [-2.0, -1.5]], "B": [[0.0], [2.0]], "x0": [1.0, -0.5]},
    "input": {"offset": [0.5], "amplitude": [[1.0]], "frequency": [[0.8]], "phase": [[0.0]]},
    "graph": {"kind": "ring", "n": 4},
    "nodes": {"positions": [[0, 0], [1, 0], [2, 0], [3, 0]], "type": ["pos", "vel", "pos", "vel"],
              "xhat0": [[0.3, -0.2], [0.0, 0.1], [-0.4, 0.0], [0.2, 0.2]], "what0": [[0.25]]},
    "node_type": {
        "pos": {"C": [[1.0, 0.0]], "L": [[4.0], [2.0]], "J": [[3.0]], "K": [[2.0]], "sigma": 0.2, "eps": 1e-4,
                "comparison_sigma": 2.0, "Q": [[2.0, 0.3, 0.0], [0.3, 1.0, 0.0], [0.0, 0.0, 0.5]]},
        "vel": {"C": [[0.0, 1.0]], "L": [[0.5], [3.0]], "J": [[2.0]], "K": [[2.0]], "sigma": 0.2, "eps": 1e-4,
                "comparison_sigma": 2.0},
    },
    "coupling": {"alpha": 5.0, "P": "lyapunov"},
    "roles": {"mode": "fixed", "active": [1, 1, 0, 1]},
    "simulation": {"t_end": 3.0, "step": 0.01, "tail_start": 1.0},
    "stochastic": {"trials": 30, "quick_trials": 30, "runs": 2, "quick_t_end": 2.0},
}


def with_(data, **changes):
    out = copy.deepcopy(data)
    for path, value in changes.items():
        node = out
        *head, last = path.split("__")
        for k in head:
            node = node[k]
        node[last] = value
    return out


# -- declared keys ---------------------------------------------------------------------------------------

def test_every_key_is_declared_with_a_meaning():
    rows = [(path, r) for path, table, _ in reference_rows(SCENARIO_MODEL) for r in table]
    assert len(rows) > 50
    paths = {f"{path}.{r['key']}" for path, r in rows}
    assert {"node_type.<name>.Q", "nodes.xhat0", "nodes.what0", "simulation.record_dt"} <= paths
    for path, r in rows:
        assert r["meaning"].strip(), f"{path}.{r['key']} has no meaning"
    from dse.scenario.declare import key

    with pytest.raises(ValueError, match="meaning"):
        key(1, doc="")


def test_the_paper_file_comments_every_key():
    for line in PAPER.read_text().splitlines():
        if re.match(r"^\s*[A-Za-z_][\w.]*\s*=", line):
            assert "#" in line, f"paper.toml: no comment on {line.strip()!r}"
    data = tomllib.loads(PAPER.read_text())
    sc = reproductions.from_dict(data).scenario
    assert sc.simulation.record_dt == 0.01 and sc.reference.dt == 0.01 and sc.stochastic.step == sc.simulation.step


@pytest.mark.parametrize("change, field, words", [
    ({"graph": {"kind": "line", "n": 1}}, "graph.n", "must be >= 2"),
    ({"graph": {"kind": "edges", "n": 4, "edges": [[0, 1], [1, 1]]}}, "graph.edges[1]", "self-loop"),
    ({"graph": {"kind": "edges", "n": 4, "edges": [[0, 1], [1, 0]]}}, "graph.edges[1]", "repeats"),
    ({"graph": {"kind": "ring", "n": 41}}, "graph.n", "at most 40"),
    ({"name": "a\u202eb"}, "name", "must match"),
    ({"node_type__pos__name": "pos\u202eition"}, "node_type.pos.name", "control or format"),
    ({"nodes__xhat0": [[0.0, 0.0], [1.0, 1.0]]}, "nodes.xhat0", "1 row (every node) or one row per node"),
    ({"nodes__what0": [[0.0, 1.0]]}, "nodes.what0", "shape"),
    ({"node_type__pos__Q": [[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, 1.0]]}, "node_type.pos.Q", "positive definite"),
    ({"node_type__pos__Q": [[1.0, 0.2, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]}, "node_type.pos.Q", "symmetric"),
    ({"node_type__pos__Qx": [[1.0]]}, "node_type.pos.Qx", "unknown key"),
    ({"roles": {"mode": "fixed", "radius": 1.0}}, "roles.radius", "only with mode"),
    ({"roles": {"mode": "proximity", "radius": 1.0}}, "roles.beta", "missing"),
    ({"simulation": {"t_end": 2e4}}, "simulation.t_end", "<= 10000"),
    ({"simulation": {"step": 1e-6}}, "simulation.step", ">= 1e-05"),
    ({"simulation": {"t_end": 3.0, "step": 0.01, "record_dt": 0.015}}, "simulation.record_dt", "multiple"),
    ({"stochastic": {"trials": 200_000}}, "stochastic.trials", "<= 100000"),
    ({"stochastic": {"runs": 20, "trials": 10}}, "stochastic.trials", ">= runs"),
])
def test_invalid_input_names_its_field(change, field, words):
    with pytest.raises(ScenarioError) as err:
        reproductions.from_dict(with_(SMALL, **change))
    assert err.value.field == field and words in err.value.reason, str(err.value)


def test_disconnected_graph_is_accepted_and_reported():
    data = with_(SMALL, graph={"kind": "edges", "n": 4, "edges": [[0, 1], [2, 3]]})
    repro = reproductions.from_dict(data)
    check = api.check(repro, quick=True)
    hyp = {h["id"]: h for h in check.hypotheses}
    assert hyp["small.hyp.graph_connected"]["holds"] is False and hyp["small.hyp.graph_undirected"]["holds"] is True


# -- the run, the design and the tables ------------------------------------------------------------------

@pytest.fixture(scope="module")
def small_run(tmp_path_factory):
    """The run and its CPU time with its outputs written (tables, figures, recording, report)."""
    start = time.process_time()
    run = api.run(SMALL, quick=True, seed=2)
    run.write(tmp_path_factory.mktemp("tran") / "small")
    return run, time.process_time() - start


def test_design_is_the_runs_design_and_hypotheses_are_decided_on_it(small_run):
    run, _ = small_run
    repro = run.reproduction
    d = repro.design(RunOptions(quick=True, seed=2), StageContext(MemoryCache()))
    same = run.computed.design
    for part in ("arrays", "law"):
        a, b = getattr(d, part), getattr(same, part)
        assert a.keys() == b.keys()
        for k in a:
            np.testing.assert_array_equal(a[k], b[k], err_msg=k)
    check = api.check(SMALL, quick=True, seed=2)
    by_id = {h["id"]: h for h in run.evaluation.hypotheses}
    for h in check.hypotheses:
        if h["id"] == hypotheses.H_INTEG.replace("tran.", "small.", 1):   # decided by the run only (its deterministic runs)
            assert h["holds"] is None and by_id[h["id"]]["holds"] is True
        else:
            assert h == by_id[h["id"]], h["id"]
    for name in check.tables:
        assert check.tables[name].equals(run.tables[name]), name
    assert {"node_types", "node_design", "bounds", "matrices", "spectra", "s_cells", "role_sweep", "noise"} <= set(check.tables)
    bad = [(c["id"], c["verdict"]) for c in run.evaluation.claims if c["verdict"] in ("fail", "error")]
    assert not bad


def test_lyapunov_P_uses_the_scenarios_Q(small_run):
    run, _ = small_run
    sc, d = run.results.scenario, run.results.design
    for i in range(sc.N):
        ty = sc.types[sc.type_of[i]]
        Ab = ce.error_matrix(sc.A, sc.B, ty.C, ty.L, ty.J, ty.sigma, ty.K, sc.roles.active[i])
        P = d.P[i]
        np.testing.assert_allclose(Ab.T @ P + P @ Ab + ty.Q, 0.0, atol=1e-12 * np.abs(P).max() * np.abs(Ab).max())
    assert d["fixed_Qi_min"][0] == pytest.approx(np.linalg.eigvalsh(sc.types[0].Q)[0], rel=1e-9)
    q = run.tables["matrices"]
    got = q[(q["matrix"] == "Q_lyapunov") & (q["index"] == 0)]["value"].to_numpy().reshape(3, 3)
    np.testing.assert_array_equal(got, sc.types[0].Q)


def test_initial_estimates_start_every_run(small_run):
    run, _ = small_run
    sc = run.results.scenario
    e0 = np.concatenate([np.array(SMALL["nodes"]["xhat0"]), np.full((4, 1), 0.25)], axis=1)
    for name in ("coest", "fixed", "comparison"):
        np.testing.assert_array_equal(run.results.runs[name]["e"][0], e0)
    est = run.tables["estimates"]
    first = est[(est["run"] == "stochastic_0") & (est["t"] == 0.0)].sort_values(["node", "component"])
    np.testing.assert_array_equal(first["value"].to_numpy().reshape(sc.N, sc.q), e0)
    mats = run.tables["matrices"]
    np.testing.assert_array_equal(mats[mats["matrix"] == "initial_estimates"]["value"].to_numpy().reshape(sc.N, sc.q), e0)


def _stacked_G(sc, law) -> np.ndarray:
    q = sc.q
    G = np.zeros((sc.N * q, 1 + sc.N))
    G[:, 0] = np.tile(np.r_[law["v"], np.zeros(sc.p)], sc.N)
    for i in range(sc.N):
        ty = sc.types[sc.type_of[i]]
        G[i * q:(i + 1) * q, 1 + i] = sc.fixed_roles.active[i] * np.r_[-ty.L @ law["h"][i], ty.J @ law["h"][i]]
    return G


def test_nodes_table_equals_the_independent_computations(small_run):
    """Σ∞ from scipy's Lyapunov solver, Σ(T) by integrating the Lyapunov ODE, the Kalman-Bucy reference from
    scipy's CARE and its Riccati ODE, the exact mean from the noise-free run, and the Monte Carlo moments from
    a direct simulation of the same trials."""
    run, _ = small_run
    res, nodes = run.results, run.tables["nodes"].sort_values("node")
    sc, d, law = res.scenario, res.design, res.design.law
    n, q, T = sc.n, sc.q, float(law["t_sde"])
    G = [sc.per_node(k) for k in ("C", "L", "J", "K", "sigma")]
    S = ce.stacked_error_matrix(sc.A, sc.B, *G[:3], G[3], G[4], d.P, sc.lap, sc.coupling.alpha,
                                np.asarray(sc.fixed_roles.active))
    GG = _stacked_G(sc, law) @ _stacked_G(sc, law).T
    steady = solve_continuous_lyapunov(S, -GG)
    D = len(S)
    ode = solve_ivp(lambda t, y: (S @ y.reshape(D, D) + y.reshape(D, D) @ S.T + GG).ravel(), (0, T), np.zeros(D * D),
                    rtol=1e-10, atol=1e-13)
    final = ode.y[:, -1].reshape(D, D)
    blk = lambda M, i: M[i * q:(i + 1) * q, i * q:(i + 1) * q]  # noqa: E731
    np.testing.assert_allclose(nodes["cov_steady_trace"], [np.trace(blk(steady, i)) for i in range(sc.N)], rtol=1e-9)
    np.testing.assert_allclose(nodes["cov_final_trace"], [np.trace(blk(final, i)) for i in range(sc.N)], rtol=1e-7)
    m = ce.errors_from_estimates(res.runs["fixed"]["x"], res.runs["fixed"]["w"], res.runs["fixed"]["e"], n)
    k_T = int(round(T / sc.simulation.record_dt))
    np.testing.assert_allclose(nodes["second_moment_final_trace"],
                               [m[k_T, i] @ m[k_T, i] + np.trace(blk(final, i)) for i in range(sc.N)], rtol=1e-7)
    C = np.vstack([G[0][i] for i in range(sc.N) if sc.fixed_roles.active[i] > 0])
    R = np.zeros((len(C), len(C)))
    for j, i in enumerate([i for i in range(sc.N) if sc.fixed_roles.active[i] > 0]):
        R[j, j] = law["h"][i, 0] ** 2
    R += 1e-9 * np.abs(R).max() * np.eye(len(R))
    Q = np.outer(law["v"], law["v"])
    kb = solve_continuous_are(sc.A.T, C.T, Q, R)
    np.testing.assert_allclose(nodes["kb_steady_trace"], np.trace(kb), rtol=1e-6)
    ric = solve_ivp(lambda t, y: (lambda P: sc.A @ P + P @ sc.A.T + Q - P @ C.T @ np.linalg.solve(R, C @ P))(
        y.reshape(n, n)).ravel(), (0, T), np.zeros(n * n), method="Radau", rtol=1e-10, atol=1e-14)
    np.testing.assert_allclose(nodes["kb_final_trace"], np.trace(ric.y[:, -1].reshape(n, n)), rtol=1e-5)
    gap = [np.linalg.eigvalsh(blk(steady, i)[:n, :n] - kb)[0] for i in range(sc.N)]
    np.testing.assert_allclose(nodes["loewner_gap_steady"], gap, rtol=1e-6, atol=1e-12)
    # Monte Carlo: the same trials simulated in one piece, their errors at T kept whole
    direct = _direct_final_errors(res, k_T)
    np.testing.assert_allclose(nodes["mc_second_moment_final"], (direct ** 2).sum(-1).mean(0), rtol=1e-11)
    np.testing.assert_allclose(nodes["mc_second_moment_final_se"], (direct ** 2).sum(-1).std(0, ddof=1) / np.sqrt(len(direct)),
                               rtol=1e-9)
    cov = [np.cov(direct[:, i].T) for i in range(sc.N)]
    np.testing.assert_allclose(nodes["mc_cov_final_trace"], [np.trace(c) for c in cov], rtol=1e-10)


def _direct_final_errors(res, k_T: int) -> np.ndarray:
    """z(T) of every trial of the fixed-role Monte Carlo, simulated again in one batch with the same streams."""
    import dse.estimators.observer_network_simulation as sim
    from dse.simulate.seeding import block_seeds, stream_seed
    from dse.simulate.units import UnitStreams

    sc, d = res.scenario, res.design
    trials = int(res.runs["sde_fixed"]["trials"])
    h, dt = sc.stochastic.step, sc.simulation.record_dt
    seq = stream_seed(res.seed, "tran", "sde", ("fixed", h))
    streams = UnitStreams(block_seeds(seq, 1), [trials])
    net = design.coestimation(sc, d.P)
    tr = sim.simulate(net, runs.role_law(sc, True), design.input_signal(sc), sc.process.x0, sc.e0, t_end=k_T * dt,
                      h=h, record_every=int(round(dt / h)), n_trials=trials, noise=d.noise, rng=streams, keep=trials)
    return ce.errors_from_estimates(tr.x[:, -1], tr.w[-1], tr.e[:, -1], sc.n)


def test_series_and_bounds_are_what_the_claims_use(small_run):
    run, _ = small_run
    res, t = run.results, run.tables
    b = t["bounds"].set_index(["quantity", "variant"])["value"]
    for k in ("wbar", "lamP_min", "lamP_max"):
        assert b[(k, "")] == float(res.design[k])
    assert b[("bound18", "fixed")] == float(res.design["fixed_bound18"])
    c = law.mean_square_constants(res.design, fixed=False)
    assert b[("kappa", "roles")] == c["kappa"] and b[("eta", "roles")] == c["eta"]
    mc = t["mc_series"]
    roles = mc[mc["run"] == "sde_roles"].sort_values("t")
    mean, sd, R = mc_moments(res.runs["sde_roles"], "V")
    np.testing.assert_array_equal(roles["V_mean"], mean)
    np.testing.assert_array_equal(roles["V_sd"], sd)
    fixed = mc[mc["run"] == "sde_fixed"].sort_values("t")
    np.testing.assert_array_equal(fixed["exact_EV"], res.runs["exact_fixed"]["EV"])
    err = t["errors"]
    net = err[(err["run"] == "coest") & err["node"].isna()].sort_values("t")
    z = res.errors("coest")
    np.testing.assert_allclose(net["V"], tran_claims.lyapunov_values(res, z), rtol=1e-13)
    S = t["matrices"]
    for name, g in (("S_all_passive", 0.0), ("S_all_active", 1.0)):
        got = S[S["matrix"] == name]["value"].to_numpy().reshape(res.scenario.N * res.scenario.q, -1)
        np.testing.assert_array_equal(got, design.stacked_S(res.scenario, res.P, np.full(res.scenario.N, g)))
    cells = t["law_cells"]
    assert len(cells) and np.all(cells["trials"] == R)


def test_metrics_are_tidy(small_run):
    run, _ = small_run
    from dse.sweeps.run import network_metrics

    m = run.tables["metrics"]
    assert str(m["node"].dtype) == "Int64"
    net = network_metrics(m)
    for k in ("bound18_single", "coest_err_final_max", "fixed_err_tail_rms", "mc_EV_final", "lmi_margin_min"):
        assert k in net, k
    per_node = m[m["metric"] == "coest_err_final"]
    assert sorted(per_node["node"].tolist()) == [0, 1, 2, 3]


# -- cost, streaming, refusal -----------------------------------------------------------------------------

def test_monte_carlo_is_identical_whatever_the_memory_budget():
    repro = reproductions.from_dict(with_(SMALL, stochastic={"trials": 2500, "runs": 2}))
    sc = repro.scenario
    d = repro.design(RunOptions(quick=True, seed=4), StageContext(MemoryCache()))
    probes = {int(k): u for k, u in zip(d.law["probe_index"], d.law["probe_dirs"])}
    kw = dict(fixed=True, trials=2500, seed=4, t_end=0.5, keep=3, h=sc.stochastic.step, probes=probes)
    tiny = runs.run_stochastic(sc, d.P, d.noise, budget_bytes=1.0, **kw)          # one unit of 1,000 trials at a time
    large = runs.run_stochastic(sc, d.P, d.noise, budget_bytes=2.0**30, **kw)     # all three units together
    assert tiny.keys() == large.keys() and int(tiny["trials"]) == 2500
    for k in tiny:
        np.testing.assert_array_equal(tiny[k], large[k], err_msg=k)


def test_unstreamable_samples_beyond_the_budget_are_refused_before_running():
    data = with_(SMALL, simulation={"t_end": 1e4, "step": 1e-3, "record_dt": 1e-3})
    repro = reproductions.from_dict(data)
    start = time.process_time()
    with pytest.raises(ScenarioError) as err:     # the driver refuses it before computing (dse.api.execute)
        opts = RunOptions(quick=True, max_memory_mib=2000)
        refuse_if_too_large(repro.cost(opts), opts)
    assert err.value.field == "simulation.record_dt" and "MiB" in err.value.reason
    assert time.process_time() - start < 5


def test_the_issue_horizon_is_estimated_in_days_and_checked_quickly(capsys):
    """The paper's file with t_end = 1e4 and step = 1e-5 (10⁹ steps): valid, recorded samples thinned to
    10,001, estimated in days, and `dse check` answers without simulating."""
    data = tomllib.loads(PAPER.read_text())
    data["simulation"].update(t_end=1e4, step=1e-5)
    repro = reproductions.from_dict(data)
    assert repro.scenario.simulation.record_dt == 1.0 and repro.scenario.reference.dt == 1.0
    start = time.process_time()
    check = api.check(repro, quick=True, workers=1)     # the API's default is now the command line's 2 workers
    assert time.process_time() - start < 10
    assert check.estimate["seconds"] > 86400 and check.estimate["peak_memory_mib"] < 4000
    assert "days" in check.estimate["detail"]
    cost.announce(repro.scenario, repro.cost(RunOptions(quick=True)))      # what `dse run` prints before it starts
    assert "days" in capsys.readouterr().err


def _peak_of(args, cwd) -> tuple[int, str, float]:
    """Exit code, output and peak resident memory (MiB) of `dse ARGS` in a fresh process. The peak is the
    process's own high-water mark (VmHWM): getrusage's ru_maxrss also carries the high-water mark of the
    process that forked it across exec on Linux, i.e. of this test process."""
    code = ("import re, sys; from dse.cli import main; rc = main(sys.argv[1:]); "
            "print('PEAK', re.search(r'VmHWM:\\s*(\\d+)', open('/proc/self/status').read()).group(1)); sys.exit(rc)")
    proc = subprocess.run([sys.executable, "-c", code, *args], cwd=cwd, capture_output=True, text=True, timeout=600,
                          env={"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin", "DSE_PROGRESS": "0",
                               "OPENBLAS_NUM_THREADS": "1", "MPLBACKEND": "Agg"})
    peak = next((int(line.split()[1]) for line in proc.stdout.splitlines() if line.startswith("PEAK")), 0)
    return proc.returncode, proc.stderr + proc.stdout, peak / 1024


LONG = """family = "coestimation"
name = "long"
[process]
A = [[0.0, 1.0], [-2.0, -1.5]]
B = [[0.0], [2.0]]
x0 = [1.0, -0.5]
[input]
offset = [0.5]
amplitude = [[1.0]]
frequency = [[0.8]]
phase = [[0.0]]
[graph]
kind = "line"
n = 2
[nodes]
type = ["pos", "vel"]
positions = [[0.0, 0.0], [1.0, 0.0]]
[node_type.pos]
C = [[1.0, 0.0]]
L = [[4.0], [2.0]]
J = [[3.0]]
K = [[2.0]]
sigma = 0.2
eps = 1e-4
[node_type.vel]
C = [[0.0, 1.0]]
L = [[0.5], [3.0]]
J = [[2.0]]
K = [[2.0]]
sigma = 0.2
eps = 1e-4
[coupling]
alpha = 5.0
P = "lmi"
[roles]
mode = "fixed"
active = [1.0, 0.0]
[simulation]
t_end = 100.0
step = 0.02
tail_start = 25.0
[stochastic]
trials = 400
quick_trials = 400
runs = 2
step = 0.04
quick_t_end = 100.0
"""


def test_long_horizon_runs_in_bounded_memory(tmp_path):
    """5,000 steps of the deterministic runs (10,000 at h/2) and 400 trials over 2,500 stochastic steps (5,000 at
    h/2): the recorded samples are thinned to the default 2,501 (every 0.04 s: the multiple of both steps above
    t_end/10,000) and the Monte Carlo keeps moments only; the run stays within a 600 MiB budget (libraries
    included) and its tables hold what the claims used."""
    (tmp_path / "long.toml").write_text(LONG)
    rc, out, peak = _peak_of(["run", "long.toml", "--quick", "--workers", "1", "--max-memory", "600M", "--out", "out"],
                             tmp_path)
    assert rc == 0, out
    assert peak < 600, f"peak {peak:.0f} MiB"
    import pandas as pd

    mc = pd.read_parquet(tmp_path / "out" / "run" / "long" / "tables" / "mc_series.parquet")
    assert mc["t"].max() == 100.0 and mc[mc["run"] == "sde_roles"]["t"].nunique() == 2501
    assert (mc["trials"] == 400).all()


def test_a_nearly_singular_sensor_noise_leaves_the_kalman_bucy_reference_out_instead_of_hanging():
    """Generated scenario 14 (found by the calibration benchmark): R = blockdiag(h_i h_iᵀ) + 1e-9 jitter is so
    close to singular that scipy cannot reorder the CARE's Hamiltonian pencil, and the Hamiltonian flow would
    need ~1e9 sub-steps. The run finishes; the reference is NaN in the nodes table; nothing is an error."""
    data = reproductions.family("coestimation").generate(14, None)
    run = api.run(data, quick=True, seed=14)
    assert run.counts["error"] == 0 and run.counts["fail"] == 0
    nodes = run.tables["nodes"]
    assert nodes["kb_steady_trace"].isna().all()


def test_input_suprema_are_written_to_round_off_and_the_bounds_use_their_certified_upper_ends(small_run):
    """SMALL's input is w = 0.5 + sin(0.8 t): sup|w| = 1.5 and sup|ẇ| = 0.8 exactly. The table's value is the
    supremum to round-off (it used to be the certified upper end, ≈1e-8 above); `upper` is that certified end and
    w̄ is built from it."""
    run, _ = small_run
    b = run.tables["bounds"].set_index(["quantity", "variant"])
    eps = np.finfo(float).eps
    for q, exact in (("w_sup", 1.5), ("wdot_sup", 0.8)):
        row = b.loc[(q, "")]
        assert abs(row["value"] - exact) <= 4 * eps * exact, (q, row["value"] - exact)
        assert row["lower"] <= row["value"] <= row["upper"] and exact <= row["upper"] <= exact * (1 + 1e-7)
    assert b.loc[("wbar", ""), "value"] == max(b.loc[("w_sup", ""), "upper"], b.loc[("wdot_sup", ""), "upper"])
