"""What the hybrid-observer claims share: the (scenario, run) cells a claim checks, gated by the
hypotheses each cell rests on, the combination of their verdicts, and the quantities the checks
read from a run (its constants, round-off allowance, worst cases, fitted rates).

A run's claims span every (scenario, run) cell of the kind they are about: each cell's own
hypotheses (the run's q against (22) or (27), (10), constancy of N(t) on the windows (23),
strong connectivity of the graphs it uses) are checked first (`hypotheses.cell_failures`); cells
whose hypotheses do not hold are left out and named in the detail, and a claim with no cell
left is `not-checkable`, naming them. Tolerances are derived from the arithmetic
(`simulation.simulation_tolerance` and the checks' docstrings); each is stated in the detail.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from dse.verify.rules import ERRATUM, FAIL, NOT_CHECKABLE, PASS, Verdict, not_checkable

from . import design, simulation
from . import hypotheses as hy
from .hypotheses import PID, claims, rests_on
from .scenario import RunSection
from .simulation import is_theorem_run
from .stages import Part, Parts

__all__ = ["PID", "claims"]
EPS = float(np.finfo(float).eps)
#: the hypotheses every cell of a claim rests on (see `hypotheses.rests_on`)
OBS = rests_on("joint_observability")
THM = rests_on("joint_observability", "strong_connectivity", "local_observers", "q_eq22")
SYM = rests_on("joint_observability", "strong_connectivity", "local_observers")
EQ44 = rests_on("joint_observability", "strong_connectivity", "q_eq22")
IDEAL = rests_on("joint_observability", "strong_connectivity")


@dataclass
class Cells:
    """The (scenario, run) cells a claim checks, and the ones left out by their hypotheses."""

    items: list = field(default_factory=list)           # (label, Part, RunSection)
    left_out: list = field(default_factory=list)        # text per cell

    def note(self) -> str:
        return (" Left out: " + "; ".join(self.left_out) + ".") if self.left_out else ""

    def verdict(self, verdicts: list[tuple[str, Verdict]], what: str) -> Verdict:
        if not verdicts:
            reason = f"no {what}"
            return not_checkable(reason + (": every candidate's hypotheses fail." + self.note() if self.left_out else ""))
        return _combine(verdicts, detail=self.note())


def cells(res: Parts, select: Callable[[Part, RunSection], bool], needs: tuple[str, ...] = ()) -> Cells:
    """The cells `select` picks, split by whether the hypotheses in `needs` hold for them."""
    out = Cells()
    for part, r in res.parts.items():
        for run in r.scenario.runs:
            if not select(r, run):
                continue
            label = f"{part}/{run.name}"
            fails = hy.cell_failures(res, part, run, needs)
            if fails:
                out.left_out.append(f"[{label}] " + ", ".join(
                    f"{hid} {'does not hold' if h.holds is False else 'is undecided'} (value {_fmt(h.value)}, "
                    f"threshold {_fmt(h.threshold)})" for hid, h in fails))
            else:
                out.items.append((label, r, run))
    return out


def _fmt(v) -> str:
    if isinstance(v, (int, np.integer)):
        return f"{int(v):,}"
    if isinstance(v, (float, np.floating)):
        return f"{float(v):.6g}"
    return str(v)


def _combine(verdicts: list[tuple[str, Verdict]], detail: str = "") -> Verdict:
    """Worst of several verdicts (fail > erratum > pass > not-checkable), details joined."""
    order = {FAIL: 0, ERRATUM: 1, PASS: 2, NOT_CHECKABLE: 3}
    label, worst = min(verdicts, key=lambda lv: (order[lv[1].status], lv[1].margin if lv[1].margin is not None else 0))
    if len(verdicts) == 1:
        text = f"[{label}] {worst.detail}"
    else:
        text = f"worst case {label}. " + "; ".join(f"[{lab}] {v.status}: {v.detail}" for lab, v in verdicts)
    return Verdict(worst.status, measured=worst.measured, reference=worst.reference, tolerance=worst.tolerance,
                   margin=worst.margin, trials=worst.trials, printed=worst.printed, corrected=worst.corrected,
                   detail=f"{text}{detail}".strip())


def timing_needs(run: RunSection) -> tuple[str, ...]:
    return ("eq10", "windows") if run.timing in ("async", "offset") else ()


def cells_with(res: Parts, select, base: tuple[str, ...]) -> Cells:
    """Like `cells`, with (10) and the windows added for asynchronous / offset runs."""
    out = Cells()
    for timing_specific in (False, True):
        part = cells(res, lambda r, run: select(r, run) and bool(timing_needs(run)) == timing_specific,
                     base + (("eq10", "windows") if timing_specific else ()))
        out.items += part.items
        out.left_out += part.left_out
    return out


def in_theorem1(r: Part, run: RunSection) -> bool:
    """A synchronous theorem run whose q satisfies (22) (for figures)."""
    return run.timing == "sync" and is_theorem_run(r.spec(run.name)) and hy.q_eq22(r, run.q).holds is True


def constants(r: Part, run: RunSection) -> dict[str, float]:
    """b, c, d, b', d', g of the proofs (see `design.constants`)."""
    return design.constants(r.design, r.scenario, run)


def simulation_tolerance(r: Part, run: RunSection) -> tuple[float, str]:
    """The round-off allowance of quantities built from a simulated run (see `simulation.simulation_tolerance`)."""
    return simulation.simulation_tolerance(r.scenario, r.design, run, r.runs[run.name])


def worst_verdict(a: dict, name: str, *, tolerance: float = 0.0, detail: str = "") -> Verdict:
    """The verdict of an inequality lo <= up over every (event, trial) case of a run, from the worst
    case the run kept (`monitor.Worst`): pass iff the smallest slack is >= -tolerance."""
    slack, count, bad = float(a[f"w_{name}_slack"]), int(a[f"w_{name}_count"]), int(a[f"w_{name}_bad"])
    if bad:
        return not_checkable(f"{bad} of {count} compared values are not finite. {detail}".strip())
    tol_text = f", round-off allowance {tolerance:.3g}" if tolerance else ""
    return Verdict(PASS if slack >= -tolerance else FAIL, measured=float(a[f"w_{name}_lo"]),
                   reference=float(a[f"w_{name}_up"]), margin=slack, tolerance=tolerance or None,
                   detail=f"smallest slack {slack:.6g} (relative {float(a[f'w_{name}_rel']):.3e}) over {count} cases"
                          f"{tol_text}. {detail}".strip())


def at_most_one(value: float, count: int, detail: str) -> Verdict:
    """A largest ratio against 1 (the ratios themselves were formed during the simulation)."""
    if not math.isfinite(value):
        return not_checkable(f"a compared ratio is not finite ({value}). {detail}")
    return Verdict(PASS if value <= 1.0 else FAIL, measured=value, reference=1.0, margin=1.0 - value,
                   detail=f"largest ratio {value:.6g} over {count:,} cases. {detail}")


def trial0_event_norms(r: Part, name: str) -> tuple[np.ndarray, np.ndarray]:
    """Trial 0's |e(s)| = max_i ||e_i(t_is)|| (S+1,) and the run's round-off floor for it (S+1,)."""
    a = r.runs[name]
    return np.linalg.norm(a["t0_e_post"], axis=-1).max(axis=-1), a["t0_floor"]


def fit_rate(t: np.ndarray, v: np.ndarray, floor: np.ndarray, skip: int = 2) -> tuple[float, int, int]:
    """Least-squares decay rate of log v over the samples from `skip` until v first reaches the
    round-off floor (exclusive). Returns (rate, first, last) sample indices; nan if < 3 samples."""
    below = np.nonzero(v[skip:] <= floor[skip:])[0]
    stop = skip + (int(below[0]) if below.size else len(v) - skip)
    if stop - skip < 3:
        return float("nan"), skip, stop
    slope = np.polyfit(t[skip:stop], np.log(v[skip:stop]), 1)[0]
    return float(-slope), skip, stop


def alpha_used(r: Part) -> tuple[float | None, str]:
    return design.alpha_used(r.design)


def stored_times(a: dict) -> np.ndarray:
    """The stored sample times of a run, in seconds."""
    return a["g_t_ns"] / 1e9
