"""Shared timing helpers and the row format of the side-by-side estimator table.

Every figure is a median over `repeats` timed runs with its (min, max) spread. A row of the
estimator table compares the batched implementation with a straightforward per-trial loop on
the same model and reports both in microseconds per trial-node-step, so that different trial
counts, node counts and horizons compare directly.
"""
from __future__ import annotations

import json
import math
import statistics
import time
from typing import Callable

from dse.scenario.fields import toml_text  # noqa: F401 (re-exported for the benchmarks)


def timed(fn: Callable[[], object], repeats: int, *, per: float = 1.0, warmup: bool = False) -> tuple[float, tuple[float, float]]:
    """Median and (min, max) over `repeats` calls of `fn`, in microseconds divided by `per`."""
    if repeats < 1:
        raise ValueError(f"repeats must be >= 1, got {repeats}")
    if warmup:
        fn()
    walls = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        walls.append((time.perf_counter() - t0) * 1e6 / per)
    return statistics.median(walls), (min(walls), max(walls))


def spread(values: list[float]) -> tuple[float, tuple[float, float]]:
    return statistics.median(values), (min(values), max(values))


def estimator_row(estimator: str, size: str, *, nodes: int, state_dim: int, trials: int, steps: int,
                  batched: tuple[float, tuple[float, float]], loop: tuple[float, tuple[float, float]] | None,
                  loop_what: str, loop_trials: int | None = None, unit: str = "µs/trial-node-step",
                  target: str = "", met: bool | None = None, note: str = "") -> dict:
    """One row of the side-by-side table. `batched` and `loop` are (median, (min, max)) in `unit`."""
    row = {"estimator": estimator, "size": size, "nodes": nodes, "state_dim": state_dim, "trials": trials,
           "steps": steps, "unit": unit, "batched": batched[0], "batched_spread": batched[1]}
    if loop is not None:
        row.update(loop_kind=loop_what, loop_trials=loop_trials, loop=loop[0], loop_spread=loop[1],
                   ratio=loop[0] / batched[0])
    row.update(target=target, met=met, note=note)
    return row


def bound_row(name: str, *, fast: tuple[float, tuple[float, float]], fast_what: str,
              naive: tuple[float, tuple[float, float]] | None = None, naive_what: str = "", max_diff: float | None = None,
              unit: str = "ms", note: str = "") -> dict:
    """One row of the bound-computation table (`fast` and `naive` as (median, (min, max)) in `unit`)."""
    row = {"computation": name, "unit": unit, "fast": fast_what, "fast_time": fast[0], "fast_time_spread": fast[1]}
    if naive is not None:
        row.update(naive=naive_what, naive_time=naive[0], naive_time_spread=naive[1], ratio=naive[0] / fast[0])
    if max_diff is not None:
        row["max_rel_diff"] = max_diff
    row["note"] = note
    return row


