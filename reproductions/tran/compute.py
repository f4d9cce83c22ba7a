"""Stages of the coestimation family, each cached: design (LMIs, P_i, bounds), deterministic
runs (coestimation with time-varying and fixed roles, the comparison architecture, a
step-halving twin), stochastic Monte Carlo (time-varying and fixed roles), exact moments
and the centralized Kalman reference."""
from __future__ import annotations

import functools
from dataclasses import dataclass, field
from typing import Any

import numpy as np

import estimators.common_lyapunov as cl
import estimators.input_state_coestimation as ce
import estimators.lyapunov_bounds as lb
import estimators.observer_network_simulation as sim
from pipeline.cache import StageCache, code_fingerprint
from pipeline.reproduction import RunOptions
from pipeline.seeding import stream_seed
from pipeline.simulate import parallel_map, run_blocks

from .central_reference import central_kalman
from .scenario import CoestimationScenario

CODE_MODULES = ("estimators.common_lyapunov", "estimators.input_state_coestimation", "estimators.lyapunov_bounds",
                "estimators.observer_network_simulation", "estimators.exponential_integrators",
                "reproductions.tran.compute", "reproductions.tran.central_reference", "reproductions.tran.scenario")
J_SWEEP = (1.0, 2.0, 5.0, 10.0, 25.0, 50.0)
SDE_BLOCK = 100
# design quantities that are legitimately undefined in some scenarios (no vertex enumeration for large N,
# an infeasible LMI, a bound with λ_min(Q̄) ≤ 0)
DESIGN_MAY_BE_NAN = ("qstar", "mu_qstar", "bound18_qstar", "thm31_vertex_max", "comp_sigma_min", "P_comparison",
                     "P_lmi", "lmi_margin", "lmi_verified", "comp_margin", "comp_margin_b", "J_sweep_margin",
                     "mu_single", "bound18_single", "mu_pernode", "bound18_pernode", "mu_certified",
                     "bound18_certified", "fixed_mu", "fixed_bound18", "bound18_single_tight_phi")


@dataclass
class Results:
    scenario: CoestimationScenario
    seed: int
    trials: int
    quick: bool
    design: dict[str, np.ndarray]
    runs: dict[str, dict[str, np.ndarray]] = field(default_factory=dict)

    # convenience accessors
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


def compute_design(sc: CoestimationScenario, quick: bool) -> dict[str, np.ndarray]:
    n, p, q, N = sc.n, sc.p, sc.n + sc.p, sc.N
    T = len(sc.types)
    out: dict[str, Any] = {}
    # (28)-(29) per node type with cvxpy; the printed P_i against the printed gains
    status, margin, verified = [], [], []
    P_lmi = np.zeros((T, q, q))
    for t in range(T):
        r = cl.common_lyapunov(vertices(sc, t), sc.types[t].eps)
        status.append(r.status)
        margin.append(r.margin)
        verified.append(r.verified)
        P_lmi[t] = r.P if r.P is not None else np.nan
    out.update(lmi_status=np.array(status), lmi_margin=np.array(margin), lmi_verified=np.array(verified), P_lmi=P_lmi)
    gs = np.linspace(0.0, 1.0, 101)
    if all(ty.P is not None for ty in sc.types):
        out["P_given"] = np.stack([ty.P for ty in sc.types])
        sweep = np.zeros((T, len(gs)))
        hurwitz = np.zeros((T, len(gs)))
        for t, ty in enumerate(sc.types):
            for k, g in enumerate(gs):
                Ab = ce.error_matrix(sc.A, sc.B, ty.C, ty.L, ty.J, ty.sigma, ty.K, g)
                sweep[t, k] = np.linalg.eigvalsh(Ab.T @ ty.P + ty.P @ Ab).max()
                hurwitz[t, k] = np.linalg.eigvals(Ab).real.max()
        out.update(given_sweep=sweep, given_hurwitz=hurwitz)
    out["g_sweep"] = gs
    # the per-node P used by the estimator
    if sc.P_mode == "given":
        P_types = out["P_given"]
    elif sc.P_mode == "lmi":
        # an infeasible (28)-(29) leaves no valid H = P⁻¹: run with P = I for that type so that the run and
        # every claim still report (tran.step_i.lmi_feasible fails with the solver status), never crash
        usable = np.array([np.all(np.isfinite(Pt)) and m > 0 and np.linalg.eigvalsh(Pt).min() > 1e-9 * np.trace(Pt)
                           for Pt, m in zip(P_lmi, margin)])
        P_types = np.where(usable[:, None, None], np.nan_to_num(P_lmi), np.eye(q)[None])
        out["P_lmi_fallback"] = ~usable
    else:
        P_types = None
    if P_types is not None:
        P = np.stack([P_types[sc.node_type[i]] for i in range(N)])
    else:  # (10) with Q_i = I for the fixed roles
        from scipy.linalg import solve_continuous_lyapunov
        g = np.asarray(sc.roles_active)
        P = np.stack([solve_continuous_lyapunov(ce.error_matrix(sc.A, sc.B, *_node(sc, i), g[i]).T, -np.eye(q))
                      for i in range(N)])
    out["P"] = P
    G = gains(sc)
    lap = sc.lap
    # comparison architecture LMIs (38)-(39): at the paper's σ and at the reconstructed σ_b
    cstat, cmargin, cstat_b, cmargin_b, sig_min = [], [], [], [], []
    P_b_types = np.zeros((T, n, n))
    for t, ty in enumerate(sc.types):
        r0 = cl.affine_lmi(_comparison_blocks(sc, t, ty.sigma), n, lower=sc.comparison_P_lower)
        cstat.append(r0.status)
        cmargin.append(r0.margin)
        rb = cl.affine_lmi(_comparison_blocks(sc, t, ty.comparison_sigma), n, lower=sc.comparison_P_lower)
        cstat_b.append(rb.status)
        cmargin_b.append(rb.margin)
        # an uncertified P would run the comparison architecture outside its theory: only a feasible one is used
        P_b_types[t] = rb.P if rb.P is not None and np.isfinite(rb.margin) and rb.margin >= 0 else np.nan
        sig_min.append(_min_feasible_sigma(sc, t, ty.sigma, max(10.0, 10 * ty.comparison_sigma), 6 if quick else 10))
    out.update(comp_status=np.array(cstat), comp_margin=np.array(cmargin), comp_status_b=np.array(cstat_b),
               comp_margin_b=np.array(cmargin_b), comp_sigma_min=np.array(sig_min), P_comparison=P_b_types)
    # J sweep: (28)-(29) margin as J grows (the remark on the input-estimate lag)
    jm = np.zeros((T, len(J_SWEEP)))
    for t in range(T):
        for k, s in enumerate(J_SWEEP):
            jm[t, k] = cl.common_lyapunov(vertices(sc, t, s), sc.types[t].eps).margin
    out.update(J_sweep=np.array(J_SWEEP), J_sweep_margin=jm)
    # standing quantities of the bounds
    signal = input_signal(sc)
    w_sup, wdot_sup = signal.sup_norms(sc.t_end)
    wbar = max(w_sup, wdot_sup)
    phi_i, phibar = lb.forcing_bound(G["sigma"], G["K"], wbar, wbar)
    _, phibar_tight = lb.forcing_bound(G["sigma"], G["K"], w_sup, wdot_sup)
    lamP = np.concatenate([np.linalg.eigvalsh(Pi) for Pi in P])
    eps_nodes = np.array([sc.types[t].eps for t in sc.node_type])
    qb_single = np.linalg.eigvalsh(lb.qbar_eps(np.full(N, eps_nodes.min()), lap, sc.alpha, q))[0]
    qb_pernode = np.linalg.eigvalsh(lb.qbar_eps(eps_nodes, lap, sc.alpha, q))[0]
    # certified per-node margins of P at the vertices (the largest ε_i each P_i certifies)
    cert = np.array([-cl.vertex_margin(ce.error_vertices(sc.A, sc.B, *_node(sc, i)[:3], _node(sc, i)[3], _node(sc, i)[4]), P[i])
                     for i in range(N)])
    qb_cert = np.linalg.eigvalsh(lb.qbar_eps(np.maximum(cert, 0), lap, sc.alpha, q))[0]
    vd = lb.vertex_dissipation(sc.A, sc.B, G["C"], G["L"], G["J"], G["K"], G["sigma"], P, lap, sc.alpha,
                               max_nodes=10 if quick else 14)
    out.update(w_sup=w_sup, wdot_sup=wdot_sup, wbar=wbar, phibar_i=phi_i, phibar=phibar, phibar_tight=phibar_tight,
               lamP_min=lamP.min(), lamP_max=lamP.max(), eps_nodes=eps_nodes, certified_eps=cert,
               qbar_single=qb_single, qbar_pernode=qb_pernode, qbar_certified=qb_cert,
               qstar=np.nan if vd is None else vd[0], qstar_g=np.full(N, -1) if vd is None else vd[1])
    for name, qmin in (("single", qb_single), ("pernode", qb_pernode), ("certified", qb_cert),
                       ("qstar", np.nan if vd is None else vd[0])):
        mu, bound = lb.ultimate_bound(P, qmin, phibar) if np.isfinite(qmin) and qmin > 0 else (np.nan, np.nan)
        out[f"mu_{name}"], out[f"bound18_{name}"] = mu, bound
    mu_t, b_t = lb.ultimate_bound(P, qb_single, phibar_tight)
    out["bound18_single_tight_phi"] = b_t
    # fixed roles: Q_i from (10), Q̄, S, identity (54)
    gfix = np.asarray(sc.fixed_active)
    Abars = [ce.error_matrix(sc.A, sc.B, *_node(sc, i), gfix[i]) for i in range(N)]
    Qi_min = np.array([np.linalg.eigvalsh(-(A_.T @ P[i] + P[i] @ A_)).min() for i, A_ in enumerate(Abars)])
    Qbar_fixed = lb.qbar_fixed(Abars, P, lap, sc.alpha)
    S_fixed = ce.stacked_error_matrix(sc.A, sc.B, G["C"], G["L"], G["J"], G["K"], G["sigma"], P, lap, sc.alpha, gfix)
    Pbig = ce.block_diag(list(P))
    res54 = S_fixed.T @ Pbig + Pbig @ S_fixed + Qbar_fixed
    qf_min = np.linalg.eigvalsh(Qbar_fixed)[0]
    mu_f, b_f = lb.ultimate_bound(P, qf_min, phibar) if qf_min > 0 else (np.nan, np.nan)
    out.update(fixed_Qi_min=Qi_min, fixed_qbar_min=qf_min, fixed_mu=mu_f, fixed_bound18=b_f,
               identity54_residual=np.abs(res54).max(), identity54_scale=np.abs(Qbar_fixed).max(), S_fixed=S_fixed)
    # S(g) Hurwitz: all-passive, all-active, the fixed roles and random g
    rng = np.random.default_rng(12345)
    g_list = [np.zeros(N), np.ones(N), gfix] + [rng.uniform(size=N) for _ in range(20)]
    out["S_max_real"] = np.array([np.linalg.eigvals(ce.stacked_error_matrix(sc.A, sc.B, G["C"], G["L"], G["J"], G["K"],
                                                                             G["sigma"], P, lap, sc.alpha, g)).real.max()
                                  for g in g_list])
    out["S_min_real"] = np.array([np.linalg.eigvals(ce.stacked_error_matrix(sc.A, sc.B, G["C"], G["L"], G["J"], G["K"],
                                                                             G["sigma"], P, lap, sc.alpha, g)).real.min()
                                  for g in g_list[:2]])
    # Thm 3.1: S(g)ᵀP + P S(g) + Q̄_ε ≤ 0 at the vertices g ∈ {0,1}^N (single ε), largest eigenvalue
    out["thm31_vertex_max"] = _thm31_vertex_check(sc, P, np.full(N, eps_nodes.min()), max_nodes=10 if quick else 14)
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
    return {k: np.asarray(v) for k, v in out.items()}


def _node(sc: CoestimationScenario, i: int):
    ty = sc.types[sc.node_type[i]]
    return ty.C, ty.L, ty.J, ty.sigma, ty.K


def _thm31_vertex_check(sc, P, eps, max_nodes: int) -> float:
    """max over g ∈ {0,1}^N of λ_max(S(g)ᵀP + PS(g) + Q̄_ε), with S(g) built explicitly (the coupling part
    −α(H(L⊗I))ᵀP − αPH(L⊗I) is formed as a product, not through the identity PH = I)."""
    N, q = sc.N, sc.n + sc.p
    if N > max_nodes:
        return float("nan")
    G = gains(sc)
    Pbig = ce.block_diag(list(P))
    Qe = lb.qbar_eps(eps, sc.lap, sc.alpha, q)
    Hc = ce.block_diag(list(np.linalg.inv(P))) @ np.kron(sc.lap, np.eye(q))
    base = -sc.alpha * (Hc.T @ Pbig + Pbig @ Hc) + Qe
    blocks = [[(lambda A_: A_.T @ P[i] + P[i] @ A_)(ce.error_matrix(sc.A, sc.B, G["C"][i], G["L"][i], G["J"][i],
                                                                   G["sigma"][i], G["K"][i], g)) for g in (0.0, 1.0)]
              for i in range(N)]
    return lb.vertex_eigen_extremes((base + base.T) / 2, blocks)[2]


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
                      record_every=every)
    return {"t": tr.t, "w": tr.w, "x": tr.x[0], "e": tr.e[0], "g": tr.g[0]}


def noise_model(sc: CoestimationScenario, seed: int) -> sim.NoiseModel:
    """v ~ U(0, v_range)^n (one scalar Brownian motion) and h_i ~ U(0, h_range)^m per node (Sec. 5.2)."""
    rng = np.random.default_rng(stream_seed(seed, "tran", "noise-intensities"))
    v = rng.uniform(0.0, sc.process_range, size=sc.n)
    h = rng.uniform(0.0, sc.measurement_range, size=(sc.N, sc.m))
    return sim.NoiseModel(v[:, None], h[:, :, None])


def _sde_reducer(sc: CoestimationScenario, P: np.ndarray):
    """Per-trial V = Σ_i z_iᵀ P_i z_i, ‖z‖, mean ‖x − x̂_i‖, mean ‖ŵ_i − w‖ and the active count.

    Called every recorded step on every trial (it was a fifth of the stochastic stage): V as one
    product with blkdiag(P_i), the norms from one array of squares."""
    Pbig = ce.block_diag(list(P))

    def reduce(t, x, w, e, g):
        z = ce.errors_from_estimates(x, w, e, sc.n)
        R = len(z)
        zf = z.reshape(R, -1)
        V = np.einsum("ri,ri->r", zf @ Pbig, zf)
        sq = np.square(z)
        nx = np.sqrt(sq[..., :sc.n].sum(-1)).mean(-1)
        nw = np.sqrt(sq[..., sc.n:].sum(-1)).mean(-1)
        return {"V": V, "znorm": np.sqrt(sq.reshape(R, -1).sum(-1)), "xerr": nx, "werr": nw,
                "n_active": (g > 0.5).sum(-1)}
    return reduce


def run_stochastic(sc: CoestimationScenario, P: np.ndarray, *, fixed: bool, trials: int, seed: int, t_end: float,
                   keep: int, h: float | None = None) -> dict[str, np.ndarray]:
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
                          keep=k, reducer=_sde_reducer(sc, P), prepared=prepared)
        if k:
            kept.append({"x": tr.x, "e": tr.e, "g": tr.g})
        return tr

    def combine(parts):
        red = {name: np.concatenate([p.reduced[name] for p in parts], axis=1) for name in parts[0].reduced}
        out = {f"red_{k}": v for k, v in red.items()}
        out.update(t=parts[0].t, w=parts[0].w, v=noise.process, h=noise.measurement)
        for name in ("x", "e", "g"):
            out[f"kept_{name}"] = np.concatenate([b[name] for b in kept]) if kept else np.zeros((0,))
        return out

    label = ("fixed" if fixed else "roles", h)
    return run_blocks(block, combine, trials, stream_seed(seed, "tran", "sde", label), block=SDE_BLOCK)


def exact_fixed_moments(sc: CoestimationScenario, design, det_fixed, noise: sim.NoiseModel) -> dict[str, np.ndarray]:
    """E{V(t)} = m(t)ᵀ P m(t) + tr(P Σ(t)) for fixed roles: m the noise-free error (11) and Σ the
    exact solution of Σ̇ = S Σ + Σ Sᵀ + G Gᵀ, G = [1_N ⊗ v̄, blockdiag(r_i)] ((45), (60))."""
    P, S = design["P"], design["S_fixed"]
    n, q, N = sc.n, sc.n + sc.p, sc.N
    g = np.asarray(sc.fixed_active)
    LJ = gains(sc)
    vbar = np.concatenate([noise.process[:, 0], np.zeros(sc.p)])
    Gm = np.zeros((N * q, 1 + N))
    Gm[:, 0] = np.tile(vbar, N)
    for i in range(N):
        hi = noise.measurement[i, :, 0]
        Gm[i * q:(i + 1) * q, 1 + i] = g[i] * np.concatenate([-LJ["L"][i] @ hi, LJ["J"][i] @ hi])
    t = det_fixed["t"]
    Sig = lb.noise_covariance_sequence(S, Gm, sc.record_dt, len(t) - 1)
    z = ce.errors_from_estimates(det_fixed["x"], det_fixed["w"], det_fixed["e"], n).reshape(len(t), -1)
    Pbig = ce.block_diag(list(P))
    EV = np.einsum("ti,ij,tj->t", z, Pbig, z) + np.einsum("ij,tji->t", Pbig, Sig)
    r_star = max(np.linalg.norm(Gm[:, 1 + i]) for i in range(N))
    return {"EV": EV, "t": t, "v_star": np.array(np.linalg.norm(noise.process)), "r_star": np.array(r_star),
            "h_star": np.array(np.linalg.norm(noise.measurement[:, :, 0], axis=1).max())}


def _sde_job(cache, key, sc, P, trials, seed, t_ends, job):
    name, fixed, h = job
    t_end = t_ends[name]
    return cache.get_or_compute(name, {**key, "t_end": t_end}, lambda: run_stochastic(sc, P, fixed=fixed, trials=trials, seed=seed,
                                                                   t_end=t_end, keep=sc.runs, h=h))


def compute(sc: CoestimationScenario, opts: RunOptions, cache: StageCache) -> Results:
    trials = trial_count(sc, opts)
    code = code_fingerprint(CODE_MODULES)
    base = {"scenario": sc.key(), "code": code}
    design = cache.get_or_compute("design", {**base, "quick": opts.quick}, lambda: compute_design(sc, opts.quick),
                                  scenario=sc.name, allow_nonfinite=DESIGN_MAY_BE_NAN)
    P = design["P"]
    res = Results(sc, opts.seed, trials, opts.quick, design)
    tv_roles = role_law(sc, fixed=False)
    jobs = {
        "coest": lambda: run_deterministic(sc, coestimation(sc, P), tv_roles, sc.step),
        "coest_half": lambda: run_deterministic(sc, coestimation(sc, P), tv_roles, sc.step / 2),
        "fixed": lambda: run_deterministic(sc, coestimation(sc, P), role_law(sc, fixed=True), sc.step),
        "comparison": lambda: run_deterministic(sc, comparison(sc, design["P_comparison"]), tv_roles, sc.step),
    }
    for name, job in jobs.items():
        if name == "comparison" and not np.all(np.isfinite(design["P_comparison"])):
            continue
        res.runs[name] = cache.get_or_compute(f"det-{name}", base, job)
    t_sde = sc.quick_t_end if opts.quick else sc.t_end
    sde_key = {**base, "seed": opts.seed, "trials": trials, "t_end": t_sde}
    sde_jobs = [("sde_roles", False, sc.sde_step), ("sde_fixed", True, sc.sde_step),
                ("sde_fixed_half", True, sc.sde_step / 2)]
    outs = parallel_map(functools.partial(_sde_job, cache, sde_key, sc, P, trials, opts.seed,
                                          {"sde_roles": t_sde, "sde_fixed": t_sde,
                                           "sde_fixed_half": min(t_sde, sc.quick_t_end)}), sde_jobs,
                        workers=opts.workers, desc="tran: stochastic Monte Carlo")
    for (name, _, _), o in zip(sde_jobs, outs):
        res.runs[name] = o
    noise = noise_model(sc, opts.seed)
    res.runs["exact_fixed"] = cache.get_or_compute("exact-fixed", {**base, "seed": opts.seed}, lambda: exact_fixed_moments(
        sc, design, res.runs["fixed"], noise))
    res.runs["central"] = cache.get_or_compute("central", {**base, "seed": opts.seed, "t_end": t_sde}, lambda: central_kalman(
        sc, res.runs["coest"], res.runs["sde_roles"], noise))
    return res
