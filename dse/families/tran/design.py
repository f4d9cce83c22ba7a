"""The deterministic design stages of the coestimation family: everything the theorems are made of
that needs no simulation, so that `dse check` reports it and the hypotheses are decided on it.

`design_core` (the runs need it): the vertex LMIs (28)-(29) per node type with status, margin and
certificate; the P_i used and where they come from (given, LMI, or the Lyapunov equation (10) with
the scenario's Q_i); per-node certified margins and the Lemma 3.1 sweep; the comparison LMIs
(38)-(39); the certified input bounds w̄ with their brackets; φ̄; the Q̄ variants and the ultimate
bounds (18); the fixed-role Q_i, Q̄, S and the identity (54); the spectra of S at the
all-passive, all-active and fixed roles and at random roles; observability ranks. The parts only
the claims use, each a stage of its own (they run beside the simulations): q* and Thm 3.1 over
the role vertices {0,1}^N, and the paper's extras (the comparison LMIs at the coestimation σ, the
smallest feasible σ, the J sweep). The law of the seed is `law.py`.
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
from dse.contract.stages import stage
from dse.estimators.jointly_observable_design import observability_matrix as obsv
from dse.verify.rules import roundoff_tolerance

from .scenario import CoestimationFile

J_SWEEP = (1.0, 2.0, 5.0, 10.0, 25.0, 50.0)
G_SWEEP = np.linspace(0.0, 1.0, 101)
N_RANDOM_G = 20
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


@dataclass
class Design:
    """The design of one scenario: `arrays` (seed-free), `law` (the noise draws of the seed and the exact
    law of the fixed-role error) and, once the deterministic runs exist, `integration` (their step-halving
    error estimates; None in `dse check`). Indexing reads `arrays`."""

    scenario: CoestimationFile
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
        return noise_of(self.law)


def noise_of(law: dict[str, np.ndarray]) -> sim.NoiseModel:
    """The noise intensities v, h_i of the seed (the law stage's draws) as the simulator's noise model."""
    return sim.NoiseModel(law["v"][:, None], law["h"][:, :, None])


def input_signal(sc: CoestimationFile) -> sim.SinusoidalInput:
    inp = sc.input
    return sim.SinusoidalInput(inp.offset, inp.amplitude, inp.frequency, inp.phase)


def t_stochastic(sc: CoestimationFile, quick: bool) -> float:
    """Horizon of the stochastic runs."""
    return sc.stochastic.quick_t_end if quick else sc.simulation.t_end


def gains(sc: CoestimationFile) -> dict[str, np.ndarray]:
    return {k: sc.per_node(k) for k in ("C", "L", "J", "K", "sigma")}


def coestimation(sc: CoestimationFile, P: np.ndarray) -> ce.NetworkObserver:
    G = gains(sc)
    return ce.coestimation_network(sc.A, sc.B, G["C"], G["L"], G["J"], G["K"], G["sigma"], P, sc.lap, sc.coupling.alpha)


def vertices(sc: CoestimationFile, t: int, J_scale: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    ty = sc.types[t]
    return ce.error_vertices(sc.A, sc.B, ty.C, ty.L, J_scale * ty.J, ty.sigma, ty.K)


def error_matrix(sc: CoestimationFile, i: int, g: float) -> np.ndarray:
    """Ā_i(g) of (27) for node i."""
    ty = sc.types[sc.type_of[i]]
    return ce.error_matrix(sc.A, sc.B, ty.C, ty.L, ty.J, ty.sigma, ty.K, g)


def _lyapunov_rounding(A: np.ndarray, P: np.ndarray) -> float:
    """Round-off allowance of an eigenvalue of AᵀP + PA: products of length d with inputs of size
    ‖|A|ᵀ|P|‖₂, then a symmetric eigenvalue problem of size d (backward stable)."""
    d = A.shape[0]
    return roundoff_tolerance(scale=2 * np.linalg.norm(np.abs(A).T @ np.abs(P), 2), operations=2 * d)[0]


def stacked_S(sc: CoestimationFile, P: np.ndarray, g) -> np.ndarray:
    """S(g) = Ā(g) − αH(L ⊗ I) of (33) with the gains of the scenario."""
    G = gains(sc)
    return ce.stacked_error_matrix(sc.A, sc.B, G["C"], G["L"], G["J"], G["K"], G["sigma"], P, sc.lap, sc.coupling.alpha,
                                   g)


def ultimate_bound_or_nan(P: np.ndarray, qmin: float, phibar: float) -> tuple[float, float]:
    """(μ, (18)) with λ_min(Q̄) = qmin; NaN when it is not a positive number."""
    return lb.ultimate_bound(P, qmin, phibar) if np.isfinite(qmin) and qmin > 0 else (np.nan, np.nan)


# -- the LMIs and the P used ---------------------------------------------------------------------------

def _comparison_blocks(sc: CoestimationFile, t: int, sigma: float):
    """The affine maps P ↦ R_i(g)(P) of (38) (g = 0) and (39) (g = 1) for node type t at σ."""
    ty = sc.types[t]
    return [functools.partial(ce.comparison_lmi_matrix, A=sc.A, B=sc.B, C_i=ty.C, L_i=ty.L, J_i=ty.J, sigma_i=sigma,
                              K_i=ty.K, g=g) for g in (0.0, 1.0)]


def _min_feasible_sigma(sc: CoestimationFile, t: int, lo: float, hi: float, iters: int) -> float:
    """Bisection on σ for the smallest σ with (38)-(39) feasible (normalised margin ≥ 0); nan if
    infeasible at `hi`."""
    def ok(s):
        r = cl.affine_lmi(_comparison_blocks(sc, t, s), sc.n, lower=sc.comparison.P_lower, feasibility=False)
        return np.isfinite(r.margin) and r.margin >= 0
    if not ok(hi):
        return float("nan")
    for _ in range(iters):
        mid = np.sqrt(lo * hi)
        lo, hi = (lo, mid) if ok(mid) else (mid, hi)
    return float(hi)


def _solve_vertex_lmis(sc: CoestimationFile) -> dict[str, np.ndarray]:
    """(28)-(29) per node type with Clarabel (status, normalised margin t*, its numpy
    re-verification, the maximiser) and an eigenvalue certificate of infeasibility: the largest
    real part of Ā_i(g) over g ∈ [0, 1] (an unstable Ā_i(g) admits no P)."""
    T, q = len(sc.types), sc.q
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
    out = {"lmi_status": np.array(status), "lmi_margin": np.array(margin, float),
           "lmi_verified": np.array(verified, float), "lmi_margin_status": np.array(mstatus), "P_lmi": P_lmi,
           "lmi_hurwitz_sweep": hurwitz, "g_sweep": G_SWEEP}
    if all(ty.P is not None for ty in sc.types):
        out["P_given"] = np.stack([ty.P for ty in sc.types])
        sweep = np.zeros((T, len(G_SWEEP)))
        for t, ty in enumerate(sc.types):
            for k, g in enumerate(G_SWEEP):
                Ab = ce.error_matrix(sc.A, sc.B, ty.C, ty.L, ty.J, ty.sigma, ty.K, g)
                sweep[t, k] = np.linalg.eigvalsh(Ab.T @ ty.P + ty.P @ Ab).max()
        out["given_sweep"] = sweep
    return out


def _design_P(sc: CoestimationFile, P_lmi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The P_i the estimator uses (H_i = P_i⁻¹) and where each comes from.

    given: the scenario's P_i. lmi: the max-margin solution of (28)-(29), scaled up when its
    verified margin is below 1.1 ε_i (the LMIs are homogeneous in (P, ε)). lyapunov: (10) with the
    node type's Q_i at the fixed roles. A design that yields no positive definite P (an infeasible
    LMI, an unstable Ā_i in (10)) runs with P_i = I so that the run still reports; the hypotheses
    then say that the theorems do not apply."""
    N, q, mode = sc.N, sc.q, sc.coupling.P
    P = np.zeros((N, q, q))
    source = []
    for i in range(N):
        t = sc.type_of[i]
        ty = sc.types[t]
        cand, label = None, mode
        if mode == "given":
            cand = ty.P
        elif mode == "lmi":
            Pt = P_lmi[t]
            if np.all(np.isfinite(Pt)):
                cert = -cl.vertex_margin(vertices(sc, t), Pt)
                if cert > 0:
                    scale = max(1.0, 1.1 * ty.eps / cert)
                    cand, label = Pt * scale, "lmi" if scale == 1.0 else f"lmi (scaled by {scale:.3g})"
        else:
            from scipy.linalg import solve_continuous_lyapunov
            Ab = error_matrix(sc, i, sc.roles.active[i])
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


def _node_margins(sc: CoestimationFile, P: np.ndarray) -> dict[str, np.ndarray]:
    """(28)-(29) with the P used: certified per-node margins (numpy eigenvalues) and their round-off
    allowance; Lemma 3.1 on the g grid."""
    N = sc.N
    node_vertices = [vertices(sc, sc.type_of[i]) for i in range(N)]
    cert = np.array([-cl.vertex_margin(node_vertices[i], P[i]) for i in range(N)])
    cert_tol = np.array([max(_lyapunov_rounding(A_, P[i]) for A_ in node_vertices[i]) for i in range(N)])
    lemma = np.zeros((N, len(G_SWEEP)))
    lemma_tol = np.zeros(N)
    for i in range(N):
        for k, g in enumerate(G_SWEEP):
            Ab = error_matrix(sc, i, g)
            lemma[i, k] = np.linalg.eigvalsh(Ab.T @ P[i] + P[i] @ Ab).max()
            lemma_tol[i] = max(lemma_tol[i], _lyapunov_rounding(Ab, P[i]))
    return dict(certified_eps=cert, certified_tol=cert_tol, eps_nodes=np.array([sc.types[t].eps for t in sc.type_of]),
                lemma_sweep=lemma, lemma_tol=lemma_tol)


def _comparison_lmis(sc: CoestimationFile) -> dict[str, np.ndarray]:
    """(38)-(39) at the reconstructed σ_b (the comparison run's P)."""
    cstat_b, cmargin_b = [], []
    P_b_types = np.full((len(sc.types), sc.n, sc.n), np.nan)
    for t, ty in enumerate(sc.types):
        rb = cl.affine_lmi(_comparison_blocks(sc, t, ty.comparison_sigma), sc.n, lower=sc.comparison.P_lower)
        cstat_b.append(rb.status)
        cmargin_b.append(rb.margin)
        # an uncertified P would run the comparison architecture outside its theory: only a feasible one is used
        if rb.P is not None and np.isfinite(rb.margin) and rb.margin >= 0:
            P_b_types[t] = rb.P
    return dict(comp_status_b=np.array(cstat_b), comp_margin_b=np.array(cmargin_b, float), P_comparison=P_b_types)


def _bounds(sc: CoestimationFile, P: np.ndarray, cert: np.ndarray, eps_nodes: np.ndarray) -> dict[str, Any]:
    """The input bounds over all t ≥ 0 (certified, with their slack), φ̄, λ(P), the Q̄_ε variants and (18)."""
    G, lap, q, N = gains(sc), sc.lap, sc.q, sc.N
    bw, bd = input_signal(sc).sup_bounds()
    # the bounds use the certified upper ends; the suprema themselves are reported to round-off
    w_upper, wdot_upper = bw.upper, bd.upper
    wbar = max(w_upper, wdot_upper)
    phi_i, phibar = lb.forcing_bound(G["sigma"], G["K"], wbar, wbar)
    _, phibar_tight = lb.forcing_bound(G["sigma"], G["K"], w_upper, wdot_upper)
    out = dict(w_sup=bw.value, w_sup_lower=bw.lower, w_sup_upper=w_upper, wdot_sup=bd.value, wdot_sup_lower=bd.lower,
               wdot_sup_upper=wdot_upper, w_method=np.array(bw.method), w_period=bw.period, wbar=wbar, phibar_i=phi_i,
               phibar=phibar, phibar_tight=phibar_tight)
    lamP = np.concatenate([np.linalg.eigvalsh(Pi) for Pi in P])
    alpha = sc.coupling.alpha
    ev_single = np.linalg.eigvalsh(lb.qbar_eps(np.full(N, eps_nodes.min()), lap, alpha, q))
    qb_pernode = np.linalg.eigvalsh(lb.qbar_eps(eps_nodes, lap, alpha, q))[0]
    qb_cert = np.linalg.eigvalsh(lb.qbar_eps(np.maximum(cert, 0), lap, alpha, q))[0]
    out.update(lamP_min=lamP.min(), lamP_max=lamP.max(), qbar_single=ev_single[0], qbar_single_norm=ev_single[-1],
               qbar_pernode=qb_pernode, qbar_certified=qb_cert)
    for name, qmin in (("single", ev_single[0]), ("pernode", qb_pernode), ("certified", qb_cert)):
        out[f"mu_{name}"], out[f"bound18_{name}"] = ultimate_bound_or_nan(P, qmin, phibar)
    out["bound18_single_tight_phi"] = lb.ultimate_bound(P, ev_single[0], phibar_tight)[1]
    return out


def _fixed_roles(sc: CoestimationFile, P: np.ndarray, phibar: float) -> dict[str, Any]:
    """Fixed roles: Q_i from (10), Q̄, S and the identity (54)."""
    N, q, lap, alpha = sc.N, sc.q, sc.lap, sc.coupling.alpha
    gfix = np.asarray(sc.fixed_roles.active)
    Abars = [error_matrix(sc, i, gfix[i]) for i in range(N)]
    Qi_min = np.array([np.linalg.eigvalsh(-(A_.T @ P[i] + P[i] @ A_)).min() for i, A_ in enumerate(Abars)])
    Qi_tol = np.array([_lyapunov_rounding(A_, P[i]) for i, A_ in enumerate(Abars)])
    Qbar_fixed = lb.qbar_fixed(Abars, P, lap, alpha)
    S_fixed = stacked_S(sc, P, gfix)
    Pbig = ce.block_diag(list(P))
    res54 = S_fixed.T @ Pbig + Pbig @ S_fixed + Qbar_fixed
    ev_fixed = np.linalg.eigvalsh(Qbar_fixed)
    qf_min = ev_fixed[0]
    mu_f, b_f = lb.ultimate_bound(P, qf_min, phibar) if qf_min > 0 else (np.nan, np.nan)
    tol54 = roundoff_tolerance(scale=np.abs(np.abs(S_fixed).T @ np.abs(Pbig)).max() * 2 + np.abs(Qbar_fixed).max(),
                               operations=N * q, condition=max(np.linalg.cond(Pi) for Pi in P))[0]
    return dict(fixed_Q=np.stack([-(A_.T @ P[i] + P[i] @ A_) for i, A_ in enumerate(Abars)]), fixed_g=gfix,
                fixed_Qi_min=Qi_min, fixed_Qi_tol=Qi_tol, fixed_qbar_min=qf_min, fixed_qbar_norm=ev_fixed[-1],
                fixed_mu=mu_f, fixed_bound18=b_f, identity54_residual=np.abs(res54).max(),
                identity54_scale=np.abs(Qbar_fixed).max(), identity54_tol=tol54, S_fixed=S_fixed)


def _spectra(sc: CoestimationFile, P: np.ndarray) -> dict[str, Any]:
    """S(g) Hurwitz at g ≡ 0, g ≡ 1, the fixed roles and random g: per g max Re λ(S(g)), its round-off
    allowance (Bauer-Fike: cond(V)·‖S‖₂ times the backward error of the eigenvalue solver), min Re λ,
    cond(V) (V the eigenvectors) and the eigenvalues."""
    N = sc.N
    rng = np.random.default_rng(12345)
    g_list = [np.zeros(N), np.ones(N), np.asarray(sc.fixed_roles.active)] + [rng.uniform(size=N)
                                                                            for _ in range(N_RANDOM_G)]
    mx, tol, mn, cond, eigs = [], [], [], [], []
    for g in g_list:
        S = stacked_S(sc, P, g)
        w, V = np.linalg.eig(S)
        eigs.append(w[np.lexsort((w.imag, w.real))])
        mx.append(w.real.max())
        mn.append(w.real.min())
        cond.append(np.linalg.cond(V))
        tol.append(roundoff_tolerance(scale=np.linalg.norm(S, 2), operations=S.shape[0], condition=cond[-1])[0])
    eigs = np.array(eigs)
    return dict(S_max_real=np.array(mx), S_tol=np.array(tol), S_min_real=np.array(mn)[:2], S_fixed_cond=cond[2],
                S_cond=np.array(cond), S_g=np.array(g_list), S_eig_real=eigs.real, S_eig_imag=eigs.imag,
                S_all_passive=stacked_S(sc, P, np.zeros(N)), S_all_active=stacked_S(sc, P, np.ones(N)))


def _structure(sc: CoestimationFile) -> dict[str, Any]:
    """Observability ranks, footnote 3 (L = J = 0 makes Ā_i Hurwitz), the spectra of A and of the Laplacian."""
    n, p, lap = sc.n, sc.p, sc.lap
    Aaug = np.block([[sc.A, sc.B], [np.zeros((p, n + p))]])
    lev = np.linalg.eigvalsh(lap)
    return dict(
        rank_obsv_local=np.array([np.linalg.matrix_rank(obsv(sc.A, ty.C)) for ty in sc.types]),
        rank_obsv_collective=np.array(np.linalg.matrix_rank(obsv(sc.A, np.vstack([ty.C for ty in sc.types])))),
        rank_obsv_augmented=np.array([np.linalg.matrix_rank(obsv(Aaug, np.hstack([ty.C, np.zeros((sc.m, p))])))
                                      for ty in sc.types]),
        fn3_max_real=np.array([np.linalg.eigvals(ce.error_matrix(sc.A, sc.B, ty.C, 0 * ty.L, 0 * ty.J, ty.sigma, ty.K,
                                                                 1.0)).real.max() for ty in sc.types]),
        A_max_real=np.linalg.eigvals(sc.A).real.max(), lap_min_eig=lev[0], lap_fiedler=lev[1] if sc.N > 1 else 0.0,
        lap_max_eig=lev[-1], lap_asymmetry=np.abs(lap - lap.T).max())


# -- stages ---------------------------------------------------------------------------------------------

@stage(name="design", allow_nonfinite=DESIGN_MAY_BE_NAN)
def design_core(sc: CoestimationFile) -> dict[str, np.ndarray]:
    """Everything the runs need (P, the comparison architecture's P, S) and every quantity that is cheap."""
    out: dict[str, Any] = _solve_vertex_lmis(sc)
    P, source = _design_P(sc, out["P_lmi"])
    out.update(P=P, P_source=source)
    out.update(_node_margins(sc, P))
    out.update(_comparison_lmis(sc))
    out.update(_bounds(sc, P, out["certified_eps"], out["eps_nodes"]))
    out.update(_fixed_roles(sc, P, out["phibar"]))
    out.update(_spectra(sc, P))
    out.update(_structure(sc))
    return {k: np.asarray(v) for k, v in out.items()}


@stage(name="design-qstar", allow_nonfinite=DESIGN_MAY_BE_NAN)
def vertex_dissipation(sc: CoestimationFile, core: dict, max_nodes: int) -> dict[str, np.ndarray]:
    """q* = min over g ∈ {0,1}^N of λ_min(−(Ā(g)ᵀP + PĀ(g)) + 2α(L⊗I)) and where it is attained."""
    G = gains(sc)
    vd = lb.vertex_dissipation(sc.A, sc.B, G["C"], G["L"], G["J"], G["K"], G["sigma"], core["P"], sc.lap,
                               sc.coupling.alpha, max_nodes=max_nodes)
    return {"qstar": np.asarray(np.nan if vd is None else vd[0]), "qstar_g": np.full(sc.N, -1) if vd is None else vd[1]}


@stage(name="design-thm31", allow_nonfinite=DESIGN_MAY_BE_NAN)
def thm31_vertices(sc: CoestimationFile, core: dict, max_nodes: int) -> dict[str, np.ndarray]:
    """Thm 3.1: max over g ∈ {0,1}^N of λ_max(S(g)ᵀP + PS(g) + Q̄_ε) (single ε), with S(g) built explicitly
    (the coupling part −α(H(L⊗I))ᵀP − αPH(L⊗I) is formed as a product, not through the identity PH = I), and its
    round-off allowance: inputs of size ‖(|S(0)| + |S(1) − S(0)|)ᵀ|P|‖₂ (a bound of |S(g)|ᵀ|P| for every g),
    products of length Nq, H = P⁻¹ with condition κ(P)."""
    N, q, P, alpha = sc.N, sc.q, core["P"], sc.coupling.alpha
    if N > max_nodes:
        return {"thm31_vertex_max": np.asarray(np.nan), "thm31_vertex_tol": np.asarray(np.nan)}
    Pbig = ce.block_diag(list(P))
    Qe = lb.qbar_eps(np.full(N, core["eps_nodes"].min()), sc.lap, alpha, q)
    Hc = ce.block_diag(list(np.linalg.inv(P))) @ np.kron(sc.lap, np.eye(q))
    base = -alpha * (Hc.T @ Pbig + Pbig @ Hc) + Qe
    blocks = [[(lambda A_: A_.T @ P[i] + P[i] @ A_)(error_matrix(sc, i, g)) for g in (0.0, 1.0)] for i in range(N)]
    top = lb.vertex_eigen_extremes((base + base.T) / 2, blocks)[2]
    S0, S1 = (stacked_S(sc, P, g) for g in (0.0, 1.0))
    absS = np.abs(S0) + np.abs(S1 - S0)
    cond = max(np.linalg.cond(Pi) for Pi in P)
    tol = roundoff_tolerance(scale=2 * np.linalg.norm(absS.T @ np.abs(Pbig), 2) + np.linalg.norm(Qe, 2),
                             operations=N * q, condition=cond)[0]
    return {"thm31_vertex_max": np.asarray(float(top)), "thm31_vertex_tol": np.asarray(float(tol))}


@stage(name="design-extras", allow_nonfinite=DESIGN_MAY_BE_NAN)
def paper_extras(sc: CoestimationFile, quick: bool) -> dict[str, np.ndarray]:
    """The comparison LMIs at the coestimation σ, the smallest feasible σ, the J sweep."""
    cstat, cmargin, sig_min = [], [], []
    for t, ty in enumerate(sc.types):
        r0 = cl.affine_lmi(_comparison_blocks(sc, t, ty.sigma), sc.n, lower=sc.comparison.P_lower)
        cstat.append(r0.status)
        cmargin.append(r0.margin)
        sig_min.append(_min_feasible_sigma(sc, t, ty.sigma, max(10.0, 10 * ty.comparison_sigma), 6 if quick else 10))
    jm = np.array([[cl.common_lyapunov(vertices(sc, t, s), ty.eps, feasibility=False).margin for s in J_SWEEP]
                   for t, ty in enumerate(sc.types)])
    return {"comp_status": np.array(cstat), "comp_margin": np.array(cmargin, float), "comp_sigma_min": np.array(sig_min),
            "J_sweep": np.array(J_SWEEP), "J_sweep_margin": jm}


def merge_design(core: dict[str, np.ndarray], parts) -> dict[str, np.ndarray]:
    """The design: the core, its parts, and the bound (18) with q*."""
    out = dict(core)
    for part in parts:
        out.update(part)
    mu, bound = ultimate_bound_or_nan(out["P"], float(out["qstar"]), float(out["phibar"]))
    out["mu_qstar"], out["bound18_qstar"] = np.asarray(mu), np.asarray(bound)
    return out
