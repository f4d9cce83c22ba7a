"""The plug-in protocol's overhead (`dse.plugin`) on the compare benchmark of issue 17 (benchmarks/bench_compare.py:
50 nodes, a 4-state plant, 1,000 trials, 500 steps, link failures).

(a) dispatch: `LocalTwin` (tests/plugins/twins.py: the built-in local filter's arithmetic through the public
    protocol) against the built-in `local`: what the harness adds per step (read-only views of the inputs, the
    checks of what comes back, the counting of what was sent). Target: at most 5 % more CPU per step.
(b) messages: `DiffusionTwin` (the diffusion filter, its two exchanges delivered through the inbox) against the
    built-in `diffusion` (sparse products over the links): the ratio, no target.
(c) the built-ins' own cost before and after the plug-in change (which added the paired `gap` statistic to the
    accumulator): the whole simulation of the built-in estimators, CPU per step, on this tree and on the tree of
    commit `BEFORE` (extracted with `git archive`). Target: at most 5 % more.

Every figure is CPU time (`time.process_time`) in one process (one worker), the median of interleaved
repetitions: in (a) and (b) the filters step in lock step within one simulation (each filter's step and its
statistics timed separately, at every step), so the machine's load hits them alike; in (c) the two trees
alternate, one process each. Run alone: `.venv/bin/python -m benchmarks.bench_plugin [--trials 1000] [--steps 500]`.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import tarfile
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
TARGET = 0.05
#: the last commit before the plug-in protocol (fb2c7f8 added it, and the `gap` sums to the accumulator)
BEFORE = "fb2c7f8^"
TWINS = {"twin": "tests.plugins.twins:LocalTwin", "dtwin": "tests.plugins.twins:DiffusionTwin"}


def _setup(links: str, steps: int, trials: int, include: list[str], plugins: dict[str, str]):
    """The benchmark scenario's simulation `Setup` with the built-ins `include` (and the centralized reference) and
    the plug-ins, designed as the monte_carlo stage designs it (the plug-ins' time limit lifted)."""
    from dse import registry
    from dse.contract.context import StageContext
    from dse.contract.options import RunOptions
    from dse.engine.cache import MemoryCache
    from dse.estimators.network_comparison import Setup
    from dse.families.compare import stages

    from .bench_compare import scenario

    data = scenario(links, steps, trials)
    data["estimators"] = {"include": include, **{name: {"factory": f} for name, f in plugins.items()}}
    run = registry.from_dict(data)
    sc = run.scenario
    d = run.design(RunOptions(seed=0, trials=trials, workers=1), StageContext(MemoryCache()))
    d.network.shared.update(trials=trials, time_limits={name: math.inf for name in plugins})
    return Setup(d.model, d.links, steps, d.running, token_times=stages.token_times(sc), n_paths=sc.simulation.paths,
                 record_steps=stages.recorded(sc))


def _timed_simulation(setup, trials: int) -> dict[str, float]:
    """name -> CPU seconds of its steps plus its statistics (`Accumulator.add`: the counting of what it sent, the
    sums) over the run, every filter in lock step in this process."""
    from dse.estimators import network_comparison as nc

    spent: dict[str, float] = {}
    add = nc.Accumulator.add

    def timed_add(self, name, *args):
        t0 = time.process_time()
        add(self, name, *args)
        spent[name] = spent.get(name, 0.0) + time.process_time() - t0

    nc.Accumulator.add = timed_add
    try:
        with np.errstate(over="ignore", invalid="ignore"):
            out = nc.simulate(setup, 0, trials, 4 * 2 ** 30, workers=1)
    finally:
        nc.Accumulator.add = add
    assert not out["faults"], out["faults"]
    return {name: out["seconds"][name] + spent.get(name, 0.0) for name in out["seconds"]}


PAIRS = (("twin", "local", "dispatch (read-only inputs, checks, counting)", True),
         ("dtwin", "diffusion", "messages through the inbox", False))


def bench_protocol(links: str = "failures", steps: int = 500, trials: int = 1000, repeats: int = 3) -> list[dict]:
    """Rows (a) and (b): each twin against its built-in in one simulation (with the centralized reference),
    CPU per step, median of `repeats` simulations."""
    if str(ROOT) not in sys.path:
        sys.path.insert(0, str(ROOT))            # tests.plugins.twins
    setups = {plugin: _setup(links, steps, trials, [builtin], {plugin: TWINS[plugin]})
              for plugin, builtin, _, _ in PAIRS}
    runs: dict[str, list[dict[str, float]]] = {plugin: [] for plugin in setups}
    for _ in range(repeats):
        for plugin, setup in setups.items():
            runs[plugin].append(_timed_simulation(setup, trials))
    rows = []
    for plugin, builtin, what, target in PAIRS:
        ratios = [r[plugin] / r[builtin] for r in runs[plugin]]
        ms = {e: [1e3 * r[e] / steps for r in runs[plugin]] for e in (plugin, builtin)}
        ratio = float(np.median(ratios))
        rows.append({"name": f"plug-in {TWINS[plugin].split(':')[1]} against the built-in {builtin}: {what}",
                     "links": links, "nodes": setups[plugin].model.N, "trials": trials, "steps": steps,
                     "plugin_ms_per_step": float(np.median(ms[plugin])),
                     "plugin_ms_per_step_spread": (min(ms[plugin]), max(ms[plugin])),
                     "builtin_ms_per_step": float(np.median(ms[builtin])),
                     "builtin_ms_per_step_spread": (min(ms[builtin]), max(ms[builtin])),
                     "ratio": ratio, "ratio_spread": (min(ratios), max(ratios)),
                     "target": f"<= {1 + TARGET:g}x the built-in's CPU per step" if target else "",
                     "met": ratio <= 1 + TARGET if target else ""})
    return rows


#: run in a fresh interpreter on one tree: the built-ins' whole simulation, CPU seconds (APIs both trees have)
_BUILTINS_SCRIPT = """
import json, sys, time
import numpy as np
from dse import registry
from dse.contract.context import StageContext
from dse.contract.options import RunOptions
from dse.engine.cache import MemoryCache
from dse.estimators.network_comparison import Setup, simulate
from dse.families.compare import stages
from benchmarks.bench_compare import scenario
links, steps, trials = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
run = registry.from_dict(scenario(links, steps, trials))
sc = run.scenario
d = run.design(RunOptions(seed=0, trials=trials, workers=1), StageContext(MemoryCache()))
setup = Setup(d.model, d.links, steps, d.running, token_times=stages.token_times(sc), n_paths=sc.simulation.paths,
              record_steps=stages.recorded(sc))
with np.errstate(over="ignore", invalid="ignore"):
    t0 = time.process_time()
    out = simulate(setup, 0, trials, 4 * 2 ** 30, workers=1)
    cpu = time.process_time() - t0
print(json.dumps({"cpu_s": cpu, "estimators": sorted(out["mc"])}))
"""


def _builtins_cpu(tree: Path, links: str, steps: int, trials: int) -> dict:
    env = {**os.environ, "PYTHONPATH": str(tree), "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1",
           "MKL_NUM_THREADS": "1"}
    proc = subprocess.run([sys.executable, "-c", _BUILTINS_SCRIPT, links, str(steps), str(trials)], cwd=tree, env=env,
                          capture_output=True, text=True, check=True)
    return json.loads(proc.stdout.splitlines()[-1])


def _tree_at(commit: str, into: Path) -> Path:
    """The package and the benchmarks of `commit`, extracted from this repository into `into`."""
    archive = subprocess.run(["git", "-C", str(ROOT), "archive", "--format=tar", commit, "dse", "benchmarks"],
                             capture_output=True, check=True).stdout
    tar = into / "tree.tar"
    tar.write_bytes(archive)
    with tarfile.open(tar) as t:
        t.extractall(into, filter="data")
    return into


def bench_builtins_before_after(links: str = "failures", steps: int = 500, trials: int = 1000,
                                repeats: int = 3) -> list[dict]:
    """Row (c): the built-ins' simulation, CPU per step, on this tree and on `BEFORE`'s, alternating."""
    with tempfile.TemporaryDirectory(prefix="dse-bench-before-") as tmp:
        before = _tree_at(BEFORE, Path(tmp))
        cpu: dict[str, list[float]] = {"before": [], "after": []}
        names = {}
        for _ in range(repeats):
            for label, tree in (("before", before), ("after", ROOT)):
                r = _builtins_cpu(tree, links, steps, trials)
                cpu[label].append(1e3 * r["cpu_s"] / steps)
                names[label] = r["estimators"]
    assert names["before"] == names["after"], names
    ratios = [a / b for a, b in zip(cpu["after"], cpu["before"])]
    ratio = float(np.median(ratios))
    return [{"name": f"the built-ins' simulation ({len(names['after'])} estimators) before ({BEFORE}) and after the "
                     "plug-in change (the paired gap statistic in the accumulator)",
             "links": links, "nodes": 50, "trials": trials, "steps": steps,
             "plugin_ms_per_step": float(np.median(cpu["after"])),
             "plugin_ms_per_step_spread": (min(cpu["after"]), max(cpu["after"])),
             "builtin_ms_per_step": float(np.median(cpu["before"])),
             "builtin_ms_per_step_spread": (min(cpu["before"]), max(cpu["before"])),
             "ratio": ratio, "ratio_spread": (min(ratios), max(ratios)),
             "target": f"<= {1 + TARGET:g}x before", "met": ratio <= 1 + TARGET}]


def bench_plugin(quick: bool = False, repeats: int = 3) -> list[dict]:
    """The `plugin` section of `make bench`: rows (a), (b), (c). In the rows of (c), `plugin_ms_per_step` is the
    tree after the change and `builtin_ms_per_step` the tree before."""
    steps, trials = (100, 200) if quick else (500, 1000)
    return bench_protocol(steps=steps, trials=trials, repeats=repeats) + bench_builtins_before_after(
        steps=steps, trials=trials, repeats=repeats)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--links", default="failures")
    p.add_argument("--steps", type=int, default=500)
    p.add_argument("--trials", type=int, default=1000)
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--only", choices=("protocol", "builtins"), default=None)
    a = p.parse_args()
    if a.only != "builtins":
        for row in bench_protocol(a.links, a.steps, a.trials, a.repeats):
            print(row, flush=True)
    if a.only != "protocol":
        for row in bench_builtins_before_after(a.links, a.steps, a.trials, a.repeats):
            print(row, flush=True)


if __name__ == "__main__":
    main()
