"""Batched Kalman filter versus one filterpy ``KalmanFilter`` object per trial.

Both run the same recursion on the same measurements (the first ``filterpy_trials`` trials
of the batch, checked to agree before timing). The batched filter computes the
data-independent gains once and updates all trials with one matrix product per time step;
filterpy runs ``update``/``predict`` for each trial and step in Python. The unit is
microseconds per trial-step, so different trial counts compare directly.

Timing: ``repeats`` rounds, each timing the batched filter and then the filterpy loop; the
median and (min, max) over rounds are reported. Constructing the filterpy objects is done
outside the timed region (this favours filterpy); the batched time includes everything
(validation, gain recursion, allocation of the outputs).

Run: ``.venv/bin/python -m benchmarks.bench_kalman``.
"""

from __future__ import annotations

import statistics
import time
from dataclasses import dataclass

import numpy as np

from dse.estimators.kalman import kalman_filter_batch


@dataclass(frozen=True)
class _Scenario:
    name: str
    F: np.ndarray
    H: np.ndarray
    Q: np.ndarray
    R: np.ndarray
    x0: np.ndarray
    P0: np.ndarray


def _random_walk_three_sensors() -> _Scenario:
    """x(k+1) = x(k) + w, three sensors y_i = x + v_i; q = 1, r = 25, P0 = 1."""
    return _Scenario(
        name="random walk, N=3 sensors",
        F=np.array([[1.0]]),
        H=np.ones((3, 1)),
        Q=np.array([[1.0]]),
        R=25.0 * np.eye(3),
        x0=np.zeros(1),
        P0=np.array([[1.0]]),
    )


def _constant_velocity_2d() -> _Scenario:
    """Planar nearly-constant-velocity target, state (px, vx, py, vy), dt = 0.1.

    Three linear sensors measure the position projected on directions 0°, 60° and 120°.
    Q is the exact discretisation of white acceleration noise of intensity 1 per axis.
    """
    dt = 0.1
    f = np.array([[1.0, dt], [0.0, 1.0]])
    q = np.array([[dt**3 / 3, dt**2 / 2], [dt**2 / 2, dt]])
    angles = np.deg2rad([0.0, 60.0, 120.0])
    H = np.zeros((3, 4))
    H[:, 0], H[:, 2] = np.cos(angles), np.sin(angles)
    return _Scenario(
        name="constant velocity 2-D, 3 sensors",
        F=np.kron(np.eye(2), f),
        H=H,
        Q=np.kron(np.eye(2), q),
        R=0.5 * np.eye(3),
        x0=np.zeros(4),
        P0=np.eye(4),
    )


def _simulate(sc: _Scenario, trials: int, steps: int, seed: int) -> np.ndarray:
    """Measurements zs of shape (trials, steps, p) from the scenario's model."""
    rng = np.random.default_rng(np.random.SeedSequence(seed))
    n, p = sc.F.shape[0], sc.H.shape[0]
    LQ, LR, L0 = (np.linalg.cholesky(M) for M in (sc.Q, sc.R, sc.P0))
    x = sc.x0 + rng.standard_normal((trials, n)) @ L0.T
    zs = np.empty((trials, steps, p))
    for k in range(steps):
        zs[:, k] = x @ sc.H.T + rng.standard_normal((trials, p)) @ LR.T
        x = x @ sc.F.T + rng.standard_normal((trials, n)) @ LQ.T
    return zs


def _filterpy_objects(sc: _Scenario, trials: int):
    from filterpy.kalman import KalmanFilter

    n, p = sc.F.shape[0], sc.H.shape[0]
    filters = []
    for _ in range(trials):
        kf = KalmanFilter(dim_x=n, dim_z=p)
        kf.F, kf.H, kf.Q, kf.R = sc.F.copy(), sc.H.copy(), sc.Q.copy(), sc.R.copy()
        kf.x, kf.P = sc.x0.reshape(n, 1).copy(), sc.P0.copy()
        filters.append(kf)
    return filters


def _run_filterpy(filters, zs: np.ndarray) -> np.ndarray:
    """The per-trial Python loop being benchmarked; returns x̂(k|k), shape (trials, K, n)."""
    trials, steps, _ = zs.shape
    n = filters[0].x.shape[0]
    x_post = np.empty((trials, steps, n))
    for t, kf in enumerate(filters):
        z_t = zs[t]
        for k in range(steps):
            kf.update(z_t[k])
            x_post[t, k] = kf.x[:, 0]
            kf.predict()
    return x_post


def bench_kalman(
    repeats: int = 5,
    batched_trials: int = 200_000,
    filterpy_trials: int = 2_000,
    steps: int = 10,
    seed: int = 0,
) -> list[dict]:
    """Time the batched filter and the filterpy loop on two scenarios; one row per scenario.

    Row keys: ``name``, ``trials`` (batched trial count), ``filterpy_trials``, ``steps``,
    ``n``, ``p``, ``batched_us_per_trial_step`` (median), ``batched_spread`` (min, max),
    ``filterpy_us_per_trial_step`` (median), ``filterpy_spread`` (min, max), ``ratio``
    (filterpy median / batched median) and ``max_abs_diff`` (batched vs filterpy x̂(k|k)
    on the common trials, checked before timing).
    """
    if repeats < 1:
        raise ValueError(f"repeats must be >= 1, got {repeats}")
    rows = []
    for i, sc in enumerate((_random_walk_three_sensors(), _constant_velocity_2d())):
        n, p = sc.F.shape[0], sc.H.shape[0]
        zs = _simulate(sc, batched_trials, steps, seed + i)
        zs_fp = zs[:filterpy_trials]

        # Correctness first, and a warm-up for both implementations.
        ref = _run_filterpy(_filterpy_objects(sc, filterpy_trials), zs_fp)
        got = kalman_filter_batch(sc.F, sc.H, sc.Q, sc.R, sc.x0, sc.P0, zs).x_post[:filterpy_trials]
        max_abs_diff = float(np.max(np.abs(got - ref)))
        if not max_abs_diff <= 1e-10 * max(1.0, float(np.max(np.abs(ref)))):
            raise AssertionError(f"{sc.name}: batched and filterpy disagree by {max_abs_diff:.3e}")

        batched_us, filterpy_us = [], []
        for _ in range(repeats):
            t0 = time.perf_counter()
            kalman_filter_batch(sc.F, sc.H, sc.Q, sc.R, sc.x0, sc.P0, zs)
            batched_us.append((time.perf_counter() - t0) * 1e6 / (batched_trials * steps))

            filters = _filterpy_objects(sc, filterpy_trials)
            t0 = time.perf_counter()
            _run_filterpy(filters, zs_fp)
            filterpy_us.append((time.perf_counter() - t0) * 1e6 / (filterpy_trials * steps))

        b_med, f_med = statistics.median(batched_us), statistics.median(filterpy_us)
        rows.append(
            dict(
                name=sc.name,
                trials=batched_trials,
                filterpy_trials=filterpy_trials,
                steps=steps,
                n=n,
                p=p,
                batched_us_per_trial_step=b_med,
                batched_spread=(min(batched_us), max(batched_us)),
                filterpy_us_per_trial_step=f_med,
                filterpy_spread=(min(filterpy_us), max(filterpy_us)),
                ratio=f_med / b_med,
                max_abs_diff=max_abs_diff,
            )
        )
    return rows


def format_table(rows: list[dict]) -> str:
    """A plain-text table of :func:`bench_kalman` rows (µs per trial-step)."""
    header = (
        f"{'scenario':34s} {'n':>2s} {'p':>2s} {'steps':>5s} "
        f"{'batched trials':>14s} {'batched µs':>11s} {'(min, max)':>19s} "
        f"{'filterpy trials':>15s} {'filterpy µs':>11s} {'(min, max)':>17s} {'ratio':>7s}"
    )
    lines = [header, "-" * len(header)]
    for r in rows:
        bs, fs = r["batched_spread"], r["filterpy_spread"]
        lines.append(
            f"{r['name']:34s} {r['n']:2d} {r['p']:2d} {r['steps']:5d} "
            f"{r['trials']:14d} {r['batched_us_per_trial_step']:11.4f} "
            f"{f'({bs[0]:.4f}, {bs[1]:.4f})':>19s} "
            f"{r['filterpy_trials']:15d} {r['filterpy_us_per_trial_step']:11.2f} "
            f"{f'({fs[0]:.2f}, {fs[1]:.2f})':>17s} {r['ratio']:6.0f}x"
        )
    return "\n".join(lines)


if __name__ == "__main__":
    print(format_table(bench_kalman()))


def bench_kalman_rows(quick: bool = False, repeats: int = 3) -> list[dict]:
    """:func:`bench_kalman` in the side-by-side row format (µs per trial-step; one node: the
    centralized filter), at one batch size (quick) or two."""
    from .common import estimator_row

    sizes = ((20_000, 200),) if quick else ((20_000, 2_000), (200_000, 2_000))
    rows = []
    for trials, fp_trials in sizes:
        for r in bench_kalman(repeats=repeats, batched_trials=trials, filterpy_trials=fp_trials):
            rows.append(estimator_row(
                f"centralized Kalman: {r['name']}", f"n={r['n']}, p={r['p']}, {trials:,} trials", nodes=1, state_dim=r["n"],
                trials=trials, steps=r["steps"], batched=(r["batched_us_per_trial_step"], r["batched_spread"]),
                loop=(r["filterpy_us_per_trial_step"], r["filterpy_spread"]), loop_what="filterpy KalmanFilter loop",
                loop_trials=fp_trials, unit="µs/trial-step", target=">= 200x filterpy",
                met=r["filterpy_us_per_trial_step"] / r["batched_us_per_trial_step"] >= 200,
                note=f"max |Δx̂| vs filterpy {r['max_abs_diff']:.1e}"))
    return rows
