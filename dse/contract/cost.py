"""The estimated cost of a run, one type for every family, and the refusal of a run that cannot fit.

A family's cost model counts each stage's work from the scenario's sizes and multiplies by
constants measured on the development machine; `Cost` is what it returns. The driver, not the
family, refuses a run whose part that cannot be streamed (`kept_mib`) plus the smallest Monte
Carlo chunk (`unit_mib`) does not fit the memory budget, naming the scenario key that sizes it.
"""
from __future__ import annotations

from dataclasses import dataclass, field

from dse.contract.options import INTERPRETER_MIB, RunOptions
from dse.errors import ScenarioError

MIB = 2.0**20


@dataclass(frozen=True)
class Cost:
    """Estimated wall time (s) and peak memory (MiB) of a run.

    `kept_mib`: what the run keeps whatever the chunking (statistics at the recorded steps, exact
    series, tables); `chunk_mib`: one Monte Carlo chunk in one worker; `unit_mib`: the smallest
    chunk (one RNG unit of trials). `sized_by` is the scenario key that sizes `kept_mib` (named
    when the run is refused) and `kept_what` says what is kept, `unit_what` what the unit is;
    `stages` breaks the time down (seconds per stage)."""

    seconds: float
    peak_mib: float
    detail: str
    kept_mib: float = 0.0
    chunk_mib: float = 0.0
    unit_mib: float = 0.0
    sized_by: str = ""
    kept_what: str = "per-step statistics and tables"
    unit_what: str = "1,000 trials"
    stages: dict[str, float] = field(default_factory=dict)

    def as_dict(self) -> dict[str, object]:
        return {"seconds": self.seconds, "peak_memory_mib": self.peak_mib, "detail": self.detail}

    def line(self) -> str:
        return f"about {self.seconds:.3g} s and {self.peak_mib:.0f} MiB peak memory ({self.detail})"


def human_seconds(s: float) -> str:
    """A duration as people read it: seconds, or minutes, hours, days beyond two of them."""
    for unit, size in (("days", 86400.0), ("hours", 3600.0), ("minutes", 60.0)):
        if s >= 2 * size:
            return f"{s / size:.3g} {unit}"
    return f"{s:.3g} s"


def refuse_if_too_large(cost: Cost, opts: RunOptions) -> None:
    """Refuse, before anything runs, a run whose kept part and one unit of trials do not fit the
    memory budget left beside the interpreter (INTERPRETER_MIB per process, as in
    `RunOptions.chunk_budget_bytes`)."""
    room = opts.memory_budget_mib - INTERPRETER_MIB
    if cost.kept_mib + cost.unit_mib > room:
        raise ScenarioError(cost.sized_by or "scenario",
                            f"the run keeps about {cost.kept_mib:,.0f} MiB of {cost.kept_what} and needs "
                            f"{cost.unit_mib:,.0f} MiB per {cost.unit_what}, more than the {room:,.0f} MiB the memory "
                            f"budget of {opts.memory_budget_mib:,.0f} MiB leaves beside the interpreter; make the "
                            f"scenario smaller (for example {cost.sized_by or 'its sizes'}), or raise --max-memory")
