"""compare's Monte Carlo on the run's unit executor (`network_comparison.simulate_group`, portable chunks): on a
local Dask cluster, in process, and with the estimators split over forked workers, every estimator's sums, token
draws and sample paths are the same bits, and a plug-in that fails in every chunk is dropped with the same line.
The scenario has 3.5 units of trials (the last one short) and a well-behaved and a failing plug-in beside three
built-ins of different kinds (no messages, messages, state swaps)."""
from __future__ import annotations

import numpy as np
import pytest

import dse
from dse.simulate import executor

from test_compare_family import tiny
from test_plugin_protocol import assert_same_bits, stage_arrays

TRIALS = 3500


def _scenario() -> dict:
    data = tiny()
    data["estimators"] = {"include": ["local", "diffusion", "gikf"],
                          "good": {"factory": "tests.plugins.twins:LocalTwin"},
                          "bad": {"factory": "tests.plugins.bad:RaisesInStep"}}
    return data


def _run(scheduler: str, workers: int):
    return dse.run(_scenario(), trials=TRIALS, seed=3, scheduler=scheduler, workers=workers)


@pytest.fixture(scope="module")
def in_process():
    return _run("inline", 1)


@pytest.mark.parametrize("scheduler,workers", [("local", 2), ("auto", 2), ("auto", 1)])
def test_the_monte_carlo_is_the_same_bits_wherever_its_units_ran(in_process, scheduler, workers, monkeypatch):
    tasks = []
    dask_map = executor.DaskExecutor.map_units

    def spy(self, simulate_chunk, seq, n_trials, per_chunk, ranges):
        ranges = list(ranges)
        tasks.extend(ranges)
        return dask_map(self, simulate_chunk, seq, n_trials, per_chunk, ranges)

    monkeypatch.setattr(executor.DaskExecutor, "map_units", spy)
    other = _run(scheduler, workers)
    if scheduler == "local":            # the units went to the cluster, every one of them
        assert sorted(u for a, b in tasks for u in range(a, b)) == list(range(-(-TRIALS // 1000)))
    a, b = in_process.results, other.results
    assert list(a.mc) == list(b.mc) and "good" in a.mc and "bad" not in a.mc
    for name in a.mc:
        assert_same_bits(stage_arrays(a, name), stage_arrays(b, name), name)
    assert set(a.paths) == set(b.paths)
    for name in a.paths:
        assert np.array_equal(a.paths[name], b.paths[name]), name
    assert a.faults == b.faults == {"bad": a.faults["bad"]}
    assert "failed at step 3: raised RuntimeError: boom" in a.faults["bad"]
    for table in in_process.tables:
        if "cpu" not in table and "time" not in table:
            assert in_process.tables[table].equals(other.tables[table]), table
