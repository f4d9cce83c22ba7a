"""The short commands pay only for what they use: `dse check` with its design in the stage cache imports no drawing,
graph or cluster library, and a run's stages start worker processes only when there is work left that is worth
their start (`StageContext.run_many`, `worth_forking`), with the same results wherever the stages ran."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from benchmarks.common import toml_text
from benchmarks.small_scenarios import small_scenario
from dse import registry
from dse.contract.context import StageContext, worth_forking
from dse.engine.cache import MemoryCache
from dse.families.template import stages as template_stages
from dse.simulate import units

ROOT = Path(__file__).resolve().parent.parent

#: `dse ARGS...` in a fresh interpreter; prints its exit code and the modules it left imported
MODULES_AFTER = """
import contextlib, io, json, sys
from dse.cli import main
with contextlib.redirect_stdout(io.StringIO()):
    code = main(sys.argv[1:])
print(json.dumps({"code": code, "modules": sorted(sys.modules)}))
"""
#: what a check whose design is cached never needs: figures, recordings, graphs (tran's Laplacian is computed from
#: its edges), clusters, the reference filters and scipy.stats (about a second each to import), and, without
#: progress bars, tqdm
NOT_FOR_CHECK = {"matplotlib", "rerun", "networkx", "dask", "distributed", "filterpy", "scipy.stats", "tqdm"}


def test_a_check_with_its_design_cached_imports_no_drawing_graph_or_cluster_library(tmp_path):
    path, out = tmp_path / "coestimation.toml", tmp_path / "out"
    path.write_text(toml_text(small_scenario("coestimation")))
    env = {"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin", "OPENBLAS_NUM_THREADS": "1", "DSE_PROGRESS": "0"}
    args = ["check", str(path), "--out", str(out)]
    first = subprocess.run([sys.executable, "-m", "dse.cli", *args], capture_output=True, text=True, env=env, cwd=ROOT,
                           timeout=600)
    assert first.returncode == 0 and "computed and stored" in first.stdout, first.stderr[-2000:]
    proc = subprocess.run([sys.executable, "-c", MODULES_AFTER, *args], capture_output=True, text=True, env=env,
                          cwd=ROOT, timeout=600)
    assert proc.returncode == 0, proc.stderr[-2000:]
    got = json.loads(proc.stdout)
    assert got["code"] == 0
    assert not NOT_FOR_CHECK & set(got["modules"]), sorted(NOT_FOR_CHECK & set(got["modules"]))


def test_workers_are_worth_starting_only_for_two_calls_or_more_that_save_more_than_their_start():
    assert not worth_forking([], 2, seconds=False) and not worth_forking([5.0], 2, seconds=True)
    assert worth_forking([0.001, 0.001], 2, seconds=False)          # weights without a unit: as before
    assert not worth_forking([0.01, 0.01, 0.02], 2, seconds=True)
    assert not worth_forking([30.0, 0.01], 2, seconds=True)          # one long call: nothing to run beside it
    assert worth_forking([1.0, 1.0], 2, seconds=True)


def _calls(n: int) -> list:
    sc = registry.from_dict(small_scenario("template")).scenarios[0]
    return [(template_stages.monte_carlo, (sc, seed, 2000, 2**26), {}) for seed in range(n)]


@pytest.fixture
def forks(monkeypatch) -> list[int]:
    """The number of items of every `parallel_map` that started workers (it still runs them)."""
    started, original = [], units.parallel_map

    def recorded(fn, items, *, workers=1, desc=""):
        items = list(items)
        if workers > 1 and len(items) > 1:
            started.append(len(items))
        return original(fn, items, workers=workers, desc=desc)

    monkeypatch.setattr(units, "parallel_map", recorded)
    return started


def test_stages_run_here_when_the_cost_model_says_workers_would_not_pay(forks):
    calls = _calls(2)
    here = StageContext(MemoryCache()).run_many(calls, workers=2, weights=[0.01, 0.01], seconds=True)
    assert forks == []
    forked = StageContext(MemoryCache()).run_many(calls, workers=2, weights=[0.01, 0.01])
    assert forks == [2]
    for a, b in zip(here, forked):
        assert a.key == b.key and a.keys() == b.keys()
        assert all(np.array_equal(a[k], b[k]) for k in a)


def test_stages_already_in_the_cache_start_no_workers(forks):
    calls = _calls(3)
    ctx = StageContext(MemoryCache())
    ctx.run(calls[0][0], *calls[0][1])
    ctx.run(calls[1][0], *calls[1][1])
    ctx.run_many(calls, workers=2)                   # one call left: computed here
    assert forks == []
    assert [r["cached"] for r in ctx.ran] == [False, False, True, True, False]
