"""The estimated cost of a run, one type for every family, and the refusal of a run that cannot fit.

A family's cost model counts each stage's work from the scenario's sizes and multiplies by
constants measured on the development machine; `Cost` is what it returns. The driver, not the
family, refuses a run whose part that cannot be streamed (`kept_mib`) plus the smallest Monte
Carlo chunk (`unit_mib`) does not fit the memory budget, naming the scenario key that sizes it,
and a run estimated to take longer than its time limit (`RunOptions.time_limit_s`, `--max-time`).
Before either, `refuse_options` checks the options themselves: `--trials` within the bounds the
family's trials key declares, `--workers` within the machine's CPUs, `--max-memory` within its memory.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

from dse.contract.options import (DEFAULT_WORKERS, INTERPRETER_MIB, RunOptions, declared_bounds, machine_cpus,
                                  machine_memory_mib)
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
    #: seconds of the design stage alone (what `dse check` computes), None when the family does not say
    design_s: float | None = None
    #: the scenario key that sizes the design (named when `dse check` refuses to compute it)
    design_sized_by: str = ""
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


def refuse_options(repro, opts: RunOptions) -> None:
    """Refuse options outside what the scenario and the machine allow, in one line naming the option:
    `trials` outside the bounds the family's trials key declares (`Family.trials_key`), `workers`
    above the machine's CPUs (DEFAULT_WORKERS is always accepted), `max_memory_mib` above its memory,
    `max_time_s` not positive."""
    key = getattr(repro.family, "trials_key", "")
    if opts.trials is not None and key:
        lo, hi = declared_bounds(repro.family.scenario_model, key)
        if (lo is not None and opts.trials < lo) or (hi is not None and opts.trials > hi):
            raise ScenarioError("--trials", f"must be within [{lo:,}, {hi:,}] (the bounds of `{key}` in the "
                                            f"{repro.family.id} family), got {opts.trials:,}")
    cpus = machine_cpus()
    if opts.workers > max(cpus, DEFAULT_WORKERS):
        raise ScenarioError("--workers", f"at most {max(cpus, DEFAULT_WORKERS)} on this machine ({cpus} CPUs): more "
                                         f"worker processes than CPUs only compete for them, got {opts.workers}")
    memory = machine_memory_mib()
    if opts.max_memory_mib is not None and opts.max_memory_mib > memory:
        raise ScenarioError("--max-memory", f"at most this machine's memory, {memory:,.0f} MiB, got "
                                            f"{opts.max_memory_mib:,.0f} MiB")
    if opts.max_time_s is not None and not opts.max_time_s > 0:
        raise ScenarioError("--max-time", f"must be a positive duration, got {opts.max_time_s}")


def refuse_if_too_long(cost: Cost, opts: RunOptions, sized_by: str = "scenario") -> None:
    """Refuse, before anything runs, a run estimated to take longer than `opts.time_limit_s` (a day
    by default: `--max-time` raises or lowers it), naming `sized_by` (the option or the key that sets
    the trials)."""
    limit = opts.time_limit_s
    if cost.seconds > limit:
        raise ScenarioError(sized_by, f"the run is estimated at about {human_seconds(cost.seconds)}, more than the "
                                      f"{human_seconds(limit)} --max-time allows (`dse check` shows the estimate's "
                                      f"parts); make it smaller, or allow it with --max-time {allowing(cost.seconds)} "
                                      f"(Python API: max_time_s)")


def allowing(seconds: float) -> str:
    """A --max-time value just above `seconds`, as people write it (90m, 36h, 400d)."""
    for suffix, size in (("d", 86400.0), ("h", 3600.0), ("m", 60.0)):
        if seconds >= 2 * size:
            return f"{math.ceil(seconds / size * 1.1):g}{suffix}"
    return f"{math.ceil(seconds * 1.1):g}s"


def parse_duration(text: str) -> float:
    """A duration: seconds (90, 1.5e3), or with a unit s, m, h, d (30m, 12h, 2d); `inf` for no limit.
    ValueError otherwise."""
    t = text.strip().lower()
    scale = {"s": 1.0, "m": 60.0, "h": 3600.0, "d": 86400.0}.get(t[-1:]) if t[-1:].isalpha() and t != "inf" else None
    value = float(t[:-1] if scale else t) * (scale or 1.0)
    if not value > 0 or math.isnan(value):
        raise ValueError(f"must be a positive duration such as 90, 30m, 12h, 2d or inf, got {text!r}")
    return value


#: the design work `dse check` computes without being asked for more (`--max-design-time`): a design
#: estimated longer is refused in one line (`dse run` computes it as its first stage, with progress)
CHECK_DESIGN_BUDGET_S = 30.0
#: `dse check` says what it is computing when its design takes longer than this
CHECK_NOTE_AFTER_S = 1.0


def refuse_long_design(cost: Cost, budget_s: float) -> None:
    """`dse check`: refuse, before computing it, a design estimated above `budget_s`, naming the key that
    sizes it."""
    if cost.design_s is not None and cost.design_s > budget_s:
        raise ScenarioError(cost.design_sized_by or "scenario",
                            f"its design (what dse check computes) is estimated at about {human_seconds(cost.design_s)}, "
                            f"more than check's budget of {human_seconds(budget_s)}; make the scenario smaller, "
                            f"allow it with `dse check --max-design-time {allowing(cost.design_s)}`, or run it "
                            f"(`dse run` computes the design as its first stage; the whole run: about "
                            f"{human_seconds(cost.seconds)})")


def run_refusal(cost: Cost, opts: RunOptions, sized_by: str) -> str:
    """The one line `dse run` would refuse this run with (memory or time), or "" when it would start."""
    try:
        refuse_if_too_large(cost, opts)
        refuse_if_too_long(cost, opts, sized_by)
    except ScenarioError as exc:
        return str(exc)
    return ""
