"""The options of one run (what a user sets on the command line beside the scenario file)."""
from __future__ import annotations

import os
from dataclasses import dataclass


def machine_memory_mib() -> float:
    """Physical memory of this machine, in MiB."""
    return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / 2**20


def machine_cpus() -> int:
    """CPUs this process may run on."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return max(1, os.cpu_count() or 1)


#: Default memory budget of a run: this fraction of the machine's physical memory.
DEFAULT_MEMORY_FRACTION = 0.5
#: Default limit of a run's estimated time: a run estimated longer is refused unless `max_time_s` (`--max-time`)
#: allows it. A day: beyond any of the papers' reproductions (minutes), short of the absurd (a mistyped
#: --trials 1e12 is estimated at years).
DEFAULT_MAX_TIME_S = 24 * 3600.0
#: the default number of worker processes of `dse run`, `dse reproduce` and `dse check`; also accepted on a
#: machine with fewer CPUs (more workers than CPUs is refused otherwise: they would only compete for them)
DEFAULT_WORKERS = 2
#: the share of a process the pipeline leaves to the interpreter and libraries when it sizes chunks
INTERPRETER_MIB = 200.0


@dataclass(frozen=True)
class RunOptions:
    """User-level knobs of a run. `trials=None` keeps the scenario's own count;
    `max_memory_mib=None` is DEFAULT_MEMORY_FRACTION of the machine's memory; `max_time_s=None` is
    DEFAULT_MAX_TIME_S (`math.inf`: no limit). `scheduler`: where the Monte Carlo units run (auto: stages
    in `workers` forked processes; inline: all in this process; local: a local Dask cluster of `workers`
    processes; ``tcp://HOST:PORT``: a running Dask scheduler; see `dse.simulate.executor`). Only `seed`,
    `trials` and `quick` can change a result; `workers`, `scheduler`, the memory budget and the time limit
    never do (none of them is part of a cache key)."""

    seed: int = 0
    trials: int | None = None
    quick: bool = False
    workers: int = 1
    max_memory_mib: float | None = None
    max_time_s: float | None = None
    scheduler: str = "auto"

    @property
    def time_limit_s(self) -> float:
        return self.max_time_s if self.max_time_s is not None else DEFAULT_MAX_TIME_S

    @property
    def memory_budget_mib(self) -> float:
        return self.max_memory_mib if self.max_memory_mib is not None else DEFAULT_MEMORY_FRACTION * machine_memory_mib()

    def chunk_budget_bytes(self, concurrent_arrays: int = 4) -> float:
        """Bytes one Monte Carlo chunk may use in one worker: the budget shared by the workers,
        with room for `concurrent_arrays` arrays of that size (temporaries, accumulators) and
        INTERPRETER_MIB per process for the interpreter and libraries. Never affects results
        (RNG units are fixed; see dse.simulate.units.run_units)."""
        per_worker = self.memory_budget_mib / max(self.workers, 1) - INTERPRETER_MIB
        return max(per_worker, 16.0) * 2**20 / max(concurrent_arrays, 1)


def declared_bounds(model: type, path: str) -> tuple[float | None, float | None]:
    """(lowest, highest) value the scenario key at dotted `path` of a declared scenario model accepts
    (its `ge`/`gt` and `le`/`lt` bounds; None where it declares none)."""
    import annotated_types as at

    section, info = model, None
    for part in path.split("."):
        info = section.model_fields[part]
        section = info.annotation
    lo = hi = None
    for m in info.metadata:
        if isinstance(m, at.Ge):
            lo = m.ge
        elif isinstance(m, at.Gt):
            lo = m.gt + 1 if isinstance(m.gt, int) else m.gt
        elif isinstance(m, at.Le):
            hi = m.le
        elif isinstance(m, at.Lt):
            hi = m.lt - 1 if isinstance(m.lt, int) else m.lt
    return lo, hi
