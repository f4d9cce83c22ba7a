"""Stages of the random-comm-filter family, each cached: deterministic bounds per scenario,
the gridded Monte Carlo per (scenario, λ), the exact event-driven Monte Carlo and the
frozen-clock-path Monte Carlo per scenario, and (paper only) the topology sweep S4."""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field

import numpy as np
import scipy.linalg as sla

import estimators.gossip_covariance as gc
import estimators.gossip_filter as gf
import estimators.kalman_bucy as kb
from estimators.linear_flows import abscissa_tolerance, van_loan
from pipeline.cache import StageCache, code_fingerprint
from pipeline.graphs import GraphSpec
from pipeline.matrix_moments import MatrixMoments
from pipeline.reproduction import RunOptions
from pipeline.seeding import stream_seed
from pipeline.simulate import parallel_map, run_blocks

from .scenario import FilterNetworkScenario, with_graph

CODE_MODULES = ("estimators.gossip_covariance", "estimators.gossip_filter", "estimators.kalman_bucy",
                "estimators.linear_flows", "pipeline.matrix_moments", "pipeline.simulate", "pipeline.seeding",
                "reproductions.tanwani.compute")
FILTERPY_FRACTIONS = (1.0, 0.5, 0.25, 0.125)
GRID_BLOCK = 2_500
EVENT_BLOCK = 1000
TOPOLOGIES = {"path": {"kind": "line", "n": 4}, "ring": {"kind": "ring", "n": 4},
              "star": {"kind": "edges", "n": 4, "edges": [[0, 1], [0, 2], [0, 3]]}, "complete": {"kind": "complete", "n": 4}}


@dataclass
class ScenarioResults:
    scenario: FilterNetworkScenario
    bounds: dict[str, np.ndarray]
    gridded: dict[float, dict[str, np.ndarray]]
    event: dict[str, np.ndarray]
    frozen: dict[str, np.ndarray]
    trials: int
    event_trials: int

    @property
    def sys(self) -> gf.GossipSystem:
        return self.scenario.system

    def grid_moments(self, rate: float) -> MatrixMoments:
        return MatrixMoments.from_arrays(self.gridded[rate], "e_")

    def event_moments(self) -> MatrixMoments:
        return MatrixMoments.from_arrays(self.event, "e_")

    def frozen_moments(self) -> MatrixMoments:
        return MatrixMoments.from_arrays(self.frozen, "e_")

    def bound(self, rate: float) -> np.ndarray:
        return self.bounds[f"bound_t_{self.scenario.rates.index(rate)}"]

    def joint(self, rate: float) -> np.ndarray | None:
        key = f"joint_t_{self.scenario.rates.index(rate)}"
        return self.bounds.get(key)


@dataclass
class Results:
    seed: int
    quick: bool
    is_paper: bool
    scenarios: dict[str, ScenarioResults]
    topology: dict[str, np.ndarray] | None = field(default=None)


def trial_counts(sc: FilterNetworkScenario, opts: RunOptions) -> tuple[int, int]:
    if opts.trials is not None:
        return opts.trials, max(50, opts.trials // 5)
    return (sc.quick_trials, sc.quick_event_trials) if opts.quick else (sc.trials, sc.event_trials)


def joint_ok(sys: gf.GossipSystem) -> bool:
    return sys.N * sys.n <= gc.MAX_JOINT_DIM


# -- bounds ----------------------------------------------------------------------------------------

QUICK_SWEEP_POINTS = 15
QUICK_TOPOLOGY_POINTS = 8
MAX_TEST_TIMES = 10        # output times at which the Monte Carlo means are tested
MAX_SWEEP_RATE = 1e9       # above it the abscissa of M_9 cannot be told from 0 (rounding ~ eps·λ)
MAX_SCHEME_DIM = 20        # N·n above which the gridded scheme's own mean covariance is not formed
PAIR_MAX = 5000            # trials kept one by one for the paired comparison of the two simulators
EPS = float(np.finfo(float).eps)


def directions(n: int) -> np.ndarray:
    """The test directions (q = n(n+1)/2, n): the axes e_a and (e_a + e_b)/√2 (a < b), in the
    order of `gc.vech_pairs`; the quadratic forms uᵀXu along them determine a symmetric X."""
    U = []
    for a, b in gc.vech_pairs(n):
        u = np.zeros(n)
        u[a] += 1.0
        u[b] += 1.0
        U.append(u / np.linalg.norm(u))
    return np.array(U)


def test_times(sc: FilterNetworkScenario) -> np.ndarray:
    """Indices (≥ 1) of at most MAX_TEST_TIMES output times spread evenly over (0, T]."""
    T = sc.n_outputs
    k = min(T, MAX_TEST_TIMES)
    return np.unique(np.round(np.linspace(T / k, T, k)).astype(int))


def quadratic_forms(U: np.ndarray, X: np.ndarray) -> np.ndarray:
    """uᵀXu for every direction: X (…, n, n) → (…, q)."""
    return np.einsum("da,...ab,db->...d", U, X, U)


def compute_bounds(sc: FilterNetworkScenario, quick: bool = False) -> dict[str, np.ndarray]:
    """Everything deterministic of one scenario (quick: a coarser λ sweep)."""
    s = sc.system
    N, n = s.N, s.n
    out: dict[str, np.ndarray] = {}
    Hs, Vs = np.vstack(s.H), sla.block_diag(*s.V)
    T = sc.n_outputs
    try:
        P_kb, K_kb = kb.kalman_bucy_steady(s.A, s.B, Hs, Vs)
        Ac = s.A - K_kb @ Hs
        if np.all(np.isfinite(P_kb)) and np.max(np.linalg.eigvals(Ac).real) < 0:
            out["P_kb"], out["K_kb"] = P_kb, K_kb
    except (np.linalg.LinAlgError, ValueError):
        pass
    out["P_kb_t"] = kb.kalman_bucy_riccati(s.A, s.B, Hs, Vs, s.P0, sc.output_step, T)
    for r, lam in enumerate(sc.rates):
        out[f"bound_t_{r}"] = gc.bound_transient(s, lam, sc.output_step, T)
        if joint_ok(s):
            out[f"joint_t_{r}"] = gc.joint_transient(s, lam, sc.output_step, T)
    out["crit_bound"] = np.array(gc.critical_rate_bound(s))
    if joint_ok(s):
        out["crit_joint"] = np.array(gc.critical_rate_joint(s, upper=float(out["crit_bound"])))
    out.update(test_cell_references(sc, out))
    abar = float(np.max(np.linalg.eigvals(s.Abar).real))
    out["abar_abscissa"] = np.array(abar)
    out["abar_tolerance"] = np.array(abscissa_tolerance(s.Abar))
    hurwitz = abar < -float(out["abar_tolerance"])
    if hurwitz:
        out["S"], out["R"] = gc.lyapunov_S(s), gc.lyapunov_R(s.Abar)
        out["S_true"] = gc.lyapunov_S_true(s)
        out["first_order"] = gc.first_order_deviation(s)
    lo, hi, pts = sc.sweep
    pts = min(pts, QUICK_SWEEP_POINTS) if quick else pts
    lams = np.geomspace(lo, hi, pts)
    extra = []
    if hurwitz:
        for variant in ("faithful", "tight"):
            c = gc.explicit_bound(s, variant)
            out[f"explicit_{variant}"] = np.array([c.C0, c.C1, c.C2, c.C3, c.a1, c.a2, c.sigma_G, c.sigma1_R, c.sigman_R,
                                                   c.kappa, c.fiedler, c.S_norm, c.threshold])
            if math.isfinite(c.threshold) and c.threshold > 0:
                extra += [c.threshold * f for f in (1.5, 3.0, 10.0, 30.0, 100.0)]
    lams = np.unique(np.concatenate([lams, [x for x in extra if x <= MAX_SWEEP_RATE]]))
    out["sweep"] = lams
    L = len(lams)
    P_inf, J_inf = np.full((L, N, n, n), np.nan), np.full((L, N, n, n), np.nan)
    dev_P, dev_J = np.full((L, N, n, n), np.nan), np.full((L, N, n, n), np.nan)
    err_P, err_J, cond_J = np.full(L, np.nan), np.full(L, np.nan), np.full(L, np.nan)
    absc9, tol9 = np.zeros(L), np.zeros(L)
    abscS = np.full(L, np.nan)
    for k, lam in enumerate(lams):
        absc9[k], tol9[k] = gc.bound_abscissa(s, lam), gc.bound_abscissa_tolerance(s, lam)
        p = gc.bound_steady(s, lam)
        if p is not None:
            P_inf[k] = p
        if hurwitz and (d := gc.bound_steady_deviation(s, lam, out["S"])) is not None:
            dev_P[k] = d
            err_P[k] = deviation_error(gc.bound_generator(s, lam)[0], d, s, out["S"])
        if joint_ok(s):
            M, g = gc.joint_generator_sym(s, lam)
            abscS[k] = float(np.max(np.linalg.eigvals(M).real))
            if abscS[k] < -abscissa_tolerance(M):
                lu = sla.lu_factor(M)
                cond_J[k] = 1.0 / max(sla.lapack.dgecon(lu[0], float(np.abs(M).sum(axis=0).max()), norm="1")[0], 1e-300)
                J_inf[k] = gc.diagonal_blocks(gc.from_sym_coords(sla.lu_solve(lu, -g), N * n), N, n)
                if hurwitz and s.mode == "edge":
                    dj = gc.joint_steady_deviation(s, lam, out["S_true"])
                    dev_J[k] = gc.diagonal_blocks(dj, N, n)
                    # as `deviation_error`: the residual's rounding is ~‖𝒜‖‖11ᵀ⊗S_true‖ ≤ ‖M‖‖S_true‖·N
                    err_J[k] = 10 * M.shape[0] * EPS * cond_J[k] * (np.abs(dj).max() + N * np.abs(out["S_true"]).max())
    out.update(sweep_bound=P_inf, sweep_joint=J_inf, sweep_dev_bound=dev_P, sweep_dev_joint=dev_J,
               sweep_dev_err=err_P, sweep_dev_joint_err=err_J, sweep_cond=cond_J,
               sweep_absc_bound=absc9, sweep_absc_tol=tol9, sweep_absc_joint=abscS)
    if hurwitz:
        for variant in ("faithful", "tight"):
            eb = gc.explicit_bound(s, variant)
            out[f"sweep_explicit_{variant}"] = np.array([eb.value(l) for l in lams])
    out.update(scheme_bias(sc))
    out.update(filterpy_reference(s, Hs, Vs, out.get("P_kb")))
    return out


def deviation_error(M: np.ndarray, D: np.ndarray, s, S: np.ndarray) -> float:
    """Round-off bound of the deviation D = 𝒫^∞ − S solved from M vec D = −r (`bound_steady_deviation`):
    10·dim·eps·κ(M)·(‖D‖ + ‖r‖/‖M‖) with the residual's own rounding ‖r‖ ~ 2‖A_i‖‖S‖ + ‖G_i‖
    and κ the 1-norm condition number (LAPACK estimate)."""
    lu = sla.lu_factor(M)
    norm = float(np.abs(M).sum(axis=0).max())
    kappa = 1.0 / max(sla.lapack.dgecon(lu[0], norm, norm="1")[0], 1e-300)
    r = max(2 * np.linalg.norm(A, 2) * np.linalg.norm(S, 2) + np.linalg.norm(G, 2) for A, G in zip(s.Ai, s.Gi))
    return 10 * M.shape[0] * EPS * kappa * (float(np.abs(D).max()) + r / norm)


def test_cell_references(sc: FilterNetworkScenario, b: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Exact references of the Monte Carlo test cells (main rate, `test_times` × nodes ×
    `directions`): the mean and second moment over clock paths of uᵀP_i(t; τ)u (eq. 14), the
    mean uᵀ𝒫_i(t)u of (9), the exact uᵀE[e_ie_iᵀ](t)u, and uᵀP_KB(t)u."""
    s = sc.system
    U, idx = directions(s.n), test_times(sc)
    q = len(U)
    out = {"cell_times": idx, "cell_dirs": U,
           "cell_bound": quadratic_forms(U, b["bound_t_0"][idx]),
           "cell_kb": quadratic_forms(U, b["P_kb_t"][idx])}
    if "joint_t_0" in b:
        out["cell_joint"] = quadratic_forms(U, gc.diagonal_blocks(b["joint_t_0"][idx], s.N, s.n))
    w = gc.vech_weights(U)
    weights = np.zeros((s.N * q, s.N * q))
    for i in range(s.N):
        weights[i * q:(i + 1) * q, i * q:(i + 1) * q] = w
    mom = gc.bound_second_moments(s, sc.main_rate, sc.output_step, sc.n_outputs, weights, check=True)
    if mom is not None:
        out["cell_P_mean"] = mom[0][idx].reshape(len(idx), s.N, q)
        out["cell_P_second"] = mom[1][idx].reshape(len(idx), s.N, q)
        out["cell_P_accuracy"] = np.array(mom[2])
    return out


def scheme_bias(sc: FilterNetworkScenario) -> dict[str, np.ndarray]:
    """The gridded simulator's own exact mean covariance minus the model's (main rate), at the
    scenario's step h and at h/2, on the output grid: its discretisation bias."""
    s = sc.system
    if s.N * s.n > MAX_SCHEME_DIM:
        return {}
    lam, h = sc.main_rate, sc.grid_step
    every = int(round(sc.output_step / h))
    exact = gc.diagonal_blocks(gc.joint_transient(s, lam, sc.output_step, sc.n_outputs), s.N, s.n)
    b1 = gc.diagonal_blocks(gc.gridded_scheme_covariance(s, lam, h, every * sc.n_outputs, every), s.N, s.n) - exact
    b2 = gc.diagonal_blocks(gc.gridded_scheme_covariance(s, lam, h / 2, 2 * every * sc.n_outputs, 2 * every),
                            s.N, s.n) - exact
    return {"scheme_bias_h": b1, "scheme_bias_h2": b2}


FILTERPY_MAX_STEPS = 6000


def _dare_residual(F, Qd, Hs, R, X) -> np.ndarray:
    Inn = Hs @ X @ Hs.T + R
    return F @ X @ F.T - F @ X @ Hs.T @ np.linalg.solve(Inn, Hs @ X @ F.T) + Qd - X


def filterpy_reference(s, Hs: np.ndarray, Vs: np.ndarray, P_kb: np.ndarray | None) -> dict[str, np.ndarray]:
    """filterpy's discrete filter on the sampled model at four sampling steps h, each run until its
    covariance stops changing (at most FILTERPY_MAX_STEPS steps; `filterpy_steady` says whether it
    did), with scipy's DARE solution X and what their difference may be: to first order an
    approximate solution Y of the DARE differs from the exact one by 𝒮⁻¹(R(Y)), 𝒮(Z) = Z − F_cZF_cᵀ
    (F_c the closed loop) and R the residual, so two approximate solutions differ by at most
    ‖𝒮⁻¹‖(‖R(X)‖ + ‖R(Y)‖), doubled for second-order terms, plus rounding (`filterpy_allow`).

    The steps scale with the fastest mode ν of the Kalman–Bucy closed loop A − P_KB HᵀV⁻¹H:
    h = min(0.1, 0.5/ν)·(1, 1/2, 1/4, 1/8), so that hν ≤ 1/2 (the first-order regime of
    the sampled filter)."""
    if P_kb is None:
        return {}
    Ac = s.A - P_kb @ Hs.T @ np.linalg.solve(Vs, Hs)
    nu = float(np.abs(np.linalg.eigvals(Ac)).max())
    hs = min(0.1, 0.5 / max(nu, 1e-12)) * np.array(FILTERPY_FRACTIONS)
    pri, post, dare, steady, allow = [], [], [], [], []
    for h in hs:
        F, Qd = van_loan(s.A, s.B @ s.B.T, h)
        X = sla.solve_discrete_are(F.T, Hs.T, Qd, Vs / h)
        Kd = X @ Hs.T @ np.linalg.inv(Hs @ X @ Hs.T + Vs / h)
        Fc = F @ (np.eye(s.n) - Kd @ Hs)
        inv_norm = 1.0 / float(np.linalg.svd(np.eye(s.n * s.n) - np.kron(Fc, Fc), compute_uv=False)[-1])
        prior, posterior = kb.discretised_kalman_covariances(s.A, s.B, Hs, Vs, s.P0, h, FILTERPY_MAX_STEPS,
                                                             until_steady=True)
        res = [float(np.linalg.norm(_dare_residual(F, Qd, Hs, Vs / h, Y), 2)) for Y in (X, prior[-1])]
        allow.append(2 * inv_norm * sum(res) + 10 * 4 * s.n * EPS * float(np.linalg.norm(X, 2)))
        pri.append(prior[-1]), post.append(posterior[-1]), dare.append(X)
        steady.append(len(prior) < FILTERPY_MAX_STEPS)
    return {"filterpy_h": hs, "filterpy_prior": np.array(pri), "filterpy_post": np.array(post),
            "dare_prior": np.array(dare), "filterpy_steady": np.array(steady), "filterpy_allow": np.array(allow),
            "kb_fastest_mode": np.array(nu)}


# -- Monte Carlo ------------------------------------------------------------------------------------

def simulate_gridded_rate(sc: FilterNetworkScenario, seed: int, trials: int, rate: float,
                          pair: int = 0) -> dict[str, np.ndarray]:
    """The gridded simulator at one rate: second-moment sums of the errors (MatrixMoments), a
    few sample trials, and (`pair` > 0, main rate) the test-cell values (uᵀe_i)² of the first
    `pair` trials one by one, for the paired comparison with the event-driven simulator."""
    s = sc.system
    n, N = s.n, s.N
    n_steps = int(round(sc.horizon / sc.grid_step))
    every = int(round(sc.output_step / sc.grid_step))
    U, idx = directions(n), test_times(sc)
    samples: dict[str, np.ndarray] = {}
    kept: list[np.ndarray] = []

    def block(size, rng):
        keep = 0 if samples else min(sc.sample_trials, size)
        run = gf.simulate_gridded(s, rate, sc.grid_step, n_steps, every, size, rng, keep_events=keep)
        if keep:
            samples["sample_z"] = run.z[:keep]
            samples["sample_events"] = run.events
        e = run.z[:, :, n:].reshape(size, -1, N, n)
        room = pair - sum(len(k) for k in kept)
        if room > 0:
            kept.append(np.square(e[:room, idx] @ U.T))
        return MatrixMoments.of(e)

    mom = run_blocks(block, MatrixMoments.combine, trials, stream_seed(seed, "gridded", sc.name, rate), GRID_BLOCK)
    out = {**mom.arrays("e_"), **samples}
    if pair:
        out["pair_values"] = np.concatenate(kept)
    return out


def simulate_event_rate(sc: FilterNetworkScenario, seed: int, trials: int) -> dict[str, np.ndarray]:
    """The exact event-driven simulator at the main rate. Besides the second-moment sums of the
    sampled errors and a few sample paths, it accumulates per test cell (`test_times` × node ×
    `directions`): sums of uᵀP_i(t; τ)u, uᵀΣ_ii(t; τ)u, (uᵀe_i)² and their squares; the sampled
    errors whitened by their own path's exact covariance (squared coordinates, summed, with
    their count); node event counts (sums and number of paths without event); the smallest
    eigenvalue of P_i − Σ_ii seen along every path; the first PAIR_MAX values of (uᵀe_i)²."""
    s = sc.system
    n, N = s.n, s.N
    rate = sc.main_rate
    times = sc.output_times
    U, idx = directions(n), test_times(sc)
    pairs = gc.vech_pairs(n)
    samples: dict[str, np.ndarray] = {}
    kept: list[np.ndarray] = []

    def block(size, rng):
        run = gf.simulate_event_driven(s, rate, times, size, rng)
        if not samples:
            k = min(sc.sample_trials, size)
            samples.update(sample_z=run.z[:k], sample_sigma=run.sigma[:k], sample_pbound=run.pbound[:k],
                           sample_event_times=run.event_times[:k], sample_event_clocks=run.event_clocks[:k])
        e = run.z[:, :, n:].reshape(size, -1, N, n)
        counts = np.zeros((size, N))
        valid = run.event_clocks >= 0
        for c, (i, j) in enumerate(s.clocks):
            hits = ((run.event_clocks == c) & valid).sum(axis=1)
            counts[:, i] += hits
            if s.mode == "edge":
                counts[:, j] += hits
        with np.errstate(invalid="ignore"):
            gaps = np.diff(run.event_times, axis=1)
        min_spacing = float(np.min(np.where(np.isfinite(gaps), gaps, np.inf))) if gaps.size else math.inf
        qP = quadratic_forms(U, run.pbound[:, idx])
        qS = quadratic_forms(U, run.sigma[:, idx])
        qE = np.square(e[:, idx] @ U.T)
        room = PAIR_MAX - sum(len(k) for k in kept)
        if room > 0:
            kept.append(qE[:room])
        w2, cnt = whitened_squares(run.sigma[:, idx], e[:, idx], pairs)
        return {"mom": MatrixMoments.of(e), "qP1": qP.sum(0), "qP2": np.square(qP).sum(0), "qS1": qS.sum(0),
                "qS2": np.square(qS).sum(0), "qE1": qE.sum(0), "qE2": np.square(qE).sum(0), "white": w2,
                "white_n": cnt, "c1": counts.sum(0), "c0": (counts == 0).sum(0), "spacing": min_spacing,
                "min_gap": run.min_gap.min(), "min_rel_gap": (run.min_gap / np.maximum(1.0, run.scale)).min(),
                "max_scale": run.scale.max(), "max_events": int(valid.sum(axis=1).max(initial=0)),
                "condition": run.condition, "n": size}

    def combine(parts):
        out = {"mom": MatrixMoments.combine([p["mom"] for p in parts])}
        for key in ("qP1", "qP2", "qS1", "qS2", "qE1", "qE2", "white", "white_n", "c1", "c0", "n"):
            out[key] = sum(p[key] for p in parts)
        for key in ("spacing", "min_gap", "min_rel_gap"):
            out[key] = min(p[key] for p in parts)
        for key in ("max_scale", "max_events", "condition"):
            out[key] = max(p[key] for p in parts)
        return out

    res = run_blocks(block, combine, trials, stream_seed(seed, "event", sc.name, rate), EVENT_BLOCK)
    arrays = res.pop("mom").arrays("e_")
    arrays.update({k: np.asarray(v) for k, v in res.items()})
    arrays.update(samples, pair_values=np.concatenate(kept))
    return arrays


WHITEN_RTOL = 1e-9      # eigenvalues of Σ_ii(t; τ) below this fraction of the largest are not whitened


def whitened_squares(sigma: np.ndarray, e: np.ndarray, pairs) -> tuple[np.ndarray, np.ndarray]:
    """Errors whitened by their own path's covariance: with Σ_ii(t; τ) = V diag(w) Vᵀ, the
    coordinates y = diag(w)^(-1/2) Vᵀ e_i are independent N(0, 1) given the clock path when the
    sampler is exact. Returns, per (time, node, cell), the sum over trials of y_a² (cells (a, a))
    and of (y_a + y_b)²/2 (cells (a, b), a < b; also N(0, 1)), and the number of terms (the
    coordinates with w ≤ WHITEN_RTOL·max w are left out: the errors there are rounding)."""
    w, V = np.linalg.eigh((sigma + np.swapaxes(sigma, -1, -2)) / 2)
    ok = w > WHITEN_RTOL * np.maximum(w[..., -1:], 1e-300)
    y = np.einsum("...ab,...a->...b", V, e) / np.sqrt(np.where(ok, w, 1.0))
    sq = np.stack([np.where(ok[..., a], y[..., a] ** 2, 0.0) if a == b
                   else np.where(ok[..., a] & ok[..., b], (y[..., a] + y[..., b]) ** 2 / 2, 0.0) for a, b in pairs], -1)
    cnt = np.stack([ok[..., a] if a == b else ok[..., a] & ok[..., b] for a, b in pairs], -1)
    return sq.sum(0), cnt.sum(0)


def simulate_frozen(sc: FilterNetworkScenario, seed: int, trials: int) -> dict[str, np.ndarray]:
    """One clock path, drawn once, shared by every trial: MC over (x0, ω, v) only."""
    s = sc.system
    n, N = s.n, s.N
    rng = np.random.Generator(np.random.SFC64(stream_seed(seed, "frozen-path", sc.name)))
    t, c = gf.sample_clock_events(len(s.clocks), sc.main_rate, sc.horizon, 1, rng)
    path = (t[0][np.isfinite(t[0])], c[0][c[0] >= 0])
    keep: dict[str, np.ndarray] = {}

    def block(size, rng):
        run = gf.simulate_event_driven(s, sc.main_rate, sc.output_times, size, rng, clock_path=path)
        if not keep:
            keep.update(path_sigma=run.sigma[0], path_pbound=run.pbound[0], path_min_gap=run.min_gap.min(axis=0))
        return MatrixMoments.of(run.z[:, :, n:].reshape(size, -1, N, n))

    mom = run_blocks(block, MatrixMoments.combine, trials, stream_seed(seed, "frozen", sc.name), 4 * EVENT_BLOCK)
    return {**mom.arrays("e_"), **keep, "path_times": path[0], "path_clocks": path[1]}


def compute_topology(sc: FilterNetworkScenario, quick: bool = False) -> dict[str, np.ndarray]:
    """S4: S2's plant and sensors on the path, ring, star and complete graphs of 4 nodes."""
    lams = np.geomspace(0.3, 1e4, QUICK_TOPOLOGY_POINTS if quick else 20)
    out: dict[str, np.ndarray] = {"lams": lams}
    for name, g in TOPOLOGIES.items():
        s = with_graph(sc, GraphSpec.from_dict(g), name)
        fied = float(np.sort(np.linalg.eigvalsh(s.laplacian))[1])
        out[f"{name}_alpha_fiedler"] = np.array(s.alpha * fied)
        S = gc.lyapunov_S(s)
        d, tr = np.full((len(lams), s.N), np.nan), np.full((len(lams), s.N), np.nan)
        gap = np.full(len(lams), np.nan)
        for k, lam in enumerate(lams):
            P = gc.bound_steady(s, lam)
            if P is not None:
                d[k] = np.linalg.norm(P - S, axis=(1, 2))
            Jm = gc.joint_steady(s, lam)
            if Jm is not None:
                Jd = gc.diagonal_blocks(Jm, s.N, s.n)
                tr[k] = np.trace(Jd, axis1=1, axis2=2)
                if P is not None:
                    gap[k] = np.linalg.eigvalsh(P - Jd)[:, 0].min()
        out[f"{name}_d"], out[f"{name}_trace_joint"], out[f"{name}_gap"] = d, tr, gap
        out[f"{name}_crit_bound"] = np.array(gc.critical_rate_bound(s))
    return out


# -- the driver --------------------------------------------------------------------------------------

def _nonfinite_allowed(stage: str, sc: FilterNetworkScenario) -> tuple[str, ...]:
    """Arrays where inf/NaN is a result, not a failure: a bound that diverges below the critical
    rate, an explicit bound below its threshold, the inf padding of event lists, Monte Carlo
    states that overflow on a strongly unstable scenario over a long horizon (the claims then
    say that nothing finite was compared)."""
    mc = ("e_s2", "e_s4", "sample_z", "pair_values")
    if stage == "bounds":
        return (("sweep_bound", "sweep_joint", "sweep_dev_bound", "sweep_dev_joint", "sweep_absc_joint",
                 "sweep_explicit_faithful", "sweep_explicit_tight", "crit_bound", "crit_joint", "explicit_faithful",
                 "explicit_tight", "P_kb_t", "cell_bound", "cell_joint", "cell_P_mean", "cell_P_second", "cell_P_accuracy",
                 "scheme_bias_h", "scheme_bias_h2", "sweep_dev_err", "sweep_dev_joint_err", "sweep_cond")
                + tuple(f"bound_t_{k}" for k in range(len(sc.rates))) + tuple(f"joint_t_{k}" for k in range(len(sc.rates))))
    if stage == "event":
        return mc + ("sample_event_times", "spacing", "sample_sigma", "sample_pbound", "qP1", "qP2", "qS1", "qS2",
                     "qE1", "qE2", "white", "min_gap", "min_rel_gap", "max_scale", "condition")
    if stage in ("gridded", "frozen"):
        return mc + ("path_sigma", "path_pbound", "path_min_gap")
    if stage == "topology":
        return tuple(f"{g}_{k}" for g in TOPOLOGIES for k in ("d", "trace_joint", "crit_bound", "gap"))
    return ()


def _work(item):
    cache, stage, params, fn, sc = item
    return cache.get_or_compute(stage, params, fn, scenario=sc.name, allow_nonfinite=_nonfinite_allowed(stage, sc))


def compute(scenarios: list[FilterNetworkScenario], opts: RunOptions, cache: StageCache, *, is_paper: bool) -> Results:
    code = code_fingerprint(CODE_MODULES)
    items, index = [], []
    for sc in scenarios:
        trials, ev_trials = trial_counts(sc, opts)
        base = {"scenario": sc.key(), "code": code}
        mc = {**base, "seed": opts.seed}
        items.append((cache, "bounds", {**base, "quick": opts.quick}, functools.partial(compute_bounds, sc, opts.quick),
                      sc))
        index.append((sc.name, "bounds", None))
        for rate in sc.rates:
            pair = min(ev_trials, trials, PAIR_MAX) if rate == sc.main_rate else 0
            items.append((cache, "gridded", {**mc, "trials": trials, "rate": rate, "samples": sc.sample_trials,
                                             "pair": pair},
                          functools.partial(simulate_gridded_rate, sc, opts.seed, trials, rate, pair), sc))
            index.append((sc.name, "gridded", rate))
        items.append((cache, "event", {**mc, "trials": ev_trials, "samples": sc.sample_trials},
                      functools.partial(simulate_event_rate, sc, opts.seed, ev_trials), sc))
        index.append((sc.name, "event", None))
        items.append((cache, "frozen", {**mc, "trials": ev_trials},
                      functools.partial(simulate_frozen, sc, opts.seed, ev_trials), sc))
        index.append((sc.name, "frozen", None))
    if is_paper:
        s2 = next(sc for sc in scenarios if sc.name == "s2")
        items.append((cache, "topology", {"scenario": s2.key(), "code": code, "quick": opts.quick},
                      functools.partial(compute_topology, s2, opts.quick),
                      s2))
        index.append(("s2", "topology", None))
    # the longest stages first, so that two workers finish together
    order = sorted(range(len(items)), key=lambda k: {"event": 0, "gridded": 1, "frozen": 2}.get(index[k][1], 3))
    done = parallel_map(_work, [items[k] for k in order], workers=opts.workers, desc="random-comm-filter stages")
    got = {index[k]: v for k, v in zip(order, done)}
    results: dict[str, ScenarioResults] = {}
    for sc in scenarios:
        trials, ev_trials = trial_counts(sc, opts)
        results[sc.name] = ScenarioResults(sc, got[(sc.name, "bounds", None)],
                                           {r: got[(sc.name, "gridded", r)] for r in sc.rates},
                                           got[(sc.name, "event", None)], got[(sc.name, "frozen", None)],
                                           trials, ev_trials)
    topo = got.get(("s2", "topology", None)) if is_paper else None
    return Results(opts.seed, opts.quick, is_paper, results, topo)
