"""Assumption checks and tail bounds for Riccati maps switched along walks of a Markov chain.

* Connectivity on average (C.1): Ā irreducible and aperiodic, its SLEM and the total-variation
  decay d_v(e_nᵀ Āˢ, U) of eq (83).
* Detectability along walks (D.1): a walk w = (n₁, …, n_ℓ) of the support graph of Ā whose
  Gramian G_w = Σ_i (F^{i−1})ᵀ C_{n_i}ᵀ C_{n_i} F^{i−1} is invertible; found by breadth-first
  search (shortest first) and recorded, never assumed. `decide_d1` also certifies failures: on
  any walk, range(G_w) ⊆ rowspace(C_{n₁}) + rowspace(O_c F) with O_c the observability matrix of
  the walk's class, so D.1 fails when every [C_n; O_c F] is rank deficient.
* Floating-point decisions have three outcomes: a ratio of singular values above
  `CERTAIN_RATIO` is nonsingular, one below `SINGULAR_RATIO` (a few hundred eps) is singular to
  working precision, and anything in between is left undecided rather than guessed.
* Lemma 14's constant: the corrected sub-optimal estimator covariance Σ_sub along a witness,
  with g_w(X) ⪯ Σ_sub for every X ⪰ 0; and Lemma 15's exact tail bound β_t(J) by a killed
  chain on the (node, matched prefix) automaton of the witness.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from .gikf_maps import GossipSystem, riccati_step

__all__ = ["ChainCheck", "check_chain", "singular_ratios", "observability_matrix", "tv_to_uniform", "tv_rows", "pbh_undetectable",
           "unobservable_modes", "walk_gramian",
           "WitnessSearch", "search_witness", "D1Decision", "decide_d1", "sigma_sub", "sigma_sub_printed", "compose_walk",
           "k_of_J", "tail_bound_single", "tail_bound_multi", "tail_bounds_single", "tail_bounds_multi", "lifted_chain_stationary", "CERTAIN_RATIO", "SINGULAR_RATIO"]

EPS = float(np.finfo(float).eps)
#: a Gramian (or stacked rank test) whose λ_min/λ_max (σ_min/σ_max) exceeds this is invertible beyond doubt:
#: its round-off is ~ℓ·M·eps relative, eight orders of magnitude below
CERTAIN_RATIO = 1e-8
#: below this ratio of singular values a matrix is singular to working precision (its computed smallest
#: singular value is at the round-off of the largest one)
SINGULAR_RATIO = 300 * EPS


@dataclass(frozen=True)
class ChainCheck:
    irreducible: bool
    aperiodic: bool
    n_classes: int
    classes: tuple[tuple[int, ...], ...]
    unit_multiplicity: int
    slem: float
    min_eig: float

    @property
    def c1(self) -> bool:
        return self.irreducible and self.aperiodic


def check_chain(Abar: np.ndarray, tol: float = 1e-12) -> ChainCheck:
    """C.1 for a symmetric stochastic Ā: irreducible (one communicating class) and aperiodic
    (no eigenvalue −1); SLEM = max_{k≥2} |λ_k|."""
    support = (Abar > tol).astype(int)
    n_cls, labels = _strong_components(support)
    classes = tuple(tuple(int(i) for i in np.flatnonzero(labels == c)) for c in range(n_cls))
    eig = np.sort(np.linalg.eigvalsh(0.5 * (Abar + Abar.T)))
    unit = int(np.sum(np.abs(eig - 1) < 1e-9))
    slem = float(np.sort(np.abs(eig))[-2]) if len(eig) > 1 else 0.0
    aperiodic = all(_class_aperiodic(support, cls) for cls in classes)
    return ChainCheck(n_cls == 1, aperiodic, n_cls, classes, unit, slem, float(eig[0]))


def _strong_components(support: np.ndarray) -> tuple[int, np.ndarray]:
    """The strongly connected components of a 0/1 support, labelled as scipy's
    `connected_components(support, directed=True, connection="strong")` labels them. A symmetric
    support (every Ā of a gossip protocol) is labelled here, by breadth-first search in the order of
    each component's first node (scipy's order for symmetric supports): `dse check` then need not
    import scipy.sparse (0.1 s)."""
    if not np.array_equal(support, support.T):
        import scipy.sparse.csgraph as csg

        return csg.connected_components(support, directed=True, connection="strong")
    n = len(support)
    labels = np.full(n, -1, dtype=np.int32)
    n_cls = 0
    for root in range(n):
        if labels[root] >= 0:
            continue
        labels[root] = n_cls
        frontier = [root]
        while frontier:
            nxt = np.flatnonzero(support[frontier].any(axis=0) & (labels < 0))
            labels[nxt] = n_cls
            frontier = nxt.tolist()
        n_cls += 1
    return n_cls, labels


def _class_aperiodic(support: np.ndarray, cls: Sequence[int]) -> bool:
    """gcd of cycle lengths through the class is 1 (BFS level parity test generalised)."""
    cls = list(cls)
    sub = support[np.ix_(cls, cls)]
    if np.any(np.diag(sub)):
        return True
    level = {0: 0}
    frontier = [0]
    g = 0
    while frontier:
        nxt = []
        for u in frontier:
            for v in np.flatnonzero(sub[u]):
                if v not in level:
                    level[v] = level[u] + 1
                    nxt.append(v)
                else:
                    g = math.gcd(g, level[u] + 1 - level[v])
        frontier = nxt
    return g == 1


def tv_to_uniform(Abar: np.ndarray, steps: int, max_rows: int = 64) -> np.ndarray:
    """max_n (1/2)‖e_nᵀ Āˢ − 1ᵀ/N‖₁ for s = 0..steps-1, eq (83): over every start node n when N ≤ max_rows,
    else over `tv_rows` (max_rows start nodes, 0 and 1 among them), which keeps the cost at
    max_rows·N² per step."""
    n = len(Abar)
    out, P = [], np.eye(n)[tv_rows(n, max_rows)]
    for _ in range(steps):
        out.append(0.5 * np.abs(P - 1.0 / n).sum(axis=1).max())
        P = P @ Abar
    return np.array(out)


def tv_rows(n: int, max_rows: int = 64) -> np.ndarray:
    """The start nodes of `tv_to_uniform`: all, or max_rows evenly spaced ones (0 and 1 included)."""
    if n <= max_rows:
        return np.arange(n)
    return np.unique(np.concatenate([[0, 1], np.linspace(0, n - 1, max_rows - 2).astype(int)]))


def pbh_undetectable(F: np.ndarray, C: np.ndarray) -> list[complex]:
    """Eigenvalues λ of F with |λ| ≥ 1 that (F, C) cannot see: empty iff (F, C) is detectable.

    Computed as the eigenvalues of F on the unobservable subspace (`unobservable_modes`), which is
    equivalent to the PBH test rank [F − λI; C] < M and stays reliable for repeated eigenvalues."""
    _, lam = unobservable_modes(F, C)
    return [complex(x) for x in lam if abs(x) >= 1 - 1e-12]


def observability_matrix(F: np.ndarray, C: np.ndarray, first: int = 0) -> np.ndarray:
    """[C F^first; …; C F^(first+M−1)], each row scaled to unit norm (zero rows dropped): row scaling
    leaves the null space unchanged and keeps unstable powers from swamping the rank decision."""
    M = F.shape[0]
    O = np.vstack([C @ np.linalg.matrix_power(F, k) for k in range(first, first + M)]) if C.size else np.zeros((0, M))
    norms = np.linalg.norm(O, axis=1)
    return O[norms > 0] / norms[norms > 0, None]


def _singular_ratios(A: np.ndarray, M: int) -> np.ndarray:
    """The M singular values of A (padded with zeros when A has fewer rows) over the largest."""
    s = np.linalg.svd(A, compute_uv=False) if A.size else np.zeros(0)
    s = np.concatenate([s, np.zeros(max(0, M - len(s)))])[:M]
    return s / s[0] if len(s) and s[0] > 0 else np.zeros(M)


singular_ratios = _singular_ratios


def observable(F: np.ndarray, C: np.ndarray) -> bool | None:
    """(F, C) observable: True / False when decided to working precision, None in between."""
    r = _singular_ratios(observability_matrix(F, C), F.shape[0])[-1]
    return True if r > CERTAIN_RATIO else (False if r <= SINGULAR_RATIO else None)


def unobservable_modes(F: np.ndarray, C: np.ndarray) -> tuple[np.ndarray | None, np.ndarray]:
    """Eigenvalues of F on the unobservable subspace of (F, C) and whether the subspace is decided.

    The subspace is the null space of the observability matrix (singular values at the round-off
    level); returns (None, eigenvalues found) when some singular value lies between the two
    thresholds, i.e. when the dimension of the subspace cannot be decided in floating point. This
    avoids PBH tests at computed eigenvalues, which are inaccurate for Jordan blocks."""
    M = F.shape[0]
    O = observability_matrix(F, C)
    if O.shape[0] == 0:
        return np.linalg.eigvals(F), np.linalg.eigvals(F)
    _, s, Vt = np.linalg.svd(O)
    s = np.concatenate([s, np.zeros(max(0, M - len(s)))])[:M] / s[0]
    null = s <= SINGULAR_RATIO
    V = Vt.T[:, null] if null.any() else np.zeros((M, 0))
    lam = np.linalg.eigvals(V.T @ F @ V) if V.shape[1] else np.zeros(0)
    decided = not np.any((s > SINGULAR_RATIO) & (s <= CERTAIN_RATIO))
    return (lam if decided else None), lam


def walk_gramian(sys: GossipSystem, walk: Sequence[int], *, weighted: bool = False) -> np.ndarray:
    """G_w of D.1 (weighted: G̃_w of (117) with R⁻¹)."""
    M = sys.M
    G = np.zeros((M, M))
    Fp = np.eye(M)
    for n in walk:
        W = np.linalg.inv(sys.R[n]) if weighted else np.eye(sys.R.shape[-1])
        G += Fp.T @ sys.C[n].T @ W @ sys.C[n] @ Fp
        Fp = sys.F @ Fp
    return G


def _gramian_ratio(G: np.ndarray) -> np.ndarray:
    """λ_min(G)/λ_max(G) (0 for G = 0), batched: scale free, unlike an absolute threshold."""
    eig = np.linalg.eigvalsh(G)
    return np.where(eig[..., -1] > 0, eig[..., 0] / np.where(eig[..., -1] > 0, eig[..., -1], 1.0), 0.0)


@dataclass(frozen=True)
class WitnessSearch:
    witness: tuple[int, ...] | None
    gramian: np.ndarray | None
    max_rank: int
    max_len: int
    walks_checked: int
    #: every Ā-walk of the witness's length with an invertible Gramian (all of them, none merged), or
    #: () when there are more walks of that length than `max_windows` (then `windows_complete` is False)
    windows: tuple[tuple[int, ...], ...]
    ratio: float = 0.0            # λ_min/λ_max of the witness Gramian (or the best ratio seen when none)
    windows_complete: bool = True


def _walk_terms(sys: GossipSystem, length: int) -> np.ndarray:
    """(length, N, M, M): (F^k)ᵀ C_nᵀ C_n F^k for k = 0..length−1."""
    out, Fp = [], np.eye(sys.M)
    for _ in range(length):
        out.append(np.einsum("ma,nim,nik,kb->nab", Fp, sys.C, sys.C, Fp))
        Fp = sys.F @ Fp
    return np.array(out)


def search_witness(sys: GossipSystem, Abar: np.ndarray, max_len: int = 6, rel: float = CERTAIN_RATIO,
                   max_walks: int = 400_000, max_windows: int = 200_000) -> WitnessSearch:
    """Shortest Ā-walk whose Gramian has λ_min/λ_max > rel (breadth first; walks may repeat nodes and
    use self-loops where Ā[n, n] > 0), and every witness walk of that length.

    The breadth-first search for existence merges walks that end at the same node with the same
    Gramian (they have the same extensions). The list of witnesses is then enumerated again without
    merging: two such walks can pass through sensors with the same C and different R, and differ in
    the constants (Σ_sub) that Lemma 15's all-windows bound takes the maximum of."""
    N, M = sys.N, sys.M
    support = Abar > 1e-12
    terms = _walk_terms(sys, max_len)
    walks = np.arange(N)[:, None]
    G = terms[0].copy()
    checked, max_rank, best = 0, 0, 0.0
    for ell in range(1, max_len + 1):
        checked += len(walks)
        ranks = np.linalg.matrix_rank(G) if len(G) else np.array([0])
        max_rank = max(max_rank, int(np.max(ranks)))
        ratio = _gramian_ratio(G)
        best = max(best, float(ratio.max()))
        ok = ratio > rel
        if ok.any():
            first = int(np.flatnonzero(ok)[0])
            windows, complete = _all_windows(terms, support, ell, rel, max_windows)
            return WitnessSearch(tuple(int(x) for x in walks[first]), G[first], max_rank, ell, checked, windows,
                                 float(ratio[first]), complete)
        if ell == max_len:
            break
        parent, child = np.nonzero(support[walks[:, -1]])
        if len(parent) > max_walks:
            break
        walks = np.hstack([walks[parent], child[:, None]])
        G = G[parent] + terms[ell][child]
        # merge walks that end at the same node with the same Gramian (same future), existence only
        key = np.round(np.concatenate([walks[:, -1:].astype(float), G.reshape(len(G), -1)], axis=1), 10)
        _, keep = np.unique(key, axis=0, return_index=True)
        keep = np.sort(keep)
        walks, G = walks[keep], G[keep]
    return WitnessSearch(None, None, max_rank, max_len, checked, (), best, True)


def _all_windows(terms: np.ndarray, support: np.ndarray, ell: int, rel: float,
                 max_windows: int) -> tuple[tuple[tuple[int, ...], ...], bool]:
    """Every Ā-walk of length ℓ with an invertible Gramian, enumerated without merging."""
    N = support.shape[0]
    walks = np.arange(N)[:, None]
    G = terms[0].copy()
    for k in range(1, ell):
        parent, child = np.nonzero(support[walks[:, -1]])
        if len(parent) > max_windows:
            return (), False
        walks = np.hstack([walks[parent], child[:, None]])
        G = G[parent] + terms[k][child]
    ok = _gramian_ratio(G) > rel
    return tuple(tuple(int(x) for x in w) for w in walks[ok]), True


@dataclass(frozen=True)
class D1Decision:
    """D.1 ("some Ā-walk has an invertible Gramian") decided: holds True / False / None (undecided).

    `how` says what decided it: a witness walk, a certificate of failure (every [C_n; O_c F] of every
    class c is singular to working precision), the derived criterion "F invertible, C.1 and (F, C_all)
    observable" (a witness then exists, possibly longer than the search depth), or nothing."""

    holds: bool | None
    search: WitnessSearch
    how: str
    certificate_ratio: float  # largest σ_min/σ_max of [C_n; O_c F] over the classes' sensors


def decide_d1(sys: GossipSystem, Abar: np.ndarray, classes: Sequence[Sequence[int]], c1: bool,
              max_len: int = 6) -> D1Decision:
    """Decide D.1 for the support of Ā with the given communicating classes (see D1Decision)."""
    M = sys.M
    search = search_witness(sys, Abar, max_len=max_len)
    cert = 0.0
    for cls in classes:
        OF = observability_matrix(sys.F, sys.C[list(cls)].reshape(-1, M), first=1)
        for n in cls:
            stacked = np.vstack([sys.C[n], OF]) if OF.size else sys.C[n]
            cert = max(cert, float(_singular_ratios(stacked, M)[-1]))
    if search.witness is not None:
        return D1Decision(True, search, f"witness walk {search.witness} (λ_min/λ_max of its Gramian "
                                        f"{search.ratio:.3g} > {CERTAIN_RATIO:g})", cert)
    if cert <= SINGULAR_RATIO:
        return D1Decision(False, search, f"certificate: on any Ā-walk range(G_w) ⊆ rowspace(C_n₁) + rowspace(O_c F), "
                                         f"and every [C_n; O_c F] is singular (largest σ_min/σ_max {cert:.2g} ≤ "
                                         f"{SINGULAR_RATIO:.2g})", cert)
    F_ratio = float(_singular_ratios(sys.F, M)[-1])
    if c1 and F_ratio > CERTAIN_RATIO and observable(sys.F, sys.C.reshape(-1, M)) is True:
        return D1Decision(True, search, "F invertible, C.1 and (F, C_all) observable: a witness exists (a walk "
                                        f"through rank-raising (node, time) pairs), longer than the search depth {max_len}",
                          cert)
    return D1Decision(None, search, f"no walk of length ≤ {max_len} has a Gramian with λ_min/λ_max > {CERTAIN_RATIO:g} "
                                    f"(best {search.ratio:.2g}), and no certificate of failure (largest σ_min/σ_max of "
                                    f"[C_n; O_c F] is {cert:.2g} > {SINGULAR_RATIO:.2g})", cert)


def compose_walk(sys: GossipSystem, walk: Sequence[int], X: np.ndarray) -> np.ndarray:
    """g_w(X) = f_{n_ℓ} ∘ … ∘ f_{n_1}(X), eq (40) (f_{n_1} first), batched over X."""
    for n in walk:
        X = riccati_step(X, sys.C[n], sys.R[n], sys.F, sys.Q)
    return X


def sigma_sub(sys: GossipSystem, walk: Sequence[int]) -> np.ndarray:
    """Error covariance of the corrected sub-optimal estimator of x(ℓ+1) along the walk
    (Lemma 14, (118)-(120) with Cᵀ and the process-noise term restored):

        Σ_sub = F^ℓ G̃⁻¹ F^ℓᵀ + Σ_s K_s Q K_sᵀ,  K_s = F^{ℓ−s} − F^ℓ G̃⁻¹ Σ_{t>s} (F^{t−1})ᵀ C_tᵀ R_t⁻¹ C_t F^{t−1−s},

    with G̃ the R⁻¹-weighted Gramian (117). G̃ and R_t enter through linear solves, never explicit inverses."""
    F, M, ell = sys.F, sys.M, len(walk)
    Gt = walk_gramian(sys, walk, weighted=True)
    Fl = np.linalg.matrix_power(F, ell)
    FG = np.linalg.solve(Gt, Fl.T).T                      # F^ℓ G̃⁻¹ (G̃ symmetric)
    out = FG @ Fl.T
    CRC = [sys.C[n].T @ np.linalg.solve(sys.R[n], sys.C[n]) for n in walk]
    for s in range(1, ell + 1):
        acc = np.zeros((M, M))
        for t in range(s + 1, ell + 1):
            acc += np.linalg.matrix_power(F, t - 1).T @ CRC[t - 1] @ np.linalg.matrix_power(F, t - 1 - s)
        Ks = np.linalg.matrix_power(F, ell - s) - FG @ acc
        out += Ks @ sys.Q @ Ks.T
    return 0.5 * (out + out.T)


def sigma_sub_printed(sys: GossipSystem, walk: Sequence[int]) -> np.ndarray:
    """The bound as printed in (120): F^ℓ G̃⁻¹ (F^ℓ)ᵀ (the process-noise term is missing)."""
    Fl = np.linalg.matrix_power(sys.F, len(walk))
    out = Fl @ np.linalg.solve(walk_gramian(sys, walk, weighted=True), Fl.T)
    return 0.5 * (out + out.T)


def k_of_J(alpha: float, alpha0: float, qnorm: float, J: float, k_max: int = 100_000) -> int:
    """k(J) = max{k : α^{2k} α₀ + (α^{2k} − 1)/(α² − 1) ‖Q‖ ≤ J}, eq (124) (α = 1: the sum is k); −1 if J < α₀.
    The left side is monotone in k (it is a^k (α₀ − L) + L with a = α², L = ‖Q‖/(1 − a), or increasing), so
    "exceeds J" switches once: found by bisection. Capped at k_max (for α < 1 it may never exceed J)."""
    if J < alpha0:
        return -1
    a2 = alpha * alpha

    def exceeds(k: int) -> bool:
        with np.errstate(over="ignore", invalid="ignore"):
            p = a2 ** k if a2 <= 1 else math.exp(min(k * math.log(a2), 700.0))
            geo = k if abs(a2 - 1) < 1e-15 else (p - 1) / (a2 - 1)
            return not (p * alpha0 + geo * qnorm <= J)

    if not exceeds(k_max):
        return k_max
    lo, hi = 0, k_max  # exceeds(hi) is True; exceeds(0) = (α₀ > J) is False
    while hi - lo > 1:
        mid = (lo + hi) // 2
        lo, hi = (lo, mid) if exceeds(mid) else (mid, hi)
    return lo


def _kmp_next(pattern: Sequence[int], k: int, node: int) -> int:
    """Length of the longest prefix of pattern that is a suffix of pattern[:k] + [node]."""
    s = list(pattern[:k]) + [node]
    for length in range(min(len(pattern), len(s)), -1, -1):
        if length == 0 or s[len(s) - length:] == list(pattern[:length]):
            return length
    return 0


def _sums_at(v: np.ndarray, step, lengths: np.ndarray, ell: int, offset: int) -> np.ndarray:
    """For each L of `lengths`: 1 where L < ℓ, otherwise v.sum() after L − offset applications of `step`
    (one propagation up to the longest L gives every L the numbers of its own propagation)."""
    out = np.ones(len(lengths))
    wanted = lengths >= ell
    if not wanted.any():
        return out
    sums = [float(v.sum())]
    for _ in range(int(lengths[wanted].max()) - offset):
        v = step(v)
        sums.append(float(v.sum()))
    out[wanted] = np.array(sums)[lengths[wanted] - offset]
    return out


def tail_bounds_single(Abar: np.ndarray, witness: Sequence[int], lengths: Sequence[int]) -> np.ndarray:
    """P(a stationary path of L nodes contains no occurrence of the witness), exact (Lemma 15), for each L."""
    lengths = np.asarray(lengths, dtype=int).reshape(-1)
    N, ell = len(Abar), len(witness)
    trans = np.array([[_kmp_next(witness, k, n) for n in range(N)] for k in range(ell)])
    v = np.zeros((N, ell))
    for n in range(N):
        k = trans[0, n]
        if k < ell:
            v[n, k] += 1.0 / N

    def step(v):
        nv = np.zeros_like(v)
        for k in range(ell):
            flow = v[:, k] @ Abar  # mass arriving at each next node from prefix state k
            nk = trans[k]
            alive = nk < ell
            np.add.at(nv, (np.flatnonzero(alive), nk[alive]), flow[alive])
        return nv

    return _sums_at(v, step, lengths, ell, 1)     # a path of L nodes: v after L − 1 steps


def tail_bound_single(Abar: np.ndarray, witness: Sequence[int], L: int) -> float:
    """P(a stationary path of L nodes contains no occurrence of the witness), exact (Lemma 15)."""
    return float(tail_bounds_single(Abar, witness, [L])[0])


def tail_bounds_multi(Abar: np.ndarray, windows: Sequence[Sequence[int]], lengths: Sequence[int]) -> np.ndarray:
    """P(no window of W occurs in a stationary path of L nodes) for each L; all windows have one length ℓ.
    State: the last ℓ−1 nodes (ℓ = 1: no occurrence means every node avoids W)."""
    lengths = np.asarray(lengths, dtype=int).reshape(-1)
    N = len(Abar)
    ell = len(windows[0])
    W = set(tuple(w) for w in windows)
    if not (lengths >= ell).any():
        return np.ones(len(lengths))
    if ell == 1:
        keep = np.array([(n,) not in W for n in range(N)], float)
        return _sums_at(keep / N, lambda v: (v @ Abar) * keep, lengths, 1, 1)
    import itertools

    states = [s for s in itertools.product(range(N), repeat=ell - 1)
              if all(Abar[a, b] > 0 for a, b in zip(s[:-1], s[1:]))]
    index = {s: i for i, s in enumerate(states)}
    v = np.zeros(len(states))
    for s in states:
        p = 1.0 / N
        for a, b in zip(s[:-1], s[1:]):
            p *= Abar[a, b]
        v[index[s]] = p
    T = np.zeros((len(states), len(states)))
    for s in states:
        for n in np.flatnonzero(Abar[s[-1]] > 0):
            if s + (int(n),) in W:
                continue
            T[index[s], index[s[1:] + (int(n),)]] += Abar[s[-1], n]
    return _sums_at(v, lambda v: v @ T, lengths, ell, ell - 1)     # a path of L nodes: v after L − ℓ + 1 steps


def tail_bound_multi(Abar: np.ndarray, windows: Sequence[Sequence[int]], L: int) -> float:
    """P(no window of W occurs in a stationary path of L nodes); all windows have one length ℓ."""
    return float(tail_bounds_multi(Abar, windows, [L])[0])


def lifted_chain_stationary(Abar: np.ndarray, ell: int) -> tuple[list[tuple[int, ...]], np.ndarray, np.ndarray, np.ndarray]:
    """Windows z = (i₁..i_ℓ) of (132), the stationary vector of the lifted chain (133) (least-squares
    solution of π(I − T) = 0, Σπ = 1: no eigenvector selection), the corrected formula
    (1/N) Π Ā[i_j, i_{j+1}] and (134) as printed, (1/N) Π_j Ā[j, j+1] with literal node labels (NaN
    where the printed product runs past node N: it is then not defined)."""
    import itertools

    N = len(Abar)
    Z = [z for z in itertools.product(range(N), repeat=ell) if all(Abar[a, b] > 0 for a, b in zip(z[:-1], z[1:]))]
    idx = {z: i for i, z in enumerate(Z)}
    T = np.zeros((len(Z), len(Z)))
    for z in Z:
        for n in np.flatnonzero(Abar[z[-1]] > 0):
            T[idx[z], idx[z[1:] + (int(n),)]] = Abar[z[-1], n]
    A = np.vstack([(np.eye(len(Z)) - T).T, np.ones((1, len(Z)))])
    rhs = np.zeros(len(Z) + 1)
    rhs[-1] = 1.0
    pi = np.linalg.lstsq(A, rhs, rcond=None)[0]
    corrected = np.array([np.prod([Abar[a, b] for a, b in zip(z[:-1], z[1:])]) / N for z in Z])
    printed_value = np.prod([Abar[j, j + 1] for j in range(ell - 1)]) / N if ell <= N else np.nan
    return Z, pi, corrected, np.full(len(Z), printed_value)
