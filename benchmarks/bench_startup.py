"""Start-up time as a user's machine sees it: `import dse`, `dse --help` and `dse list`, each in a fresh
interpreter, on a copy of the source tree precompiled as the install step does (`make`'s set-up runs
`compileall`) and on the same copy with no bytecode at all, each with `PYTHONDONTWRITEBYTECODE=1` (as
some shells, containers and CI set it: then nothing is ever cached) and without.

`dse list` imports every family's claims modules and reads no scenario file: what it prints is declared
(`Family.listing`; tests/test_list_declared.py traps file reads and scenario construction).

Targets: `import dse` <= 0.3 s, `dse --help` <= 0.3 s, `dse list` <= 0.5 s (precompiled; either setting)."""
from __future__ import annotations

import shutil
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

from .bench_commands import ROOT, _env, timed_command

COMMANDS = {"import dse": (["-c", "import dse"], 0.3), "dse --help": (["-m", "dse.cli", "--help"], 0.3),
            "dse list": (["-m", "dse.cli", "list"], 0.5)}


def _copy_of_sources(dest: Path) -> Path:
    """The package and its metadata as a clone has them (no __pycache__), so that the entry points resolve."""
    shutil.copytree(ROOT / "dse", dest / "dse", ignore=shutil.ignore_patterns("__pycache__"))
    return dest


def _timed(tree: Path, args: list[str], no_bytecode: bool, repeats: int) -> list[tuple[float, float, int]]:
    env = {**_env(), "PYTHONPATH": str(tree)}
    if no_bytecode:
        env["PYTHONDONTWRITEBYTECODE"] = "1"
    else:
        env.pop("PYTHONDONTWRITEBYTECODE", None)
    return [timed_command([sys.executable, *args], cwd=tree, env=env) for _ in range(repeats)]


def bench_startup(repeats: int = 3) -> list[dict]:
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        tree = _copy_of_sources(Path(tmp))
        for compiled in (False, True):
            if compiled:
                subprocess.run([sys.executable, "-m", "compileall", "-q", str(tree / "dse")], check=True)
            for no_bytecode in (True, False):
                if not compiled and not no_bytecode:
                    continue  # the first run would write the bytecode: the same as precompiled after it
                setting = "PYTHONDONTWRITEBYTECODE=1" if no_bytecode else "bytecode allowed"
                state = "precompiled" if compiled else "no bytecode"
                for name, (args, target) in COMMANDS.items():
                    times = _timed(tree, args, no_bytecode, repeats)
                    wall = statistics.median(t[0] for t in times)
                    row = {"command": f"{name} ({state}, {setting})", "wall_s": wall,
                           "cpu_s": statistics.median(t[1] for t in times), "ok": all(t[2] == 0 for t in times)}
                    if compiled:
                        row.update(target=f"<= {target:g} s", met=row["ok"] and wall <= target)
                    rows.append(row)
    return rows


if __name__ == "__main__":
    for row in bench_startup(repeats=int(sys.argv[1]) if len(sys.argv) > 1 else 3):
        print(row)
