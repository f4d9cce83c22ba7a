"""What the gossip-kalman checks share: the covariance features of the samples, the families of exact tests
that make one verdict (Kolmogorov-Smirnov with exact p-values, Bonferroni within the claim), the verdict on
Loewner margins with their round-off allowances, and the ids of the hypotheses a claim rests on.

Statistics: one sample per independent run; every test is exact or conservative at the sample it
gets (see `stats`), at the claim's share of the report's family-wise confidence (Bonferroni over
the cells of the claim). Inequalities between computed matrices carry a round-off allowance
derived from the computation (`riccati_roundoff`: input sizes and operation counts, propagated
through the maps), never a fixed slack.
"""
from __future__ import annotations

import math
from dataclasses import asdict

import numpy as np

from dse.estimators.gikf_maps import FEATURES
from dse.verify.rules import EPS, FAIL, PASS, Verdict, claim_confidence, not_checkable, p_value_test

from . import stats as kst
from .results import ScenarioResults

PAPER = "kar-moura"
FEAT = {name: i for i, name in enumerate(FEATURES)}
KS_FEATURES = ("log_trace", "log_lam_max", "log_lam_min", "log_det")
MONOTONE_FEATURES = ("log_trace", "log_lam_max", "log_lam_min")  # upward-closed sets {f(X) ≥ a}


def hyp(*names: str) -> tuple[str, ...]:
    """The ids (templates) of the scenario's hypotheses `names` (see `hypotheses`)."""
    return tuple(f"{PAPER}.hyp.{name}{{.scenario}}" for name in names)


#: what the theorem's conclusions rest on (S.1 always holds: validation requires Q ≻ 0)
THEOREM = hyp("c1", "d1", "s1")

ROUNDOFF_SENTENCE = ("Round-off allowance: the first-order bound e(t+1) = ‖FA‖²e(t) + 10·(4M+3m+4)·eps·(‖F‖²(‖A‖²‖X‖ + "
                     "‖K‖²‖R‖) + ‖Q‖) of every Joseph-form step (A = I − KC; Frobenius norms), carried along each computed "
                     "matrix and added for both sides of the comparison.")


def feat(arr: np.ndarray, name: str) -> np.ndarray:
    return arr[FEAT[name]]


def fsample(arr: np.ndarray, name: str) -> tuple[np.ndarray, np.ndarray]:
    """A feature's values and their numerical resolution, for the tests' tie merging: log tr and log λ_max
    of a PSD matrix are accurate to a few eps; log λ_min (and log det, dominated by it) only to
    ~eps‖X‖/λ_min = eps·κ (Weyl), taken as 1e3·M·eps·κ to cover the matrix's own round-off."""
    v = feat(arr, name)
    if name not in ("log_lam_min", "log_det"):
        return v, np.zeros(np.shape(v))
    M = arr.shape[0] - len(FEATURES)
    with np.errstate(over="ignore", invalid="ignore"):
        kappa = np.exp(feat(arr, "log_lam_max") - feat(arr, "log_lam_min"))
    return v, 1e3 * M * EPS * kappa


def error_level() -> float:
    """The claim's error level (1 − its share of the report's family-wise confidence), split by its cells."""
    return 1.0 - claim_confidence()


def tidx(r: ScenarioResults, t: int, which: str = "gikf") -> int:
    times = list((r.gikf if which == "gikf" else r.reference)["times"])
    return times.index(t)


def ks_family(tests: list[tuple[str, np.ndarray, np.ndarray]], what: str, extra: list[tuple[str, float]] = ()) -> Verdict:
    """Every two-sample KS test of the family (exact p-values) and any extra exact p-values must
    pass at the claim's confidence, Bonferroni over all of them. Tests with a sample under
    MIN_SAMPLE are left out and named; with nothing left the claim is not checkable."""
    small, cells = [], []
    for label, a, b in tests:
        D, p, na, nb = kst.ks_test(a, b)
        if min(na, nb) < kst.MIN_SAMPLE:
            small.append(f"{label} (n = {na} vs {nb})")
            continue
        cells.append((label, D, p, na, nb))
    skipped = f" Left out (a sample under {kst.MIN_SAMPLE}): {'; '.join(small)}." if small else ""
    if not cells and not extra:
        return not_checkable(f"{what}: every sample is under {kst.MIN_SAMPLE}, the smallest this claim tests.{skipped}")
    pv = [c[2] for c in cells] + [p for _, p in extra]
    worst = int(np.argmin(pv))
    labels = [c[0] for c in cells] + [label for label, _ in extra]
    lines = "; ".join(f"{label}: D={D:.4f} p={p:.3g} (n {na} vs {nb})" for label, D, p, na, nb in cells)
    trials = min((min(c[3], c[4]) for c in cells), default=kst.MIN_SAMPLE)
    return p_value_test(pv, trials=trials, min_trials=kst.MIN_SAMPLE,
                        detail=(f"{what}. Two-sample Kolmogorov-Smirnov tests with exact p-values (log features, "
                                f"near-ties within {kst.SNAP:g} merged; conservative for atomic laws), "
                                f"{len(pv)} cells, smallest p at {labels[worst]}. {lines}"
                                + (". " + "; ".join(f"{label}: p={p:.3g}" for label, p in extra) if extra else "")
                                + f". Each test needs ≥ {kst.MIN_SAMPLE} samples per side.{skipped}"))


def slack_verdict(slack: np.ndarray, raw: np.ndarray, detail: str) -> Verdict:
    """Pass iff every slack (margin plus its round-off allowance) is ≥ 0."""
    slack, raw = np.asarray(slack, float).ravel(), np.asarray(raw, float).ravel()
    keep = np.isfinite(slack)
    if not keep.any():
        return not_checkable(f"no finite margin was computed. {detail}")
    i = int(np.argmin(np.where(keep, slack, np.inf)))
    return Verdict(PASS if slack[keep].min() >= 0 else FAIL, measured=float(raw[i]), reference=0.0,
                   tolerance=float(slack[i] - raw[i]), margin=float(slack[i]),
                   detail=(f"smallest relative Loewner margin λ_min / max(1, ‖·‖) {raw[keep].min():.3e}; smallest margin "
                           f"plus its round-off allowance {slack[keep].min():.3e} (must be ≥ 0) over {int(keep.sum())} cases. "
                           + detail))


def with_detail(v: Verdict, extra: str) -> Verdict:
    return Verdict(**{**asdict(v), "detail": f"{v.detail}{extra}"})


def resolved(features: np.ndarray, name: str, err: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A log feature of computed matrices and its resolution from their round-off bound err (‖error‖ ≤ err),
    by Weyl's inequality: err/λ_max for log λ_max, err/λ_min for log λ_min, M·err/tr for log tr and
    M·err/λ_min for log det; plus a few eps."""
    v = feat(features, name)
    M = features.shape[0] - len(FEATURES)
    size = {"log_trace": feat(features, "log_trace") - math.log(M), "log_lam_max": feat(features, "log_lam_max"),
            "log_lam_min": feat(features, "log_lam_min"), "log_det": feat(features, "log_lam_min") - math.log(M)}[name]
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        res = np.asarray(err, float) * np.exp(-size) + 10 * M * EPS
    keep = np.isfinite(v)
    return v[keep], np.where(np.isfinite(res[keep]), res[keep], np.inf)


def ks_stat(a: np.ndarray, b: np.ndarray) -> float:
    a, b = np.sort(a), np.sort(b)
    x = np.concatenate([a, b])
    return float(np.abs(np.searchsorted(a, x, side="right") / len(a) - np.searchsorted(b, x, side="right") / len(b)).max())


def random_psd(rng, size, M, log_scale=(-2, 8)):
    """`size` random PSD M x M matrices (Wishart, M + 2 degrees of freedom) scaled by 10^U(log_scale)."""
    Z = rng.standard_normal((size, M, M + 2))
    X = Z @ np.swapaxes(Z, -1, -2) / (M + 2)
    return X * (10.0 ** rng.uniform(*log_scale, size))[:, None, None]
