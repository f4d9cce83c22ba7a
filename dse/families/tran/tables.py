"""The tables of a coestimation run: every number a claim, a figure or a recording uses.

Design tables (also printed by `dse check`): the node types with their LMI results (`node_types`),
the nodes' design quantities (`node_design`), the bounds and constants of (15)-(18), (46) and (52)
with their variants (`bounds`), matrices entry by entry (`matrices`: the P_i used, the LMI
solutions, the S of the all-passive, all-active and fixed roles, ...), the spectra (`spectra`,
`s_cells`), the role sweeps of Lemma 3.1 (`role_sweep`), the noise of the seed (`noise`), and for
the paper's example the J sweep (`j_sweep`). Run tables add the runs: per node (`nodes`,
`node_covariance`), the trajectories (`truth`, `estimates`, `roles`), the error norms along the
deterministic runs (`errors`), the Monte Carlo per recorded time (`mc_series`) and against the
exact law (`law_cells`), the centralized Kalman filter (`central`) and the summary `metrics`.
A state or input component is an integer: 0..n−1 the states x, n..n+p−1 the inputs w.
"""
from __future__ import annotations

import json

import numpy as np
import pandas as pd

import dse.estimators.input_state_coestimation as ce
import dse.estimators.lyapunov_bounds as lb
from dse.outputs.tables import TableSpec, spec
from dse.scenario.graphs import degrees

from .design import Design
from .law import mean_square_constants
from .runs import Results, mc_moments

SC = ("scenario", "", "scenario name")
COMPONENT = ("component", "1", "0..n−1: state x_{k+1}; n..n+p−1: input w_{k−n+1}")
RUN = ("run", "", "which run (see the table's description)")

NODE_TYPES = spec("node_types", "node type", [
    SC, ("type", "", "node type name"), ("index", "1", "type index (order of the [node_type.<name>] tables)"),
    ("nodes", "1", "number of nodes of this type"), ("eps", "1", "ε_i required by (28)-(29)"),
    ("sigma", "1", "σ_i"), ("comparison_sigma", "1", "σ_i of the comparison architecture"),
    ("lmi_status", "", "solver status of the feasibility problem (28)-(29) (Clarabel, in cvxpy's words)"),
    ("lmi_margin", "1", "normalised margin t* = max t with tr P = n + p, ĀᵀP + PĀ ⪯ −tI at g = 0, 1 (> 0: feasible)"),
    ("lmi_margin_status", "", "solver status of the margin problem"),
    ("lmi_verified", "1", "max eigenvalue of Ā(g)ᵀP* + P*Ā(g), g ∈ {0, 1}, at the margin maximiser P* (numpy)"),
    ("abar_max_real", "1/s", "max over g ∈ [0, 1] (101 points) of max Re λ(Ā_i(g)) (≥ 0 certifies infeasibility)"),
    ("given_max_eig_g0", "1", "max eig(Ā_i(0)ᵀP_i + P_iĀ_i(0)) with the given P_i (NaN without one)"),
    ("given_max_eig_g1", "1", "the same at g = 1"),
    ("comparison_status", "", "status of the comparison LMIs (38)-(39) at comparison_sigma"),
    ("comparison_margin", "1", "their max margin t* (P ⪰ P_lower·I, tr P ≤ 1e4; < 0: infeasible)"),
    ("comparison_status_at_sigma", "", "status of (38)-(39) at the coestimation σ_i (paper's example only)"),
    ("comparison_margin_at_sigma", "1", "their margin at σ_i (paper's example only; NaN otherwise)"),
    ("comparison_sigma_min", "1", "smallest σ with (38)-(39) feasible, by bisection (paper's example only)"),
    ("rank_obsv", "1", "rank of the observability matrix of (A, C_i)"),
    ("rank_obsv_augmented", "1", "rank for the augmented pair ([[A, B], [0, 0]], [C_i, 0]) (x and a constant w)"),
    ("fn3_max_real", "1/s", "max Re λ(Ā_i(1)) with L_i = J_i = 0 (footnote 3)")],
    "The LMI vertices are Ā_i(0) and Ā_i(1) of (27).")
NODE_DESIGN = spec("node_design", "node", [
    SC, ("node", "1", "node i (0-based)"), ("type", "", "its type"), ("x", "position", "position c_i, first coordinate"),
    ("y", "position", "second coordinate"), ("degree", "1", "number of neighbours"),
    ("fixed_role", "1", "g_i of the fixed-role runs"), ("P_source", "", "where P_i comes from"),
    ("P_eig_min", "1", "λ_min(P_i)"), ("P_eig_max", "1", "λ_max(P_i)"), ("P_cond", "1", "condition number of P_i"),
    ("certified_eps", "1", "−max eig(Ā_i(g)ᵀP_i + P_iĀ_i(g)), g ∈ {0, 1}: the ε the P_i used certifies (numpy)"),
    ("certified_tol", "1", "its round-off allowance"), ("eps_required", "1", "ε_i of the node's type"),
    ("lemma_max_eig", "1", "max over g ∈ [0, 1] (101 points) of max eig(Ā_i(g)ᵀP_i + P_iĀ_i(g)) (Lemma 3.1: ≤ −ε_i)"),
    ("fixed_Q_min_eig", "1", "λ_min(Q_i), Q_i = −(Ā_i(g_i)ᵀP_i + P_iĀ_i(g_i)) at the fixed roles (> 0: (10) holds)"),
    ("fixed_Q_tol", "1", "its round-off allowance"),
    ("phibar_i", "input/s", "φ̄_i = σ_i‖K_i‖w̄ + w̄ (15)")])
BOUNDS = spec("bounds", "design quantity (and its variant)", [
    SC, ("quantity", "", "name (see definition)"), ("variant", "", "which variant of it (empty: the only one)"),
    ("value", "as defined", "value (for a supremum: the supremum to round-off)"),
    ("lower", "as defined", "a supremum's certified lower end, a value attained (NaN otherwise)"),
    ("upper", "as defined", "a supremum's certified upper end, what the bounds use (NaN otherwise)"),
    ("definition", "", "what it is")])
MATRICES = spec("matrices", "matrix entry", [
    SC, ("matrix", "", "name: P (per node, the P_i used), P_lmi (per type, max-margin solution of (28)-(29)), P_given "
         "(per type), P_comparison (per type, n x n, of (38)-(39)), Q_lyapunov (per type, the Q_i of (10)), Q_fixed "
         "(per node, −(Ā_iᵀP_i + P_iĀ_i) at the fixed roles), Abar0 / Abar1 (per type, the vertices Ā_i(0), Ā_i(1)), "
         "S_all_passive / S_all_active / S_fixed (S(g) = Ā(g) − αH(L⊗I) at g ≡ 0, g ≡ 1, the fixed roles), laplacian, "
         "initial_estimates (row: node, col: component), qstar_vertex (the g ∈ {0,1}^N where q* is attained)"),
    ("index", "1", "node or type index (empty for network-wide matrices)"), ("row", "1", "row"), ("col", "1", "column"),
    ("value", "as defined", "entry")])
SPECTRA = spec("spectra", "eigenvalue", [
    SC, ("matrix", "", "S_all_passive, S_all_active, S_fixed, S_random_<k> (random roles), laplacian, A"),
    ("index", "1", "position (ascending real part)"), ("real", "1/s", "real part"), ("imag", "1/s", "imaginary part")])
S_CELLS = spec("s_cells", "role vector g at which S(g) is checked Hurwitz", [
    SC, ("cell", "", "all_passive, all_active, fixed, random_<k>"), ("max_real", "1/s", "max Re λ(S(g))"),
    ("tol", "1/s", "its Bauer-Fike round-off allowance"), ("eigvec_cond", "1", "condition number of the eigenvectors"),
    ("roles", "", "g as a JSON list")])
ROLE_SWEEP = spec("role_sweep", "node and role g on [0, 1] (101 points)", [
    SC, ("node", "1", "node i"), ("type", "", "its type"), ("g", "1", "role"),
    ("lemma_max_eig", "1", "max eig(Ā_i(g)ᵀP_i + P_iĀ_i(g)) with the P_i used"),
    ("abar_max_real", "1/s", "max Re λ(Ā_i(g))"),
    ("given_max_eig", "1", "max eig with the type's given P_i (NaN without one)")])
J_SWEEP = spec("j_sweep", "node type and scale of J_i", [
    SC, ("type", "", "node type"), ("J_scale", "1", "J_i multiplied by this"),
    ("lmi_margin", "1", "normalised margin t* of (28)-(29) (> 0: feasible)")])
NOISE = spec("noise", "noise intensity component", [
    SC, ("node", "1", "node i of h_i (empty: the process noise v)"), ("component", "1", "component"),
    ("value", "as defined", "v_k (state/√s) or h_i,k (output·√s), drawn once per seed")])

NODES = spec("nodes", "node", [
    SC, ("node", "1", "node i"), ("type", "", "its type"), ("fixed_role", "1", "g_i of the fixed-role runs"),
    ("active_fraction", "1", "fraction of the recorded samples of the coestimation run with g_i > 1/2"),
    ("final_x_error", "state", "‖x(T) − x̂_i(T)‖ of the coestimation run"),
    ("final_w_error", "input", "‖ŵ_i(T) − w(T)‖ of the coestimation run"),
    ("tail_rms_x", "state", "RMS of ‖x − x̂_i‖ over t ≥ tail_start (coestimation)"),
    ("tail_rms_w", "input", "RMS of ‖ŵ_i − w‖ over t ≥ tail_start (coestimation)"),
    ("comparison_tail_rms_x", "state", "the same for the comparison architecture (NaN without its run)"),
    ("comparison_tail_rms_w", "input", "the same for the comparison architecture"),
    ("t_final", "s", "end T_s of the stochastic horizon (the 'final time' below)"),
    ("trials", "1", "Monte Carlo trials of the fixed-role run"),
    ("cov_steady_trace", "state²", "tr Σ_ii∞: the exact steady-state error covariance of z_i = [x − x̂_i; ŵ_i − w] with "
                                   "fixed roles (SΣ + ΣSᵀ + GGᵀ = 0; NaN when S is not Hurwitz)"),
    ("cov_final_trace", "state²", "tr Σ_ii(T_s), the exact covariance of (60) at the final time"),
    ("second_moment_final_trace", "state²", "tr J_ii(T_s) = ‖m_i(T_s)‖² + tr Σ_ii(T_s), the exact E‖z_i(T_s)‖² "
                                            "(J = E{zzᵀ} of (57)-(60); m the noise-free run)"),
    ("mc_second_moment_final", "state²", "Monte Carlo E‖z_i(T_s)‖² (fixed roles)"),
    ("mc_second_moment_final_se", "state²", "its standard error"),
    ("mc_cov_final_trace", "state²", "trace of the Monte Carlo covariance of z_i(T_s) (ddof = 1)"),
    ("mc_cov_final_trace_se", "state²", "its standard error √(2 tr(Σ̂²)/(R − 1)) (the Gaussian law's)"),
    ("cov_x_steady_trace", "state²", "tr of the x block of Σ_ii∞ (the node's state error)"),
    ("kb_steady_trace", "state²", "tr P_KB∞, the centralized Kalman-Bucy covariance of x with w known and every sensor "
                                  "of the fixed roles (a lower bound of every distributed estimate's)"),
    ("kb_final_trace", "state²", "tr P_KB(T_s) (P(0) = 0)"),
    ("ratio_steady", "1", "tr of the x block of Σ_ii∞ / tr P_KB∞"),
    ("loewner_gap_steady", "state²", "λ_min(x block of Σ_ii∞ − P_KB∞) (≥ 0 up to the reference's jitter)"),
    ("ratio_final", "1", "tr of the x block of Σ_ii(T_s) / tr P_KB(T_s)"),
    ("loewner_gap_final", "state²", "λ_min(x block of Σ_ii(T_s) − P_KB(T_s))")],
    "Deterministic-run columns from the coestimation run (time-varying roles); covariance columns from the "
    "stochastic variant with fixed roles, whose error is Gaussian with an exactly computable law.")
NODE_COVARIANCE = spec("node_covariance", "node, quantity and matrix entry", [
    SC, ("node", "1", "node i"),
    ("quantity", "", "cov_steady (Σ_ii∞), cov_final (Σ_ii(T_s)), second_moment_final (J_ii(T_s)), mean_final (m_i(T_s), "
                     "col 0), mc_cov_final (Monte Carlo covariance), mc_mean_final (Monte Carlo mean, col 0), kb_steady "
                     "and kb_final (x only: n x n)"),
    ("row", "1", "row (a component)"), ("col", "1", "column (a component)"), ("value", "as defined", "entry")])
TRUTH = spec("truth", "run, recorded time and component of the process", [
    SC, ("run", "", "deterministic (every noise-free run) or stochastic_<k> (stored trial k, time-varying roles)"),
    ("t", "s", "time"), COMPONENT, ("value", "state or input", "x(t) or w(t)")])
ESTIMATES = spec("estimates", "run, recorded time, node and component", [
    SC, ("run", "", "coest (coestimation, the scenario's roles), fixed (fixed roles), comparison (architecture "
                    "(36)-(37)), stochastic_<k> (stored trial k of the stochastic run with the scenario's roles)"),
    ("t", "s", "time"), ("node", "1", "node i"), COMPONENT, ("value", "state or input", "x̂_i(t) or ŵ_i(t)")])
ROLES = spec("roles", "run, recorded time and node", [
    SC, ("run", "", "coest (every noise-free run with the scenario's roles) or stochastic_<k>"), ("t", "s", "time"),
    ("node", "1", "node i"), ("g", "1", "role g_i(t)")])
ERRORS = spec("errors", "deterministic run, recorded time and node (empty: the network)", [
    SC, ("run", "", "coest, fixed or comparison"), ("t", "s", "time"), ("node", "1", "node i; empty for the network"),
    ("norm_x", "state", "‖x − x̂_i‖ (network: the mean over nodes)"),
    ("norm_w", "input", "‖ŵ_i − w‖ (network: the mean over nodes)"),
    ("norm_z", "1", "‖z_i‖ (network: ‖z‖ of the stacked error)"),
    ("V", "1", "z_iᵀP_iz_i (network: V = zᵀPz; NaN for the comparison run)")])
MC_SERIES = spec("mc_series", "stochastic run and recorded time", [
    SC, ("run", "", "sde_roles (the scenario's roles), sde_fixed (fixed roles), sde_fixed_half (fixed roles, half "
                    "the step)"), ("t", "s", "time"), ("trials", "1", "trials R"),
    ("V_mean", "1", "Monte Carlo mean of V = zᵀPz"), ("V_sd", "1", "its standard deviation over trials (ddof = 1)"),
    ("V_se", "1", "standard error of the mean"),
    ("exact_EV", "1", "exact E{V(t)} = mᵀPm + tr(PΣ) (fixed roles; NaN otherwise)"),
    ("bound46", "1", "(46): e^{−κt}V(0) + η/κ with the run's κ, η (fixed: Q̄ = Q + 2α(L⊗I); roles: Q̄_ε)"),
    ("x_error_mean", "state", "Monte Carlo mean over trials and nodes of ‖x − x̂_i‖"),
    ("w_error_mean", "input", "Monte Carlo mean over trials and nodes of ‖ŵ_i − w‖")])
LAW_CELLS = spec("law_cells", "fixed-role stochastic run, check time and principal direction u_j", [
    SC, ("run", "", "sde_fixed (step h) or sde_fixed_half (h/2)"), ("t", "s", "check time"),
    ("direction", "1", "j (principal directions of P^{1/2}ΣP^{1/2}, largest first)"),
    ("exact_mean", "1", "u_jᵀm(t), m the noise-free run at the run's step"),
    ("mc_mean", "1", "Monte Carlo mean of u_jᵀz(t)"), ("law_var", "1", "var(u_jᵀz) under (60)"),
    ("recursion_var", "1", "var(u_jᵀz) of the simulated recursion (the law the Monte Carlo has exactly)"),
    ("mc_var", "1", "Monte Carlo variance of u_jᵀz(t) (ddof = 1)"), ("trials", "1", "trials R")])
CENTRAL = spec("central", "run of the centralized Kalman filter, its time and component", [
    SC, ("run", "", "deterministic (active sensors), deterministic_all_sensors, stochastic_0 (stored trial 0)"),
    ("t", "s", "time (step reference.dt)"), COMPONENT, ("estimate", "state or input", "the filter's estimate"),
    ("truth", "state or input", "the true value")])
METRICS = spec("metrics", "metric, run and node (empty node: the whole network)", [
    SC, ("metric", "", "name: <run>_err_final_max, <run>_err_tail_rms, <run>_gain_final_max, <run>_err_final (per node), "
                       "<run>_tail_rms_x / _w (per node); <run>_integration_error (2·max|Δ| between the run at h and "
                       "h/2) and _integration_scale (the trajectories' size it is compared with); bound18_single, "
                       "mu_single, qbar_single, lamP_max, lamP_min, lmi_margin_min; exact_EV_final, mc_EV_final (fixed "
                       "roles)"),
    ("node", "1", "node, empty for the network"), ("run", "", "the run it describes (empty for design quantities)"),
    ("value", "as the metric", "value")])


# -- design tables ------------------------------------------------------------------------------------

def design_tables(d: Design) -> list[tuple[TableSpec, pd.DataFrame]]:
    sc, a = d.scenario, d.arrays
    name, names, extras = sc.name, [t.name for t in sc.types], "comp_status" in a
    rows = []
    for t, ty in enumerate(sc.types):
        given = a["given_sweep"][t] if "given_sweep" in a else np.full(2, np.nan)
        rows.append({"scenario": name, "type": ty.name, "index": t, "nodes": int(sum(k == t for k in sc.type_of)),
                     "eps": ty.eps, "sigma": ty.sigma, "comparison_sigma": ty.comparison_sigma,
                     "lmi_status": str(a["lmi_status"][t]), "lmi_margin": float(a["lmi_margin"][t]),
                     "lmi_margin_status": str(a["lmi_margin_status"][t]), "lmi_verified": float(a["lmi_verified"][t]),
                     "abar_max_real": float(a["lmi_hurwitz_sweep"][t].max()), "given_max_eig_g0": float(given[0]),
                     "given_max_eig_g1": float(given[-1]), "comparison_status": str(a["comp_status_b"][t]),
                     "comparison_margin": float(a["comp_margin_b"][t]),
                     "comparison_status_at_sigma": str(a["comp_status"][t]) if extras else "",
                     "comparison_margin_at_sigma": float(a["comp_margin"][t]) if extras else np.nan,
                     "comparison_sigma_min": float(a["comp_sigma_min"][t]) if extras else np.nan,
                     "rank_obsv": int(a["rank_obsv_local"][t]), "rank_obsv_augmented": int(a["rank_obsv_augmented"][t]),
                     "fn3_max_real": float(a["fn3_max_real"][t])})
    out = [(NODE_TYPES, pd.DataFrame(rows, columns=NODE_TYPES.column_names))]
    degree = degrees(sc.network)
    P = a["P"]
    lamP = [np.linalg.eigvalsh(Pi) for Pi in P]
    out.append((NODE_DESIGN, pd.DataFrame({
        "scenario": name, "node": np.arange(sc.N), "type": [names[t] for t in sc.type_of], "x": sc.nodes.positions[:, 0],
        "y": sc.nodes.positions[:, 1], "degree": degree, "fixed_role": np.asarray(sc.fixed_roles.active),
        "P_source": a["P_source"].astype(str), "P_eig_min": [w[0] for w in lamP], "P_eig_max": [w[-1] for w in lamP],
        "P_cond": [w[-1] / w[0] for w in lamP], "certified_eps": a["certified_eps"], "certified_tol": a["certified_tol"],
        "eps_required": a["eps_nodes"], "lemma_max_eig": a["lemma_sweep"].max(axis=1), "fixed_Q_min_eig": a["fixed_Qi_min"],
        "fixed_Q_tol": a["fixed_Qi_tol"], "phibar_i": a["phibar_i"]})))
    out.append((BOUNDS, bounds_frame(d)))
    out.append((MATRICES, matrices_frame(d)))
    out += spectra_frames(d)
    out.append((ROLE_SWEEP, _role_sweep(d)))
    if "J_sweep_margin" in a:
        jm = a["J_sweep_margin"]
        out.append((J_SWEEP, pd.DataFrame({"scenario": name, "type": np.repeat(names, jm.shape[1]),
                                           "J_scale": np.tile(a["J_sweep"], len(names)), "lmi_margin": jm.ravel()})))
    law = d.law
    noise = [{"scenario": name, "node": None, "component": k, "value": float(v)} for k, v in enumerate(law["v"])]
    noise += [{"scenario": name, "node": i, "component": k, "value": float(v)}
              for i in range(sc.N) for k, v in enumerate(law["h"][i])]
    out.append((NOISE, pd.DataFrame(noise, columns=NOISE.column_names).astype({"node": "Int64"})))
    return out


#: what the value of a supremum is, per method of `sinusoid_sup`
SUP_VALUE = {"constant": "exact", "period": "to round-off, by local ascent in the last boxes of the search",
             "torus": "of the torus of independent phases, to round-off",
             "triangle": "not computed: the value is the upper end"}


def bounds_frame(d: Design) -> pd.DataFrame:
    a, sc, law = d.arrays, d.scenario, d.law
    rows = []

    def add(quantity, value, definition, variant="", lower=np.nan, upper=np.nan):
        rows.append({"scenario": sc.name, "quantity": quantity, "variant": variant, "value": float(value),
                     "lower": float(lower), "upper": float(upper), "definition": definition})

    method = str(a["w_method"])
    how = SUP_VALUE[method] if method in SUP_VALUE else ""
    add("w_sup", a["w_sup"], f"sup over t ≥ 0 of ‖w(t)‖ ({how}); bracketed in [lower, upper], certified ({method})",
        lower=a["w_sup_lower"], upper=a["w_sup_upper"])
    add("wdot_sup", a["wdot_sup"], f"sup over t ≥ 0 of ‖ẇ(t)‖ ({how}); bracketed in [lower, upper], certified ({method})",
        lower=a["wdot_sup_lower"], upper=a["wdot_sup_upper"])
    add("wbar", a["wbar"], "w̄ = max(sup‖w‖, sup‖ẇ‖), the one bound of (15) for both (their certified upper ends)")
    add("w_period", a["w_period"], "period of ‖w(t)‖ searched (inf when the frequencies are incommensurate)")
    add("phibar", a["phibar"], "φ̄ = (Σ φ̄_i²)^{1/2} of (16) with w̄ for ‖w‖ and ‖ẇ‖", "paper")
    add("phibar", a["phibar_tight"], "φ̄ with the separate bounds sup‖w‖ and sup‖ẇ‖", "tight")
    add("lamP_min", a["lamP_min"], "λ_min(P), P = blockdiag(P_i)")
    add("lamP_max", a["lamP_max"], "λ_max(P) = ‖P‖")
    variants = {"single": "Q̄_ε = εI + 2α(L⊗I) with the single ε = min ε_i (Thm 3.1 as stated)",
                "pernode": "Q̄_ε with each node's ε_i", "certified": "Q̄_ε with the certified per-node margins",
                "qstar": "the vertex dissipation q* = min over g ∈ {0,1}^N of λ_min(−(Ā(g)ᵀP + PĀ(g)) + 2α(L⊗I))"}
    qmins = {"single": a["qbar_single"], "pernode": a["qbar_pernode"], "certified": a["qbar_certified"],
             "qstar": a["qstar"]}
    for v, text in variants.items():
        add("qbar_min", qmins[v], f"λ_min(Q̄): {text}", v)
        add("mu", a[f"mu_{v}"], "μ = 2‖P‖φ̄/λ_min(Q̄) (paper φ̄)", v)
        add("bound18", a[f"bound18_{v}"], "ultimate bound (18): (λ_max(P)/λ_min(P))^{1/2} μ", v)
    add("bound18", a["bound18_single_tight_phi"], "(18) with the single ε and the tight φ̄", "single_tight_phi")
    add("qbar_min", a["fixed_qbar_min"], "λ_min(Q̄), Q̄ = Q + 2α(L⊗I) with Q_i of the fixed roles (Thm 2.1)", "fixed")
    add("mu", a["fixed_mu"], "μ with the fixed-role Q̄", "fixed")
    add("bound18", a["fixed_bound18"], "(18) with the fixed-role Q̄ (Cor 2.1)", "fixed")
    add("thm31_vertex_max", a["thm31_vertex_max"], "max over g ∈ {0,1}^N of λ_max(S(g)ᵀP + PS(g) + Q̄_ε) (≤ 0: Thm 3.1's "
        "inequality; NaN when not enumerated)")
    add("thm31_vertex_tol", a["thm31_vertex_tol"], "its round-off allowance")
    add("identity54_residual", a["identity54_residual"], "max |SᵀP + PS + Q̄| at the fixed roles ((54))")
    add("identity54_tol", a["identity54_tol"], "its round-off allowance")
    add("A_max_real", a["A_max_real"], "max Re λ(A)")
    add("laplacian_fiedler", a["lap_fiedler"], "λ₂(L) (> 0: connected)")
    add("laplacian_max", a["lap_max_eig"], "λ_max(L)")
    add("rank_obsv_collective", a["rank_obsv_collective"], "rank of obsv(A, [C_1; …; C_N])")
    for label, fixed in (("fixed", True), ("roles", False)):
        c = mean_square_constants(d, fixed)
        add("kappa", c["kappa"], "κ = λ_min(Q̄)/(2λ_max(P)) of Prop 4.1", label)
        add("eta", c["eta"], "η = 2φ̄²‖P‖²/λ_min(Q̄) + λ_max(P)ψ̄² of Prop 4.1", label)
        add("eta_over_kappa", c["eta"] / c["kappa"], "η/κ, the limit of the bound (46)", label)
        add("psibar", c["psibar"], "ψ̄ = (N(v*² + r*²))^{1/2}", label)
        add("limit52", c["limit52"], "the limit (52) of E‖z‖ as displayed", label)
        add("r_star", c["r_star"], "r* = max_i ‖r_i‖ (fixed roles: g_i as fixed; roles: any g_i ∈ [0, 1])", label)
    add("v_star", law["v_star"], "v* = ‖v‖ (the seed's draw)")
    add("h_star", law["h_star"], "h* = max_i ‖h_i‖ (the seed's draw)")
    add("t_stochastic", law["t_sde"], "horizon of the stochastic runs")
    return pd.DataFrame(rows, columns=BOUNDS.column_names)


def matrices_frame(d: Design) -> pd.DataFrame:
    a, sc = d.arrays, d.scenario
    parts = []

    def add(name, M, index=None):
        parts.append(_entries(M, scenario=sc.name, matrix=name, index=index))

    for i in range(sc.N):
        add("P", a["P"][i], i)
    for t, ty in enumerate(sc.types):
        if np.all(np.isfinite(a["P_lmi"][t])):
            add("P_lmi", a["P_lmi"][t], t)
        if ty.P is not None:
            add("P_given", ty.P, t)
        if np.all(np.isfinite(a["P_comparison"][t])):
            add("P_comparison", a["P_comparison"][t], t)
        if sc.coupling.P == "lyapunov":
            add("Q_lyapunov", ty.Q, t)
        A0, A1 = ce.error_vertices(sc.A, sc.B, ty.C, ty.L, ty.J, ty.sigma, ty.K)
        add("Abar0", A0, t)
        add("Abar1", A1, t)
    for i in range(sc.N):
        add("Q_fixed", a["fixed_Q"][i], i)
    add("S_all_passive", a["S_all_passive"])
    add("S_all_active", a["S_all_active"])
    add("S_fixed", a["S_fixed"])
    add("laplacian", sc.lap)
    add("initial_estimates", sc.e0)
    if np.all(a["qstar_g"] >= 0):
        add("qstar_vertex", a["qstar_g"][None, :])
    return pd.concat(parts, ignore_index=True)[MATRICES.column_names].astype({"index": "Int64"})


def _entries(M: np.ndarray, **keys) -> pd.DataFrame:
    """One row per entry of a matrix: keys..., row, col, value (row-major)."""
    M = np.atleast_2d(np.asarray(M, float))
    r, c = np.divmod(np.arange(M.size), M.shape[1])
    return pd.DataFrame({**{k: [v] * M.size for k, v in keys.items()}, "row": r, "col": c, "value": M.ravel()})


def spectra_frames(d: Design) -> list[tuple[TableSpec, pd.DataFrame]]:
    a, sc = d.arrays, d.scenario
    cells = ["all_passive", "all_active", "fixed"] + [f"random_{k}" for k in range(len(a["S_max_real"]) - 3)]
    parts = []
    for c, cell in enumerate(cells):
        parts.append(pd.DataFrame({"scenario": sc.name, "matrix": f"S_{cell}", "index": np.arange(a["S_eig_real"].shape[1]),
                                   "real": a["S_eig_real"][c], "imag": a["S_eig_imag"][c]}))
    for label, M in (("laplacian", sc.lap), ("A", sc.A)):
        w = np.linalg.eigvals(M)
        w = w[np.lexsort((w.imag, w.real))]
        parts.append(pd.DataFrame({"scenario": sc.name, "matrix": label, "index": np.arange(len(w)), "real": w.real,
                                   "imag": w.imag}))
    cells_frame = pd.DataFrame({"scenario": sc.name, "cell": cells, "max_real": a["S_max_real"], "tol": a["S_tol"],
                                "eigvec_cond": a["S_cond"], "roles": [json.dumps(g.tolist()) for g in a["S_g"]]})
    return [(SPECTRA, pd.concat(parts, ignore_index=True)[SPECTRA.column_names]), (S_CELLS, cells_frame)]


def _role_sweep(d: Design) -> pd.DataFrame:
    a, sc = d.arrays, d.scenario
    g, names, t_of = a["g_sweep"], [t.name for t in sc.types], np.asarray(sc.type_of)
    given = a["given_sweep"][t_of] if "given_sweep" in a else np.full((sc.N, len(g)), np.nan)
    return pd.DataFrame({"scenario": sc.name, "node": np.repeat(np.arange(sc.N), len(g)),
                         "type": np.repeat([names[t] for t in t_of], len(g)), "g": np.tile(g, sc.N),
                         "lemma_max_eig": a["lemma_sweep"].ravel(), "abar_max_real": a["lmi_hurwitz_sweep"][t_of].ravel(),
                         "given_max_eig": given.ravel()})


# -- run tables ------------------------------------------------------------------------------------------

def _tail_rms(sc, r, z) -> tuple[np.ndarray, np.ndarray]:
    m = r["t"] >= sc.simulation.tail_start
    zt = z[m]
    return (np.sqrt(np.mean(np.sum(zt[..., :sc.n] ** 2, -1), axis=0)), np.sqrt(np.mean(np.sum(zt[..., sc.n:] ** 2, -1), axis=0)))


def run_tables(res: Results) -> list[tuple[TableSpec, pd.DataFrame]]:
    out = design_tables(res.design)
    out += [(NODES, nodes_frame(res)), (NODE_COVARIANCE, node_covariance_frame(res))]
    out += trajectory_frames(res)
    out += [(ERRORS, errors_frame(res)), (MC_SERIES, mc_series_frame(res)), (LAW_CELLS, law_cells_frame(res)),
            (CENTRAL, central_frame(res)), (METRICS, metrics_frame(res))]
    return out


def _fixed_mc(res: Results):
    """Monte Carlo final-time moments of the fixed-role run: (R, mean (N, q), covariance (N, q, q), E‖z_i‖² (N,),
    its SE (N,))."""
    r = res.runs["sde_fixed"]
    R = int(r["trials"])
    cov = r["final_m2"] / max(R - 1, 1)
    sq_se = np.sqrt(np.maximum(r["final_sq_m2"], 0.0) / max(R - 1, 1) / R)
    return R, r["final_mean"], cov, r["final_sq_mean"], sq_se



def _loewner_gap(S: np.ndarray, reference: np.ndarray) -> float:
    """λ_min(S − reference): ≥ 0 when the node's covariance dominates the reference (NaN when either is not finite)."""
    if not (np.all(np.isfinite(S)) and np.all(np.isfinite(reference))):
        return np.nan
    return float(np.linalg.eigvalsh(S - reference)[0])

def nodes_frame(res: Results) -> pd.DataFrame:
    sc, d, law = res.scenario, res.design, res.design.law
    n = sc.n
    co = res.runs["coest"]
    z = res.errors("coest")
    rms_x, rms_w = _tail_rms(sc, co, z)
    if "comparison" in res.runs:
        cp = res.runs["comparison"]
        crms_x, crms_w = _tail_rms(sc, cp, res.errors("comparison"))
    else:
        crms_x = crms_w = np.full(sc.N, np.nan)
    R, mc_mean, mc_cov, mc_sq, mc_sq_se = _fixed_mc(res)
    m_final = res.runs["exact_fixed"]["mean_final"]
    S_inf, S_T = law["Sigma_steady"], law["Sigma_final"]
    kb_inf, kb_T = law["kb_steady"], law["kb_final"]
    rows = []
    for i in range(sc.N):
        gap_inf = _loewner_gap(S_inf[i, :n, :n], kb_inf)
        gap_T = _loewner_gap(S_T[i, :n, :n], kb_T)
        rows.append({
            "scenario": sc.name, "node": i, "type": sc.types[sc.type_of[i]].name, "fixed_role": sc.fixed_roles.active[i],
            "active_fraction": float(np.mean(co["g"][:, i] > 0.5)), "final_x_error": float(np.linalg.norm(z[-1, i, :n])),
            "final_w_error": float(np.linalg.norm(z[-1, i, n:])), "tail_rms_x": float(rms_x[i]), "tail_rms_w": float(rms_w[i]),
            "comparison_tail_rms_x": float(crms_x[i]), "comparison_tail_rms_w": float(crms_w[i]),
            "t_final": float(law["t_sde"]), "trials": R, "cov_steady_trace": float(np.trace(S_inf[i])),
            "cov_final_trace": float(np.trace(S_T[i])),
            "second_moment_final_trace": float(m_final[i] @ m_final[i] + np.trace(S_T[i])),
            "mc_second_moment_final": float(mc_sq[i]), "mc_second_moment_final_se": float(mc_sq_se[i]),
            "mc_cov_final_trace": float(np.trace(mc_cov[i])),
            "mc_cov_final_trace_se": float(np.sqrt(2 * np.trace(mc_cov[i] @ mc_cov[i]) / max(R - 1, 1))),
            "cov_x_steady_trace": float(np.trace(S_inf[i, :n, :n])), "kb_steady_trace": float(np.trace(kb_inf)),
            "kb_final_trace": float(np.trace(kb_T)), "ratio_steady": float(np.trace(S_inf[i, :n, :n]) / np.trace(kb_inf)),
            "loewner_gap_steady": gap_inf, "ratio_final": float(np.trace(S_T[i, :n, :n]) / np.trace(kb_T)),
            "loewner_gap_final": gap_T})
    return pd.DataFrame(rows, columns=NODES.column_names)


def node_covariance_frame(res: Results) -> pd.DataFrame:
    sc, law = res.scenario, res.design.law
    R, mc_mean, mc_cov, _, _ = _fixed_mc(res)
    m_final = res.runs["exact_fixed"]["mean_final"]
    parts = []
    for i in range(sc.N):
        for quantity, M in (("cov_steady", law["Sigma_steady"][i]), ("cov_final", law["Sigma_final"][i]),
                            ("second_moment_final", np.outer(m_final[i], m_final[i]) + law["Sigma_final"][i]),
                            ("mean_final", m_final[i][:, None]), ("mc_cov_final", mc_cov[i]),
                            ("mc_mean_final", mc_mean[i][:, None]), ("kb_steady", law["kb_steady"]),
                            ("kb_final", law["kb_final"])):
            parts.append(_entries(M, scenario=sc.name, node=i, quantity=quantity))
    return pd.concat(parts, ignore_index=True)[NODE_COVARIANCE.column_names]


def _long(scenario: str, run: str, t: np.ndarray, values: np.ndarray, keys: tuple[str, ...], value: str) -> pd.DataFrame:
    """A (T, a, b, ...) array as rows (t, key_a, key_b, ..., value) in C order."""
    grids = np.meshgrid(*(np.arange(s) for s in values.shape[1:]), indexing="ij")
    T = len(t)
    cols = {"scenario": scenario, "run": run, "t": np.repeat(t, values[0].size)}
    for k, g in zip(keys, grids):
        cols[k] = np.tile(g.ravel(), T)
    cols[value] = values.reshape(-1)
    return pd.DataFrame(cols)


def trajectory_frames(res: Results) -> list[tuple[TableSpec, pd.DataFrame]]:
    sc = res.scenario
    truth, est, roles = [], [], []
    co = res.runs["coest"]
    truth.append(_long(sc.name, "deterministic", co["t"], np.concatenate([co["x"], co["w"]], axis=1), ("component",),
                       "value"))
    for run in ("coest", "fixed", "comparison"):
        if run in res.runs:
            r = res.runs[run]
            est.append(_long(sc.name, run, r["t"], r["e"], ("node", "component"), "value"))
    roles.append(_long(sc.name, "coest", co["t"], co["g"], ("node",), "g"))
    s = res.runs["sde_roles"]
    for k in range(len(s["kept_x"]) if s["kept_x"].size else 0):
        label = f"stochastic_{k}"
        truth.append(_long(sc.name, label, s["t"], np.concatenate([s["kept_x"][k], s["w"]], axis=1), ("component",), "value"))
        est.append(_long(sc.name, label, s["t"], s["kept_e"][k], ("node", "component"), "value"))
        roles.append(_long(sc.name, label, s["t"], s["kept_g"][k], ("node",), "g"))
    return [(TRUTH, pd.concat(truth, ignore_index=True)[TRUTH.column_names]),
            (ESTIMATES, pd.concat(est, ignore_index=True)[ESTIMATES.column_names]),
            (ROLES, pd.concat(roles, ignore_index=True)[ROLES.column_names])]


def errors_frame(res: Results) -> pd.DataFrame:
    sc = res.scenario
    P = res.P
    parts = []
    for run in ("coest", "fixed", "comparison"):
        if run not in res.runs:
            continue
        r = res.runs[run]
        z = res.errors(run)
        nx, nw = np.linalg.norm(z[..., :sc.n], axis=-1), np.linalg.norm(z[..., sc.n:], axis=-1)
        Vi = np.einsum("tni,nij,tnj->tn", z, P, z) if run != "comparison" else np.full(nx.shape, np.nan)
        T = len(r["t"])
        net = pd.DataFrame({"scenario": sc.name, "run": run, "t": r["t"], "node": None, "norm_x": nx.mean(1),
                            "norm_w": nw.mean(1), "norm_z": np.linalg.norm(z.reshape(T, -1), axis=1), "V": Vi.sum(1)})
        per = pd.DataFrame({"scenario": sc.name, "run": run, "t": np.repeat(r["t"], sc.N), "node": np.tile(np.arange(sc.N), T),
                            "norm_x": nx.ravel(), "norm_w": nw.ravel(), "norm_z": np.sqrt(nx ** 2 + nw ** 2).ravel(),
                            "V": Vi.ravel()})
        parts += [net, per]
    return pd.concat(parts, ignore_index=True)[ERRORS.column_names].astype({"node": "Int64"})


def mc_series_frame(res: Results) -> pd.DataFrame:
    sc = res.scenario
    ex = res.runs["exact_fixed"]
    parts = []
    for run in ("sde_roles", "sde_fixed", "sde_fixed_half"):
        r = res.runs[run]
        mean, sd, R = mc_moments(r, "V")
        c = mean_square_constants(res.design, fixed=run != "sde_roles")
        exact = ex["EV"][:len(mean)] if run != "sde_roles" else np.full(len(mean), np.nan)
        parts.append(pd.DataFrame({"scenario": sc.name, "run": run, "t": r["t"], "trials": R, "V_mean": mean, "V_sd": sd,
                                   "V_se": sd / np.sqrt(R), "exact_EV": exact,
                                   "bound46": lb.mean_square_bound(r["t"], float(mean[0]), c["kappa"], c["eta"]),
                                   "x_error_mean": r["xerr_mean"], "w_error_mean": r["werr_mean"]}))
    return pd.concat(parts, ignore_index=True)[MC_SERIES.column_names]


def law_cells_frame(res: Results) -> pd.DataFrame:
    sc, law, ex = res.scenario, res.design.law, res.runs["exact_fixed"]
    parts = []
    for run, key in (("sde_fixed", "h"), ("sde_fixed_half", "half")):
        r = res.runs[run]
        if "proj_mean" not in r:
            continue
        sel = np.isin(law["probe_index"], r["probe_index"])
        R = int(r["trials"])
        C, K = r["proj_mean"].shape
        parts.append(pd.DataFrame({
            "scenario": sc.name, "run": run, "t": np.repeat(r["probe_index"] * sc.simulation.record_dt, K),
            "direction": np.tile(np.arange(K), C), "exact_mean": ex[f"mean_proj_{key}"][sel].ravel(),
            "mc_mean": r["proj_mean"].ravel(), "law_var": law["probe_var"][sel].ravel(),
            "recursion_var": law[f"sim_var_{key}"][sel].ravel(), "mc_var": (r["proj_m2"] / max(R - 1, 1)).ravel(),
            "trials": R}))
    if not parts:
        return pd.DataFrame(columns=LAW_CELLS.column_names)
    return pd.concat(parts, ignore_index=True)[LAW_CELLS.column_names]


def central_frame(res: Results) -> pd.DataFrame:
    sc = res.scenario
    c, co = res.runs["central"], res.runs["coest"]
    stride = int(round(sc.reference.dt / sc.simulation.record_dt))
    truth_det = np.concatenate([co["x"], co["w"]], axis=1)[::stride]
    rows = [("deterministic", c["det_t"], c["det_s"], truth_det), ("deterministic_all_sensors", c["det_t"], c["det_all_s"],
                                                                   truth_det)]
    if "sde_s" in c:
        s = res.runs["sde_roles"]
        rows.append(("stochastic_0", c["sde_t"], c["sde_s"], np.concatenate([s["kept_x"][0], s["w"]], axis=1)[::stride]))
    parts = [_long(sc.name, run, t, est, ("component",), "estimate").assign(truth=truth.reshape(-1))
             for run, t, est, truth in rows]
    return pd.concat(parts, ignore_index=True)[CENTRAL.column_names]


def metrics_frame(res: Results) -> pd.DataFrame:
    """The summary of a run for sweeps: network-wide rows (one per metric) and per-node rows."""
    sc, d = res.scenario, res.design
    rows = []

    def add(metric, value, run=None, node=None):
        rows.append({"scenario": sc.name, "metric": metric, "node": node, "run": run, "value": float(value)})

    for k in ("bound18_single", "mu_single", "qbar_single", "lamP_max", "lamP_min"):
        add(k, d[k])
    add("lmi_margin_min", np.min(d["lmi_margin"]))
    for run in ("coest", "fixed", "comparison"):
        if run not in res.runs:
            continue
        r = res.runs[run]
        z = res.errors(run)
        norm = np.linalg.norm(z, axis=-1)                       # (T, nodes)
        tail = norm[-max(1, len(norm) // 10):]
        add(f"{run}_err_final_max", norm[-1].max(), run)
        add(f"{run}_err_tail_rms", np.sqrt(np.mean(tail ** 2)), run)
        add(f"{run}_gain_final_max", np.max(r["g"][-1]), run)
        rms_x, rms_w = _tail_rms(sc, r, z)
        for i in range(sc.N):
            add(f"{run}_err_final", norm[-1, i], run, i)
            add(f"{run}_tail_rms_x", rms_x[i], run, i)
            add(f"{run}_tail_rms_w", rms_w[i], run, i)
    for run, e in d.integration.items():
        add(f"{run}_integration_error", e["error"], run)
        add(f"{run}_integration_scale", e["scale"], run)
    add("exact_EV_final", res.runs["exact_fixed"]["EV"][-1], "sde_fixed")
    add("mc_EV_final", res.runs["sde_fixed"]["V_mean"][-1], "sde_fixed")
    return pd.DataFrame(rows, columns=METRICS.column_names).astype({"node": "Int64"})
