"""Hypotheses, claims and verdicts.

A `Hypothesis` is one condition a theorem rests on (a matrix is Hurwitz, a rate exceeds
the critical rate, an LMI is feasible, a sample is large enough). It is evaluated once
per scenario and reported first, holding or not, with the number that decides it.

A `Claim` is one checkable statement of a paper (an identity, an inequality, a
statistical or a qualitative statement). It names the hypotheses its conclusion rests
on and its scope (any scenario of the family, or the paper's own example only), and its
`check` turns computed results into a `Verdict`. `evaluate` applies the rules that give
the verdict words their meaning on any scenario:

- a claim about the paper's own example is not evaluated on a user's scenario;
- a claim whose hypotheses do not hold is `not-checkable`, naming the hypothesis;
- a check that raises is `error` (a defect of ours), never `fail`;
- a `fail` whose compared numbers are not finite is `not-checkable` (a NaN is not a
  counterexample);
- the statistical claims of one report share one family-wise confidence (Bonferroni):
  each gets ``1 − (1 − family)/K`` for K statistical claims, read by `claim_confidence()`; claims of a
  `confidence_group` (a plug-in filter's) share the same family-wise confidence among themselves, apart,
  so that adding them changes no other claim's confidence.

The helpers below build verdicts so that every kind reports the same fields: what was
measured, against what reference, with which tolerance, how much margin there was, and at
what confidence.
"""
from __future__ import annotations

import contextvars
import math
import traceback
from dataclasses import asdict, dataclass, field
from typing import Any, Callable, Sequence

import numpy as np


PASS, FAIL, ERRATUM, NOT_CHECKABLE, ERROR = "pass", "fail", "erratum", "not-checkable", "error"
STATUSES = (PASS, FAIL, ERRATUM, NOT_CHECKABLE, ERROR)
KINDS = ("identity", "inequality", "statistical", "qualitative")
#: "family": the claim is a statement about every scenario of the family; "paper-example":
#: it is about the paper's own example (a figure, a printed number, a fixed counterexample).
SCOPES = ("family", "paper-example")

#: Default family-wise confidence of all statistical claims of one report together.
FAMILY_CONFIDENCE = 0.999
EPS = float(np.finfo(float).eps)

_confidence: contextvars.ContextVar[float] = contextvars.ContextVar("claim_confidence", default=FAMILY_CONFIDENCE)


def claim_confidence() -> float:
    """The confidence allotted to the statistical claim being evaluated (Bonferroni share of
    the report's family-wise confidence); the family-wise value itself outside `evaluate`."""
    return _confidence.get()


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
class Holds:
    """Whether a hypothesis holds on a scenario: `holds` is True, False, or None when it
    cannot be decided (then the claims resting on it are not checkable either); `value`
    is the number that decides it and `threshold` what it is compared with."""

    holds: bool | None
    value: Any = None
    threshold: Any = None
    detail: str = ""
    #: what the scenario declares it expects (a negative control built to break the hypothesis declares
    #: False); None when it declares nothing. A hypothesis that does not hold as declared is reported as
    #: "does not hold (expected)", not as a failure.
    expected: bool | None = None


@dataclass(frozen=True)
class Hypothesis:
    """A condition some claims rest on. `check(design) -> Holds`, where `design` is the run's
    deterministic design stage when the family has one (`Reproduction.design_of(results)`),
    so that `dse check` can evaluate it without simulating; else the run's results."""

    id: str
    statement: str
    check: Callable[[Any], Holds] = field(repr=False, compare=False)

    def evaluate(self, results: Any) -> dict[str, Any]:
        try:
            h = self.check(results)
            error = ""
        except Exception as exc:  # a broken hypothesis check is a defect, reported as such
            h, error = Holds(None), f"{type(exc).__name__}: {exc}\n{traceback.format_exc(limit=3)}"
        return {"id": self.id, "statement": self.statement, "holds": h.holds, "value": _plain(h.value),
                "threshold": _plain(h.threshold), "detail": h.detail, "error": error, "expected": h.expected}


@dataclass(frozen=True)
class Claim:
    """A paper's statement and how to check it. `check(results) -> Verdict`.

    `hypotheses`: ids of the hypotheses the conclusion rests on; `scope`: see SCOPES.
    """

    id: str
    source: str
    statement: str
    kind: str
    check: Callable[[Any], Verdict] = field(repr=False, compare=False)
    hypotheses: tuple[str, ...] = ()
    scope: str = "family"
    #: statistical claims of one non-empty group share a family-wise confidence apart from the report's
    confidence_group: str = ""

    def __post_init__(self):
        if self.kind not in KINDS:
            raise ValueError(f"claim {self.id}: unknown kind {self.kind!r}")
        if self.scope not in SCOPES:
            raise ValueError(f"claim {self.id}: unknown scope {self.scope!r}")
        object.__setattr__(self, "hypotheses", tuple(self.hypotheses))

    def evaluate(self, results: Any, hypotheses: dict[str, dict] | None = None) -> dict[str, Any]:
        """Check the claim given the evaluated hypotheses (rows of `Hypothesis.evaluate`)."""
        verdict = self._precondition(hypotheses or {})
        if verdict is None:
            try:
                verdict = _finite_or_not_checkable(self.check(results))
            except Exception as exc:  # a broken check must show up in the report, not vanish
                verdict = Verdict(ERROR, detail=f"check raised {type(exc).__name__}: {exc}\n"
                                                f"{traceback.format_exc(limit=3)}")
            if verdict.status == FAIL and self.hypotheses:
                verdict = _with_detail(verdict, "The hypotheses " + ", ".join(self.hypotheses) + " hold, so this is a "
                                                "counterexample to the statement or a defect of ours.")
        row = {"id": self.id, "source": self.source, "statement": self.statement, "kind": self.kind,
               "scope": self.scope, "hypotheses": list(self.hypotheses), "verdict": verdict.status}
        row.update({k: _plain(v) for k, v in asdict(verdict).items() if k != "status"})
        return row

    def _precondition(self, hyps: dict[str, dict]) -> Verdict | None:
        for hid in self.hypotheses:
            h = hyps.get(hid)
            if h is None:
                return Verdict(ERROR, detail=f"hypothesis {hid} is not defined for this scenario")
            if h["error"]:
                return Verdict(ERROR, detail=f"hypothesis {hid} could not be evaluated: {h['error']}")
            if h["holds"] is None:
                return not_checkable(f"hypothesis {hid} could not be decided: {h['detail']}")
            if not h["holds"]:
                return not_checkable(f"hypothesis {hid} does not hold ({h['statement']}): {h['detail']}")
        return None


@dataclass(frozen=True)
class Evaluation:
    """Every hypothesis and claim of one run, and how the statistical confidence was shared."""

    hypotheses: list[dict[str, Any]]
    claims: list[dict[str, Any]]
    statistics: dict[str, Any]
    omitted_paper_example: int = 0


def evaluate(claims: Sequence[Claim], hypotheses: Sequence[Hypothesis], results: Any, *, paper_run: bool,
             family_confidence: float = FAMILY_CONFIDENCE, per_claim_confidence: float | None = None,
             design: Any = None) -> Evaluation:
    """Hypotheses first, then every claim in scope, with a shared family-wise confidence.

    Hypotheses are evaluated on `design` when given (the run's deterministic design stage,
    which `dse check` computes without simulating), else on `results`.

    `per_claim_confidence` replaces the Bonferroni share (the calibration benchmark runs
    every statistical claim at one fixed level to measure its false-fail rate)."""
    hyp_rows = [h.evaluate(results if design is None else design) for h in hypotheses]
    by_id = {r["id"]: r for r in hyp_rows}
    if len(by_id) != len(hyp_rows):
        raise ValueError("duplicate hypothesis ids")
    in_scope = [c for c in claims if paper_run or c.scope == "family"]
    runnable = [c for c in in_scope if c.kind == "statistical" and c._precondition(by_id) is None]
    sizes = {g: sum(c.confidence_group == g for c in runnable) for g in dict.fromkeys(c.confidence_group
                                                                                         for c in in_scope)}
    share = {g: (1.0 - (1.0 - family_confidence) / max(k, 1) if per_claim_confidence is None
                 else per_claim_confidence) for g, k in sizes.items()}
    rows = []
    for c in in_scope:
        token = _confidence.set(share[c.confidence_group])
        try:
            rows.append(c.evaluate(results, by_id))
        finally:
            _confidence.reset(token)
    per_claim = share.get("", 1.0 - (1.0 - family_confidence) if per_claim_confidence is None else per_claim_confidence)
    stats = {"family_confidence": family_confidence if per_claim_confidence is None else None,
             "statistical_claims": sizes.get("", 0), "per_claim_confidence": per_claim,
             "method": "Bonferroni over the report's statistical claims" if per_claim_confidence is None
             else "one fixed level per claim (calibration)",
             "groups": {g: {"statistical_claims": k, "per_claim_confidence": share[g]} for g, k in sizes.items() if g}}
    return Evaluation(hyp_rows, rows, stats, len(claims) - len(in_scope))


def _with_detail(v: Verdict, extra: str) -> Verdict:
    return Verdict(**{**asdict(v), "detail": f"{v.detail} {extra}".strip()})


def _finite_or_not_checkable(v: Verdict) -> Verdict:
    """A fail compared against NaN or inf says nothing about the paper: not checkable."""
    if v.status != FAIL:
        return v
    bad = [name for name in ("measured", "reference", "margin")
           if getattr(v, name) is not None and not np.all(np.isfinite(np.asarray(getattr(v, name), dtype=float)))]
    if bad:
        return Verdict(NOT_CHECKABLE, measured=v.measured, reference=v.reference, tolerance=v.tolerance,
                       detail=f"a compared quantity is not finite ({', '.join(bad)}), so nothing was compared. {v.detail}")
    return v


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


# -- tolerances derived from the arithmetic ------------------------------------------------------------

def roundoff_tolerance(*, scale: float, operations: float, condition: float = 1.0, safety: float = 10.0) -> tuple[float, str]:
    """An absolute round-off allowance for a computed quantity and the sentence that says how.

    ``safety · operations · eps · condition · scale``: `scale` is the size of the inputs the
    result is computed from (not of the result), `operations` the length of the longest chain
    of floating-point operations (sums of n terms count n), `condition` the condition number
    of the problem solved along the way.
    """
    tol = safety * operations * EPS * condition * scale
    return tol, (f"round-off allowance {tol:.3g} = {safety:g}·{operations:.3g} operations·eps·condition "
                 f"{condition:.3g}·input scale {scale:.3g}")


# -- verdict helpers ------------------------------------------------------------------------------------

def _nonfinite(*arrays) -> str | None:
    for a in arrays:
        a = np.asarray(a, float)
        if a.size and not np.all(np.isfinite(a)):
            return f"{int(np.size(a) - np.isfinite(a).sum())} of {a.size} compared values are not finite"
    return None


def relative_error(measured, reference) -> np.ndarray:
    measured, reference = np.asarray(measured, float), np.asarray(reference, float)
    return np.abs(measured - reference) / np.maximum(np.abs(reference), 1e-300)


def identity(measured, reference, *, rtol: float, atol: float = 0.0, detail: str = "") -> Verdict:
    """Pass iff |measured − reference| <= atol + rtol·|reference| everywhere."""
    m, r = np.asarray(measured, float), np.asarray(reference, float)
    if (bad := _nonfinite(m, r)) is not None:
        return not_checkable(f"{bad}. {detail}".strip())
    err = np.abs(m - r)
    allowed = atol + rtol * np.abs(r)
    worst = int(np.argmax(err - allowed)) if err.size else 0
    ok = bool(np.all(err <= allowed))
    rel = float(relative_error(m, r).max()) if err.size else 0.0
    size = f"max relative error {rel:.3e}" if rtol else f"max absolute error {err.max() if err.size else 0.0:.3e}"
    return Verdict(PASS if ok else FAIL, measured=m.flat[worst] if m.size else None,
                   reference=r.flat[worst] if r.size else None, tolerance=rtol or atol,
                   margin=float(rtol - rel) if rtol else float(atol - (err.max() if err.size else 0.0)),
                   detail=f"{size}. {detail}".strip())


def inequality(lower, upper, *, detail: str = "", strict: bool = False, tolerance: float = 0.0) -> Verdict:
    """Pass iff lower <= upper + tolerance everywhere (< if strict); margin = min(upper − lower).

    `tolerance` is a round-off allowance (see `roundoff_tolerance`), never a slack that the
    claim itself would need.
    """
    lo, up = np.asarray(lower, float), np.asarray(upper, float)
    if (bad := _nonfinite(lo, up)) is not None:
        return not_checkable(f"{bad}. {detail}".strip())
    slack = up - lo
    worst = int(np.argmin(slack))
    ok = bool(np.all(slack > -tolerance) if strict else np.all(slack >= -tolerance))
    rel = float(np.min(slack / np.maximum(np.abs(up), 1e-300)))
    tol_text = f", round-off allowance {tolerance:.3g}" if tolerance else ""
    return Verdict(PASS if ok else FAIL, measured=lo.flat[worst], reference=up.flat[worst], margin=float(slack.flat[worst]),
                   tolerance=tolerance or None,
                   detail=f"smallest slack {slack.flat[worst]:.6g} (relative {rel:.3e}) over {slack.size} cases"
                          f"{tol_text}. {detail}".strip())


def statistical(estimate, se, reference, *, trials: int, confidence: float | None = None, min_trials: int = 2,
                detail: str = "") -> Verdict:
    """Pass iff every |estimate − reference| <= z·se, z chosen for the claim's confidence.

    The cells checked together share the claim's confidence (Bonferroni); the claim's
    confidence is its share of the report's (`claim_confidence`) unless given. Only valid
    where the estimates are close to normal at this sample size: below `min_trials` the
    claim is not checkable. `margin` is z minus the worst observed |z-score|.
    """
    from dse.simulate.stats import z_for_confidence

    confidence = claim_confidence() if confidence is None else confidence
    if trials < min_trials:
        return not_checkable(f"needs ≥ {min_trials} trials for this test to keep its confidence; ran {trials}. {detail}".strip())
    est, se, ref = (np.asarray(a, float) for a in (estimate, se, reference))
    if (bad := _nonfinite(est, se, ref)) is not None:
        return not_checkable(f"{bad}. {detail}".strip())
    n = est.size
    z = z_for_confidence(confidence, n)
    scores = np.abs(est - ref) / np.maximum(se, 1e-300)
    worst = int(np.argmax(scores))
    ok = bool(np.all(scores <= z))
    return Verdict(PASS if ok else FAIL, measured=est.flat[worst], reference=ref.flat[worst], tolerance=z,
                   margin=float(z - scores.flat[worst]), confidence=confidence, trials=trials,
                   detail=(f"worst |z| = {scores.flat[worst]:.2f} over {n} cells (threshold {z:.2f} for "
                           f"confidence {confidence:.6g}); median |z| = {np.median(scores):.2f}. {detail}").strip())


def p_value_test(p_values, *, trials: int, confidence: float | None = None, measured=None, reference=None,
                 min_trials: int = 2, detail: str = "") -> Verdict:
    """Pass iff every cell's p-value exceeds (1 − confidence)/cells (Bonferroni over the cells).

    For tests whose p-value is exact or conservative at the sample size used (exact
    chi-square laws, rank tests, binomial tests). `margin` is log10(min p / threshold).
    """
    confidence = claim_confidence() if confidence is None else confidence
    if trials < min_trials:
        return not_checkable(f"needs ≥ {min_trials} trials for this test; ran {trials}. {detail}".strip())
    p = np.asarray(p_values, float)
    if (bad := _nonfinite(p)) is not None:
        return not_checkable(f"{bad}. {detail}".strip())
    threshold = (1.0 - confidence) / max(p.size, 1)
    worst = int(np.argmin(p))
    ok = bool(np.all(p > threshold))
    return Verdict(PASS if ok else FAIL, measured=p.flat[worst] if measured is None else measured,
                   reference=threshold if reference is None else reference, tolerance=threshold,
                   margin=float(np.log10(max(p.flat[worst], 1e-300) / threshold)), confidence=confidence, trials=trials,
                   detail=(f"smallest p-value {p.flat[worst]:.3g} over {p.size} cells (rejected below {threshold:.3g} "
                           f"for confidence {confidence:.6g}). {detail}").strip())


def erratum(printed, corrected, reference, *, rtol: float, detail: str = "", corrected_reference=None) -> Verdict:
    """A printed formula against a reference (an independent exact computation).

    pass: the printed formula matches; erratum: it does not but the correction does;
    fail: the correction does not match either. `corrected_reference` defaults to
    `reference` (it differs when the correction is a changed hypothesis, not a formula).
    """
    p_ok = identity(printed, reference, rtol=rtol)
    c_ok = identity(corrected, reference if corrected_reference is None else corrected_reference, rtol=rtol)
    if NOT_CHECKABLE in (p_ok.status, c_ok.status):
        return not_checkable(f"printed: {p_ok.detail}; corrected: {c_ok.detail}. {detail}")
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


def within(measured, reference, allowance, *, detail: str) -> Verdict:
    """Pass iff |measured − reference| <= allowance elementwise, each value with its own allowance
    (derived from the arithmetic of that value: `roundoff_tolerance` per element)."""
    m, r, t = np.broadcast_arrays(*(np.asarray(a, float).ravel() for a in (measured, reference, allowance)))
    if m.size == 0:
        return not_checkable(f"nothing to compare. {detail}")
    if not (np.all(np.isfinite(m)) and np.all(np.isfinite(r))):
        return not_checkable(f"a compared value is not finite. {detail}")
    err = np.abs(m - r)
    worst = int(np.argmax(err / np.maximum(t, 1e-300)))
    ok = bool(np.all(err <= t))
    return Verdict(PASS if ok else FAIL, measured=float(m[worst]), reference=float(r[worst]), tolerance=float(t[worst]),
                   margin=float(t[worst] - err[worst]),
                   detail=(f"worst error {err[worst]:.3g} against its allowance {t[worst]:.3g} "
                           f"(largest error/allowance {err[worst] / max(t[worst], 1e-300):.3g}) over {m.size} values. "
                           f"{detail}").strip())


def below(lower, upper, allowance, *, detail: str, strict: bool = False) -> Verdict:
    """Pass iff lower <= upper + allowance elementwise (< with `strict`), each value with its own
    allowance; margin = the slack of the worst case."""
    lo, up, t = np.broadcast_arrays(*(np.asarray(a, float).ravel() for a in (lower, upper, allowance)))
    if lo.size == 0:
        return not_checkable(f"nothing to compare. {detail}")
    if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(up))):
        return not_checkable(f"a compared value is not finite. {detail}")
    slack = up - lo
    worst = int(np.argmin(slack + t))
    ok = bool(np.all(slack > -t) if strict else np.all(slack >= -t))
    return Verdict(PASS if ok else FAIL, measured=float(lo[worst]), reference=float(up[worst]),
                   tolerance=float(t[worst]), margin=float(slack[worst]),
                   detail=(f"smallest slack {slack[worst]:.6g} (allowance {t[worst]:.3g}) over {lo.size} "
                           f"cases. {detail}").strip())


def not_checkable(reason: str) -> Verdict:
    return Verdict(NOT_CHECKABLE, detail=reason)

