"""The tables of a random-comm-filter run: every number a claim, a figure or a recording uses.

Design tables (also printed by `dse check`): the scalar design quantities (`design`: sizes, α,
σ₂(𝓛), the abscissa of Ā, the critical rates of (9) and of the exact covariance, traces of S,
S_true and P_KB, the explicit constants of (12) in both variants, the gridded step and how it
was chosen, the `numerics` check, ...), the spectra (Ā, every A_i, A, the Laplacian), the design
matrices (A, B, P0, m0, Ā, Ḡ, R, S, S_true, P_KB, K_KB, Π, and per node H_i, V_i, L_i, A_i, G_i,
P_i(0) and the first-order coefficient C_i), per simulated λ the abscissae of both generators and
B_12(λ) (`rates`), the per-node steady states (`steady_states`), the λ sweep (`sweep`,
`sweep_nodes`), the transients on the output grid (`series`), the graph (`graph_nodes`,
`graph_edges`) and every exact node covariance entry (`node_entries`).

Run tables: per node the exact steady-state and final-time covariances with the Monte Carlo
estimates, the Kalman–Bucy reference, ratios and Loewner gaps (`nodes`; entries in
`node_entries`), the Monte Carlo series (`mc_series`), the sample trials (`sample_paths`), the
stored clock paths (`path_series`, `path_events`), the test cells of the statistical claims
(`cells`), the frozen clock path (`frozen`), the node event counts (`poisson`), filterpy's sampled
filter and the gridded scheme's bias (`references`, `scheme_bias`), the paper's topology sweep
(`topology`, `topology_rates`, `topology_graphs`) and the summary `metrics` of sweeps.
"""
from __future__ import annotations

import json

import numpy as np
import pandas as pd

import dse.estimators.gossip_covariance as gc
from dse.outputs.tables import TableSpec, spec

from .design import EXPLICIT_FIELDS, Design, ScenarioDesign
from .references import directions
from .results import Results, ScenarioResults
from .topology import TOPOLOGIES

SC = ("scenario", "", "scenario name")
RATE = ("rate", "1/s", "Poisson rate λ of every clock")
NODE = ("node", "1", "sensor node i = 0..N−1")
T = ("t", "s", "time")
V2 = "state²"
Frame = list[tuple[TableSpec, pd.DataFrame]]

DESIGN = spec("design", "scenario and scalar design quantity", [
    SC, ("quantity", "", "name (see definition)"),
    ("value", "as stated", "the value (booleans as 1/0; NaN: not computed, e.g. Ā not Hurwitz)"),
    ("unit", "", "unit of the value"), ("definition", "", "what it is (for grid_step: how it was chosen)")])
SPECTRA = spec("spectra", "eigenvalue of a design matrix", [
    SC, ("matrix", "", "Abar (Ā = (1/N)Σ_i A_i), A_i (node i's error dynamics A − L_iH_i), A (the plant), laplacian "
                       "(𝓛, ascending)"),
    ("node", "1", "node of A_i (empty otherwise)"), ("index", "1", "position"), ("real", "1/s", "real part"),
    ("imag", "1/s", "imaginary part")])
MATRICES = spec("matrices", "entry of a design matrix", [
    SC, ("matrix", "", "A, B, P0, m0 (a column), Abar (Ā), Gbar (Ḡ = BBᵀ + (1/N)Σ L_iV_iL_iᵀ), R ((10) as the equality "
                       "RĀ + ĀᵀR = −I), S ((11)), S_true (the large-rate limit of E[e_ie_iᵀ]), P_kb (Kalman–Bucy "
                       "steady covariance), K_kb (its gain), Pi (Π = I − α𝓛), laplacian; per node: H, V, L, A_i "
                       "(A − L_iH_i), G_i (BBᵀ + L_iV_iL_iᵀ), P_init (P_i(0)), first_order (C_i: 𝒫_i^∞(λ) = S + C_i/λ "
                       "+ O(λ⁻²))"),
    ("node", "1", "node of a per-node matrix (empty otherwise)"), ("row", "1", "row"), ("col", "1", "column"),
    ("value", "as the matrix", "entry")])
RATES = spec("rates", "scenario and simulated rate λ", [
    SC, RATE, ("main", "", "true for the main rate (the event-driven simulator and the statistical claims)"),
    ("abscissa_bound", "1/s", "spectral abscissa of the generator M_9(λ) of (9)"),
    ("abscissa_bound_tol", "1/s", "its round-off level"),
    ("abscissa_exact", "1/s", "spectral abscissa of the generator of the exact mean joint covariance (NaN: N·n > 40)"),
    ("abscissa_exact_tol", "1/s", "its round-off level"),
    ("above_critical", "", "λ > λ_crit of (9): 𝒫_i(t) has a finite limit"),
    ("grid_regime", "1", "h·(max‖A_i‖₂ + λ d_max) of the gridded simulator at this λ (hypothesis grid_asymptotic: "
                         "≤ 1)"),
    ("B12_faithful", V2, "explicit bound (12) on limsup ‖𝒫_i − S‖_F, paper-faithful constants (inf below λ_thr)"),
    ("B12_tight", V2, "the same with the tight constants")])
STEADY = spec("steady_states", "scenario, simulated rate λ and node", [
    SC, RATE, NODE, ("trP_bound", V2, "tr 𝒫_i^∞(λ), steady state of (9) (NaN: diverges)"),
    ("trP_exact", V2, "tr E[e_ie_iᵀ]^∞(λ), steady state of the exact mean joint covariance (NaN: diverges or not "
                      "formed)"),
    ("trP_kb", V2, "tr P_KB, the centralized Kalman–Bucy steady covariance (a lower bound)"),
    ("dev_bound_S", V2, "‖𝒫_i^∞(λ) − S‖_F (item 2 of Theorem III.1)"),
    ("dev_exact_S_true", V2, "‖E[e_ie_iᵀ]^∞(λ) − S_true‖_F"),
    ("gap_bound_exact", V2, "smallest eigenvalue of 𝒫_i^∞ − E[e_ie_iᵀ]^∞ (≥ 0: (8) at steady state)"),
    ("gap_exact_kb", V2, "smallest eigenvalue of E[e_ie_iᵀ]^∞ − P_KB (≥ 0: the centralized filter is a lower bound)"),
    ("ratio_exact_kb", "1", "tr E[e_ie_iᵀ]^∞ / tr P_KB")])
SWEEP = spec("sweep", "scenario and rate λ of the steady-state sweep", [
    SC, RATE, ("abscissa_bound", "1/s", "spectral abscissa of M_9(λ)"), ("abscissa_bound_tol", "1/s", "its round-off "
                                                                                                     "level"),
    ("abscissa_exact", "1/s", "spectral abscissa of the exact mean covariance generator"),
    ("dev_bound", V2, "d(λ) = max_i ‖𝒫_i^∞(λ) − S‖_F, solved for directly"),
    ("dev_bound_err", V2, "round-off bound of d(λ)"),
    ("dev_exact", V2, "max_i ‖E[e_ie_iᵀ]^∞(λ) − S_true‖_F, solved for directly (edge clocks)"),
    ("dev_exact_err", V2, "its round-off bound"),
    ("cond_exact", "1", "1-norm condition number of the exact steady-state solve"),
    ("B12_faithful", V2, "explicit (12), paper-faithful constants"), ("B12_tight", V2, "explicit (12), tight constants")])
SWEEP_NODES = spec("sweep_nodes", "scenario, sweep rate λ and node", [
    SC, RATE, NODE, ("trP_bound", V2, "tr 𝒫_i^∞(λ) (NaN: diverges)"), ("trP_exact", V2, "tr E[e_ie_iᵀ]^∞(λ)"),
    ("dev_bound", V2, "‖𝒫_i^∞(λ) − S‖_F"), ("dev_exact", V2, "‖E[e_ie_iᵀ]^∞(λ) − S_true‖_F"),
    ("gap_bound_exact", V2, "smallest eigenvalue of 𝒫_i^∞ − E[e_ie_iᵀ]^∞")])
SERIES = spec("series", "scenario, simulated rate λ, output time t and node", [
    SC, RATE, T, NODE, ("trP_bound", V2, "tr 𝒫_i(t), the bound (9) from P_i(0)"),
    ("trP_exact", V2, "tr E[e_ie_iᵀ](t), the exact mean joint covariance ODE (NaN: N·n > 40)"),
    ("gap_bound_exact", V2, "smallest eigenvalue of 𝒫_i(t) − E[e_ie_iᵀ](t)"),
    ("trP_kb", V2, "tr P_KB(t), the Kalman–Bucy Riccati ODE from P0 (the same for every node and rate)")])
GRAPH_NODES = spec("graph_nodes", "scenario and node", [
    SC, NODE, ("x", "1", "drawing position"), ("y", "1", "drawing position"), ("degree", "1", "number of neighbours")])
GRAPH_EDGES = spec("graph_edges", "scenario and clock", [
    SC, ("clock", "1", "clock index (one per undirected edge, or per ordered pair with mode = ordered)"),
    ("i", "1", "node that updates at its rings (receiver)"), ("j", "1", "the other node (both update with mode = "
                                                                       "edge)")])
NODE_ENTRIES = spec("node_entries", "scenario, rate, node, quantity and matrix entry", [
    SC, RATE, NODE, ("quantity", "", "bound_steady (𝒫_i^∞), exact_steady (E[e_ie_iᵀ]^∞), bound_final (𝒫_i(T)), "
                                     "exact_final (E[e_ie_iᵀ](T)), mc_final / mc_final_se (gridded Monte Carlo at T and "
                                     "its standard error), event_final / event_final_se (event-driven Monte Carlo, main "
                                     "rate)"),
    ("row", "1", "row"), ("col", "1", "column"), ("value", V2, "entry")])

NODES = spec("nodes", "scenario, simulated rate λ and node", [
    SC, RATE, NODE,
    ("trP_bound_steady", V2, "tr 𝒫_i^∞(λ) (NaN: the bound diverges)"),
    ("trP_exact_steady", V2, "tr E[e_ie_iᵀ]^∞(λ), exact"),
    ("trP_bound_final", V2, "tr 𝒫_i(T), the bound (9) at the horizon"),
    ("trP_exact_final", V2, "tr E[e_ie_iᵀ](T), exact"),
    ("trP_mc_final", V2, "tr Ê[e_ie_iᵀ](T), gridded Monte Carlo (second moment about zero)"),
    ("trP_mc_final_se", V2, "its standard error"),
    ("trP_event_final", V2, "the same from the exact event-driven simulator (main rate; NaN otherwise)"),
    ("trP_event_final_se", V2, "its standard error"),
    ("trP_kb_steady", V2, "tr P_KB, centralized Kalman–Bucy steady state"),
    ("trP_kb_final", V2, "tr P_KB(T)"),
    ("ratio_steady", "1", "tr E[e_ie_iᵀ]^∞ / tr P_KB"),
    ("ratio_final_mc", "1", "tr Ê[e_ie_iᵀ](T) / tr P_KB(T)"),
    ("gap_bound_exact_steady", V2, "smallest eigenvalue of 𝒫_i^∞ − E[e_ie_iᵀ]^∞ (Loewner gap of (8))"),
    ("gap_exact_kb_steady", V2, "smallest eigenvalue of E[e_ie_iᵀ]^∞ − P_KB"),
    ("gap_bound_exact_final", V2, "smallest eigenvalue of 𝒫_i(T) − E[e_ie_iᵀ](T)"),
    ("gap_exact_kb_final", V2, "smallest eigenvalue of E[e_ie_iᵀ](T) − P_KB(T)"),
    ("trS", V2, "tr S of (11) (NaN: Ā not Hurwitz)"), ("trS_true", V2, "tr S_true")])
MC_SERIES = spec("mc_series", "scenario, simulator, rate, output time t and node", [
    SC, ("simulator", "", "gridded (every rate), event (exact event-driven, main rate) or frozen (one clock path, main "
                          "rate)"),
    RATE, T, NODE, ("trP_mc", V2, "tr Ê[e_ie_iᵀ](t), Monte Carlo second moment"),
    ("trP_mc_se", V2, "its standard error"), ("trials", "1", "Monte Carlo trials")])
SAMPLE_PATHS = spec("sample_paths", "scenario, simulator, sample trial, output time, node and state component", [
    SC, ("simulator", "", "gridded (first rate) or event (main rate)"), ("trial", "1", "sample trial"), T, NODE,
    ("component", "1", "state component a"), ("x", "state", "true state x_a(t)"),
    ("xhat", "state", "node i's estimate x̂_i,a(t)"), ("error", "state", "e_i,a(t) = x_a − x̂_i,a")])
PATH_SERIES = spec("path_series", "scenario, stored clock path, output time and node", [
    SC, ("path", "1", "sample path of the event-driven simulator (main rate)"), T, NODE,
    ("trP_path", V2, "tr P_i(t; τ), the per-path bound (14)"),
    ("trSigma_path", V2, "tr E[e_ie_iᵀ | τ](t), the exact per-path covariance"),
    ("gap_path", V2, "smallest eigenvalue of P_i(t; τ) − E[e_ie_iᵀ | τ](t) (≥ 0: Prop. III.2)")])
PATH_EVENTS = spec("path_events", "scenario, clock path and ring", [
    SC, ("path", "1", "sample path of the event-driven simulator (−1: the frozen path)"),
    ("event", "1", "ring index in time order"), T, ("clock", "1", "clock that rang (see graph_edges)"),
    ("i", "1", "its receiving node"), ("j", "1", "the other node")])
CELLS = spec("cells", "scenario, test time, node and direction (the statistical claims' cells, main rate)", [
    SC, T, NODE, ("direction", "1", "index of the direction u (e_a, then (e_a + e_b)/√2 for a < b)"),
    ("u", "", "the direction as JSON"),
    ("bound", V2, "uᵀ𝒫_i(t)u, (9)"), ("exact", V2, "uᵀE[e_ie_iᵀ](t)u, exact (NaN: not formed)"),
    ("kb", V2, "uᵀP_KB(t)u"), ("P_mean", V2, "exact mean over clock paths of uᵀP_i(t; τ)u (NaN: not formed)"),
    ("P_second", "state⁴", "exact second moment over clock paths of uᵀP_i(t; τ)u"),
    ("paths", "1", "event-driven paths"), ("mc_P_mean", V2, "Monte Carlo mean of uᵀP_i(t; τ)u"),
    ("mc_P_second", "state⁴", "Monte Carlo mean of (uᵀP_i(t; τ)u)²"),
    ("mc_Sigma_mean", V2, "Monte Carlo mean of uᵀE[e_ie_iᵀ | τ](t)u"),
    ("mc_Sigma_second", "state⁴", "Monte Carlo mean of its square"),
    ("mc_e_mean", V2, "Monte Carlo mean of (uᵀe_i)²"), ("mc_e_second", "state⁴", "Monte Carlo mean of (uᵀe_i)⁴"),
    ("whitened_sum", "1", "Σ over paths of the whitened squared error of this cell (χ² with `whitened_terms` degrees "
                          "of freedom)"),
    ("whitened_terms", "1", "number of terms")])
FROZEN = spec("frozen", "scenario, output time and node (the frozen clock path, main rate)", [
    SC, T, NODE, ("trP_path", V2, "tr P_i(t; τ) on the frozen path"),
    ("trSigma_path", V2, "tr E[e_ie_iᵀ | τ](t), exact"), ("trP_mc", V2, "Monte Carlo tr Ê[e_ie_iᵀ](t) over (x0, ω, v)"),
    ("trP_mc_se", V2, "its standard error"), ("trials", "1", "trials")])
POISSON = spec("poisson", "scenario and node (event-driven simulator, main rate)", [
    SC, NODE, ("degree", "1", "d_i"), ("expected_events", "1", "d_iλT, the mean number of rings per path"),
    ("mean_events", "1", "Monte Carlo mean over the paths"),
    ("paths_without_event", "1", "paths on which the node never communicated"),
    ("expected_without_event", "1", "n·e^(−d_iλT)"), ("paths", "1", "paths")])
REFERENCES = spec("references", "scenario and sampling step h of filterpy's discrete filter", [
    SC, ("h", "s", "sampling step"), ("trP_prior", V2, "tr of filterpy's steady prior covariance"),
    ("trP_post", V2, "tr of its steady posterior covariance"), ("trP_dare", V2, "tr of scipy's DARE solution"),
    ("diff_dare", V2, "‖prior − DARE‖₂"), ("allow", V2, "what that difference may be (residuals and rounding)"),
    ("err_prior", V2, "‖P⁻(h) − P_KB‖_F (first order in h)"), ("err_post", V2, "‖P⁺(h) − P_KB‖_F"),
    ("steady", "", "the filter reached its steady state")])
SCHEME_BIAS = spec("scheme_bias", "scenario, output time and node (gridded scheme, main rate)", [
    SC, T, NODE, ("bias_h", V2, "max |entry| of the gridded scheme's exact mean covariance minus the model's, step h"),
    ("bias_h2", V2, "the same at h/2")])
TOPOLOGY = spec("topology", "graph of S4, rate λ and node (paper)", [
    ("graph", "", "path, ring, star or complete (4 nodes)"), RATE, NODE,
    ("dev_bound", V2, "‖𝒫_i^∞(λ) − S‖_F (NaN below λ_crit)"), ("trP_exact", V2, "tr E[e_ie_iᵀ]^∞(λ)")])
TOPOLOGY_RATES = spec("topology_rates", "graph of S4 and rate λ (paper)", [
    ("graph", "", "graph"), RATE, ("gap", V2, "smallest eigenvalue of 𝒫_i^∞ − E[e_ie_iᵀ]^∞ over the nodes")])
TOPOLOGY_GRAPHS = spec("topology_graphs", "graph of S4 (paper)", [
    ("graph", "", "graph"), ("alpha_fiedler", "1", "α σ₂(𝓛)"), ("crit_bound", "1/s", "λ_crit of (9)")])
METRICS = spec("metrics", "metric, node and rate (empty node: the whole network; empty rate: rate-free)", [
    SC, ("metric", "", "mse_final (tr Ê[e_ie_iᵀ](T), gridded; network: mse_final_mean, mse_final_max; mse_final_mean_se: "
                       "the node average of the nodes' standard errors, a bound of the standard error of "
                       "mse_final_mean), mse_time_avg "
                       "(over the output grid and nodes), bound_final (tr 𝒫_i(T); network: bound_final_mean), "
                       "exact_final, exact_steady, bound_steady (per node), kb_trP (tr P_KB), abar_abscissa, "
                       "crit_bound (λ_crit of (9); that of the exact covariance is in `design`)"),
    NODE, RATE, ("value", "as the metric", "value")])


def _tr(X) -> np.ndarray:
    return np.trace(X, axis1=-2, axis2=-1)


def _min_eig(X) -> np.ndarray:
    X = np.asarray(X, float)
    out = np.full(X.shape[:-2], np.nan)
    ok = np.all(np.isfinite(X), axis=(-2, -1))
    if ok.any():
        Y = X[ok]
        out[ok] = np.linalg.eigvalsh((Y + np.swapaxes(Y, -1, -2)) / 2)[..., 0]
    return out


def _frob(X) -> np.ndarray:
    return np.linalg.norm(X, axis=(-2, -1))


def _nodes(d: ScenarioDesign, key: str) -> np.ndarray:
    """A per-rate joint matrix (Nn, Nn) or series as per-node blocks; NaN when not formed."""
    s = d.sys
    if key not in d.bounds:
        return None
    return gc.diagonal_blocks(d.bounds[key], s.N, s.n)


def _nan_like(shape) -> np.ndarray:
    return np.full(shape, np.nan)


# -- design tables ---------------------------------------------------------------------------------------------

def _design_rows(d: ScenarioDesign) -> list[tuple]:
    sc, s, b = d.scenario, d.sys, d.bounds
    name = sc.name
    has = lambda k: k in b
    val = lambda k: float(b[k]) if has(k) else float("nan")
    E0 = gc.diagonal_blocks(s.joint_second_moment0()[s.n:, s.n:], s.N, s.n)
    num = np.concatenate([b["numerics_pbound"].ravel(), b["numerics_sigma"].ravel()])
    ref = np.concatenate([b["numerics_ref_pbound"].ravel(), b["numerics_ref_sigma"].ravel()])
    with np.errstate(invalid="ignore", over="ignore"):
        num_rel = float(np.abs(num - ref).max() / max(float(np.abs(ref).max()), 1e-300))
    rows = [
        ("N", s.N, "1", "number of nodes"), ("n", s.n, "1", "state dimension"),
        ("edges", len(s.edges), "1", "undirected edges"), ("clocks", len(s.clocks), "1", f"Poisson clocks (mode {s.mode})"),
        ("edge_mode", float(s.mode == "edge"), "1", "1: one clock per undirected edge, both ends update; 0: one per "
                                                    "ordered pair, only the receiver updates"),
        ("d_max", int(s.degrees.max()), "1", "largest node degree"),
        ("alpha", s.alpha, "1", "fusion weight α of (3), (6)"),
        ("fiedler", val("fiedler"), "1", "σ₂(𝓛), the algebraic connectivity (0: disconnected graph)"),
        ("alpha_fiedler", s.alpha * val("fiedler"), "1", "α σ₂(𝓛), the coupling strength per unit rate in (12)"),
        ("main_rate", sc.main_rate, "1/s", "the main rate λ (event-driven simulator, statistical claims)"),
        ("abar_abscissa", val("abar_abscissa"), "1/s", "spectral abscissa of Ā = (1/N)Σ(A − L_iH_i)"),
        ("abar_tolerance", val("abar_tolerance"), "1/s", "its round-off level"),
        ("abar_hurwitz", float(val("abar_abscissa") < -val("abar_tolerance")), "1", "Ā Hurwitz (item 2 of Thm III.1)"),
        ("crit_bound", val("crit_bound"), "1/s", "λ_crit of (9): inf{λ : M_9(λ) Hurwitz} (inf: never up to 1e9)"),
        ("crit_joint", val("crit_joint"), "1/s", "λ_crit of the exact mean covariance (NaN: N·n > 40)"),
        ("trS", float(np.trace(b["S"])) if has("S") else np.nan, V2, "tr S of (11)"),
        ("S_norm", float(np.linalg.norm(b["S"])) if has("S") else np.nan, V2, "‖S‖_F"),
        ("trS_true", float(np.trace(b["S_true"])) if has("S_true") else np.nan, V2, "tr S_true"),
        ("trR", float(np.trace(b["R"])) if has("R") else np.nan, "1", "tr R of (10)"),
        ("first_order_norm", float(_frob(b["first_order"]).max()) if has("first_order") else np.nan, V2,
         "max_i ‖C_i‖_F: λ‖𝒫_i^∞(λ) − S‖_F → it as λ → ∞"),
        ("trP_kb", float(np.trace(b["P_kb"])) if has("P_kb") else np.nan, V2, "tr P_KB, Kalman–Bucy steady state"),
        ("kb_condition", val("kb_condition"), "1", "relative condition number of the filter CARE (hypothesis "
                                                    "kalman_bucy: ≤ 1e8)"),
        ("initial_gap", float(_min_eig(np.asarray(s.P_init) - E0).min()), V2,
         "min over nodes of the smallest eigenvalue of P_i(0) − E[e_i(0)e_i(0)ᵀ] (hypothesis initial: ≥ 0)"),
        ("horizon", sc.horizon, "s", "horizon T"), ("output_step", sc.output_step, "s", "output grid spacing"),
        ("grid_step", sc.grid_step, "s", f"step h of the gridded simulator: {sc.grid_rule}"),
        ("grid_step_automatic", float(sc.grid_rule != "given"), "1", "1 when the step was chosen automatically"),
        ("grid_steps", sc.grid_steps, "1", "gridded steps over the horizon"),
        ("grid_regime", val("grid_regime_0"), "1", "h·(max‖A_i‖₂ + λ d_max) at the main rate (hypothesis "
                                                   "grid_asymptotic: ≤ 1)"),
        ("numerics_rel", num_rel, "1", "largest relative difference of the batched per-path covariances from a "
                                       "per-interval Van Loan computation on the design's clock paths (hypothesis "
                                       "numerics: ≤ 1e-6)"),
        ("numerics_t_end", float(b["numerics_times"][-1]), "s", "end of the design's clock paths"),
        ("numerics_condition", val("numerics_condition"), "1", "eigenvector condition number of the exact flows"),
        ("sweep_points", len(b["sweep"]), "1", "rates of the steady-state sweep"),
    ]
    for variant in ("faithful", "tight"):
        key = f"explicit_{variant}"
        vals = b[key] if has(key) else [np.nan] * len(EXPLICIT_FIELDS)
        for f, v in zip(EXPLICIT_FIELDS, vals):
            unit = "1/s" if f == "threshold" else ("1/s" if f in ("C1",) else "")
            rows.append((f"explicit_{variant}.{f}", float(v), unit or "1",
                         f"constant {f} of the explicit (12), {variant} variant" + (" (λ_thr: the explicit 'λ "
                                                                                    "sufficiently large')"
                                                                                    if f == "threshold" else "")))
    return [(name, q, float(v), u, dfn) for q, v, u, dfn in rows]


def _spectra_rows(d: ScenarioDesign) -> list[dict]:
    name, b, s = d.scenario.name, d.bounds, d.sys
    rows = [{"scenario": name, "matrix": "Abar", "node": None, "index": k, "real": z[0], "imag": z[1]}
            for k, z in enumerate(b["abar_eig"])]
    for i, eig in enumerate(b["ai_eig"]):
        rows += [{"scenario": name, "matrix": "A_i", "node": i, "index": k, "real": z[0], "imag": z[1]}
                 for k, z in enumerate(eig)]
    rows += [{"scenario": name, "matrix": "A", "node": None, "index": k, "real": z.real, "imag": z.imag}
             for k, z in enumerate(np.linalg.eigvals(s.A))]
    rows += [{"scenario": name, "matrix": "laplacian", "node": None, "index": k, "real": z, "imag": 0.0}
             for k, z in enumerate(b["laplacian_eig"])]
    return rows


def _matrix_rows(name: str, matrix: str, M, node=None) -> list[dict]:
    M = np.atleast_2d(np.asarray(M, float))
    r, c = np.indices(M.shape)
    return [{"scenario": name, "matrix": matrix, "node": node, "row": int(i), "col": int(j), "value": float(v)}
            for i, j, v in zip(r.ravel(), c.ravel(), M.ravel())]


def _matrices_rows(d: ScenarioDesign) -> list[dict]:
    name, b, s = d.scenario.name, d.bounds, d.sys
    rows = []
    for key, M in (("A", s.A), ("B", s.B), ("P0", s.P0), ("m0", s.m0[:, None]), ("Abar", s.Abar), ("Gbar", s.Gbar),
                   ("Pi", np.eye(s.N) - s.alpha * s.laplacian), ("laplacian", s.laplacian)):
        rows += _matrix_rows(name, key, M)
    for key in ("R", "S", "S_true", "P_kb", "K_kb"):
        if key in b:
            rows += _matrix_rows(name, key, b[key])
    for i in range(s.N):
        for key, M in (("H", s.H[i]), ("V", s.V[i]), ("L", s.L[i]), ("A_i", s.Ai[i]), ("G_i", s.Gi[i]),
                       ("P_init", s.P_init[i])):
            rows += _matrix_rows(name, key, M, i)
        if "first_order" in b:
            rows += _matrix_rows(name, "first_order", b["first_order"][i], i)
    return rows


def _rates_rows(d: ScenarioDesign) -> list[dict]:
    sc, b, s = d.scenario, d.bounds, d.sys
    rows = []
    for r, lam in enumerate(sc.rates):
        ab, abt = b[f"absc_bound_{r}"]
        aj, ajt = b.get(f"absc_joint_{r}", [np.nan, np.nan])
        rows.append({"scenario": sc.name, "rate": lam, "main": r == 0, "abscissa_bound": ab, "abscissa_bound_tol": abt,
                     "abscissa_exact": aj, "abscissa_exact_tol": ajt, "above_critical": bool(lam > float(b["crit_bound"])),
                     "grid_regime": float(b[f"grid_regime_{r}"]),
                     "B12_faithful": explicit_value(s, b, "faithful", lam), "B12_tight": explicit_value(s, b, "tight", lam)})
    return rows


def explicit_value(s, b, variant: str, lam: float) -> float:
    """B_12(λ) of the explicit (12) for one variant (NaN when Ā is not Hurwitz, inf below λ_thr)."""
    if f"explicit_{variant}" not in b:
        return float("nan")
    return gc.explicit_bound(s, variant).value(lam)


def _steady_rows(d: ScenarioDesign) -> list[dict]:
    sc, b, s = d.scenario, d.bounds, d.sys
    rows = []
    P_kb = b.get("P_kb")
    for r, lam in enumerate(sc.rates):
        P = b[f"bound_inf_{r}"]
        J = _nodes(d, f"joint_inf_{r}")
        J = J if J is not None else _nan_like(P.shape)
        for i in range(s.N):
            rows.append({"scenario": sc.name, "rate": lam, "node": i, "trP_bound": _tr(P[i]), "trP_exact": _tr(J[i]),
                         "trP_kb": _tr(P_kb) if P_kb is not None else np.nan,
                         "dev_bound_S": float(_frob(P[i] - b["S"])) if "S" in b else np.nan,
                         "dev_exact_S_true": float(_frob(J[i] - b["S_true"])) if "S_true" in b else np.nan,
                         "gap_bound_exact": float(_min_eig(P[i] - J[i])),
                         "gap_exact_kb": float(_min_eig(J[i] - P_kb)) if P_kb is not None else np.nan,
                         "ratio_exact_kb": _tr(J[i]) / _tr(P_kb) if P_kb is not None else np.nan})
    return rows


def _sweep_frames(d: ScenarioDesign) -> tuple[pd.DataFrame, pd.DataFrame]:
    sc, b, s = d.scenario, d.bounds, d.sys
    lams = b["sweep"]
    P, J = b["sweep_bound"], b["sweep_joint"]
    dP, dJ = b["sweep_dev_bound"], b["sweep_dev_joint"]
    nan = np.full(len(lams), np.nan)
    with np.errstate(invalid="ignore"):
        net = pd.DataFrame({"scenario": sc.name, "rate": lams, "abscissa_bound": b["sweep_absc_bound"],
                            "abscissa_bound_tol": b["sweep_absc_tol"], "abscissa_exact": b["sweep_absc_joint"],
                            "dev_bound": _frob(dP).max(axis=1), "dev_bound_err": b["sweep_dev_err"],
                            "dev_exact": _frob(dJ).max(axis=1), "dev_exact_err": b["sweep_dev_joint_err"],
                            "cond_exact": b["sweep_cond"], "B12_faithful": b.get("sweep_explicit_faithful", nan),
                            "B12_tight": b.get("sweep_explicit_tight", nan)})
    L, N = len(lams), s.N
    nodes = pd.DataFrame({"scenario": sc.name, "rate": np.repeat(lams, N), "node": np.tile(np.arange(N), L),
                          "trP_bound": _tr(P).ravel(), "trP_exact": _tr(J).ravel(), "dev_bound": _frob(dP).ravel(),
                          "dev_exact": _frob(dJ).ravel(), "gap_bound_exact": _min_eig(P - J).ravel()})
    return net, nodes


def _series_frame(d: ScenarioDesign) -> pd.DataFrame:
    sc, b, s = d.scenario, d.bounds, d.sys
    t = sc.output_times
    T, N = len(t), s.N
    parts = []
    for r, lam in enumerate(sc.rates):
        P = b[f"bound_t_{r}"]
        J = _nodes(d, f"joint_t_{r}")
        J = J if J is not None else _nan_like(P.shape)
        parts.append(pd.DataFrame({"scenario": sc.name, "rate": lam, "t": np.repeat(t, N), "node": np.tile(np.arange(N), T),
                                   "trP_bound": _tr(P).ravel(), "trP_exact": _tr(J).ravel(),
                                   "gap_bound_exact": _min_eig(P - J).ravel(),
                                   "trP_kb": np.repeat(_tr(b["P_kb_t"]), N)}))
    return pd.concat(parts, ignore_index=True)


def _entry_rows(name: str, lam: float, quantity: str, X: np.ndarray) -> pd.DataFrame:
    """X (N, n, n) → one row per node and entry."""
    N, n, _ = X.shape
    i, a, c = np.indices(X.shape)
    return pd.DataFrame({"scenario": name, "rate": lam, "node": i.ravel(), "quantity": quantity, "row": a.ravel(),
                         "col": c.ravel(), "value": X.ravel()})


def _design_entries(d: ScenarioDesign) -> pd.DataFrame:
    sc, b = d.scenario, d.bounds
    parts = []
    for r, lam in enumerate(sc.rates):
        P = b[f"bound_inf_{r}"]
        J = _nodes(d, f"joint_inf_{r}")
        Pt = b[f"bound_t_{r}"][-1]
        Jt = _nodes(d, f"joint_t_{r}")
        parts += [_entry_rows(sc.name, lam, "bound_steady", P), _entry_rows(sc.name, lam, "bound_final", Pt)]
        if J is not None:
            parts += [_entry_rows(sc.name, lam, "exact_steady", J), _entry_rows(sc.name, lam, "exact_final", Jt[-1])]
    return pd.concat(parts, ignore_index=True)


def _graph_frames(d: ScenarioDesign) -> tuple[pd.DataFrame, pd.DataFrame]:
    sc, s = d.scenario, d.sys
    pos = sc.network.positions()
    nodes = pd.DataFrame({"scenario": sc.name, "node": np.arange(s.N), "x": pos[:, 0], "y": pos[:, 1],
                          "degree": s.degrees})
    cl = np.array(s.clocks).reshape(-1, 2)
    edges = pd.DataFrame({"scenario": sc.name, "clock": np.arange(len(cl)), "i": cl[:, 0], "j": cl[:, 1]})
    return nodes, edges


def _frame(table: TableSpec, rows) -> pd.DataFrame:
    f = pd.DataFrame(rows, columns=table.column_names)
    if "node" in f.columns and table.name in ("spectra", "matrices", "metrics"):
        f["node"] = f["node"].astype("Int64")
    return f


def scenario_design_tables(d: ScenarioDesign) -> Frame:
    sweep, sweep_nodes = _sweep_frames(d)
    gnodes, gedges = _graph_frames(d)
    return [(DESIGN, _frame(DESIGN, _design_rows(d))), (SPECTRA, _frame(SPECTRA, _spectra_rows(d))),
            (MATRICES, _frame(MATRICES, _matrices_rows(d))), (RATES, _frame(RATES, _rates_rows(d))),
            (STEADY, _frame(STEADY, _steady_rows(d))), (SWEEP, sweep), (SWEEP_NODES, sweep_nodes),
            (SERIES, _series_frame(d)), (GRAPH_NODES, gnodes), (GRAPH_EDGES, gedges),
            (NODE_ENTRIES, _design_entries(d))]


def design_tables(design: Design) -> Frame:
    out: Frame = []
    for d in design.scenarios.values():
        out += scenario_design_tables(d)
    return out


# -- run tables --------------------------------------------------------------------------------------------------

def _nodes_rows(r: ScenarioResults) -> list[dict]:
    sc, b, s = r.scenario, r.bounds, r.sys
    P_kb = b.get("P_kb")
    kb_T = b["P_kb_t"][-1]
    rows = []
    for k, lam in enumerate(sc.rates):
        P, Pt = b[f"bound_inf_{k}"], b[f"bound_t_{k}"][-1]
        J, Jt = _nodes(r.design, f"joint_inf_{k}"), _nodes(r.design, f"joint_t_{k}")
        J = J if J is not None else _nan_like(P.shape)
        Jt = Jt[-1] if Jt is not None else _nan_like(P.shape)
        mc, se = r.grid_moments(lam).trace()
        if k == 0:
            emc, ese = r.event_moments().trace()
        for i in range(s.N):
            rows.append({"scenario": sc.name, "rate": lam, "node": i, "trP_bound_steady": _tr(P[i]),
                         "trP_exact_steady": _tr(J[i]), "trP_bound_final": _tr(Pt[i]), "trP_exact_final": _tr(Jt[i]),
                         "trP_mc_final": mc[-1, i], "trP_mc_final_se": se[-1, i],
                         "trP_event_final": emc[-1, i] if k == 0 else np.nan,
                         "trP_event_final_se": ese[-1, i] if k == 0 else np.nan,
                         "trP_kb_steady": _tr(P_kb) if P_kb is not None else np.nan, "trP_kb_final": _tr(kb_T),
                         "ratio_steady": _tr(J[i]) / _tr(P_kb) if P_kb is not None else np.nan,
                         "ratio_final_mc": mc[-1, i] / _tr(kb_T),
                         "gap_bound_exact_steady": float(_min_eig(P[i] - J[i])),
                         "gap_exact_kb_steady": float(_min_eig(J[i] - P_kb)) if P_kb is not None else np.nan,
                         "gap_bound_exact_final": float(_min_eig(Pt[i] - Jt[i])),
                         "gap_exact_kb_final": float(_min_eig(Jt[i] - kb_T)),
                         "trS": _tr(b["S"]) if "S" in b else np.nan,
                         "trS_true": _tr(b["S_true"]) if "S_true" in b else np.nan})
    return rows


def _mc_entries(r: ScenarioResults) -> pd.DataFrame:
    sc = r.scenario
    parts = []
    for lam in sc.rates:
        m, se = r.grid_moments(lam).entries()
        parts += [_entry_rows(sc.name, lam, "mc_final", m[-1]), _entry_rows(sc.name, lam, "mc_final_se", se[-1])]
    m, se = r.event_moments().entries()
    parts += [_entry_rows(sc.name, sc.main_rate, "event_final", m[-1]),
              _entry_rows(sc.name, sc.main_rate, "event_final_se", se[-1])]
    return pd.concat(parts, ignore_index=True)


def _series_rows(name: str, simulator: str, lam: float, t: np.ndarray, mom, trials: int) -> pd.DataFrame:
    tr, se = mom.trace()
    T, N = tr.shape
    return pd.DataFrame({"scenario": name, "simulator": simulator, "rate": lam, "t": np.repeat(t, N),
                         "node": np.tile(np.arange(N), T), "trP_mc": tr.ravel(), "trP_mc_se": se.ravel(), "trials": trials})


def _mc_series(r: ScenarioResults) -> pd.DataFrame:
    sc = r.scenario
    t = sc.output_times
    parts = [_series_rows(sc.name, "gridded", lam, t, r.grid_moments(lam), r.trials) for lam in sc.rates]
    parts.append(_series_rows(sc.name, "event", sc.main_rate, t, r.event_moments(), int(r.event["n"])))
    parts.append(_series_rows(sc.name, "frozen", sc.main_rate, t, r.frozen_moments(), r.frozen_moments().count))
    return pd.concat(parts, ignore_index=True)


def _sample_frame(name: str, simulator: str, z: np.ndarray, t: np.ndarray, N: int, n: int) -> pd.DataFrame:
    S, T, _ = z.shape
    x = z[:, :, :n]
    e = z[:, :, n:].reshape(S, T, N, n)
    xs = np.broadcast_to(x[:, :, None, :], e.shape)
    tr, tt, nd, cp = np.indices(e.shape)
    return pd.DataFrame({"scenario": name, "simulator": simulator, "trial": tr.ravel(), "t": t[tt.ravel()],
                         "node": nd.ravel(), "component": cp.ravel(), "x": xs.ravel(), "xhat": (xs - e).ravel(),
                         "error": e.ravel()})


def _path_frames(r: ScenarioResults) -> tuple[pd.DataFrame, pd.DataFrame]:
    sc, s, ev = r.scenario, r.sys, r.event
    t = sc.output_times
    P, Sg = ev["sample_pbound"], ev["sample_sigma"]
    S, T, N = P.shape[:3]
    p, tt, nd = np.indices((S, T, N))
    series = pd.DataFrame({"scenario": sc.name, "path": p.ravel(), "t": t[tt.ravel()], "node": nd.ravel(),
                           "trP_path": _tr(P).ravel(), "trSigma_path": _tr(Sg).ravel(), "gap_path": _min_eig(P - Sg).ravel()})
    cl = np.array(s.clocks).reshape(-1, 2)
    rows = []
    for path in range(S):
        et, ec = ev["sample_event_times"][path], ev["sample_event_clocks"][path]
        ok = ec >= 0
        rows.append(pd.DataFrame({"scenario": sc.name, "path": path, "event": np.arange(int(ok.sum())), "t": et[ok],
                                  "clock": ec[ok], "i": cl[ec[ok], 0], "j": cl[ec[ok], 1]}))
    ft, fc = r.frozen["path_times"], r.frozen["path_clocks"].astype(int)
    rows.append(pd.DataFrame({"scenario": sc.name, "path": -1, "event": np.arange(len(ft)), "t": ft, "clock": fc,
                              "i": cl[fc, 0], "j": cl[fc, 1]}))
    return series, pd.concat(rows, ignore_index=True)


def _cells_frame(r: ScenarioResults) -> pd.DataFrame:
    sc, b, ev, s = r.scenario, r.bounds, r.event, r.sys
    U = directions(s.n)
    idx = b["cell_times"]
    C, N, q = b["cell_bound"].shape
    c, i, k = np.indices((C, N, q))
    n = int(ev["n"])
    full = lambda key: b[key].ravel() if key in b else np.full(C * N * q, np.nan)
    return pd.DataFrame({"scenario": sc.name, "t": sc.output_times[idx][c.ravel()], "node": i.ravel(),
                         "direction": k.ravel(), "u": [json.dumps(U[j].tolist()) for j in k.ravel()],
                         "bound": b["cell_bound"].ravel(), "exact": full("cell_joint"), "kb": np.broadcast_to(
                             b["cell_kb"][:, None, :], (C, N, q)).ravel(),
                         "P_mean": full("cell_P_mean"), "P_second": full("cell_P_second"), "paths": n,
                         "mc_P_mean": ev["qP1"].ravel() / n, "mc_P_second": ev["qP2"].ravel() / n,
                         "mc_Sigma_mean": ev["qS1"].ravel() / n, "mc_Sigma_second": ev["qS2"].ravel() / n,
                         "mc_e_mean": ev["qE1"].ravel() / n, "mc_e_second": ev["qE2"].ravel() / n,
                         "whitened_sum": ev["white"].ravel(), "whitened_terms": ev["white_n"].ravel()})


def _frozen_frame(r: ScenarioResults) -> pd.DataFrame:
    sc, fz = r.scenario, r.frozen
    mom = r.frozen_moments()
    tr, se = mom.trace()
    T, N = tr.shape
    return pd.DataFrame({"scenario": sc.name, "t": np.repeat(sc.output_times, N), "node": np.tile(np.arange(N), T),
                         "trP_path": _tr(fz["path_pbound"]).ravel(), "trSigma_path": _tr(fz["path_sigma"]).ravel(),
                         "trP_mc": tr.ravel(), "trP_mc_se": se.ravel(), "trials": mom.count})


def _poisson_frame(r: ScenarioResults) -> pd.DataFrame:
    sc, s, ev = r.scenario, r.sys, r.event
    n = int(ev["n"])
    mu = s.degrees * sc.main_rate * sc.horizon
    return pd.DataFrame({"scenario": sc.name, "node": np.arange(s.N), "degree": s.degrees, "expected_events": mu,
                         "mean_events": np.asarray(ev["c1"], float) / n, "paths_without_event": ev["c0"],
                         "expected_without_event": n * np.exp(-mu), "paths": n})


def _references_frame(r: ScenarioResults) -> pd.DataFrame:
    b = r.bounds
    if "filterpy_h" not in b:
        return pd.DataFrame(columns=REFERENCES.column_names)
    pri, post, dare = b["filterpy_prior"], b["filterpy_post"], b["dare_prior"]
    return pd.DataFrame({"scenario": r.scenario.name, "h": b["filterpy_h"], "trP_prior": _tr(pri), "trP_post": _tr(post),
                         "trP_dare": _tr(dare), "diff_dare": np.linalg.norm(pri - dare, 2, axis=(1, 2)),
                         "allow": b["filterpy_allow"], "err_prior": _frob(pri - b["P_kb"]),
                         "err_post": _frob(post - b["P_kb"]), "steady": b["filterpy_steady"].astype(bool)})


def _scheme_frame(r: ScenarioResults) -> pd.DataFrame:
    b, sc = r.bounds, r.scenario
    if "scheme_bias_h" not in b:
        return pd.DataFrame(columns=SCHEME_BIAS.column_names)
    b1, b2 = np.abs(b["scheme_bias_h"]).max(axis=(2, 3)), np.abs(b["scheme_bias_h2"]).max(axis=(2, 3))
    T, N = b1.shape
    return pd.DataFrame({"scenario": sc.name, "t": np.repeat(sc.output_times, N), "node": np.tile(np.arange(N), T),
                         "bias_h": b1.ravel(), "bias_h2": b2.ravel()})


def _metrics_rows(r: ScenarioResults) -> list[dict]:
    sc, b = r.scenario, r.bounds
    name = sc.name
    rows = []

    def add(metric, value, node=None, rate=np.nan):
        rows.append({"scenario": name, "metric": metric, "node": node, "rate": rate, "value": float(value)})

    for k, lam in enumerate(sc.rates):
        mse, mse_se = r.grid_moments(lam).trace()
        bound = _tr(b[f"bound_t_{k}"])
        add("mse_final_mean", mse[-1].mean(), rate=lam)
        add("mse_final_mean_se", mse_se[-1].mean(), rate=lam)
        add("mse_final_max", mse[-1].max(), rate=lam)
        add("mse_time_avg", mse.mean(), rate=lam)
        add("bound_final_mean", bound[-1].mean(), rate=lam)
        J, Jt = _nodes(r.design, f"joint_inf_{k}"), _nodes(r.design, f"joint_t_{k}")
        for i in range(r.sys.N):
            add("mse_final", mse[-1, i], i, lam)
            add("bound_final", bound[-1, i], i, lam)
            add("bound_steady", _tr(b[f"bound_inf_{k}"][i]), i, lam)
            if J is not None:
                add("exact_steady", _tr(J[i]), i, lam)
                add("exact_final", _tr(Jt[-1, i]), i, lam)
    if "P_kb" in b:
        add("kb_trP", np.trace(b["P_kb"]))
    add("abar_abscissa", b["abar_abscissa"])
    add("crit_bound", b["crit_bound"])
    return rows


def _topology_frames(topo: dict) -> Frame:
    lams = topo["lams"]
    nodes, rates, graphs = [], [], []
    for g in TOPOLOGIES:
        d, tr = topo[f"{g}_d"], topo[f"{g}_trace_joint"]
        L, N = d.shape
        nodes.append(pd.DataFrame({"graph": g, "rate": np.repeat(lams, N), "node": np.tile(np.arange(N), L),
                                   "dev_bound": d.ravel(), "trP_exact": tr.ravel()}))
        rates.append(pd.DataFrame({"graph": g, "rate": lams, "gap": topo[f"{g}_gap"]}))
        graphs.append({"graph": g, "alpha_fiedler": float(topo[f"{g}_alpha_fiedler"]),
                       "crit_bound": float(topo[f"{g}_crit_bound"])})
    return [(TOPOLOGY, pd.concat(nodes, ignore_index=True)), (TOPOLOGY_RATES, pd.concat(rates, ignore_index=True)),
            (TOPOLOGY_GRAPHS, pd.DataFrame(graphs, columns=TOPOLOGY_GRAPHS.column_names))]


def run_tables(res: Results) -> Frame:
    out = design_tables(res.design())
    for r in res.scenarios.values():
        sc, s = r.scenario, r.sys
        paths, events = _path_frames(r)
        first = r.gridded[sc.rates[0]]["sample_z"]
        out += [(NODE_ENTRIES, _mc_entries(r)), (NODES, _frame(NODES, _nodes_rows(r))), (MC_SERIES, _mc_series(r)),
                (SAMPLE_PATHS, pd.concat([_sample_frame(sc.name, "gridded", first, sc.output_times, s.N, s.n),
                                          _sample_frame(sc.name, "event", r.event["sample_z"], sc.output_times, s.N,
                                                        s.n)], ignore_index=True)),
                (PATH_SERIES, paths), (PATH_EVENTS, events), (CELLS, _cells_frame(r)), (FROZEN, _frozen_frame(r)),
                (POISSON, _poisson_frame(r)), (REFERENCES, _references_frame(r)), (SCHEME_BIAS, _scheme_frame(r)),
                (METRICS, _frame(METRICS, _metrics_rows(r)))]
    if res.topology is not None:
        out += _topology_frames(res.topology)
    return out
