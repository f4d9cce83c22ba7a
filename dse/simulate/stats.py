"""Monte Carlo statistics accumulated over blocks of trials.

`ErrorMoments` keeps, for an error array of shape (trials, K, N), the sums needed for
the per-agent mean, variance (ddof = 1) and their standard errors, and for the trace of
the error covariance with its standard error, without keeping the trials.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np
from statistics import NormalDist


@dataclass(frozen=True)
class ErrorMoments:
    """Sums over trials of e, e², e⁴ per (k, agent) and of s = Σ_i e_i², s² per k."""

    count: int
    s1: np.ndarray  # (K, N)
    s2: np.ndarray  # (K, N)
    s4: np.ndarray  # (K, N)
    t1: np.ndarray  # (K,)
    t2: np.ndarray  # (K,)

    @classmethod
    def of(cls, err: np.ndarray) -> "ErrorMoments":
        # einsum runs fast on strided views and needs no BLAS (deterministic whatever the threads)
        sq = np.square(err)
        tr = np.einsum("tkn->tk", sq)
        return cls(err.shape[0], np.einsum("tkn->kn", err), np.einsum("tkn->kn", sq), np.einsum("tkn,tkn->kn", sq, sq),
                   np.einsum("tk->k", tr), np.einsum("tk,tk->k", tr, tr))

    @classmethod
    def combine(cls, parts: Sequence["ErrorMoments"]) -> "ErrorMoments":
        """Sum in the given order (fixed block order keeps results bit-identical)."""
        first, *rest = parts
        out = first
        for p in rest:
            out = cls(out.count + p.count, out.s1 + p.s1, out.s2 + p.s2, out.s4 + p.s4, out.t1 + p.t1, out.t2 + p.t2)
        return out

    def arrays(self) -> dict[str, np.ndarray]:
        return {"count": np.array(self.count), "s1": self.s1, "s2": self.s2, "s4": self.s4, "t1": self.t1, "t2": self.t2}

    @classmethod
    def from_arrays(cls, a: dict[str, np.ndarray]) -> "ErrorMoments":
        return cls(int(a["count"]), a["s1"], a["s2"], a["s4"], a["t1"], a["t2"])

    # derived statistics -------------------------------------------------------------
    @property
    def mean(self) -> np.ndarray:
        return self.s1 / self.count

    @property
    def mean_se(self) -> np.ndarray:
        return np.sqrt(self.variance / self.count)

    @property
    def variance(self) -> np.ndarray:
        """Per-agent sample variance, ddof = 1 (the paper's 'var')."""
        n = self.count
        return (self.s2 - self.s1 ** 2 / n) / (n - 1)

    @property
    def mse(self) -> np.ndarray:
        return self.s2 / self.count

    @property
    def variance_se(self) -> np.ndarray:
        """Standard error of the per-agent second moment: sqrt((E e⁴ − (E e²)²)/n)."""
        n = self.count
        return np.sqrt(np.maximum(self.s4 / n - (self.s2 / n) ** 2, 0.0) / n)

    @property
    def trace(self) -> np.ndarray:
        """Σ_i var(e_i) per k: the estimate of tr P."""
        return self.variance.sum(axis=1)

    @property
    def trace_se(self) -> np.ndarray:
        n = self.count
        return np.sqrt(np.maximum(self.t2 / n - (self.t1 / n) ** 2, 0.0) / n)


def z_for_confidence(confidence: float, n_tests: int = 1) -> float:
    """Two-sided normal quantile for a family of n_tests checks at the given confidence (Bonferroni)."""
    alpha = (1.0 - confidence) / n_tests
    return NormalDist().inv_cdf(1.0 - alpha / 2.0)


def confidence_of_z(z: float, n_tests: int = 1) -> float:
    """Family-wise confidence of |Z| <= z over n_tests independent checks (Bonferroni lower bound)."""
    return float(max(0.0, 1.0 - n_tests * 2.0 * (1.0 - NormalDist().cdf(z))))


# -- tests whose level holds at the sample size used ---------------------------------------------------

def chi2_two_sided_p(statistic, dof) -> np.ndarray:
    """Two-sided p-value of an exact χ²(dof) statistic: 2·min(F, 1 − F), capped at 1.

    Exact when the statistic is a sum of `dof` squared independent standard normals, e.g.
    Σ_k (uᵀe_k)²/(uᵀΣu) over k = 1..n Gaussian errors e_k ~ N(0, Σ) with Σ known.
    """
    from scipy.special import gammainc, gammaincc  # the χ² laws without importing scipy.stats (1 s)

    s, d = np.asarray(statistic, float), np.asarray(dof, float)
    x = np.maximum(s, 0.0) / 2.0
    return np.minimum(1.0, 2.0 * np.minimum(gammainc(d / 2.0, x), gammaincc(d / 2.0, x)))


def normal_two_sided_p(z) -> np.ndarray:
    """Two-sided p-value of a standard normal statistic."""
    from scipy.special import ndtr

    return 2.0 * ndtr(-np.abs(np.asarray(z, float)))


def clopper_pearson(successes: int, n: int, confidence: float = 0.95) -> tuple[float, float]:
    """Exact (conservative) binomial confidence interval for a proportion."""
    from scipy.special import betaincinv

    a = 1.0 - confidence
    lo = 0.0 if successes == 0 else float(betaincinv(successes, n - successes + 1, a / 2))
    hi = 1.0 if successes == n else float(betaincinv(successes + 1, n - successes, 1 - a / 2))
    return lo, hi


def effective_sample_size(values, axis: int = 0) -> np.ndarray:
    """(Σx)²/Σx² of nonnegative values along `axis`: the number of equally weighted samples
    that carry the same information about the mean. Far below the count when a few samples
    dominate (heavy tails): a normal approximation of the sample mean is then not to be
    trusted, whatever its estimated standard error says."""
    x = np.abs(np.asarray(values, float))
    s1, s2 = x.sum(axis=axis), np.square(x).sum(axis=axis)
    return np.where(s2 > 0, s1 ** 2 / np.where(s2 > 0, s2, 1.0), x.shape[axis])


@dataclass(frozen=True)
class Moments:
    """Count, mean and sum of squared deviations (M2) of samples on a leading trial axis, merged
    part by part (Chan, Golub & LeVeque's update), so that trials can stream in units: merged in
    a fixed order the result does not depend on how the units were grouped in memory. With
    `outer`, the samples are vectors (last axis) and M2 holds the cross-products (a covariance)."""

    count: int
    mean: np.ndarray
    m2: np.ndarray
    outer: bool = False

    @classmethod
    def of(cls, x: np.ndarray, outer: bool = False) -> "Moments":
        x = np.asarray(x, float)
        mean = x.mean(axis=0)
        d = x - mean
        m2 = np.einsum("r...i,r...j->...ij", d, d) if outer else np.einsum("r...,r...->...", d, d)
        return cls(x.shape[0], mean, m2, outer)

    def merge(self, other: "Moments") -> "Moments":
        n = self.count + other.count
        delta = other.mean - self.mean
        w = self.count * other.count / n
        cross = delta[..., :, None] * delta[..., None, :] if self.outer else delta * delta
        return Moments(n, self.mean + delta * (other.count / n), self.m2 + other.m2 + cross * w, self.outer)

    @classmethod
    def combine(cls, parts: Sequence["Moments"]) -> "Moments":
        first, *rest = parts
        for p in rest:
            first = first.merge(p)
        return first

    @property
    def variance(self) -> np.ndarray:
        """Sample variance (covariance with `outer`), ddof = 1."""
        return self.m2 / (self.count - 1)

    @property
    def sd(self) -> np.ndarray:
        return np.sqrt(np.maximum(self.variance, 0.0))

    @property
    def mean_se(self) -> np.ndarray:
        """Standard error of the mean (of each component; the diagonal with `outer`)."""
        var = np.diagonal(self.variance, axis1=-2, axis2=-1) if self.outer else self.variance
        return np.sqrt(np.maximum(var, 0.0) / self.count)
