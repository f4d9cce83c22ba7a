"""The options of one run (what a user sets on the command line beside the scenario file)."""
from __future__ import annotations

import os
from dataclasses import dataclass


def machine_memory_mib() -> float:
    """Physical memory of this machine, in MiB."""
    return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / 2**20


#: Default memory budget of a run: this fraction of the machine's physical memory.
DEFAULT_MEMORY_FRACTION = 0.5
#: the share of a process the pipeline leaves to the interpreter and libraries when it sizes chunks
INTERPRETER_MIB = 200.0


@dataclass(frozen=True)
class RunOptions:
    """User-level knobs of a run. `trials=None` keeps the scenario's own count;
    `max_memory_mib=None` is DEFAULT_MEMORY_FRACTION of the machine's memory. Only `seed`,
    `trials` and `quick` can change a result; `workers` and the memory budget never do."""

    seed: int = 0
    trials: int | None = None
    quick: bool = False
    workers: int = 1
    max_memory_mib: float | None = None

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
