"""Stages of the coestimation family, each cached: design (LMIs, the P_i used, bounds and the
numbers the hypotheses are decided on), deterministic runs (coestimation with time-varying and
fixed roles, each also at half the step; the comparison architecture), the exact moments of the
fixed-role error (60), stochastic Monte Carlo (time-varying and fixed roles) and the
centralized Kalman reference."""
from __future__ import annotations

import functools
from dataclasses import dataclass, field
from typing import Any

import numpy as np

import estimators.common_lyapunov as cl
import estimators.input_state_coestimation as ce
import estimators.lyapunov_bounds as lb
import estimators.observer_network_simulation as sim
import estimators.sinusoid_sup  # noqa: F401  (imported for the code fingerprint)
from pipeline.cache import StageCache, code_fingerprint
from pipeline.reproduction import RunOptions
from pipeline.seeding import stream_seed
from pipeline.simulate import parallel_map, run_blocks
from pipeline.verify import roundoff_tolerance

from .central_reference import central_kalman
from .scenario import CoestimationScenario

CODE_MODULES = ("estimators.common_lyapunov", "estimators.input_state_coestimation", "estimators.lyapunov_bounds",
                "estimators.observer_network_simulation", "estimators.exponential_integrators",
                "estimators.sinusoid_sup", "reproductions.tran.compute", "reproductions.tran.central_reference",
                "reproductions.tran.scenario")
J_SWEEP = (1.0, 2.0, 5.0, 10.0, 25.0, 50.0)
SDE_BLOCK = 100
G_SWEEP = np.linspace(0.0, 1.0, 101)
N_RANDOM_G = 20
MAX_CHECK_TIMES = 20       # times at which the fixed-role Monte Carlo is compared with the exact law
N_DIRECTIONS = 3           # principal directions of E{zᵀPz} tested at each of those times
# design quantities that are legitimately undefined in some scenarios (no vertex enumeration for large N,
# an infeasible LMI, a bound with λ_min(Q̄) ≤ 0, extras computed for the paper's example only)
DESIGN_MAY_BE_NAN = ("qstar", "mu_qstar", "bound18_qstar", "thm31_vertex_max", "thm31_vertex_tol", "comp_sigma_min",
                     "P_comparison", "P_lmi", "lmi_margin", "lmi_verified", "comp_margin", "comp_margin_b",
                     "J_sweep_margin", "mu_single", "bound18_single", "mu_pernode", "bound18_pernode", "mu_certified",
                     "bound18_certified", "fixed_mu", "fixed_bound18", "bound18_single_tight_phi", "S_max_real",
                     "S_tol", "S_min_real", "S_fixed_cond", "lmi_hurwitz_sweep", "given_sweep", "given_hurwitz", "w_period")
# a diverging run (an unstable error system: the hypotheses do not hold) is kept with its non-finite values
RUN_MAY_BE_NAN = ("x", "w", "e", "g", "red_V", "red_znorm", "red_xerr", "red_werr", "red_proj", "kept_x", "kept_e",
                  "kept_g", "EV", "mean_proj", "det_s", "det_all_s", "sde_s")


@dataclass
class Results:
    scenario: CoestimationScenario
    seed: int
    trials: int
    quick: bool
    design: dict[str, np.ndarray]
    runs: dict[str, dict[str, np.ndarray]] = field(default_factory=dict)

    @property
    def P(self) -> np.ndarray:
        return self.design["P"]

    def signal(self) -> sim.SinusoidalInput:
        return input_signal(self.scenario)


def trial_count(sc: CoestimationScenario, opts: RunOptions) -> int:
    return opts.trials if opts.trials is not None else (sc.quick_trials if opts.quick else sc.trials)


def input_signal(sc: CoestimationScenario) -> sim.SinusoidalInput:
    return sim.SinusoidalInput(sc.w_offset, sc.w_amplitude, sc.w_frequency, sc.w_phase)


def gains(sc: CoestimationScenario) -> dict[str, np.ndarray]:
    return {k: sc.per_node(k) for k in ("C", "L", "J", "K", "sigma")}


def vertices(sc: CoestimationScenario, t: int, J_scale: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    ty = sc.types[t]
    return ce.error_vertices(sc.A, sc.B, ty.C, ty.L, J_scale * ty.J, ty.sigma, ty.K)


def node_vertices(sc: CoestimationScenario, i: int) -> tuple[np.ndarray, np.ndarray]:
    return vertices(sc, sc.node_type[i])


def _node(sc: CoestimationScenario, i: int):
    ty = sc.types[sc.node_type[i]]
    return ty.C, ty.L, ty.J, ty.sigma, ty.K


def _lyapunov_rounding(A: np.ndarray, P: np.ndarray) -> float:
    """Round-off allowance of an eigenvalue of AᵀP + PA: products of length d with inputs of size
    ‖|A|ᵀ|P|‖₂, then a symmetric eigenvalue problem of size d (backward stable)."""
    d = A.shape[0]
    return roundoff_tolerance(scale=2 * np.linalg.norm(np.abs(A).T @ np.abs(P), 2), operations=2 * d)[0]


# -- design stage ---------------------------------------------------------------------------------

def _comparison_blocks(sc: CoestimationScenario, t: int, sigma: float):
    import cvxpy as cp

    ty = sc.types[t]
    out = []
    for g in (0.0, 1.0):
        Acl, c12, c22 = ce.comparison_lmi_blocks(sc.A, sc.B, ty.C, ty.L, ty.J, sigma, ty.K, g)

        def R(P, Acl=Acl, c12=c12, c22=c22):
            if isinstance(P, np.ndarray):
                top = -P @ sc.B + c12
                return np.block([[Acl.T @ P + P @ Acl, top], [top.T, c22]])
            top = -P @ sc.B + c12
            M = cp.bmat([[Acl.T @ P + P @ Acl, top], [top.T, c22]])
            return (M + M.T) / 2
        out.append(R)
    return out


def _min_feasible_sigma(sc: CoestimationScenario, t: int, lo: float, hi: float, iters: int) -> float:
    """Bisection on σ for the smallest σ with (38)-(39) feasible (normalised margin ≥ 0); nan if
    infeasible at `hi`."""
    def ok(s):
        r = cl.affine_lmi(_comparison_blocks(sc, t, s), sc.n, lower=sc.comparison_P_lower)
        return np.isfinite(r.margin) and r.margin >= 0
    if not ok(hi):
        return float("nan")
    for _ in range(iters):
        mid = np.sqrt(lo * hi)
        lo, hi = (lo, mid) if ok(mid) else (mid, hi)
    return float(hi)


def _solve_vertex_lmis(sc: CoestimationScenario) -> dict[str, np.ndarray]:
    """(28)-(29) per node type with cvxpy/Clarabel (status, normalised margin t*, its numpy
    re-verification, the maximiser) and an eigenvalue certificate of infeasibility: the largest
    real part of Ā_i(g) over g ∈ [0, 1] (an unstable Ā_i(g) admits no P)."""
    T, q = len(sc.types), sc.n + sc.p
    status, margin, verified, mstatus = [], [], [], []
    P_lmi = np.full((T, q, q), np.nan)
    hurwitz = np.zeros((T, len(G_SWEEP)))
    for t, ty in enumerate(sc.types):
        r = cl.common_lyapunov(vertices(sc, t), ty.eps)
        status.append(r.status)
        margin.append(r.margin)
        verified.append(r.verified)
        mstatus.append(r.margin_status)
        if r.P is not None:
            P_lmi[t] = r.P
        hurwitz[t] = [np.linalg.eigvals(ce.error_matrix(sc.A, sc.B, ty.C, ty.L, ty.J, ty.sigma, ty.K, g)).real.max()
                      for g in G_SWEEP]
    return {"lmi_status": np.array(status), "lmi_margin": np.array(margin, float),
            "lmi_verified": np.array(verified, float), "lmi_margin_status": np.array(mstatus), "P_lmi": P_lmi,
            "lmi_hurwitz_sweep": hurwitz}


def _design_P(sc: CoestimationScenario, P_lmi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The P_i the estimator uses (H_i = P_i⁻¹) and where each comes from.

    given: the scenario's P_i. lmi: the max-margin solution of (28)-(29), scaled up when its
    verified margin is below 1.1 ε_i (the LMIs are homogeneous in (P, ε)). lyapunov: (10) with
    Q_i = I at the fixed roles. A design that yields no positive definite P (an infeasible LMI,
    an unstable Ā_i in (10)) runs with P_i = I so that the run still reports; the hypotheses then
    say that the theorems do not apply."""
    N, q = sc.N, sc.n + sc.p
    P = np.zeros((N, q, q))
    source = []
    for i in range(N):
        t = sc.node_type[i]
        ty = sc.types[t]
        cand, label = None, sc.P_mode
        if sc.P_mode == "given":
            cand = ty.P
        elif sc.P_mode == "lmi":
            Pt = P_lmi[t]
            if np.all(np.isfinite(Pt)):
                cert = -cl.vertex_margin(vertices(sc, t), Pt)
                if cert > 0:
                    scale = max(1.0, 1.1 * ty.eps / cert)
                    cand, label = Pt * scale, "lmi" if scale == 1.0 else f"lmi (scaled by {scale:.3g})"
        else:
            from scipy.linalg import solve_continuous_lyapunov
            Ab = ce.error_matrix(sc.A, sc.B, *_node(sc, i), sc.roles_active[i])
            if np.linalg.eigvals(Ab).real.max() < 0:   # (10) has a positive definite solution only then
                X = solve_continuous_lyapunov(Ab.T, -np.eye(q))
                cand = (X + X.T) / 2
        if cand is not None and np.all(np.isfinite(cand)):
            ev = np.linalg.eigvalsh(cand)
            if ev[0] > 1e3 * np.finfo(float).eps * ev[-1]:
                P[i] = cand
                source.append(label)
                continue
        P[i] = np.eye(q)
        source.append("identity (no positive definite P from the design)")
    return P, np.array(source)


def _s_cells(sc: CoestimationScenario, P: np.ndarray, g_list):
    """max Re λ(S(g)) per g, its round-off allowance (Bauer-Fike: cond(V)·‖S‖₂ times the backward
    error of the eigenvalue solver), min Re λ and cond(V) (V the eigenvectors)."""
    G = gains(sc)
    mx, tol, mn, cond = [], [], [], []
    for g in g_list:
        S = ce.stacked_error_matrix(sc.A, sc.B, G["C"], G["L"], G["J"], G["K"], G["sigma"], P, sc.lap, sc.alpha, g)
        w, V = np.linalg.eig(S)
        mx.append(w.real.max())
        mn.append(w.real.min())
        cond.append(np.linalg.cond(V))
        tol.append(roundoff_tolerance(scale=np.linalg.norm(S, 2), operations=S.shape[0], condition=cond[-1])[0])
    return np.array(mx), np.array(tol), np.array(mn), np.array(cond)


def _thm31_vertex_check(sc, P, eps, max_nodes: int) -> tuple[float, float]:
    """max over g ∈ {0,1}^N of λ_max(S(g)ᵀP + PS(g) + Q̄_ε), with S(g) built explicitly (the coupling part
    −α(H(L⊗I))ᵀP − αPH(L⊗I) is formed as a product, not through the identity PH = I), and its
    round-off allowance: inputs of size ‖(|S(0)| + |S(1) − S(0)|)ᵀ|P|‖₂ (a bound of |S(g)|ᵀ|P| for
    every g), products of length Nq, H = P⁻¹ with condition κ(P)."""
    N, q = sc.N, sc.n + sc.p
    if N > max_nodes:
        return float("nan"), float("nan")
    G = gains(sc)
    Pbig = ce.block_diag(list(P))
    Qe = lb.qbar_eps(eps, sc.lap, sc.alpha, q)
    Hc = ce.block_diag(list(np.linalg.inv(P))) @ np.kron(sc.lap, np.eye(q))
    base = -sc.alpha * (Hc.T @ Pbig + Pbig @ Hc) + Qe
    blocks = [[(lambda A_: A_.T @ P[i] + P[i] @ A_)(ce.error_matrix(sc.A, sc.B, G["C"][i], G["L"][i], G["J"][i],
                                                                   G["sigma"][i], G["K"][i], g)) for g in (0.0, 1.0)]
              for i in range(N)]
    top = lb.vertex_eigen_extremes((base + base.T) / 2, blocks)[2]
    S0, S1 = (ce.stacked_error_matrix(sc.A, sc.B, G["C"], G["L"], G["J"], G["K"], G["sigma"], P, sc.lap, sc.alpha, g)
              for g in (0.0, 1.0))
    absS = np.abs(S0) + np.abs(S1 - S0)
    cond = max(np.linalg.cond(Pi) for Pi in P)
    tol = roundoff_tolerance(scale=2 * np.linalg.norm(absS.T @ np.abs(Pbig), 2) + np.linalg.norm(Qe, 2),
                             operations=N * q, condition=cond)[0]
    return float(top), float(tol)


def compute_design(sc: CoestimationScenario, quick: bool, extras: bool = True) -> dict[str, np.ndarray]:
    """Everything that needs no simulation. `extras`: the computations only claims about the paper's
    own example use (the comparison LMIs at the coestimation σ, the smallest feasible σ, the J
    sweep), skipped for users' scenarios."""
    n, p, q, N = sc.n, sc.p, sc.n + sc.p, sc.N
    T = len(sc.types)
    out: dict[str, Any] = _solve_vertex_lmis(sc)
    if all(ty.P is not None for ty in sc.types):
        out["P_given"] = np.stack([ty.P for ty in sc.types])
        sweep = np.zeros((T, len(G_SWEEP)))
        for t, ty in enumerate(sc.types):
            for k, g in enumerate(G_SWEEP):
                Ab = ce.error_matrix(sc.A, sc.B, ty.C, ty.L, ty.J, ty.sigma, ty.K, g)
                sweep[t, k] = np.linalg.eigvalsh(Ab.T @ ty.P + ty.P @ Ab).max()
        out["given_sweep"] = sweep
    out["g_sweep"] = G_SWEEP
    P, source = _design_P(sc, out["P_lmi"])
    out.update(P=P, P_source=source)
    G = gains(sc)
    lap = sc.lap
    eps_nodes = np.array([sc.types[t].eps for t in sc.node_type])
    # (28)-(29) with the P used: certified per-node margins (numpy eigenvalues) and their round-off allowance
    cert = np.array([-cl.vertex_margin(node_vertices(sc, i), P[i]) for i in range(N)])
    cert_tol = np.array([max(_lyapunov_rounding(A_, P[i]) for A_ in node_vertices(sc, i)) for i in range(N)])
    # Lemma 3.1 on a g grid, with the P used
    lemma = np.zeros((N, len(G_SWEEP)))
    lemma_tol = np.zeros(N)
    for i in range(N):
        for k, g in enumerate(G_SWEEP):
            Ab = ce.error_matrix(sc.A, sc.B, *_node(sc, i), g)
            lemma[i, k] = np.linalg.eigvalsh(Ab.T @ P[i] + P[i] @ Ab).max()
            lemma_tol[i] = max(lemma_tol[i], _lyapunov_rounding(Ab, P[i]))
    out.update(certified_eps=cert, certified_tol=cert_tol, eps_nodes=eps_nodes, lemma_sweep=lemma, lemma_tol=lemma_tol)
    # comparison architecture (38)-(39) at the reconstructed σ_b (its run), and the paper-only extras
    cstat_b, cmargin_b = [], []
    P_b_types = np.full((T, n, n), np.nan)
    for t, ty in enumerate(sc.types):
        rb = cl.affine_lmi(_comparison_blocks(sc, t, ty.comparison_sigma), n, lower=sc.comparison_P_lower)
        cstat_b.append(rb.status)
        cmargin_b.append(rb.margin)
        # an uncertified P would run the comparison architecture outside its theory: only a feasible one is used
        if rb.P is not None and np.isfinite(rb.margin) and rb.margin >= 0:
            P_b_types[t] = rb.P
    out.update(comp_status_b=np.array(cstat_b), comp_margin_b=np.array(cmargin_b, float), P_comparison=P_b_types)
    if extras:
        cstat, cmargin, sig_min = [], [], []
        for t, ty in enumerate(sc.types):
            r0 = cl.affine_lmi(_comparison_blocks(sc, t, ty.sigma), n, lower=sc.comparison_P_lower)
            cstat.append(r0.status)
            cmargin.append(r0.margin)
            sig_min.append(_min_feasible_sigma(sc, t, ty.sigma, max(10.0, 10 * ty.comparison_sigma), 6 if quick else 10))
        jm = np.array([[cl.common_lyapunov(vertices(sc, t, s), sc.types[t].eps).margin for s in J_SWEEP]
                       for t in range(T)])
        out.update(comp_status=np.array(cstat), comp_margin=np.array(cmargin, float), comp_sigma_min=np.array(sig_min),
                   J_sweep=np.array(J_SWEEP), J_sweep_margin=jm)
    # the input bounds over all t ≥ 0 (certified, with their slack)
    bw, bd = input_signal(sc).sup_bounds()
    w_sup, wdot_sup = bw.upper, bd.upper
    wbar = max(w_sup, wdot_sup)
    phi_i, phibar = lb.forcing_bound(G["sigma"], G["K"], wbar, wbar)
    _, phibar_tight = lb.forcing_bound(G["sigma"], G["K"], w_sup, wdot_sup)
    out.update(w_sup=w_sup, w_sup_lower=bw.lower, wdot_sup=wdot_sup, wdot_sup_lower=bd.lower, w_method=np.array(bw.method),
               w_period=bw.period, wbar=wbar, phibar_i=phi_i, phibar=phibar, phibar_tight=phibar_tight)
    lamP = np.concatenate([np.linalg.eigvalsh(Pi) for Pi in P])
    Qe_single = lb.qbar_eps(np.full(N, eps_nodes.min()), lap, sc.alpha, q)
    ev_single = np.linalg.eigvalsh(Qe_single)
    qb_pernode = np.linalg.eigvalsh(lb.qbar_eps(eps_nodes, lap, sc.alpha, q))[0]
    qb_cert = np.linalg.eigvalsh(lb.qbar_eps(np.maximum(cert, 0), lap, sc.alpha, q))[0]
    vd = lb.vertex_dissipation(sc.A, sc.B, G["C"], G["L"], G["J"], G["K"], G["sigma"], P, lap, sc.alpha,
                               max_nodes=10 if quick else 14)
    out.update(lamP_min=lamP.min(), lamP_max=lamP.max(), qbar_single=ev_single[0], qbar_single_norm=ev_single[-1],
               qbar_pernode=qb_pernode, qbar_certified=qb_cert,
               qstar=np.nan if vd is None else vd[0], qstar_g=np.full(N, -1) if vd is None else vd[1])
    for name, qmin in (("single", ev_single[0]), ("pernode", qb_pernode), ("certified", qb_cert),
                       ("qstar", np.nan if vd is None else vd[0])):
        mu, bound = lb.ultimate_bound(P, qmin, phibar) if np.isfinite(qmin) and qmin > 0 else (np.nan, np.nan)
        out[f"mu_{name}"], out[f"bound18_{name}"] = mu, bound
    out["bound18_single_tight_phi"] = lb.ultimate_bound(P, ev_single[0], phibar_tight)[1]
    # fixed roles: Q_i from (10), Q̄, S, identity (54)
    gfix = np.asarray(sc.fixed_active)
    Abars = [ce.error_matrix(sc.A, sc.B, *_node(sc, i), gfix[i]) for i in range(N)]
    Qi_min = np.array([np.linalg.eigvalsh(-(A_.T @ P[i] + P[i] @ A_)).min() for i, A_ in enumerate(Abars)])
    Qi_tol = np.array([_lyapunov_rounding(A_, P[i]) for i, A_ in enumerate(Abars)])
    Qbar_fixed = lb.qbar_fixed(Abars, P, lap, sc.alpha)
    S_fixed = ce.stacked_error_matrix(sc.A, sc.B, G["C"], G["L"], G["J"], G["K"], G["sigma"], P, lap, sc.alpha, gfix)
    Pbig = ce.block_diag(list(P))
    res54 = S_fixed.T @ Pbig + Pbig @ S_fixed + Qbar_fixed
    ev_fixed = np.linalg.eigvalsh(Qbar_fixed)
    qf_min = ev_fixed[0]
    mu_f, b_f = lb.ultimate_bound(P, qf_min, phibar) if qf_min > 0 else (np.nan, np.nan)
    tol54 = roundoff_tolerance(scale=np.abs(np.abs(S_fixed).T @ np.abs(Pbig)).max() * 2 + np.abs(Qbar_fixed).max(),
                               operations=N * q, condition=max(np.linalg.cond(Pi) for Pi in P))[0]
    out.update(fixed_Qi_min=Qi_min, fixed_Qi_tol=Qi_tol, fixed_qbar_min=qf_min, fixed_qbar_norm=ev_fixed[-1],
               fixed_mu=mu_f, fixed_bound18=b_f, identity54_residual=np.abs(res54).max(),
               identity54_scale=np.abs(Qbar_fixed).max(), identity54_tol=tol54, S_fixed=S_fixed)
    # S(g) Hurwitz: all-passive, all-active, the fixed roles and random g
    rng = np.random.default_rng(12345)
    g_list = [np.zeros(N), np.ones(N), gfix] + [rng.uniform(size=N) for _ in range(N_RANDOM_G)]
    mx, tol, mn, cond = _s_cells(sc, P, g_list)
    out.update(S_max_real=mx, S_tol=tol, S_min_real=mn[:2], S_fixed_cond=cond[2])
    # Thm 3.1: S(g)ᵀP + PS(g) + Q̄_ε ≤ 0 at the vertices g ∈ {0,1}^N (single ε), largest eigenvalue
    top, ttol = _thm31_vertex_check(sc, P, np.full(N, eps_nodes.min()), max_nodes=10 if quick else 14)
    out.update(thm31_vertex_max=top, thm31_vertex_tol=ttol)
    # observability facts
    from control import obsv
    out["rank_obsv_local"] = np.array([np.linalg.matrix_rank(obsv(sc.A, ty.C)) for ty in sc.types])
    out["rank_obsv_collective"] = np.array(np.linalg.matrix_rank(obsv(sc.A, np.vstack([ty.C for ty in sc.types]))))
    Aaug = np.block([[sc.A, sc.B], [np.zeros((p, n + p))]])
    out["rank_obsv_augmented"] = np.array([np.linalg.matrix_rank(obsv(Aaug, np.hstack([ty.C, np.zeros((sc.m, p))])))
                                           for ty in sc.types])
    # footnote 3: L = J = 0 makes Ā_i Hurwitz
    out["fn3_max_real"] = np.array([np.linalg.eigvals(ce.error_matrix(sc.A, sc.B, ty.C, 0 * ty.L, 0 * ty.J, ty.sigma,
                                                                      ty.K, 1.0)).real.max() for ty in sc.types])
    out["A_max_real"] = np.linalg.eigvals(sc.A).real.max()
    lev = np.linalg.eigvalsh(lap)
    out.update(lap_min_eig=lev[0], lap_fiedler=lev[1] if N > 1 else 0.0, lap_max_eig=lev[-1],
               lap_asymmetry=np.abs(lap - lap.T).max())
    return {k: np.asarray(v) for k, v in out.items()}


# -- networks and simulations ---------------------------------------------------------------------

def coestimation(sc: CoestimationScenario, P: np.ndarray) -> ce.NetworkObserver:
    G = gains(sc)
    return ce.coestimation_network(sc.A, sc.B, G["C"], G["L"], G["J"], G["K"], G["sigma"], P, sc.lap, sc.alpha)


def comparison(sc: CoestimationScenario, P_b_types: np.ndarray) -> ce.NetworkObserver:
    G = gains(sc)
    sig_b = np.array([sc.types[t].comparison_sigma for t in sc.node_type])
    P_b = np.stack([P_b_types[t] for t in sc.node_type])
    return ce.estimation_network(sc.A, sc.B, G["C"], G["L"], G["J"], G["K"], sig_b, P_b, sc.lap,
                                 sc.comparison_alpha, sc.gamma)


def role_law(sc: CoestimationScenario, fixed: bool):
    if fixed:
        return sim.FixedRoles(np.asarray(sc.fixed_active, float))
    if sc.role_mode == "fixed":
        return sim.FixedRoles(np.asarray(sc.roles_active, float))
    return sim.ProximityRoles(sc.positions, sc.radius, sc.beta, sc.position_states)


def run_deterministic(sc: CoestimationScenario, net: ce.NetworkObserver, roles, h: float) -> dict[str, np.ndarray]:
    every = int(round(sc.record_dt / h))
    tr = sim.simulate(net, roles, input_signal(sc), sc.x0, np.zeros((sc.N, sc.n + sc.p)), t_end=sc.t_end, h=h,
                      record_every=every, allow_nonfinite=True)
    return {"t": tr.t, "w": tr.w, "x": tr.x[0], "e": tr.e[0], "g": tr.g[0]}


def noise_model(sc: CoestimationScenario, seed: int) -> sim.NoiseModel:
    """v ~ U(0, v_range)^n (one scalar Brownian motion) and h_i ~ U(0, h_range)^m per node (Sec. 5.2)."""
    rng = np.random.default_rng(stream_seed(seed, "tran", "noise-intensities"))
    v = rng.uniform(0.0, sc.process_range, size=sc.n)
    h = rng.uniform(0.0, sc.measurement_range, size=(sc.N, sc.m))
    return sim.NoiseModel(v[:, None], h[:, :, None])


def _sde_reducer(sc: CoestimationScenario, P: np.ndarray, probes: dict | None = None):
    """Per-trial V = Σ_i z_iᵀ P_i z_i, ‖z‖, mean ‖x − x̂_i‖, mean ‖ŵ_i − w‖ and the active count; with
    `probes` ({record index: directions (k, Nq)}) also the projections uᵀz of every trial there.

    Called every recorded step on every trial (it was a fifth of the stochastic stage): V as one
    product with blkdiag(P_i), the norms from one array of squares."""
    Pbig = ce.block_diag(list(P))
    probes = probes or {}

    def reduce(t, x, w, e, g):
        z = ce.errors_from_estimates(x, w, e, sc.n)
        R = len(z)
        zf = z.reshape(R, -1)
        V = np.einsum("ri,ri->r", zf @ Pbig, zf)
        sq = np.square(z)
        nx = np.sqrt(sq[..., :sc.n].sum(-1)).mean(-1)
        nw = np.sqrt(sq[..., sc.n:].sum(-1)).mean(-1)
        out = {"V": V, "znorm": np.sqrt(sq.reshape(R, -1).sum(-1)), "xerr": nx, "werr": nw,
               "n_active": (g > 0.5).sum(-1)}
        k = int(round(t / sc.record_dt))
        if k in probes:
            out["proj"] = zf @ probes[k].T
        return out
    return reduce


def run_stochastic(sc: CoestimationScenario, P: np.ndarray, *, fixed: bool, trials: int, seed: int, t_end: float,
                   keep: int, h: float | None = None, probes: dict | None = None) -> dict[str, np.ndarray]:
    """All trials in seeded blocks of SDE_BLOCK; the first `keep` trials are stored in full."""
    net = coestimation(sc, P)
    noise = noise_model(sc, seed)
    h = sc.sde_step if h is None else h
    every = int(round(sc.record_dt / h))
    prepared = sim.prepare(net, h, noise)
    kept: list = []

    def block(size: int, rng: np.random.Generator):
        k = max(0, keep - sum(len(b["x"]) for b in kept))
        tr = sim.simulate(net, role_law(sc, fixed), input_signal(sc), sc.x0, np.zeros((sc.N, sc.n + sc.p)),
                          t_end=t_end, h=h, record_every=every, n_trials=size, noise=noise, rng=rng,
                          keep=k, reducer=_sde_reducer(sc, P, probes), prepared=prepared, allow_nonfinite=True)
        if k:
            kept.append({"x": tr.x, "e": tr.e, "g": tr.g})
        return tr

    def combine(parts):
        red = {name: np.concatenate([p.reduced[name] for p in parts], axis=1) for name in parts[0].reduced}
        out = {f"red_{k}": v for k, v in red.items()}
        out.update(t=parts[0].t, w=parts[0].w, v=noise.process, h=noise.measurement)
        for name in ("x", "e", "g"):
            out[f"kept_{name}"] = np.concatenate([b[name] for b in kept]) if kept else np.zeros((0,))
        if probes:
            out["probe_index"] = np.array(sorted(probes))
        return out

    label = ("fixed" if fixed else "roles", h)
    return run_blocks(block, combine, trials, stream_seed(seed, "tran", "sde", label), block=SDE_BLOCK)


def noise_input_matrix(sc: CoestimationScenario, noise: sim.NoiseModel, g) -> np.ndarray:
    """G = [1_N ⊗ v̄, blockdiag(r_i)], r_i = g_i [−L_i h_i; J_i h_i] ((44)-(45) with dimensions fixed)."""
    N, q = sc.N, sc.n + sc.p
    LJ = gains(sc)
    vbar = np.concatenate([noise.process[:, 0], np.zeros(sc.p)])
    Gm = np.zeros((N * q, 1 + N))
    Gm[:, 0] = np.tile(vbar, N)
    for i in range(N):
        hi = noise.measurement[i, :, 0]
        Gm[i * q:(i + 1) * q, 1 + i] = g[i] * np.concatenate([-LJ["L"][i] @ hi, LJ["J"][i] @ hi])
    return Gm


def check_indices(sc: CoestimationScenario, t_sde: float) -> np.ndarray:
    """Record indices (t > 0) at which the fixed-role Monte Carlo is compared with the exact law."""
    last = int(round(t_sde / sc.record_dt))
    stride = max(1, int(np.ceil(last / MAX_CHECK_TIMES)))
    return np.arange(stride, last + 1, stride)


def error_map(sc: CoestimationScenario) -> np.ndarray:
    """Z with z = Z u + (terms in w): z_i = [x − x̂_i; ŵ_i − w] from u = [x; e_1; …; e_N]."""
    n, p, N = sc.n, sc.p, sc.N
    q = n + p
    Z = np.zeros((N * q, n + N * q))
    for i in range(N):
        Z[i * q:i * q + n, :n] = np.eye(n)
        Z[i * q:i * q + n, n + i * q:n + i * q + n] = -np.eye(n)
        Z[i * q + n:(i + 1) * q, n + i * q + n:n + (i + 1) * q] = np.eye(p)
    return Z


def simulated_error_covariance(sc: CoestimationScenario, P: np.ndarray, noise: sim.NoiseModel, h: float,
                               idx: np.ndarray) -> np.ndarray:
    """The exact covariance of the simulated fixed-role error at the record indices `idx` (an arithmetic
    sequence from its step): the recursion u⁺ = Φu + κ, κ ~ N(0, Q) of `sim.linear_gaussian_step`,
    composed over the record step and over the stride between checks (positive semidefinite sums only)."""
    net = coestimation(sc, P)
    Phi, Q = sim.linear_gaussian_step(net, sim.prepare(net, h, noise), np.asarray(sc.fixed_active, float))

    def compose(Phi, Q, k):
        Pk, Qk = np.eye(len(Phi)), np.zeros_like(Q)
        for _ in range(k):
            Qk = Phi @ Qk @ Phi.T + Q
            Pk = Phi @ Pk
        return Pk, (Qk + Qk.T) / 2
    with np.errstate(over="ignore", invalid="ignore"):
        Phi, Q = compose(Phi, Q, int(round(sc.record_dt / h)))
        Phi, Q = compose(Phi, Q, int(idx[0]))
        Z = error_map(sc)
        out, Sig = [], np.zeros_like(Q)
        for _ in idx:
            Sig = Phi @ Sig @ Phi.T + Q
            out.append(Z @ Sig @ Z.T)
    return np.array(out)


def exact_fixed_moments(sc: CoestimationScenario, design, means: dict[str, dict], noise: sim.NoiseModel,
                        idx: np.ndarray) -> dict[str, np.ndarray]:
    """The exact law of the fixed-role error: z(t) ~ N(m(t), Σ(t)), Σ̇ = SΣ + ΣSᵀ + GGᵀ, Σ(0) = 0 ((45), (60)).

    E{V(t)} = m(t)ᵀPm(t) + tr(PΣ(t)) at every record time, with m the noise-free error of the run at
    the simulation's own step (`means['h']`; the SDE step is the same recursion plus zero-mean
    kicks, so this is its exact mean). At the check times `idx`: the principal directions u_j = P^{1/2}v_j
    of P^{1/2}ΣP^{1/2} (v_j its eigenvectors, λ_j = var(u_jᵀz) its largest eigenvalues, Σ_j λ_j = tr(PΣ)),
    and the means u_jᵀm for the run at h and at h/2; the variances var(u_jᵀz) of the simulated recursion at h
    and h/2 (the law the Monte Carlo has exactly, `simulated_error_covariance`)."""
    P, S = design["P"], design["S_fixed"]
    n = sc.n
    Gm = noise_input_matrix(sc, noise, np.asarray(sc.fixed_active))
    det = means["h"]
    t = det["t"]
    trace, Sig = lb.noise_covariance_traces(S, Gm, sc.record_dt, len(t) - 1, ce.block_diag(list(P)), idx)
    zf = {k: ce.errors_from_estimates(r["x"], r["w"], r["e"], n).reshape(len(r["t"]), -1) for k, r in means.items()}
    Pbig = ce.block_diag(list(P))
    EV = np.einsum("ti,ij,tj->t", zf["h"], Pbig, zf["h"]) + trace
    # P^{1/2} block by block
    root = ce.block_diag([(U * np.sqrt(np.maximum(w, 0))) @ U.T for w, U in (np.linalg.eigh(Pi) for Pi in P)])
    dirs, lam = [], []
    for S_k in Sig:
        if not np.all(np.isfinite(S_k)):   # an unstable S overflows: no law to compare with
            dirs.append(np.full((N_DIRECTIONS, len(S_k)), np.nan))
            lam.append(np.full(N_DIRECTIONS, np.nan))
            continue
        w, V = np.linalg.eigh(root @ S_k @ root)
        order = np.argsort(w)[::-1][:N_DIRECTIONS]
        # directions below the numerical rank of Σ (λ_j ≤ 1e-8 λ_1: eigh's relative error there is eps·λ_1/λ_j)
        # carry round-off, not noise: not tested
        lost = w[order] <= 1e-8 * max(w[order[0]], 0.0)
        lam.append(np.where(lost, 0.0, w[order]))
        dirs.append(np.where(lost[:, None], np.nan, (root @ V[:, order]).T))
    dirs, lam = np.array(dirs), np.array(lam)
    mean_proj = {k: np.einsum("ckd,cd->ck", dirs, z[idx]) for k, z in zf.items() if len(z) > idx.max()}
    sim_var = {}
    for k, h in (("h", sc.sde_step), ("half", sc.sde_step / 2)):
        Sz = simulated_error_covariance(sc, P, noise, h, idx)
        sim_var[k] = np.einsum("ckd,cde,cke->ck", dirs, Sz, dirs)
    r_fixed = max(np.linalg.norm(Gm[:, 1 + i]) for i in range(sc.N))
    r_any = max(np.linalg.norm(noise_input_matrix(sc, noise, np.ones(sc.N))[:, 1 + i]) for i in range(sc.N))
    return {"EV": EV, "t": t, "v_star": np.array(np.linalg.norm(noise.process)), "r_star": np.array(r_fixed),
            "r_star_roles": np.array(r_any), "h_star": np.array(np.linalg.norm(noise.measurement[:, :, 0], axis=1).max()),
            "tr_PSigma": trace, "probe_index": idx, "probe_dirs": dirs, "probe_var": lam,
            **{f"mean_proj_{k}": v for k, v in mean_proj.items()}, **{f"sim_var_{k}": v for k, v in sim_var.items()}}


def _sde_job(cache, key, sc, P, trials, seed, t_ends, probes, job):
    name, fixed, h = job
    t_end = t_ends[name]
    pr = probes.get(name)
    return cache.get_or_compute(name, {**key, "t_end": t_end},
                                lambda: run_stochastic(sc, P, fixed=fixed, trials=trials, seed=seed, t_end=t_end,
                                                       keep=sc.runs, h=h, probes=pr),
                                scenario=sc.name, allow_nonfinite=RUN_MAY_BE_NAN)


def compute(sc: CoestimationScenario, opts: RunOptions, cache: StageCache, *, paper: bool = True) -> Results:
    trials = trial_count(sc, opts)
    code = code_fingerprint(CODE_MODULES)
    base = {"scenario": sc.key(), "code": code}
    design = cache.get_or_compute("design", {**base, "quick": opts.quick, "extras": paper},
                                  lambda: compute_design(sc, opts.quick, extras=paper),
                                  scenario=sc.name, allow_nonfinite=DESIGN_MAY_BE_NAN)
    P = design["P"]
    res = Results(sc, opts.seed, trials, opts.quick, design)
    tv_roles = role_law(sc, fixed=False)
    fixed_roles = role_law(sc, fixed=True)
    jobs = {
        "coest": lambda: run_deterministic(sc, coestimation(sc, P), tv_roles, sc.step),
        "coest_half": lambda: run_deterministic(sc, coestimation(sc, P), tv_roles, sc.step / 2),
        "fixed": lambda: run_deterministic(sc, coestimation(sc, P), fixed_roles, sc.step),
        "fixed_half": lambda: run_deterministic(sc, coestimation(sc, P), fixed_roles, sc.step / 2),
        "comparison": lambda: run_deterministic(sc, comparison(sc, design["P_comparison"]), tv_roles, sc.step),
    }
    if sc.sde_step != sc.step:   # the exact mean of the fixed-role SDE is the noise-free run at its own step
        jobs["fixed_sde"] = lambda: run_deterministic(sc, coestimation(sc, P), fixed_roles, sc.sde_step)
        jobs["fixed_sde_half"] = lambda: run_deterministic(sc, coestimation(sc, P), fixed_roles, sc.sde_step / 2)
    for name, job in jobs.items():
        if name == "comparison" and not np.all(np.isfinite(design["P_comparison"])):
            continue
        res.runs[name] = cache.get_or_compute(f"det-{name}", base, job, scenario=sc.name, allow_nonfinite=RUN_MAY_BE_NAN)
    t_sde = sc.quick_t_end if opts.quick else sc.t_end
    t_half = min(t_sde, sc.quick_t_end)
    noise = noise_model(sc, opts.seed)
    idx = check_indices(sc, t_sde)
    means = {"h": res.runs["fixed" if sc.sde_step == sc.step else "fixed_sde"],
             "half": res.runs["fixed_half" if sc.sde_step == sc.step else "fixed_sde_half"]}
    res.runs["exact_fixed"] = cache.get_or_compute(
        "exact-fixed", {**base, "seed": opts.seed, "t_sde": t_sde}, lambda: exact_fixed_moments(sc, design, means, noise, idx),
        scenario=sc.name, allow_nonfinite=RUN_MAY_BE_NAN + tuple(f"mean_proj_{k}" for k in means) + tuple(f"sim_var_{k}" for k in means)
        + ("probe_dirs", "probe_var", "tr_PSigma"))
    ex = res.runs["exact_fixed"]
    probes = {"sde_fixed": {int(k): d for k, d in zip(ex["probe_index"], ex["probe_dirs"])},
              "sde_fixed_half": {int(k): d for k, d in zip(ex["probe_index"], ex["probe_dirs"])
                                 if k * sc.record_dt <= t_half + 1e-9}}
    sde_key = {**base, "seed": opts.seed, "trials": trials, "t_end": t_sde}
    sde_jobs = [("sde_roles", False, sc.sde_step), ("sde_fixed", True, sc.sde_step),
                ("sde_fixed_half", True, sc.sde_step / 2)]
    outs = parallel_map(functools.partial(_sde_job, cache, sde_key, sc, P, trials, opts.seed,
                                          {"sde_roles": t_sde, "sde_fixed": t_sde, "sde_fixed_half": t_half}, probes),
                        sde_jobs, workers=opts.workers, desc="tran: stochastic Monte Carlo")
    for (name, _, _), o in zip(sde_jobs, outs):
        res.runs[name] = o
    res.runs["central"] = cache.get_or_compute("central", {**base, "seed": opts.seed, "t_end": t_sde}, lambda: central_kalman(
        sc, res.runs["coest"], res.runs["sde_roles"], noise), scenario=sc.name, allow_nonfinite=RUN_MAY_BE_NAN)
    return res
