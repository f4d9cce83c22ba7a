"""Stages of the hybrid-observer family: design quantities (ρ, α, q, σ, c_i; cached), one
exact simulation per run (cached per run, trials on a leading axis), the error-recursion
matrices of each interval, and a centralized Kalman reference (filterpy)."""
from __future__ import annotations

import functools
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import scipy.linalg as sla

import estimators.hybrid_observer as ho
import estimators.jointly_observable_design as jd
from pipeline.cache import StageCache, code_fingerprint
from pipeline.reproduction import RunOptions
from pipeline.seeding import stream_seed
from pipeline.simulate import block_generator, parallel_map

from .scenario import HybridScenario, RunSpec

CODE_MODULES = ("estimators.hybrid_observer", "estimators.jointly_observable_design",
                "reproductions.wang_liu_morse.compute", "reproductions.wang_liu_morse.scenario")
LEMMA5_SAMPLES = 20_000
LEMMA5_FLOPS = 10 ** 9          # at most about this many flops for the sampled products of Lemma 5
LEMMA6_SAMPLES = 2000
BASIS_CONDITION = 100.0     # condition number of the non-orthogonal change of basis of footnote 3
#: arrays in which NaN marks "not applicable" (intervals an agent sat out; identities of runs with an input)
NOT_APPLICABLE = ("res_minus", "res_plus", "res_scale", "A_mixed", "B_mixed", "G_mixed", "A_2", "B_2", "Phi_max",
                  "ebar_dev", "ebar_dev2")
DT_PLOT = 0.01
PHI_INTERVALS = 4


def observer_design(sc: HybridScenario) -> ho.ObserverDesign:
    locs = [jd.local_design(sc.A, sc.C[i], rank_tol=sc.rank_tol, L=None if sc.L_given is None else sc.L_given[i])
            for i in range(sc.m)]
    if sc.gains == "given":
        K = tuple(np.asarray(k, float) for k in sc.K_given)
    else:
        K = tuple(jd.place_gain(loc.Abar, loc.Cbar, p) for loc, p in zip(locs, sc.poles))
    return ho.ObserverDesign(sc.A, tuple(sc.C), tuple(l.L for l in locs), tuple(l.Abar for l in locs),
                             tuple(l.Cbar for l in locs), K, tuple(l.Q for l in locs), np.array([l.P for l in locs]))


def central_gain(sc: HybridScenario) -> np.ndarray:
    """Centralized observer on the stacked outputs: x_c' = (A + K_c C) x_c - K_c y (see `jd.stacked_gain`)."""
    return jd.stacked_gain(sc.A, np.vstack(sc.C), sc.central_poles, sc.rank_tol)


# -- design stage ----------------------------------------------------------------------------------

def compute_design(sc: HybridScenario, seed: int, extras: bool = False) -> dict[str, np.ndarray]:
    """Design quantities; `extras` adds the ones only the paper's claims use (Section 5's vertex-loss
    design, the model-mismatch demonstration of Section 4)."""
    d = observer_design(sc)
    m, n = d.m, d.n
    out: dict[str, np.ndarray] = {}
    nA = float(np.linalg.norm(sc.A, 2))
    out["norm_A"] = np.array(nA)
    out["norm_eAT"] = np.array(np.linalg.norm(sla.expm(sc.A * sc.T), 2))
    out["P"] = d.P
    out["n_i"] = np.array(d.n_i)
    out.update(local_design_checks(sc, d, seed))
    stack = np.vstack([np.eye(n) - d.P[i] for i in range(m)])
    out["sigma_min_16"] = np.array(np.linalg.svd(stack, compute_uv=False).min())
    F = [d.F(i) for i in range(m)]
    out["local_abscissa"] = np.array([jd.spectral_abscissa(Fi) for Fi in F])
    out["local_abscissa_tol"] = np.array([eigenvalue_roundoff(Fi) for Fi in F])
    out["c_i"] = np.array([jd.transient_constant(Fi, sc.lam_bar) for Fi in F])
    out["Q_mixed"] = np.array(jd.mixed_norm(sla.block_diag(*d.Q), [n] * m, d.n_i))
    out["Q_2"] = np.array(np.linalg.norm(sla.block_diag(*d.Q), 2))
    rho = jd.rho_exact(d.P)
    out["rho"], out["rho_exact"], out["rho_words"] = np.array(rho.rho), np.array(rho.exact), np.array(rho.words)
    out["rho_upper"] = np.array(rho.upper)
    out["rho_worst_word"] = np.array(rho.worst_word)
    if rho.upper < 1:           # (22) from the proven upper bound on ρ: a q that is sufficient for sure
        sq = jd.sufficient_q(rho.upper, m, nA, sc.lam, sc.T)
        out["alpha_lemma5_upper"] = np.array(float(sq.alpha_lemma5))
        out["q_thm22_upper"] = np.array(str(sq.q_thm22))
    for label, lam in (("", sc.lam), ("_paper", float(sc.paper_values.get("lambda", sc.lam)))):
        sq = jd.sufficient_q(rho.rho, m, nA, lam, sc.T)
        out[f"alpha_lemma5{label}"] = np.array(float(sq.alpha_lemma5))
        out[f"one_minus_alpha_log10{label}"] = np.array(sq.log10_one_minus_alpha)
        out[f"alpha_printed{label}"] = np.array(float(sq.alpha_printed))
        out[f"r_lemma5{label}"] = np.array(float(sq.r_lemma5))
        out[f"r_printed{label}"] = np.array(float(sq.r_printed))
        for k in ("q_thm22", "q_thm21", "q_minimal", "q_thm22_printed_alpha", "q_minimal_printed_alpha"):
            out[f"{k}{label}"] = np.array(str(getattr(sq, k)))
    if m <= 6:
        sig, worst, vals = jd.sigma_symmetric(d.P)
        out["sigma"], out["sigma_worst"], out["sigma_graphs"] = np.array(sig), np.array(worst), np.array(len(vals))
        out["sigma_worst_mask"] = jd.connected_undirected_graphs(m)[worst]
        for label, lam in (("", sc.lam), ("_paper", float(sc.paper_values.get("lambda", sc.lam)))):
            if sig < 1:
                out[f"q27{label}"] = np.array(jd.q_symmetric(sig, nA, lam, sc.T))
                out[f"q27_minimal{label}"] = np.array(jd.q_symmetric_minimal(sig, nA, lam, sc.T))
    # Lemma 5: products of N = (m-1)^2+1 steps P(S⊗I) with S flocking matrices of strongly connected graphs
    N = (m - 1) ** 2 + 1
    if m <= 4:
        pool = jd.strongly_connected_digraphs(m)
    else:
        gen = block_generator(stream_seed(seed, "lemma5-pool"))
        cand = gen.random((4000, m, m)) < 0.5
        cand |= np.eye(m, dtype=bool)[None]
        pool = cand[jd.strongly_connected_batch(cand)]
    flock = np.array([jd.flocking_matrix(g) for g in pool])
    Pbig = sla.block_diag(*d.P)
    steps = Pbig[None] @ np.einsum("gij,ab->giajb", flock, np.eye(n)).reshape(len(pool), m * n, m * n)
    gen = block_generator(stream_seed(seed, "lemma5"))
    samples = int(min(LEMMA5_SAMPLES, max(len(pool), LEMMA5_FLOPS // (N * (m * n) ** 3))))
    idx = gen.integers(0, len(pool), size=(samples, N))
    # adversarial members: every constant sequence (the slowest mixing graphs repeated)
    idx[: len(pool)] = np.arange(len(pool))[:, None]
    prod = steps[idx[:, 0]]
    for k in range(1, N):
        prod = steps[idx[:, k]] @ prod
    norms = jd.mixed_norm(prod, [n] * m, [n] * m)
    out["lemma5_max"] = np.array(norms.max())
    out["lemma5_samples"] = np.array(samples)
    out["lemma5_pool"] = np.array(len(pool))
    # Lemma 6: random doubly stochastic F = w0 I + Σ_k w_k Π_k (Π_k permutations) with a strongly connected graph
    gen = block_generator(stream_seed(seed, "lemma6"))
    perms = np.array([[np.eye(m)[gen.permutation(m)] for _ in range(3)] for _ in range(LEMMA6_SAMPLES)])
    wts = gen.dirichlet(np.ones(4), size=LEMMA6_SAMPLES)
    Fm = wts[:, :1, None] * np.eye(m)[None] + np.einsum("bk,bkij->bij", wts[:, 1:], perms)
    Fm = Fm[jd.strongly_connected_batch(Fm > 1e-12)]
    vals = jd.spectral_norm(Pbig[None] @ np.einsum("fij,ab->fiajb", Fm, np.eye(n)).reshape(len(Fm), m * n, m * n)
                            ) if len(Fm) else np.array([np.nan])
    out["lemma6_max"] = np.array(np.max(vals))
    out["lemma6_count"] = np.array(len(Fm))
    if extras:
        out.update(section5_design(sc, d, nA))
        out.update(model_mismatch(sc, seed))
    return out


def section5_design(sc: HybridScenario, d: ho.ObserverDesign, nA: float) -> dict[str, np.ndarray]:
    """Section 5: joint observability and strong connectivity without agent i; for every d = m
    minus one agent that stays jointly observable, ρ_d (its upper bound) and q_d of (22); q* = max."""
    m, n = d.m, d.n
    out: dict[str, np.ndarray] = {}
    red_obs = [jd.observable_basis(sc.A, np.vstack([sc.C[j] for j in range(m) if j != i]), sc.rank_tol).rows.shape[0]
               == n for i in range(m)]
    out["redundant_observable"] = np.array(red_obs)
    out["redundant_connected"] = np.array([[jd.is_strongly_connected(np.delete(np.delete(G, i, 0), i, 1))
                                            for i in range(m)] for G in sc.graphs])
    rho_d, q_d = [], []
    lam_p = float(sc.paper_values.get("lambda", sc.lam))
    for i in range(m):
        keep = [j for j in range(m) if j != i]
        if red_obs[i] and m - 1 >= 2:
            rd = jd.rho_exact(d.P[keep]).upper
            rho_d.append(rd)
            q_d.append(str(jd.sufficient_q(rd, m - 1, nA, lam_p, sc.T).q_thm22) if rd < 1 else "")
        else:
            rho_d.append(-1.0)
            q_d.append("")
    out["vertex_loss_ok"], out["vertex_loss_q"] = np.array(red_obs), np.array(q_d)
    out["vertex_loss_rho"] = np.array(rho_d)
    return out


def eigenvalue_roundoff(F: np.ndarray) -> float:
    """Round-off allowance of a computed eigenvalue of F (Bauer-Fike): 10·k·eps·||F||_2·κ(V) for
    the k x k matrix F with eigenvector matrix V (infinite for a defective F)."""
    _, V = np.linalg.eig(F)
    sv = np.linalg.svd(V, compute_uv=False)
    kappa = sv[0] / sv[-1] if sv[-1] > 0 else np.inf
    return float(10 * len(F) * np.finfo(float).eps * np.linalg.norm(F, 2) * kappa)


def random_orthogonal(gen: np.random.Generator, k: int) -> np.ndarray:
    Qm, Rm = np.linalg.qr(gen.standard_normal((k, k)))
    return Qm * np.sign(np.diag(Rm))


def local_design_checks(sc: HybridScenario, d: ho.ObserverDesign, seed: int) -> dict[str, np.ndarray]:
    """Per agent: the residuals of C_i = C̄_i L_i and L_i A = Ā_i L_i (relative to ||C_i||,
    ||A|| ||L_i||), the rank of the observability matrix of (C̄_i, Ā_i), and footnote 3: the
    largest entry of P_i(M L_i) - P_i(L_i) for a random orthogonal M and a random M of
    condition number BASIS_CONDITION. What each residual may be from round-off and from the
    rank decision is recorded beside it (κ(L_i), κ(M L_i), the singular value the rank
    decision discarded, the distance of a given L_i's row space from the computed one)."""
    gen = block_generator(stream_seed(seed, "basis-change"))
    m = d.m
    rows = {k: [] for k in ("residual_C", "residual_A", "kappa_L", "discarded", "row_space_dist", "obs_rank_local",
                            "P_basis_dev", "kappa_ML")}
    for i in range(m):
        loc = jd.local_design(sc.A, sc.C[i], rank_tol=sc.rank_tol, L=None if sc.L_given is None else sc.L_given[i])
        basis = jd.observable_basis(sc.A, sc.C[i], sc.rank_tol)
        L = loc.L
        nL = float(np.linalg.norm(L, 2))
        rows["residual_C"].append(np.abs(sc.C[i] - loc.Cbar @ L).max() / max(float(np.linalg.norm(sc.C[i], 2)), 1e-300))
        rows["residual_A"].append(np.abs(L @ sc.A - loc.Abar @ L).max() / max(float(np.linalg.norm(sc.A, 2)) * nL, 1e-300))
        rows["kappa_L"].append(loc.condition)
        rows["discarded"].append(basis.discarded)
        rows["row_space_dist"].append(float(np.linalg.norm(L - (L @ basis.rows.T) @ basis.rows, 2)) / nL)
        rows["obs_rank_local"].append(jd.observable_basis(loc.Abar, loc.Cbar, sc.rank_tol).rows.shape[0])
        k = loc.n_i
        dev, kap = [], []
        U, V = random_orthogonal(gen, k), random_orthogonal(gen, k)
        for M in (U, U @ np.diag(np.logspace(0, np.log10(BASIS_CONDITION), k)) @ V):
            _, P_alt, cond = jd.pseudo_inverse_rows(M @ L)
            dev.append(np.abs(P_alt - loc.P).max())
            kap.append(cond)
        rows["P_basis_dev"].append(max(dev))
        rows["kappa_ML"].append(max(kap))
    return {k: np.array(v) for k, v in rows.items()}


def model_mismatch(sc: HybridScenario, seed: int, steps: int = 2000, dt: float = 0.01, size: float = 1e-3
                   ) -> dict[str, np.ndarray]:
    """Section 4's key point: a centralized Kalman filter (filterpy) on all outputs, with the model
    A + δE (||δE|| = size) instead of A, against the same filter with the exact model; noise-free
    plant. Trajectories of ||x||, and of the error for both filters."""
    from filterpy.kalman import KalmanFilter

    n = sc.n
    Cs = np.vstack(sc.C)
    gen = block_generator(stream_seed(seed, "model-mismatch"))
    E = gen.standard_normal((n, n))
    E *= size / np.linalg.norm(E, 2)
    Phi = sla.expm(sc.A * dt)
    x = np.empty((steps, n))
    x[0] = sc.x0
    for k in range(1, steps):
        x[k] = Phi @ x[k - 1]
    errs = {}
    for label, Ahat in (("exact", sc.A), ("mismatch", sc.A + E)):
        kf = KalmanFilter(dim_x=n, dim_z=Cs.shape[0])
        kf.F, kf.H = sla.expm(Ahat * dt), Cs
        kf.Q, kf.R = 1e-6 * np.eye(n), 1e-4 * np.eye(Cs.shape[0])
        kf.x, kf.P = np.zeros(n), np.eye(n)
        e = np.empty(steps)
        for k in range(steps):
            if k:
                kf.predict()
            kf.update(Cs @ x[k])
            e[k] = np.linalg.norm(kf.x - x[k])
        errs[label] = e
    return {"kp_t": np.arange(steps) * dt, "kp_xnorm": np.linalg.norm(x, axis=1), "kp_err_exact": errs["exact"],
            "kp_err_mismatch": errs["mismatch"], "kp_size": np.array(size)}


# -- runs --------------------------------------------------------------------------------------------

def initial_conditions(sc: HybridScenario, d: ho.ObserverDesign, run: RunSpec, trials: int, seed: int):
    """Trial 0: the scenario's initial conditions; trials 1..: random (the same for every run)."""
    B = trials if run.mc else 1
    nw = sum(d.n_i)
    x0 = np.empty((B, sc.n))
    w0 = np.empty((B, nw))
    xh = np.empty((B, sc.m, sc.n))
    x0[0], xh[0] = sc.x0, sc.xhat0
    w0[0] = sc.w0 if sc.w0 is not None else 0.0
    if B > 1:
        gen = block_generator(stream_seed(seed, "initial-conditions", B))
        x0[1:] = sc.ic_scale * gen.standard_normal((B - 1, sc.n))
        w0[1:] = sc.ic_scale * gen.standard_normal((B - 1, nw))
        xh[1:] = sc.ic_scale * gen.standard_normal((B - 1, sc.m, sc.n))
    if run.ideal:
        w0 = np.concatenate([x0 @ L.T for L in d.L], axis=1)
    return x0, w0, xh


def schedule_for(sc: HybridScenario, run: RunSpec) -> ho.GraphSchedule:
    return ho.GraphSchedule(sc.graphs, kind=run.switching, fixed=run.graph, T=sc.T, Delta=run.Delta, beta=run.beta,
                            q=run.q)


def simulate_run(sc: HybridScenario, run: RunSpec, trials: int, seed: int) -> dict[str, np.ndarray]:
    d = observer_design(sc)
    x0, w0, xh = initial_conditions(sc, d, run, trials, seed)
    jitter = None
    if run.timing == "async":
        gen = block_generator(stream_seed(seed, "jitter", run.name))
        eps = np.asarray(run.epsilon)
        jitter = gen.uniform(-1.0, 1.0, size=(run.intervals, sc.m, run.q + 1)) * eps[None, :, None]
    timing = ho.Timing(sc.T, run.q, run.Delta, run.beta, np.asarray(run.offsets, float), jitter)
    members = ()
    if run.leave is not None:
        lv = run.leave
        members = (ho.Membership(lv.agent, lv.at, lv.rejoin, lv.policy, xh[:, lv.agent],
                                 w0[:, d.w_slices[lv.agent]]),)
    res = ho.simulate(d, timing, schedule_for(sc, run), x0=x0, w0=w0, xhat0=xh, intervals=run.intervals,
                      dt_plot=DT_PLOT, rule=run.rule, noise_b=sc.noise_b if run.noise else None,
                      noise_omega=sc.noise_omega, membership=members, central_gain=central_gain(sc),
                      xc0=xh.mean(axis=1))
    out = res.arrays()
    out.update(recursion_checks(sc, d, run, res))
    out.update(local_error_deviation(sc, d, res))
    if jitter is not None:
        out["jitter"] = jitter
    if run.noise:
        out.update(kalman_reference(sc, res))
    return out


def local_error_deviation(sc: HybridScenario, d: ho.ObserverDesign, res: ho.HybridRun) -> dict[str, np.ndarray]:
    """δē(s) = ē(s) - e^(F_i sT) ē(0) per agent: how far the simulated local observer errors are from
    their exact law ē_i' = F_i ē_i, i.e. the simulation's round-off in ē (large when the gains K_i are
    large). Max over agents (mixed norm) and stacked 2-norm, (S+1, B)."""
    S = res.ebar.shape[0] - 1
    dev = np.zeros((S + 1, res.ebar.shape[1], d.m))
    for i, sl in enumerate(d.w_slices):
        step = sla.expm(d.F(i) * (ho.to_ns(sc.T) / ho.NS))
        exact = res.ebar[0][:, sl]
        for k in range(1, S + 1):
            exact = exact @ step.T
            dev[k, :, i] = np.linalg.norm(res.ebar[k][:, sl] - exact, axis=-1)
    return {"ebar_dev": dev.max(axis=-1), "ebar_dev2": np.sqrt((dev ** 2).sum(axis=-1))}


def recursion_checks(sc: HybridScenario, d: ho.ObserverDesign, run: RunSpec, res: ho.HybridRun) -> dict[str, np.ndarray]:
    """Per interval: A(s), B(s), G(s) norms and the residual of (41) / (61') (both signs)."""
    m, n, S = d.m, d.n, run.intervals
    B = res.e_post.shape[1]
    out = {k: np.full(S, np.nan) for k in ("A_mixed", "B_mixed", "G_mixed", "A_2", "B_2", "Phi_max")}
    out["res_minus"] = np.full((S, B), np.nan)
    out["res_plus"] = np.full((S, B), np.nan)
    out["res_scale"] = np.full((S, B), np.nan)
    # the offsets and the period as simulated (whole nanoseconds), not as written in the scenario
    offsets = res.event_ns[:, 0] / ho.NS
    eAT = sla.expm(sc.A * (ho.to_ns(sc.T) / ho.NS))
    E = np.array([sla.expm(sc.A * t) if t else np.eye(n) for t in offsets])
    for s in range(1, S + 1):
        if not res.participating[s - 1].all():
            continue
        Phi = ho.transition_products(d.P, res.W[s - 1])
        As, Bs, G = ho.error_recursion(d, res.W[s - 1], sc.T, offsets, Phi=Phi, eAT=eAT, E=E)
        out["A_mixed"][s - 1] = jd.mixed_norm(As, [n] * m, [n] * m)
        out["B_mixed"][s - 1] = jd.mixed_norm(Bs, [n] * m, d.n_i)
        out["G_mixed"][s - 1] = jd.mixed_norm(G, [n] * m, [n])
        out["A_2"][s - 1] = np.linalg.norm(As, 2)
        out["B_2"][s - 1] = np.linalg.norm(Bs, 2)
        if s <= PHI_INTERVALS:      # (49) on the first intervals: q+1 mixed norms each
            out["Phi_max"][s - 1] = jd.mixed_norm(Phi, [n] * m, [n] * m).max()
        if run.noise:
            continue
        prev = res.e_post[s - 1].reshape(B, m * n)
        base = prev @ As.T + res.ebar[s - 1] @ Bs.T
        xg = res.x_nominal[s - 1] @ G.T
        cur = res.e_post[s].reshape(B, m * n)
        out["res_minus"][s - 1] = np.abs(cur - (base - xg)).max(axis=1)
        out["res_plus"][s - 1] = np.abs(cur - (base + xg)).max(axis=1)
        out["res_scale"][s - 1] = np.maximum.reduce([np.linalg.norm(res.x_event[s], axis=-1).max(axis=-1),
                                                     np.linalg.norm(res.x_event[s - 1], axis=-1).max(axis=-1),
                                                     np.abs(res.e_post[s - 1]).reshape(B, -1).max(axis=1),
                                                     np.linalg.norm(res.ebar[s - 1], axis=-1), np.ones(B)])
    return out


def kalman_reference(sc: HybridScenario, res: ho.HybridRun) -> dict[str, np.ndarray]:
    """A centralized Kalman filter (filterpy) on the stacked outputs y = C x sampled every DT_PLOT,
    trial 0; the harmonic input is modelled as white process noise of the same power."""
    from filterpy.kalman import KalmanFilter

    Cs = np.vstack(sc.C)
    n = sc.n
    kf = KalmanFilter(dim_x=n, dim_z=Cs.shape[0])
    kf.F = sla.expm(sc.A * DT_PLOT)
    kf.H = Cs
    b = sc.noise_b if sc.noise_b is not None else np.zeros(n)
    kf.Q = 0.5 * np.outer(b, b) * DT_PLOT + 1e-12 * np.eye(n)
    kf.R = 1e-6 * np.eye(Cs.shape[0])
    kf.x = np.zeros(n)
    kf.P = 100.0 * np.eye(n)
    errs = []
    for k, x in enumerate(res.x0):
        if k:
            kf.predict()
        kf.update(Cs @ x)
        errs.append(np.linalg.norm(kf.x - x))
    return {"kf_err": np.array(errs)}


# -- results ----------------------------------------------------------------------------------------

@dataclass
class Results:
    scenario: HybridScenario
    seed: int
    trials: int
    quick: bool
    design: dict[str, np.ndarray]
    runs: dict[str, dict[str, np.ndarray]] = field(default_factory=dict)
    is_paper: bool = False

    def run(self, name: str) -> ho.HybridRun:
        cache = self.__dict__.setdefault("_runs", {})
        if name not in cache:
            cache[name] = ho.HybridRun.from_arrays(self.runs[name])
        return cache[name]

    def spec(self, name: str) -> RunSpec:
        return next(r for r in self.scenario.runs if r.name == name)

    @property
    def obs(self) -> ho.ObserverDesign:
        if "_obs" not in self.__dict__:
            self.__dict__["_obs"] = observer_design(self.scenario)
        return self.__dict__["_obs"]


@dataclass
class MultiResults:
    """The paper reproduction checks two systems: the paper's example and a generic one."""

    parts: dict[str, Results]

    def __getitem__(self, key: str) -> Results:
        return self.parts[key]


def trial_count(sc: HybridScenario, opts: RunOptions) -> int:
    return opts.trials if opts.trials is not None else (sc.quick_trials if opts.quick else sc.trials)


def _cached_run(cache: StageCache, base: dict[str, Any], sc: HybridScenario, seed: int, trials: int,
                run: RunSpec) -> dict[str, np.ndarray]:
    return cache.get_or_compute("run", {**base, "run": run.key(), "seed": seed, "trials": trials if run.mc else 1},
                                functools.partial(simulate_run, sc, run, trials, seed), scenario=f"{sc.name}/{run.name}",
                                allow_nonfinite=NOT_APPLICABLE)


def compute(sc: HybridScenario, opts: RunOptions, cache: StageCache, *, is_paper: bool = False,
            extras: bool = False) -> Results:
    """`extras`: the design quantities only the paper's own claims use (see `compute_design`)."""
    trials = trial_count(sc, opts)
    base = {"scenario": sc.key(), "code": code_fingerprint(CODE_MODULES)}
    design = cache.get_or_compute("design", {**base, "seed": opts.seed, "extras": extras},
                                  lambda: compute_design(sc, opts.seed, extras), scenario=sc.name)
    work = functools.partial(_cached_run, cache, base, sc, opts.seed, trials)
    outs = parallel_map(work, list(sc.runs), workers=opts.workers, desc=f"{sc.name}: hybrid observer runs")
    return Results(sc, opts.seed, trials, opts.quick, design, {r.name: o for r, o in zip(sc.runs, outs)}, is_paper)
