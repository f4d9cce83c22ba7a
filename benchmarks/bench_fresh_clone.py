"""`make reproduce` on a fresh clone (target 6 minutes on the 2-core machine, the environment included): the
repository's committed HEAD cloned into a temporary directory, then the steps `make reproduce` runs, one after the
other and each timed (wall, and CPU of the step's processes): the environment (`make .venv/.installed`: a new
virtual environment with the pinned dependencies from the package registry, the sources precompiled), the five
papers at their default quality (`dse reproduce --out out`), the example sweeps (`make sweeps`), the example
plug-in's arena (`make arena`) and the report site (`make site`). The total is their sum: what `make reproduce`
takes, with the time of each part beside it."""
from __future__ import annotations

import os
import resource
import shutil
import subprocess
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
TARGET_S = 360.0
#: the steps of `make reproduce` (Makefile), in its order
STEPS = (("environment (make .venv/.installed)", ["make", "--no-print-directory", ".venv/.installed"]),
         ("five papers, default (dse reproduce --out out)", [".venv/bin/dse", "reproduce", "--out", "out"]),
         ("example sweeps (make sweeps)", ["make", "--no-print-directory", "sweeps"]),
         ("arena (make arena)", ["make", "--no-print-directory", "arena"]),
         ("site (make site)", ["make", "--no-print-directory", "site"]))


def _children_cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def bench_fresh_clone() -> list[dict]:
    """One row per step of `make reproduce` on a fresh clone of HEAD, then the total against the target."""
    tmp = Path(tempfile.mkdtemp(prefix="dse-bench-clone-"))
    try:
        clone = tmp / "dse"
        subprocess.run(["git", "clone", "-q", str(ROOT), str(clone)], check=True)
        env = {k: v for k, v in os.environ.items() if k not in ("VIRTUAL_ENV", "PYTHONPATH")}
        rows, ok = [], True
        for what, argv in STEPS:
            cpu0, t0 = _children_cpu(), time.perf_counter()
            proc = subprocess.run(argv, cwd=clone, env={**env, "DSE_PROGRESS": "0"}, capture_output=True, text=True)
            row = {"what": f"  {what}", "wall_s": time.perf_counter() - t0, "cpu_s": _children_cpu() - cpu0,
                   "ok": proc.returncode == 0}
            if proc.returncode != 0:
                row["error"] = (proc.stderr.strip() or proc.stdout.strip())[-300:]
                ok = False
            rows.append(row)
            if not ok:
                break
        wall = sum(r["wall_s"] for r in rows)
        total = {"what": "make reproduce on a fresh clone (environment included)", "wall_s": wall,
                 "cpu_s": sum(r["cpu_s"] for r in rows), "ok": ok, "target": f"<= {TARGET_S / 60:g} min",
                 "met": ok and wall <= TARGET_S}
        return [total] + rows
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    for row in bench_fresh_clone():
        print(row)
