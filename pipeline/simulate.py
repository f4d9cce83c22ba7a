"""Monte Carlo driver: trials in fixed-size blocks, each block with its own random stream.

Blocks are the unit of determinism: block b of a stream always sees the same random
numbers, and partial results are combined in block order, so the result is bit-identical
whatever the memory chunking or the number of workers. Only one block's arrays are alive
at a time in a worker, which bounds memory.
"""
from __future__ import annotations

import resource
import signal
from typing import Callable, Iterable, Sequence, TypeVar

import numpy as np

from .progress import progress
from .seeding import block_seeds

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


def block_generator(seed: np.random.SeedSequence) -> np.random.Generator:
    """The generator of one block: SFC64, a small fast chaotic generator that passes the
    standard statistical batteries; measured 20% faster than PCG64 for normal draws here,
    and normal draws are the floor of every Monte Carlo in this project."""
    return np.random.Generator(np.random.SFC64(seed))


def _ignore_sigint() -> None:
    """Workers leave Ctrl-C to the parent, which stops them (no traceback per worker), and die
    at once on SIGTERM (the parent's handler, inherited through fork, would unwind them)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)


def parallel_map(fn: Callable[[T], R], items: Iterable[T], *, workers: int = 1, desc: str = "") -> list[R]:
    """Map `fn` over `items` in `workers` processes (fork), with a progress bar; order kept.

    On Ctrl-C or a failed task the workers are terminated at once; tasks already finished
    have stored their results in the stage cache, so a re-run resumes from there.
    """
    items = list(items)
    if workers <= 1 or len(items) <= 1:
        return [fn(x) for x in progress(items, desc=desc)]
    import multiprocessing

    pool = multiprocessing.get_context("fork").Pool(processes=min(workers, len(items)), initializer=_ignore_sigint)
    try:
        results = list(progress(pool.imap(fn, items), total=len(items), desc=desc))
    except BaseException:
        pool.terminate()
        pool.join()
        raise
    pool.close()
    pool.join()
    return results


def peak_memory_mib() -> float:
    """Peak resident memory of this process and its finished children, in MiB."""
    own = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    children = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    return max(own, children) / 1024.0
