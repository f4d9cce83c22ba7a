"""Centralized discrete-time Kalman filter, batched over Monte Carlo trials.

This is the project's reference estimator: every distributed filter is compared with
the optimal centralized filter that sees all sensors' measurements at once.

Model (time-invariant)::

    x(k+1) = F x(k) + w(k),      w(k) ~ N(0, Q)
    z(k)   = H x(k) + v(k),      v(k) ~ N(0, R)
    x(0)   ~ N(x0, P0)

with ``x`` of size n and ``z`` of size p. Notation: ``x̂(k|k-1)`` and ``P(k|k-1)`` are the
prior (predicted) mean and covariance given z(0..k-1); ``x̂(k|k)`` and ``P(k|k)`` the
posterior given z(0..k). So ``x̂(0|-1) = x0`` and ``P(0|-1) = P0``.

One step, for k = 0 .. K-1 (the same order as filterpy's ``update`` then ``predict``)::

    S(k)      = H P(k|k-1) Hᵀ + R                       innovation covariance
    G(k)      = P(k|k-1) Hᵀ S(k)⁻¹                      gain, (n, p)
    x̂(k|k)   = x̂(k|k-1) + G(k) (z(k) - H x̂(k|k-1))
    P(k|k)    = (I - G H) P(k|k-1) (I - G H)ᵀ + G R Gᵀ  Joseph form
    x̂(k+1|k) = F x̂(k|k)
    P(k+1|k)  = F P(k|k) Fᵀ + Q

The covariances and gains do not depend on the measurements. They are therefore computed
once (:func:`kalman_covariances`) and shared by all trials, and the mean recursion of
:func:`kalman_filter_batch` is a handful of matrix products over the whole trials axis per
time step. This is what makes it orders of magnitude faster than one filter object per trial
(see ``benchmarks/bench_kalman.py``).

Why the Joseph form: for the optimal gain it equals ``(I - G H) P``, but it stays symmetric
positive semi-definite under rounding, which the short form does not. We also symmetrise
each step, so ``P_post`` is exactly symmetric.

References: R. E. Kalman (1960); B. D. O. Anderson and J. B. Moore, *Optimal Filtering*
(1979), ch. 3 (recursion) and ch. 4 (steady state, the discrete algebraic Riccati equation);
R. Labbe, *Kalman and Bayesian Filters in Python* (filterpy's derivation).
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass

import numpy as np
import scipy  # scipy.linalg loads on first use (scipy imports submodules lazily): `dse list` skips it

__all__ = [
    "KalmanCovariances",
    "KalmanRun",
    "kalman_covariances",
    "kalman_filter_batch",
    "steady_state_prior_covariance",
    "steady_state_gain",
    "scalar_random_walk_steady_state",
]


@dataclass(frozen=True)
class KalmanCovariances:
    """The data-independent part of a Kalman filter run, for K time steps.

    Attributes
    ----------
    P_prior : ndarray, shape (K, n, n)
        ``P_prior[k] = P(k|k-1)``, the covariance of x(k) given z(0..k-1).
        ``P_prior[0]`` is the initial covariance P0.
    P_post : ndarray, shape (K, n, n)
        ``P_post[k] = P(k|k)``, the covariance of x(k) given z(0..k). Exactly symmetric.
    gains : ndarray, shape (K, n, p)
        ``gains[k] = P(k|k-1) Hᵀ (H P(k|k-1) Hᵀ + R)⁻¹``, the gain applied to the
        innovation z(k) - H x̂(k|k-1).
    """

    P_prior: np.ndarray
    P_post: np.ndarray
    gains: np.ndarray


@dataclass(frozen=True)
class KalmanRun:
    """Means of a batched Kalman filter run, with the shared covariances.

    Attributes
    ----------
    x_prior : ndarray, shape (trials, K, n)
        ``x_prior[t, k] = x̂(k|k-1)`` in trial t; ``x_prior[:, 0]`` is x0.
    x_post : ndarray, shape (trials, K, n)
        ``x_post[t, k] = x̂(k|k)`` in trial t.
    cov : KalmanCovariances
        ``P(k|k-1)``, ``P(k|k)`` and the gains, the same for every trial.
    """

    x_prior: np.ndarray
    x_post: np.ndarray
    cov: KalmanCovariances


# --------------------------------------------------------------------------- validation


def _as_matrix(name: str, value, shape: tuple[int | None, int | None]) -> np.ndarray:
    """Return ``value`` as a finite float64 2-D array of ``shape`` (None = any), or raise."""
    arr = np.asarray(value, dtype=np.float64)
    if arr.ndim != 2:
        raise ValueError(f"{name} must be a 2-D matrix, got an array of shape {arr.shape}")
    for axis, (got, want) in enumerate(zip(arr.shape, shape)):
        if want is not None and got != want:
            raise ValueError(
                f"{name} must have shape {_fmt_shape(shape)}, got {arr.shape} "
                f"(axis {axis} is {got}, expected {want})"
            )
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} contains non-finite values")
    return arr


def _fmt_shape(shape: tuple[int | None, ...]) -> str:
    return "(" + ", ".join("*" if s is None else str(s) for s in shape) + ")"


def _check_symmetric(name: str, arr: np.ndarray) -> None:
    scale = max(1.0, float(np.max(np.abs(arr))))
    if not np.allclose(arr, arr.T, rtol=0.0, atol=1e-10 * scale):
        raise ValueError(f"{name} must be symmetric (a covariance matrix)")


def _validate_system(F, H, Q, R) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    F = _as_matrix("F", F, (None, None))
    n = F.shape[0]
    if F.shape != (n, n):
        raise ValueError(f"F must be square (n, n), got shape {F.shape}")
    H = _as_matrix("H", H, (None, n))
    p = H.shape[0]
    Q = _as_matrix("Q", Q, (n, n))
    R = _as_matrix("R", R, (p, p))
    _check_symmetric("Q", Q)
    _check_symmetric("R", R)
    return F, H, Q, R


# --------------------------------------------------------------------------- recursion


def kalman_covariances(F, H, Q, R, P0, n_steps: int) -> KalmanCovariances:
    """Covariance and gain recursion of the Kalman filter for ``n_steps`` steps.

    Runs the Riccati recursion (Anderson & Moore 1979, eqs. 3.1.9-3.1.12) from
    ``P(0|-1) = P0``: for each k it records ``P(k|k-1)``, computes the gain and the Joseph
    form ``P(k|k)``, then predicts ``P(k+1|k) = F P(k|k) Fᵀ + Q``. It needs no measurements,
    which is why a batch of trials can share it.

    Parameters
    ----------
    F : array_like, shape (n, n)
        State transition matrix.
    H : array_like, shape (p, n)
        Measurement matrix.
    Q : array_like, shape (n, n)
        Process noise covariance (symmetric).
    R : array_like, shape (p, p)
        Measurement noise covariance (symmetric). ``H P Hᵀ + R`` must be invertible.
    P0 : array_like, shape (n, n)
        Prior covariance of x(0), i.e. ``P(0|-1)`` (symmetric).
    n_steps : int
        Number K >= 0 of time steps.

    Returns
    -------
    KalmanCovariances
        ``P_prior`` (K, n, n), ``P_post`` (K, n, n), ``gains`` (K, n, p), float64.

    Raises
    ------
    ValueError
        If a matrix has the wrong shape or is not symmetric (the message names it), or
        ``n_steps`` is not a non-negative integer.
    """
    F, H, Q, R = _validate_system(F, H, Q, R)
    n, p = F.shape[0], H.shape[0]
    P0 = _as_matrix("P0", P0, (n, n))
    _check_symmetric("P0", P0)
    if isinstance(n_steps, bool) or not isinstance(n_steps, numbers.Integral) or n_steps < 0:
        raise ValueError(f"n_steps must be a non-negative integer, got {n_steps!r}")
    n_steps = int(n_steps)

    P_prior = np.empty((n_steps, n, n))
    P_post = np.empty((n_steps, n, n))
    gains = np.empty((n_steps, n, p))
    eye = np.eye(n)
    P = 0.5 * (P0 + P0.T)
    for k in range(n_steps):
        P_prior[k] = P
        PHt = P @ H.T
        S = H @ PHt + R
        # G = P Hᵀ S⁻¹, solved rather than inverted; S is symmetric so Gᵀ = S⁻¹ H P.
        G = np.linalg.solve(S, PHt.T).T
        I_GH = eye - G @ H
        P = I_GH @ P @ I_GH.T + G @ R @ G.T
        P = 0.5 * (P + P.T)
        P_post[k] = P
        gains[k] = G
        P = F @ P @ F.T + Q
        P = 0.5 * (P + P.T)
    return KalmanCovariances(P_prior=P_prior, P_post=P_post, gains=gains)


def kalman_filter_batch(F, H, Q, R, x0, P0, zs) -> KalmanRun:
    """Run the Kalman filter on many independent measurement sequences at once.

    The gains are computed once by :func:`kalman_covariances`; then, for each time step k,
    all trials are updated together. States are row vectors with trials on the leading
    axis, so ``F x`` becomes ``x @ F.T``. The update is written in its affine form::

        x̂(k|k)   = x̂(k|k-1) + G(k) (z(k) - H x̂(k|k-1))      (innovation form)
                  = (I - G(k) H) x̂(k|k-1) + G(k) z(k)         (what is computed)
        x̂(k+1|k) = F x̂(k|k)

    because the term ``G(k) z(k)`` does not depend on the recursion and is computed for all
    steps and trials in a single batched product. There is no Python loop over trials. Per
    trial and step this is filterpy's ``KalmanFilter`` sequence: record ``(x, P)``,
    ``update(z[k])``, ``predict()`` (the two agree to rounding, ~1e-15 relative).

    Parameters
    ----------
    F, H, Q, R, P0 : array_like
        As in :func:`kalman_covariances`.
    x0 : array_like, shape (n,) or (trials, n)
        Prior mean ``x̂(0|-1)``, shared by all trials or one per trial.
    zs : array_like, shape (trials, K, p)
        Measurements: ``zs[t, k]`` is z(k) in trial t. For one trial, pass ``zs[None]``.

    Returns
    -------
    KalmanRun
        ``x_prior`` and ``x_post`` of shape (trials, K, n), and ``cov``. The two mean arrays
        are stored time-major (they are transposed views of (K, trials, n) arrays), so the
        per-step slices ``x_post[:, k]`` used for Monte Carlo statistics are contiguous.

    Raises
    ------
    ValueError
        If any argument has the wrong shape; the message names the argument.
    """
    F, H, Q, R = _validate_system(F, H, Q, R)
    n, p = F.shape[0], H.shape[0]
    zs = np.asarray(zs, dtype=np.float64)
    if zs.ndim != 3 or zs.shape[2] != p:
        raise ValueError(
            f"zs must have shape (trials, K, p) = (*, *, {p}), got {zs.shape}"
            + (" (for a single trial pass zs[None])" if zs.ndim == 2 else "")
        )
    trials, n_steps, _ = zs.shape
    x0 = np.asarray(x0, dtype=np.float64)
    if x0.shape == (n,):
        x0 = np.broadcast_to(x0, (trials, n))
    elif x0.shape != (trials, n):
        raise ValueError(f"x0 must have shape ({n},) or (trials, n) = ({trials}, {n}), got {x0.shape}")

    cov = kalman_covariances(F, H, Q, R, P0, n_steps)

    # Time-major work arrays (K, trials, n): every per-step read and write below is then a
    # contiguous block, and the matrix products run in BLAS. Writing into (trials, K, n)
    # slices instead costs about as much as all the arithmetic together.
    gains_t = np.swapaxes(cov.gains, 1, 2)  # G(k)ᵀ, (K, p, n)
    closed_t = np.swapaxes(np.eye(n) - cov.gains @ H, 1, 2)  # (I - G(k) H)ᵀ, (K, n, n)
    # G(k) z(k) for all k and trials in one batched product; it becomes x̂(k|k) in place.
    x_post_t = np.matmul(np.swapaxes(zs, 0, 1), gains_t)
    x_prior_t = np.empty((n_steps, trials, n))
    if n_steps:
        x_prior_t[0] = x0
    Ft = F.T
    for k in range(n_steps):
        x_post_t[k] += x_prior_t[k] @ closed_t[k]
        if k + 1 < n_steps:
            np.matmul(x_post_t[k], Ft, out=x_prior_t[k + 1])
    # (trials, K, n) views of the time-major arrays: x_prior[:, k] stays contiguous.
    x_prior = np.swapaxes(x_prior_t, 0, 1)
    x_post = np.swapaxes(x_post_t, 0, 1)
    return KalmanRun(x_prior=x_prior, x_post=x_post, cov=cov)


# --------------------------------------------------------------------------- steady state


def steady_state_prior_covariance(F, H, Q, R) -> np.ndarray:
    """Steady-state prior covariance ``P⁻ = lim P(k|k-1)``: the stabilising DARE solution.

    Solves the filtering discrete algebraic Riccati equation (Anderson & Moore 1979, §4.4)::

        P = F P Fᵀ - F P Hᵀ (H P Hᵀ + R)⁻¹ H P Fᵀ + Q

    as ``scipy.linalg.solve_discrete_are(F.T, H.T, Q, R)`` (the control DARE of the dual
    system). A stabilising solution, one that makes ``F (I - G H)`` Schur stable, exists
    when (F, H) is detectable and (F, Q^½) has no unreachable mode on the unit circle;
    then P(k|k-1) converges to it from any P0 ⪰ 0.

    Parameters
    ----------
    F, H, Q, R : array_like
        As in :func:`kalman_covariances`; R must be positive definite.

    Returns
    -------
    ndarray, shape (n, n)
        The symmetric steady-state prior covariance.
    """
    F, H, Q, R = _validate_system(F, H, Q, R)
    P = scipy.linalg.solve_discrete_are(F.T, H.T, Q, R)
    return 0.5 * (P + P.T)


def steady_state_gain(F, H, Q, R) -> np.ndarray:
    """Steady-state Kalman gain ``G = P⁻ Hᵀ (H P⁻ Hᵀ + R)⁻¹``, shape (n, p).

    ``P⁻`` is :func:`steady_state_prior_covariance`. This is the limit of
    ``KalmanCovariances.gains[k]`` (the gain applied to the innovation in the update step,
    not the one-step predictor gain ``F G``).
    """
    F, H, Q, R = _validate_system(F, H, Q, R)
    P = steady_state_prior_covariance(F, H, Q, R)
    S = H @ P @ H.T + R
    return np.linalg.solve(S, H @ P).T


def scalar_random_walk_steady_state(q: float, r_eff: float) -> tuple[float, float]:
    """Closed-form steady state of the scalar random-walk Kalman filter.

    For ``x(k+1) = x(k) + w``, ``y = x + v``, ``Var w = q > 0``, ``Var v = r_eff > 0``, the
    scalar DARE ``P = P r_eff / (P + r_eff) + q`` reduces to ``P² - q P - q r_eff = 0``,
    whose positive root is::

        P⁻ = (q + sqrt(q² + 4 q r_eff)) / 2,      gain = P⁻ / (P⁻ + r_eff).

    With N sensors of noise variance r each, the centralized filter is this filter on the
    mean measurement with ``r_eff = r / N``; its gain is then the gain per mean measurement
    (the sum of the N entries of the (1, N) centralized gain).

    Returns
    -------
    (P_prior, gain) : tuple of float
    """
    q = float(q)
    r_eff = float(r_eff)
    if not (math.isfinite(q) and q > 0):
        raise ValueError(f"q must be a finite positive variance, got {q!r}")
    if not (math.isfinite(r_eff) and r_eff > 0):
        raise ValueError(f"r_eff must be a finite positive variance, got {r_eff!r}")
    P = 0.5 * (q + math.sqrt(q * q + 4.0 * q * r_eff))
    return P, P / (P + r_eff)
