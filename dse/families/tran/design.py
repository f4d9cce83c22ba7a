"""The deterministic design stage of the coestimation family: everything the theorems are made of
that needs no simulation, so that `dse check` reports it and the hypotheses are decided on it.

Seed-free (one cached stage): the vertex LMIs (28)-(29) per node type with status, margin and
certificate; the P_i used and where they come from (given, LMI, or the Lyapunov equation (10) with
the scenario's Q_i); per-node certified margins and the Lemma 3.1 sweep; the comparison LMIs
(38)-(39); the certified input bounds w̄ with their brackets; φ̄; the Q̄ variants and the ultimate
bounds (18); q* over the role vertices; the fixed-role Q_i, Q̄, S and the identity (54); the spectra
of S at the all-passive, all-active and fixed roles and at random roles; observability ranks.

Per seed (a second cached stage): the noise intensities of the stochastic runs and the exact law of
the fixed-role error (60) at the check times (principal directions, the variances of (60) and of the
simulated recursion at h and h/2), the exact covariances at the end of the stochastic horizon and in
the steady state, and the centralized Kalman-Bucy reference.
"""
from __future__ import annotations

import functools
from dataclasses import dataclass, field
from typing import Any

import numpy as np

import dse.estimators.common_lyapunov as cl
import dse.estimators.input_state_coestimation as ce
import dse.estimators.lyapunov_bounds as lb
import dse.estimators.observer_network_simulation as sim
from dse.simulate.seeding import stream_seed
from dse.verify.rules import roundoff_tolerance

from .scenario import CoestimationScenario

J_SWEEP = (1.0, 2.0, 5.0, 10.0, 25.0, 50.0)
G_SWEEP = np.linspace(0.0, 1.0, 101)
N_RANDOM_G = 20
MAX_CHECK_TIMES = 20       # times at which the fixed-role Monte Carlo is compared with the exact law
N_DIRECTIONS = 3           # principal directions of E{zᵀPz} tested at each of those times
#: vertex enumerations over {0,1}^N (q*, Thm 3.1) are done up to this many nodes (quick: QUICK_VERTEX_NODES)
VERTEX_NODES = 14
QUICK_VERTEX_NODES = 10
# design quantities that are legitimately undefined in some scenarios (no vertex enumeration for large N,
# an infeasible LMI, a bound with λ_min(Q̄) ≤ 0, extras computed for the paper's example only)
DESIGN_MAY_BE_NAN = ("qstar", "mu_qstar", "bound18_qstar", "thm31_vertex_max", "thm31_vertex_tol", "comp_sigma_min",
                     "P_comparison", "P_lmi", "lmi_margin", "lmi_verified", "comp_margin", "comp_margin_b",
                     "J_sweep_margin", "mu_single", "bound18_single", "mu_pernode", "bound18_pernode", "mu_certified",
                     "bound18_certified", "fixed_mu", "fixed_bound18", "bound18_single_tight_phi", "S_max_real",
                     "S_tol", "S_min_real", "S_fixed_cond", "lmi_hurwitz_sweep", "given_sweep", "given_hurwitz",
                     "w_period", "S_eig_real", "S_eig_imag", "S_all_passive", "S_all_active", "S_fixed")
LAW_MAY_BE_NAN = ("probe_dirs", "probe_var", "tr_PSigma", "sim_var_h", "sim_var_half", "Sigma_final", "Sigma_steady",
                  "kb_final", "kb_steady", "steady_ok")


@dataclass
class Design:
    """The design of one scenario: `arrays` (seed-free), `law` (the noise draws of the seed and the exact
    law of the fixed-role error) and, once the deterministic runs exist, `integration` (their step-halving
    error estimates; None in `dse check`). Indexing reads `arrays`."""

    scenario: CoestimationScenario
    quick: bool
    seed: int
    arrays: dict[str, np.ndarray]
    law: dict[str, np.ndarray]
    integration: dict[str, dict[str, float]] | None = field(default=None)

    def __getitem__(self, name: str) -> np.ndarray:
        return self.arrays[name]

    def __contains__(self, name: str) -> bool:
        return name in self.arrays

    @property
    def P(self) -> np.ndarray:
        return self.arrays["P"]

    @property
    def noise(self) -> sim.NoiseModel:
        return sim.NoiseModel(self.law["v"][:, None], self.law["h"][:, :, None])


def input_signal(sc: CoestimationScenario) -> sim.SinusoidalInput:
    return sim.SinusoidalInput(sc.w_offset, sc.w_amplitude, sc.w_frequency, sc.w_phase)


def t_stochastic(sc: CoestimationScenario, quick: bool) -> float:
    """Horizon of the stochastic runs."""
    return sc.quick_t_end if quick else sc.t_end


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


def obsv(A: np.ndarray, C: np.ndarray) -> np.ndarray:
    """The observability matrix [C; CA; …; CAⁿ⁻¹] (as python-control's `obsv`, without importing it)."""
    blocks = [np.asarray(C, float)]
    for _ in range(1, A.shape[0]):
        blocks.append(blocks[-1] @ A)
    return np.vstack(blocks)


def _lyapunov_rounding(A: np.ndarray, P: np.ndarray) -> float:
    """Round-off allowance of an eigenvalue of AᵀP + PA: products of length d with inputs of size
    ‖|A|ᵀ|P|‖₂, then a symmetric eigenvalue problem of size d (backward stable)."""
    d = A.shape[0]
    return roundoff_tolerance(scale=2 * np.linalg.norm(np.abs(A).T @ np.abs(P), 2), operations=2 * d)[0]


# -- design stage ---------------------------------------------------------------------------------

def _comparison_blocks(sc: CoestimationScenario, t: int, sigma: float):
    """The affine maps P ↦ R_i(g)(P) of (38) (g = 0) and (39) (g = 1) for node type t at σ."""
    ty = sc.types[t]
    return [functools.partial(ce.comparison_lmi_matrix, A=sc.A, B=sc.B, C_i=ty.C, L_i=ty.L, J_i=ty.J, sigma_i=sigma,
                              K_i=ty.K, g=g) for g in (0.0, 1.0)]


def _min_feasible_sigma(sc: CoestimationScenario, t: int, lo: float, hi: float, iters: int) -> float:
    """Bisection on σ for the smallest σ with (38)-(39) feasible (normalised margin ≥ 0); nan if
    infeasible at `hi`."""
    def ok(s):
        r = cl.affine_lmi(_comparison_blocks(sc, t, s), sc.n, lower=sc.comparison_P_lower, feasibility=False)
        return np.isfinite(r.margin) and r.margin >= 0
    if not ok(hi):
        return float("nan")
    for _ in range(iters):
        mid = np.sqrt(lo * hi)
        lo, hi = (lo, mid) if ok(mid) else (mid, hi)
    return float(hi)


def _solve_vertex_lmis(sc: CoestimationScenario) -> dict[str, np.ndarray]:
    """(28)-(29) per node type with Clarabel (status, normalised margin t*, its numpy
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
    verified margin is below 1.1 ε_i (the LMIs are homogeneous in (P, ε)). lyapunov: (10) with the
    node type's Q_i at the fixed roles. A design that yields no positive definite P (an infeasible
    LMI, an unstable Ā_i in (10)) runs with P_i = I so that the run still reports; the hypotheses
    then say that the theorems do not apply."""
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
                X = solve_continuous_lyapunov(Ab.T, -ty.Q)
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


def stacked_S(sc: CoestimationScenario, P: np.ndarray, g) -> np.ndarray:
    """S(g) = Ā(g) − αH(L ⊗ I) of (33) with the gains of the scenario."""
    G = gains(sc)
    return ce.stacked_error_matrix(sc.A, sc.B, G["C"], G["L"], G["J"], G["K"], G["sigma"], P, sc.lap, sc.alpha, g)


def _s_cells(sc: CoestimationScenario, P: np.ndarray, g_list):
    """Per g: max Re λ(S(g)), its round-off allowance (Bauer-Fike: cond(V)·‖S‖₂ times the backward
    error of the eigenvalue solver), min Re λ, cond(V) (V the eigenvectors) and the eigenvalues."""
    mx, tol, mn, cond, eigs = [], [], [], [], []
    for g in g_list:
        S = stacked_S(sc, P, g)
        w, V = np.linalg.eig(S)
        eigs.append(w[np.lexsort((w.imag, w.real))])
        mx.append(w.real.max())
        mn.append(w.real.min())
        cond.append(np.linalg.cond(V))
        tol.append(roundoff_tolerance(scale=np.linalg.norm(S, 2), operations=S.shape[0], condition=cond[-1])[0])
    return np.array(mx), np.array(tol), np.array(mn), np.array(cond), np.array(eigs)


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


def compute_design(sc: CoestimationScenario, quick: bool, extras: bool = True, workers: int = 1) -> dict[str, np.ndarray]:
    """Everything that needs no simulation. `extras`: the computations only claims about the paper's
    own example use (the comparison LMIs at the coestimation σ, the smallest feasible σ, the J
    sweep), skipped for users' scenarios. The parts independent of each other (`design_parts`) run in
    `workers` forked processes."""
    from dse.simulate.units import run_jobs

    core = design_core(sc)
    parts = design_parts(sc, quick, extras, core)
    return merge_design(core, dict(zip(parts, run_jobs(list(parts.values()), workers))))


def design_parts(sc: CoestimationScenario, quick: bool, extras: bool, core: dict[str, np.ndarray]) -> dict[str, tuple]:
    """The parts of the design that only the claims use, each (estimated CPU seconds, callable returning arrays):
    the vertex enumerations of q* and Thm 3.1 over {0,1}^N, and the paper's extras."""
    from .cost import EXTRAS_TYPE_S, VERTEX_CUBE_S

    max_nodes = QUICK_VERTEX_NODES if quick else VERTEX_NODES
    enumeration = 2 ** sc.N * VERTEX_CUBE_S * (sc.N * sc.q) ** 3 if sc.N <= max_nodes else 0.0
    parts = {"qstar": (enumeration, lambda: _qstar(sc, core["P"], max_nodes)),
             "thm31": (enumeration, lambda: _thm31_part(sc, core, max_nodes))}
    if extras:
        parts["extras"] = (EXTRAS_TYPE_S * len(sc.types), lambda: _paper_extras(sc, quick))
    return parts


def _qstar(sc: CoestimationScenario, P: np.ndarray, max_nodes: int) -> dict[str, np.ndarray]:
    G = gains(sc)
    vd = lb.vertex_dissipation(sc.A, sc.B, G["C"], G["L"], G["J"], G["K"], G["sigma"], P, sc.lap, sc.alpha,
                               max_nodes=max_nodes)
    return {"qstar": np.asarray(np.nan if vd is None else vd[0]), "qstar_g": np.full(sc.N, -1) if vd is None else vd[1]}


def _thm31_part(sc: CoestimationScenario, core: dict[str, np.ndarray], max_nodes: int) -> dict[str, np.ndarray]:
    """Thm 3.1: S(g)ᵀP + PS(g) + Q̄_ε ≤ 0 at the vertices g ∈ {0,1}^N (single ε), largest eigenvalue."""
    top, ttol = _thm31_vertex_check(sc, core["P"], np.full(sc.N, core["eps_nodes"].min()), max_nodes=max_nodes)
    return {"thm31_vertex_max": np.asarray(top), "thm31_vertex_tol": np.asarray(ttol)}


def _paper_extras(sc: CoestimationScenario, quick: bool) -> dict[str, np.ndarray]:
    """The comparison LMIs at the coestimation σ, the smallest feasible σ, the J sweep."""
    n, T = sc.n, len(sc.types)
    cstat, cmargin, sig_min = [], [], []
    for t, ty in enumerate(sc.types):
        r0 = cl.affine_lmi(_comparison_blocks(sc, t, ty.sigma), n, lower=sc.comparison_P_lower)
        cstat.append(r0.status)
        cmargin.append(r0.margin)
        sig_min.append(_min_feasible_sigma(sc, t, ty.sigma, max(10.0, 10 * ty.comparison_sigma), 6 if quick else 10))
    jm = np.array([[cl.common_lyapunov(vertices(sc, t, s), sc.types[t].eps, feasibility=False).margin for s in J_SWEEP]
                   for t in range(T)])
    return {"comp_status": np.array(cstat), "comp_margin": np.array(cmargin, float), "comp_sigma_min": np.array(sig_min),
            "J_sweep": np.array(J_SWEEP), "J_sweep_margin": jm}


def merge_design(core: dict[str, np.ndarray], parts: dict[str, dict[str, np.ndarray]]) -> dict[str, np.ndarray]:
    """The design: the core, its parts, and the bound (18) with q*."""
    out = dict(core)
    for part in parts.values():
        out.update(part)
    qmin = float(out["qstar"])
    mu, bound = ultimate_bound_or_nan(out["P"], qmin, float(out["phibar"]))
    out["mu_qstar"], out["bound18_qstar"] = np.asarray(mu), np.asarray(bound)
    return out


def ultimate_bound_or_nan(P: np.ndarray, qmin: float, phibar: float) -> tuple[float, float]:
    """(μ, (18)) with λ_min(Q̄) = qmin; NaN when it is not a positive number."""
    return lb.ultimate_bound(P, qmin, phibar) if np.isfinite(qmin) and qmin > 0 else (np.nan, np.nan)


def design_core(sc: CoestimationScenario) -> dict[str, np.ndarray]:
    """The design without `design_parts`: everything the runs need (P, the comparison architecture's P, S) and
    every quantity that is cheap."""
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
    out.update(lamP_min=lamP.min(), lamP_max=lamP.max(), qbar_single=ev_single[0], qbar_single_norm=ev_single[-1],
               qbar_pernode=qb_pernode, qbar_certified=qb_cert)
    for name, qmin in (("single", ev_single[0]), ("pernode", qb_pernode), ("certified", qb_cert)):
        out[f"mu_{name}"], out[f"bound18_{name}"] = ultimate_bound_or_nan(P, qmin, phibar)
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
    out.update(fixed_Q=np.stack([-(A_.T @ P[i] + P[i] @ A_) for i, A_ in enumerate(Abars)]), fixed_g=gfix,
               fixed_Qi_min=Qi_min, fixed_Qi_tol=Qi_tol, fixed_qbar_min=qf_min, fixed_qbar_norm=ev_fixed[-1],
               fixed_mu=mu_f, fixed_bound18=b_f, identity54_residual=np.abs(res54).max(),
               identity54_scale=np.abs(Qbar_fixed).max(), identity54_tol=tol54, S_fixed=S_fixed)
    # S(g) Hurwitz: all-passive, all-active, the fixed roles and random g
    rng = np.random.default_rng(12345)
    g_list = [np.zeros(N), np.ones(N), gfix] + [rng.uniform(size=N) for _ in range(N_RANDOM_G)]
    mx, tol, mn, cond, eigs = _s_cells(sc, P, g_list)
    out.update(S_max_real=mx, S_tol=tol, S_min_real=mn[:2], S_fixed_cond=cond[2], S_cond=cond, S_g=np.array(g_list),
               S_eig_real=eigs.real, S_eig_imag=eigs.imag, S_all_passive=stacked_S(sc, P, np.zeros(N)),
               S_all_active=stacked_S(sc, P, np.ones(N)))
    # observability facts
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




# -- per seed: the noise and the exact law of the fixed-role error -------------------------------------

def coestimation(sc: CoestimationScenario, P: np.ndarray) -> ce.NetworkObserver:
    G = gains(sc)
    return ce.coestimation_network(sc.A, sc.B, G["C"], G["L"], G["J"], G["K"], G["sigma"], P, sc.lap, sc.alpha)


#: step operators (φ-functions and exact noise factors) of the last few (network, noise, step) triples: the
#: exact law and the Monte Carlo at the same step share them (forked workers inherit them)
_STEP_OPERATORS: dict[tuple, sim.Prepared] = {}


def step_operators(sc: CoestimationScenario, P: np.ndarray, noise: sim.NoiseModel, h: float) -> sim.Prepared:
    """`sim.prepare` of the coestimation network with these P_i, noise and step, computed once per process."""
    key = (sc.name, repr(sc.key()), P.tobytes(), noise.process.tobytes(), noise.measurement.tobytes(), float(h))
    if key not in _STEP_OPERATORS:
        while len(_STEP_OPERATORS) >= 4:
            _STEP_OPERATORS.pop(next(iter(_STEP_OPERATORS)))
        _STEP_OPERATORS[key] = sim.prepare(coestimation(sc, P), h, noise)
    return _STEP_OPERATORS[key]


def noise_model(sc: CoestimationScenario, seed: int) -> sim.NoiseModel:
    """v ~ U(0, v_range)^n (one scalar Brownian motion) and h_i ~ U(0, h_range)^m per node (Sec. 5.2)."""
    rng = np.random.default_rng(stream_seed(seed, "tran", "noise-intensities"))
    v = rng.uniform(0.0, sc.process_range, size=sc.n)
    h = rng.uniform(0.0, sc.measurement_range, size=(sc.N, sc.m))
    return sim.NoiseModel(v[:, None], h[:, :, None])


def noise_input_matrix(sc: CoestimationScenario, noise: sim.NoiseModel, g) -> np.ndarray:
    """G = [1_N ⊗ v̄, blockdiag(r_i)], r_i = g_i [−L_i h_i; J_i h_i] ((44)-(45) with dimensions fixed)."""
    N, q = sc.N, sc.q
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


def _power_sum(Phi: np.ndarray, Q: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """(Φᵏ, Σ_{j<k} Φʲ Q Φʲᵀ) by binary doubling: the k-step composition of u⁺ = Φu + κ, κ ~ N(0, Q)
    (only positive semidefinite sums, O(log k) products)."""
    D = len(Phi)
    P_acc, Q_acc = np.eye(D), np.zeros_like(Q)
    P_pow, Q_pow = Phi, Q                      # the 2^j-step composition
    while k:
        if k & 1:                              # append 2^j steps after the accumulated ones
            Q_acc = P_pow @ Q_acc @ P_pow.T + Q_pow
            P_acc = P_pow @ P_acc
        k >>= 1
        if k:
            Q_pow = P_pow @ Q_pow @ P_pow.T + Q_pow
            P_pow = P_pow @ P_pow
    return P_acc, (Q_acc + Q_acc.T) / 2


def simulated_error_covariance(sc: CoestimationScenario, P: np.ndarray, noise: sim.NoiseModel, h: float,
                               idx: np.ndarray) -> np.ndarray:
    """The exact covariance of the simulated fixed-role error at the record indices `idx` (an arithmetic
    sequence from its step): the recursion u⁺ = Φu + κ, κ ~ N(0, Q) of `sim.linear_gaussian_step`,
    composed over the record step and over the stride between checks (positive semidefinite sums only)."""
    net = coestimation(sc, P)
    Phi, Q = sim.linear_gaussian_step(net, step_operators(sc, P, noise, h), np.asarray(sc.fixed_active, float))
    with np.errstate(over="ignore", invalid="ignore"):
        Phi, Q = _power_sum(Phi, Q, int(round(sc.record_dt / h)))
        Phi, Q = _power_sum(Phi, Q, int(idx[0]))
        Z = error_map(sc)
        out, Sig = [], np.zeros_like(Q)
        for _ in idx:
            Sig = Phi @ Sig @ Phi.T + Q
            out.append(Z @ Sig @ Z.T)
    return np.array(out)


def _node_blocks(M: np.ndarray, N: int, q: int) -> np.ndarray:
    return np.stack([M[i * q:(i + 1) * q, i * q:(i + 1) * q] for i in range(N)])


def fixed_law(sc: CoestimationScenario, arrays: dict[str, np.ndarray], seed: int, quick: bool) -> dict[str, np.ndarray]:
    """The noise of the seed and the exact law of the fixed-role error z(t) ~ N(m(t), Σ(t)),
    Σ̇ = SΣ + ΣSᵀ + GGᵀ, Σ(0) = 0 ((45), (60)); m is the noise-free run (a simulation, not here).

    tr(PΣ) at every record time of the stochastic horizon; Σ at its end and (S Hurwitz) in the steady
    state, per node block; at the check times the principal directions u_j = P^{1/2}v_j of P^{1/2}ΣP^{1/2}
    (v_j its eigenvectors, λ_j = var(u_jᵀz) its largest eigenvalues, Σ_j λ_j = tr(PΣ)) and the variances
    var(u_jᵀz) of the simulated recursion at h and h/2 (the law the Monte Carlo has exactly); the bounds v*,
    h*, r* of Prop 4.1; the centralized Kalman-Bucy reference of x at the fixed roles."""
    from scipy.linalg import solve_continuous_lyapunov

    from .central_reference import kalman_bucy_reference

    noise = noise_model(sc, seed)
    P, S = arrays["P"], arrays["S_fixed"]
    N, q = sc.N, sc.q
    t_sde = t_stochastic(sc, quick)
    last = int(round(t_sde / sc.record_dt))
    idx = check_indices(sc, t_sde)
    gfix = np.asarray(sc.fixed_active, float)
    Gm = noise_input_matrix(sc, noise, gfix)
    keep = sorted(set(int(k) for k in idx) | {last})
    trace, Sig = lb.noise_covariance_traces(S, Gm, sc.record_dt, last, ce.block_diag(list(P)), keep)
    at = {k: Sig[j] for j, k in enumerate(keep)}
    stable = bool(np.all(np.isfinite(S))) and float(np.linalg.eigvals(S).real.max()) < 0
    with np.errstate(over="ignore", invalid="ignore"):
        steady = solve_continuous_lyapunov(S, -Gm @ Gm.T) if stable else np.full_like(S, np.nan)
    # P^{1/2} block by block
    root = ce.block_diag([(U * np.sqrt(np.maximum(w, 0))) @ U.T for w, U in (np.linalg.eigh(Pi) for Pi in P)])
    dirs, lam = [], []
    for k in idx:
        S_k = at[int(k)]
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
    sim_var = {}
    for label, h in (("h", sc.sde_step), ("half", sc.sde_step / 2)):
        Sz = simulated_error_covariance(sc, P, noise, h, idx)
        sim_var[label] = np.einsum("ckd,cde,cke->ck", dirs, Sz, dirs)
    r_fixed = max(np.linalg.norm(Gm[:, 1 + i]) for i in range(N))
    r_any = max(np.linalg.norm(noise_input_matrix(sc, noise, np.ones(N))[:, 1 + i]) for i in range(N))
    kb_steady, kb_final = kalman_bucy_reference(sc, noise, gfix, t_sde)
    return {"v": noise.process[:, 0], "h": noise.measurement[:, :, 0], "v_star": np.array(np.linalg.norm(noise.process)),
            "h_star": np.array(np.linalg.norm(noise.measurement[:, :, 0], axis=1).max()), "r_star": np.array(r_fixed),
            "r_star_roles": np.array(r_any), "t_sde": np.array(t_sde), "tr_PSigma": trace, "probe_index": idx,
            "probe_dirs": dirs, "probe_var": lam, "sim_var_h": sim_var["h"], "sim_var_half": sim_var["half"],
            "Sigma_final": _node_blocks(at[last], N, q), "Sigma_steady": _node_blocks(steady, N, q),
            "steady_ok": np.array(stable), "kb_steady": kb_steady, "kb_final": kb_final}


def mean_square_constants(d: Design, fixed: bool) -> dict[str, float]:
    """κ, η, ψ̄ and (52) of Prop 4.1 with λ_min(Q̄) of the fixed roles (Q̄ = Q + 2α(L⊗I)) or of the
    time-varying roles (Q̄_ε, single ε). r* = max_i ‖r_i‖ over the roles the run can take: the fixed g_i,
    or any g_i ∈ [0, 1] for time-varying roles (‖g_i[−L_ih_i; J_ih_i]‖ ≤ ‖[L_ih_i; J_ih_i]‖)."""
    qmin = float(d["fixed_qbar_min"]) if fixed else float(d["qbar_single"])
    r_star = float(d.law["r_star"]) if fixed else float(d.law["r_star_roles"])
    c = lb.mean_square_constants(d.P, qmin, float(d["phibar"]), float(d.law["v_star"]), r_star, d.scenario.N)
    return {**c, "qmin": qmin, "r_star": r_star}
