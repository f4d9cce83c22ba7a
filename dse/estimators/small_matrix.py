"""Small matrices stacked over many trials and nodes, with the matrix indices leading.

An array of shape (r, c, *batch) holds one r x c matrix per batch entry; `a[i, j]` is the
(i, j) entry of every matrix at once, a contiguous array over the batch. For the tiny
matrices of state estimation (a few states, one or two measurement rows) entry-by-entry
arithmetic on these contiguous slices is several times faster than numpy's stacked linear
algebra, which pays a fixed cost per matrix (measured: 50,000 inverses of 4 x 4 matrices
take ~45 ms with `numpy.linalg.inv`, ~4 ms here).

The batch axes broadcast: a matrix shared by all trials has batch shape (N, 1) against
(N, B) for one matrix per node and trial. Constant matrices (F, Q) are plain (r, c) arrays.
"""
from __future__ import annotations

import numpy as np

__all__ = ["pack", "unpack", "matmul", "transpose", "const_left", "const_sandwich", "sandwich", "cholesky", "spd_inverse",
           "spd_solve", "symmetrize", "trace", "quad_form", "matvec", "to_batched", "from_batched", "identity"]


def to_batched(a: np.ndarray) -> np.ndarray:
    """(*batch, r, c) -> (r, c, *batch)."""
    return np.moveaxis(np.moveaxis(a, -2, 0), -1, 1)


def from_batched(a: np.ndarray) -> np.ndarray:
    """(r, c, *batch) -> (*batch, r, c)."""
    return np.moveaxis(np.moveaxis(a, 0, -1), 0, -1)


def identity(n: int, batch_ndim: int) -> np.ndarray:
    return np.eye(n).reshape((n, n) + (1,) * batch_ndim)


def _triu(n: int):
    return np.triu_indices(n)


def pack(X: np.ndarray) -> np.ndarray:
    """The upper triangle of stacked symmetric matrices (n, n, *b) -> (n(n+1)/2, *b)."""
    i, j = _triu(X.shape[0])
    return X[i, j]


def unpack(p: np.ndarray, n: int) -> np.ndarray:
    """Inverse of `pack`: (n(n+1)/2, *b) -> (n, n, *b), exactly symmetric."""
    i, j = _triu(n)
    out = np.empty((n, n) + p.shape[1:])
    out[i, j] = p
    out[j, i] = p
    return out


def transpose(a: np.ndarray) -> np.ndarray:
    return np.swapaxes(a, 0, 1)


def matmul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(r, k, *b1) @ (k, c, *b2) -> (r, c, *broadcast(b1, b2)), entry by entry."""
    r, k = a.shape[:2]
    c = b.shape[1]
    batch = np.broadcast_shapes(a.shape[2:], b.shape[2:])
    out = np.empty((r, c) + batch)
    for i in range(r):
        for j in range(c):
            acc = a[i, 0] * b[0, j]
            for l in range(1, k):
                acc = acc + a[i, l] * b[l, j]
            out[i, j] = acc
    return out


def matvec(a: np.ndarray, x: np.ndarray) -> np.ndarray:
    """(r, k, *b1) applied to vectors (k, *b2) -> (r, *broadcast)."""
    r, k = a.shape[:2]
    return np.stack([sum(a[i, l] * x[l] for l in range(k)) for i in range(r)])


def const_left(F: np.ndarray, x: np.ndarray) -> np.ndarray:
    """A constant (r, k) matrix times (k, ...) stacked matrices or vectors: one BLAS product."""
    return np.tensordot(F, x, axes=(1, 0))


def const_sandwich(F: np.ndarray, X: np.ndarray) -> np.ndarray:
    """F X Fᵀ for a constant F and stacked X (n, n, *batch), exactly symmetric."""
    Y = np.tensordot(F, X, axes=(1, 0))                     # (r, n, *b)
    Z = np.moveaxis(np.tensordot(F, Y, axes=(1, 1)), 0, 1)  # (r, r, *b): Z[i, j] = Σ_l F[j, l] Y[i, l]
    return symmetrize(Z)


def sandwich(A: np.ndarray, X: np.ndarray) -> np.ndarray:
    """A X Aᵀ for stacked A and X, exactly symmetric."""
    return symmetrize(matmul(matmul(A, X), transpose(A)))


def symmetrize(X: np.ndarray) -> np.ndarray:
    return 0.5 * (X + transpose(X))


def trace(X: np.ndarray) -> np.ndarray:
    return sum(X[i, i] for i in range(X.shape[0]))


def quad_form(X: np.ndarray, v: np.ndarray) -> np.ndarray:
    """vᵀ X v for stacked X (n, n, *b) and vectors v (n, *b)."""
    n = X.shape[0]
    return sum(v[i] * X[i, j] * v[j] for i in range(n) for j in range(n))


def cholesky(A: np.ndarray) -> np.ndarray:
    """Lower-triangular L with L Lᵀ = A for stacked symmetric positive definite A.

    A matrix that is not positive definite gives NaN entries (no exception: the caller decides
    what a non-definite covariance means, e.g. a diverged filter)."""
    n = A.shape[0]
    L = np.zeros(A.shape)
    with np.errstate(invalid="ignore", divide="ignore"):
        for j in range(n):
            d = A[j, j] - sum(L[j, l] * L[j, l] for l in range(j))
            L[j, j] = np.sqrt(np.where(d > 0, d, np.nan))
            for i in range(j + 1, n):
                L[i, j] = (A[i, j] - sum(L[i, l] * L[j, l] for l in range(j))) / L[j, j]
    return L


def _lower_inverse(L: np.ndarray) -> np.ndarray:
    n = L.shape[0]
    M = np.zeros(L.shape)
    for i in range(n):
        M[i, i] = 1.0 / L[i, i]
        for j in range(i):
            M[i, j] = -sum(L[i, l] * M[l, j] for l in range(j, i)) / L[i, i]
    return M


def spd_inverse(A: np.ndarray) -> np.ndarray:
    """Inverse of stacked symmetric positive definite matrices through their Cholesky factor
    (A⁻¹ = L⁻ᵀ L⁻¹), exactly symmetric."""
    n = A.shape[0]
    if n == 1:
        return 1.0 / A
    M = _lower_inverse(cholesky(A))
    out = np.empty(np.broadcast_shapes(A.shape, M.shape))
    for i in range(n):
        for j in range(i + 1):
            out[i, j] = out[j, i] = sum(M[l, i] * M[l, j] for l in range(i, n))
    return out


def spd_solve(A: np.ndarray, b: np.ndarray) -> np.ndarray:
    """A⁻¹ b for stacked SPD A (n, n, *b1) and b (n, k, *b2), by forward and back substitution."""
    n = A.shape[0]
    L = cholesky(A)
    k = b.shape[1]
    batch = np.broadcast_shapes(A.shape[2:], b.shape[2:])
    y = np.empty((n, k) + batch)
    for i in range(n):
        y[i] = (b[i] - sum(L[i, l] * y[l] for l in range(i))) / L[i, i]
    x = np.empty_like(y)
    for i in reversed(range(n)):
        x[i] = (y[i] - sum(L[l, i] * x[l] for l in range(i + 1, n))) / L[i, i]
    return x
