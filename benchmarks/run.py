"""`make bench`: every benchmark side by side in one run; writes out/bench.md and out/bench.json.

Benchmarks are measurements, not tests: nothing here fails the build.
"""
from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):  # as the `dse` command does
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import json
import os
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from .bench_kalman import bench_kalman
from .bench_kar_moura import bench_kar_moura
from .bench_record import bench_record
from .bench_savas import bench_fig1, bench_filter
from .bench_wang_liu_morse import bench_hybrid


def bench_reproduce(paper: str, repeats: int = 2) -> dict:
    """Wall time and peak memory of `dse reproduce PAPER`, cold cache then warm cache."""
    cold, warm, mem = [], [], []
    for _ in range(repeats):
        out = Path(tempfile.mkdtemp(prefix="dse-bench-"))
        try:
            for bucket in (cold, warm):
                t0 = time.perf_counter()
                subprocess.run([sys.executable, "-m", "pipeline.cli", "reproduce", paper, "--out", str(out)], check=True,
                               capture_output=True, env={**os.environ, "DSE_PROGRESS": "0"})
                bucket.append(time.perf_counter() - t0)
                mem.append(resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024)
        finally:
            shutil.rmtree(out, ignore_errors=True)
    return {"name": f"dse reproduce {paper}", "cold_s": statistics.median(cold), "cold_spread": (min(cold), max(cold)),
            "warm_s": statistics.median(warm), "warm_spread": (min(warm), max(warm)), "peak_memory_mib": max(mem)}


def _fmt(v):
    if isinstance(v, float):
        return f"{v:.4g}"
    if isinstance(v, (tuple, list)):
        return "(" + ", ".join(_fmt(x) for x in v) + ")"
    return str(v)


def table(title: str, rows: list[dict]) -> str:
    keys = list(dict.fromkeys(k for r in rows for k in r))
    lines = [f"## {title}", "", "| " + " | ".join(keys) + " |", "|" + "---|" * len(keys)]
    lines += ["| " + " | ".join(_fmt(r.get(k, "")) for k in keys) + " |" for r in rows]
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--out", default="out")
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    sections = {
        "centralized Kalman filter: batched vs filterpy loop (µs per trial-step)": bench_kalman(repeats=args.repeats),
        "noisy-consensus filter: batched vs per-trial loop (µs per trial-node-step)": bench_filter(args.repeats),
        "Fig. 1 Monte Carlo at the paper's scale": [bench_fig1(1), bench_fig1(2)],
        "gossip interactive Kalman filter (kar-moura)": bench_kar_moura(),
        "hybrid observer (wang-liu-morse)": bench_hybrid(),
        "rerun write throughput": [bench_record()],
        "full reproduction": [bench_reproduce(p) for p in ("savas", "kar-moura", "wang-liu-morse")],
    }
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    header = f"# Benchmarks\n\nmachine: {os.cpu_count()} cores, Python {sys.version.split()[0]}; medians with (min, max).\n\n"
    (out / "bench.md").write_text(header + "\n".join(table(t, rows) for t, rows in sections.items()))
    (out / "bench.json").write_text(json.dumps(sections, indent=1, default=list))
    print((out / "bench.md").read_text())


if __name__ == "__main__":
    main()
