"""One run's Monte Carlo on a Dask cluster (`dse run --scheduler`, `dse.run(scheduler=...)`): the same bits as
in process whatever the number of workers, a bounded number of partial results on the client, a worker that
dies replaced and its units recomputed, an interrupted stage resumed from the units it had stored, and the
option checked in one line. The 10^7-trial comparison and the random-comm-filter and coestimation examples on a
cluster are marked `large` (minutes: skipped unless DSE_LARGE_TESTS=1; `make bench`, section `scheduler`, runs
the 10^7-trial comparison)."""
from __future__ import annotations

import functools
import os
from pathlib import Path

import numpy as np
import pytest

import dse
from dse.cli import main
from dse.errors import UsageError
from dse.simulate import checkpoints, executor
from dse.simulate.seeding import stream_seed
from dse.simulate.units import run_units

#: a noisy-consensus-filter scenario small per trial (2 agents, one step, no consensus round): 10^7 trials
#: take about 30 s of CPU in one process
MICRO = {"family": "noisy-consensus-filter", "name": "micro", "graph": {"kind": "line", "n": 2},
         "model": {"q": 1.0, "r": 1.0}, "sweep": {"rounds": [0], "sigma_c": [0.5], "n_steps": 1},
         "gains": {"grid": [11, 11]}, "monte_carlo": {"trials": 100_000, "sample_paths": 2}}
large = pytest.mark.skipif(os.environ.get("DSE_LARGE_TESTS") != "1",
                           reason="10^7 trials: set DSE_LARGE_TESTS=1 (make bench runs it, section scheduler)")


def _mc_bytes(run) -> dict[str, bytes]:
    """Every Monte Carlo array of a savas run, as bytes."""
    return {f"{label}/{k}": np.ascontiguousarray(v).tobytes() + str(v.dtype).encode()
            for label, arrays in run.results.mc.items() for k, v in arrays.items()}


def _same_run(a, b) -> None:
    assert _mc_bytes(a) == _mc_bytes(b)
    assert list(a.tables) == list(b.tables)
    for name in a.tables:
        assert a.tables[name].equals(b.tables[name]), name


@pytest.fixture(scope="module")
def in_process():
    return dse.run(MICRO, trials=30_000, scheduler="inline", workers=1)


def test_a_local_cluster_gives_the_same_bits_as_in_process(in_process):
    on_cluster = dse.run(MICRO, trials=30_000, scheduler="local", workers=2)
    _same_run(in_process, on_cluster)
    _same_run(in_process, dse.run(MICRO, trials=30_000, scheduler="auto", workers=2))


@large
def test_ten_million_trials_on_two_workers_are_the_same_bits_as_in_process():
    _same_run(dse.run(MICRO, trials=10**7, scheduler="inline", workers=1, max_time_s=float("inf")),
              dse.run(MICRO, trials=10**7, scheduler="local", workers=2, max_time_s=float("inf")))


def _normal_sums(streams, die_at: int = -1, marker: str = ""):
    """A portable chunk: per unit, the sum of its trials' draws (3 per trial). With `die_at`, the worker that
    first computes unit `die_at` dies (its process exits) once."""
    if streams.first_unit <= die_at < streams.first_unit + len(streams.sizes) and not Path(marker).exists():
        Path(marker).write_text("died")
        os._exit(1)
    return [part.sum(axis=0) for part in streams.split(streams.standard_normal((3,)))]


def _add(acc, part):
    return part if acc is None else acc + part


def _sums(chunk, trials: int = 40_000, budget: float = 2 * 8 * 3 * 1000):
    return run_units(chunk, _add, trials, stream_seed(7, "test"), bytes_per_trial=8 * 3, budget_bytes=budget,
                     portable=True)


@pytest.fixture(scope="module")
def two_workers():
    """One local cluster of two workers for the tests below."""
    dask = executor.DaskExecutor("local", 2)
    yield dask
    dask.close()


def test_the_client_holds_a_bounded_number_of_tasks(two_workers):
    window = executor.IN_FLIGHT_PER_WORKER * two_workers.workers       # the most the executor sends at once
    held = []
    for _ in two_workers.map_units(_normal_sums, stream_seed(1, "bounded"), 200_000, 2,
                                   executor.task_ranges(0, 200, 2)):
        held.append(len(two_workers.client().futures))
    assert len(held) == 100 and max(held) <= window + 1      # the tasks in flight and the chunk function


def test_a_local_cluster_keeps_its_housekeeping_quiet(two_workers):
    """The dashboard's profiler is off and the event-loop health checks are sparse on the scheduler and on every
    worker (`cluster.QUIET_CONFIG`): with Dask's defaults they took a fifth of a core from the tasks on 2 cores."""
    def worker_settings(dask_worker):
        return "profile" in dask_worker.periodic_callbacks, dask_worker._tick_interval

    client = two_workers.client()
    assert set(client.run(worker_settings).values()) == {(False, 0.5)}
    assert client.run_on_scheduler(lambda dask_scheduler: dask_scheduler._tick_interval) == 0.5


@pytest.fixture
def store_at_once(monkeypatch):
    """Units are kept from a call's start (not after STORE_AFTER_S seconds): the tests' stages are short."""
    monkeypatch.setattr(checkpoints, "STORE_AFTER_S", 0.0)


def test_units_travel_packed_and_unpickle_as_they_were(tmp_path, store_at_once):
    """A task's partials are sent as one stacked array per key (`executor.PackedUnits`) and unpickle to the same
    list (also when stored from that pickle and read back): same keys, types, dtypes, shapes and bits; partials
    that do not share them travel as the list."""
    import pickle

    parts = [{"s": np.arange(6.0).reshape(2, 3) * (i + 0.1), "n": np.int64(i), "z": np.array(1.5 * i)} for i in range(4)]
    blob = pickle.dumps(executor.PackedUnits(parts), protocol=pickle.HIGHEST_PROTOCOL)
    assert b"_unstack_units" in blob
    store = checkpoints.UnitCheckpoints(tmp_path / "call")
    store.add(0, parts, blob)
    store.flush()
    back = pickle.loads(blob)
    stored = store.load(store.stored()[0][2], len(parts))
    assert [list(p) for p in back] == [list(p) for p in stored] == [list(p) for p in parts]
    for p, q in [*zip(parts, back), *zip(parts, stored)]:
        for k in p:
            assert type(q[k]) is type(p[k]) and q[k].dtype == p[k].dtype and q[k].shape == p[k].shape
            assert np.asarray(q[k]).tobytes() == np.asarray(p[k]).tobytes()
    for odd in (parts[:2] + [{**parts[2], "s": np.zeros(3)}], [*parts[:3], {"n": np.int64(3)}], [1.0, 2.0]):
        blob = pickle.dumps(executor.PackedUnits(odd), protocol=pickle.HIGHEST_PROTOCOL)
        assert b"_unstack_units" not in blob and repr(pickle.loads(blob)) == repr(odd)


def test_a_worker_that_dies_has_its_units_recomputed(tmp_path, two_workers):
    expected = _sums(_normal_sums)
    with executor.using(two_workers, close=False):
        got = _sums(functools.partial(_normal_sums, die_at=13, marker=str(tmp_path / "died")))
    assert (tmp_path / "died").exists()          # a worker did die
    assert got.tobytes() == expected.tobytes()


def test_an_interrupted_stage_resumes_from_the_units_it_stored(tmp_path, store_at_once):
    expected = _sums(_normal_sums)
    computed: list[int] = []

    def interrupted(streams):
        if streams.first_unit >= 24:
            raise KeyboardInterrupt
        computed.append(streams.first_unit)
        return _normal_sums(streams)

    with checkpoints.stage_scope(tmp_path / "stage"), pytest.raises(KeyboardInterrupt):
        _sums(interrupted)
    assert checkpoints.checkpoint_summary(tmp_path / "stage") == {"files": 1, "units": 24}

    def counted(streams):
        computed.append(streams.first_unit)
        return _normal_sums(streams)

    computed.clear()
    with checkpoints.stage_scope(tmp_path / "stage"):
        got = _sums(counted)
    assert got.tobytes() == expected.tobytes()
    assert sorted(computed) == list(range(24, 40, 2))          # the 16 units not stored, two per chunk


def test_a_short_call_keeps_no_units(tmp_path):
    with checkpoints.stage_scope(tmp_path / "stage"):
        _sums(_normal_sums)
    assert checkpoints.checkpoint_summary(tmp_path / "stage") == {"files": 0, "units": 0}


def test_an_interrupted_run_resumes_and_gives_the_same_numbers(tmp_path, monkeypatch, in_process, store_at_once):
    """Through the stage cache: Ctrl-C in the middle of the savas groups, then the same run again: only the
    chunks not stored are simulated (10 units each), and the numbers are those of an uninterrupted run."""
    import dse.estimators.consensus_filter as cf

    real, calls = cf.consensus_filter_moments, []

    def counted(*args, **kwargs):
        calls.append(1)
        if len(calls) == stop_at:
            raise KeyboardInterrupt
        return real(*args, **kwargs)

    monkeypatch.setattr(cf, "consensus_filter_moments", counted)
    stop_at = 0
    dse.run(MICRO, trials=30_000, scheduler="inline", workers=1, cache_dir=tmp_path / "fresh")
    fresh_calls, stop_at = len(calls), 6
    calls.clear()
    with pytest.raises(KeyboardInterrupt):
        dse.run(MICRO, trials=30_000, scheduler="inline", workers=1, cache_dir=tmp_path / "run")
    stored = checkpoints.checkpoint_summary(tmp_path / "run" / "units")
    assert stored["units"] >= 10 and stored["units"] % 10 == 0
    calls.clear()
    again = dse.run(MICRO, trials=30_000, scheduler="inline", workers=1, cache_dir=tmp_path / "run")
    _same_run(in_process, again)
    assert not (tmp_path / "run" / "units").exists()            # removed once the stages' entries are stored
    finished_groups = 5 - stored["units"] // 10                # chunks of the groups stored whole before Ctrl-C
    assert len(calls) == fresh_calls - finished_groups - stored["units"] // 10


def test_the_machinery_is_in_no_stage_key():
    """How units are run and stored cannot change them: editing the executor, the stored units or the cluster
    code invalidates no stage (they are not in the portable stages' code closures)."""
    from dse.contract.stages import code_closure

    for module in ("dse.families.savas.monte_carlo", "dse.families.tanwani.monte_carlo", "dse.families.tran.runs",
                   "dse.families.kar_moura.gikf", "dse.families.template.stages"):
        closure = code_closure(module)
        assert "dse.simulate.units" in closure, module
        assert not closure & {"dse.simulate.executor", "dse.simulate.checkpoints", "dse.simulate.cluster"}, module


def test_the_scheduler_is_in_no_key(tmp_path, in_process):
    first = dse.run(MICRO, trials=30_000, scheduler="inline", workers=1, cache_dir=tmp_path)
    again = dse.run(MICRO, trials=30_000, scheduler="local", workers=2, cache_dir=tmp_path)
    assert again.provenance["memo"] and first.run_key == again.run_key


def test_a_bad_scheduler_is_one_line(capsys, tmp_path):
    with pytest.raises(UsageError, match=r"^scheduler: must be auto, inline, local or an address"):
        dse.run(MICRO, scheduler="cluster")
    with pytest.raises(UsageError, match=r"^scheduler: "):
        dse.run(MICRO, scheduler=2)
    (tmp_path / "s.toml").write_text('family = "template"\n')
    for command in (["run", str(tmp_path / "s.toml")], ["reproduce", "savas"]):
        with pytest.raises(SystemExit) as exit_:
            main([*command, "--scheduler", "nowhere", "--out", str(tmp_path / "o")])
        err = capsys.readouterr().err.strip().splitlines()
        assert exit_.value.code == 2 and len(err) == 1 and "--scheduler" in err[0], err


@pytest.mark.parametrize("command", ["run", "reproduce"])
def test_the_flag_is_documented(capsys, command):
    with pytest.raises(SystemExit):
        main([command, "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "--scheduler" in text and "tcp://HOST:8786" in text and "same bits" in text


def _stage_bytes(family: str, trials: int) -> dict[str, bytes]:
    """Every stage array of a quick run of the family's example scenario (computed by the executor in use)."""
    from dse import registry
    from dse.contract.context import StageContext
    from dse.contract.options import RunOptions
    from dse.engine.cache import MemoryCache
    from dse.scenario.fields import load_toml

    repro = registry.from_dict(load_toml(registry.families()[family].example_file()))
    cache = MemoryCache()
    repro.compute(RunOptions(quick=True, trials=trials, workers=1), StageContext(cache))
    return {f"{key}/{name}": np.ascontiguousarray(a).tobytes() + str(a.dtype).encode() + str(a.shape).encode()
            for key, arrays in cache._entries.items() for name, a in arrays.items()}


@pytest.mark.parametrize("family, trials", [pytest.param("random-comm-filter", 1500, marks=large),
                                            pytest.param("coestimation", 1200, marks=large),
                                            ("gossip-kalman", 1500), ("template", 2500)])
def test_every_portable_family_gives_the_same_bits_on_a_cluster(family, trials, two_workers):
    """The families whose Monte Carlo is portable (their chunk functions keep nothing between chunks): every
    stage array is the same on the cluster as in process (noisy-consensus-filter: the tests above)."""
    with executor.using(executor.UnitExecutor()):
        expected = _stage_bytes(family, trials)
    with executor.using(two_workers, close=False):
        assert _stage_bytes(family, trials) == expected


def test_stages_in_threads_give_their_results_in_order_and_fail_at_once():
    """`run_threads` (a family's stages on a cluster, a few at a time): results in the order given, the heaviest
    started first; an error is raised as soon as it happens, not after a job still waiting has ended."""
    import threading
    import time

    from dse.simulate.units import run_threads

    started = []

    def job(i):
        def go():
            started.append(i)
            time.sleep(0.01)
            return i * i
        return go

    assert run_threads([(w, job(i)) for i, w in enumerate([1.0, 5.0, 3.0, 2.0])], 1) == [0, 1, 4, 9]
    assert started == [1, 2, 3, 0]
    release = threading.Event()

    def waits():
        release.wait(30)
        return "late"

    def fails():
        raise RuntimeError("stage failed")

    t0 = time.perf_counter()
    with pytest.raises(RuntimeError, match="stage failed"):
        run_threads([(2.0, waits), (1.0, fails)], 2)
    assert time.perf_counter() - t0 < 10
    release.set()


def test_the_units_a_stage_stores_are_its_own_in_each_thread(tmp_path):
    """The stored units' scope is per thread: two stages computing at once keep their units in their own directories."""
    import threading

    seen = {}

    def stage(name):
        with checkpoints.stage_scope(tmp_path / name):
            barrier.wait(10)
            seen[name] = checkpoints.for_call(np.random.SeedSequence(1), 10).directory.parent.name

    barrier = threading.Barrier(2)
    threads = [threading.Thread(target=stage, args=(n,)) for n in ("a", "b")]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert seen == {"a": "a", "b": "b"}
