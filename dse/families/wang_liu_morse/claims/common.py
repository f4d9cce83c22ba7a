"""What the hybrid-observer claims share. A claim spans every (scenario, run) cell of the kind it
is about; each cell's own hypotheses (its q against (22) or (27), (10), N(t) constant on the
windows (23), strong connectivity of its graphs) are checked first: cells whose hypotheses do
not hold are left out and named in the detail, and a claim with no cell left is not checkable.
Tolerances are round-off allowances derived from the arithmetic, stated in each detail."""
from __future__ import annotations

import math
from typing import Callable

import numpy as np

from dse.verify.rules import ERRATUM, FAIL, NOT_CHECKABLE, PASS, Verdict, not_checkable

from .. import design, simulation
from ..scenario import RunSection
from ..simulation import is_theorem_run
from ..stages import Part, Parts
from .hypotheses import PID, cell_failures, claims, q_eq22, rests_on

__all__ = ["PID", "claims"]
EPS = float(np.finfo(float).eps)
#: the hypotheses every cell of a claim rests on (see `hypotheses.rests_on`)
OBS = rests_on("joint_observability")
THM = rests_on("joint_observability", "strong_connectivity", "local_observers", "q_eq22")
SYM = rests_on("joint_observability", "strong_connectivity", "local_observers")
EQ44 = rests_on("joint_observability", "strong_connectivity", "q_eq22")
IDEAL = rests_on("joint_observability", "strong_connectivity")


class Cells:
    """The (label, part, run) cells a claim checks (`items`), and the ones its hypotheses left out."""

    def __init__(self, res: Parts, select: Callable[[Part, RunSection], bool], needs: tuple[str, ...] = (),
                 timing: bool = False):
        """The cells `select` picks whose hypotheses `needs` hold; with `timing`, (10) and the windows
        are needed too for the asynchronous and offset runs (listed after the others)."""
        self.items, self.left_out = [], []
        for late in ((False, True) if timing else (None,)):
            for part, r in res.parts.items():
                for run in r.scenario.runs:
                    jittered = run.timing in ("async", "offset")
                    if not select(r, run) or (late is not None and jittered != late):
                        continue
                    label = f"{part}/{run.name}"
                    fails = cell_failures(res, part, run, needs + (("eq10", "windows") if late else ()))
                    if fails:
                        self.left_out.append(f"[{label}] " + ", ".join(
                            f"{hid} {'does not hold' if h.holds is False else 'is undecided'} (value {_fmt(h.value)}, "
                            f"threshold {_fmt(h.threshold)})" for hid, h in fails))
                    else:
                        self.items.append((label, r, run))

    def note(self) -> str:
        return (" Left out: " + "; ".join(self.left_out) + ".") if self.left_out else ""

    def verdict(self, verdicts: list[tuple[str, Verdict]], what: str) -> Verdict:
        if not verdicts:
            return not_checkable(f"no {what}" + (": every candidate's hypotheses fail." + self.note()
                                                  if self.left_out else ""))
        return combine(verdicts, detail=self.note())


def _fmt(v) -> str:
    if isinstance(v, (int, np.integer)):
        return f"{int(v):,}"
    return f"{float(v):.6g}" if isinstance(v, (float, np.floating)) else str(v)


def combine(verdicts: list[tuple[str, Verdict]], detail: str = "") -> Verdict:
    """Worst of several labelled verdicts (fail > erratum > pass > not-checkable), details joined."""
    order = {FAIL: 0, ERRATUM: 1, PASS: 2, NOT_CHECKABLE: 3}
    label, worst = min(verdicts, key=lambda lv: (order[lv[1].status], lv[1].margin if lv[1].margin is not None else 0))
    if len(verdicts) == 1:
        text = f"[{label}] {worst.detail}"
    else:
        text = f"worst case {label}. " + "; ".join(f"[{lab}] {v.status}: {v.detail}" for lab, v in verdicts)
    return Verdict(worst.status, measured=worst.measured, reference=worst.reference, tolerance=worst.tolerance,
                   margin=worst.margin, trials=worst.trials, printed=worst.printed, corrected=worst.corrected,
                   detail=f"{text}{detail}".strip())


def per_part(res: Parts, check: Callable[[Part], Verdict]) -> Verdict:
    """A design claim: checked on every scenario, the worst reported."""
    return combine([(name, check(r)) for name, r in res.parts.items()])


def in_theorem1(r: Part, run: RunSection) -> bool:
    """A synchronous theorem run whose q satisfies (22) (for figures)."""
    return run.timing == "sync" and is_theorem_run(r.spec(run.name)) and q_eq22(r, run.q).holds is True


def constants(r: Part, run: RunSection) -> dict[str, float]:
    """b, c, d, b', d', g of the proofs (see `design.constants`)."""
    return design.constants(r.design, r.scenario, run)


def alpha_used(r: Part) -> tuple[float | None, str]:
    return design.alpha_used(r.design)


def simulation_tolerance(r: Part, run: RunSection) -> tuple[float, str]:
    """The round-off allowance of quantities built from a simulated run (`simulation.simulation_tolerance`)."""
    return simulation.simulation_tolerance(r.scenario, r.design, run, r.runs[run.name])


def worst_verdict(a: dict, name: str, *, detail: str = "") -> Verdict:
    """The verdict of an inequality lo <= up over every (event, trial) case of a run, from the worst
    case the run kept (`monitor.Worst`; the allowances are in its bound side): pass iff the smallest
    slack is >= 0."""
    slack, count, bad = float(a[f"w_{name}_slack"]), int(a[f"w_{name}_count"]), int(a[f"w_{name}_bad"])
    if bad:
        return not_checkable(f"{bad} of {count} compared values are not finite. {detail}".strip())
    return Verdict(PASS if slack >= 0 else FAIL, measured=float(a[f"w_{name}_lo"]), reference=float(a[f"w_{name}_up"]),
                   margin=slack, detail=f"smallest slack {slack:.6g} (relative {float(a[f'w_{name}_rel']):.3e}) over "
                                        f"{count} cases. {detail}".strip())


def at_most_one(value: float, count: int, detail: str) -> Verdict:
    """A largest ratio against 1 (the ratios themselves were formed during the simulation)."""
    if not math.isfinite(value):
        return not_checkable(f"a compared ratio is not finite ({value}). {detail}")
    return Verdict(PASS if value <= 1.0 else FAIL, measured=value, reference=1.0, margin=1.0 - value,
                   detail=f"largest ratio {value:.6g} over {count:,} cases. {detail}")


def fit_rate(t: np.ndarray, v: np.ndarray, floor: np.ndarray, skip: int = 2) -> tuple[float, int, int]:
    """Least-squares decay rate of log v over the samples from `skip` until v first reaches the
    round-off floor (exclusive). Returns (rate, first, last) sample indices; nan if < 3 samples."""
    below = np.nonzero(v[skip:] <= floor[skip:])[0]
    stop = skip + (int(below[0]) if below.size else len(v) - skip)
    if stop - skip < 3:
        return float("nan"), skip, stop
    return float(-np.polyfit(t[skip:stop], np.log(v[skip:stop]), 1)[0]), skip, stop


def stored_times(a: dict) -> np.ndarray:
    """The stored sample times of a run, in seconds."""
    return a["g_t_ns"] / 1e9
