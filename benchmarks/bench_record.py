"""Rerun write throughput with the project's own helpers (columnar send_series)."""
from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np
import rerun.blueprint as rrb

from pipeline import record


def bench_record(n_entities: int = 50, steps: int = 10_000, width: int = 4) -> dict:
    values = np.random.default_rng(0).standard_normal((n_entities, steps, width))
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "bench.rrd"
        t0 = time.perf_counter()
        with record.recording(path, application_id="dse-bench", recording_id="bench",
                              blueprint=rrb.Blueprint(rrb.TimeSeriesView(origin="/"))) as rec:
            idx = record.sequence_index("k", np.arange(steps))
            for e in range(n_entities):
                record.send_series(rec, f"nodes/{e}/estimate", idx, values[e])
        wall = time.perf_counter() - t0
        size = path.stat().st_size
    scalars = values.size
    return {"name": f"rerun send_series, {n_entities} entities × {steps} steps × {width}", "scalars": scalars,
            "wall_s": wall, "scalars_per_s": scalars / wall, "file_mb": size / 2**20}


if __name__ == "__main__":
    print(bench_record())
