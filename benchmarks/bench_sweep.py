"""Scaling of `dse sweep`: the same 1,000-point sweep (benchmarks/sweep_scaling.toml) in process,
and on a local Dask cluster with 1 and with 2 worker processes. Ideal scaling halves the wall
time from 1 to 2 workers; the cluster's start (about 2 s per worker) and the final gathering and
writing are the serial part."""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

SWEEP = Path(__file__).with_name("sweep_scaling.toml")


def _run(scheduler: str, workers: int, points: int) -> dict:
    out = Path(tempfile.mkdtemp(prefix="dse-bench-sweep-"))
    try:
        sweep = out / "sweep.toml"
        text = SWEEP.read_text().replace('base = "../dse/families/', f'base = "{SWEEP.parent.parent}/dse/families/')
        sweep.write_text(text.replace("samples = 1000", f"samples = {points}"))
        t0 = time.perf_counter()
        subprocess.run([sys.executable, "-m", "dse.cli", "sweep", str(sweep), "--out", str(out),
                        "--scheduler", scheduler, "--workers", str(workers)], check=True, capture_output=True,
                       env={**os.environ, "DSE_PROGRESS": "0"})
        wall = time.perf_counter() - t0
        meta = json.loads((out / "sweep" / "bench-scaling" / "sweep.json").read_text())
        task_s = sum(p["wall_s"] for p in meta["points"])
        return {"scheduler": scheduler, "workers": workers, "points": len(meta["points"]), "wall_s": wall,
                "task_s_sum": task_s, "efficiency": task_s / (wall * workers)}
    finally:
        shutil.rmtree(out, ignore_errors=True)


def bench_sweep_scaling(points: int = 1000) -> list[dict]:
    rows = [_run("inline", 1, points), _run("local", 1, points), _run("local", 2, points)]
    rows[-1]["speedup_vs_1_worker"] = rows[1]["wall_s"] / rows[2]["wall_s"]
    return rows


if __name__ == "__main__":
    for row in bench_sweep_scaling():
        print(row)
