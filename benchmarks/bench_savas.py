"""The noisy-consensus filters: batched simulator against a per-trial loop, and the whole
Fig. 1 Monte Carlo (200,000 trials per cell, the paper's scale) through the pipeline."""
from __future__ import annotations

import functools
import statistics
import time

import numpy as np

import estimators.consensus_filter as cf
from pipeline.simulate import parallel_map
from reproductions.savas import compute
from reproductions.savas.scenario import paper_scenario


def _loop_filter(Q, *, ell, m, sigma_c, q, r, sigma0, n_steps, n_trials, rng):
    """The straightforward implementation: one trial at a time, one agent vector per step."""
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
                z = Q @ z + sigma_c * rng.standard_normal(N)
            xp = z
            x = x + np.sqrt(q) * rng.standard_normal()
    return errs


def bench_filter(repeats: int = 3) -> list[dict]:
    sc = paper_scenario()
    rows = []
    for m in (1, 5):
        kw = dict(ell=0.25, m=m, sigma_c=1.0, q=sc.q, r=sc.r, sigma0=sc.sigma0, n_steps=10)
        batched, loop = [], []
        for rep in range(repeats):
            rng = np.random.default_rng(rep)
            t0 = time.perf_counter()
            cf.simulate_consensus_filter(sc.Q, x0_mean=0.0, n_trials=200_000, rng=rng, reinjection=False, **kw)
            batched.append((time.perf_counter() - t0) / (200_000 * 10 * sc.n) * 1e6)
            t0 = time.perf_counter()
            _loop_filter(sc.Q, n_trials=2_000, rng=rng, **kw)
            loop.append((time.perf_counter() - t0) / (2_000 * 10 * sc.n) * 1e6)
        b, lp = statistics.median(batched), statistics.median(loop)
        rows.append({"name": f"two-stage consensus filter, N=3, m={m}", "trials": 200_000, "steps": 10,
                     "batched_us_per_trial_node_step": b, "batched_spread": (min(batched), max(batched)),
                     "loop_us_per_trial_node_step": lp, "loop_spread": (min(loop), max(loop)), "ratio": lp / b})
    return rows


def bench_fig1(workers: int) -> dict:
    """All Fig. 1 cells (7 σ_c × 6 m, Carli's filter, 200,000 trials each, k = 0..9), no cache; the
    σ_c values of one m share their random draws (one run per m)."""
    sc = paper_scenario()
    cells = [compute.Cell("carli", m, s, sc.carli_ell, 1.0, sc.n_steps) for m in sc.rounds for s in sc.sigma_c]

    groups = sorted(compute.cell_groups(cells), key=lambda g: -g[0].m)
    t0 = time.perf_counter()
    parallel_map(functools.partial(compute.simulate_group, sc, 0, 200_000), groups, workers=workers)
    wall = time.perf_counter() - t0
    return {"name": f"Fig. 1 Monte Carlo, {len(cells)} cells × 200,000 trials, workers={workers}", "wall_s": wall,
            "us_per_trial_node_step": wall / (len(cells) * 200_000 * 10 * sc.n) * 1e6}


if __name__ == "__main__":
    for row in bench_filter():
        print(row)
    for w in (1, 2):
        print(bench_fig1(w))
