"""The Monte Carlo of the compare and hybrid-observer families on the run's unit executor (portable chunks), beside
tests/test_scheduler_run.py's families: every unit goes to a local Dask cluster, and the numbers are the same bits
as in process.

- compare (`network_comparison.simulate_group`): on a local cluster, in process, and with the estimators split over
  forked workers, every estimator's sums, token draws and sample paths are the same bits, and a plug-in that fails
  in every chunk is dropped with the same line. The scenario has 3.5 units of trials (the last one short) and a
  well-behaved and a failing plug-in beside three built-ins of different kinds (no messages, messages, swaps).
- hybrid-observer (`wang_liu_morse.monitor`: a chunk's units kept apart, absorbed by the run in unit order): the
  generator's two-agent scenario, three runs (synchronous, ideal, asynchronous) of 2.1 units each; every table
  and verdict is the same."""
from __future__ import annotations

import numpy as np
import pytest

import dse
from dse import registry
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


class _Tasks:
    """The unit ranges a `DaskExecutor` was given (a spy on `map_units`)."""

    def __init__(self, monkeypatch):
        self.ranges = []
        dask_map = executor.DaskExecutor.map_units

        def spy(executor_, simulate_chunk, seq, n_trials, per_chunk, ranges):
            ranges = list(ranges)
            self.ranges.append(ranges)
            return dask_map(executor_, simulate_chunk, seq, n_trials, per_chunk, ranges)

        monkeypatch.setattr(executor.DaskExecutor, "map_units", spy)

    def units(self) -> list[list[int]]:
        """Per `run_units` call, the units sent to the cluster."""
        return [sorted(u for a, b in call for u in range(a, b)) for call in self.ranges]


def _same_tables(a, b) -> None:
    assert list(a.tables) == list(b.tables)
    for table in a.tables:
        assert a.tables[table].equals(b.tables[table]), table


def _run(scheduler: str, workers: int):
    return dse.run(_scenario(), trials=TRIALS, seed=3, scheduler=scheduler, workers=workers)


@pytest.fixture(scope="module")
def cluster():
    """The address of one local cluster of two workers, which the module's runs on a cluster are given (as
    `--scheduler tcp://...`): a run with `scheduler="local"` starts a cluster of its own, and its workers import
    the scenario's code anew (tests/test_scheduler_run.py runs one)."""
    from dse.simulate.cluster import start_local

    local, client = start_local(2)
    try:
        yield local.scheduler_address
    finally:
        client.close()
        local.close()


@pytest.fixture(scope="module")
def in_process():
    return _run("inline", 1)


@pytest.mark.parametrize("scheduler,workers", [("local", 2), ("auto", 2), ("auto", 1)])
def test_the_monte_carlo_is_the_same_bits_wherever_its_units_ran(in_process, scheduler, workers, monkeypatch, request):
    tasks = _Tasks(monkeypatch)
    other = _run(request.getfixturevalue("cluster") if scheduler == "local" else scheduler, workers)
    if scheduler == "local":            # the units went to the cluster, every one of them
        assert tasks.units() == [list(range(-(-TRIALS // 1000)))]
    a, b = in_process.results, other.results
    assert list(a.mc) == list(b.mc) and "good" in a.mc and "bad" not in a.mc
    for name in a.mc:
        assert_same_bits(stage_arrays(a, name), stage_arrays(b, name), name)
    assert set(a.paths) == set(b.paths)
    for name in a.paths:
        assert np.array_equal(a.paths[name], b.paths[name]), name
    assert a.faults == b.faults == {"bad": a.faults["bad"]}
    assert "failed at step 3: raised RuntimeError: boom" in a.faults["bad"]
    _same_tables(in_process, other)


def test_hybrid_observer_runs_on_a_local_cluster_with_the_same_bits(cluster, monkeypatch):
    scenario = registry.families()["hybrid-observer"].generate(0, "two_agents")
    in_process = dse.run(scenario, trials=2100, scheduler="inline", workers=1)
    tasks = _Tasks(monkeypatch)
    on_cluster = dse.run(scenario, trials=2100, scheduler=cluster, workers=2)
    assert tasks.units() == [[0, 1, 2]] * len(scenario["runs"])
    _same_tables(in_process, on_cluster)
    assert in_process.evaluation.claims == on_cluster.evaluation.claims
