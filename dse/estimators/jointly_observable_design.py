"""Design quantities of a hybrid (local observer + distributed parameter estimator) observer
for a jointly observable multi-channel LTI system  x' = A x,  y_i = C_i x  (i = 1..m).

Everything here is pure numpy/scipy on small matrices; nothing is paper specific. The
equation numbers in docstrings refer to the hybrid-observer construction of Wang, Liu and
Morse (local observers (3), parameter estimator (12)-(13), ρ (17), α (18)/Lemma 5, q (22),
σ (26), q (27)) because that is where the formulas come from.

Conventions: agents 0..m-1; a neighbour mask N[i, j] = True iff j is a neighbour of i
(i receives from j); self-arcs always present.
"""
from __future__ import annotations

import functools
import itertools
import math
from dataclasses import dataclass
from decimal import Decimal, getcontext, localcontext

import numpy as np
import scipy  # scipy.linalg loads on first use (scipy imports submodules lazily): `dse list` skips it

# ρ of (17) lives in its own module; its names are part of this module's interface
from .projection_products import (RHO_FRONTIER_BYTES, RhoResult, count_complete_repeat_free_words,  # noqa: F401
                                  range_bases, rho_exact, spectral_norm)


# -- per-agent quantities ---------------------------------------------------------------------

def observability_matrix(A: np.ndarray, C: np.ndarray) -> np.ndarray:
    """[C; CA; ...; CA^{n-1}]."""
    n = A.shape[0]
    rows, M = [], np.asarray(C, float)
    for _ in range(n):
        rows.append(M)
        M = M @ A
    return np.vstack(rows)


@dataclass(frozen=True)
class ObservableBasis:
    """Orthonormal rows spanning the observable row space of (C, A) (= the row space of the
    observability matrix). `gap`: the smallest singular value the rank decisions accepted,
    relative to its step's scale (||C|| for the rows of C, ||A|| after); `discarded`: the
    largest one they rejected, on the same scale (~ eps when the rank is clear). The rows are
    A-invariant (ker A-invariant) to within `discarded`·||A|| plus round-off."""

    rows: np.ndarray
    gap: float
    discarded: float


def observable_basis(A: np.ndarray, C: np.ndarray, rank_tol: float = 1e-9) -> ObservableBasis:
    """Row space of [C; CA; ...; CA^(n-1)] by an orthogonal Krylov iteration: start from an
    orthonormal basis R of the rows of C, add the part of R A orthogonal to R, repeat until
    nothing new appears. Each step multiplies an orthonormal R by A once, so the rank
    decisions compare singular values with rank_tol·||A|| (or rank_tol·||C||) instead of with
    the largest singular value of a matrix holding A^(n-1) (badly scaled for ||A|| far from 1)."""
    A, C = np.asarray(A, float), np.asarray(C, float)
    n = A.shape[0]
    _, sv, Vt = np.linalg.svd(C, full_matrices=False)
    top = max(sv[0] if sv.size else 0.0, 1e-300)
    keep = sv > rank_tol * top
    R = Vt[keep]
    gap = float(sv[keep][-1] / top) if keep.any() else 0.0
    discarded = float(sv[~keep].max() / top) if (~keep).any() else 0.0
    scale = max(float(np.linalg.norm(A, 2)), 1e-300)
    while 0 < R.shape[0] < n:
        X = R @ A
        for _ in range(2):                         # project out span(R) twice (re-orthogonalisation)
            X = X - (X @ R.T) @ R
        _, sx, Vx = np.linalg.svd(X, full_matrices=False)
        new = sx > rank_tol * scale
        if (~new).any():
            discarded = max(discarded, float(sx[~new].max() / scale))
        if not new.any():
            break
        gap = min(gap, float(sx[new][-1] / scale))
        R = np.vstack([R, Vx[new]])
        R = np.linalg.qr(R.T)[0].T                 # keep the rows exactly orthonormal
    return ObservableBasis(R, gap, discarded)


@dataclass(frozen=True)
class LocalDesign:
    """The design objects of one agent (§2 of the construction).

    L (n_i x n): full row rank, ker L = unobservable space of (C_i, A).
    Abar (n_i x n_i), Cbar (s_i x n_i): the unique solutions of L A = Abar L, C_i = Cbar L.
    Q (n x n_i) = L'(L L')^{-1};  P (n x n) = I - Q L, the orthogonal projection onto ker L.
    `condition`: κ(L) (1 for the orthonormal default); `gap`: see `ObservableBasis`.
    """

    L: np.ndarray
    Abar: np.ndarray
    Cbar: np.ndarray
    Q: np.ndarray
    P: np.ndarray
    condition: float
    gap: float

    @property
    def n_i(self) -> int:
        return self.L.shape[0]


def pseudo_inverse_rows(L: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """Q = L'(L L')^{-1} and P = I - Q L for a full-row-rank L, without forming (L L')^{-1}:
    with L' = U R (thin QR), Q = U R^{-T} (a triangular solve) and P = I - U U' (depends on the
    orthonormal U only, so its accuracy does not degrade with κ(L) beyond the QR's own).
    Also κ(L) = κ(R)."""
    U, Rm = np.linalg.qr(np.asarray(L, float).T)
    # (R^{-1} U')' = U R^{-T}. numpy's LU solve of a triangular R pivots nowhere (the entries below the
    # diagonal are exact zeros), so it is the triangular solve itself (bit for bit scipy's solve_triangular, checked
    # on 3,300 random cases up to n = 200), without importing scipy.linalg when a scenario file is read (`dse list`)
    Q = np.linalg.solve(Rm, U.T).T
    sv = np.linalg.svd(Rm, compute_uv=False)
    return Q, np.eye(L.shape[1]) - U @ U.T, float(sv[0] / sv[-1])


def local_design(A: np.ndarray, C: np.ndarray, *, rank_tol: float = 1e-9, L: np.ndarray | None = None) -> LocalDesign:
    """L_i (orthonormal rows of the observable row space unless given), Ā_i, C̄_i, Q_i, P_i."""
    basis = observable_basis(A, C, rank_tol)
    L = basis.rows if L is None else np.asarray(L, float)
    Q, P, cond = pseudo_inverse_rows(L)
    Abar = L @ A @ Q              # unique solution of L A = Abar L when ker L is A-invariant
    Cbar = np.asarray(C, float) @ Q
    return LocalDesign(L, Abar, Cbar, Q, P, cond, basis.gap)


def same_kernel(L: np.ndarray, A: np.ndarray, C: np.ndarray, rank_tol: float = 1e-9) -> bool:
    """True iff L has full row rank and ker L = ker O(C, A) (the row spaces agree: the rows of
    L lie in the observable row space, to rank_tol relative to ||L||)."""
    L = np.asarray(L, float)
    basis = observable_basis(A, C, rank_tol).rows
    if L.ndim != 2 or L.shape[1] != basis.shape[1] or L.shape[0] != basis.shape[0]:
        return False
    sv = np.linalg.svd(L, compute_uv=False)
    if sv[-1] <= rank_tol * sv[0]:
        return False
    outside = L - (L @ basis.T) @ basis
    return bool(np.linalg.norm(outside, 2) <= rank_tol * sv[0])


def place_gain(Abar: np.ndarray, Cbar: np.ndarray, poles) -> np.ndarray:
    """K with eig(Ā + K C̄) = poles (note the + sign of (3)): scipy.signal.place_poles on the dual
    system. Real poles with one output or outputs of full rank (the eigenvector choice is unique,
    or the identity) take `_place_direct`, the same computation without importing scipy.signal
    (0.5 s: it loads scipy.stats); other cases iterate (method YT) in scipy itself."""
    A, B = np.asarray(Abar, float).T, np.asarray(Cbar, float).T
    P = np.asarray(poles)
    rank = np.linalg.matrix_rank(B)
    if np.isrealobj(P) and P.ndim == 1 and len(P) == len(A) and (rank == 1 or rank == len(A)) and not unplaceable(P, rank):
        return -_place_direct(A, B, np.sort(P.astype(float)), rank).T
    from scipy.signal import place_poles

    return -place_poles(A, B, P).gain_matrix.T


def _place_direct(A: np.ndarray, B: np.ndarray, poles: np.ndarray, rank: int) -> np.ndarray:
    """scipy.signal.place_poles(A, B, poles).gain_matrix (scipy 1.17, `_ltisys.py`) for sorted real
    poles and B of rank 1 or of full row rank, where no iteration runs: the same operations in the
    same order (tests compare the two bit for bit)."""
    if B.shape[0] == rank:       # K = lstsq(B, diag(poles) - A): the transfer matrix is the identity
        return -np.real(np.linalg.lstsq(B, np.diag(poles) - A, rcond=-1)[0])
    u, z = scipy.linalg.qr(B, mode="full")
    u0, u1, z = u[:, :rank], u[:, rank:], z[:rank, :]
    columns = []
    for p in poles:              # one vector of the kernel of u1'(A - p I) per pole (unique up to scale)
        pole_space = np.dot(u1.T, A - p * np.eye(B.shape[0])).T
        Q, _ = scipy.linalg.qr(pole_space, mode="full")
        x = np.sum(Q[:, pole_space.shape[1]:], axis=1)[:, np.newaxis]
        columns.append(x / np.linalg.norm(x))
    X = np.hstack(columns).astype(complex)
    M = np.linalg.solve(X.T, np.dot(np.diag(poles), X.T)).T
    return -np.real(np.linalg.solve(z, np.dot(u0.T, M - A)))


def unplaceable(poles, rank: int) -> str | None:
    """Why real `poles` cannot be placed for an observable pair whose output matrix has rank
    `rank` (a pole repeated more often than the rank: scipy's place_poles, below `place_gain`,
    refuses it), or None; decided without placing (and without importing scipy.signal)."""
    values, counts = np.unique(np.asarray(poles, float), return_counts=True)
    k = int(np.argmax(counts))
    if counts[k] > rank:
        return f"pole {values[k]:g} is repeated {counts[k]} times, more than the rank {rank} of the outputs allows"
    return None


def stacked_rank(C: np.ndarray, rank_tol: float = 1e-9) -> tuple[int, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """The rank r of C (singular values above rank_tol relative) and its SVD U S V'."""
    U, sv, Vt = np.linalg.svd(np.asarray(C, float), full_matrices=False)
    return int(np.sum(sv > rank_tol * max(sv[0], 1e-300))), (U, sv, Vt)


def stacked_gain(A: np.ndarray, C: np.ndarray, poles, rank_tol: float = 1e-9) -> np.ndarray:
    """K with eig(A + K C) = poles for a C whose rows may be dependent (agents sharing outputs):
    the poles are placed for the orthonormal rows V_r' of C = U S V' (rank r), and K = K_r S_r^-1 U_r',
    so that K C = K_r V_r'."""
    r, (U, sv, Vt) = stacked_rank(C, rank_tol)
    K_r = place_gain(A, Vt[:r], poles)
    return K_r @ (U[:, :r] / sv[:r]).T


def spectral_abscissa(F: np.ndarray) -> float:
    return float(np.max(np.linalg.eigvals(F).real))


def transient_constant(F: np.ndarray, rate: float, *, horizon: float | None = None, samples: int = 20001) -> float:
    """c = sup_{τ >= 0} ||e^{Fτ}|| e^{rate τ}  (15); finite iff rate <= -spectral abscissa (no
    Jordan block on the boundary). Dense sampling on [0, horizon] plus a bounded local refine."""
    gap = -spectral_abscissa(F) - rate
    if gap < -1e-12:
        return math.inf
    horizon = horizon if horizon is not None else (min(200.0, 60.0 / gap) if gap > 1e-9 else 200.0)
    G = F + rate * np.eye(len(F))
    h = horizon / (samples - 1)
    E = np.empty((samples, *F.shape))
    E[0] = np.eye(len(F))
    step, filled = scipy.linalg.expm(G * h), 1
    while filled < samples:                      # E[k] = step^k by doubling: E[f:2f] = E[0:f] step^f
        take = min(filled, samples - filled)
        E[filled:filled + take] = E[:take] @ step
        step = step @ step
        filled += take
    vals = spectral_norm(E)
    k = int(np.argmax(vals))
    best = float(vals[k])
    lo, hi = max(k - 1, 0) * h, min(k + 1, samples - 1) * h
    if hi > lo:
        from scipy.optimize import minimize_scalar

        res = minimize_scalar(lambda t: -np.linalg.norm(scipy.linalg.expm(G * t), 2), bounds=(lo, hi), method="bounded",
                              options={"xatol": 1e-12})
        best = max(best, float(-res.fun))
    return best


# -- graphs and averaging -----------------------------------------------------------------------

def neighbour_mask(neighbours: list[list[int]] | list[set[int]], m: int) -> np.ndarray:
    """Boolean m x m mask from neighbour lists; self-arcs added."""
    N = np.eye(m, dtype=bool)
    for i, nb in enumerate(neighbours):
        for j in nb:
            N[i, j] = True
    return N


def is_strongly_connected(N: np.ndarray) -> bool:
    """Arc j -> i iff N[i, j]; strongly connected iff every vertex reaches every other."""
    m = len(N)
    R = N.astype(bool) | np.eye(m, dtype=bool)
    reach = R.copy()
    for _ in range(max(1, int(math.ceil(math.log2(max(m, 2)))) + 1)):
        reach = reach | ((reach.astype(np.int64) @ reach.astype(np.int64)) > 0)
    return bool(reach.all())


def strongly_connected_batch(N: np.ndarray) -> np.ndarray:
    """`is_strongly_connected` for a stack of masks (..., m, m): boolean per mask."""
    N = np.asarray(N, bool)
    m = N.shape[-1]
    reach = (N | np.eye(m, dtype=bool)).astype(np.int64)
    for _ in range(max(1, int(math.ceil(math.log2(max(m, 2)))) + 1)):
        reach = ((reach @ reach) > 0).astype(np.int64)
    return reach.astype(bool).all(axis=(-2, -1))


def flocking_matrix(N: np.ndarray) -> np.ndarray:
    """F[i, j] = 1/|N_i| for j ∈ N_i (straight averaging (13)); row stochastic."""
    Nf = N.astype(float)
    return Nf / Nf.sum(axis=1, keepdims=True)


def symmetric_weights_batch(N: np.ndarray, m_design: int | None = None) -> np.ndarray:
    """`symmetric_weights` for a stack of masks (..., m, m)."""
    N = np.asarray(N, bool)
    m = N.shape[-1] if m_design is None else m_design
    W = N.astype(float) / (m + 1)
    idx = np.arange(N.shape[-1])
    W[..., idx, idx] = 0.0
    W[..., idx, idx] = 1.0 - W.sum(axis=-1)
    return W


def symmetric_weights(N: np.ndarray, m_design: int | None = None) -> np.ndarray:
    """The convex-combination rule (25): self 1 - (|N_i| - 1)/(m+1), each other neighbour 1/(m+1)."""
    m = len(N) if m_design is None else m_design
    W = N.astype(float) / (m + 1)
    np.fill_diagonal(W, 0.0)
    W[np.diag_indices(len(N))] = 1.0 - W.sum(axis=1)
    return W


def _masks_from_bits(m: int, pairs: list[tuple[int, int]], symmetric: bool) -> np.ndarray:
    """Every neighbour mask (self-arcs on) whose off-diagonal arcs are a subset of `pairs`."""
    bits = np.arange(1 << len(pairs))
    on = ((bits[:, None] >> np.arange(len(pairs))[None, :]) & 1).astype(bool)
    N = np.zeros((len(bits), m, m), dtype=bool)
    N[:, np.arange(m), np.arange(m)] = True
    for b, (i, j) in enumerate(pairs):
        N[:, i, j] = on[:, b]
        if symmetric:
            N[:, j, i] = on[:, b]
    return N


@functools.lru_cache(maxsize=8)
def _strongly_connected_digraphs(m: int) -> np.ndarray:
    N = _masks_from_bits(m, [(i, j) for i in range(m) for j in range(m) if i != j], symmetric=False)
    out = N[strongly_connected_batch(N)]
    out.flags.writeable = False
    return out


@functools.lru_cache(maxsize=8)
def _connected_undirected_graphs(m: int) -> np.ndarray:
    N = _masks_from_bits(m, list(itertools.combinations(range(m), 2)), symmetric=True)
    out = N[strongly_connected_batch(N)]
    out.flags.writeable = False
    return out


def strongly_connected_digraphs(m: int) -> np.ndarray:
    """All strongly connected digraphs with self-arcs on m labelled vertices, (count, m, m) masks."""
    return _strongly_connected_digraphs(m).copy()


def connected_undirected_graphs(m: int) -> np.ndarray:
    """All connected simple undirected graphs on m labelled vertices as symmetric masks with self-arcs."""
    return _connected_undirected_graphs(m).copy()


# -- norms --------------------------------------------------------------------------------------

def mixed_norm(M: np.ndarray, row_sizes, col_sizes) -> float | np.ndarray:
    """|M| = max row sum of the matrix of blockwise spectral norms (Sec. 3). Batched over
    leading axes."""
    M = np.asarray(M, float)
    r = np.concatenate([[0], np.cumsum(row_sizes)])
    c = np.concatenate([[0], np.cumsum(col_sizes)])
    blocks = np.stack([np.stack([spectral_norm(M[..., r[a]:r[a + 1], c[b]:c[b + 1]])
                                 for b in range(len(col_sizes))], axis=-1) for a in range(len(row_sizes))], axis=-2)
    return blocks.sum(axis=-1).max(axis=-1)


# -- α (18 / Lemma 5), q (22), σ (26), q (27) ----------------------------------------------------

@dataclass(frozen=True)
class SufficientQ:
    """The q's of the sufficient conditions; Python ints (they overflow int64 for large m)."""

    alpha_lemma5: Decimal
    alpha_printed: Decimal
    log10_one_minus_alpha: float        # Lemma-5 form
    r_lemma5: Decimal
    r_printed: Decimal
    q_thm22: int                        # N ceil(r) + 1, (22) as stated, Lemma-5 α
    q_thm21: int                        # N (ceil(r) + 1), (21) + (19)
    q_minimal: int                      # N (floor(r) + 1), the Lemma 4 proof's need
    q_thm22_printed_alpha: int          # (22) with α as printed in (18)
    q_minimal_printed_alpha: int
    q_thm21_printed_alpha: int          # (21) + (19) with α as printed in (18)


def _ln1p_neg(u: Decimal) -> Decimal:
    """-ln(1 - u) for 0 < u < 1 in Decimal, accurate for tiny u (series) and large u (ln)."""
    if u < Decimal("1e-8"):
        s, term, k = Decimal(0), u, 1
        while True:
            add = term / k
            s += add
            if add < s * Decimal(10) ** (-(getcontext().prec + 2)):
                return s
            term *= u
            k += 1
    return -(Decimal(1) - u).ln()


def exact_text(q: int) -> str:
    """An integer as decimal text, whatever its size (Python refuses str() beyond 4,300 digits; the
    q of (22) has about (m-1)² log10(m) digits)."""
    return str(Decimal(q))


def exact_int(text: str) -> int:
    """The integer written by `exact_text`."""
    return int(Decimal(text))


def readable_int(q: int) -> str:
    """An integer for people: thousands separators up to 10^15, else a power of ten."""
    if q < 10**15:
        return f"{q:,}"
    digits = exact_text(q)
    return f"{digits[0]}.{digits[1:4]}e{len(digits) - 1}"


def exact_decimal(value: float) -> Decimal:
    """The exact value of a float as a Decimal (its binary expansion, not the shortest decimal that
    rounds to it: repr(0.1) is '0.1', the float is 0.1000000000000000055511151231257827...)."""
    return Decimal(float(value))


def _ratio_and_rounding(num: tuple[float, float, float], u: Decimal, digits: int) -> tuple[Decimal, int, int]:
    """r = (λ + ||A||)T / (-ln(1 - u)) with the floats' exact values, and ceil(r), floor(r), carrying
    `digits` + 60 significant digits (`digits` about those of r's integer part); where r falls within
    10^-40 of an integer the rounding could depend on the last digits, so 100 more are carried."""
    lam, norm_A, T = (exact_decimal(v) for v in num)
    prec = digits + 60
    while True:
        with localcontext() as ctx:
            ctx.prec = prec
            r = (lam + norm_A) * T / _ln1p_neg(+u)
            ceil, floor = int(r.to_integral_value(rounding="ROUND_CEILING")), int(r.to_integral_value(rounding="ROUND_FLOOR"))
            if min(r - floor, ceil - r) > Decimal(10) ** -40 or ceil == floor:
                return r, ceil, floor
        prec += 100


def sufficient_q(rho: float, m: int, norm_A: float, lam: float, T: float, *, prec: int | None = None) -> SufficientQ:
    """α = 1 - (m-1)(1-ρ)/m^{(m-1)²} (Lemma 5) and as printed in (18), 1 - (m-1)(1-ρ)/(m(m-1)²);
    r = (λ + ||A||)T / ln(1/α) and the three q variants, in decimal arithmetic on the inputs' exact
    binary values with enough digits that ceil(r) and floor(r), hence the q's, are exact integers
    (nothing overflows or rounds 1 - α to zero: 1 - α ≈ m^{-(m-1)²}). `prec` adds digits."""
    if m < 2:
        raise ValueError("m >= 2 (for m = 1, P_1 = 0 and q = 1 suffices)")
    N = (m - 1) ** 2 + 1
    extra = prec or 0
    with localcontext() as ctx:
        ctx.prec = 1200                                        # a float's expansion has at most 1,075 digits: exact
        one_minus_rho = Decimal(1) - exact_decimal(rho)
        up = Decimal(m - 1) * one_minus_rho / (Decimal(m) * Decimal(m - 1) ** 2)
    # the printed α is not close to 1: r has few digits
    rp, cp, fp = _ratio_and_rounding((lam, norm_A, T), up, int(math.log10(m * (m - 1) ** 2 + 1)) + extra)
    alpha_p = Decimal(1) - up
    digits = int((m - 1) ** 2 * math.log10(m)) + extra          # r of Lemma 5 has about (m-1)² log10(m) digits
    with localcontext() as ctx:
        ctx.prec = digits + 1200
        u5 = Decimal(m - 1) * one_minus_rho / Decimal(m) ** ((m - 1) ** 2)
    r5, c5, f5 = _ratio_and_rounding((lam, norm_A, T), u5, digits)    # ln by its series: 1 - α is tiny for m >= 4
    # log10(1 - α) from the decimal exponent and the leading digits (Decimal.log10 at thousands of digits is slow)
    log10_u5 = math.log10(float(u5.scaleb(-u5.adjusted()))) + u5.adjusted() if u5 > 0 else -math.inf
    with localcontext() as ctx:
        ctx.prec = digits + 1200
        alpha5 = Decimal(1) - u5
    return SufficientQ(alpha5, alpha_p, log10_u5, r5, rp, N * c5 + 1, N * (c5 + 1), N * (f5 + 1),
                       N * cp + 1, N * (fp + 1), N * (cp + 1))


#: memory of one batch of the matrices P (M_G ⊗ I) whose norms give σ
SIGMA_BATCH_BYTES = 64 * 2**20


def sigma_symmetric(P_blocks: np.ndarray, graphs: np.ndarray | None = None, m_design: int | None = None
                    ) -> tuple[float, int, np.ndarray]:
    """σ = max over symmetric strongly connected graphs G of ||P (M_G ⊗ I)||_2 (26), with
    M_G = I - L_G/(m+1); all connected graphs on m vertices unless `graphs` is given. Returns σ,
    the index of the worst graph and the per-graph values."""
    P = np.asarray(P_blocks, float)
    m, n, _ = P.shape
    graphs = connected_undirected_graphs(m) if graphs is None else graphs
    Pbig = np.zeros((m * n, m * n))                                  # blockdiag(P_1, ..., P_m)
    for i in range(m):
        Pbig[i * n:(i + 1) * n, i * n:(i + 1) * n] = P[i]
    Ms = symmetric_weights_batch(graphs, m_design)
    batch = max(1, SIGMA_BATCH_BYTES // (8 * (m * n) ** 2))         # graphs per batch, memory bounded
    vals = np.concatenate([np.linalg.norm(Pbig @ _kron_batch(Ms[a:a + batch], n), ord=2, axis=(1, 2))
                           for a in range(0, len(Ms), batch)])
    k = int(np.argmax(vals))
    return float(vals[k]), k, vals


def _kron_batch(W: np.ndarray, n: int) -> np.ndarray:
    g, m, _ = W.shape
    return np.einsum("gij,ab->giajb", W, np.eye(n)).reshape(g, m * n, m * n)


def _r_symmetric(sigma: float, norm_A: float, lam: float, T: float) -> float:
    if not 0.0 <= sigma < 1.0:
        raise ValueError(f"σ = {sigma} is not in [0, 1): (27) gives no q")
    return 0.0 if sigma == 0.0 else (lam + norm_A) * T / -math.log(sigma)


def _symmetric_rounding(sigma: float, norm_A: float, lam: float, T: float) -> tuple[int, int]:
    """ceil and floor of r = (λ + ||A||)T / ln(1/σ), exactly (decimal arithmetic on the floats' values)."""
    _r_symmetric(sigma, norm_A, lam, T)                          # the range check
    if sigma == 0.0:
        return 0, 0
    with localcontext() as ctx:
        ctx.prec = 1200
        u = Decimal(1) - exact_decimal(sigma)
    digits = max(0, int(math.log10(max(_r_symmetric(sigma, norm_A, lam, T), 1.0)))) + 2
    _, ceil, floor = _ratio_and_rounding((lam, norm_A, T), u, digits)
    return ceil, floor


def q_symmetric(sigma: float, norm_A: float, lam: float, T: float) -> int:
    """Smallest integer q with q > ceil((λ + ||A||)T / ln(1/σ))  (27); σ = 0 (every P_i = 0) gives 1.
    Exact (the rounding is decided in decimal arithmetic, not on the float r)."""
    return _symmetric_rounding(sigma, norm_A, lam, T)[0] + 1


def r_symmetric(sigma: float, norm_A: float, lam: float, T: float) -> float:
    """r = (λ + ||A||)T / ln(1/σ), the quantity (27) rounds up (0 for σ = 0)."""
    return _r_symmetric(sigma, norm_A, lam, T)


def q_symmetric_minimal(sigma: float, norm_A: float, lam: float, T: float) -> int:
    """Smallest q with e^{||A||T} σ^q < e^{-λT} (the need stated before (27)), exact."""
    return _symmetric_rounding(sigma, norm_A, lam, T)[1] + 1
