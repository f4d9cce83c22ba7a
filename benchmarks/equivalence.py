"""Check that a change of code leaves every user-visible number as it was.

Two steps, each a command:

    python -m benchmarks.equivalence generate DIR [--python PY] [--tree SRC]
    python -m benchmarks.equivalence compare OLD NEW [--rtol 1e-12]

`generate` runs, with the given interpreter in the given source tree (defaults: this one),
every paper with `dse reproduce` (quick and default, seeds 0 and 1) and every shipped
`compare` scenario with `dse run` (quick and default, seed 0), writing report and tables
only (`--no-figures`). `compare` reads two such directories and lists every difference:
a claim or hypothesis present in one only, a verdict or `holds` that differs, a number
(measured, reference, margin, tolerance; a hypothesis's value and threshold) or a table
cell that differs by more than `rtol` relative (NaN equals NaN), a table or column present
in one only, or a column whose type changed. Exit status 1 when anything differs.

The baseline of a refactoring is generated from a checkout of the commit before it
(`git worktree add /tmp/base <commit>`, then `generate` with `--tree /tmp/base`).
"""
from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

SEEDS = (0, 1)
MODES = ("quick", "default")
NUMBERS = ("measured", "reference", "margin", "tolerance", "printed", "corrected")


def compare_scenarios(tree: Path) -> list[Path]:
    """The shipped compare scenarios of a source tree, whatever its layout."""
    found = sorted(tree.glob("**/compare/scenarios/*.toml"))
    return [p for p in found if ".venv" not in p.parts and "out" not in p.parts]


def _dse(python: str, tree: Path, args: list[str], log) -> None:
    env = {**os.environ, "PYTHONPATH": str(tree), "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"}
    code = "import sys; from dse.cli import main\nsys.exit(main())" if (tree / "dse" / "cli.py").exists() \
        else "import sys; from dse.cli import main\nsys.exit(main())"
    start = time.perf_counter()
    done = subprocess.run([python, "-c", code, *args], cwd=tree, env=env, stdout=log, stderr=subprocess.STDOUT)
    print(f"  {' '.join(args)}: exit {done.returncode}, {time.perf_counter() - start:.0f} s", flush=True)


def generate(out: Path, python: str, tree: Path, papers: list[str] | None = None, compare: bool = True) -> None:
    """Every paper (or `papers` only) and, with `compare`, every shipped compare scenario."""
    out = out.resolve()
    out.mkdir(parents=True, exist_ok=True)
    with open(out / "generate.log", "a") as log:
        for mode in MODES:
            flags = ["--quick"] if mode == "quick" else []
            for seed in SEEDS if papers != [] else ():
                root = out / f"{mode}-s{seed}"
                _dse(python, tree, ["reproduce", *(papers or []), *flags, "--seed", str(seed), "--no-figures",
                                    "--out", str(root)], log)
            for scenario in compare_scenarios(tree) if compare else ():
                _dse(python, tree, ["run", str(scenario), *flags, "--seed", "0", "--no-figures",
                                    "--out", str(out / f"{mode}-compare")], log)


def _same(a, b, rtol: float) -> bool:
    if isinstance(a, str) and isinstance(b, str):
        return a == b
    if isinstance(a, (list, tuple)) and isinstance(b, (list, tuple)):
        return len(a) == len(b) and all(_same(x, y, rtol) for x, y in zip(a, b))
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(_same(a[k], b[k], rtol) for k in a)
    if isinstance(a, (int, float)) and isinstance(b, (int, float)) and not isinstance(a, bool) \
            and not isinstance(b, bool):
        if math.isnan(a) or math.isnan(b):
            return math.isnan(a) and math.isnan(b)
        return a == b or abs(a - b) <= rtol * max(abs(a), abs(b))
    return a == b


def compare_reports(old: dict, new: dict, where: str, rtol: float) -> list[str]:
    diffs = []
    for part, fields in (("hypotheses", ("holds", "value", "threshold")),
                         ("claims", ("verdict", *NUMBERS))):
        a = {r["id"]: r for r in old.get(part, [])}
        b = {r["id"]: r for r in new.get(part, [])}
        diffs += [f"{where}: {part[:-1]} {i} only in the old run" for i in a.keys() - b.keys()]
        diffs += [f"{where}: {part[:-1]} {i} only in the new run" for i in b.keys() - a.keys()]
        for i in a.keys() & b.keys():
            for f in fields:
                if not _same(a[i].get(f), b[i].get(f), rtol):
                    diffs.append(f"{where}: {i} {f}: {a[i].get(f)!r} -> {b[i].get(f)!r}")
    return diffs


def compare_tables(old: Path, new: Path, where: str, rtol: float) -> list[str]:
    import pandas as pd

    a = {p.name: p for p in old.glob("*.parquet")}
    b = {p.name: p for p in new.glob("*.parquet")}
    diffs = [f"{where}: table {n} only in the old run" for n in a.keys() - b.keys()]
    diffs += [f"{where}: table {n} only in the new run" for n in b.keys() - a.keys()]
    for name in sorted(a.keys() & b.keys()):
        x, y = pd.read_parquet(a[name]), pd.read_parquet(b[name])
        if list(x.columns) != list(y.columns):
            diffs.append(f"{where}/{name}: columns {list(x.columns)} -> {list(y.columns)}")
            continue
        if len(x) != len(y):
            diffs.append(f"{where}/{name}: {len(x)} rows -> {len(y)} rows")
            continue
        for col in x.columns:
            u, v = x[col], y[col]
            if str(u.dtype) != str(v.dtype):
                diffs.append(f"{where}/{name}.{col}: type {u.dtype} -> {v.dtype}")
                continue
            if pd.api.types.is_float_dtype(u.dtype) or pd.api.types.is_complex_dtype(u.dtype):
                p, q = u.to_numpy(), v.to_numpy()
                nan_p, nan_q = pd.isna(u).to_numpy(), pd.isna(v).to_numpy()
                p, q = np.where(nan_p, 0, p).astype(complex), np.where(nan_q, 0, q).astype(complex)
                with np.errstate(invalid="ignore"):      # inf - inf: equal infinities compare by ==
                    bad = (nan_p != nan_q) | ~((p == q) | (np.abs(p - q) <= rtol * np.maximum(np.abs(p), np.abs(q))))
            else:
                bad = ~((u == v) | (u.isna() & v.isna())).to_numpy(dtype=bool)
            if bad.any():
                i = int(np.flatnonzero(bad)[0])
                diffs.append(f"{where}/{name}.{col}: {int(bad.sum())} of {len(u)} rows differ "
                             f"(row {i}: {u.iloc[i]!r} -> {v.iloc[i]!r})")
    return diffs


def compare(old: Path, new: Path, rtol: float, only: list[str] | None = None) -> list[str]:
    """Differences between the runs of two `generate` directories (`only`: the runs whose path
    names one of these papers, or `compare` for the compare scenarios)."""
    diffs = []

    def wanted(rel: Path) -> bool:
        return not only or any(o in rel.parts or (o == "compare" and rel.parts[0].endswith("compare")) for o in only)

    runs = sorted(r for r in (p.parent.relative_to(old) for p in old.glob("**/report.json") if ".cache" not in p.parts)
                  if wanted(r))
    if not runs:
        return [f"{old} holds no report.json"]
    new_runs = {r for r in (p.parent.relative_to(new) for p in new.glob("**/report.json") if ".cache" not in p.parts)
                if wanted(r)}
    diffs += [f"{r}: only in the new runs" for r in sorted(new_runs - set(runs))]
    for rel in runs:
        if rel not in new_runs:
            diffs.append(f"{rel}: only in the old runs")
            continue
        ra = json.loads((old / rel / "report.json").read_text())
        rb = json.loads((new / rel / "report.json").read_text())
        diffs += compare_reports(ra, rb, str(rel), rtol)
        diffs += compare_tables(old / rel / "tables", new / rel / "tables", str(rel), rtol)
    print(f"compared {len(runs)} runs (report.json and every table)")
    return diffs


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.equivalence", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", required=True)
    gen = sub.add_parser("generate")
    gen.add_argument("out", type=Path)
    gen.add_argument("--python", default=sys.executable)
    gen.add_argument("--tree", type=Path, default=Path(__file__).resolve().parent.parent)
    gen.add_argument("--paper", action="append", dest="papers", help="only this paper (repeatable)")
    gen.add_argument("--no-papers", action="store_true", help="no paper (the compare scenarios only)")
    gen.add_argument("--no-compare", action="store_true", help="without the compare scenarios")
    cmp = sub.add_parser("compare")
    cmp.add_argument("old", type=Path)
    cmp.add_argument("new", type=Path)
    cmp.add_argument("--rtol", type=float, default=1e-12)
    cmp.add_argument("--only", action="append", help="only the runs of this paper, or 'compare' (repeatable)")
    args = parser.parse_args(argv)
    if args.command == "generate":
        generate(args.out, args.python, args.tree.resolve(), [] if args.no_papers else args.papers,
                 compare=not args.no_compare)
        return 0
    diffs = compare(args.old, args.new, args.rtol, args.only)
    for line in diffs:
        print(line)
    print(f"{len(diffs)} differences")
    return int(bool(diffs))


if __name__ == "__main__":
    sys.exit(main())
