"""GIKF at the issue's scale: spec E1 with 20,000 independent runs of 200 slots (target < 60 s),
the batched Theorem-8 process, and the per-run loop a naive implementation would use."""
from __future__ import annotations

import time

import numpy as np

import estimators.gossip_kalman as gk
import estimators.kalman as kal
import estimators.switched_riccati as sr
from reproductions.kar_moura.compute import J_GRID, STAT_STRIDE
from reproductions.kar_moura.scenario import load_scenario


def _e1():
    sc = load_scenario("e1")
    return sc, sc.system(), sc.protocol.build(sc.graph)


def bench_gikf_e1(runs: int = 20_000, slots: int = 200, seed: int = 0) -> dict:
    """Full GIKF run as the reproduction does it: covariances, error recursion, centralized error,
    per-slot quantiles, tail counts, Loewner margins, NEES, token counts."""
    sc, sys_, prot = _e1()
    cov = kal.kalman_covariances(sc.F, sys_.C_all, sc.Q, sys_.R_all, sc.P0, slots + 1)
    env = [sc.P0]
    for _ in range(slots):
        env.append(gk.lyapunov_step(env[-1], sc.F, sc.Q))
    t0 = time.perf_counter()
    gk.simulate_gikf(sys_, prot, runs, slots, np.random.default_rng(seed), record_times=[1, 2, 5, 20, 100, slots],
                     P_central=cov.P_prior, K_central=cov.gains, envelope=np.array(env), j_grid=J_GRID,
                     stat_stride=STAT_STRIDE)
    wall = time.perf_counter() - t0
    return {"name": f"GIKF E1 (N=10, M=2): {runs:,} runs x {slots} slots, covariances + errors + statistics",
            "wall_s": wall, "target_s": 60.0, "us_per_run_sensor_slot": wall / (runs * slots * 10) * 1e6}


def bench_covariances_only(runs: int = 20_000, slots: int = 200) -> dict:
    sc, sys_, prot = _e1()
    rng = np.random.default_rng(1)
    P = np.broadcast_to(sc.P0, (runs, 10, 2, 2)).copy()
    t0 = time.perf_counter()
    for t in range(slots):
        P = gk.gikf_covariance_step(P, prot.sample(runs, rng) if t else np.tile(np.arange(10), (runs, 1)), sys_)
    wall = time.perf_counter() - t0
    return {"name": f"GIKF E1 covariance recursion only, {runs:,} x {slots}", "wall_s": wall,
            "us_per_run_sensor_slot": wall / (runs * slots * 10) * 1e6}


def bench_loop(runs: int = 20, slots: int = 200) -> dict:
    """One run at a time, one sensor at a time (what the batched code replaces)."""
    sc, sys_, prot = _e1()
    rng = np.random.default_rng(2)
    t0 = time.perf_counter()
    for _ in range(runs):
        P = [sc.P0.copy() for _ in range(10)]
        for t in range(slots):
            p = prot.sample(1, rng)[0] if t else np.arange(10)
            P = [gk.riccati_step(P[p[n]], sys_.C[n], sys_.R[n], sc.F, sc.Q) for n in range(10)]
    wall = time.perf_counter() - t0
    return {"name": f"GIKF E1 per-run loop, {runs} x {slots}", "wall_s": wall,
            "us_per_run_sensor_slot": wall / (runs * slots * 10) * 1e6}


def bench_theorem8(runs: int = 20_000, slots: int = 300) -> dict:
    sc, sys_, prot = _e1()
    rng = np.random.default_rng(3)
    t0 = time.perf_counter()
    path = sr.sample_chain(prot.mean_matrix(), runs, slots, rng)
    sr.switched_riccati(sys_, path, sc.P0, [slots])
    wall = time.perf_counter() - t0
    return {"name": f"Theorem-8 process E1, {runs:,} x {slots}", "wall_s": wall}


def bench_kar_moura() -> list[dict]:
    rows = [bench_gikf_e1(), bench_covariances_only(), bench_loop(), bench_theorem8()]
    rows[2]["ratio_loop_over_batched"] = rows[2]["us_per_run_sensor_slot"] / rows[1]["us_per_run_sensor_slot"]
    return rows


if __name__ == "__main__":
    for row in bench_kar_moura():
        print(row)
