"""Random-communication filters: the S2 Monte Carlo at the required scale (10,000 trials to t = 10,
gridded simulator with exact flow, h = 0.01, moments included) and the exact event-driven simulator."""
from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import statistics  # noqa: E402
import time  # noqa: E402

from reproductions.tanwani import compute  # noqa: E402
from reproductions.tanwani.scenario import load_scenario  # noqa: E402


def bench_tanwani(repeats: int = 2) -> list[dict]:
    sc = load_scenario("s2")
    rows = []
    walls = []
    for rep in range(repeats):
        t0 = time.perf_counter()
        compute.simulate_gridded_rate(sc, rep, 10_000, sc.main_rate)
        walls.append(time.perf_counter() - t0)
    steps = int(round(sc.horizon / sc.grid_step))
    w = statistics.median(walls)
    rows.append({"name": "S2 gridded Monte Carlo, 10,000 trials, t in [0, 10], h = 0.01, λ = 2 (budget 30 s)",
                 "wall_s": w, "spread": (min(walls), max(walls)),
                 "us_per_trial_step": w / (10_000 * steps) * 1e6, "within_budget": w < 30.0})
    walls = []
    for rep in range(repeats):
        t0 = time.perf_counter()
        compute.simulate_event_rate(sc, rep, 1_000)
        walls.append(time.perf_counter() - t0)
    w = statistics.median(walls)
    rows.append({"name": "S2 exact event-driven Monte Carlo (+ per-path Σ, P), 1,000 trials, t in [0, 10], λ = 2",
                 "wall_s": w, "spread": (min(walls), max(walls)), "ms_per_trial": w / 1_000 * 1e3})
    return rows


if __name__ == "__main__":
    for row in bench_tanwani():
        print(row)
