"""`dse sweep`: its per-point overhead, and its scaling.

Overhead (target 10 ms per point at 100 trials): the scaling sweep (benchmarks/sweep_scaling.toml,
savas, one cell per point) at 100 trials per point, in process, asking for one claim and no table or
metric, as `dse sweep` in a fresh interpreter at N points and at 1 point (CPU time of the process,
RUSAGE_CHILDREN). The points' kernel time (their design and Monte Carlo stages, `Reproduction.compute`
with nothing shared, CPU time) is measured in this process on the same scenarios and seeds. The overhead
per point is ((CPU_N − kernel_N) − (CPU_1 − kernel_1)) / (N − 1): what one more point costs beyond its
own stages (start-up, the figure and the other fixed costs cancel). A cProfile of the same sweep in this
process says where the per-point overhead goes.

Scaling: the same 1,000-point sweep in process, and on a local Dask cluster with 1 and with 2 worker
processes. Ideal scaling halves the wall time from 1 to 2 workers; the cluster's start (about 2 s per
worker) and the final gathering and writing are the serial part."""
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
#: what a lean sweep asks of each point: one claim, no table, no metric (a point computes nothing else)
LEAN = 'claims = ["mc.trace"]\ntables = []\nmetrics = []\n'
OVERHEAD_TARGET_MS = 10.0
#: the profiled functions of the per-point breakdown (pstats cumulative times; the stages' own time apart)
BREAKDOWN = {"whole sweep (run_sweep)": ("dse/sweeps/run.py", "run_sweep"),
             "validate (build_tasks)": ("dse/sweeps/run.py", "build_tasks"),
             "point total (run_point)": ("dse/sweeps/run.py", "run_point"),
             "stages (kernel)": ("dse/contract/context.py", "compute"),
             "claims (_evaluate)": ("dse/sweeps/run.py", "_evaluate"),
             "tables (_point_tables)": ("dse/sweeps/run.py", "_point_tables"),
             "refusals and cost (_compute minus stages)": ("dse/sweeps/run.py", "_compute"),
             "store (PointStore.save)": ("dse/sweeps/run.py", "save"),
             "outputs (write_sweep_outputs)": ("dse/sweeps/run.py", "write_sweep_outputs")}


def sweep_text(points: int, trials: int, lean: bool) -> str:
    """The scaling sweep with `points` random points at `trials` trials (lean: one claim, nothing else)."""
    text = SWEEP.read_text().replace('base = "../dse/families/', f'base = "{SWEEP.parent.parent}/dse/families/')
    text = text.replace("trials = 2000", f"trials = {trials}").replace("samples = 1000", f"samples = {points}")
    return text.replace("quick = true\n", "quick = true\n" + LEAN) if lean else text


def kernel_cpu_s(sweep_file: Path) -> float:
    """CPU seconds of every point's stages (design and Monte Carlo), nothing shared between points."""
    from dse import registry
    from dse.contract.context import StageContext
    from dse.contract.options import RunOptions
    from dse.engine.cache import MemoryCache
    from dse.sweeps.spec import load_sweep

    spec = load_sweep(sweep_file)
    runs = [(registry.from_dict(spec.scenario(p)), RunOptions(seed=p.seed, trials=spec.trials, quick=spec.quick,
                                                               workers=1)) for p in spec.points()]
    runs[0][0].compute(runs[0][1], StageContext(MemoryCache()))        # imports, untimed
    total = 0.0
    for repro, opts in runs:
        t0 = time.process_time()
        repro.compute(opts, StageContext(MemoryCache()))
        total += time.process_time() - t0
    return total


def _profile_breakdown(sweep_file: Path, points: int) -> dict[str, float]:
    """ms per point of each BREAKDOWN function under cProfile (the profiler inflates Python-heavy code several
    times: read them as shares of the whole sweep's)."""
    import cProfile
    import pstats

    from dse.sweeps.run import run_sweep
    from dse.sweeps.spec import load_sweep

    with tempfile.TemporaryDirectory() as tmp:
        prof = cProfile.Profile()
        prof.runcall(run_sweep, load_sweep(sweep_file), Path(tmp), scheduler="inline", log=lambda _: None)
    stats = pstats.Stats(prof).stats
    out = {}
    for label, (path, name) in BREAKDOWN.items():
        cum = sum(v[3] for (file, _, func), v in stats.items() if func == name and file.endswith(path))
        out[label] = 1e3 * cum / points
    out["refusals and cost (_compute minus stages)"] -= out["stages (kernel)"]
    return out


def bench_sweep_overhead(points: int = 200, trials: int = 100) -> list[dict]:
    """The per-point overhead of a lean sweep (the target's row) and of the same sweep keeping every claim,
    table and metric (for comparison), with the profile's breakdown of the lean one."""
    from .bench_commands import _dse, timed_command

    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for lean in (True, False):
            measured = {}
            for n in (1, points):
                f = Path(tmp) / f"s{n}-{lean}.toml"
                f.write_text(sweep_text(n, trials, lean))
                wall, cpu, rc = timed_command(_dse("sweep", str(f), "--out", str(Path(tmp) / f"o{n}-{lean}"),
                                                   "--scheduler", "inline"))
                measured[n] = (cpu, kernel_cpu_s(f), rc)
            (cpu_n, kern_n, rc_n), (cpu_1, kern_1, rc_1) = measured[points], measured[1]
            per_point = ((cpu_n - kern_n) - (cpu_1 - kern_1)) / (points - 1)
            row = {"what": f"dse sweep, {points} savas points at {trials} trials, in process, "
                           + ("one claim, no table or metric" if lean else "every claim, table and metric"),
                   "cpu_s": cpu_n, "kernel_cpu_s": kern_n, "one_point_cpu_s": cpu_1,
                   "overhead_ms_per_point": 1e3 * per_point, "ok": rc_n == 0 and rc_1 == 0}
            if lean:
                row.update(target=f"<= {OVERHEAD_TARGET_MS:g} ms per point",
                           met=row["ok"] and 1e3 * per_point <= OVERHEAD_TARGET_MS)
            rows.append(row)
            if lean:
                split = _profile_breakdown(Path(tmp) / f"s{points}-{lean}.toml", points)
                rows += [{"what": f"  where it goes (cProfile, per point): {label}", "profile_ms_per_point": ms,
                          "share_of_sweep": ms / split["whole sweep (run_sweep)"]} for label, ms in split.items()]
    return rows


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


#: the example sweeps' share of `make reproduce`'s 6 minutes on 2 cores (beside about 1 min of environment,
#: at most 1 min of papers at default quality, and the site)
EXAMPLES_TARGET_S = 90.0


def bench_example_sweeps() -> list[dict]:
    """`make sweeps` cold: every shipped sweep (dse/families/sweeps/*.toml) into a fresh output directory in one
    command, as the Makefile runs them (one local Dask cluster); wall and CPU time (children included: the Dask
    workers), and each sweep's own wall time from its sweep.json."""
    from .bench_commands import _dse, timed_command

    files = sorted((SWEEP.parent.parent / "dse" / "families" / "sweeps").glob("*.toml"))
    with tempfile.TemporaryDirectory() as tmp:
        wall, cpu, rc = timed_command(_dse("sweep", *map(str, files), "--out", tmp))
        rows = [{"what": f"  example sweep {meta['name']} ({len(meta['points'])} points, {meta['scheduler']})",
                 "wall_s": meta["wall_s"]}
                for meta in (json.loads(p.read_text()) for p in sorted(Path(tmp).glob("sweep/*/sweep.json")))]
    total = {"what": "the example sweeps (make sweeps), cold", "wall_s": wall, "cpu_s": cpu, "ok": rc == 0,
             "target": f"<= {EXAMPLES_TARGET_S:g} s wall"}
    total["met"] = total["ok"] and wall <= EXAMPLES_TARGET_S
    return [total] + rows


if __name__ == "__main__":
    for row in bench_sweep_overhead() + (bench_sweep_scaling() if "--scaling" in sys.argv else []):
        print(row)
