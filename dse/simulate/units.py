"""Monte Carlo driver: trials in fixed-size blocks, each block with its own random stream.

Blocks are the unit of determinism: block b of a stream always sees the same random
numbers, and partial results are combined in block order, so the result is bit-identical
whatever the memory chunking or the number of workers. Only one block's arrays are alive
at a time in a worker, which bounds memory.
"""
from __future__ import annotations

import contextlib
import resource
import signal
from typing import Callable, Iterable, Iterator, Sequence, TypeVar

import numpy as np

from dse.engine.progress import progress
from dse.simulate.seeding import block_seeds

DEFAULT_BLOCK = 50_000
BLOCK_MEMORY_BYTES = 192 * 2**20

T = TypeVar("T")
R = TypeVar("R")


def trial_blocks(n_trials: int, block: int = DEFAULT_BLOCK) -> list[tuple[int, int]]:
    """(start, size) of each block covering n_trials trials."""
    if n_trials <= 0:
        raise ValueError(f"n_trials must be positive, got {n_trials}")
    return [(s, min(block, n_trials - s)) for s in range(0, n_trials, block)]


def block_size(bytes_per_trial: int, *, budget: int = BLOCK_MEMORY_BYTES, largest: int = DEFAULT_BLOCK) -> int:
    """Trials per block so that one block's arrays stay within `budget` bytes.

    A multiple of 1,000 between 1,000 and `largest`, derived only from the scenario's array
    shapes: the same scenario always gets the same blocks, hence the same random numbers.
    """
    fit = budget // max(int(bytes_per_trial), 1)
    return int(min(largest, max(1_000, fit // 1_000 * 1_000)))


def run_blocks(simulate_block: Callable[[int, np.random.Generator], T],
               combine: Callable[[Sequence[T]], R],
               n_trials: int, seq: np.random.SeedSequence, block: int = DEFAULT_BLOCK) -> R:
    """Run `simulate_block(size, rng)` for every block and `combine` the results in order."""
    blocks = trial_blocks(n_trials, block)
    seeds = block_seeds(seq, len(blocks))
    return combine([simulate_block(size, block_generator(s)) for (_, size), s in zip(blocks, seeds)])


#: Trials per independent random stream. Fixed: a trial's random numbers depend only on the seed
#: and its index, never on how many trials are simulated together (the memory chunk).
RNG_UNIT = 1_000


class UnitStreams:
    """The random streams of consecutive units of trials, seen as one batch.

    Every draw is made unit by unit (each unit from its own generator, in the same order)
    and stacked on the leading trial axis, so trial i gets the same numbers whatever chunk
    it is simulated in. Reductions over trials must be made per unit (`split`) and folded in
    unit order for results that do not depend on the chunking either.
    """

    def __init__(self, seeds: Sequence[np.random.SeedSequence], sizes: Sequence[int], first_unit: int = 0):
        self.generators = [block_generator(s) for s in seeds]
        self.sizes = list(sizes)
        #: the index of this batch's first unit in its stream (its first trial is first_unit * RNG_UNIT)
        self.first_unit = first_unit

    @property
    def n(self) -> int:
        return sum(self.sizes)

    def _stack(self, draw: Callable[[np.random.Generator, int], np.ndarray]) -> np.ndarray:
        parts = [draw(g, m) for g, m in zip(self.generators, self.sizes)]
        return parts[0] if len(parts) == 1 else np.concatenate(parts, axis=0)

    def standard_normal(self, tail: tuple[int, ...] = ()) -> np.ndarray:
        return self._stack(lambda g, m: g.standard_normal((m, *tail)))

    def random(self, tail: tuple[int, ...] = ()) -> np.ndarray:
        return self._stack(lambda g, m: g.random((m, *tail)))

    def exponential(self, tail: tuple[int, ...] = ()) -> np.ndarray:
        return self._stack(lambda g, m: g.standard_exponential((m, *tail)))

    def integers(self, low: int, high: int, tail: tuple[int, ...] = ()) -> np.ndarray:
        return self._stack(lambda g, m: g.integers(low, high, size=(m, *tail)))

    def split(self, array: np.ndarray) -> list[np.ndarray]:
        """The per-unit slices of an array whose leading axis is this batch's trials."""
        edges = np.cumsum([0, *self.sizes])
        return [array[a:b] for a, b in zip(edges[:-1], edges[1:])]


def kept_rows(streams: UnitStreams, keep: int) -> int:
    """How many of a chunk's trials are among the first `keep` trials of its stream (the trials a stage keeps
    whole: sample paths), counted from the chunk's first trial."""
    return max(0, min(keep - streams.first_unit * RNG_UNIT, streams.n))


def rows_by_unit(streams: UnitStreams, **arrays) -> list[dict]:
    """The rows of `arrays` (leading axis: the chunk's first trials, as many of them as each keeps: `kept_rows`)
    split by the unit they belong to: one dict per unit of the chunk, without the arrays none of whose rows
    is the unit's. A portable chunk function returns them in its partials, and the stage stacks them
    (`stack_rows`) in unit order."""
    edges = np.cumsum([0, *streams.sizes])
    return [{k: a[lo:min(hi, len(a))] for k, a in arrays.items() if lo < len(a)}
            for lo, hi in zip(edges[:-1], edges[1:])]


def stack_rows(parts: Sequence[dict], name: str, empty: np.ndarray) -> np.ndarray:
    """The kept rows `name` of every unit, in unit order (`empty`, the array of no row, when none is kept)."""
    rows = [p[name] for p in parts if name in p]
    return np.concatenate(rows) if rows else empty


class LocalProgress:
    """A progress bar (`dse.engine.progress.counter`) a portable chunk function may advance: the bar in the
    process that made it; a copy sent elsewhere (to a Dask worker) advances nothing."""

    def __init__(self, bar=None):
        self.bar = bar

    def update(self, n: int) -> None:
        if self.bar is not None:
            self.bar.update(n)

    def __reduce__(self):
        return (LocalProgress, ())


#: how portable chunks are run: `dse.simulate.executor.run_portable`, registered when that module is imported (by
#: the driver and the stage context), so that the machinery that runs a stage stays out of its code closure and
#: its cache key (`dse.contract.stages.code_closure`); without it they run here like any other
_PORTABLE_RUNNER: list[Callable] = []


def units_per_chunk(bytes_per_trial: float, budget_bytes: float) -> int:
    """How many RNG units one chunk may hold within `budget_bytes` (at least one)."""
    return max(1, int(budget_bytes // max(bytes_per_trial * RNG_UNIT, 1.0)))


def run_units(simulate_chunk: Callable[[UnitStreams], Sequence[T]], fold: Callable[[R | None, T], R],
              n_trials: int, seq: np.random.SeedSequence, *, bytes_per_trial: float,
              budget_bytes: float = BLOCK_MEMORY_BYTES, desc: str = "", portable: bool = False) -> R:
    """Simulate `n_trials` trials in RNG units of RNG_UNIT trials, as many units per chunk as
    `budget_bytes` allows; `simulate_chunk` returns one partial result per unit, and `fold`
    accumulates them in unit order (streaming: memory does not grow with the trial count).
    The result is bit-identical whatever the budget.

    `portable=True` declares that `simulate_chunk` is a function of its units alone (it keeps no state
    between chunks and changes nothing outside; `UnitStreams.first_unit` says where the chunk starts): its
    chunks then go to the run's unit executor (`dse.simulate.executor`: this process, or a Dask cluster),
    and the finished units are stored while the stage runs, so that an interrupted stage resumes from them
    (`dse.simulate.checkpoints`). Otherwise the chunks run here, one after the other."""
    n_units = -(-n_trials // RNG_UNIT)
    per_chunk = units_per_chunk(bytes_per_trial, budget_bytes)
    if portable and _PORTABLE_RUNNER:
        return _PORTABLE_RUNNER[0](simulate_chunk, fold, n_trials, seq, per_chunk, desc)
    sizes = [min(RNG_UNIT, n_trials - u * RNG_UNIT) for u in range(n_units)]
    seeds = block_seeds(seq, n_units)
    acc = None
    for start in progress(range(0, n_units, per_chunk), desc=desc) if desc else range(0, n_units, per_chunk):
        stop = min(start + per_chunk, n_units)
        for part in simulate_chunk(UnitStreams(seeds[start:stop], sizes[start:stop], first_unit=start)):
            acc = fold(acc, part)
    return acc


def block_generator(seed: np.random.SeedSequence) -> np.random.Generator:
    """The generator of one block: SFC64, a small fast chaotic generator that passes the
    standard statistical batteries; measured 20% faster than PCG64 for normal draws here,
    and normal draws are the floor of every Monte Carlo in this project."""
    return np.random.Generator(np.random.SFC64(seed))


_STOP_SIGNALS = {signal.SIGINT, signal.SIGTERM}


def _ignore_sigint() -> None:
    """Workers leave Ctrl-C to the parent, which stops them (no traceback per worker), and die
    at once on SIGTERM (the parent's handler, inherited through fork, would unwind them). They are
    forked with both signals blocked (`parallel_map`), so that a signal that arrives before these
    handlers are set waits for them instead of reaching the parent's handlers in the child."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, _STOP_SIGNALS)


def _start_worker() -> None:
    """A forked worker's start: its signals (`_ignore_sigint`), and every object it inherited exempted from its
    garbage collector's passes (`gc.freeze`). A worker allocates many objects (matplotlib's artists, a
    simulator's events), and each full pass of its collector went over the parent's millions too (pandas',
    scipy's, matplotlib's, the run's tables): a second of the five quick papers' figure workers. The
    inherited objects are the parent's to free; what the worker allocates is collected as before."""
    import gc

    _ignore_sigint()
    gc.freeze()


def parallel_map(fn: Callable[[T], R], items: Iterable[T], *, workers: int = 1, desc: str = "") -> list[R]:
    """Map `fn` over `items` in `workers` processes (fork), with a progress bar; order kept.

    On Ctrl-C or a failed task the workers are terminated at once; tasks already finished
    have stored their results in the stage cache, so a re-run resumes from there.
    """
    with forked_map(fn, items, workers=workers, desc=desc) as results:
        return list(results)


@contextlib.contextmanager
def forked_map(fn: Callable[[T], R], items: Iterable[T], *, workers: int = 1, desc: str = "") -> Iterator[Iterator[R]]:
    """`parallel_map` in the background: the workers start on every item at once, the body of the
    `with` block runs meanwhile in this process, and the iterator it is given yields the results in
    order (with a progress bar); the body consumes it. Leaving the block waits for the workers, or
    terminates them at once when the body raised (Ctrl-C included). With one worker or one item,
    the items are mapped here, as the iterator is consumed."""
    items = list(items)
    if workers <= 1 or len(items) <= 1:
        yield (fn(x) for x in progress(items, desc=desc))
        return
    import multiprocessing

    # fork with SIGINT and SIGTERM blocked: a worker sets its own handlers before it can receive them; the
    # parent takes a signal that came meanwhile once the pool exists (and then stops the pool like any other)
    previous, pool = signal.pthread_sigmask(signal.SIG_BLOCK, _STOP_SIGNALS), None
    try:
        pool = multiprocessing.get_context("fork").Pool(processes=min(workers, len(items)), initializer=_start_worker)
        signal.pthread_sigmask(signal.SIG_SETMASK, previous)
        results = pool.imap(fn, items)
        _do_idle_work()
        yield iter(progress(results, total=len(items), desc=desc))
    except BaseException:
        signal.pthread_sigmask(signal.SIG_SETMASK, previous)
        if pool is not None:
            pool.terminate()
            pool.join()
        raise
    pool.close()
    pool.join()


#: work for this process while its forked workers run (`forked_map`), each done once, by the first such wait: the
#: imports of what comes after the Monte Carlo (the driver's pandas and matplotlib, `dse.engine.driver.run`; a
#: family's claims' libraries), on a core the Monte Carlo's workers may leave idle, instead of after the run
_IDLE_WORK: list[Callable[[], object]] = []


@contextlib.contextmanager
def idle_work(fn: Callable[[], object]) -> Iterator[None]:
    """Have `fn` done (once) while forked workers run, if any run within the block."""
    _IDLE_WORK.append(fn)
    try:
        yield
    finally:
        if fn in _IDLE_WORK:
            _IDLE_WORK.remove(fn)


def _do_idle_work() -> None:
    while _IDLE_WORK:
        fn = _IDLE_WORK.pop(0)
        try:
            fn()
        except Exception:   # only a head start: what needs it does it again, and fails there if it must
            pass


#: the jobs of the current `run_jobs`, run by index in forked workers (closures are inherited, not pickled)
_JOBS: list = []


def _run_job(index: int):
    return _JOBS[index]()


def run_jobs(jobs: Sequence[tuple[float, Callable[[], R]]], workers: int = 1, *, desc: str = "") -> list[R]:
    """Run (weight, callable) jobs in `workers` forked processes, the heaviest first (the light ones then fill in
    around them), and return their results in the order given. The callables need not be picklable: workers
    inherit them through fork and receive an index; their results come back pickled."""
    global _JOBS
    order = sorted(range(len(jobs)), key=lambda i: -jobs[i][0])
    if workers <= 1 or len(jobs) <= 1:
        outs = [jobs[i][1]() for i in order]
    else:
        previous, _JOBS = _JOBS, [jobs[i][1] for i in order]
        try:
            outs = parallel_map(_run_job, range(len(order)), workers=workers, desc=desc)
        finally:
            _JOBS = previous
    results: list = [None] * len(jobs)
    for i, o in zip(order, outs):
        results[i] = o
    return results


def run_threads(jobs: Sequence[tuple[float, Callable[[], R]]], threads: int) -> list[R]:
    """Run (weight, callable) jobs in up to `threads` threads of this process, the heaviest first, and return
    their results in the order given: for jobs that mostly wait (on a Dask cluster's tasks). The first error,
    or an interrupt, cancels the jobs not yet started and is raised once the running ones are left to end
    (they end when the run's executor closes its client)."""
    from concurrent.futures import FIRST_EXCEPTION, ThreadPoolExecutor, wait

    order = sorted(range(len(jobs)), key=lambda i: -jobs[i][0])
    pool = ThreadPoolExecutor(max_workers=max(1, min(threads, len(jobs))), thread_name_prefix="dse-stage")
    futures = {}
    try:
        for i in order:
            futures[i] = pool.submit(jobs[i][1])
        done, _ = wait(futures.values(), return_when=FIRST_EXCEPTION)
        failed = [f for f in done if f.exception() is not None]
        if failed:
            raise failed[0].exception()
        results = [futures[i].result() for i in range(len(jobs))]
    except BaseException:
        pool.shutdown(wait=False, cancel_futures=True)
        raise
    pool.shutdown(wait=True)
    return results


def peak_memory_mib() -> float:
    """Peak resident memory of this process and its finished children, in MiB."""
    own = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    children = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    return max(own, children) / 1024.0
