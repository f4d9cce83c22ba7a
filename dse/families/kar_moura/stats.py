"""Tests of the gossip-Kalman claims whose level holds at any sample size.

Every test here is exact or conservative for the sample it gets, so that a claim's stated
confidence (its Bonferroni share of the report's family-wise confidence, `claim_confidence`) is
kept however few runs a scenario has and however heavy the tails of the covariances are:

* two-sample Kolmogorov-Smirnov with the exact p-value (`ks_test`): distribution free for
  continuous laws and conservative for atomic ones (ties only make the statistic smaller); the
  covariance features are log scale, and values closer than their numerical resolution (`SNAP`,
  far above the round-off of two equivalent computations and far below any statistical resolution,
  or ~eps·κ for the smallest eigenvalue of a matrix of condition κ) are merged into ties first, so
  that two bitwise-different computations of the same atom do not look like different laws;
* exact binomial p-values (`binom_p`, twice the smaller tail) for counts of a known probability;
* the exact χ² law of a sum of squared standard normals (`dse.simulate.stats.chi2_two_sided_p`);
* Clopper-Pearson bounds for one-sided comparisons of proportions with an allowance;
* Hoeffding's inequality for means of variables in [0, 1] (any distribution);
* the Dvoretzky-Kiefer-Wolfowitz inequality (Massart's constant) for a distance between
  empirical CDFs with an allowance.
"""
from __future__ import annotations

import math
import warnings

import numpy as np

from dse.simulate.stats import clopper_pearson

#: log-feature resolution: values closer than this are ties (round-off of equivalent computations ~1e-13)
SNAP = 1e-6
#: the smallest sample (each side) a test is run on; smaller ones are left out and named
MIN_SAMPLE = 20


def finite(a) -> np.ndarray:
    a = np.asarray(a, float).ravel()
    return a[np.isfinite(a)]


def snap_many(*samples, tol: float = SNAP) -> list[np.ndarray]:
    """The finite values of each sample, every value replaced by the smallest of its run of pooled
    values closer than the tolerance to their neighbour (single linkage on the sorted pooled sample):
    nearly equal values become exact ties, in all samples alike.

    A sample may be an array of values or a pair (values, per-value resolution): two neighbours merge
    when their gap is within the larger of their resolutions (and of `tol`), so a feature that is
    only resolved to ~eps·κ (the smallest eigenvalue of an ill-conditioned matrix) merges at that
    scale and well-resolved values do not."""
    vals, tols = [], []
    for x in samples:
        v, r = (x if isinstance(x, tuple) else (x, np.zeros(np.shape(x))))
        v, r = np.asarray(v, float).ravel(), np.broadcast_to(np.asarray(r, float), np.shape(v)).ravel()
        keep = np.isfinite(v)
        vals.append(v[keep])
        tols.append(np.maximum(r[keep], tol))
    pooled, res = np.concatenate(vals), np.concatenate(tols)
    if pooled.size == 0:
        return vals
    order = np.argsort(pooled, kind="stable")
    v, r = pooled[order], res[order]
    new_group = np.concatenate([[True], np.diff(v) > np.maximum(r[1:], r[:-1])])
    rep = v[np.flatnonzero(new_group)][np.cumsum(new_group) - 1]
    out = np.empty_like(pooled)
    out[order] = rep
    return np.split(out, np.cumsum([len(x) for x in vals])[:-1])


def snap(a, b, tol: float = SNAP) -> tuple[np.ndarray, np.ndarray]:
    a, b = snap_many(a, b, tol=tol)
    return a, b


def ks_test(a, b) -> tuple[float, float, int, int]:
    """(D, exact two-sided p-value, n_a, n_b) after snapping near-ties (a, b: values or (values, resolution))."""
    a, b = snap(a, b)
    if min(len(a), len(b)) == 0:
        return math.nan, 1.0, len(a), len(b)
    from scipy import stats     # here, not at the top: `dse list` and `dse check` import this module (1 s)

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        r = stats.ks_2samp(a, b, method="exact")
    return float(r.statistic), float(r.pvalue), len(a), len(b)


def binom_p(k, n, p) -> np.ndarray:
    """Two-sided exact binomial p-value, twice the smaller tail (capped at 1); 0 where p = 0 < k."""
    from scipy import stats

    k, n, p = (np.asarray(x, float) for x in (k, n, p))
    p = np.clip(p, 0.0, 1.0)  # probabilities summed in floating point may exceed 1 by an ulp
    lower = stats.binom.cdf(k, n, p)
    upper = stats.binom.sf(k - 1, n, p)
    return np.minimum(1.0, 2.0 * np.minimum(lower, upper))


def cp_upper(k: int, n: int, level: float) -> float:
    """One-sided Clopper-Pearson upper bound at confidence 1 − level."""
    return clopper_pearson(int(k), int(n), 1.0 - 2.0 * level)[1]


def cp_lower(k: int, n: int, level: float) -> float:
    """One-sided Clopper-Pearson lower bound at confidence 1 − level."""
    return clopper_pearson(int(k), int(n), 1.0 - 2.0 * level)[0]


def hoeffding_p(diff: float, n1: int, n2: int) -> float:
    """P-value of |mean₁ − mean₂| = diff for independent samples of [0, 1] variables with equal means:
    2 exp(−2 diff² / (1/n1 + 1/n2)) (Hoeffding), capped at 1."""
    return float(min(1.0, 2.0 * math.exp(-2.0 * diff * diff / (1.0 / n1 + 1.0 / n2))))


def dkw_eps(n: int, level: float) -> float:
    """sup_x |F̂_n(x) − F(x)| ≤ eps with probability ≥ 1 − level (DKW, Massart): sqrt(ln(2/level)/(2n))."""
    return math.sqrt(math.log(2.0 / level) / (2.0 * n))
