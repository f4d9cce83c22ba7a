"""`make bench`: every benchmark side by side in one run; writes out/bench.md and out/bench.json.

    .venv/bin/python -m benchmarks.run [--out out] [--repeats 3] [--quick] [--only a,b]

Sections (``--only`` takes their keys): ``floor`` (what the machine allows: normal draws, memory
bandwidth), ``estimators`` (every estimator, batched vs a per-trial loop, µs per trial-node-step),
``bounds`` (the deterministic computations against a naive version), ``scale`` (Monte Carlo
stages at the papers' scale), ``record`` (rerun write throughput), ``reproduce`` (wall time and
peak memory of `dse reproduce` per paper, cold and warm cache), ``startup`` (`import dse`, `dse --help`,
`dse list` on a fresh copy of the sources, precompiled or not, with PYTHONDONTWRITEBYTECODE=1 and without), ``commands`` (`dse list`, `dse check`
on every shipped scenario with its design computed and with it cached, `dse run --quick` per family
and on each family's small scenario, the test suite), ``estimates`` (`dse check`'s estimated time of `dse run --quick` against the measured one, for
every shipped scenario and scenarios of every family's generator: target within 2x), ``sweep`` (the per-point CPU overhead of
`dse sweep` beyond the points' stages, with a cProfile breakdown; the example sweeps cold, as `make sweeps`
runs them; a 1,000-point `dse sweep` in process and on a local Dask cluster with 1 and 2 workers), ``scheduler`` (one `dse run` of 10^7 trials
in process and with its Monte Carlo units on a local Dask cluster of 1 and 2 workers: the same bits, and the
speed-up), ``calibration`` (every statistical
claim on 200 random valid scenarios per family: observed false-fail rate at α = 0.05 with its
exact interval, and fails at the report's own confidence), ``fresh`` (`make reproduce` on a fresh clone of HEAD,
step by step, the environment included: target 6 min). ``--quick``: fewer repeats and
sizes, quick reproductions only, no fresh clone (a smoke test of the whole harness, a few minutes).

Every figure is a median over repeats with its (min, max). Benchmarks are measurements, not
tests: nothing here fails the build; a target that is missed is reported as missed.
"""
from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):  # as the `dse` command does
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import json  # noqa: E402
import math  # noqa: E402
import platform  # noqa: E402
import re  # noqa: E402
import shutil  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
import traceback  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Callable  # noqa: E402

import numpy as np  # noqa: E402

from .bench_calibration import bench_calibration  # noqa: E402
from .bench_commands import bench_commands  # noqa: E402
from .bench_estimates import TARGET_FACTOR, bench_estimates  # noqa: E402
from .bench_fresh_clone import bench_fresh_clone  # noqa: E402
from .bench_plugin import bench_plugin  # noqa: E402
from .bench_scheduler import bench_scheduler  # noqa: E402
from .bench_startup import bench_startup  # noqa: E402
from .bench_sweep import bench_example_sweeps, bench_sweep_overhead, bench_sweep_scaling  # noqa: E402
from .common import bound_row, estimator_row, spread, timed  # noqa: E402

SECTIONS = ("floor", "estimators", "bounds", "scale", "plugin", "record", "reproduce", "startup", "commands",
            "estimates", "sweep", "scheduler", "calibration", "fresh")
TITLES = {
    "floor": "What the machine allows (floors behind the per-step targets)",
    "estimators": "Estimators side by side: batched vs a straightforward per-trial loop",
    "bounds": "Bound computations: closed form / exponential vs a naive version",
    "scale": "Monte Carlo stages at the papers' scale",
    "plugin": "Plug-in filters (dse.plugin) on the 50-node compare benchmark: the protocol's overhead against the "
              "built-in dispatch, CPU per step in one process (in the before/after row, plugin = after, builtin = "
              "before)",
    "record": "Rerun write throughput (project helpers, `dse.outputs.record.send_series`)",
    "reproduce": "`dse reproduce PAPER`: wall time and peak memory, cold and warm cache",
    "startup": "Start-up: `import dse`, `dse --help`, `dse list`, precompiled or not, with PYTHONDONTWRITEBYTECODE=1 and without",
    "commands": "The commands people wait on: `dse list`, `dse check`, `dse run --quick`, the tests",
    "estimates": "`dse check`'s estimate against the measured `dse run --quick` (one worker; CPU and wall time), "
                 "every shipped scenario and generated ones",
    "sweep": "`dse sweep`: per-point overhead (CPU beyond the points' stages), the example sweeps cold, and the "
             "same 1,000-point sweep in process and on 1 and 2 Dask workers",
    "scheduler": "One run on a Dask cluster (`dse run --scheduler`): 10^7 trials in process and on 1 and 2 local workers",
    "calibration": "Statistical claims on random valid scenarios (quick sample sizes): false-fail rate at α = 0.05",
    "fresh": "`make reproduce` on a fresh clone of HEAD, step by step (the environment included)",
}


# -- floor -------------------------------------------------------------------------------------------

def bench_floor(quick: bool, repeats: int) -> list[dict]:
    """Standard normal draws (SFC64, the generator of every Monte Carlo block), a streaming copy
    and a small batched matmul: the per-element costs every simulator step is built from."""
    n = 2_000_000 if quick else 10_000_000
    rng = np.random.Generator(np.random.SFC64(0))
    out = np.empty(n)
    rows = []
    t = timed(lambda: rng.standard_normal(out=out), repeats, per=n / 1e3, warmup=True)
    rows.append({"what": "standard normal draw (SFC64, into a preallocated array)", "value": t[0], "spread": t[1],
                 "unit": "ns per draw"})
    src = np.random.default_rng(0).standard_normal(n)
    t = timed(lambda: np.copyto(out, src), repeats, per=1.0, warmup=True)
    gbs = 16 * n / (t[0] * 1e-6) / 1e9
    rows.append({"what": f"memory copy of {8 * n / 2**20:.0f} MiB (read + write)", "value": gbs,
                 "spread": tuple(16 * n / (x * 1e-6) / 1e9 for x in t[1][::-1]), "unit": "GB/s"})
    t = timed(lambda: np.add(out, src, out=out), repeats, per=n / 1e3, warmup=True)
    rows.append({"what": "one in-place elementwise op (a += b) per element", "value": t[0], "spread": t[1],
                 "unit": "ns per element"})
    X = np.random.default_rng(0).standard_normal((100_000, 4))
    F = np.random.default_rng(1).standard_normal((4, 4))
    t = timed(lambda: X @ F, repeats, per=len(X) / 1e3, warmup=True)
    rows.append({"what": "(trials, 4) @ (4, 4) per trial", "value": t[0], "spread": t[1], "unit": "ns per trial"})
    return rows


# -- estimators --------------------------------------------------------------------------------------

def _gikf_rows(quick: bool, repeats: int) -> list[dict]:
    """GIKF (kar-moura): the batched per-sensor covariance recursion against one run and one
    sensor at a time, through `benchmarks.bench_kar_moura.bench_covariance_filter` (owned by the
    kar-moura reproduction; its rows are put in the side-by-side format here)."""
    from . import bench_kar_moura as km

    rows = []
    for r in km.bench_covariance_filter(repeats=1 if quick else repeats, slots=20 if quick else 100):
        b = r["batched_us_per_trial_node_step"]
        dims = {k: int(v) for k, v in re.findall(r"\b([NM])=(\d+)", r["name"])}
        rows.append(estimator_row(r["name"], f"{r['trials']:,} runs", nodes=dims.get("N"), state_dim=dims.get("M"),
                                  trials=r["trials"],
                                  steps=r["slots"], batched=(b, r["batched_spread"]),
                                  loop=(r["loop_us_per_trial_node_step"], r["loop_spread"]),
                                  loop_what="per-run, per-sensor loop", unit="µs/trial-node-step",
                                  target=f"<= {r.get('target_us', 3.0):g} µs", met=b <= r.get("target_us", 3.0),
                                  note="per-trial covariance filter (Joseph form); sizes in the name"))
    return rows


def bench_estimators(quick: bool, repeats: int) -> list[dict]:
    from .bench_kalman import bench_kalman_rows
    from .bench_savas import bench_filter
    from .bench_tanwani import bench_event, bench_gridded
    from .bench_tran import bench_stochastic_rows
    from .bench_wang_liu_morse import bench_hybrid_rows
    from .bench_kar_moura import bench_greedy_matching

    parts: list[Callable[[bool, int], list[dict]]] = [bench_kalman_rows, bench_filter, bench_gridded, bench_event,
                                                      _gikf_rows, bench_greedy_matching, bench_hybrid_rows,
                                                      bench_stochastic_rows]
    return _collect(parts, quick, repeats)


# -- bounds ------------------------------------------------------------------------------------------

def _theorem8_rows(quick: bool, repeats: int) -> list[dict]:
    from . import bench_kar_moura as km

    runs, slots = (2_000, 50) if quick else (20_000, 300)
    r = km.bench_theorem8(repeats=1 if quick else repeats, runs=runs, slots=slots)
    lo, hi = r["wall_spread"]
    return [bound_row(r["name"], fast=(1e3 * r["wall_s"], (1e3 * lo, 1e3 * hi)), fast_what="batched over chains",
                      note=f"{r['us_per_chain_step']:.3g} µs per chain-slot")]


def _wlm_rho(quick: bool, repeats: int) -> list[dict]:
    from .bench_wang_liu_morse import bench_rho

    return [bench_rho(repeats)]


def _tran_bounds(quick: bool, repeats: int) -> list[dict]:
    from .bench_tran import bench_deterministic_rows, bench_lmis

    return bench_lmis(repeats) + (bench_deterministic_rows(2.0 if quick else 10.0))


def bench_bounds(quick: bool, repeats: int) -> list[dict]:
    from .bench_savas import bench_bounds as savas_bounds
    from .bench_tanwani import bench_bounds as tanwani_bounds

    return _collect([savas_bounds, tanwani_bounds, _theorem8_rows, _wlm_rho, _tran_bounds], quick, repeats)


# -- scale -------------------------------------------------------------------------------------------

def bench_scale(quick: bool, repeats: int) -> list[dict]:
    from . import bench_kar_moura as km
    from .bench_compare import bench_compare
    from .bench_savas import bench_fig1
    from .bench_tanwani import bench_s2_budget

    rows = []
    if quick:
        rows.append(bench_fig1(2, trials=20_000))
        rows.append(km.bench_gikf_e1(repeats=1, runs=2_000, slots=50))
        rows.append(bench_compare("failures", steps=50))
        return rows
    rows += [bench_fig1(1), bench_fig1(2)]
    rows.append(bench_s2_budget(repeats=min(repeats, 2)))
    rows.append(km.bench_gikf_e1(repeats=min(repeats, 2)))
    rows += [bench_compare("reliable", noise=0.1), bench_compare("failures")]     # the compare family, issue 17
    return rows


# -- record ------------------------------------------------------------------------------------------

def bench_records(quick: bool, repeats: int, replay_dir: Path | None = None) -> list[dict]:
    from .bench_record import SHAPES, bench_record, bench_replay, startup_cost

    rows = [{"name": "first recording of a process (rerun start-up, excluded below)", "wall_s": startup_cost()}]
    rows += bench_record(repeats, SHAPES[1:] if quick else SHAPES)
    if replay_dir is not None and replay_dir.exists():
        rows += bench_replay(replay_dir, repeats)
    return rows


# -- reproduce ---------------------------------------------------------------------------------------

def bench_reproductions(quick: bool, repeats: int, replay_dir: Path | None = None) -> list[dict]:
    from .reproduce import bench_reproduce, papers, totals

    rows = []
    for p in papers():
        if not quick:
            rows.append(_safe(lambda: bench_reproduce(p, quick=False, repeats=min(repeats, 2), keep_dir=replay_dir),
                              {"paper": p, "mode": "default"}))
        rows.append(_safe(lambda: bench_reproduce(p, quick=True, repeats=1, warm=not quick,
                                                  keep_dir=replay_dir if quick else None), {"paper": p, "mode": "quick"}))
    return rows + totals([r for r in rows if "cold_s" in r])


# -- driver ------------------------------------------------------------------------------------------

def _safe(fn: Callable[[], dict], label: dict) -> dict:
    try:
        return fn()
    except Exception as exc:  # a benchmark that breaks is reported, the others still run
        traceback.print_exc()
        return {**label, "error": f"{type(exc).__name__}: {exc}"}


def _collect(parts, quick: bool, repeats: int) -> list[dict]:
    rows = []
    for part in parts:
        try:
            rows += part(quick, repeats)
        except Exception as exc:
            traceback.print_exc()
            rows.append({"estimator": part.__name__, "error": f"{type(exc).__name__}: {exc}"})
    return rows


def _fmt(v) -> str:
    if isinstance(v, bool) or v is None:
        return {True: "yes", False: "**no**", None: ""}[v]
    if isinstance(v, (float, np.floating)):
        return f"{v:.3g}" if abs(v) < 1e5 else f"{v:.3e}"
    if isinstance(v, (tuple, list)) and len(v) == 2 and all(isinstance(x, (float, int)) for x in v):
        return f"({_fmt(float(v[0]))}, {_fmt(float(v[1]))})"
    return str(v).replace("|", "/")


def table(rows: list[dict]) -> str:
    """A markdown table; `X` and `X_spread` are merged into one cell 'median (min, max)'."""
    keys = [k for k in dict.fromkeys(k for r in rows for k in r) if not k.endswith("_spread") and k != "spread"]
    head = []
    for k in keys:
        head.append(k)
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        cells = []
        for k in keys:
            v = r.get(k, "")
            sp = r.get(f"{k}_spread") if f"{k}_spread" in r else (r.get("spread") if k in ("value", "wall_s",
                                                                                          "M_scalars_per_s") else None)
            cells.append(_fmt(v) + (f" {_fmt(sp)}" if sp is not None and v != "" else ""))
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="out")
    parser.add_argument("--repeats", type=int, default=None, help="timed repeats per figure (default 3, quick 2)")
    parser.add_argument("--quick", action="store_true", help="fewer repeats and sizes; quick reproductions only")
    parser.add_argument("--only", default=",".join(SECTIONS), help=f"comma-separated subset of {','.join(SECTIONS)}")
    parser.add_argument("--keep-outputs", default=None, metavar="DIR",
                        help="keep the last reproduction of each paper (reports, recordings) under DIR")
    args = parser.parse_args(argv)
    repeats = args.repeats or (2 if args.quick else 3)
    only = [s.strip() for s in args.only.split(",") if s.strip()]
    unknown = [s for s in only if s not in SECTIONS]
    if unknown:
        parser.error(f"unknown section(s) {', '.join(unknown)} (known: {', '.join(SECTIONS)})")

    t_start = time.perf_counter()
    keep = args.keep_outputs is not None
    replay_dir = Path(args.keep_outputs) if keep else Path(tempfile.mkdtemp(prefix="dse-bench-replay-"))
    replay_dir.mkdir(parents=True, exist_ok=True)
    results: dict[str, list[dict]] = {}
    timings: dict[str, float] = {}
    try:
        runners = {"floor": lambda: bench_floor(args.quick, repeats),
                   "estimators": lambda: bench_estimators(args.quick, repeats),
                   "bounds": lambda: bench_bounds(args.quick, repeats),
                   "scale": lambda: bench_scale(args.quick, repeats),
                   "plugin": lambda: bench_plugin(args.quick, repeats),
                   "reproduce": lambda: bench_reproductions(args.quick, repeats, replay_dir),
                   "record": lambda: bench_records(args.quick, repeats, replay_dir),
                   "startup": lambda: bench_startup(repeats),
                   "commands": lambda: bench_commands(repeats, args.quick),
                   "estimates": lambda: bench_estimates(repeats=1, quick=args.quick),
                   "sweep": lambda: bench_sweep_overhead(points=50 if args.quick else 200)
                   + ([] if args.quick else bench_example_sweeps())
                   + bench_sweep_scaling(points=100 if args.quick else 1000),
                   "scheduler": lambda: bench_scheduler(trials=10**6 if args.quick else 10**7),
                   "calibration": lambda: bench_calibration(seeds=20 if args.quick else 200),
                   "fresh": lambda: [] if args.quick else bench_fresh_clone()}
        # reproduce before record: the recording replay uses the reproductions' recordings
        order = ("floor", "estimators", "bounds", "scale", "plugin", "reproduce", "record", "startup", "commands", "estimates",
                 "sweep", "scheduler", "calibration", "fresh")
        for key in sorted(only, key=order.index):
            print(f"[bench] {key} ...", file=sys.stderr, flush=True)
            t0 = time.perf_counter()
            try:
                results[key] = runners[key]()
            except Exception as exc:
                traceback.print_exc()
                results[key] = [{"error": f"{type(exc).__name__}: {exc}"}]
            timings[key] = time.perf_counter() - t0
    finally:
        if not keep:
            shutil.rmtree(replay_dir, ignore_errors=True)

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    meta = {"machine": f"{os.cpu_count()} cores, {platform.machine()}, Python {sys.version.split()[0]}, "
                       f"numpy {np.__version__}", "quick": args.quick, "repeats": repeats,
            "section_wall_s": timings, "total_wall_s": time.perf_counter() - t_start,
            "date": time.strftime("%Y-%m-%d %H:%M:%S")}
    md = [f"# Benchmarks{' (quick)' if args.quick else ''}", "",
          f"{meta['machine']}; {meta['date']}; OPENBLAS_NUM_THREADS=1; each figure the median of {repeats} repeats "
          "with (min, max) unless marked otherwise. Timings on a shared 2-core machine are noisy: compare medians.", ""]
    md += _targets(results)
    for key in SECTIONS:
        if key in results:
            md += [f"## {TITLES[key]}", "", table(results[key])]
    md.append(f"Section wall times (s): {', '.join(f'{k} {v:.0f}' for k, v in timings.items())}.")
    (out / "bench.md").write_text("\n".join(md) + "\n")
    (out / "bench.json").write_text(json.dumps({"meta": meta, **results}, indent=1, default=_json_default))
    print((out / "bench.md").read_text())
    return 0


def _json_default(x):
    if isinstance(x, (np.floating, np.integer, np.bool_)):
        return x.item()
    if isinstance(x, (tuple, set)):
        return list(x)
    return str(x)


def _targets(results: dict[str, list[dict]]) -> list[str]:
    """The issue's targets with the measured figure and whether it is met."""
    lines = ["## Targets", "", "| target | measured | met |", "|---|---|---|"]
    for r in results.get("estimators", []):
        if r.get("target"):
            lines.append(f"| {r['estimator']} ({r['size']}): {r['target']} | "
                         f"{_fmt(r['batched'])} {r['unit']}" + (f", {_fmt(r['ratio'])}x loop" if "ratio" in r else "")
                         + f" | {_fmt(r['met'])} |")
    for r in results.get("scale", []):
        if r.get("target") and "mc_s" in r:
            lines.append(f"| {r['name']} ({r['trials']:,} trials, {r['steps']} steps): {r['target']} | "
                         f"{_fmt(r['mc_s'])} s | {_fmt(r['met'])} |")
    for r in results.get("plugin", []):
        if r.get("target"):
            lines.append(f"| {r['name']} ({r['nodes']} nodes, {r['trials']:,} trials, {r['steps']} steps, CPU): "
                         f"{r['target']} | {_fmt(r['ratio'])}x | {_fmt(r['met'])} |")
    for r in results.get("record", []):
        if r.get("target"):
            lines.append(f"| {r['name']}: {r['target']} | {_fmt(r['M_scalars_per_s'])} M/s | {_fmt(r['met'])} |")
    for r in results.get("reproduce", []):
        if "error" in r:
            lines.append(f"| reproduce {r['paper']} ({r['mode']}) | error: {r['error']} | **no** |")
        elif r.get("paper", "").startswith("all"):
            lines.append(f"| {r['paper']} papers, {r['mode']}, {r['what']}: {r['target']} | {_fmt(r['value'])} s | "
                         f"{_fmt(r['met'])} |")
        elif r.get("mode") == "default":
            lines.append(f"| peak memory, reproduce {r['paper']}: {r['target']} | {_fmt(r['peak_tree_rss_mib'])} MiB "
                         f"(tree), {_fmt(r['max_process_rss_mib'])} MiB (one process) | {_fmt(r['met'])} |")
    for r in results.get("startup", []) + results.get("commands", []):
        if r.get("target"):
            lines.append(f"| {r['command']}: {r['target']} | {_fmt(r['wall_s'])} s wall"
                         + (f", {_fmt(r['cpu_s'])} s CPU" if "cpu_s" in r else "") + f" | {_fmt(r['met'])} |")
    estimates = [r for r in results.get("estimates", []) if "est/cpu" in r]
    if estimates:
        missed = [r for r in estimates if not r["met"]]
        worst = max(estimates, key=lambda r: abs(math.log(r["est/cpu"])))
        lines.append(f"| dse check's time estimate within {TARGET_FACTOR:g}x of the measured `dse run --quick` (CPU, one "
                     f"worker; {len(estimates)} scenarios) | worst {worst['scenario']}: {_fmt(worst['est/cpu'])} | "
                     + ("yes" if not missed else f"**no** ({len(missed)}: " + ", ".join(r["scenario"] for r in missed[:5])
                        + ")") + " |")
    for r in results.get("sweep", []):
        if "overhead_ms_per_point" in r and r.get("target"):
            lines.append(f"| {r['what']}: overhead {r['target']} (CPU beyond the points' stages) | "
                         f"{_fmt(r['overhead_ms_per_point'])} ms per point | {_fmt(r['met'])} |")
        elif r.get("target") and "wall_s" in r:
            lines.append(f"| {r['what']}: {r['target']} | {_fmt(r['wall_s'])} s wall, {_fmt(r['cpu_s'])} s CPU | "
                         f"{_fmt(r['met'])} |")
        if "speedup_vs_1_worker" in r:
            lines.append(f"| dse sweep, {r['points']} points: 2 workers >= 1.9x one | "
                         f"speed-up {_fmt(r['speedup_vs_1_worker'])} | {'yes' if r['speedup_vs_1_worker'] >= 1.9 else '**no**'} |")
    for r in results.get("fresh", []):
        if r.get("target"):
            lines.append(f"| {r['what']}: {r['target']} | {_fmt(r['wall_s'] / 60)} min wall ({_fmt(r['cpu_s'])} s CPU) | "
                         f"{_fmt(r['met'])} |")
    for r in results.get("scheduler", []):
        if "speedup_vs_1_worker" in r:
            lines.append(f"| dse run --scheduler local, {r['trials']:,} trials: {r['target']}, numbers identical to in "
                         f"process | speed-up {_fmt(r['speedup_vs_1_worker'])} ({_fmt(r['speedup_vs_in_process'])} over "
                         f"in process); differences: {r['differences']} | {_fmt(r['met'])} |")
    calib = [r for r in results.get("calibration", []) if "tested" in r]
    if calib:
        bad = [r for r in calib if not r["calibrated"]]
        worst = max(calib, key=lambda r: r["rate"] if r["tested"] else -1)
        lines.append(f"| statistical claims keep their level on random valid scenarios (no 95 % interval of the false-fail "
                     f"rate wholly above 0.05; {len(calib)} claims) | worst {worst['claim']}: {_fmt(worst['rate'])} "
                     f"| {'yes' if not bad else '**no** (' + ', '.join(r['claim'] for r in bad[:5]) + ')'} |")
    return lines + [""]


if __name__ == "__main__":
    raise SystemExit(main())
