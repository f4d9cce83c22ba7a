"""The hypotheses the coestimation theorems rest on, decided on a scenario's design with their numbers
(registered on the family's `ClaimSet`, which `claims.py` completes with the claims).

Thm 2.1 / Cor 2.1 / Prop 4.1 (fixed roles): P_i solves (10) for some Q_i > 0, i.e.
Q_i = −(Ā_i(g_i)ᵀP_i + P_iĀ_i(g_i)) is positive definite (so Ā_i(g_i) is Hurwitz, the "local
sufficient stability condition"), H_i = P_i⁻¹, the graph is undirected, ‖w‖, ‖ẇ‖ ≤ w̄.
Thm 3.1 / Cor 3.1 / Lemma 3.1 / Remark 4.1 (time-varying roles): the P_i used satisfy (28)-(29)
with the node's ε_i, certified by numpy eigenvalues beyond their round-off (the SDP solver's
status and margin are reported with it, and an unstable Ā_i(g) as an infeasibility certificate).
The checks built on simulated trajectories also need the integration to be accurate (step
halving). Connectivity and collective observability are stated by the paper but used by no
proof: they are reported, and no claim rests on them.

Every check takes the scenario's `Design` (`design.py`); the step-halving hypothesis needs the
deterministic runs and is undecided before them (`dse check`).
"""
from __future__ import annotations

import numpy as np

from dse.contract.claims import ClaimSet
from dse.verify.rules import Holds, roundoff_tolerance

STEP_RTOL = 1e-3   # integration error estimate allowed, relative to the trajectories' scale

H_A = "tran.hyp.A_hurwitz"
H_INPUT = "tran.hyp.input_bound"
H_LMI = "tran.hyp.vertex_lmi"
H_FIXED = "tran.hyp.fixed_local"
H_QSTAR = "tran.hyp.qstar_positive"
H_GRAPH = "tran.hyp.graph_undirected"
H_CONNECTED = "tran.hyp.graph_connected"
H_OBSV = "tran.hyp.collective_observability"
H_INTEG = "tran.hyp.integration"
H_NOISE = "tran.hyp.noise_bounded"
H_SFIX = "tran.hyp.S_fixed_hurwitz"
H_SDE = "tran.hyp.sde_step"

#: the family's hypotheses and claims, in report order (ids are the paper's in every run)
claims = ClaimSet()


def _decide(margin: np.ndarray, tol: np.ndarray) -> bool | None:
    """True when every margin exceeds its round-off allowance, False when one is below minus it,
    None when one lies within round-off of zero (undecidable in floating point)."""
    if np.any(margin < -tol):
        return False
    if np.all(margin > tol):
        return True
    return None


@claims.hypothesis(H_A, "A is Hurwitz")
def a_hurwitz(d) -> Holds:
    v = float(d["A_max_real"])
    return Holds(v < 0, value=v, threshold=0.0, detail=f"max Re λ(A) = {v:.4g} (a standing assumption: passive nodes "
                                                      "run open loop)")


@claims.hypothesis(H_GRAPH, "the graph is undirected (L = Lᵀ ⪰ 0)")
def graph_undirected(d) -> Holds:
    asym, lmin = float(d["lap_asymmetry"]), float(d["lap_min_eig"])
    tol = 1e-12 * max(1.0, float(d["lap_max_eig"]))
    return Holds(asym == 0.0 and lmin > -tol, value=lmin, threshold=0.0,
                 detail=f"Laplacian symmetric (max |L − Lᵀ| = {asym:g}) and positive semidefinite (λ_min = {lmin:.3g})")


@claims.hypothesis(H_CONNECTED, "the graph is connected (stated, not used)")
def graph_connected(d) -> Holds:
    f = float(d["lap_fiedler"])
    tol = 1e-9 * max(1.0, float(d["lap_max_eig"]))
    return Holds(f > tol, value=f, threshold=0.0,
                 detail=f"λ₂(L) = {f:.4g}. Stated by the theorems, used by none of their proofs (only L ⪰ 0 is): "
                        "no claim rests on it")


@claims.hypothesis(H_OBSV, "(A, C) collectively observable (footnote 2; not used)")
def collective_observability(d) -> Holds:
    n = d.scenario.n
    coll = int(d["rank_obsv_collective"])
    return Holds(coll == n, value=coll, threshold=n,
                 detail=f"rank obsv(A, [C_1; …; C_N]) = {coll} (n = {n}); per node type {d['rank_obsv_local'].tolist()}. "
                        "A well-posedness assumption (footnote 2) that no proof uses: no claim rests on it")


@claims.hypothesis(H_INPUT, "‖w(t)‖ ≤ w̄ and ‖ẇ(t)‖ ≤ w̄ for all t ≥ 0 (certified w̄)")
def input_bound(d) -> Holds:
    method = str(d["w_method"])
    how = {"period": f"by branch and bound over the whole period {float(d['w_period']):.6g} of the norm",
           "torus": "by branch and bound over independent phases of the incommensurate frequencies (an upper bound "
                    "of the supremum over t)",
           "constant": "the input is constant",
           "triangle": "by the sum of the amplitudes per component (many incommensurate frequencies)"}[method]
    w, wl, wd, wdl = (float(d[k]) for k in ("w_sup_upper", "w_sup_lower", "wdot_sup_upper", "wdot_sup_lower"))
    ok = bool(np.isfinite(w) and np.isfinite(wd))
    return Holds(ok, value=float(d["wbar"]), threshold=max(wl, wdl),
                 detail=f"w̄ = max(sup‖w‖, sup‖ẇ‖) = {float(d['wbar']):.10g}: sup‖w‖ ∈ [{wl:.10g}, {w:.10g}], sup‖ẇ‖ ∈ "
                        f"[{wdl:.10g}, {wd:.10g}] for all t ≥ 0, certified {how}; the upper ends "
                        f"are used (slack {w - wl:.2g}, {wd - wdl:.2g})")


def _lmi_solver_text(d) -> str:
    parts = []
    for t, ty in enumerate(d.scenario.types):
        hur = float(np.max(d["lmi_hurwitz_sweep"][t]))
        cert = f"; Ā(g) unstable at some g ∈ [0, 1] (max Re λ = {hur:.3g}): no P exists" if hur >= 0 else ""
        parts.append(f"type '{ty.name}': Clarabel feasibility status {d['lmi_status'][t]}; normalised margin "
                     f"t* = {float(d['lmi_margin'][t]):.4g} (status {d['lmi_margin_status'][t]}; t* < 0 certifies "
                     f"infeasibility), numpy re-verification at its P {float(d['lmi_verified'][t]):.4g}{cert}")
    return "; ".join(parts)


@claims.hypothesis(H_LMI, "the P_i used satisfy (28)-(29) with ε_i (Thm 3.1, Lemma 3.1, Remark 4.1)")
def vertex_lmi(d) -> Holds:
    cert, tol, eps = d["certified_eps"], d["certified_tol"], d["eps_nodes"]
    margin = cert - eps
    worst = int(np.argmin(margin))
    src = sorted(set(d["P_source"].tolist()))
    return Holds(_decide(margin, tol), value=cert.tolist(), threshold=eps.tolist(),
                 detail=f"P_i used ({', '.join(src)}): certified ε (−max eig of Ā_i(g)ᵀP_i + P_iĀ_i(g), g ∈ {{0, 1}}, "
                        f"numpy) per node {np.round(cert, 8).tolist()} against the required ε_i "
                        f"{eps.tolist()}; worst node {worst + 1}: margin {margin[worst]:.4g} (round-off allowance "
                        f"{tol[worst]:.2g}). Solver: {_lmi_solver_text(d)}")


@claims.hypothesis(H_FIXED, "fixed roles: Q_i = −(Ā_iᵀP_i + P_iĀ_i) > 0, i.e. (10) with Q_i > 0 (Thm 2.1, Prop 4.1)")
def fixed_local(d) -> Holds:
    qmin, tol = d["fixed_Qi_min"], d["fixed_Qi_tol"]
    worst = int(np.argmin(qmin))
    return Holds(_decide(qmin, tol), value=qmin.tolist(), threshold=0.0,
                 detail=f"fixed roles g = {list(d.scenario.fixed_roles.active)}: min eig Q_i = −(Ā_iᵀP_i + P_iĀ_i) per "
                        f"node {np.round(qmin, 8).tolist()} (worst node {worst + 1}, round-off allowance "
                        f"{tol[worst]:.2g}); λ_min(Q̄) = {float(d['fixed_qbar_min']):.4g}")


@claims.hypothesis(H_QSTAR, "q* > 0 (the vertex dissipation of the tighter variant of (18))")
def qstar_positive(d) -> Holds:
    q = float(d["qstar"])
    if not np.isfinite(q):
        return Holds(None, value=q, threshold=0.0, detail="q* not computed (the 2^N vertex enumeration is skipped for "
                                                          "this many nodes)")
    sc = d.scenario
    # entries of −(Ā(g)ᵀP + PĀ(g)) + 2α(L⊗I): at most 2·q·max|Ā|·λ_max(P) + ‖2α(L⊗I)‖ in size
    tol = roundoff_tolerance(scale=2 * sc.q * float(np.abs(d["S_fixed"]).max()) * float(d["lamP_max"]) +
                             float(d["qbar_single_norm"]), operations=sc.N * sc.q)[0]
    return Holds(_decide(np.array([q]), np.array([tol])), value=q, threshold=0.0,
                 detail=f"q* = min over g ∈ {{0,1}}^N of λ_min(−(Ā(g)ᵀP + PĀ(g)) + 2α(L⊗I)) = {q:.4g} at g = "
                        f"{d['qstar_g'].tolist()}")


@claims.hypothesis(H_SFIX, "S at the fixed roles is Hurwitz (the fixed-role error system is stable)")
def s_fixed_hurwitz(d) -> Holds:
    """S at the fixed roles Hurwitz: the fixed-role error (and the simulation's rounding errors) do not grow.
    Decided on the computed eigenvalues up to the Bauer-Fike allowance cond(V)·‖S‖·Nq·eps."""
    v, tol = float(d["S_max_real"][2]), float(d["S_tol"][2])
    return Holds(_decide(np.array([-v]), np.array([tol])), value=v, threshold=0.0,
                 detail=f"max Re λ(S) at the fixed roles = {v:.4g} (Bauer-Fike allowance {tol:.2g}; eigenvector "
                        f"condition {float(d['S_fixed_cond']):.3g})")


def sde_deviation(d) -> tuple[float, float]:
    """Largest relative difference of var(u_jᵀz) between the simulated recursion (at h, at h/2) and (60), over
    the principal directions and check times of the fixed-role law; (0, 0) without noise."""
    law = d.law
    lam = law["probe_var"]
    ok = lam > 0
    if not np.any(ok):
        return 0.0, 0.0
    return tuple(float(np.max(np.abs(law[f"sim_var_{k}"][ok] / lam[ok] - 1.0))) for k in ("h", "half"))


@claims.hypothesis(H_SDE, "the stochastic step is in its convergent regime (the simulated law approaches (60) as h "
                   "halves)")
def sde_step(d) -> Holds:
    """The stochastic step is in the scheme's convergent regime: halving it at least halves the difference
    between the simulated recursion's law and (60) (or both are at round-off level, below 1e-6)."""
    dh, dhalf = sde_deviation(d)
    ok = bool(np.isfinite(dh) and np.isfinite(dhalf) and (dh <= 1e-6 or dhalf <= 0.5 * dh))
    return Holds(ok, value=[dh, dhalf], threshold=0.5,
                 detail=f"largest relative difference of var(u_jᵀz) between the simulated recursion and (60) along the "
                        f"principal directions: {dh:.3g} at h = {d.scenario.stochastic.step:g}, {dhalf:.3g} at h/2 "
                        "(halving h must at least halve it: the scheme converges to (60) and the step is in that regime)")


@claims.hypothesis(H_NOISE, "bounded noise intensities ‖v‖ ≤ v*, ‖h_i‖ ≤ h* (Prop 4.1)")
def noise_bounded(d) -> Holds:
    law = d.law
    v, h, r = float(law["v_star"]), float(law["h_star"]), float(law["r_star_roles"])
    return Holds(True, value=[v, h], threshold=None,
                 detail=f"constant intensities: v* = ‖v‖ = {v:.4g}, h* = max‖h_i‖ = {h:.4g}, r* = max_i ‖[L_ih_i; J_ih_i]‖ "
                        f"= {r:.4g} (any role g_i ∈ [0, 1])")


@claims.hypothesis(H_INTEG, "the deterministic runs are accurate (step halving)")
def integration(d) -> Holds:
    if d.integration is None:
        return Holds(None, value=None, threshold=STEP_RTOL,
                     detail="decided by the run: the deterministic runs at h and h/2 are compared (not simulated here)")
    parts, ok = [], True
    worst = 0.0
    for run in ("coest", "fixed"):
        est, scale, t_bad = (d.integration[run][k] for k in ("error", "scale", "t_bad"))
        if not np.isfinite(est):
            ok = False
            parts.append(f"{run}: not finite from t = {t_bad:g} (the error system diverges)")
            continue
        rel = est / scale
        worst = max(worst, rel)
        ok &= rel <= STEP_RTOL
        parts.append(f"{run}: 2·max|Δ(x̂, ŵ)| = {est:.3g} against scale {scale:.3g} (relative {rel:.2g})")
    return Holds(ok, value=worst if ok else float("nan"), threshold=STEP_RTOL,
                 detail=f"ETD2RK at h = {d.scenario.simulation.step:g} against h/2, error estimate relative to the "
                        f"trajectories' size ≤ {STEP_RTOL:g}: " + "; ".join(parts))
