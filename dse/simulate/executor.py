"""Where a run's Monte Carlo is computed: the unit executor, chosen by the run's `scheduler` option.

A stage's trials are RNG units of 1,000 (`dse.simulate.units.run_units`); the stage hands chunks of
consecutive units to the executor of the run and folds what comes back in unit order, so the numbers are
the same bits wherever the units ran. The executors (`executor_for`):

- `auto` (`ForkedExecutor`, what dse always did): the stages of a family in `workers` forked processes
  (`StageContext.run_many`), each stage's units in its own process, one chunk after the other;
- `inline` (`UnitExecutor`): every stage and every unit in this process;
- `local` or an address ``tcp://HOST:PORT`` (`DaskExecutor`): the units of every portable stage (one whose
  chunk function keeps no state between chunks: `run_units(..., portable=True)`) as tasks of a Dask cluster
  (a local one of `workers` processes, started in the background when the run starts, or a running scheduler),
  the stages in this process, two at a time (in threads: `STAGE_THREADS`). A few tasks per worker are in
  flight at a time and their results are taken in unit order, so the client holds a bounded number of partial results whatever the
  trial count; a worker that dies has its tasks rescheduled by the Dask scheduler.

The executor never enters a cache key: it cannot change a result.
"""
from __future__ import annotations

import contextlib
import math
import pickle
import threading
import warnings
from collections import deque
from typing import Callable, Iterable, Iterator

import numpy as np

from dse.engine.progress import progress
from dse.simulate import checkpoints, units
from dse.simulate.seeding import block_seeds
from dse.simulate.units import RNG_UNIT

#: Dask tasks per worker a stage's units are split into (at least: a task never holds fewer units than one
#: in-process chunk) and at most this many units per task, so that the last tasks balance the workers and a
#: stored range of finished units is never far behind
TASKS_PER_WORKER = 16
MAX_TASK_UNITS = 1000
#: tasks in flight per worker: one running, the next ones queued so that a worker never waits for the client
IN_FLIGHT_PER_WORKER = 3
#: stages of a family computing at once on a cluster (threads of the client, each with its tasks in flight): while
#: one stage's last tasks run and it is folded and finished here, the next one's tasks keep the workers busy
STAGE_THREADS = 2


def unit_sizes(n_trials: int, first: int, stop: int) -> list[int]:
    """Trials of units first..stop-1 of a stream of `n_trials` trials (the last unit may be short)."""
    return [min(RNG_UNIT, n_trials - u * RNG_UNIT) for u in range(first, stop)]


def compute_units(simulate_chunk: Callable, seq: np.random.SeedSequence, n_trials: int, first: int, stop: int,
                  per_chunk: int) -> list:
    """The partial results of units first..stop-1, computed in chunks of `per_chunk` units (aligned on
    multiples of `per_chunk`, as one process would chunk them): one partial per unit, in unit order."""
    parts: list = []
    for start, end in task_ranges(first, stop, per_chunk):
        out = list(simulate_chunk(units.UnitStreams(block_seeds(seq, end, start), unit_sizes(n_trials, start, end),
                                              first_unit=start)))
        if len(out) != end - start:
            raise ValueError(f"the chunk of units {start}..{end - 1} returned {len(out)} partial results")
        parts.extend(out)
    return parts


class UnitExecutor:
    """Units in this process, chunk after chunk; the stages in this process too (`--scheduler inline`)."""

    name = "inline"

    def stage_workers(self, workers: int) -> int:
        """How many forked processes `StageContext.run_many` may run stages in, of the `workers` a family asks for."""
        return 1

    def stage_threads(self) -> int:
        """How many of `StageContext.run_many`'s stages may compute at once in threads of this process (stages
        whose units go elsewhere, so that one stage's last tasks and the work between two stages leave no worker
        idle)."""
        return 1

    def units_per_task(self, n_units: int, per_chunk: int) -> int:
        """Units per task handed to `map_units` (a multiple of `per_chunk`)."""
        return per_chunk

    def map_units(self, simulate_chunk: Callable, seq: np.random.SeedSequence, n_trials: int, per_chunk: int,
                  ranges: Iterable[tuple[int, int]]) -> Iterator[tuple[list, bytes | None]]:
        """The partials of every (first, stop) range of units, in the order given, each with its pickle when it
        came as one (from another process: what the stored units are written from), else None."""
        for first, stop in ranges:
            yield compute_units(simulate_chunk, seq, n_trials, first, stop, per_chunk), None

    def close(self) -> None:
        """Release what the executor started (a cluster, a connection)."""


class ForkedExecutor(UnitExecutor):
    """Units in the process of their stage; stages in `workers` forked processes (`--scheduler auto`)."""

    name = "auto"

    def stage_workers(self, workers: int) -> int:
        return workers


def _identity(x):
    return x


def _pickled_units(*args) -> bytes:
    """`compute_units` on a worker, its partials sent back as one pickle (`PackedUnits`): Dask serializes every
    small array of a result apart, which costs far more than computing a unit."""
    return pickle.dumps(PackedUnits(compute_units(*args)), protocol=pickle.HIGHEST_PROTOCOL)


class PackedUnits:
    """The partials of consecutive units as they travel from a worker: when every partial is a dict with the same
    keys, each holding a numpy array (or scalar) of one type, dtype and shape per key, one stacked array per key;
    else the list as it is. Unpickled, it is the list of partials again (each value a row of its stacked array:
    the same type, dtype, shape and bits), so the stored units and the fold see what `compute_units` returned.
    Pickling a few stacked arrays instead of thousands of small ones costs a worker a quarter, and the client a
    seventh, of the time (320 units of the micro scenario of `benchmarks.bench_scheduler`: 27 -> 8 ms, 18 -> 3 ms)."""

    def __init__(self, parts: list):
        self.parts = parts

    def __reduce__(self):
        stacked = _stack_units(self.parts)
        return (_unstack_units, stacked) if stacked is not None else (list, (self.parts,))


def _stack_units(parts: list) -> tuple[list, list, list] | None:
    """(keys, whether each is a numpy scalar, one stacked array per key) of `parts`, or None when they do not
    all share their keys and each key's type, dtype and shape."""
    if not parts or not all(type(p) is dict for p in parts):
        return None
    keys = list(parts[0])
    scalar = []
    for k in keys:
        v = parts[0][k]
        if not (type(v) is np.ndarray or isinstance(v, np.generic)):
            return None
        scalar.append(isinstance(v, np.generic))
    for p in parts:
        if list(p) != keys:
            return None
        for k in keys:
            v, v0 = p[k], parts[0][k]
            if type(v) is not type(v0) or v.dtype != v0.dtype or v.shape != v0.shape:
                return None
    return keys, scalar, [np.stack([p[k] for p in parts]) for k in keys]


def _unstack_units(keys: list, scalar: list, arrays: list) -> list[dict]:
    """The partials `_stack_units` stacked: unit i's value of a key is row i of its array (a numpy scalar where it
    was one, else an array view)."""
    n = len(arrays[0]) if arrays else 0
    return [{k: (a[i] if sc else a[i, ...]) for k, sc, a in zip(keys, scalar, arrays)} for i in range(n)]


class DaskExecutor(UnitExecutor):
    """Units on a Dask cluster (`--scheduler local` or ``tcp://HOST:PORT``); stages in this process. The
    client (and a local cluster) starts with the first portable stage, or earlier (`start_early`), and stops
    with `close`."""

    def __init__(self, scheduler: str, workers: int, log: Callable[[str], None] | None = None):
        self.name, self.workers = scheduler, workers
        self.log = log or (lambda line: None)
        self._stack: contextlib.ExitStack | None = None
        self._client = None
        self._starting = threading.Lock()      # stages in threads (`stage_threads`) start one client between them
        self._early: threading.Thread | None = None

    def client(self):
        with self._starting:
            if self._client is None:
                from dse.simulate.cluster import dask_client

                stack = contextlib.ExitStack()
                self._client = stack.enter_context(dask_client(self.name, self.workers, log=self.log))
                self._stack = stack
        return self._client

    def start_early(self) -> None:
        """Start the client (a local cluster: its worker processes, about 2 s) in a background thread, while the
        run computes its design; the first portable stage then finds it ready. A start that fails here is tried
        again, and fails in one line, when a stage asks for the client."""
        def start():
            try:
                self.client()
            except BaseException:      # noqa: BLE001 - said by the stage's own `client()` call
                pass

        self._early = threading.Thread(target=start, name="dse-dask-start", daemon=True)
        self._early.start()

    def stage_threads(self) -> int:
        return STAGE_THREADS

    def n_workers(self) -> int:
        return max(1, len(self.client().scheduler_info().get("workers", {})))

    def units_per_task(self, n_units: int, per_chunk: int) -> int:
        wanted = min(MAX_TASK_UNITS, math.ceil(n_units / (TASKS_PER_WORKER * self.n_workers())))
        return per_chunk * max(1, math.ceil(wanted / per_chunk))

    def map_units(self, simulate_chunk, seq, n_trials, per_chunk, ranges) -> Iterator[tuple[list, bytes | None]]:
        client = self.client()
        # the chunk function travels once, as the result of a task: a worker that dies with it is recomputed;
        # a large one (a scenario's design, say) is expected here, not a mistake Dask should warn about
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", message="Sending large graph")
            fn = client.submit(_identity, simulate_chunk, pure=False)
        window, pending = IN_FLIGHT_PER_WORKER * self.n_workers(), deque()
        ranges = iter(ranges)
        try:
            while True:
                while len(pending) < window and (r := next(ranges, None)) is not None:
                    pending.append(client.submit(_pickled_units, fn, seq, n_trials, *r, per_chunk, pure=False))
                if not pending:
                    return
                head = pending.popleft()
                blob = head.result()
                head.release()
                yield pickle.loads(blob), blob
        finally:
            for f in pending:
                f.cancel()
            fn.release()

    def close(self) -> None:
        if self._early is not None:
            self._early.join()
        if self._stack is not None:
            self._stack.close()
            self._stack = self._client = None


#: the executor of the run being computed (`using`); outside a run, what dse always did
_CURRENT: list[UnitExecutor] = [ForkedExecutor()]


def current() -> UnitExecutor:
    return _CURRENT[-1]


def executor_for(scheduler: str, workers: int, log: Callable[[str], None] | None = None) -> UnitExecutor:
    """The executor `scheduler` names (see the module's docstring). A scheduler's address is connected to at
    once (a wrong one fails before any stage runs); a local cluster starts at once in the background
    (`DaskExecutor.start_early`), while the run computes what comes before its first portable stage."""
    if scheduler == "auto":
        return ForkedExecutor()
    if scheduler == "inline":
        return UnitExecutor()
    dask = DaskExecutor(scheduler, workers, log)
    if scheduler != "local":
        dask.client()
    else:
        dask.start_early()
    return dask


@contextlib.contextmanager
def using(executor: UnitExecutor, *, close: bool = True) -> Iterator[UnitExecutor]:
    """Run the block's stages and units on `executor`; it is closed when the block ends (unless `close` is
    False: the caller closes it, after other blocks)."""
    _CURRENT.append(executor)
    try:
        yield executor
    finally:
        _CURRENT.pop()
        if close:
            executor.close()


def task_ranges(first: int, stop: int, per_task: int) -> list[tuple[int, int]]:
    """Ranges of at most `per_task` units covering first..stop-1, cut at multiples of `per_task`."""
    out, start = [], first
    while start < stop:
        end = min(stop, (start // per_task + 1) * per_task)
        out.append((start, end))
        start = end
    return out


def run_portable(simulate_chunk, fold, n_trials: int, seq: np.random.SeedSequence, per_chunk: int, desc: str):
    """`run_units` of a portable chunk function: the units stored by an earlier attempt of the stage are read
    back, the others computed by the run's executor, and all folded in unit order."""
    n_units = -(-n_trials // RNG_UNIT)
    runner, store = current(), checkpoints.for_call(seq, n_trials)
    per_task = runner.units_per_task(n_units, per_chunk)
    segments = _segments(n_units, store.stored() if store is not None else [], per_task)
    computed = runner.map_units(simulate_chunk, seq, n_trials, per_chunk,
                                [(a, b) for a, b, path in segments if path is None])
    acc = None
    try:
        for first, stop, path in progress(segments, desc=desc) if desc else segments:
            parts = store.load(path, stop - first) if path is not None else None
            if parts is None:
                parts, pickled = next(computed) if path is None else (
                    _compute_here(simulate_chunk, seq, n_trials, first, stop, per_chunk), None)
                if store is not None:
                    store.add(first, parts, pickled)
            for part in parts:
                acc = fold(acc, part)
    finally:
        computed.close()
        if store is not None:
            store.flush()
    return acc


def _compute_here(simulate_chunk, seq, n_trials: int, first: int, stop: int, per_chunk: int) -> list:
    """Units whose stored file turned out damaged: computed again in this process."""
    return compute_units(simulate_chunk, seq, n_trials, first, stop, per_chunk)


def _segments(n_units: int, stored: list[tuple[int, int, object]], per_task: int) -> list[tuple[int, int, object]]:
    """(first, stop, stored file or None) covering units 0..n_units-1 in order: the stored ranges, and the
    gaps between them in tasks of `per_task` units."""
    out, at = [], 0
    for a, b, path in [s for s in stored if s[1] <= n_units] + [(n_units, n_units, None)]:
        out += [(x, y, None) for x, y in task_ranges(at, a, per_task)]
        if b > a:
            out.append((a, b, path))
        at = b
    return out


def stderr_log(line: str) -> None:
    """Where the executor says what it connected to (one line on stderr: stdout is the command's result)."""
    import sys

    print(line, file=sys.stderr, flush=True)


units._PORTABLE_RUNNER[:] = [run_portable]

__all__ = ["UnitExecutor", "ForkedExecutor", "DaskExecutor", "current", "executor_for", "using", "compute_units",
           "task_ranges"]
