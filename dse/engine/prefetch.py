"""Computing the stages of a multi-paper `dse reproduce` ahead, in one forked process of low priority.

The papers of `dse reproduce` run one after the other, and much of a paper is serial: the claims, the tables,
the figures and the report, the setup of each stage phase, the tail of a phase when one long stage is left. A
core is idle for all of that. The prefetcher fills it: a forked process, at the lowest CPU priority (it runs when
a core would idle, and hardly slows the run when none does), that computes the stages of the last papers (the
last one first) into their stage caches, in process, while the run works through the first ones. When the run
reaches a paper the prefetcher has done, its stages come from the cache. When it reaches the paper the
prefetcher is computing, the prefetcher is stopped (the run does not wait for a process of low priority): the
stages it finished are in the cache, and the finished Monte Carlo units of the stage it was in are stored beside
it (`dse.simulate.checkpoints`), which the run resumes from, as after an interrupted run. The stages the
prefetcher computes are the very entries the run would compute (same keys; a stage's result does not depend on
the process that computes it), so every number the run writes is the same.

The prefetcher writes nothing but stage cache entries, and only for papers the run has not reached. A paper it
cannot compute (a refusal, a failure) stops it: the run then computes that paper itself and reports what goes
wrong there, as it would have. It is stopped when the run ends, before the run undoes anything on a refusal.
"""
from __future__ import annotations

import contextlib
import dataclasses
import gc
import os
import signal
import sys
from pathlib import Path
from typing import Callable, Iterator, Sequence

STOP_SIGNALS = {signal.SIGINT, signal.SIGTERM}
#: how long the run waits for the lock at a time before it checks that the prefetcher is alive (s)
POLL_S = 0.5
#: how long a stopped prefetcher has to unwind (remove the temporary file of an entry it was writing) (s)
STOP_S = 5.0


def _unwind(signum, frame):
    raise SystemExit(1)


def _die_with(parent: int) -> None:
    """Have this process stopped (SIGTERM) when the run's process dies, even by SIGKILL (Linux): an orphan would
    keep writing the stage cache under a later run's feet, holding the inherited lock on OUT."""
    try:
        import ctypes

        ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGTERM)      # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass
    if os.getppid() != parent:      # the run died before that was set
        raise SystemExit(1)


class Prefetcher:
    """The run's side of the prefetcher: `reach(i)` before the run computes paper i."""

    def __init__(self, n: int, compute: Callable[[int], None]):
        import multiprocessing

        mp = multiprocessing.get_context("fork")
        self.n, self.parent, self.stopped = n, os.getpid(), False
        self.lock = mp.Lock()
        self.reached = mp.Value("i", 0, lock=False)     # the run has reached every paper up to this one
        self.current = mp.Value("i", -1, lock=False)    # the paper the prefetcher is computing (-1: none)
        sys.stdout.flush()
        sys.stderr.flush()
        # forked with SIGINT and SIGTERM blocked: the process sets its own handlers before it can receive them
        previous = signal.pthread_sigmask(signal.SIG_BLOCK, STOP_SIGNALS)
        try:
            self.proc = mp.Process(target=self._serve, args=(compute,))
            self.proc.start()
        finally:
            signal.pthread_sigmask(signal.SIG_SETMASK, previous)

    def _serve(self, compute: Callable[[int], None]) -> None:
        """In the forked process: the papers n-1, n-2, ... until one the run has reached; then exit at once."""
        signal.signal(signal.SIGINT, signal.SIG_IGN)    # Ctrl-C is the run's: it stops this process
        signal.signal(signal.SIGTERM, _unwind)          # `stop`: unwind (temporary files removed), then exit
        signal.pthread_sigmask(signal.SIG_UNBLOCK, STOP_SIGNALS)
        devnull = os.open(os.devnull, os.O_WRONLY)      # nothing of this process reaches the terminal
        os.dup2(devnull, 1)
        os.dup2(devnull, 2)
        status = 0
        try:
            _die_with(self.parent)
            os.nice(19)
            gc.freeze()             # its collector passes over its own objects, not the run's (see units._start_worker)
            for i in range(self.n - 1, 0, -1):
                with self.lock:
                    if i <= self.reached.value:
                        break
                    self.current.value = i
                compute(i)
                with self.lock:
                    self.current.value = -1
        except BaseException:       # stopped, or a paper it cannot compute: the run computes it and reports
            status = 1
        finally:
            os._exit(status)        # no atexit handler, no buffer of the run's flushed twice

    def reach(self, i: int) -> None:
        """The run is about to compute paper i: the prefetcher will not start it (or any before it); if it is
        computing it now, it is stopped (the run resumes from what it stored)."""
        if self.stopped:
            return
        while not self.lock.acquire(timeout=POLL_S):
            if not self.proc.is_alive():        # it died holding the lock (killed from outside): it is done
                self.stop()
                return
        try:
            self.reached.value = max(self.reached.value, i)
            busy = self.current.value == i
        finally:
            self.lock.release()
        if busy:
            self.stop()

    def stop(self) -> None:
        self.stopped = True
        if self.proc.is_alive():
            self.proc.terminate()
            self.proc.join(STOP_S)
        if self.proc.is_alive():
            self.proc.kill()
        self.proc.join()


@contextlib.contextmanager
def prefetching(n: int, compute: Callable[[int], None], enabled: bool) -> Iterator[Callable[[int], None]]:
    """`reach(i)`, to call before the run computes paper i of n; with `enabled` and n > 1, papers are computed
    ahead by `compute(i)` (their stages only) in a forked process, which is stopped when the block ends."""
    pre = None
    if enabled and n > 1:
        try:
            pre = Prefetcher(n, compute)
        except OSError:         # no shared semaphores or no process to spare here: the run computes every paper
            pre = None
    if pre is None:
        yield lambda i: None
        return
    try:
        yield pre.reach
    finally:
        pre.stop()


def paper_stages(repro, opts, cache_dir: Path) -> None:
    """The stages of one paper's run computed into its stage cache, in this process, unless the run would not
    compute them (its memo is stored) or would refuse it (`dse.api.execute` makes the same checks first)."""
    from dse.api import refuse_beyond_limits, run_key
    from dse.contract.context import StageContext
    from dse.contract.cost import refuse_options
    from dse.engine.cache import StageCache
    from dse.engine.memo import load_memo
    from dse.simulate.executor import UnitExecutor, using

    refuse_options(repro, opts)
    if load_memo(cache_dir, run_key(repro, opts, None)) is not None:
        return
    refuse_beyond_limits(repro, opts)
    # a process more than the run's workers share the run's memory: this one's chunks get a (workers+1)-th of it
    # (chunk sizes never change a result)
    mine = dataclasses.replace(opts, max_memory_mib=opts.memory_budget_mib * opts.workers / (opts.workers + 1))
    with using(UnitExecutor()):         # every stage here, one after the other: the run has the other cores
        repro.compute(mine, StageContext(StageCache(cache_dir)))


def worth_prefetching(papers: Sequence[str], opts, fresh: bool) -> bool:
    """Whether to compute papers ahead: several papers, each once (a paper's stage cache is one directory, not to be
    written by two processes at once), two processes or more, stages in forked processes of this machine
    (`--scheduler auto`: a cluster's units do not use this machine's cores), and no `--fresh` (whose run recomputes
    every stage it has not itself written). DSE_PREFETCH=0 in the environment turns it off (to measure what it
    saves)."""
    if os.environ.get("DSE_PREFETCH", "1") in ("0", "", "false", "no"):
        return False
    return (len(papers) > 1 and len(set(papers)) == len(papers) and opts.workers > 1 and opts.scheduler == "auto"
            and not fresh)
