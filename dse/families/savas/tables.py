"""The tables of a noisy-consensus-filter run: every number a claim, a figure or a recording uses.

Design tables (also printed by `dse check`): the consensus matrix and its spectrum, the
references (centralized and single-sensor Kalman filters), the optimal gains, the σ_c thresholds
of Fig. 1, the cells with their exact steady-state, evaluation-step and final-step traces, and
the steady-state covariance matrices. Run tables add the Monte Carlo: per agent (`nodes`), per
recorded step (`trace_series`, `node_series`), the sample trials (`sample_paths`,
`consensus_rounds`) and the summary `metrics` of sweeps. A cell is identified by the columns
(alg, m, sigma_c, n_steps): n_steps is the horizon, the scenario's own or the long run of
Theorem 1(i).
"""
from __future__ import annotations

from typing import Any

import numpy as np
import pandas as pd

from dse.outputs.tables import TableSpec, spec

from .cells import LARGE_M, Cell
from .design import Design
from .results import Results

CELL_COLUMNS = [
    ("alg", "", "filter: carli (two-stage filter (7)+(9)) or reinjection (the paper's filter (11)-(13))"),
    ("m", "1", "consensus rounds between two measurements"),
    ("sigma_c", "state", "standard deviation of the communication noise per round"),
    ("n_steps", "1", "horizon of the cell (the scenario's n_steps, or the long run of Theorem 1(i))"),
]
SC = ("scenario", "", "scenario name")

CONSENSUS_MATRIX = spec("consensus_matrix", "entry of Q", [SC, ("row", "1", "agent i (row)"),
                        ("col", "1", "agent j (column)"), ("value", "1", "q_ij, the weight agent i gives agent j")])
SPECTRUM = spec("spectrum", "eigenvalue of Q (ascending real part)", [
    SC, ("index", "1", "position in ascending order of the real part"), ("real", "1", "real part"),
    ("imag", "1", "imaginary part (0 for a symmetric Q)"), ("modulus", "1", "|λ|")])
REFERENCES = spec("references", "reference quantity of the scenario", [
    SC, ("quantity", "", "name"), ("value", "as defined", "value"), ("definition", "", "what it is")])
GAINS = spec("gains", "(objective, σ_c, m) cell of the optimal-gain tables (Fig. 2)", [
    SC, ("objective", "", "corrected: (16) with the exponent 2m (the exact steady-state trace); printed: (16) as "
         "printed; carli: the steady-state trace J_C of Carli's filter (ζ = 1)"),
    ("sigma_c", "state", "communication noise"), ("m", "1", "consensus rounds (0..rounds_max, and 50..200 for the "
                                                           "corrected objective)"),
    ("ell", "1", "optimal gain ℓ*"), ("zeta", "1", "optimal weight ζ* (1 at m = 0 and for carli)"),
    ("J", "state²", "the objective at the optimum"),
    ("dJ_dell", "state²", "∂J/∂ℓ at the optimum (central difference)"),
    ("dJ_dzeta", "state²", "∂J/∂ζ at the optimum (central difference; 0 where ζ is not free)"),
    ("d2J_dell2", "state²", "∂²J/∂ℓ² at the optimum"), ("d2J_dzeta2", "state²", "∂²J/∂ζ² at the optimum"),
    ("kkt_residual", "state²", "largest component of the projected gradient (0 at a KKT point)"),
    ("kkt_scaled", "1", "the projected gradient in units of what a minimum located from values of J resolves "
                        "(savas.tuning.kkt compares it with 10√(eps/(1−(1−ℓ)²)))"),
    ("grid_min", "state²", "smallest J on the search grid")])
THRESHOLDS = spec("carli_thresholds", "step m → m' between consecutive rounds of the scenario (Fig. 1)", [
    SC, ("m_from", "1", "m"), ("m_to", "1", "m'"),
    ("sigma_c_threshold", "state", "σ_c above which tr P(k_eval|k_eval−1) of Carli's filter is larger at m' than at m "
                                   "(0: at every σ_c; inf: never)"),
    ("noise_coef_from", "1", "b_m: tr P(k_eval|k_eval−1) = a_m + b_m σ_c²"), ("noise_coef_to", "1", "b_m'"),
    ("noise_free_from", "state²", "a_m, the trace without communication noise"), ("noise_free_to", "state²", "a_m'")])
CELLS = spec("cells", "Monte Carlo cell (filter, m, σ_c, horizon)", [
    SC, *CELL_COLUMNS, ("ell", "1", "gain ℓ of the cell"), ("zeta", "1", "weight ζ of (13) (1 for carli)"),
    ("trP_steady", "state²", "tr P∞, the exact steady state (Theorem 1(i); Lyapunov or modal solution)"),
    ("trP_eval", "state²", "exact tr P(k_eval|k_eval−1) of (22), the figures' metric"),
    ("trP_final", "state²", "exact tr P(K−1|K−2) at the cell's last step"),
    ("kf_trP_steady", "state²", "N P_c⁻: N times the centralized Kalman filter's steady prior variance"),
    ("kf_trP_eval", "state²", "N P_KF(k_eval|k_eval−1)"), ("kf_trP_final", "state²", "N P_KF(K−1|K−2)"),
    ("ratio_steady", "1", "tr P∞ / (N P_c⁻)"),
    ("loewner_gap_steady", "state²", "smallest eigenvalue of P∞ − P_c⁻ 11ᵀ (>= 0: no direction of the agents' errors "
                                     "beats the centralized filter)")])
STEADY = spec("steady_covariance", "entry of a cell's steady-state covariance P∞ (scenarios of at most 50 agents)", [
    SC, *CELL_COLUMNS, ("row", "1", "agent i"), ("col", "1", "agent j"), ("value", "state²", "[P∞]_ij")])
NODES = spec("nodes", "cell and agent", [
    SC, *CELL_COLUMNS, ("node", "1", "agent i"), ("ell", "1", "gain ℓ"), ("zeta", "1", "weight ζ"),
    ("P_steady", "state²", "[P∞]_ii, exact steady-state error variance"),
    ("P_final_exact", "state²", "[P(K−1|K−2)]_ii of (22) at the last step"),
    ("P_final_mc", "state²", "Monte Carlo variance (ddof = 1) of x̃_i(K−1|K−2)"),
    ("P_final_mc_se", "state²", "its standard error √((m4 − m2²)/R)"),
    ("P_eval_exact", "state²", "[P(k_eval|k_eval−1)]_ii"), ("P_eval_mc", "state²", "Monte Carlo variance at k_eval"),
    ("P_eval_mc_se", "state²", "its standard error"),
    ("kf_steady", "state²", "P_c⁻, the centralized Kalman filter's steady prior variance"),
    ("kf_final", "state²", "P_KF(K−1|K−2)"),
    ("ratio_steady", "1", "[P∞]_ii / P_c⁻"), ("gap_steady", "state²", "[P∞]_ii − P_c⁻ (>= 0)")])
TRACE_SERIES = spec("trace_series", "cell and recorded step k", [
    SC, *CELL_COLUMNS, ("k", "1", "step"), ("trP_exact", "state²", "tr P(k|k−1) of (22)"),
    ("trP_mc", "state²", "Monte Carlo Σ_i var x̃_i(k|k−1) (ddof = 1), the paper's metric"),
    ("trP_mc_se", "state²", "its standard error (from the trials' Σ_i x̃_i²)"),
    ("kf_trP", "state²", "N P_KF(k|k−1), the centralized Kalman filter (a lower bound)")])
NODE_SERIES = spec("node_series", "cell, recorded step k and agent", [
    SC, *CELL_COLUMNS, ("k", "1", "step"), ("node", "1", "agent i"),
    ("P_exact", "state²", "[P(k|k−1)]_ii of (22)"), ("var_mc", "state²", "Monte Carlo variance (ddof = 1)"),
    ("var_mc_se", "state²", "its standard error"), ("mean_mc", "state", "Monte Carlo mean of x̃_i(k|k−1) (exactly 0 "
                                                                       "in law)"),
    ("mean_mc_se", "state", "its standard error"),
    ("Pfilt_exact", "state²", "[P(k|k)]_ii = (1−ℓ)²[P(k|k−1)]_ii + ℓ²r (18)"),
    ("var_filt_mc", "state²", "Monte Carlo variance of x̃_i(k|k)"), ("var_filt_mc_se", "state²", "its standard error")])
SAMPLE_PATHS = spec("sample_paths", "cell, sample trial, step k (the first sample_steps) and agent", [
    SC, *CELL_COLUMNS, ("trial", "1", "sample trial"), ("k", "1", "step"), ("node", "1", "agent i"),
    ("x", "state", "true state x(k) (shared by the cells of one m)"), ("y", "state", "measurement y_i(k)"),
    ("xhat_pred", "state", "x̂_i(k|k−1)"), ("xhat_filt", "state", "x̂_i(k|k)"), ("w", "state", "process noise w(k)")])
CONSENSUS_ROUNDS = spec("consensus_rounds", "cell, sample trial 0, step k, round h and agent", [
    SC, *CELL_COLUMNS, ("k", "1", "step"), ("round", "1", "h = 0..m (h = 0: x̂_i(k|k))"), ("node", "1", "agent i"),
    ("z", "state", "consensus iterate z_i(k + h/m | k)"),
    ("u", "1", "standard normal communication draw u_i(k + h/m) (unscaled; empty at h = 0)")])
METRICS = spec("metrics", "metric, cell and agent (empty node: the whole network)", [
    SC, ("metric", "", "name: <filter>_trP_exact / _trP_mc / _trP_mc_se (the trace at k_eval), _trP_exact_per_agent "
                        "(divided by N), _trP_steady; <filter>_P_exact / _P_mc / _P_mc_se / _P_steady per agent; "
                        "kf_trP, kf_trP_per_agent, kf_trP_steady (centralized Kalman filter)"),
    ("node", "1", "agent, empty for the network"),
    ("alg", "", "filter (carli, reinjection, or centralized)"), ("m", "1", "rounds (empty for the centralized filter)"),
    ("sigma_c", "state", "communication noise (empty for the centralized filter)"),
    ("value", "as the metric", "value")])


def _cell_keys(name: str, cells: list[Cell], rows) -> dict[str, np.ndarray]:
    """The cell columns (scenario, alg, m, sigma_c, n_steps) of `rows` rows per cell (a count, or one per cell)."""
    rows = np.broadcast_to(np.asarray(rows, dtype=np.int64), (len(cells),))

    def column(values, dtype):
        return np.repeat(np.array(values, dtype=dtype), rows)

    return {"scenario": column([name] * len(cells), object), "alg": column([c.alg for c in cells], object),
            "m": column([c.m for c in cells], np.int64), "sigma_c": column([c.sigma_c for c in cells], np.float64),
            "n_steps": column([c.n_steps for c in cells], np.int64)}


def _matrix_columns(a: np.ndarray) -> dict[str, np.ndarray]:
    """row, col and value of every entry of a matrix (row-major)."""
    row, col = np.indices(np.shape(a)).reshape(2, -1).astype(np.int64)
    return {"row": row, "col": col, "value": np.asarray(a, float).ravel()}


def _frame(table: TableSpec, columns: dict[str, Any]) -> pd.DataFrame:
    return pd.DataFrame(columns, columns=table.column_names)


def _index(steps: np.ndarray, k: int) -> int:
    return int(np.searchsorted(steps, k))


def _per_cell(table: TableSpec, name: str, parts: list[tuple[Cell, dict[str, Any]]]) -> pd.DataFrame:
    """A block of rows per cell: the cell's columns, then its own (arrays of one length per cell)."""
    rows = [np.size(next(iter(cols.values()))) for _, cols in parts]
    columns = {k: np.concatenate([np.ravel(cols[k]) for _, cols in parts]) for k in parts[0][1]}
    return _frame(table, {**_cell_keys(name, [c for c, _ in parts], rows), **columns})


def design_tables(d: Design) -> list[tuple[TableSpec, pd.DataFrame]]:
    sc, a = d.scenario, d.arrays
    name = sc.name
    out = [(CONSENSUS_MATRIX, _frame(CONSENSUS_MATRIX, {"scenario": np.full(sc.Q.size, name, object),
                                                        **_matrix_columns(sc.Q)}))]
    lam = a["eig_real"] + 1j * a["eig_imag"]
    out.append((SPECTRUM, pd.DataFrame({"scenario": name, "index": np.arange(lam.size), "real": a["eig_real"],
                                        "imag": a["eig_imag"], "modulus": np.abs(lam)})))
    Kc, Pc, K1, P1 = a["centralized"]
    second = float(np.sort(np.abs(lam))[-2])
    refs = [("N", sc.n, "number of agents"), ("K_c", Kc, "centralized Kalman gain (steady state)"),
            ("P_c", Pc, "centralized steady prior variance P_c⁻ (a lower bound of every agent's variance)"),
            ("N_P_c", sc.n * Pc, "N P_c⁻, the lower bound of every trace and the limit of J*(m) as m → ∞"),
            ("K_1", K1, "single-sensor steady Kalman gain: the optimal ℓ without communication (m = 0)"),
            ("P_1", P1, "single-sensor steady prior variance P_1⁻"),
            ("N_P_1", sc.n * P1, "N P_1⁻ = J*(0), the cost without communication"),
            ("second_modulus", second, "second largest |λ(Q)|: < 1 iff the unit eigenvalue is the only one on the unit "
                                       "circle"),
            ("spectral_gap", 1.0 - second, "1 − second largest |λ(Q)|"),
            ("eval_step", sc.sweep.eval_step, "k of the figures' metric tr P(k|k−1)"),
            ("recorded_steps", len(d.steps), "steps with per-step statistics")]
    out.append((REFERENCES, pd.DataFrame([{"scenario": name, "quantity": q, "value": float(v), "definition": t}
                                          for q, v, t in refs], columns=REFERENCES.column_names)))
    gains: dict[str, list] = {c: [] for c in GAINS.column_names[1:]}
    for objective, prefix, ms in (("corrected", "corrected", range(sc.rounds_max + 1)),
                                  ("printed", "printed", range(sc.rounds_max + 1)),
                                  ("carli", "carli_opt", range(sc.rounds_max + 1)),
                                  ("corrected", "large_m", LARGE_M)):
        if f"{prefix}_ell" not in a:
            continue
        # the large-m rows at m <= rounds_max repeat the optimisation of the m = 0..rounds_max table's row
        keep = np.array([prefix != "large_m" or m > sc.rounds_max for m in ms], bool)
        S, M = len(sc.sweep.sigma_c), int(keep.sum())
        gains["objective"].append(np.full(S * M, objective, object))
        gains["sigma_c"].append(np.repeat(np.array(sc.sweep.sigma_c, np.float64), M))
        gains["m"].append(np.tile(np.array(list(ms), np.int64)[keep], S))
        for c in GAINS.column_names[4:]:
            gains[c].append(np.asarray(a[f"{prefix}_{c}"], np.float64)[:, keep].ravel())
    if gains["m"]:
        gains = {c: np.concatenate(v) for c, v in gains.items()}
        out.append((GAINS, _frame(GAINS, {"scenario": np.full(len(gains["m"]), name, object), **gains})))
    else:   # no gain tables (Q not symmetric)
        out.append((GAINS, pd.DataFrame([], columns=GAINS.column_names)))
    if "carli_thresholds" in a:
        out.append((THRESHOLDS, pd.DataFrame({
            "scenario": name, "m_from": sc.sweep.rounds[:-1], "m_to": sc.sweep.rounds[1:], "sigma_c_threshold": a["carli_thresholds"],
            "noise_coef_from": a["carli_noise_coef"][:-1], "noise_coef_to": a["carli_noise_coef"][1:],
            "noise_free_from": a["carli_noise_free"][:-1], "noise_free_to": a["carli_noise_free"][1:]})))
    cells, n = [], sc.n
    for c in d.all_cells():
        ex, st, steps = d.exact(c), d.steady(c), d.steps_of(c)
        ie, kf = _index(steps, sc.sweep.eval_step), d.kf_prior(steps)
        cells.append((c, {"ell": [float(c.ell)], "zeta": [float(c.zeta)], "trP_steady": st["trace"],
                          "trP_eval": ex.trace[ie], "trP_final": ex.trace[-1], "kf_trP_steady": n * Pc,
                          "kf_trP_eval": n * kf[ie], "kf_trP_final": n * kf[-1], "ratio_steady": st["trace"] / (n * Pc),
                          "loewner_gap_steady": st["gap"]}))
    out.append((CELLS, _per_cell(CELLS, name, cells)))
    matrices = [(c, _matrix_columns(d.steady(c)["matrix"])) for c, _ in cells if "matrix" in d.steady(c)]
    if matrices:
        out.append((STEADY, _per_cell(STEADY, name, matrices)))
    return out


def run_tables(res: Results) -> list[tuple[TableSpec, pd.DataFrame]]:
    d, sc = res.design, res.scenario
    N, r = sc.n, sc.model.r
    Pc = d.arrays["centralized"][1]
    nodes, traces, series = [], [], []
    for c in d.all_cells():
        steps, ex, st = d.steps_of(c), d.exact(c), d.steady(c)
        mom, fmom = res.moments(c), res.moments(c, "filt")
        var, var_se = mom.variance, mom.variance_se
        ie = _index(steps, sc.sweep.eval_step)
        kf = d.kf_prior(steps)
        nodes.append((c, {"node": np.arange(N), "ell": np.full(N, c.ell, np.float64), "zeta": np.full(N, c.zeta, np.float64),
                          "P_steady": st["diag"], "P_final_exact": ex.diag[-1], "P_final_mc": var[-1],
                          "P_final_mc_se": var_se[-1], "P_eval_exact": ex.diag[ie], "P_eval_mc": var[ie],
                          "P_eval_mc_se": var_se[ie], "kf_steady": np.full(N, Pc), "kf_final": np.full(N, kf[-1]),
                          "ratio_steady": st["diag"] / Pc, "gap_steady": st["diag"] - Pc}))
        traces.append((c, {"k": steps, "trP_exact": ex.trace, "trP_mc": mom.trace, "trP_mc_se": mom.trace_se,
                           "kf_trP": N * kf}))
        series.append((c, {"k": np.repeat(steps, N), "node": np.tile(np.arange(N), len(steps)), "P_exact": ex.diag,
                           "var_mc": var, "var_mc_se": var_se, "mean_mc": mom.mean, "mean_mc_se": mom.mean_se,
                           "Pfilt_exact": (1 - c.ell) ** 2 * ex.diag + c.ell ** 2 * r, "var_filt_mc": fmom.variance,
                           "var_filt_mc_se": fmom.variance_se}))
    return [*design_tables(d), (NODES, _per_cell(NODES, sc.name, nodes)),
            (TRACE_SERIES, _per_cell(TRACE_SERIES, sc.name, traces)),
            (NODE_SERIES, _per_cell(NODE_SERIES, sc.name, series)), *_path_tables(res), (METRICS, metrics_frame(res))]


def _path_tables(res: Results) -> list[tuple[TableSpec, pd.DataFrame]]:
    paths, rounds = [], []
    for c in res.design.all_cells():
        p = res.paths(c)
        if "x" not in p or p["x"].size == 0:
            continue
        P, K, N = p["xhat_pred"].shape
        trial, k, node = (a.ravel() for a in np.meshgrid(np.arange(P), np.arange(K), np.arange(N), indexing="ij"))
        paths.append((c, {"trial": trial, "k": k, "node": node, "x": p["x"][trial, k], "y": p["y"],
                          "xhat_pred": p["xhat_pred"], "xhat_filt": p["xhat_filt"], "w": p["w"][trial, k]}))
        z = p["z_rounds"][0]                                    # (K, m+1, N), trial 0
        u = np.concatenate([np.full((K, 1, N), np.nan), p["u"][0]], axis=1)
        kk, hh, nn = (a.ravel() for a in np.meshgrid(np.arange(K), np.arange(z.shape[1]), np.arange(N), indexing="ij"))
        rounds.append((c, {"k": kk, "round": hh, "node": nn, "z": z, "u": u}))
    if not paths:
        return []
    name = res.scenario.name
    return [(SAMPLE_PATHS, _per_cell(SAMPLE_PATHS, name, paths)),
            (CONSENSUS_ROUNDS, _per_cell(CONSENSUS_ROUNDS, name, rounds))]


#: the metrics of a cell, in their order: network-wide, then per agent (one row each)
CELL_METRICS = ("trP_exact", "trP_exact_per_agent", "trP_mc", "trP_mc_se", "trP_steady")
AGENT_METRICS = ("P_exact", "P_mc", "P_mc_se", "P_steady")


def metrics_frame(res: Results) -> pd.DataFrame:
    """The summary of a run for sweeps: per cell of the scenario's grid (not the long run) the trace at
    k_eval (exact, Monte Carlo, its SE, per agent) and in the steady state, and per agent the same
    variances; the centralized filter's trace. One row each; the cell is in the columns."""
    d, sc = res.design, res.scenario
    _, Pc, _, _ = d.arrays["centralized"]
    N = sc.n
    ie = _index(d.steps, sc.sweep.eval_step)
    kf = float(d.kf_prior([sc.sweep.eval_step])[0])
    per_cell = len(CELL_METRICS) + len(AGENT_METRICS) * N
    metric = [np.array(["kf_trP", "kf_trP_per_agent", "kf_trP_steady"], object)]
    values = [np.array([sc.n * kf, kf, sc.n * Pc], np.float64)]
    for c in d.cells:
        ex, st = d.exact(c), d.steady(c)
        mom = res.moments(c)
        metric.append(np.array([f"{c.alg}_{m}" for m in CELL_METRICS] + [f"{c.alg}_{m}" for m in AGENT_METRICS] * N,
                               object))
        values.append(np.concatenate([
            np.array([ex.trace[ie], ex.trace[ie] / sc.n, mom.trace[ie], mom.trace_se[ie], st["trace"]], np.float64),
            np.stack([ex.diag[ie], mom.variance[ie], mom.variance_se[ie], st["diag"]], axis=1).ravel()]))
    C = len(d.cells)
    cell_node = np.concatenate([np.zeros(len(CELL_METRICS), np.int64), np.repeat(np.arange(N), len(AGENT_METRICS))])
    node = np.concatenate([np.zeros(3, np.int64), np.tile(cell_node, C)])
    node_missing = np.concatenate([np.ones(3, bool), np.tile(np.arange(per_cell) < len(CELL_METRICS), C)])
    m = np.concatenate([np.zeros(3, np.int64), np.repeat(np.array([c.m for c in d.cells], np.int64), per_cell)])
    m_missing = np.concatenate([np.ones(3, bool), np.zeros(C * per_cell, bool)])
    frame = _frame(METRICS, {
        "scenario": np.full(3 + C * per_cell, sc.name, object), "metric": np.concatenate(metric),
        "node": pd.arrays.IntegerArray(node, node_missing),
        "alg": np.concatenate([np.full(3, "centralized", object), np.repeat(np.array([c.alg for c in d.cells], object),
                                                                             per_cell)]),
        "m": pd.arrays.IntegerArray(m, m_missing),
        "sigma_c": np.concatenate([np.full(3, np.nan), np.repeat(np.array([c.sigma_c for c in d.cells], np.float64),
                                                                 per_cell)]),
        "value": np.concatenate(values)})
    return frame.astype({"node": "Int64", "m": "Int64", "sigma_c": "float64"})
