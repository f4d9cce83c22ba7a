"""The hybrid observer: batched trials vs one trial at a time, the q-step estimator per
iteration, and the exhaustive ρ enumeration. Measurements, not tests."""
from __future__ import annotations

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


if __name__ == "__main__":
    for row in bench_hybrid():
        print(row)
