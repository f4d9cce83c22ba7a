"""Rerun write throughput with the project's own helpers (columnar `send_series`).

Two measurements, each a median over repeats (the first recording of a process pays rerun's
one-time start-up, ~0.4 s here; it is timed separately and excluded from the medians):

* synthetic series of three shapes (long, medium, short), which shows the fixed cost per
  entity next to the per-scalar cost;
* a replay of the project's real recordings: every scalar series of every `.rrd` of a
  reproduction output directory, read back with `dse.outputs.record.read_scalars` and written
  again entity by entity with `send_series` (same entity paths, timelines and row counts).
"""
from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np
import rerun.blueprint as rrb

from dse.outputs import record

from .common import spread

SHAPES = ((50, 10_000, 4), (20, 2_000, 12), (500, 200, 1))


def _write(path: Path, series: list[tuple[str, str, np.ndarray, np.ndarray]]) -> float:
    """Seconds to write `series` [(entity, timeline, index values, (T, k) scalars)] as one recording."""
    t0 = time.perf_counter()
    with record.recording(path, application_id="dse-bench", recording_id="bench",
                          blueprint=rrb.Blueprint(rrb.TimeSeriesView(origin="/"))) as rec:
        for entity, timeline, index, values in series:
            idx = record.sequence_index(timeline, index) if timeline == "k" else record.duration_index(timeline, index)
            record.send_series(rec, entity, idx, values)
    return time.perf_counter() - t0


def startup_cost() -> float:
    """Seconds for the first (tiny) recording of this process: rerun's one-time start-up."""
    with tempfile.TemporaryDirectory() as tmp:
        return _write(Path(tmp) / "warm.rrd", [("warm", "k", np.arange(3), np.zeros((3, 1)))])


def bench_record(repeats: int = 3, shapes=SHAPES) -> list[dict]:
    startup_cost()
    rows = []
    for n_entities, steps, width in shapes:
        values = np.random.default_rng(0).standard_normal((n_entities, steps, width))
        series = [(f"nodes/{e}/estimate", "k", np.arange(steps), values[e]) for e in range(n_entities)]
        rates, size = [], 0
        with tempfile.TemporaryDirectory() as tmp:
            for r in range(repeats):
                path = Path(tmp) / f"bench{r}.rrd"
                rates.append(values.size / _write(path, series) / 1e6)
                size = path.stat().st_size
        med, (lo, hi) = spread(rates)
        rows.append({"name": f"synthetic: {n_entities} entities × {steps:,} rows × {width}", "scalars": values.size,
                     "M_scalars_per_s": med, "spread": (lo, hi), "file_mb": size / 2**20,
                     "target": ">= 5 M/s", "met": med >= 5.0})
    return rows


def _series_of(rrd: Path) -> list[tuple[str, str, np.ndarray, np.ndarray]]:
    out = []
    for timeline in ("k", "t"):
        for entity, (index, values) in record.read_scalars(rrd, timeline).items():
            idx = np.asarray(index)
            idx = idx.astype("timedelta64[ns]").astype(np.int64) if idx.dtype.kind == "m" else idx.astype(np.int64)
            out.append((entity, timeline, idx, np.asarray(values, dtype=np.float64)))
    return out


def bench_replay(out_dir: Path, repeats: int = 3) -> list[dict]:
    """Replay every recording under `out_dir/<paper>/*.rrd`, one row per paper."""
    startup_cost()
    rows = []
    for paper_dir in sorted(p for p in Path(out_dir).iterdir() if p.is_dir() and any(p.glob("*.rrd"))):
        series = [s for rrd in sorted(paper_dir.glob("*.rrd")) for s in _series_of(rrd)]
        scalars = sum(v.size for *_, v in series)
        if not scalars:
            continue
        rates = []
        with tempfile.TemporaryDirectory() as tmp:
            for r in range(repeats):
                rates.append(scalars / _write(Path(tmp) / f"replay{r}.rrd", series) / 1e6)
        med, (lo, hi) = spread(rates)
        rows.append({"name": f"replay of {paper_dir.name}'s recordings", "entities": len(series), "scalars": scalars,
                     "mean_rows_per_entity": scalars / len(series), "M_scalars_per_s": med, "spread": (lo, hi),
                     "target": ">= 5 M/s", "met": med >= 5.0})
    return rows


if __name__ == "__main__":
    print(f"start-up {startup_cost():.3f} s")
    for row in bench_record():
        print(row)
