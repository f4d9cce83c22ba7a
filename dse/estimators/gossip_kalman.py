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
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

__all__ = ["GossipSystem", "MatchingDistribution", "SingleEdgeGossip", "MatchingSequence", "NodeInitiatedGossip",
           "GreedyMatchingGossip", "matching_at", "riccati_step",
           "lyapunov_step", "factor_psd", "riccati_sqrt_step", "factor_features", "riccati_roundoff", "eigvalsh",
           "lyapunov_roundoff", "propagate_error", "error_norm",
           "gikf_covariance_step", "gikf_error_step", "covariance_features", "FEATURES"]


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


# -- gossip protocols ------------------------------------------------------------------------------

@dataclass(frozen=True)
class MatchingDistribution:
    """A finite distribution over matchings; with the remaining probability, no communication.

    partners: (K, N) int, partners[k, n] = partner of n in matching k (n itself if unmatched).
    probs: (K,) with sum ≤ 1. Single-edge gossip is the case where every matching is one edge.
    """

    partners: np.ndarray
    probs: np.ndarray
    label: str = "matchings"

    @classmethod
    def from_matchings(cls, n: int, matchings: Sequence[Sequence[tuple[int, int]]], probs: Sequence[float],
                       label: str = "matchings") -> "MatchingDistribution":
        table = np.tile(np.arange(n), (len(matchings), 1))
        for k, mt in enumerate(matchings):
            for i, j in mt:
                table[k, i], table[k, j] = j, i
        return cls(table, np.asarray(probs, float), label)

    @classmethod
    def single_edge(cls, n: int, edges: Sequence[tuple[int, int]], probs: Sequence[float]) -> "MatchingDistribution":
        return cls.from_matchings(n, [[e] for e in edges], probs, label="single-edge")

    @property
    def n(self) -> int:
        return self.partners.shape[1]

    def mean_matrix(self) -> np.ndarray:
        """Ā = E[A(t)] = Σ_k p_k Π_k + (1 − Σ p) I, eq (6)."""
        n = self.n
        Abar = (1.0 - self.probs.sum()) * np.eye(n)
        for p, row in zip(self.probs, self.partners):
            Abar[np.arange(n), row] += p
        return Abar

    def sample(self, size: int, rng: np.random.Generator) -> np.ndarray:
        """(size, N) partner arrays of i.i.d. matchings."""
        cum = np.cumsum(self.probs)
        k = np.searchsorted(cum, rng.random(size), side="right")
        table = np.vstack([self.partners, np.arange(self.n)[None]])
        return table[k]


@dataclass(frozen=True)
class SingleEdgeGossip:
    """Each edge is the slot's only swap with probability `edge_prob` (E·edge_prob ≤ 1; else no
    communication). The same draws as `MatchingDistribution.single_edge`, without its (E, N) table
    of partner arrays (a complete graph of 1,000 nodes has 499,500 edges)."""

    n_nodes: int
    edges: tuple[tuple[int, int], ...]
    edge_prob: float
    label: str = "single-edge"

    @property
    def n(self) -> int:
        return self.n_nodes

    @property
    def probs(self) -> np.ndarray:
        return np.full(len(self.edges), self.edge_prob)

    def mean_matrix(self) -> np.ndarray:
        """Ā = I − p Σ_(u,v) (e_u − e_v)(e_u − e_v)ᵀ, eq (6)."""
        e = np.asarray(self.edges, dtype=np.int64).reshape(-1, 2)
        A = np.eye(self.n_nodes)
        np.add.at(A, (e[:, 0], e[:, 0]), -self.edge_prob)
        np.add.at(A, (e[:, 1], e[:, 1]), -self.edge_prob)
        A[e[:, 0], e[:, 1]] += self.edge_prob
        A[e[:, 1], e[:, 0]] += self.edge_prob
        return A

    def sample(self, size: int, rng: np.random.Generator) -> np.ndarray:
        """(size, N) partner arrays."""
        e = np.asarray(self.edges, dtype=np.int64).reshape(-1, 2)
        k = np.searchsorted(np.cumsum(self.probs), rng.random(size), side="right")
        out = np.tile(np.arange(self.n_nodes), (size, 1))
        rows = np.flatnonzero(k < len(e))
        u, v = e[k[rows], 0], e[k[rows], 1]
        out[rows, u] = v
        out[rows, v] = u
        return out


@dataclass(frozen=True)
class MatchingSequence:
    """A given matching for each slot t = 1, 2, ... (repeated cyclically), the same in every run:
    a replayed protocol or trace. Nothing is random, so the theorems' i.i.d. protocol does not
    apply; `mean_matrix` is the average of A(t) over one cycle (the empirical law of the matchings).
    partners: (L, N), partners[k, n] = partner of n in slot k + 1."""

    partners: np.ndarray
    label: str = "sequence"

    @classmethod
    def from_matchings(cls, n: int, matchings: Sequence[Sequence[tuple[int, int]]]) -> "MatchingSequence":
        return cls(MatchingDistribution.from_matchings(n, matchings, [0.0] * len(matchings)).partners)

    @property
    def n(self) -> int:
        return self.partners.shape[1]

    def mean_matrix(self) -> np.ndarray:
        L, n = self.partners.shape
        A = np.zeros((n, n))
        for row in self.partners:
            A[np.arange(n), row] += 1.0 / L
        return A

    def at(self, t: int, size: int) -> np.ndarray:
        """(size, N) partner arrays of slot t ≥ 1."""
        return np.broadcast_to(self.partners[(t - 1) % len(self.partners)], (size, self.n)).copy()


def matching_at(protocol, t: int, size: int, rng: np.random.Generator) -> np.ndarray:
    """The partners of the step from slot t to t + 1 for `size` runs: A(0) = I, then a fresh draw
    of a random protocol (or the given matching of a sequence)."""
    if t == 0:
        return np.tile(np.arange(protocol.n), (size, 1))
    if isinstance(protocol, MatchingSequence):
        return protocol.at(t, size)
    return protocol.sample(size, rng)


@dataclass(frozen=True)
class NodeInitiatedGossip:
    """A uniformly random node wakes up and swaps with a uniformly random neighbour."""

    neighbours: tuple[tuple[int, ...], ...]
    label: str = "node-initiated"

    @property
    def n(self) -> int:
        return len(self.neighbours)

    def mean_matrix(self) -> np.ndarray:
        """Ā_ij = (1/N)(1/d_i + 1/d_j) on edges, rows summing to 1."""
        n = self.n
        Abar = np.zeros((n, n))
        for i, nb in enumerate(self.neighbours):
            for j in nb:
                Abar[i, j] += 1.0 / (n * len(nb))
                Abar[j, i] += 1.0 / (n * len(nb))
        Abar[np.diag_indices(n)] = 1.0 - Abar.sum(axis=1)
        return Abar

    def sample(self, size: int, rng: np.random.Generator) -> np.ndarray:
        n = self.n
        deg = np.array([len(nb) for nb in self.neighbours])
        table = np.full((n, max(deg.max(), 1)), -1)
        for i, nb in enumerate(self.neighbours):
            table[i, : len(nb)] = nb
        i = rng.integers(0, n, size)
        j = table[i, np.minimum((rng.random(size) * deg[i]).astype(np.int64), deg[i] - 1)]
        out = np.tile(np.arange(n), (size, 1))
        rows = np.arange(size)
        ok = j >= 0
        out[rows[ok], i[ok]] = j[ok]
        out[rows[ok], j[ok]] = i[ok]
        return out


@dataclass(frozen=True)
class GreedyMatchingGossip:
    """Random greedy maximal matching with link failures (protocol P4 of our scenarios;
    graph-matching style [6]): every edge gets an i.i.d. U(0, 1) priority, the edges are scanned in priority order
    and an edge is added when both its endpoints are still free; then every chosen edge is kept
    independently with probability p_link (the others fail: their endpoints stay unmatched).

    Ā = E[A(t)] (eq (6)) has no closed form. `exact_mean_matrix` computes it exactly for small
    graphs from the recursion "the lowest-priority remaining edge is uniform among the remaining
    edges; delete its endpoints; the rest is again a uniform order" (components are independent);
    `estimate_mean_matrix` is the Monte Carlo estimate with its standard error. For larger graphs
    drive the Theorem-8 chain by an independent copy of the protocol instead (sampler S3),
    which needs no Ā at all.
    """

    n_nodes: int
    edges: tuple[tuple[int, int], ...]
    p_link: float
    label: str = "greedy-matching"

    def __post_init__(self):
        if not 0.0 < self.p_link <= 1.0:
            raise ValueError(f"p_link must be in (0, 1], got {self.p_link}")
        if not self.edges:
            raise ValueError("the graph has no edges")

    @property
    def n(self) -> int:
        return self.n_nodes

    @property
    def _ends(self) -> tuple[np.ndarray, np.ndarray]:
        e = np.asarray(self.edges, dtype=np.int64)
        return e[:, 0], e[:, 1]

    def greedy_chosen(self, priority: np.ndarray) -> np.ndarray:
        """(B, E) bool: the greedy maximal matching for each row of priorities (B, E): the edges
        are scanned in increasing priority and added when both endpoints are free.

        The scan is a loop over the E positions of the order, vectorised over the batch: the flat
        indices of both endpoints of the k-th edge of every row are precomputed, so each position
        costs two gathers and two scatters of the free flags (the indices of one position are
        distinct, so the scatters need no masking: an endpoint that was free stays free iff the other
        endpoint was already taken)."""
        B, E = priority.shape
        N = self.n_nodes
        u, v = self._ends
        order = np.ascontiguousarray(np.argsort(priority, axis=1).T)   # (E, B): k-th edge of every row
        base = np.arange(B) * N
        fa = u[order] + base                                       # flat (row, endpoint) indices
        fb = v[order] + base
        free = np.ones(B * N, bool)
        taken = np.empty((E, B), bool)
        for k in range(E):
            a, b = fa[k], fb[k]
            ga, gb = free[a], free[b]
            ok = ga & gb
            free[a] = ga & ~gb
            free[b] = gb & ~ga
            taken[k] = ok
        chosen = np.empty((B, E), bool)
        chosen[np.arange(B)[None, :], order] = taken
        return chosen

    def sample(self, size: int, rng: np.random.Generator) -> np.ndarray:
        """(size, N) partner arrays of i.i.d. matchings."""
        E = len(self.edges)
        chosen = self.greedy_chosen(rng.random((size, E)))
        b, k = np.nonzero(chosen)
        if self.p_link < 1.0:  # each chosen link works independently with probability p_link
            works = rng.random(len(b)) < self.p_link
            b, k = b[works], k[works]
        u, v = self._ends
        out = np.tile(np.arange(self.n_nodes), (size, 1))
        out[b, u[k]] = v[k]
        out[b, v[k]] = u[k]
        return out

    # -- exact law (small graphs) -----------------------------------------------------------------

    def _components(self, remaining: frozenset) -> list[frozenset]:
        """Split a set of edge indices into groups connected through shared nodes."""
        left = set(remaining)
        out = []
        while left:
            k = left.pop()
            comp, nodes, grew = {k}, set(self.edges[k]), True
            while grew:
                grew = False
                for j in list(left):
                    a, b = self.edges[j]
                    if a in nodes or b in nodes:
                        left.discard(j)
                        comp.add(j)
                        nodes |= {a, b}
                        grew = True
            out.append(frozenset(comp))
        return out

    def _after(self, remaining: frozenset, k: int) -> frozenset:
        a, b = self.edges[k]
        return frozenset(j for j in remaining if not ({a, b} & set(self.edges[j])))

    def exact_inclusion(self, max_states: int = 20_000, max_edges: int = 40) -> np.ndarray | None:
        """P(edge k is in the greedy matching) before link failures, exactly; None if the graph has
        more than max_edges edges or the recursion would visit more than max_states edge sets."""
        E = len(self.edges)
        if E > max_edges:
            return None
        memo: dict[frozenset, np.ndarray] = {}

        def incl(comp: frozenset) -> np.ndarray:
            if comp in memo:
                return memo[comp]
            if len(memo) >= max_states:
                raise OverflowError
            acc = np.zeros(E)
            for k in comp:
                acc[k] += 1.0
                for sub in self._components(self._after(comp, k)):
                    acc += incl(sub)
            memo[comp] = acc / len(comp)
            return memo[comp]

        try:
            return sum((incl(c) for c in self._components(frozenset(range(E)))), np.zeros(E))
        except OverflowError:
            return None

    def exact_mean_matrix(self, max_states: int = 20_000, max_edges: int = 40) -> np.ndarray | None:
        """Ā exactly: Ā_ij = p_link P((i, j) chosen), Ā_ii = 1 − Σ_j Ā_ij; None if too large."""
        inc = self.exact_inclusion(max_states, max_edges)
        if inc is None:
            return None
        Abar = np.zeros((self.n_nodes, self.n_nodes))
        u, v = self._ends
        Abar[u, v] = Abar[v, u] = self.p_link * inc
        Abar[np.diag_indices(self.n_nodes)] = 1.0 - Abar.sum(axis=1)
        return Abar

    def mean_matrix(self) -> np.ndarray:
        """The exact Ā (eq (6)); raises ValueError when the graph is too large for the recursion."""
        A = self.exact_mean_matrix()
        if A is None:
            raise ValueError(f"no exact Ā for greedy matching on {len(self.edges)} edges: use estimate_mean_matrix, "
                             f"or drive the chain by the protocol (switched_riccati.sample_protocol_chain)")
        return A

    def exact_matching_law(self) -> dict[tuple[int, ...], float]:
        """Law of the final matching (after link failures) as {sorted edge indices: probability};
        enumerates every greedy outcome, so only for small graphs (tests)."""
        memo: dict[frozenset, dict[frozenset, float]] = {}

        def law(rem: frozenset) -> dict[frozenset, float]:
            if not rem:
                return {frozenset(): 1.0}
            if rem in memo:
                return memo[rem]
            out: dict[frozenset, float] = {}
            for k in rem:
                for m, p in law(self._after(rem, k)).items():
                    key = m | {k}
                    out[key] = out.get(key, 0.0) + p / len(rem)
            memo[rem] = out
            return out

        final: dict[tuple[int, ...], float] = {}
        q = self.p_link
        for m, p in law(frozenset(range(len(self.edges)))).items():
            ms = sorted(m)
            for mask in range(1 << len(ms)):
                kept = tuple(k for i, k in enumerate(ms) if mask >> i & 1)
                w = q ** len(kept) * (1 - q) ** (len(ms) - len(kept))
                if w > 0:
                    final[kept] = final.get(kept, 0.0) + p * w
        return final

    def estimate_mean_matrix(self, draws: int, rng: np.random.Generator, chunk: int | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Monte Carlo Ā from `draws` matchings and the standard error of each entry; by default in chunks of about
        64 MiB of edge priorities and orders (a function of the graph only, so the draws do not depend on memory)."""
        N = self.n_nodes
        if chunk is None:
            chunk = int(min(50_000, max(1_000, 2**26 // (40 * len(self.edges)))))
        counts = np.zeros((N, N))
        done = 0
        while done < draws:
            b = min(chunk, draws - done)
            p = self.sample(b, rng)
            counts += np.bincount((np.arange(N) * N + p).ravel(), minlength=N * N).reshape(N, N)
            done += b
        Abar = counts / draws
        Abar = 0.5 * (Abar + Abar.T)   # symmetric by construction of the counts; removes nothing but round-off
        se = np.sqrt(Abar * (1 - Abar) / draws)
        return Abar, se

    def support_matrix(self) -> np.ndarray:
        """A symmetric doubly stochastic matrix with Ā's support (edges, and the diagonal when
        p_link < 1: a chosen link fails with positive probability). For the structural checks
        (C.1, D.1 search) without estimating Ā."""
        N = self.n_nodes
        u, v = self._ends
        deg = np.bincount(np.concatenate([u, v]), minlength=N)
        S = np.zeros((N, N))
        S[u, v] = S[v, u] = 1.0 / (2 * max(deg.max(), 1))
        S[np.diag_indices(N)] = 1.0 - S.sum(axis=1)
        if self.p_link >= 1.0:
            # without failures a node may never be left unmatched (even ring: Ā_nn = 0, periodic):
            # use Ā itself, exact when small, else estimated from 20,000 draws (support only)
            A = self.exact_mean_matrix()
            return A if A is not None else self.estimate_mean_matrix(20_000, np.random.default_rng(0))[0]
        return S


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


# -- batched GIKF run with on-line statistics -----------------------------------------------------------

QUANTILES = (0.05, 0.25, 0.5, 0.75, 0.95, 0.99)
#: at most this many slots carry the per-slot series of the sample runs, and at most STAT_SLOTS the
#: statistics over runs (quantiles, tail counts, Loewner margins): memory does not grow with the horizon
SERIES_SLOTS = 1000
STAT_SLOTS = 250
#: the matching of the sample runs is kept at every slot up to this one (the matching animation)
PARTNER_SLOTS = 1000


def decimated_slots(T: int, record_times: Sequence[int], stride: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """(series slots, statistic slots) of a run of T slots: every slot (series) and every `stride`-th slot
    (statistics) while they fit in SERIES_SLOTS and STAT_SLOTS, else evenly thinned; both always hold
    0, T − 1, T and the record times (statistics: from slot 1 on)."""
    times = {int(t) for t in record_times if 0 <= t <= T}
    k1 = max(1, -(-T // SERIES_SLOTS))
    series = set(range(0, T + 1, k1)) | times | {0, max(T - 1, 0), T}
    k2 = max(stride, -(-T // STAT_SLOTS))
    k2 = -(-k2 // k1) * k1                      # statistics on series slots
    stats = set(range(0, T + 1, k2)) | times | {T}
    return np.array(sorted(series)), np.array(sorted(stats))


def _units_draw(units, draw) -> np.ndarray:
    parts = [draw(g, m) for g, m in units]
    return parts[0] if len(parts) == 1 else np.concatenate(parts, axis=0)


#: how per-unit results combine: per-run arrays are concatenated along the given axis, counts and
#: float sums added (in unit order, so sums do not depend on how units are chunked), minima taken
RUN_AXIS = {"q": 0, "feat_q": 2, "feat_n": 2, "log_trace": 1, "nees_q": 1, "nees_c": 1, "nees_run": 1}
SUMS = ("exceed", "nees", "trans", "token0", "token0_final", "final_sum", "final_sq", "runs")
MINS = ("margins", "slack")


def gikf_units(sys: GossipSystem, protocol, units: Sequence[tuple[np.random.Generator, int]], n_slots: int, *,
               record_times: Sequence[int], P_central: np.ndarray, K_central: np.ndarray, envelope: np.ndarray,
               j_grid: np.ndarray, envelope_log: np.ndarray | None = None, n_paths: int = 3, check: bool = True,
               paths: bool = True, nees_window: tuple[int, int] = (20, 60), token_steps: int = 20,
               nees_level: float = 0.99, stat_stride: int = 1, P_floor: np.ndarray | None = None,
               floor_index: np.ndarray | None = None, floor_err: np.ndarray | None = None,
               envelope_err: np.ndarray | None = None, nees_slots: Sequence[int] = (),
               x0: np.ndarray | None = None) -> list[dict[str, np.ndarray]]:
    """GIKF runs (covariances and the error recursion) for units of runs, each unit drawing from its own
    generator (`units`: (generator, runs) pairs, simulated together): one dict of statistics per unit,
    which depend only on that unit's draws. Combine them with `fold_gikf` and `finish_gikf`.

    P_central (T+1, M, M) and K_central (T, M, N m) are the centralized filter's prior covariances
    and update gains; envelope (T+1, M, M) is f_0^t(P0), divided by exp(envelope_log[t]) when
    envelope_log is given (a rescaled envelope stays finite over any horizon). Statistics:
    features (`covariance_features`) of a uniformly random sensor q and of every sensor at the record
    times; log tr P̂_n(t) of every run at the statistic slots (`decimated_slots`: quantiles over runs),
    exceedance counts of ‖P̂_n(t)‖ over j_grid there; NEES sums; token-chain counts; sums of P̂_n(T) and of
    its squares; with `paths`, the first n_paths runs of the first unit whole at the series slots.

    With `check` (the first unit of a run), relative Loewner margins at the statistic slots, (S, 3, N):
    `margins`, min over the unit's runs of λ_min(difference) / max(1, ‖P̂‖) per sensor, against a lower bound
    P_floor (a matrix per class, (T+1, C, M, M), sensor n in class floor_index[n]; default P_c(t)), against Q
    and below the envelope; `slack`, the same with the round-off allowance of both sides added before the
    minimum (the first-order bound of `riccati_roundoff` carried along every run, `floor_err` /
    `envelope_err` of the references, eps·‖Q‖). A margin is a counterexample only where its slack is < 0.
    `nees_slots`: slots at which the NEES of the random sensor q and of the centralized filter are kept
    per run (given the gossip path each is exactly χ²_M and independent across runs).

    When a covariance leaves float64 the covariance work stops for these units (the draws go on, so every
    unit's token counts stay its own); `overflow` is the slot, and `finish_gikf` blanks what follows it.
    """
    from scipy.stats import chi2

    N, M, m = sys.N, sys.M, sys.C.shape[1]
    sizes = [size for _, size in units]
    B, T = sum(sizes), n_slots
    edges = np.cumsum([0, *sizes])
    sl = [slice(a, b) for a, b in zip(edges[:-1], edges[1:])]
    times = sorted(set(int(t) for t in record_times if 0 <= t <= T))
    series, stat = decimated_slots(T, times, stat_stride)
    series_i = {int(t): i for i, t in enumerate(series)}
    stat_i = {int(t): i for i, t in enumerate(stat)}
    q = _units_draw(units, lambda g, k: g.integers(0, N, k))
    rows = np.arange(B)
    P = np.broadcast_to(sys.P0, (B, N, M, M)).copy()
    e = np.broadcast_to(_units_draw(units, lambda g, k: g.standard_normal((k, 1, M))) @ factor_psd(sys.P0).T,
                        (B, N, M)).copy()
    e_c = e[:, 0].copy()
    Lr = sys.R_chol
    Lq = np.linalg.cholesky(sys.Q)
    nf = len(FEATURES) + M
    n_units = len(units)
    feat_q = np.full((len(times), nf, B), np.nan)
    feat_n = np.full((len(times), nf, B, N), np.nan)
    log_trace = np.full((len(stat), B, N), np.nan)
    exceed = np.zeros((n_units, len(stat), N, len(j_grid)), dtype=np.int64)
    margins = np.full((len(stat), 3, N), np.nan)
    slack = np.full((len(stat), 3, N), np.nan)
    if P_floor is None:
        P_floor, floor_index = P_central[:, None], np.zeros(N, dtype=np.int64)
    floor_err = np.zeros(P_floor.shape[:2]) if floor_err is None else np.asarray(floor_err, float)
    envelope_err = np.zeros(T + 1) if envelope_err is None else np.asarray(envelope_err, float)
    envelope_log = np.zeros(T + 1) if envelope_log is None else np.asarray(envelope_log, float)
    q_norm = EPS * float(np.linalg.norm(sys.Q, 2))
    nees_slots = [int(t) for t in nees_slots if 1 <= t <= T]
    nees_q = np.full((len(nees_slots), B), np.nan)
    nees_cq = np.full((len(nees_slots), B), np.nan)
    sp = min(n_paths, sizes[0]) if paths else 0
    n_part = min(T, PARTNER_SLOTS) + 1
    path_trace = np.full((sp, len(series), N), np.nan)
    path_err = np.full((sp, len(series), N, M), np.nan)
    path_err_c = np.full((sp, len(series), M), np.nan)
    path_state = np.full((sp, len(series), M), np.nan)
    path_partners = np.tile(np.arange(N), (sp, n_part, 1))
    nees_thr = chi2.ppf(nees_level, M)
    nees = np.zeros((n_units, 6))  # per unit: NEES sum, count above, n (sensors); sum, count above, n (central)
    nees_run = np.zeros((4, B))   # per run: NEES sum and exceedances (sensors), NEES sum and exceedances (central)
    loc = np.tile(np.arange(N), (B, 1))  # token locations p_n(t)
    trans = np.zeros((n_units, N, N), dtype=np.int64)
    tok0 = np.zeros((n_units, token_steps + 1, N), dtype=np.int64)
    for u, s_ in enumerate(sl):
        tok0[u, 0, 0] = s_.stop - s_.start
    overflow = -1
    cr = sizes[0] if check else 0
    err = np.zeros((cr, N, M, M))  # first-order round-off bound of P̂_n(t) of the checked runs (see propagate_error)
    x = (np.zeros(M) if x0 is None else np.asarray(x0, float)) + e[:sp, 0]   # states of the sample runs
    unit_of = np.repeat(np.arange(n_units), sizes)

    def per_unit(values: np.ndarray) -> np.ndarray:
        return np.array([values[s_].sum(axis=0) for s_ in sl])

    def record(t: int) -> None:
        if t in series_i:
            i = series_i[t]
            path_trace[:, i] = np.trace(P[:sp], axis1=-2, axis2=-1)
            path_err[:, i] = e[:sp]
            path_err_c[:, i] = e_c[:sp]
            path_state[:, i] = x
        if t in nees_slots:
            k = nees_slots.index(t)
            eq = e[rows, q]
            nees_q[k] = np.einsum("bm,bm->b", eq, np.linalg.solve(P[rows, q], eq[..., None])[..., 0])
            nees_cq[k] = np.einsum("bm,bm->b", e_c, np.linalg.solve(P_central[t], e_c.T).T)
        if t in stat_i:
            i = stat_i[t]
            log_trace[i] = np.log(np.maximum(np.trace(P, axis1=-2, axis2=-1), np.finfo(float).tiny))
            lam_max = eigvalsh(P)[..., -1]
            hit = lam_max[..., None] >= j_grid
            exceed[:, i] = per_unit(hit)
            if cr:
                _margins(i, t, lam_max[:cr])
        if t in times:
            i = times.index(t)
            feat_n[i] = covariance_features(P)
            feat_q[i] = feat_n[i][:, rows, q]
        if max(1, nees_window[0]) <= t < nees_window[1]:
            z = np.einsum("bnm,bnm->bn", e, np.linalg.solve(P, e[..., None])[..., 0])
            zc = np.einsum("bm,bm->b", e_c, np.linalg.solve(P_central[t], e_c.T).T)
            nees[:, 0] += per_unit(z.sum(axis=1))
            nees[:, 1] += per_unit((z > nees_thr).sum(axis=1))
            nees[:, 2] += np.array(sizes) * N
            nees[:, 3] += per_unit(zc)
            nees[:, 4] += per_unit(zc > nees_thr)
            nees[:, 5] += sizes
            nees_run[0] += z.sum(axis=1)
            nees_run[1] += (z > nees_thr).sum(axis=1)
            nees_run[2] += zc
            nees_run[3] += zc > nees_thr

    def _margins(i: int, t: int, lam_max: np.ndarray) -> None:
        scale = np.maximum(1.0, lam_max)
        # the envelope is exp(envelope_log[t]) · envelope[t]: divide both sides by max(1, ‖envelope‖)
        env_log = envelope_log[t] + math.log(max(float(np.linalg.norm(envelope[t], 2)), np.finfo(float).tiny))
        shift = max(0.0, env_log)
        env_unit = math.exp(envelope_log[t] - shift) * envelope[t]
        e_P = error_norm(err)
        floor, f_err = P_floor[t][floor_index], floor_err[t][floor_index]
        lam_min = eigvalsh(np.stack([P[:cr] - floor, P[:cr] - sys.Q, env_unit - math.exp(-shift) * P[:cr]]))[..., 0]
        for col, (tol, sc_) in enumerate(((e_P + f_err, scale), (e_P + q_norm, scale),
                                          (math.exp(-shift) * e_P + math.exp(envelope_log[t] - shift) * envelope_err[t],
                                           1.0))):
            if col == 1 and t == 0:
                continue
            margins[i, col] = (lam_min[col] / sc_).min(axis=0)
            slack[i, col] = ((lam_min[col] + tol) / sc_).min(axis=0)

    with np.errstate(over="ignore", invalid="ignore"):
        record(0)
        for t in range(T):
            partners = _units_draw(units, lambda g, k: matching_at(protocol, t, k, g))
            if t < n_part - 1:
                path_partners[:, t] = partners[:sp]
            new_loc = partners[rows[:, None], loc]
            if t > 0:
                flat = (unit_of[:, None] * N + loc) * N + new_loc
                trans += np.bincount(flat.ravel(), minlength=n_units * N * N).reshape(n_units, N, N)
            loc = new_loc
            if 1 <= t <= token_steps:
                tok0[:, t] = np.bincount(unit_of * N + loc[:, 0], minlength=n_units * N).reshape(n_units, N)
            w = _units_draw(units, lambda g, k: g.standard_normal((k, M))) @ Lq.T
            v = np.einsum("nij,bnj->bni", Lr, _units_draw(units, lambda g, k: g.standard_normal((k, N, m))))
            if overflow >= 0:
                continue            # the draws go on (token counts), the covariances have left float64
            X_in = swap(P, partners)
            P, K = riccati_step(X_in, sys.C, sys.R, sys.F, sys.Q, return_gain=True)     # eq (12)
            if cr:
                delta, G = riccati_roundoff(X_in[:cr], K[:cr], sys.C, sys.R, sys.F, sys.Q)
                err = propagate_error(err[rows[:cr, None], partners[:cr]], G, delta)
            e = gikf_error_step(e, partners, K, sys, w, v)
            e_c = (e_c - (np.einsum("bi,mi->bm", np.einsum("ij,bj->bi", sys.C_all, e_c) + v.reshape(B, -1),
                                    K_central[t]))) @ sys.F.T + w
            x = x @ sys.F.T + w[:sp]
            if not np.isfinite(P).all():
                overflow = t + 1
                continue
            record(t + 1)
    final = P if overflow < 0 else np.full_like(P, np.nan)
    common = {"times": np.array(times), "series_slots": series, "stat_slots": stat, "nees_slots":
              np.array(nees_slots, dtype=np.int64), "nees_threshold": np.array(nees_thr), "overflow": np.array(overflow)}
    out = []
    for u, s_ in enumerate(sl):
        part = {**common, "q": q[s_], "feat_q": feat_q[..., s_], "feat_n": feat_n[:, :, s_], "log_trace": log_trace[:, s_],
                "exceed": exceed[u], "nees": nees[u], "trans": trans[u], "token0": tok0[u],
                "token0_final": np.bincount(loc[s_, 0], minlength=N), "nees_q": nees_q[:, s_], "nees_c": nees_cq[:, s_],
                "nees_run": nees_run[:, s_], "final_sum": final[s_].sum(axis=0),
                "final_sq": np.square(final[s_]).sum(axis=0), "runs": np.array(s_.stop - s_.start)}
        if u == 0 and check:
            part.update(margins=margins, slack=slack)
        if u == 0 and paths:
            part.update(path_trace=path_trace, path_err=path_err, path_err_c=path_err_c, path_state=path_state,
                        path_partners=path_partners)
        out.append(part)
    return out


def fold_gikf(acc: dict | None, part: dict) -> dict:
    """Accumulate one unit's statistics (in unit order): see RUN_AXIS, SUMS, MINS."""
    if acc is None:
        acc = {k: ([v] if k in RUN_AXIS else v) for k, v in part.items()}
        acc["overflow"] = part["overflow"]
        return acc
    for k, v in part.items():
        if k in RUN_AXIS:
            acc[k].append(v)
        elif k in SUMS:
            acc[k] = acc[k] + v
        elif k in MINS:
            acc[k] = np.fmin(acc[k], v) if k in acc else v
        elif k == "overflow":
            a, b = int(acc[k]), int(v)
            acc[k] = np.array(min(a, b) if a >= 0 and b >= 0 else max(a, b))
        elif k not in acc:
            acc[k] = v
    return acc


def finish_gikf(acc: dict) -> dict[str, np.ndarray]:
    """The folded statistics as arrays: per-run arrays joined, quantiles over runs of log tr P̂_n(t) at the
    statistic slots (`quantiles`, (S, N, len(QUANTILES)); the per-run log traces are dropped), and, after an
    overflow at slot t₀, every statistic of a slot ≥ t₀ blanked (NaN; counts −1), so that nothing depends on
    which units were simulated together."""
    out = {k: (np.concatenate(v, axis=RUN_AXIS[k]) if k in RUN_AXIS else np.asarray(v)) for k, v in acc.items()}
    lt = out.pop("log_trace")
    with np.errstate(invalid="ignore"):
        out["quantiles"] = np.moveaxis(np.quantile(lt, QUANTILES, axis=1), 0, -1)
    t0 = int(out["overflow"])
    if t0 >= 0:
        late = out["stat_slots"] >= t0
        out["quantiles"][late] = np.nan
        out["exceed"][late] = -1
        for k in MINS:
            if k in out:
                out[k][late] = np.nan
        for k in ("feat_q", "feat_n"):
            out[k][out["times"] >= t0] = np.nan
        for k in ("nees_q", "nees_c"):
            out[k][out["nees_slots"] >= t0] = np.nan
        for k in ("path_trace", "path_err", "path_err_c", "path_state"):
            if k in out:
                out[k][:, out["series_slots"] >= t0] = np.nan
        out["nees"][:] = np.nan
        out["nees_run"][:] = np.nan
    return out


def simulate_gikf(sys: GossipSystem, protocol, n_runs: int, n_slots: int, rng: np.random.Generator,
                  **kw) -> dict[str, np.ndarray]:
    """All runs as one unit drawn from `rng` (see `gikf_units`); the Loewner margins on the first
    `check_runs` (default all) runs are not split off: every run is checked."""
    kw.pop("check_runs", None)
    return finish_gikf(fold_gikf(None, gikf_units(sys, protocol, [(rng, n_runs)], n_slots, **kw)[0]))
