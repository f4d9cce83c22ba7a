"""The noisy-consensus filters (savas): the batched simulator against a per-trial loop at three
sizes, the exact covariance computations against their naive versions, and the whole Fig. 1
Monte Carlo (200,000 trials per cell, the paper's scale) through the pipeline."""
from __future__ import annotations

import functools
import time
from pathlib import Path

import numpy as np

import dse.estimators.consensus_covariance as cc
import dse.estimators.consensus_filter as cf
import dse.estimators.consensus_trace as ct
import dse.families
from dse.contract.options import RunOptions
from dse.families.savas import cells, monte_carlo
from dse.simulate.units import parallel_map

from .common import bound_row, estimator_row, timed

TARGET_US = 0.3
#: one Carli and one re-injection cell at 2,000 trials per point (the sweep-scaling benchmark's points)
SWEEP_POINTS = Path(__file__).with_name("sweep_scaling.toml")


def _loop_filter(Q, *, ell, m, sigma_c, q, r, sigma0, n_steps, n_trials, rng, reinjection=False, zeta=1.0):
    """The straightforward implementation: one trial at a time, one agent vector per step
    (eqs (7)+(9), or (11)-(13) with re-injection)."""
    N = len(Q)
    errs = np.empty((n_trials, n_steps, N))
    for t in range(n_trials):
        x = np.sqrt(sigma0) * rng.standard_normal()
        xp = np.zeros(N)
        for k in range(n_steps):
            errs[t, k] = x - xp
            xf = (1 - ell) * xp + ell * (x + np.sqrt(r) * rng.standard_normal(N))
            z = xf
            for _ in range(m):
                z = Q @ z + sigma_c * rng.standard_normal(N) + (xf if reinjection else 0.0)
            xp = zeta * xf + (1 - zeta) * z / (m + 1) if reinjection else z
            x = x + np.sqrt(q) * rng.standard_normal()
    return errs


def ring_matrix(N: int) -> np.ndarray:
    """Doubly stochastic ring: weight 1/3 on self and on each neighbour."""
    Q = np.zeros((N, N))
    for i in range(N):
        for j in (i - 1, i, i + 1):
            Q[i, j % N] += 1.0 / 3.0
    return Q


def paper_scenario():
    return dse.families.paper("savas").scenario


def _sizes(quick: bool):
    sc = paper_scenario()
    sizes = [("Carli (7)+(9), paper Q", sc.Q, 1, False), ("Carli (7)+(9), paper Q", sc.Q, 5, False),
             ("re-injection (11)-(13), paper Q", sc.Q, 5, True), ("Carli (7)+(9), ring", ring_matrix(10), 5, False)]
    return sc, (sizes[1:3] if quick else sizes)


def bench_filter(quick: bool = False, repeats: int = 3) -> list[dict]:
    sc, sizes = _sizes(quick)
    trials, loop_trials, steps = (20_000, 200, 10) if quick else (200_000, 2_000, 10)
    rows = []
    for label, Q, m, reinj in sizes:
        N = len(Q)
        kw = dict(ell=0.25, m=m, sigma_c=1.0, q=sc.model.q, r=sc.model.r, sigma0=sc.model.sigma0, n_steps=steps)
        zeta = 0.5 if reinj else 1.0
        rng = np.random.default_rng(0)
        batched = timed(lambda: cf.simulate_consensus_filter(Q, x0_mean=0.0, n_trials=trials, rng=rng, reinjection=reinj,
                                                             zeta=zeta, **kw), repeats, per=trials * steps * N, warmup=True)
        loop = timed(lambda: _loop_filter(Q, n_trials=loop_trials, rng=rng, reinjection=reinj, zeta=zeta, **kw), repeats,
                     per=loop_trials * steps * N)
        rows.append(estimator_row(f"savas {label}, m={m}", f"N={N}, n=1, {trials:,} trials", nodes=N, state_dim=1,
                                  trials=trials, steps=steps, batched=batched, loop=loop,
                                  loop_what="per-trial Python loop", loop_trials=loop_trials,
                                  target=f"<= {TARGET_US} µs", met=batched[0] <= TARGET_US))
    return rows


def bench_bounds(quick: bool = False, repeats: int = 3) -> list[dict]:
    """Exact covariances of the filters: recursion (22) vs the unrolled sum of matrix powers (23);
    the steady state (15) by a discrete Lyapunov solve and by the spectral closed form vs the
    truncated series."""
    sc = paper_scenario()
    rows = []
    for N, Q in ((3, sc.Q), (10, ring_matrix(10))):
        kw = dict(ell=0.25, m=5, sigma_c=1.0, q=sc.model.q, r=sc.model.r, reinjection=True, zeta=0.5)
        K = 200
        seq = cc.predictive_covariance_sequence(Q, sigma0=sc.model.sigma0, n_steps=K, **kw)
        unr = cc.predictive_covariance_unrolled(Q, sigma0=sc.model.sigma0, n_steps=K, **kw)
        fast = timed(lambda: cc.predictive_covariance_sequence(Q, sigma0=sc.model.sigma0, n_steps=K, **kw), repeats, per=1e3)
        naive = timed(lambda: cc.predictive_covariance_unrolled(Q, sigma0=sc.model.sigma0, n_steps=K, **kw), repeats, per=1e3)
        rows.append(bound_row(f"savas P(k|k-1), k < {K}, N={N}", fast=fast, fast_what="recursion (22)", naive=naive,
                              naive_what="unrolled powers (23)", max_diff=float(np.abs(seq - unr).max() / np.abs(seq).max())))
        lyap = cc.asymptotic_covariance_lyapunov(Q, **kw)
        ser = cc.asymptotic_covariance_series(Q, **kw)
        fast = timed(lambda: cc.asymptotic_covariance_lyapunov(Q, **kw), repeats, per=1e3)
        naive = timed(lambda: cc.asymptotic_covariance_series(Q, **kw), repeats, per=1e3)
        rows.append(bound_row(f"savas steady P (15), N={N}", fast=fast, fast_what="discrete Lyapunov solve", naive=naive,
                              naive_what="truncated series to 1e-16",
                              max_diff=float(np.abs(lyap - ser).max() / np.abs(ser).max())))
        if N == 3 or not quick:
            tr = ct.trace_formula_corrected(Q, ell=0.25, zeta=0.5, m=5, sigma_c=1.0, q=sc.model.q, r=sc.model.r)
            fast = timed(lambda: ct.trace_formula_corrected(Q, ell=0.25, zeta=0.5, m=5, sigma_c=1.0, q=sc.model.q, r=sc.model.r),
                         repeats, per=1e3)
            rows.append(bound_row(f"savas steady trace (16) corrected, N={N}", fast=fast, fast_what="spectral closed form",
                                  naive=naive, naive_what="trace of truncated series",
                                  max_diff=abs(float(tr) - float(np.trace(ser))) / float(np.trace(ser))))
    return rows


def bench_fig1(workers: int, trials: int = 200_000) -> dict:
    """All Fig. 1 cells (7 σ_c × 6 m, Carli's filter, `trials` each, k = 0..9), no cache; the
    σ_c values of one m share their random draws (one run per m)."""
    sc = paper_scenario()
    sw = sc.sweep
    fig1 = [cells.Cell("carli", m, s, sc.carli.ell, 1.0, sw.n_steps) for m in sw.rounds for s in sw.sigma_c]
    steps = cells.scenario_steps(sc)
    budget = RunOptions(workers=workers).chunk_budget_bytes()
    groups = sorted(monte_carlo.cell_groups(fig1), key=lambda g: -g[0].m)
    t0 = time.perf_counter()
    parallel_map(functools.partial(monte_carlo.simulate_group, sc, 0, trials, steps, budget), groups, workers=workers)
    wall = time.perf_counter() - t0
    return {"name": f"Fig. 1 Monte Carlo, {len(fig1)} cells × {trials:,} trials, workers={workers}", "wall_s": wall,
            "us_per_trial_node_step": wall / (len(fig1) * trials * 10 * sc.n) * 1e6}


def bench_sweep_point(points: int = 40, sweep: Path = SWEEP_POINTS) -> dict:
    """The per-point path of `dse sweep` in process (`dse.sweeps.run.run_point`: compute, claims, tables,
    metrics; no figures, no recordings) on the points of `sweep`, after one warm-up point: wall and CPU
    per point, the Monte Carlo kernel's share (the filters' simulation, `consensus_filter_moments`) and the
    rest (design with the gain optimisation, filterpy's reference, claims, tables), the overhead."""
    from dse.sweeps import run as sw
    from dse.scenario.fields import load_toml
    from dse.sweeps.spec import parse_sweep

    spec = parse_sweep(load_toml(sweep), base_dir=sweep.parent)
    tasks = sw.build_tasks(spec)[: points + 1]
    kernel = np.zeros(2)   # wall, CPU
    original = cf.consensus_filter_moments

    def timed_kernel(*args, **kwargs):
        t = np.array([time.perf_counter(), time.process_time()])
        try:
            return original(*args, **kwargs)
        finally:
            kernel[:] += np.array([time.perf_counter(), time.process_time()]) - t

    cf.consensus_filter_moments = timed_kernel
    try:
        sw.run_point(tasks[0].payload())
        kernel[:] = 0.0
        w, c = time.perf_counter(), time.process_time()
        for task in tasks[1:]:
            sw.run_point(task.payload())
        wall, cpu, n = time.perf_counter() - w, time.process_time() - c, len(tasks) - 1
    finally:
        cf.consensus_filter_moments = original
    ms = 1e3 / n
    kernel = [float(k) for k in kernel]
    return {"name": f"sweep point in process ({sweep.name}, {n} points)", "wall_ms": wall * ms, "cpu_ms": cpu * ms,
            "monte_carlo_ms": kernel[0] * ms, "monte_carlo_cpu_ms": kernel[1] * ms, "overhead_ms": (wall - kernel[0]) * ms,
            "overhead_cpu_ms": (cpu - kernel[1]) * ms, "target": "overhead <= 10 ms",
            "met": (wall - kernel[0]) / n <= 0.010}


if __name__ == "__main__":
    for row in bench_filter() + bench_bounds():
        print(row)
    for w in (1, 2):
        print(bench_fig1(w))
    print(bench_sweep_point())
