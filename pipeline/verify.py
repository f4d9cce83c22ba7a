"""Claims and verdicts.

A `Claim` is one checkable statement of a paper (an identity, an inequality, a
statistical or a qualitative statement) with a `check` that turns computed results
into a `Verdict`. The helpers below build verdicts so that every kind reports the same
fields: what was measured, against what reference, with which tolerance, how much
margin there was, and at what confidence.
"""
from __future__ import annotations

import math
import traceback
from dataclasses import asdict, dataclass, field
from typing import Any, Callable

import numpy as np


PASS, FAIL, ERRATUM, NOT_CHECKABLE = "pass", "fail", "erratum", "not-checkable"
STATUSES = (PASS, FAIL, ERRATUM, NOT_CHECKABLE)
KINDS = ("identity", "inequality", "statistical", "qualitative")


@dataclass(frozen=True)
class Verdict:
    """The outcome of checking one claim.

    `measured` / `reference`: the headline numbers (the worst case over all checked
    cells). `margin`: for inequalities the smallest slack (positive = holds), for
    identities the tolerance minus the error, for statistical checks the z-budget left.
    For an erratum, `printed` is what the paper's statement gives and `corrected` what
    the documented correction gives.
    """

    status: str
    measured: Any = None
    reference: Any = None
    tolerance: float | None = None
    margin: float | None = None
    confidence: float | None = None
    trials: int | None = None
    printed: Any = None
    corrected: Any = None
    detail: str = ""

    def __post_init__(self):
        if self.status not in STATUSES:
            raise ValueError(f"unknown verdict status {self.status!r}")


@dataclass(frozen=True)
class Claim:
    """A paper's statement and how to check it. `check(results) -> Verdict`."""

    id: str
    source: str
    statement: str
    kind: str
    check: Callable[[Any], Verdict] = field(repr=False, compare=False)

    def __post_init__(self):
        if self.kind not in KINDS:
            raise ValueError(f"claim {self.id}: unknown kind {self.kind!r}")

    def evaluate(self, results: Any) -> dict[str, Any]:
        """Run the check; a check that raises is reported as a failure with the error."""
        try:
            verdict = self.check(results)
        except Exception as exc:  # a broken check must show up in the report, not vanish
            verdict = Verdict(FAIL, detail=f"check raised {type(exc).__name__}: {exc}\n{traceback.format_exc(limit=3)}")
        row = {"id": self.id, "source": self.source, "statement": self.statement, "kind": self.kind,
               "verdict": verdict.status}
        row.update({k: _plain(v) for k, v in asdict(verdict).items() if k != "status"})
        return row


def _plain(x: Any) -> Any:
    if isinstance(x, np.ndarray):
        return [_plain(v) for v in x.tolist()]
    if isinstance(x, (list, tuple)):
        return [_plain(v) for v in x]
    if isinstance(x, dict):
        return {str(k): _plain(v) for k, v in x.items()}
    if isinstance(x, (np.floating, float)):
        v = float(x)
        return v if math.isfinite(v) else str(v)
    if isinstance(x, np.integer):
        return int(x)
    if isinstance(x, np.bool_):
        return bool(x)
    return x


def relative_error(measured, reference) -> np.ndarray:
    measured, reference = np.asarray(measured, float), np.asarray(reference, float)
    return np.abs(measured - reference) / np.maximum(np.abs(reference), 1e-300)


def identity(measured, reference, *, rtol: float, atol: float = 0.0, detail: str = "") -> Verdict:
    """Pass iff |measured − reference| <= atol + rtol·|reference| everywhere."""
    m, r = np.asarray(measured, float), np.asarray(reference, float)
    err = np.abs(m - r)
    allowed = atol + rtol * np.abs(r)
    worst = int(np.argmax(err - allowed)) if err.size else 0
    ok = bool(np.all(err <= allowed)) and bool(np.all(np.isfinite(m)))
    rel = float(relative_error(m, r).max()) if err.size else 0.0
    size = f"max relative error {rel:.3e}" if rtol else f"max absolute error {err.max():.3e}"
    return Verdict(PASS if ok else FAIL, measured=m.flat[worst], reference=r.flat[worst], tolerance=rtol or atol,
                   margin=float(rtol - rel) if rtol else float(atol - err.max()),
                   detail=f"{size}. {detail}".strip())


def inequality(lower, upper, *, detail: str = "", strict: bool = False) -> Verdict:
    """Pass iff lower <= upper everywhere (< if strict); margin = min(upper − lower)."""
    lo, up = np.asarray(lower, float), np.asarray(upper, float)
    slack = up - lo
    worst = int(np.argmin(slack))
    ok = bool(np.all(slack > 0) if strict else np.all(slack >= 0))
    rel = float(np.min(slack / np.maximum(np.abs(up), 1e-300)))
    return Verdict(PASS if ok else FAIL, measured=lo.flat[worst], reference=up.flat[worst], margin=float(slack.flat[worst]),
                   detail=f"smallest slack {slack.flat[worst]:.6g} (relative {rel:.3e}) over {slack.size} cases. {detail}".strip())


def statistical(estimate, se, reference, *, confidence: float, trials: int, detail: str = "") -> Verdict:
    """Pass iff every |estimate − reference| <= z·se, z chosen for the family-wise confidence.

    The family is all the cells checked together (Bonferroni). `margin` is z minus the
    worst observed |z-score|.
    """
    from .stats import z_for_confidence

    est, se, ref = (np.asarray(a, float) for a in (estimate, se, reference))
    n = est.size
    z = z_for_confidence(confidence, n)
    scores = np.abs(est - ref) / np.maximum(se, 1e-300)
    worst = int(np.argmax(scores))
    ok = bool(np.all(scores <= z))
    return Verdict(PASS if ok else FAIL, measured=est.flat[worst], reference=ref.flat[worst], tolerance=z,
                   margin=float(z - scores.flat[worst]), confidence=confidence, trials=trials,
                   detail=(f"worst |z| = {scores.flat[worst]:.2f} over {n} cells (threshold {z:.2f} for "
                           f"family-wise confidence {confidence}); median |z| = {np.median(scores):.2f}. {detail}").strip())


def erratum(printed, corrected, reference, *, rtol: float, detail: str = "", corrected_reference=None) -> Verdict:
    """A printed formula against a reference (an independent exact computation).

    pass: the printed formula matches; erratum: it does not but the correction does;
    fail: the correction does not match either. `corrected_reference` defaults to
    `reference` (it differs when the correction is a changed hypothesis, not a formula).
    """
    p_ok = identity(printed, reference, rtol=rtol)
    c_ok = identity(corrected, reference if corrected_reference is None else corrected_reference, rtol=rtol)
    if p_ok.status == PASS:
        status, worst = PASS, p_ok
    elif c_ok.status == PASS:
        status, worst = ERRATUM, p_ok
    else:
        status, worst = FAIL, c_ok
    p, c = np.asarray(printed, float), np.asarray(corrected, float)
    idx = int(np.argmax(relative_error(p, reference))) if p.size else 0
    return Verdict(status, measured=worst.measured, reference=worst.reference, tolerance=rtol,
                   margin=c_ok.margin, printed=p.flat[idx], corrected=c.flat[idx],
                   detail=(f"printed: {p_ok.detail}; corrected: {c_ok.detail}. {detail}").strip())


def not_checkable(reason: str) -> Verdict:
    return Verdict(NOT_CHECKABLE, detail=reason)
