"""Exact (or conservative) p-values for Monte Carlo sums of Gaussian errors with a known covariance.

Given the gains, every error of the consensus filters is a linear function of independent
Gaussian noises with zero mean, so across R independent trials the errors x̃(k) are i.i.d.
N(0, P(k)) with P(k) the exact recursion (22). Hence, for each agent i and step k:

- Σ_t x̃_i² / P_ii ~ χ²(R) exactly (the mean is known to be 0, so the raw second moment is used);
- Σ_t x̃_i ~ N(0, R P_ii) exactly;
- Σ_t ‖x̃‖² = Σ_j λ_j χ²_j(R) with λ_j the eigenvalues of P and independent χ²_j: a weighted
  sum of χ² variables. Its two tails are bounded by Chernoff's inequality,
  P(T ≥ t) ≤ min_θ E[e^{θT}] e^{−θt} = min_θ exp(−θt − (R/2) Σ_j log(1 − 2θλ_j)), and the same
  for the lower tail with −θ; the two-sided p-value 2·min(upper, lower) is therefore
  conservative at every R (it is exact χ² when one eigenvalue carries everything).

A zero variance means the error is exactly zero (for instance P(0|−1) = 0 when σ0 = 0): the
p-value is 1 if the simulated sum is exactly 0 and 0 otherwise.
"""
from __future__ import annotations

import numpy as np

from dse.simulate.stats import chi2_two_sided_p, normal_two_sided_p

_BISECTIONS = 200


def chi2_sum_p(sum_sq, variance, dof: int) -> np.ndarray:
    """Two-sided p-value of a sum of `dof` squared i.i.d. N(0, variance) draws (exact χ²)."""
    s, v = np.broadcast_arrays(np.asarray(sum_sq, float), np.asarray(variance, float))
    pos = v > 0
    p = np.where(s == 0, 1.0, 0.0)
    if pos.any():
        p = np.where(pos, chi2_two_sided_p(s / np.where(pos, v, 1.0), dof), p)
    return p


def normal_sum_p(total, variance, count: int) -> np.ndarray:
    """Two-sided p-value of a sum of `count` i.i.d. N(0, variance) draws (exact normal)."""
    s, v = np.broadcast_arrays(np.asarray(total, float), np.asarray(variance, float))
    pos = v > 0
    p = np.where(s == 0, 1.0, 0.0)
    if pos.any():
        p = np.where(pos, normal_two_sided_p(s / np.sqrt(count * np.where(pos, v, 1.0))), p)
    return p


def _converged(mid, lo, hi) -> bool:
    """Every bracket is down to adjacent (or equal) doubles, so that the midpoint is one of its ends:
    after one more step (which may close the bracket on that end) bisecting changes nothing."""
    return bool(np.all((mid == lo) | (mid == hi)))


def _log_upper_bound(t, lam, dof):
    """log of min_θ P(T ≥ t) Chernoff bound, T = Σ λ_j χ²_j(dof); one value per row of `lam`."""
    mean = dof * lam.sum(axis=-1)
    out = np.zeros(t.shape)
    idx = np.flatnonzero(t > mean)
    if idx.size == 0:
        return out
    lam_i, t_i = lam[idx], t[idx]
    lam_max = lam_i.max(axis=-1)
    lo, hi = np.zeros(idx.size), np.ones(idx.size)  # θ = u / (2 λ_max), u in (0, 1)
    for _ in range(_BISECTIONS):
        u = 0.5 * (lo + hi)
        last = _converged(u, lo, hi)
        theta = u / (2 * lam_max)
        grad = dof * np.sum(lam_i / (1 - 2 * theta[:, None] * lam_i), axis=-1) - t_i
        lo, hi = np.where(grad < 0, u, lo), np.where(grad < 0, hi, u)
        if last:
            break
    theta = lo / (2 * lam_max)
    out[idx] = -theta * t_i - 0.5 * dof * np.sum(np.log1p(-2 * theta[:, None] * lam_i), axis=-1)
    return np.minimum(out, 0.0)


def _log_lower_bound(t, lam, dof):
    """log of min_θ P(T ≤ t) Chernoff bound (−inf when t = 0 and some λ > 0)."""
    mean = dof * lam.sum(axis=-1)
    out = np.zeros(t.shape)
    zero = (t <= 0) & (mean > 0)
    out[zero] = -np.inf
    idx = np.flatnonzero((t < mean) & ~zero)
    if idx.size == 0:
        return out
    lam_i, t_i = lam[idx], t[idx]
    n_pos = np.count_nonzero(lam_i > 0, axis=-1)
    lo, hi = np.zeros(idx.size), np.log(n_pos * dof / t_i + 1.0)  # θ = expm1(v); at θ = n·dof/t the gradient is > 0
    for _ in range(_BISECTIONS):
        v = 0.5 * (lo + hi)
        last = _converged(v, lo, hi)
        theta = np.expm1(v)
        grad = t_i - dof * np.sum(lam_i / (1 + 2 * theta[:, None] * lam_i), axis=-1)
        lo, hi = np.where(grad < 0, v, lo), np.where(grad < 0, hi, v)
        if last:
            break
    theta = np.expm1(lo)
    out[idx] = theta * t_i - 0.5 * dof * np.sum(np.log1p(2 * theta[:, None] * lam_i), axis=-1)
    return np.minimum(out, 0.0)


def weighted_chi2_p(total, weights, dof: int) -> np.ndarray:
    """Conservative two-sided p-value of T = Σ_j w_j χ²_j(dof) (independent χ², w_j ≥ 0).

    `total`: shape (...); `weights`: shape (..., J). Exact χ² when at most one weight is
    positive (up to 1e-12 of the largest), Chernoff bounds otherwise (see the module docstring).
    """
    t = np.asarray(total, float)
    lam = np.clip(np.asarray(weights, float), 0.0, None)
    lam = lam.reshape(t.shape + lam.shape[-1:])
    flat_t, flat_lam = t.reshape(-1), lam.reshape(-1, lam.shape[-1])
    top = flat_lam.max(axis=-1)
    single = np.count_nonzero(flat_lam > 1e-12 * top[:, None], axis=-1) <= 1
    p = np.empty(flat_t.shape)
    p[single] = chi2_sum_p(flat_t[single], top[single], dof)
    many = ~single
    if many.any():
        log_p = np.log(2.0) + np.minimum(_log_upper_bound(flat_t[many], flat_lam[many], dof),
                                         _log_lower_bound(flat_t[many], flat_lam[many], dof))
        p[many] = np.minimum(1.0, np.exp(log_p))
    return p.reshape(t.shape)
