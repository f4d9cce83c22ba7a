"""GIKF recursions carried with the first-order bound of their round-off (`riccati_roundoff`,
`propagate_error`), and Loewner comparisons that add those bounds: the centralized filter, the
Lyapunov envelope f_0^t(P0) (eq (73)) carried rescaled, compositions of the maps f_n, and the
relative Loewner margin λ_min(upper − lower) of two batches of matrices.
"""
from __future__ import annotations

import math

import numpy as np

from .gikf_maps import (EPS, GossipSystem, eigvalsh, error_norm, lyapunov_roundoff, lyapunov_step, propagate_error,
                        riccati_roundoff, riccati_step)
from .kalman import kalman_covariances

__all__ = ["centralized_filter", "lyapunov_envelope", "compose_with_error", "loewner_slack", "fro", "spectral_norm"]


def centralized_filter(F, C, Q, R, P0, steps: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Prior covariances, update gains and the first-order round-off bound of a centralized filter
    (Joseph form, `riccati_roundoff` carried along the recursion)."""
    cov = kalman_covariances(F, C, Q, R, P0, steps)
    E = np.zeros_like(cov.P_prior)
    r_min = float(np.linalg.eigvalsh(R)[0])
    for t in range(steps - 1):
        delta, G = riccati_roundoff(cov.P_prior[t], cov.gains[t], C, R, F, Q, r_min=r_min)
        E[t + 1] = propagate_error(E[t], G, delta)
    return cov.P_prior, cov.gains, error_norm(E)


def lyapunov_envelope(F: np.ndarray, Q: np.ndarray, P0: np.ndarray, slots: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """f_0^t(P0), t = 0..slots (eq (73)), rescaled: (log s_t, E_t, e_t) with f_0^t(P0) = s_t E_t, ‖E_t‖ = 1
    (or E_t = 0 when P0 = 0 at t = 0), and e_t a bound of the round-off of E_t (relative to s_t). The scaled
    recursion E' = (F E Fᵀ + Q/s_t)/‖·‖ stays finite over any horizon, however fast F grows."""
    M = F.shape[0]
    logs, units, errs = np.empty(slots + 1), np.empty((slots + 1, M, M)), np.empty(slots + 1)
    n0 = float(np.linalg.norm(P0, 2))
    logs[0], units[0] = (math.log(n0), P0 / n0) if n0 > 0 else (0.0, np.zeros((M, M)))
    # the rescaling rounds too: each division by the norm (eps relative), and exp(log s_t) carries the rounding of
    # log s_t, eps·|log s_t| relative
    E_err = EPS * np.eye(M)
    errs[0] = float(error_norm(E_err)) + M * EPS * (2 + abs(logs[0]))
    for t in range(slots):
        Qs = math.exp(-logs[t]) * Q
        delta, G = lyapunov_roundoff(units[t], F, Qs)
        Y = lyapunov_step(units[t], F, Qs)
        norm = float(np.linalg.norm(Y, 2))
        E_err = propagate_error(E_err, G, delta) / norm + EPS * np.eye(M)
        logs[t + 1], units[t + 1] = logs[t] + math.log(norm), Y / norm
        errs[t + 1] = float(error_norm(E_err)) + M * EPS * (2 + abs(logs[t + 1]))
    return logs, units, errs


def fro(X: np.ndarray) -> np.ndarray:
    """Frobenius norms of a batch of matrices."""
    return np.sqrt(np.square(X).sum(axis=(-2, -1)))


def spectral_norm(X: np.ndarray) -> np.ndarray:
    """Spectral norm of symmetric matrices (largest |eigenvalue|, cheaper than an SVD)."""
    return np.abs(eigvalsh(X)[..., [0, -1]]).max(axis=-1)


def loewner_slack(lower: np.ndarray, upper: np.ndarray, tol) -> tuple[np.ndarray, np.ndarray]:
    """(λ_min(upper − lower) + tol, λ_min(upper − lower)), both over max(1, ‖lower‖_F, ‖upper‖_F) (a positive
    normaliser for reading the numbers; the sign, hence the verdict, does not depend on it)."""
    scale = np.maximum(1.0, np.maximum(fro(lower), fro(upper)))
    lam = eigvalsh(upper - lower)[..., 0]
    return (lam + tol) / scale, lam / scale


def compose_with_error(sys_: GossipSystem, X: np.ndarray, seq, err0) -> tuple[np.ndarray, np.ndarray]:
    """g(X) = f_{seq[-1]} ∘ … ∘ f_{seq[0]}(X) for a batch X (B, M, M), with the first-order bound E of its
    round-off (−E ⪯ error ⪯ E; `riccati_roundoff`, `propagate_error`). err0: the input's bound, either a
    norm per batch entry (B,) or scalar, or a matrix bound (B, M, M)."""
    E = np.asarray(err0, float)
    if E.ndim != X.ndim:
        E = np.broadcast_to(E, X.shape[:-2])[..., None, None] * np.eye(X.shape[-1])
    E = np.broadcast_to(E, X.shape).copy()
    for n in seq:
        n = np.asarray(n)
        C, R = sys_.C[n], sys_.R[n]
        Y, K = riccati_step(X, C, R, sys_.F, sys_.Q, return_gain=True)
        delta, G = riccati_roundoff(X, K, C, R, sys_.F, sys_.Q)
        X, E = Y, propagate_error(E, G, delta)
    return X, E
