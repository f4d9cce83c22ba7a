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

import itertools
import math
from dataclasses import dataclass
from decimal import Decimal, getcontext, localcontext

import numpy as np
import scipy.linalg as sla
from scipy.optimize import minimize_scalar
from scipy.signal import place_poles


# -- per-agent quantities ---------------------------------------------------------------------

def observability_matrix(A: np.ndarray, C: np.ndarray) -> np.ndarray:
    """[C; CA; ...; CA^{n-1}]."""
    n = A.shape[0]
    rows, M = [], np.asarray(C, float)
    for _ in range(n):
        rows.append(M)
        M = M @ A
    return np.vstack(rows)


def row_space_basis(O: np.ndarray, rank_tol: float) -> tuple[np.ndarray, np.ndarray]:
    """Orthonormal rows spanning the row space of O (SVD, relative rank tolerance); also the
    singular values, so that a caller can report how clear the rank decision was."""
    _, sv, Vt = np.linalg.svd(O)
    rank = int(np.sum(sv > rank_tol * max(sv[0], 1e-300))) if sv.size else 0
    return Vt[:rank], sv


@dataclass(frozen=True)
class LocalDesign:
    """The design objects of one agent (§2 of the construction).

    L (n_i x n): full row rank, ker L = unobservable space of (C_i, A).
    Abar (n_i x n_i), Cbar (s_i x n_i): the unique solutions of L A = Abar L, C_i = Cbar L.
    Q (n x n_i) = L'(L L')^{-1};  P (n x n) = I - Q L, the orthogonal projection onto ker L.
    """

    L: np.ndarray
    Abar: np.ndarray
    Cbar: np.ndarray
    Q: np.ndarray
    P: np.ndarray
    singular_values: np.ndarray

    @property
    def n_i(self) -> int:
        return self.L.shape[0]


def local_design(A: np.ndarray, C: np.ndarray, *, rank_tol: float = 1e-9, L: np.ndarray | None = None) -> LocalDesign:
    """L_i (orthonormal rows of the observable row space unless given), Ā_i, C̄_i, Q_i, P_i."""
    O = observability_matrix(A, C)
    basis, sv = row_space_basis(O, rank_tol)
    if L is None:
        L = basis
    L = np.asarray(L, float)
    Q = L.T @ np.linalg.inv(L @ L.T)
    Abar = L @ A @ Q              # unique solution of L A = Abar L when ker L is A-invariant
    Cbar = np.asarray(C, float) @ Q
    P = np.eye(A.shape[0]) - Q @ L
    return LocalDesign(L, Abar, Cbar, Q, P, sv)


def same_kernel(L: np.ndarray, A: np.ndarray, C: np.ndarray, rank_tol: float = 1e-9) -> bool:
    """True iff L has full row rank and ker L = ker O(C, A)."""
    basis, _ = row_space_basis(observability_matrix(A, C), rank_tol)
    if np.linalg.matrix_rank(L) != L.shape[0] or L.shape[0] != basis.shape[0]:
        return False
    return np.linalg.matrix_rank(np.vstack([L, basis]), tol=rank_tol * 10 * max(1.0, np.abs(L).max())) == basis.shape[0]


def place_gain(Abar: np.ndarray, Cbar: np.ndarray, poles) -> np.ndarray:
    """K with eig(Ā + K C̄) = poles (note the + sign of (3))."""
    return -place_poles(Abar.T, Cbar.T, np.asarray(poles)).gain_matrix.T


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
    step = sla.expm(G * h)
    E = np.empty((samples, *F.shape))
    E[0] = np.eye(len(F))
    for k in range(1, samples):
        E[k] = E[k - 1] @ step
    vals = spectral_norm(E)
    k = int(np.argmax(vals))
    best = float(vals[k])
    lo, hi = max(k - 1, 0) * h, min(k + 1, samples - 1) * h
    if hi > lo:
        res = minimize_scalar(lambda t: -np.linalg.norm(sla.expm(G * t), 2), bounds=(lo, hi), method="bounded",
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


def flocking_matrix(N: np.ndarray) -> np.ndarray:
    """F[i, j] = 1/|N_i| for j ∈ N_i (straight averaging (13)); row stochastic."""
    Nf = N.astype(float)
    return Nf / Nf.sum(axis=1, keepdims=True)


def symmetric_weights(N: np.ndarray, m_design: int | None = None) -> np.ndarray:
    """The convex-combination rule (25): self 1 - (|N_i| - 1)/(m+1), each other neighbour 1/(m+1)."""
    m = len(N) if m_design is None else m_design
    W = N.astype(float) / (m + 1)
    np.fill_diagonal(W, 0.0)
    W[np.diag_indices(len(N))] = 1.0 - W.sum(axis=1)
    return W


def strongly_connected_digraphs(m: int) -> np.ndarray:
    """All strongly connected digraphs with self-arcs on m labelled vertices, (count, m, m) masks."""
    off = [(i, j) for i in range(m) for j in range(m) if i != j]
    out = []
    for bits in range(1 << len(off)):
        N = np.eye(m, dtype=bool)
        for b, (i, j) in enumerate(off):
            if bits >> b & 1:
                N[i, j] = True
        if is_strongly_connected(N):
            out.append(N)
    return np.array(out)


def connected_undirected_graphs(m: int) -> np.ndarray:
    """All connected simple undirected graphs on m labelled vertices as symmetric masks with self-arcs."""
    pairs = list(itertools.combinations(range(m), 2))
    out = []
    for bits in range(1 << len(pairs)):
        N = np.eye(m, dtype=bool)
        for b, (i, j) in enumerate(pairs):
            if bits >> b & 1:
                N[i, j] = N[j, i] = True
        if is_strongly_connected(N):
            out.append(N)
    return np.array(out)


# -- norms --------------------------------------------------------------------------------------

def spectral_norm(M: np.ndarray) -> np.ndarray:
    """||M||_2 batched over leading axes (largest eigenvalue of MᵀM or MMᵀ, the smaller one)."""
    M = np.asarray(M, float)
    G = np.swapaxes(M, -1, -2) @ M if M.shape[-1] <= M.shape[-2] else M @ np.swapaxes(M, -1, -2)
    return np.sqrt(np.maximum(np.linalg.eigvalsh(G)[..., -1], 0.0))


def mixed_norm(M: np.ndarray, row_sizes, col_sizes) -> float | np.ndarray:
    """|M| = max row sum of the matrix of blockwise spectral norms (Sec. 3). Batched over
    leading axes."""
    M = np.asarray(M, float)
    r = np.concatenate([[0], np.cumsum(row_sizes)])
    c = np.concatenate([[0], np.cumsum(col_sizes)])
    blocks = np.stack([np.stack([spectral_norm(M[..., r[a]:r[a + 1], c[b]:c[b + 1]])
                                 for b in range(len(col_sizes))], axis=-1) for a in range(len(row_sizes))], axis=-2)
    return blocks.sum(axis=-1).max(axis=-1)


# -- ρ (17) -------------------------------------------------------------------------------------

@dataclass(frozen=True)
class RhoResult:
    rho: float
    exact: bool
    words: int
    worst_word: tuple[int, ...]


def rho_exact(P_blocks: np.ndarray, *, max_words: int = 3_000_000, rng: np.random.Generator | None = None,
              samples: int = 200_000) -> RhoResult:
    """ρ = max ||P_{i1} ··· P_{iN}|| over products of N = (m-1)^2 + 1 factors containing every P_i (17).

    P_i² = P_i, so the set equals the repeat-free words of length <= N containing all letters;
    appending a factor never increases the norm (||W P_a|| <= ||W||), so only the words that
    become complete at their last letter need evaluating. Exhaustive (exact) when their number
    is below `max_words`; otherwise random complete words give a lower estimate (exact=False).
    """
    P = np.asarray(P_blocks, float)
    m = len(P)
    N = (m - 1) ** 2 + 1
    full = (1 << m) - 1
    if m == 1:
        return RhoResult(float(np.linalg.norm(P[0], 2)), True, 1, (0,))
    # count minimal complete words first (dynamic programming over (mask, last))
    count = 0
    counts = {(1 << a, a): 1 for a in range(m)}
    for _ in range(2, N + 1):
        nxt: dict = {}
        for (mask, last), c in counts.items():
            for a in range(m):
                if a == last:
                    continue
                key = (mask | 1 << a, a)
                if key[0] == full:
                    count += c
                else:
                    nxt[key] = nxt.get(key, 0) + c
        counts = nxt
    if count > max_words:
        rng = rng or np.random.default_rng(0)
        best, worst = 0.0, ()
        for _ in range(max(1, samples // 10_000)):
            words = _random_complete_words(m, N, 10_000, rng)
            for w in words:
                M = P[w[0]]
                for a in w[1:]:
                    M = M @ P[a]
                v = np.linalg.norm(M, 2)
                if v > best:
                    best, worst = float(v), tuple(int(x) for x in w)
        return RhoResult(best, False, samples, worst)
    prods = P.copy()
    last = np.arange(m)
    mask = 1 << last
    words = [[a] for a in range(m)]
    best, worst, seen = -1.0, (), 0
    for _ in range(2, N + 1):
        new_p, new_l, new_m, new_w = [], [], [], []
        for a in range(m):
            sel = np.nonzero(last != a)[0]
            if sel.size == 0:
                continue
            pa = prods[sel] @ P[a]
            ma = mask[sel] | (1 << a)
            done = ma == full
            if done.any():
                nrm = np.linalg.norm(pa[done], ord=2, axis=(1, 2))
                seen += int(done.sum())
                k = int(np.argmax(nrm))
                if nrm[k] > best:
                    best = float(nrm[k])
                    worst = tuple(words[sel[np.nonzero(done)[0][k]]]) + (a,)
            keep = ~done
            new_p.append(pa[keep])
            new_l.append(np.full(int(keep.sum()), a))
            new_m.append(ma[keep])
            new_w.extend(words[i] + [a] for i in sel[keep])
        if not new_p or sum(len(x) for x in new_l) == 0:
            break
        prods, last, mask, words = np.concatenate(new_p), np.concatenate(new_l), np.concatenate(new_m), new_w
    return RhoResult(max(best, 0.0), True, seen, worst)


def _random_complete_words(m: int, N: int, k: int, rng: np.random.Generator) -> list[np.ndarray]:
    out = []
    while len(out) < k:
        length = int(rng.integers(m, N + 1))
        w = [int(rng.integers(m))]
        while len(w) < length:
            a = int(rng.integers(m - 1))
            w.append(a if a < w[-1] else a + 1)
        if len(set(w)) == m:
            out.append(np.array(w))
    return out


def count_complete_repeat_free_words(m: int, max_len: int) -> int:
    """Number of repeat-free words over m letters of length <= max_len containing every letter
    (inclusion-exclusion; the regression value for m = 4, max_len = 10 is 105,936)."""
    total = 0
    for L in range(1, max_len + 1):
        for k in range(m + 1):
            # words over a fixed k-letter subset, repeat-free, length L: k (k-1)^(L-1)
            words = k * (k - 1) ** (L - 1) if k > 0 else 0
            total += (-1) ** (m - k) * math.comb(m, k) * words
    return total


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


def sufficient_q(rho: float, m: int, norm_A: float, lam: float, T: float, *, prec: int | None = None) -> SufficientQ:
    """α = 1 - (m-1)(1-ρ)/m^{(m-1)²} (Lemma 5) and as printed in (18), 1 - (m-1)(1-ρ)/(m(m-1)²);
    r = (λ + ||A||)T / ln(1/α) and the three q variants, all in exact decimal arithmetic so that
    nothing overflows or rounds 1 - α to zero (1 - α ≈ m^{-(m-1)²})."""
    if m < 2:
        raise ValueError("m >= 2 (for m = 1, P_1 = 0 and q = 1 suffices)")
    N = (m - 1) ** 2 + 1
    with localcontext() as ctx:
        # r has about (m-1)² log10(m) integer digits: carry 40 more so that ceil/floor are exact
        ctx.prec = prec or int((m - 1) ** 2 * math.log10(m)) + 60
        one_minus_rho = Decimal(1) - Decimal(repr(float(rho)))
        u5 = Decimal(m - 1) * one_minus_rho / Decimal(m) ** ((m - 1) ** 2)
        up = Decimal(m - 1) * one_minus_rho / (Decimal(m) * Decimal(m - 1) ** 2)
        num = (Decimal(repr(float(lam))) + Decimal(repr(float(norm_A)))) * Decimal(repr(float(T)))
        r5 = num / _ln1p_neg(u5)
        rp = num / _ln1p_neg(up)
        c5, f5 = int(r5.to_integral_value(rounding="ROUND_CEILING")), int(r5.to_integral_value(rounding="ROUND_FLOOR"))
        cp, fp = int(rp.to_integral_value(rounding="ROUND_CEILING")), int(rp.to_integral_value(rounding="ROUND_FLOOR"))
        log10_u5 = float(u5.log10())
        return SufficientQ(Decimal(1) - u5, Decimal(1) - up, log10_u5, r5, rp, N * c5 + 1, N * (c5 + 1), N * (f5 + 1),
                           N * cp + 1, N * (fp + 1))


def sigma_symmetric(P_blocks: np.ndarray, graphs: np.ndarray | None = None, m_design: int | None = None
                    ) -> tuple[float, int, np.ndarray]:
    """σ = max over symmetric strongly connected graphs G of ||P (M_G ⊗ I)||_2 (26), with
    M_G = I - L_G/(m+1); all connected graphs on m vertices unless `graphs` is given. Returns σ,
    the index of the worst graph and the per-graph values."""
    P = np.asarray(P_blocks, float)
    m, n, _ = P.shape
    graphs = connected_undirected_graphs(m) if graphs is None else graphs
    Pbig = sla.block_diag(*P)
    Ms = np.array([symmetric_weights(G, m_design) for G in graphs])
    big = Pbig @ _kron_batch(Ms, n)
    vals = np.linalg.norm(big, ord=2, axis=(1, 2))
    k = int(np.argmax(vals))
    return float(vals[k]), k, vals


def _kron_batch(W: np.ndarray, n: int) -> np.ndarray:
    g, m, _ = W.shape
    return np.einsum("gij,ab->giajb", W, np.eye(n)).reshape(g, m * n, m * n)


def q_symmetric(sigma: float, norm_A: float, lam: float, T: float) -> int:
    """Smallest integer q with q > ceil((λ + ||A||)T / ln(1/σ))  (27)."""
    return int(math.ceil((lam + norm_A) * T / -math.log(sigma))) + 1


def q_symmetric_minimal(sigma: float, norm_A: float, lam: float, T: float) -> int:
    """Smallest q with e^{||A||T} σ^q < e^{-λT} (the need stated before (27))."""
    r = (lam + norm_A) * T / -math.log(sigma)
    return int(math.floor(r)) + 1
