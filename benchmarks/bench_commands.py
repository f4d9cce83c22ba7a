"""The commands people wait on, for every family: `dse list`, `dse check` on every shipped scenario
file, first with an empty output root (the design computed: the cost model's estimate of the design beside
it says what is left) then again with its design in the stage cache, as after a run or an earlier check
(target 0.5 s), `dse run --quick` on each family's first example and on each family's small scenario
(`benchmarks.small_scenarios`: target 2 s) cold and as an identical re-run, and the test suite (target
150 s). (The per-point overhead of `dse sweep` is in benchmarks/bench_sweep.py.)

Each command runs in a fresh interpreter (`python -m dse.cli`, as the `dse` script does), so
its time includes the imports; CPU time is the process and its workers (RUSAGE_CHILDREN), which
shows how much of a wall time on a loaded machine was waiting."""
from __future__ import annotations

import os
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from .small_scenarios import write_small_scenarios

ROOT = Path(__file__).resolve().parent.parent
REPRO = ROOT / "dse" / "families"
#: one example a user starts from, per family (the first file `dse run --quick` is tried on)
RUN_EXAMPLES = ("savas/paper.toml", "wang_liu_morse/generic.toml", "tran/paper.toml", "tanwani/example.toml",
                "kar_moura/scenarios/e2.toml", "compare/scenarios/noisy_ring.toml")


def _env() -> dict[str, str]:
    return {"PATH": os.environ.get("PATH", "/usr/bin:/bin"), "PYTHONPATH": str(ROOT), "DSE_PROGRESS": "0",
            "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1", "HOME": os.environ.get("HOME", "/tmp")}


def timed_command(argv: list[str], cwd: Path = ROOT, env: dict[str, str] | None = None) -> tuple[float, float, int]:
    """(wall s, CPU s of the process and the children it waited for, exit code)."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    proc = subprocess.run(argv, capture_output=True, cwd=cwd, env=_env() if env is None else env)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime), proc.returncode


def _dse(*args: str) -> list[str]:
    return [sys.executable, "-m", "dse.cli", *args]


def shipped_scenarios() -> list[Path]:
    files = sorted(REPRO.glob("*/*.toml")) + sorted(REPRO.glob("*/scenarios/*.toml"))
    return [f for f in files if f.parent.name != "sweeps"]


def _row(command: str, times: list[tuple[float, float, int]], target: float | None) -> dict:
    wall = statistics.median(t[0] for t in times)
    row = {"command": command, "wall_s": wall, "cpu_s": statistics.median(t[1] for t in times),
           "ok": all(t[2] == 0 for t in times)}
    if target is not None:
        row.update(target=f"<= {target:g} s", met=row["ok"] and wall <= target)
    return row


def bench_commands(repeats: int = 3, quick: bool = False) -> list[dict]:
    rows = [_row("dse list", [timed_command(_dse("list")) for _ in range(repeats)], 0.5)]
    files = shipped_scenarios()
    if quick:
        files = [REPRO / f for f in RUN_EXAMPLES]
    for f in files:
        rows += bench_check(f, max(1, repeats - 1))
    with tempfile.TemporaryDirectory() as tmp:
        runs = [(name, REPRO / name, None) for name in RUN_EXAMPLES]
        for name, text in users_small_scenarios().items():
            (Path(tmp) / name).write_text(text)
            runs.append((f"{name} (a user's small scenario)", Path(tmp) / name, None))
        for family_id, path in write_small_scenarios(Path(tmp)).items():
            runs.append((f"{family_id} small scenario (benchmarks.small_scenarios)", path, 2.0))
        for name, path, target in runs:
            cold, memo = [], []
            for r in range(max(1, repeats - 1)):
                out = Path(tmp) / f"out{r}"
                cold.append(timed_command(_dse("run", "--quick", str(path), "--out", str(out))))
                memo.append(timed_command(_dse("run", "--quick", str(path), "--out", str(out))))
                shutil.rmtree(out, ignore_errors=True)
            rows.append(_row(f"dse run --quick {name}", cold, target))
            rows.append(_row(f"dse run --quick {name} (an identical re-run: memo)", memo, None))
    if not quick:
        rows.append(bench_test_suite())
    return rows


def bench_check(path: Path, repeats: int) -> list[dict]:
    """`dse check` on one file: with an empty output root (the design computed and stored; the cost model's
    estimate of the design beside it), then again on that root (the design read back: target 0.5 s)."""
    from dse import api
    from dse.contract.options import RunOptions

    name = path.relative_to(REPRO)
    cold, cached = [], []
    with tempfile.TemporaryDirectory() as tmp:
        for r in range(repeats):
            out = Path(tmp) / f"out{r}"
            cold.append(timed_command(_dse("check", str(path), "--out", str(out))))
            cached.append(timed_command(_dse("check", str(path), "--out", str(out))))
    cost = api.load(path).cost(RunOptions())
    first = {**_row(f"dse check {name} (design computed)", cold, None),
             "design_estimate_s": cost.design_s if cost.design_s is not None else cost.stages.get("design")}
    return [first, _row(f"dse check {name} (design in the stage cache)", cached, 0.5)]


def users_small_scenarios() -> dict[str, str]:
    """Small scenarios a user might write first (file name -> TOML): a 4-node coestimation ring and a
    4-agent hybrid observer."""
    from .bench_tran import SMALL_TOML
    from .bench_wang_liu_morse import agents_scenario
    from .common import toml_text

    return {"ring4.toml": SMALL_TOML, "agents4.toml": toml_text(agents_scenario(4, intervals=15, trials=64, name="agents4"))}


def bench_test_suite() -> dict:
    """`make test`'s command (the virtual environment is already set up)."""
    env = {**_env(), "PYTHONPATH": str(ROOT)}
    t0 = time.perf_counter()
    workers = str(2 * (os.cpu_count() or 1))
    proc = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-n", workers, "--dist",
                           "loadfile"], cwd=ROOT, env=env, capture_output=True)
    wall = time.perf_counter() - t0
    return {"command": "make test (the pytest run)", "wall_s": wall, "ok": proc.returncode == 0,
            "target": "<= 150 s", "met": proc.returncode == 0 and wall <= 150}


if __name__ == "__main__":
    for row in bench_commands(repeats=1, quick="--quick" in sys.argv):
        print(row)
