"""Loewner comparisons of computed covariances with their round-off allowances: the relative margin
λ_min(upper − lower) of two batches of matrices, and compositions of the maps f_n carried with the
first-order bound of their round-off (`riccati_roundoff`, `propagate_error`).
"""
from __future__ import annotations

import numpy as np

from dse.estimators.gikf_maps import GossipSystem, eigvalsh, error_norm, propagate_error, riccati_roundoff, riccati_step

ROUNDOFF_SENTENCE = ("Round-off allowance: the first-order bound e(t+1) = ‖FA‖²e(t) + 10·(4M+3m+4)·eps·(‖F‖²(‖A‖²‖X‖ + "
                     "‖K‖²‖R‖) + ‖Q‖) of every Joseph-form step (A = I − KC; Frobenius norms), carried along each computed "
                     "matrix and added for both sides of the comparison.")


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


enorm = error_norm
