"""One large run on a Dask cluster (`dse run --scheduler`): 10^7 trials of a noisy-consensus-filter scenario that
is small per trial (2 agents, one step, no consensus round; the scenario of tests/test_scheduler_run.py) run in
process (`--scheduler inline`), and on a local Dask cluster of 1 and of 2 workers. Each run is a `dse run`
subprocess with a cold cache; its wall time and its CPU time (children included: the cluster's workers are
its descendants) are measured, and every table and claim of the cluster runs is compared with the in-process
run (they must be the same bits). Ideal scaling halves the wall time from 1 to 2 workers; the cluster's start
(about 2 s), the design and the claims are the serial part."""
from __future__ import annotations

import json
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from dse.scenario.fields import toml_text

MICRO = {"family": "noisy-consensus-filter", "name": "micro", "graph": {"kind": "line", "n": 2},
         "model": {"q": 1.0, "r": 1.0}, "sweep": {"rounds": [0], "sigma_c": [0.5], "n_steps": 1},
         "gains": {"grid": [11, 11]}, "monte_carlo": {"trials": 100_000, "sample_paths": 2}}
#: the speed-up of 2 workers over 1 the issue asks for
TARGET_SPEEDUP = 1.8


def _children_cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def _run(scenario: Path, out: Path, scheduler: str, workers: int, trials: int) -> dict:
    cpu0, t0 = _children_cpu(), time.perf_counter()
    proc = subprocess.run([sys.executable, "-m", "dse.cli", "run", str(scenario), "--out", str(out), "--trials",
                           str(trials), "--scheduler", scheduler, "--workers", str(workers), "--no-figures",
                           "--max-time", "inf"], capture_output=True, text=True,
                          env={**os.environ, "DSE_PROGRESS": "0"})
    wall, cpu = time.perf_counter() - t0, _children_cpu() - cpu0
    if proc.returncode != 0:
        raise RuntimeError(f"dse run --scheduler {scheduler} --workers {workers} failed: {proc.stderr.strip()[-500:]}")
    return {"scheduler": scheduler, "workers": workers, "trials": trials, "wall_s": wall, "cpu_s": cpu}


def _differences(a: Path, b: Path) -> list[str]:
    """Tables and claims of run directory `b` that differ from `a`'s (tables by value, claims as report.json has them)."""
    import pandas as pd

    diffs = []
    for table in sorted((a / "tables").glob("*.parquet")):
        other = b / "tables" / table.name
        if not other.exists() or not pd.read_parquet(table).equals(pd.read_parquet(other)):
            diffs.append(table.name)
    claims = [json.loads((d / "report.json").read_text())["claims"] for d in (a, b)]
    strip = [[{k: v for k, v in c.items() if k not in ("wall_s",)} for c in cs] for cs in claims]
    if strip[0] != strip[1]:
        diffs.append("report.json claims")
    return diffs


def bench_scheduler(trials: int = 10**7) -> list[dict]:
    """In process, then 1 and 2 local workers; the cluster runs' differences from the in-process one."""
    tmp = Path(tempfile.mkdtemp(prefix="dse-bench-scheduler-"))
    try:
        scenario = tmp / "micro.toml"
        scenario.write_text(toml_text(MICRO))
        rows = []
        for scheduler, workers in (("inline", 1), ("local", 1), ("local", 2)):
            out = tmp / f"{scheduler}-{workers}"
            rows.append(_run(scenario, out, scheduler, workers, trials))
            if rows[0] is not rows[-1]:
                diffs = _differences(tmp / "inline-1" / "run" / "micro", out / "run" / "micro")
                rows[-1]["differences"] = ", ".join(diffs) or "none"
        inline, one, two = rows
        for r in (one, two):
            r["speedup_vs_in_process"] = inline["wall_s"] / r["wall_s"]
        two["speedup_vs_1_worker"] = one["wall_s"] / two["wall_s"]
        two["target"] = f"2 workers >= {TARGET_SPEEDUP:g}x one"
        two["met"] = two["speedup_vs_1_worker"] >= TARGET_SPEEDUP and one["differences"] == two["differences"] == "none"
        return rows
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    for row in bench_scheduler(int(sys.argv[1]) if len(sys.argv) > 1 else 10**7):
        print(row)
