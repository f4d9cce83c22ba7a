"""Random-communication filters (tanwani): the gridded simulator (exact flow over h/2, Poisson
rings, exact flow over h/2) batched over trials against the same simulator called one trial at a
time; the exact event-driven simulator; and the bounds: ODE (9) by its augmented matrix
exponential against a naive fixed-step RK4 integrator and scipy's adaptive RK45, and the
Kalman-Bucy Riccati equation by its Hamiltonian exponential against scipy's RK45."""
from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import numpy as np  # noqa: E402
import scipy.linalg as sla  # noqa: E402
from scipy.integrate import solve_ivp  # noqa: E402

import dse.estimators.gossip_covariance as gc  # noqa: E402
import dse.estimators.gossip_filter as gf  # noqa: E402
import dse.estimators.kalman_bucy as kb  # noqa: E402
from dse.families.tanwani import monte_carlo  # noqa: E402
from dse.families.tanwani.scenario import load_scenario  # noqa: E402

from .common import bound_row, estimator_row, spread, timed  # noqa: E402

TARGET_US = 0.3


def bench_gridded(quick: bool = False, repeats: int = 3) -> list[dict]:
    """µs per trial-node-step of `gossip_filter.simulate_gridded` (a step is one grid step h,
    i.e. two exact half-step flows and the Poisson rings), batched vs one trial per call."""
    rows = []
    names = ("s2",) if quick else ("s1a", "s2", "s3")
    for name in names:
        sc = load_scenario(name)
        s = sc.gossip
        horizon = 2.0 if quick else sc.horizon
        steps = int(round(horizon / sc.grid_step))
        every = int(round(sc.output_step / sc.grid_step))
        trials = 1_000 if quick else 2_500
        loop_trials = 5 if quick else 20
        rng = np.random.default_rng(0)
        per = steps * s.N
        batched = timed(lambda: gf.simulate_gridded(s, sc.main_rate, sc.grid_step, steps, every, trials, rng),
                        repeats, per=per * trials, warmup=True)
        loop = timed(lambda: [gf.simulate_gridded(s, sc.main_rate, sc.grid_step, steps, every, 1, rng)
                              for _ in range(loop_trials)], repeats, per=per * loop_trials)
        rows.append(estimator_row(f"tanwani gridded {name}, λ={sc.main_rate:g}, h={sc.grid_step:g}",
                                  f"N={s.N}, n={s.n}, {trials:,} trials, t≤{horizon:g}", nodes=s.N, state_dim=s.n,
                                  trials=trials, steps=steps, batched=batched, loop=loop,
                                  loop_what="same simulator, 1 trial per call", loop_trials=loop_trials,
                                  target=f"<= {TARGET_US} µs", met=batched[0] <= TARGET_US))
    return rows


def bench_event(quick: bool = False, repeats: int = 3) -> list[dict]:
    """The exact event-driven simulator (per-path Σ and P propagated with every trial's own
    inter-event times): µs per trial-node-output-step, batched vs one trial per call."""
    sc = load_scenario("s2")
    s = sc.gossip
    times = sc.output_times if not quick else sc.output_times[sc.output_times <= 2.0 + 1e-9]
    trials, loop_trials = (200, 3) if quick else (1_000, 10)
    rng = np.random.default_rng(0)
    per = (len(times) - 1) * s.N
    batched = timed(lambda: gf.simulate_event_driven(s, sc.main_rate, times, trials, rng), repeats, per=per * trials)
    loop = timed(lambda: [gf.simulate_event_driven(s, sc.main_rate, times, 1, rng) for _ in range(loop_trials)],
                 repeats, per=per * loop_trials)
    return [estimator_row(f"tanwani exact event-driven s2 (+ per-path Σ, P), λ={sc.main_rate:g}",
                          f"N={s.N}, n={s.n}, {trials:,} trials, t≤{times[-1]:g}", nodes=s.N, state_dim=s.n,
                          trials=trials, steps=len(times) - 1, batched=batched, loop=loop,
                          loop_what="same simulator, 1 trial per call", loop_trials=loop_trials,
                          unit="µs/trial-node-output-step",
                          note="covariance propagation per trial (not a fixed-gain filter)")]


def _rk4(M, g, p0, step, n_steps, sub):
    """Naive fixed-step RK4 on ṗ = M p + g, `sub` substeps per output step."""
    h = step / sub
    out = np.empty((n_steps + 1, len(p0)))
    out[0] = p = p0.copy()
    f = lambda v: M @ v + g  # noqa: E731
    for k in range(n_steps):
        for _ in range(sub):
            k1 = f(p)
            k2 = f(p + 0.5 * h * k1)
            k3 = f(p + 0.5 * h * k2)
            k4 = f(p + h * k3)
            p = p + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        out[k + 1] = p
    return out


def bench_bounds(quick: bool = False, repeats: int = 3) -> list[dict]:
    rows = []
    for name in (("s2",) if quick else ("s2", "s3")):
        sc = load_scenario(name)
        s = sc.gossip
        T = sc.n_outputs
        lam = sc.main_rate
        exact = gc.bound_transient(s, lam, sc.output_step, T).reshape(T + 1, -1)
        M, g = gc.bound_generator(s, lam)
        p0 = np.concatenate([gc.vec(P) for P in s.P_init])
        fast = timed(lambda: gc.bound_transient(s, lam, sc.output_step, T), repeats, per=1e3)
        sub = 10
        rk4 = _rk4(M, g, p0, sc.output_step, T, sub)
        naive = timed(lambda: _rk4(M, g, p0, sc.output_step, T, sub), repeats, per=1e3)
        scale = np.abs(exact).max()
        rows.append(bound_row(f"tanwani ODE (9) {name}, λ={lam:g}, {T} outputs (dim {len(p0)})", fast=fast,
                              fast_what="augmented expm, one matrix exponential", naive=naive,
                              naive_what=f"RK4, h = output step/{sub}",
                              max_diff=float(np.abs(rk4 - exact).max() / scale)))
        t_eval = np.arange(T + 1) * sc.output_step
        ivp = lambda: solve_ivp(lambda t, p: M @ p + g, (0, t_eval[-1]), p0, t_eval=t_eval, rtol=1e-10,  # noqa: E731
                                atol=1e-12 * scale).y.T
        naive = timed(ivp, repeats, per=1e3)
        rows.append(bound_row(f"tanwani ODE (9) {name}, λ={lam:g}", fast=fast, fast_what="augmented expm", naive=naive,
                              naive_what="scipy RK45 rtol 1e-10", max_diff=float(np.abs(ivp() - exact).max() / scale)))
        Hs, Vs = np.vstack(s.H), sla.block_diag(*s.V)
        exact_kb = kb.kalman_bucy_riccati(s.A, s.B, Hs, Vs, s.P0, sc.output_step, T)
        fast = timed(lambda: kb.kalman_bucy_riccati(s.A, s.B, Hs, Vs, s.P0, sc.output_step, T), repeats, per=1e3)
        S = Hs.T @ np.linalg.solve(Vs, Hs)
        BB = s.B @ s.B.T
        n = s.n

        def riccati(t, p):
            P = p.reshape(n, n)
            return (s.A @ P + P @ s.A.T + BB - P @ S @ P).ravel()

        kb_ivp = lambda: solve_ivp(riccati, (0, t_eval[-1]), s.P0.ravel(), t_eval=t_eval, rtol=1e-10,  # noqa: E731
                                   atol=1e-12).y.T.reshape(T + 1, n, n)
        naive = timed(kb_ivp, repeats, per=1e3)
        rows.append(bound_row(f"tanwani Kalman-Bucy Riccati {name}, {T} outputs", fast=fast,
                              fast_what="Hamiltonian expm, Möbius step", naive=naive, naive_what="scipy RK45 rtol 1e-10",
                              max_diff=float(np.abs(kb_ivp() - exact_kb).max() / np.abs(exact_kb).max())))
    return rows


def bench_s2_budget(repeats: int = 2) -> dict:
    """The S2 gridded Monte Carlo at the scale the project sets itself (10,000 trials to t = 10, h = 0.01,
    streamed moments included; budget 30 s)."""
    sc = load_scenario("s2")
    walls = []
    for rep in range(repeats):
        walls.append(timed(lambda: monte_carlo.simulate_gridded_rate(sc, rep, 10_000, sc.main_rate), 1)[0] / 1e6)
    w = spread(walls)
    return {"name": "tanwani S2 gridded Monte Carlo, 10,000 trials, t in [0, 10], h = 0.01 (budget 30 s)",
            "wall_s": w[0], "spread": w[1], "within_budget": w[0] < 30.0}


if __name__ == "__main__":
    for row in bench_gridded(True, 1) + bench_event(True, 1) + bench_bounds(True, 1):
        print(row)
