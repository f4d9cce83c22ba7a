"""Assumption checks and tail bounds for Riccati maps switched along walks of a Markov chain.

* Connectivity on average (C.1): Ā irreducible and aperiodic, its SLEM and the total-variation
  decay d_v(e_nᵀ Āˢ, U) of eq (83).
* Detectability along walks (D.1): a walk w = (n₁, …, n_ℓ) of the support graph of Ā whose
  Gramian G_w = Σ_i (F^{i−1})ᵀ C_{n_i}ᵀ C_{n_i} F^{i−1} is invertible; found by breadth-first
  search (shortest first) and recorded, never assumed.
* Lemma 14's constant: the corrected sub-optimal estimator covariance Σ_sub along a witness,
  with g_w(X) ⪯ Σ_sub for every X ⪰ 0; and Lemma 15's exact tail bound β_t(J) by a killed
  chain on the (node, matched prefix) automaton of the witness.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np
import scipy.sparse.csgraph as csg

from .gossip_kalman import GossipSystem, riccati_step

__all__ = ["ChainCheck", "check_chain", "tv_to_uniform", "pbh_undetectable", "walk_gramian", "WitnessSearch",
           "search_witness", "sigma_sub", "sigma_sub_printed", "compose_walk", "k_of_J", "tail_bound_single",
           "tail_bound_multi", "lifted_chain_stationary"]


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
    n_cls, labels = csg.connected_components(support, directed=True, connection="strong")
    classes = tuple(tuple(int(i) for i in np.flatnonzero(labels == c)) for c in range(n_cls))
    eig = np.sort(np.linalg.eigvalsh(0.5 * (Abar + Abar.T)))
    unit = int(np.sum(np.abs(eig - 1) < 1e-9))
    slem = float(np.sort(np.abs(eig))[-2]) if len(eig) > 1 else 0.0
    aperiodic = all(_class_aperiodic(support, cls) for cls in classes)
    return ChainCheck(n_cls == 1, aperiodic, n_cls, classes, unit, slem, float(eig[0]))


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


def tv_to_uniform(Abar: np.ndarray, steps: int) -> np.ndarray:
    """max_n (1/2)‖e_nᵀ Āˢ − 1ᵀ/N‖₁ for s = 0..steps-1, eq (83)."""
    n = len(Abar)
    out, P = [], np.eye(n)
    for _ in range(steps):
        out.append(0.5 * np.abs(P - 1.0 / n).sum(axis=1).max())
        P = P @ Abar
    return np.array(out)


def pbh_undetectable(F: np.ndarray, C: np.ndarray, *, stable_only_strict: bool = True) -> list[complex]:
    """Eigenvalues λ of F with |λ| ≥ 1 and rank [F − λI; C] < M (PBH): empty iff (F, C) is detectable."""
    M = F.shape[0]
    bad = []
    for lam in np.linalg.eigvals(F):
        if abs(lam) < 1 - 1e-12:
            continue
        stacked = np.vstack([F - lam * np.eye(M), C]) if C.size else F - lam * np.eye(M)
        if np.linalg.matrix_rank(stacked, tol=1e-9 * max(1.0, np.abs(stacked).max())) < M:
            bad.append(complex(lam))
    return bad


def observable(F: np.ndarray, C: np.ndarray) -> bool:
    M = F.shape[0]
    O = np.vstack([C @ np.linalg.matrix_power(F, k) for k in range(M)])
    return bool(np.linalg.matrix_rank(O, tol=1e-9 * max(1.0, np.abs(O).max())) == M)


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


def _invertible(G: np.ndarray, rel: float) -> np.ndarray:
    eig = np.linalg.eigvalsh(G)
    return eig[..., 0] > rel * np.maximum(1.0, eig[..., -1])


@dataclass(frozen=True)
class WitnessSearch:
    witness: tuple[int, ...] | None
    gramian: np.ndarray | None
    max_rank: int
    max_len: int
    walks_checked: int
    windows: tuple[tuple[int, ...], ...]  # every walk of the witness's length with an invertible Gramian


def search_witness(sys: GossipSystem, Abar: np.ndarray, max_len: int = 6, rel: float = 1e-8,
                   max_walks: int = 400_000) -> WitnessSearch:
    """Shortest Ā-walk with an invertible Gramian (breadth first, walks may repeat nodes and use
    self-loops where Ā[n, n] > 0). Also returns all witnesses of that length."""
    N, M = sys.N, sys.M
    support = Abar > 1e-12
    walks = np.arange(N)[:, None]
    G = np.einsum("nim,nik->nmk", sys.C, sys.C)
    Fp = np.eye(M)
    checked, max_rank = 0, 0
    for ell in range(1, max_len + 1):
        checked += len(walks)
        ranks = np.linalg.matrix_rank(G, tol=None) if len(G) else np.array([0])
        max_rank = max(max_rank, int(np.max(ranks)))
        ok = _invertible(G, rel)
        if ok.any():
            first = int(np.flatnonzero(ok)[0])
            return WitnessSearch(tuple(int(x) for x in walks[first]), G[first], max_rank, ell, checked,
                                 tuple(tuple(int(x) for x in w) for w in walks[ok]))
        if ell == max_len:
            break
        Fp = sys.F @ Fp
        term = np.einsum("ma,nim,nik,kb->nab", Fp, sys.C, sys.C, Fp)
        parent, child = np.nonzero(support[walks[:, -1]])
        if len(parent) > max_walks:
            break
        walks = np.hstack([walks[parent], child[:, None]])
        G = G[parent] + term[child]
        # prune walks that end at the same node with the same Gramian (same future)
        key = np.round(np.concatenate([walks[:, -1:].astype(float), G.reshape(len(G), -1)], axis=1), 10)
        _, keep = np.unique(key, axis=0, return_index=True)
        keep = np.sort(keep)
        walks, G = walks[keep], G[keep]
    return WitnessSearch(None, None, max_rank, max_len, checked, ())


def compose_walk(sys: GossipSystem, walk: Sequence[int], X: np.ndarray) -> np.ndarray:
    """g_w(X) = f_{n_ℓ} ∘ … ∘ f_{n_1}(X), eq (40) (f_{n_1} first), batched over X."""
    for n in walk:
        X = riccati_step(X, sys.C[n], sys.R[n], sys.F, sys.Q)
    return X


def sigma_sub(sys: GossipSystem, walk: Sequence[int]) -> np.ndarray:
    """Error covariance of the corrected sub-optimal estimator of x(ℓ+1) along the walk
    (Lemma 14, (118)-(120) with Cᵀ and the process-noise term restored)."""
    F, M, ell = sys.F, sys.M, len(walk)
    Gt = walk_gramian(sys, walk, weighted=True)
    Gi = np.linalg.inv(Gt)
    Fl = np.linalg.matrix_power(F, ell)
    out = Fl @ Gi @ Fl.T
    Rinv = [np.linalg.inv(sys.R[n]) for n in walk]
    for s in range(1, ell + 1):
        acc = np.zeros((M, M))
        for t in range(s + 1, ell + 1):
            n = walk[t - 1]
            acc += np.linalg.matrix_power(F, t - 1).T @ sys.C[n].T @ Rinv[t - 1] @ sys.C[n] @ np.linalg.matrix_power(F, t - 1 - s)
        Ks = np.linalg.matrix_power(F, ell - s) - Fl @ Gi @ acc
        out += Ks @ sys.Q @ Ks.T
    return 0.5 * (out + out.T)


def sigma_sub_printed(sys: GossipSystem, walk: Sequence[int]) -> np.ndarray:
    """The bound as printed in (120): F^ℓ G̃⁻¹ (F^ℓ)ᵀ (the process-noise term is missing)."""
    Fl = np.linalg.matrix_power(sys.F, len(walk))
    return Fl @ np.linalg.inv(walk_gramian(sys, walk, weighted=True)) @ Fl.T


def k_of_J(alpha: float, alpha0: float, qnorm: float, J: float, k_max: int = 100_000) -> int:
    """k(J) = max{k : α^{2k} α₀ + (α^{2k} − 1)/(α² − 1) ‖Q‖ ≤ J}, eq (124) (α = 1: the sum is k); −1 if J < α₀."""
    if J < alpha0:
        return -1
    a2 = alpha * alpha
    k = 0
    while k < k_max:
        nk = k + 1
        geo = nk if abs(a2 - 1) < 1e-15 else (a2 ** nk - 1) / (a2 - 1)
        if a2 ** nk * alpha0 + geo * qnorm > J:
            return k
        k = nk
    return k_max


def _kmp_next(pattern: Sequence[int], k: int, node: int) -> int:
    """Length of the longest prefix of pattern that is a suffix of pattern[:k] + [node]."""
    s = list(pattern[:k]) + [node]
    for length in range(min(len(pattern), len(s)), -1, -1):
        if length == 0 or s[len(s) - length:] == list(pattern[:length]):
            return length
    return 0


def tail_bound_single(Abar: np.ndarray, witness: Sequence[int], L: int) -> float:
    """P(a stationary path of L nodes contains no occurrence of the witness), exact (Lemma 15)."""
    N, ell = len(Abar), len(witness)
    if L < ell:
        return 1.0
    trans = np.array([[_kmp_next(witness, k, n) for n in range(N)] for k in range(ell)])
    v = np.zeros((N, ell))
    for n in range(N):
        k = trans[0, n]
        if k < ell:
            v[n, k] += 1.0 / N
    for _ in range(L - 1):
        nv = np.zeros_like(v)
        for k in range(ell):
            flow = v[:, k] @ Abar  # mass arriving at each next node from prefix state k
            nk = trans[k]
            alive = nk < ell
            np.add.at(nv, (np.flatnonzero(alive), nk[alive]), flow[alive])
        v = nv
    return float(v.sum())


def tail_bound_multi(Abar: np.ndarray, windows: Sequence[Sequence[int]], L: int) -> float:
    """P(no window of W occurs in a stationary path of L nodes); all windows have one length ℓ.
    State: the last ℓ−1 nodes (ℓ = 1: no occurrence means every node avoids W)."""
    N = len(Abar)
    ell = len(windows[0])
    W = set(tuple(w) for w in windows)
    if L < ell:
        return 1.0
    if ell == 1:
        keep = np.array([(n,) not in W for n in range(N)], float)
        v = keep / N
        for _ in range(L - 1):
            v = (v @ Abar) * keep
        return float(v.sum())
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
    for _ in range(L - ell + 1):
        v = v @ T
    return float(v.sum())


def lifted_chain_stationary(Abar: np.ndarray, ell: int) -> tuple[list[tuple[int, ...]], np.ndarray, np.ndarray, np.ndarray]:
    """Windows z = (i₁..i_ℓ) of (132), the stationary vector of the lifted chain (133) computed as the
    left unit eigenvector, the corrected formula (1/N) Π Ā[i_j, i_{j+1}] and (134) as printed
    (1/N) Π_j Ā[j, j+1] (literal node labels)."""
    import itertools

    N = len(Abar)
    Z = [z for z in itertools.product(range(N), repeat=ell) if all(Abar[a, b] > 0 for a, b in zip(z[:-1], z[1:]))]
    idx = {z: i for i, z in enumerate(Z)}
    T = np.zeros((len(Z), len(Z)))
    for z in Z:
        for n in np.flatnonzero(Abar[z[-1]] > 0):
            T[idx[z], idx[z[1:] + (int(n),)]] = Abar[z[-1], n]
    vals, vecs = np.linalg.eig(T.T)
    pi = np.real(vecs[:, np.argmin(np.abs(vals - 1))])
    pi = pi / pi.sum()
    corrected = np.array([np.prod([Abar[a, b] for a, b in zip(z[:-1], z[1:])]) / N for z in Z])
    printed = np.full(len(Z), np.prod([Abar[j, j + 1] for j in range(ell - 1)]) / N)
    return Z, pi, corrected, printed
