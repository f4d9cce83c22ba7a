"""Gossip interactive Kalman filtering: sensors swap (estimate, covariance) pairs along
random matchings and each updates what it receives with its own observation.

Model::

    x(t+1) = F x(t) + w(t),        w ~ N(0, Q)
    y_n(t) = C_n x(t) + v_n(t),    v_n ~ N(0, R_n),  sensor n = 0..N-1

One slot t (Kar & Moura's GIKF, eqs (8)-(12)): draw a matching A(t) (A(0) = I); every sensor
n takes the *old* state of its partner ->(n, t) (simultaneous swap), updates it with its own
y_n(t), C_n, R_n and predicts. The covariance recursion is

    P_n(t+1) = f_n(P_{->(n,t)}(t)),   f_n(X) = F X Fᵀ + Q − F X C_nᵀ (C_n X C_nᵀ + R_n)⁻¹ C_n X Fᵀ   (11), (12)

computed in Joseph form and symmetrised, which keeps the well-observed directions accurate
when ‖X‖ is huge (the textbook form (11) loses ~eps·‖X‖ there). A sensor with C_n = 0 applies
the Lyapunov map f_0(X) = F X Fᵀ + Q.

Sensors may have different numbers of observation rows m_n: every C_n is padded with zero
rows (and R_n with a unit diagonal block) to the largest m. A zero row with unit noise carries
no information, so the padded filter is exactly the original one.

Everything is batched over independent runs on a leading axis: covariances have shape
(B, N, M, M), partner arrays (B, N). Estimates are not simulated directly: with an unstable F
x(t) grows like |λ|^t and x − x̂ cancels catastrophically, so the error recursion

    e_n(t+1) = F (e_{->(n,t)}(t) − K (C_n e_{->(n,t)}(t) + v_n(t))) + w(t)

is simulated instead, with w(t) common to all sensors.

This module holds the signal model (`GossipSystem`), the maps f_n and f_0 with their first-order
round-off bounds, the square-root form, the covariance features and one GIKF slot; the protocols
are in `gossip_protocols`, the batched runs and their statistics in `gikf_monte_carlo`
(`gossip_kalman` gathers the three).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

__all__ = ["GossipSystem", "riccati_step", "lyapunov_step", "factor_psd", "riccati_sqrt_step", "factor_features", "riccati_roundoff", "eigvalsh",
           "lyapunov_roundoff", "propagate_error", "error_norm",
           "gikf_covariance_step", "gikf_error_step", "covariance_features", "FEATURES", "swap", "EPS"]


def _sym(X: np.ndarray) -> np.ndarray:
    return 0.5 * (X + np.swapaxes(X, -1, -2))


@dataclass(frozen=True)
class GossipSystem:
    """Signal model and sensors. C: (N, m, M) zero-padded; R: (N, m, m)."""

    F: np.ndarray
    Q: np.ndarray
    C: np.ndarray
    R: np.ndarray
    P0: np.ndarray

    @classmethod
    def build(cls, F, Q, C_list: Sequence[np.ndarray], R_list: Sequence[np.ndarray], P0) -> "GossipSystem":
        F, Q, P0 = (np.asarray(a, float) for a in (F, Q, P0))
        M = F.shape[0]
        m = max([1] + [np.atleast_2d(c).shape[0] for c in C_list if np.size(c)])
        N = len(C_list)
        C = np.zeros((N, m, M))
        R = np.tile(np.eye(m), (N, 1, 1))
        for n, (c, r) in enumerate(zip(C_list, R_list)):
            if np.size(c) == 0:
                continue
            c = np.atleast_2d(np.asarray(c, float))
            r = np.atleast_2d(np.asarray(r, float))
            C[n, : c.shape[0]] = c
            R[n, : c.shape[0], : c.shape[0]] = r
        return cls(F, Q, C, R, P0)

    @property
    def N(self) -> int:
        return self.C.shape[0]

    @property
    def M(self) -> int:
        return self.F.shape[0]

    @property
    def C_all(self) -> np.ndarray:
        """Stacked observation matrix of all sensors (centralized filter), (N m, M)."""
        return self.C.reshape(-1, self.M)

    @property
    def R_all(self) -> np.ndarray:
        import scipy.linalg

        return scipy.linalg.block_diag(*self.R)

    @property
    def R_chol(self) -> np.ndarray:
        return np.linalg.cholesky(self.R)


def lyapunov_step(X: np.ndarray, F: np.ndarray, Q: np.ndarray) -> np.ndarray:
    """f_0(X) = F X Fᵀ + Q, eq (70)."""
    return _sym(F @ X @ F.T + Q)


def _gain(X: np.ndarray, C: np.ndarray, R: np.ndarray) -> np.ndarray:
    """K = X Cᵀ (C X Cᵀ + R)⁻¹, batched; (…, M, m)."""
    XCt = X @ np.swapaxes(C, -1, -2)
    S = C @ XCt + R
    if S.shape[-1] == 1:
        return XCt / S[..., 0:1, 0:1].reshape(S.shape[:-2] + (1, 1))
    if S.shape[-1] == 2:
        # 2 x 2 innovation covariance: explicit inverse (S ≻ 0 since R ≻ 0); batched LAPACK solves of
        # tiny systems cost ~0.4 µs each, this a few ns
        a, b, c, d = S[..., 0, 0], S[..., 0, 1], S[..., 1, 0], S[..., 1, 1]
        det = a * d - b * c
        Sinv = np.stack([np.stack([d, -b], -1), np.stack([-c, a], -1)], -2) / det[..., None, None]
        return XCt @ Sinv
    return np.swapaxes(np.linalg.solve(S, np.swapaxes(XCt, -1, -2)), -1, -2)


def riccati_step(X: np.ndarray, C: np.ndarray, R: np.ndarray, F: np.ndarray, Q: np.ndarray,
                 *, return_gain: bool = False):
    """f(X) of eq (11) in Joseph form, batched over leading axes (C, R broadcast against X).

    Returns F P⁺ Fᵀ + Q with P⁺ = (I − K C) X (I − K C)ᵀ + K R Kᵀ, symmetrised. For scalar
    observations (m = 1) the products with C, K and R are outer products done elementwise.
    """
    M = X.shape[-1]
    if C.shape[-2] == 1:
        if use_compiled(math.prod(np.broadcast_shapes(X.shape[:-2], C.shape[:-2], R.shape[:-2])), X, C, R, F, Q):
            return _riccati_scalar_compiled(X, C, R, F, Q, return_gain)
        return _riccati_scalar_obs(X, C, R, F, Q, return_gain)
    K = _gain(X, C, R)
    A = np.eye(M) - K @ C
    Pf = A @ X @ np.swapaxes(A, -1, -2) + K @ R @ np.swapaxes(K, -1, -2)
    out = F @ Pf @ F.T + Q
    out = 0.5 * (out + np.swapaxes(out, -1, -2))
    return (out, K) if return_gain else out


def _riccati_scalar_obs(X, C, R, F, Q, return_gain):
    """The m = 1 case entry by entry: the batch axes stay innermost, so every operation is one
    vectorised pass over the batch (tiny stacked matmuls cost ~50 ns per matrix; this ~15 ns)."""
    M = X.shape[-1]
    Xs = np.moveaxis(X, (-2, -1), (0, 1))
    c = np.moveaxis(C[..., 0, :], -1, 0)
    r = R[..., 0, 0]
    u = [sum(Xs[i, j] * c[j] for j in range(M)) for i in range(M)]
    s = sum(c[i] * u[i] for i in range(M)) + r
    k = [ui / s for ui in u]
    A = [[(1.0 if i == j else 0.0) - k[i] * c[j] for j in range(M)] for i in range(M)]
    AX = [[sum(A[i][l] * Xs[l, j] for l in range(M)) for j in range(M)] for i in range(M)]
    low = {(i, j): sum(AX[i][l] * A[j][l] for l in range(M)) + r * k[i] * k[j] for i in range(M) for j in range(i + 1)}
    Pf = [[low[(i, j)] if j <= i else low[(j, i)] for j in range(M)] for i in range(M)]
    G = [[sum(F[i, l] * Pf[l][j] for l in range(M) if F[i, l] != 0) for j in range(M)] for i in range(M)]
    batch = np.broadcast_shapes(X.shape[:-2], c.shape[1:], np.shape(r))
    out = np.empty(batch + (M, M))
    for i in range(M):
        for j in range(i + 1):
            out[..., i, j] = out[..., j, i] = sum(G[i][l] * F[j, l] for l in range(M) if F[j, l] != 0) + Q[i, j]
    if not return_gain:
        return out
    K = np.empty(batch + (M, 1))
    for i in range(M):
        K[..., i, 0] = k[i]
    return out, K


#: batches of at least this many matrices go to the compiled kernels of `gikf_compiled` (the same bits), once the
#: numpy versions have spent about COMPILE_AFTER_S seconds of CPU in the process: numba costs ~0.5 s of CPU and
#: ~130 MiB of memory to import and load the kernels, which a long Monte Carlo repays in its first seconds, and a
#: small run (`dse run --quick` of a small scenario, a design for `dse check`, a test) never does
COMPILED_MIN_BATCH = 64
COMPILE_AFTER_S = 1.0
_numpy_s = 0.0                      # the estimated CPU seconds the numpy versions have spent in this process
#: what numba and the loaded kernels add to a process's memory (measured: ~100 MiB to import, ~50 MiB to load);
#: a run whose memory budget has no room for it sets `compiled_allowed` to False (kar-moura's `compute`)
COMPILED_MIB = 150.0
compiled_allowed = True


def use_compiled(n: int, *arrays, item_s: float = 1e-7) -> bool:
    """Whether a call on a batch of n matrices (or rows of draws) goes to the compiled kernels: `compiled_allowed`,
    n ≥ COMPILED_MIN_BATCH, all `arrays` float64 (the kernels are compiled for float64 only), and the numpy versions
    have spent COMPILE_AFTER_S in this process (estimated at ~100 µs per call of some 100 numpy passes over the
    batch, plus `item_s` per matrix or row)."""
    global _numpy_s
    if not compiled_allowed or n < COMPILED_MIN_BATCH or any(np.asarray(a).dtype != np.float64 for a in arrays):
        return False
    if _numpy_s >= COMPILE_AFTER_S:
        return True
    _numpy_s += 1e-4 + item_s * n
    return False


def preload_compiled() -> None:
    """Import numba and start its code generator now, and let the kernels start at once: for a run whose Monte
    Carlo repays them anyway, before it forks its workers, which then share them instead of each spending ~0.5 s
    (and its first second in numpy) on its own."""
    global _numpy_s
    from . import gikf_compiled

    gikf_compiled.chain_step(np.ones((1, 1)), np.zeros(1, np.int64), np.zeros(1), np.empty(1, np.int64))
    _numpy_s = max(_numpy_s, COMPILE_AFTER_S)


def _flat(a: np.ndarray, batch: tuple, tail: tuple) -> np.ndarray:
    """`a` broadcast to batch + tail as a C-contiguous, writable (n, *tail) array (a copy only when it must be; numba
    would compile a kernel version of its own for a read-only broadcast view)."""
    a = np.asarray(a)
    if a.shape != batch + tail:
        a = np.broadcast_to(a, batch + tail)
    return np.require(a, requirements="CW").reshape((-1,) + tail)


def _riccati_scalar_compiled(X, C, R, F, Q, return_gain):
    """`_riccati_scalar_obs` by the compiled kernel (the same bits)."""
    from . import gikf_compiled

    M = X.shape[-1]
    batch = np.broadcast_shapes(X.shape[:-2], C.shape[:-2], R.shape[:-2])
    out = np.empty(batch + (M, M))
    K = np.empty(batch + (M, 1))
    gikf_compiled.riccati_scalar_obs(_flat(X, batch, (M, M)), _flat(C[..., 0, :], batch, (M,)),
                                     _flat(R[..., 0, 0], batch, ()), np.require(F, requirements="CW"),
                                     np.require(Q, requirements="CW"), out.reshape(-1, M, M), K.reshape(-1, M),
                                     gikf_compiled.dims(M))
    return (out, K) if return_gain else out


EPS = float(np.finfo(float).eps)


def _fro2(A: np.ndarray) -> np.ndarray:
    return np.einsum("...ij,...ij->...", A, A)


#: state dimension up to which the round-off bounds are computed entry by entry, each entry a vector over the batch:
#: a stacked product of tiny matrices costs ~50 ns per matrix, an entry of the bound a few ns per batch element;
#: from M = 4 on the entry loops (M² m and M³ terms) cost more than the matrix products
ENTRYWISE_MAX_M = 3


def riccati_roundoff(X: np.ndarray, K: np.ndarray, C: np.ndarray, R: np.ndarray, F: np.ndarray,
                     Q: np.ndarray, r_min=None) -> tuple[np.ndarray, np.ndarray]:
    """Round-off of one Joseph-form step f(X) (as computed by `riccati_step`), to first order.

    Returns (delta, G), batched. `delta` bounds the spectral norm of the error the step itself
    commits: γ(‖F‖²(‖A‖²‖X‖ + ‖K‖²‖R‖) + ‖Q‖) with γ = 10·n_ops·eps, A = I − K C and n_ops = 4M + 3m + 4
    the longest chain of products and sums in the step (each product of matrices commits at most
    ~n·eps relative to the product of absolute values, whose norm the Frobenius norms bound), plus
    the effect of the computed gain's error, ‖F‖²‖dK S^½‖² (S = C X Cᵀ + R; large when S is
    ill-conditioned or C X Cᵀ cancels, i.e. when X is huge along a direction C barely sees).
    G = F A is the closed loop: the map's derivative Df(X)[H] = G H Gᵀ carries an earlier error H,
    so an error bound E (−E ⪯ H ⪯ E) propagates as `propagate_error` (G E Gᵀ + delta·I), which follows
    the actual contraction of the composed maps rather than a product of norms.

    The same formula is evaluated entry by entry for M ≤ ENTRYWISE_MAX_M (same bound; the sums of the
    norms may round differently in the last bit)."""
    M, m = F.shape[0], C.shape[-2]
    gamma = 10.0 * (4 * M + 3 * m + 4) * EPS
    # S ⪰ R; r_min = λ_min(R) when the caller has it (a centralized R of 1,000 sensors is constant over the slots)
    s_min = np.maximum(_lambda_min_psd(R) if r_min is None else r_min, np.finfo(float).tiny)
    fF, fQ = float(_fro2(F)), math.sqrt(float(_fro2(Q)))
    if M <= ENTRYWISE_MAX_M and m <= M:
        batch = np.broadcast_shapes(X.shape[:-2], K.shape[:-2], C.shape[:-2], R.shape[:-2], np.shape(s_min))
        if use_compiled(math.prod(batch), X, K, C, R, F, s_min):
            return _roundoff_entries_compiled(X, K, C, R, F, gamma, s_min, fF, fQ)
        return _roundoff_entries(X, K, C, R, F, gamma, s_min, fF, fQ)
    A = np.eye(M) - K @ C
    k2 = _fro2(K)
    scale = fF * (_fro2(A) * np.sqrt(_fro2(X)) + k2 * np.sqrt(_fro2(R))) + fQ
    # the gain: K̂ = K + dK adds exactly F dK S dKᵀ Fᵀ to the Joseph form (P(K) = P(K*) + (K − K*) S (K − K*)ᵀ),
    # with ‖dK S^½‖ ≤ (‖E₁‖ + ‖K‖‖E₂‖)/√λ_min(S) + ‖K‖ γ κ(S) √‖S‖ for the errors E₁ of X Cᵀ and E₂ of S
    aX, aC = np.abs(X), np.abs(C)
    S = C @ X @ np.swapaxes(C, -1, -2) + R
    s_max = np.trace(S, axis1=-2, axis2=-1)                          # ≥ λ_max(S), S ⪰ 0
    aXC = aX @ np.swapaxes(aC, -1, -2)
    E1 = gamma * np.sqrt(_fro2(aXC))
    E2 = gamma * np.sqrt(_fro2(aC @ aXC + np.abs(R)))
    return _roundoff_delta(gamma, scale, fF, E1, E2, np.sqrt(k2), s_min, s_max), F @ A


def _roundoff_delta(gamma, scale, fF, E1, E2, k, s_min, s_max):
    dK = (E1 + k * E2) / np.sqrt(s_min) + k * gamma * (s_max / s_min) * np.sqrt(s_max)
    return gamma * scale + fF * dK * dK


def _entries(A: np.ndarray) -> list[list[np.ndarray]]:
    """The entries A[..., i, j] of a batch of small matrices (views, each a vector over the batch)."""
    return [[A[..., i, j] for j in range(A.shape[-1])] for i in range(A.shape[-2])]


def _sum(terms):
    it = iter(terms)
    acc = next(it)
    for t in it:
        acc = acc + t
    return acc


def _sq(rows) -> np.ndarray:
    """Squared Frobenius norm of a matrix given by its entries."""
    return _sum(a * a for row in rows for a in row)


def _roundoff_entries(X, K, C, R, F, gamma, s_min, fF, fQ):
    """`riccati_roundoff` entry by entry (small M): the same quantities, each a vector over the batch."""
    M, m = F.shape[0], C.shape[-2]
    x, k, c, r = _entries(X), _entries(K), _entries(C), _entries(R)
    A = [[(1.0 if i == j else 0.0) - _sum(k[i][l] * c[l][j] for l in range(m)) for j in range(M)] for i in range(M)]
    k2 = _sq(k)
    scale = fF * (_sq(A) * np.sqrt(_sq(x)) + k2 * np.sqrt(_sq(r))) + fQ
    ax = [[abs(v) for v in row] for row in x]
    ac = [[abs(v) for v in row] for row in c]
    axc = [[_sum(ax[i][j] * ac[a][j] for j in range(M)) for a in range(m)] for i in range(M)]          # |X| |C|ᵀ
    e2 = [[_sum(ac[a][i] * axc[i][b] for i in range(M)) + abs(r[a][b]) for b in range(m)] for a in range(m)]
    xc = [[_sum(x[i][j] * c[a][j] for j in range(M)) for a in range(m)] for i in range(M)]            # X Cᵀ
    s_max = _sum(_sum(c[a][i] * xc[i][a] for i in range(M)) + r[a][a] for a in range(m))             # tr S
    delta = _roundoff_delta(gamma, scale, fF, gamma * np.sqrt(_sq(axc)), gamma * np.sqrt(_sq(e2)), np.sqrt(k2),
                            s_min, s_max)
    G = np.zeros(np.shape(delta) + (M, M))
    for i in np.flatnonzero(np.abs(F).sum(axis=1)):           # G = F A (a zero row of F: a zero row of G)
        for j in range(M):
            G[..., i, j] = _sum(F[i, l] * A[l][j] for l in range(M) if F[i, l] != 0)
    return delta, G


def _roundoff_entries_compiled(X, K, C, R, F, gamma, s_min, fF, fQ):
    """`_roundoff_entries` by the compiled kernel (the same bits)."""
    from . import gikf_compiled

    M, m = F.shape[0], C.shape[-2]
    batch = np.broadcast_shapes(X.shape[:-2], K.shape[:-2], C.shape[:-2], R.shape[:-2], np.shape(s_min))
    delta = np.empty(batch)
    G = np.zeros(batch + (M, M))
    gikf_compiled.roundoff_entries(_flat(X, batch, (M, M)), _flat(K, batch, (M, m)), _flat(C, batch, (m, M)),
                                   _flat(R, batch, (m, m)), np.require(F, requirements="CW"), np.abs(F).sum(axis=1) != 0,
                                   gamma, _flat(np.asarray(s_min, float), batch, ()), float(fF), float(fQ),
                                   delta.reshape(-1), G.reshape(-1, M, M), gikf_compiled.dims(M),
                                   gikf_compiled.dims(m))
    return delta, G


def _lambda_min_psd(R: np.ndarray) -> np.ndarray:
    """λ_min of (batched) symmetric matrices: closed form for 1×1 and 2×2 (the usual sensor sizes)."""
    m = R.shape[-1]
    if m == 1:
        return R[..., 0, 0]
    if m == 2:
        tr, det = R[..., 0, 0] + R[..., 1, 1], R[..., 0, 0] * R[..., 1, 1] - R[..., 0, 1] * R[..., 1, 0]
        return 0.5 * (tr - np.sqrt(np.maximum(tr * tr - 4 * det, 0.0)))
    return np.linalg.eigvalsh(R)[..., 0]


#: LAPACK scales a matrix whose largest entry is beyond these (dsyevd, dsterf) before its 2×2 formulas
_EIG2_RANGE = (1e-120, 1e145)


def eigvalsh(X: np.ndarray) -> np.ndarray:
    """`np.linalg.eigvalsh` (ascending eigenvalues of symmetric matrices, lower triangle), with batches of 2×2
    matrices in closed form: LAPACK's own arithmetic for them (dsyevd → dsterf: the split test on the
    off-diagonal, then dlae2), the same values bit for bit at ~1/5 of the cost of a batched LAPACK call
    (the tests compare them on millions of matrices). Matrices LAPACK would first rescale (entries beyond
    _EIG2_RANGE, or not finite) go to LAPACK."""
    X = np.asarray(X, float)
    if X.shape[-1] != 2 or X.ndim < 3:
        return np.linalg.eigvalsh(X)
    if use_compiled(math.prod(X.shape[:-2])):
        from . import gikf_compiled

        batch = X.shape[:-2]
        out, far = np.empty(batch + (2,)), np.zeros(batch, bool)
        gikf_compiled.eigvalsh2(_flat(X, batch, (2, 2)), out.reshape(-1, 2), far.reshape(-1), *_EIG2_RANGE)
        if far.any():
            out[far] = np.linalg.eigvalsh(X[far])
        return out
    a, b, c = X[..., 0, 0], X[..., 1, 0], X[..., 1, 1]
    eps = 0.5 * EPS                                                   # LAPACK's dlamch('E')
    with np.errstate(divide="ignore", invalid="ignore", over="ignore", under="ignore"):
        sm, adf, ab = a + c, np.abs(a - c), np.abs(b + b)
        big = np.abs(a) > np.abs(c)
        acmx, acmn = np.where(big, a, c), np.where(big, c, a)
        rt = np.where(adf > ab, adf * np.sqrt(1.0 + (ab / adf) ** 2),
                      np.where(adf < ab, ab * np.sqrt(1.0 + (adf / ab) ** 2), ab * np.sqrt(2.0)))
        rt1 = np.where(sm < 0, 0.5 * (sm - rt), 0.5 * (sm + rt))
        rt2 = np.where(sm == 0, -0.5 * rt, (acmx / rt1) * acmn - (b / rt1) * b)
        split = ((np.abs(b) <= np.sqrt(np.abs(a)) * np.sqrt(np.abs(c)) * eps)
                 | (b * b <= (eps * eps * np.abs(a)) * np.abs(c)))
    out = np.empty(X.shape[:-1])
    out[..., 0] = np.where(split, np.minimum(a, c), np.minimum(rt1, rt2))
    out[..., 1] = np.where(split, np.maximum(a, c), np.maximum(rt1, rt2))
    size = np.abs(X).max(axis=(-2, -1))
    far = ~((size <= _EIG2_RANGE[1]) & ((size >= _EIG2_RANGE[0]) | (size == 0)))
    if far.any():
        out[far] = np.linalg.eigvalsh(X[far])
    return out


def lyapunov_roundoff(X: np.ndarray, F: np.ndarray, Q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """`riccati_roundoff` for f_0(X) = F X Fᵀ + Q: (10·(2M+2)·eps·(‖F‖²‖X‖ + ‖Q‖), F)."""
    M = F.shape[0]
    return 10.0 * (2 * M + 2) * EPS * (_fro2(F) * np.sqrt(_fro2(X)) + np.sqrt(_fro2(Q))), F


def propagate_error(E: np.ndarray, G: np.ndarray, delta) -> np.ndarray:
    """The error bound after one step: G E Gᵀ + delta·I (E: (…, M, M), a PSD bound −E ⪯ H ⪯ E of the error H);
    entry by entry for M ≤ ENTRYWISE_MAX_M (lower triangle, mirrored: exactly symmetric)."""
    M = E.shape[-1]
    delta = np.asarray(delta)
    if M > ENTRYWISE_MAX_M:
        return G @ E @ np.swapaxes(G, -1, -2) + delta[..., None, None] * np.eye(M)
    if use_compiled(math.prod(np.broadcast_shapes(E.shape[:-2], G.shape[:-2], delta.shape)), E, G, delta):
        from . import gikf_compiled

        out = np.empty(np.broadcast_shapes(E.shape, G.shape, delta.shape + (1, 1)))
        batch = out.shape[:-2]
        gikf_compiled.propagate_error(_flat(E, batch, (M, M)), _flat(G, batch, (M, M)), _flat(delta, batch, ()),
                                      out.reshape(-1, M, M), gikf_compiled.dims(M))
        return out
    e, g = _entries(E), _entries(G)
    ge = [[_sum(g[i][j] * e[j][l] for j in range(M)) for l in range(M)] for i in range(M)]
    out = np.empty(np.broadcast_shapes(E.shape, G.shape, delta.shape + (1, 1)))
    for i in range(M):
        for j in range(i + 1):
            v = _sum(ge[i][l] * g[j][l] for l in range(M))
            out[..., i, j] = out[..., j, i] = v + delta if i == j else v
    return out


def error_norm(E: np.ndarray) -> np.ndarray:
    """‖H‖ ≤ λ_max(E) ≤ tr E for any −E ⪯ H ⪯ E (E ⪰ 0; the trace is cheap and at most M times larger);
    inf where the bound itself left float64."""
    tr = np.trace(E, axis1=-2, axis2=-1)
    return np.where(np.isfinite(tr), tr, np.inf)


def factor_psd(X: np.ndarray) -> np.ndarray:
    """A factor S with S Sᵀ = X for (batched) PSD X: V diag(√λ) from the eigendecomposition, so that
    singular X (e.g. X = 0) needs no special case."""
    lam, V = np.linalg.eigh(_sym(np.asarray(X, float)))
    return V * np.sqrt(np.maximum(lam, 0.0))[..., None, :]


def riccati_sqrt_step(S: np.ndarray, C: np.ndarray, R_half: np.ndarray, F: np.ndarray, Q_half: np.ndarray) -> np.ndarray:
    """f in square-root (array) form: given S with X = S Sᵀ, a factor S' with S' S'ᵀ = f(X), batched.

    The pre-array [[R^½, C S, 0], [0, F S, Q^½]] is triangularised by an orthogonal transformation
    (QR of its transpose); the lower-triangular result [[R_e^½, 0], [K̄, S']] has R_e^½ R_e^½ᵀ = C X Cᵀ + R
    and S' S'ᵀ = F X Fᵀ + Q − K̄ K̄ᵀ = f(X). The innovation variance is a sum of squares, never a
    difference, and the transformation is backward stable, so the factor stays accurate (and finite)
    for ‖X‖ far beyond the range where the Joseph form loses the well-observed directions."""
    m, M = C.shape[-2], F.shape[0]
    batch = np.broadcast_shapes(S.shape[:-2], C.shape[:-2], R_half.shape[:-2])
    pre = np.zeros(batch + (m + M, m + 2 * M))
    pre[..., :m, :m] = R_half
    pre[..., :m, m:m + M] = C @ S
    pre[..., m:, m:m + M] = F @ S
    pre[..., m:, m + M:] = Q_half
    r = np.linalg.qr(np.swapaxes(pre, -1, -2), mode="r")
    return np.swapaxes(r, -1, -2)[..., m:, m:]


def riccati_textbook(X, C, R, F, Q):
    """Eq (11) as printed (short form); used only to show its round-off for huge X."""
    XCt = X @ np.swapaxes(C, -1, -2)
    S = C @ XCt + R
    return F @ X @ F.T + Q - F @ XCt @ np.linalg.solve(S, np.swapaxes(XCt, -1, -2)) @ F.T


# -- one GIKF slot ----------------------------------------------------------------------------------

def swap(arr: np.ndarray, partners: np.ndarray) -> np.ndarray:
    """Simultaneous swap: sensor n receives the old entry of partners[b, n]. arr: (B, N, ...)."""
    return arr[np.arange(arr.shape[0])[:, None], partners]


def gikf_covariance_step(P: np.ndarray, partners: np.ndarray, sys: GossipSystem, *, return_gain: bool = False):
    """P (B, N, M, M) = P̂_n(t) → P̂_n(t+1) = f_n(P̂_{->(n,t)}(t)), eq (12)."""
    return riccati_step(swap(P, partners), sys.C, sys.R, sys.F, sys.Q, return_gain=return_gain)


def gikf_error_step(e: np.ndarray, partners: np.ndarray, K: np.ndarray, sys: GossipSystem,
                    w: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Error recursion: e (B, N, M), K (B, N, M, m) from the swapped covariance, w (B, M) common,
    v (B, N, m) per sensor (already scaled by R_n^½)."""
    ein = swap(e, partners)
    innov = np.einsum("nim,bnm->bni", sys.C, ein) + v
    ef = ein - np.einsum("bnmi,bni->bnm", K, innov)
    return ef @ sys.F.T + w[:, None, :]


# -- scalar functionals of covariance matrices --------------------------------------------------------

FEATURES = ("log_trace", "log_lam_max", "log_lam_min", "log_det")


def covariance_features(P: np.ndarray) -> np.ndarray:
    """(len(FEATURES) + M, …): log tr, log λmax, log λmin, log det, then the diagonal entries (logs of
    values below the smallest positive float, a zero P0, are taken at that float)."""
    eig = eigvalsh(P)
    tiny = np.finfo(float).tiny
    diag = np.moveaxis(np.diagonal(P, axis1=-2, axis2=-1), -1, 0)
    return np.concatenate([np.stack([np.log(np.maximum(np.trace(P, axis1=-2, axis2=-1), tiny)),
                                     np.log(np.maximum(eig[..., -1], tiny)),
                                     np.log(np.maximum(eig[..., 0], tiny)),
                                     np.log(np.maximum(eig, tiny)).sum(-1)]), diag])


def factor_features(S: np.ndarray) -> np.ndarray:
    """`covariance_features` of X = S Sᵀ computed from the factor: eigenvalues are the squared
    singular values of S, the trace its squared Frobenius norm and the diagonal its squared row
    norms, so the small eigenvalues stay accurate when ‖X‖ is far beyond 1/eps."""
    sv = np.linalg.svd(S, compute_uv=False)
    tiny = np.finfo(float).tiny
    lam = np.maximum(sv * sv, tiny)
    rows = np.square(S).sum(axis=-1)
    return np.concatenate([np.stack([np.log(rows.sum(-1)), np.log(lam[..., 0]), np.log(lam[..., -1]),
                                     np.log(lam).sum(-1)]), np.moveaxis(rows, -1, 0)])
