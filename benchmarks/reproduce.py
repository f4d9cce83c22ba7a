"""Wall time and peak memory of `dse reproduce PAPER`, cold cache (a fresh output root) then warm
cache (the same root again: every stage is read back, figures and recordings are rewritten).

Peak memory is reported two ways: the largest resident set of any one process of the run
(ru_maxrss of `dse` and its worker processes, through a small wrapper process), and the largest sum of resident
sets over the whole process tree, sampled every 0.1 s (an upper bound: forked workers share
pages with their parent).
"""
from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

from .common import spread

def papers() -> tuple[str, ...]:
    """Every registered paper (`dse.families`)."""
    from dse import registry

    return tuple(registry.papers())
GiB = 2**30


def _tree_rss(pid: int) -> int:
    import psutil

    try:
        root = psutil.Process(pid)
        procs = [root] + root.children(recursive=True)
    except psutil.Error:
        return 0
    total = 0
    for p in procs:
        try:
            total += p.memory_info().rss
        except psutil.Error:
            pass
    return total


_MARK = "DSE_BENCH_MAXRSS_KB"
# A small parent for the measured command: ru_maxrss of a child counts the memory of the process
# it was forked from (before exec), so forking `dse` straight from this benchmark process would
# report the benchmark's own size. The wrapper is small; it reports the largest resident set of
# `dse` and of the worker processes `dse` waited for.
_WRAPPER = ("import resource, subprocess, sys; r = subprocess.run(sys.argv[1:]); "
            f"print('\\n{_MARK}', resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss, flush=True); "
            "sys.exit(r.returncode)")


def run_once(paper: str, out: Path, quick: bool) -> dict:
    """One `dse reproduce` in a subprocess: wall seconds, max single-process RSS, peak tree RSS."""
    cmd = [sys.executable, "-c", _WRAPPER, sys.executable, "-m", "dse.cli", "reproduce", paper, "--out", str(out)]
    cmd += ["--quick"] if quick else []
    env = {**os.environ, "DSE_PROGRESS": "0"}
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, env=env,
                            cwd=Path(__file__).resolve().parent.parent)
    peak = [0]
    done = threading.Event()

    def sample():
        while not done.is_set():
            peak[0] = max(peak[0], _tree_rss(proc.pid))
            done.wait(0.1)

    sampler = threading.Thread(target=sample, daemon=True)
    sampler.start()
    with proc.stdout:
        output = proc.stdout.read().decode(errors="replace")
    proc.wait()
    wall = time.perf_counter() - t0
    done.set()
    sampler.join()
    lines = [line for line in output.splitlines() if line.strip()]
    marks = [line.split()[1] for line in lines if line.startswith(_MARK)]
    lines = [line for line in lines if not line.startswith(_MARK)]
    verdicts = [line.split(" -> ")[0] for line in lines if line.startswith(f"{paper}:")]
    return {"wall_s": wall, "max_rss_mib": int(marks[-1]) / 1024 if marks else float("nan"), "tree_rss_mib": peak[0] / 2**20,
            "ok": proc.returncode == 0, "verdicts": verdicts[-1] if verdicts else lines[-1:]}


def bench_reproduce(paper: str, *, quick: bool = False, repeats: int = 2, warm: bool = True,
                    keep_dir: Path | None = None) -> dict:
    """Median (min, max) wall time of `repeats` cold runs (and as many warm runs), peak memory
    over all of them. `keep_dir`: the output root of the last run is copied there (for the
    recording replay benchmark)."""
    cold, hot, rss, tree, notes = [], [], [], [], []
    ok = True
    for r in range(repeats):
        out = Path(tempfile.mkdtemp(prefix="dse-bench-"))
        try:
            for bucket in (cold, hot) if warm else (cold,):
                res = run_once(paper, out, quick)
                bucket.append(res["wall_s"])
                rss.append(res["max_rss_mib"])
                tree.append(res["tree_rss_mib"])
                ok &= res["ok"]
                notes.append(res["verdicts"])
            if keep_dir is not None and r == repeats - 1:
                shutil.copytree(out / paper, keep_dir / paper, dirs_exist_ok=True,
                                ignore=shutil.ignore_patterns(".cache"))
        finally:
            shutil.rmtree(out, ignore_errors=True)
    c = spread(cold)
    row = {"paper": paper, "mode": "quick" if quick else "default", "cold_s": c[0], "cold_spread": c[1]}
    if warm:
        w = spread(hot)
        row.update(warm_s=w[0], warm_spread=w[1])
    row.update(max_process_rss_mib=max(rss), peak_tree_rss_mib=max(tree), target="< 4 GiB",
               met=max(tree) * 2**20 < 4 * GiB, ok=ok, verdicts=notes[-1])
    return row


def totals(rows: list[dict]) -> list[dict]:
    """The five papers one after the other: the sum of the cold medians per mode (targets: default
    60 s, quick 20 s) and of the warm medians of the default mode (every stage and the run memo
    cached: 5 s)."""
    out = []
    for mode, key, what, limit in (("default", "cold_s", "cold", 60.0), ("quick", "cold_s", "cold", 20.0),
                                   ("default", "warm_s", "cached (nothing to simulate)", 5.0)):
        sel = [r for r in rows if r["mode"] == mode and key in r]
        if sel:
            total = sum(r[key] for r in sel)
            out.append({"paper": f"all {len(sel)}", "mode": mode, "what": what, "value": total,
                        "target": f"<= {limit:g} s", "met": total <= limit and all(r["ok"] for r in sel)})
    return out

if __name__ == "__main__":
    for p in papers():
        print(bench_reproduce(p, quick=True, repeats=1, warm=False))
