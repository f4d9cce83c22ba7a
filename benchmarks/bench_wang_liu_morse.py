"""The hybrid observer: batched trials vs one trial at a time, the q-step estimator per
iteration, and the exhaustive ρ enumeration. Measurements, not tests."""
from __future__ import annotations

import dataclasses
import statistics
import time

import numpy as np

import estimators.hybrid_observer as ho
import estimators.jointly_observable_design as jd
from reproductions.wang_liu_morse import compute
from reproductions.wang_liu_morse.scenario import generic_scenario, paper_scenario


def _simulate(sc, run, x0, w0, xh):
    d = compute.observer_design(sc)
    timing = ho.Timing(sc.T, run.q, run.Delta, run.beta, np.asarray(run.offsets, float))
    return ho.simulate(d, timing, compute.schedule_for(sc, run), x0=x0, w0=w0, xhat0=xh, intervals=run.intervals,
                       central_gain=compute.central_gain(sc))


def bench_hybrid(trials: int = 256, repeats: int = 3) -> list[dict]:
    rows = []
    for sc in (paper_scenario(), generic_scenario()):
        run = next(r for r in sc.runs if r.name == "sync")
        rng = np.random.default_rng(0)
        d = compute.observer_design(sc)
        x0 = rng.standard_normal((trials, sc.n))
        w0 = rng.standard_normal((trials, sum(d.n_i)))
        xh = rng.standard_normal((trials, sc.m, sc.n))
        batched, single = [], []
        for _ in range(repeats):
            t0 = time.perf_counter()
            _simulate(sc, run, x0, w0, xh)
            batched.append((time.perf_counter() - t0) / trials)
            t0 = time.perf_counter()
            for b in range(4):
                _simulate(sc, run, x0[b:b + 1], w0[b:b + 1], xh[b:b + 1])
            single.append((time.perf_counter() - t0) / 4)
        b, s = statistics.median(batched), statistics.median(single)
        rows.append({"name": f"hybrid observer {sc.name}/sync: m={sc.m}, q={run.q}, {run.intervals} intervals",
                     "trials": trials, "batched_ms_per_trial": 1e3 * b, "single_trial_ms": 1e3 * s,
                     "iterations_per_s_batched": run.q * run.intervals * trials / (b * trials), "ratio": s / b})
    P = compute.observer_design(paper_scenario()).P
    t0 = time.perf_counter()
    res = jd.rho_exact(P)
    rows.append({"name": "ρ by exhaustive enumeration, m = 4 (minimal complete words)", "words": res.words,
                 "wall_ms": 1e3 * (time.perf_counter() - t0)})
    return rows


def bench_hybrid_rows(quick: bool = False, repeats: int = 3) -> list[dict]:
    """Side-by-side rows: µs per trial-node-iteration (one iteration = one of the q estimator
    updates of an interval; nodes = the m agents), batched trials vs one trial per call."""
    from .common import estimator_row, timed

    rows = []
    sizes = [(paper_scenario(), None, (64,) if quick else (64, 1024))]
    if not quick:   # generic: q = 786 iterations per interval; 8 of its 80 intervals keep the run short
        sizes.append((generic_scenario(), 8, (256,)))
    for sc, intervals, trial_sizes in sizes:
        run = next(r for r in sc.runs if r.name == "sync")
        if intervals is not None:
            run = dataclasses.replace(run, intervals=intervals)
        d = compute.observer_design(sc)
        for trials in trial_sizes:
            rng = np.random.default_rng(0)
            x0 = rng.standard_normal((trials, sc.n))
            w0 = rng.standard_normal((trials, sum(d.n_i)))
            xh = rng.standard_normal((trials, sc.m, sc.n))
            steps = run.q * run.intervals
            per = steps * sc.m
            batched = timed(lambda: _simulate(sc, run, x0, w0, xh), repeats, per=per * trials, warmup=True)
            loop_trials = 2 if quick else 4
            loop = timed(lambda: [_simulate(sc, run, x0[b:b + 1], w0[b:b + 1], xh[b:b + 1]) for b in range(loop_trials)],
                         repeats, per=per * loop_trials)
            rows.append(estimator_row(f"hybrid observer {sc.name}/sync, q={run.q}, {run.intervals} intervals",
                                      f"m={sc.m}, n={sc.n}, {trials:,} trials", nodes=sc.m, state_dim=sc.n, trials=trials,
                                      steps=steps, batched=batched, loop=loop, loop_what="same simulator, 1 trial per call",
                                      loop_trials=loop_trials, unit="µs/trial-node-iteration",
                                      note="hybrid: continuous flow + q discrete iterations per interval"))
    return rows


def bench_rho(repeats: int = 3) -> dict:
    from .common import bound_row, timed

    P = compute.observer_design(paper_scenario()).P
    words = jd.rho_exact(P).words
    t = timed(lambda: jd.rho_exact(P), repeats, per=1e3)
    return bound_row(f"wang-liu-morse ρ by exhaustive enumeration, m = 4 ({words} minimal complete words)", fast=t,
                     fast_what="batched word products")


if __name__ == "__main__":
    for row in bench_hybrid_rows(True, 1) + [bench_rho(1)]:
        print(row)
