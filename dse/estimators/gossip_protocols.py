"""Gossip protocols of the GIKF: the law of the matching A(t) drawn at every slot t ≥ 1 (A(0) = I).

Each protocol draws `sample(size, rng)`, (size, N) partner arrays (partners[b, n] = the sensor
whose pair n receives, n itself when unmatched), and knows its mean matrix Ā = E[A(t)] (eq (6)):
in closed form (a finite law over matchings, single-edge gossip, node-initiated gossip), by an
exact recursion over edge sets or a Monte Carlo estimate (greedy maximal matching), or as the
average over one cycle of a replayed sequence. `matching_at` is the slot's draw, A(0) = I.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from .gikf_maps import use_compiled

__all__ = ["MatchingDistribution", "SingleEdgeGossip", "MatchingSequence", "NodeInitiatedGossip",
           "GreedyMatchingGossip", "matching_at"]

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

        The scan is a loop over the E positions of the order, vectorised over the batch. With at most 64
        nodes the free nodes of a row are the bits of one word, and each position costs four elementwise
        operations on contiguous words (`_scan_words`); else the free flags are gathered and scattered by
        flat (row, node) indices (`_scan_flags`). Both give the same matching."""
        order = np.argsort(priority, axis=1)                      # (B, E): the k-th edge of every row
        scan = self._scan_words if self.n_nodes <= 64 else self._scan_flags
        taken = scan(np.ascontiguousarray(order.T))               # (E, B): the k-th edge of the row is taken
        chosen = np.empty(priority.shape, bool)
        np.put_along_axis(chosen, order, taken.T, axis=1)
        return chosen

    def _scan_words(self, order: np.ndarray) -> np.ndarray:
        """The greedy scan on (E, B) edge orders with each row's free nodes as the bits of a uint64: the k-th
        edge is taken iff both its endpoint bits are still set, and taking it clears them."""
        u, v = self._ends
        one = np.uint64(1)
        masks = ((one << u.astype(np.uint64)) | (one << v.astype(np.uint64)))[order]     # (E, B) endpoint bits
        E, B = order.shape
        free = np.full(B, np.iinfo(np.uint64).max, np.uint64)
        both = np.empty(B, np.uint64)
        taken = np.empty((E, B), bool)
        for k in range(E):
            mk = masks[k]
            np.bitwise_and(free, mk, out=both)
            np.equal(both, mk, out=taken[k])
            np.multiply(mk, taken[k], out=both)                   # the endpoint bits of a taken edge, else 0
            np.bitwise_xor(free, both, out=free)
        return taken

    def _scan_flags(self, order: np.ndarray) -> np.ndarray:
        """The greedy scan on (E, B) edge orders with one free flag per (row, node): the flat indices of both
        endpoints of the k-th edge of every row are precomputed, so each position costs two gathers and two
        scatters (the indices of one position are distinct, so the scatters need no masking: an endpoint that
        was free stays free iff the other endpoint was already taken)."""
        u, v = self._ends
        E, B = order.shape
        base = np.arange(B) * self.n_nodes
        fa = u[order] + base                                       # flat (row, endpoint) indices
        fb = v[order] + base
        free = np.ones(B * self.n_nodes, bool)
        taken = np.empty((E, B), bool)
        for k in range(E):
            a, b = fa[k], fb[k]
            ga, gb = free[a], free[b]
            ok = ga & gb
            free[a] = ga & ~gb
            free[b] = gb & ~ga
            taken[k] = ok
        return taken

    def sample(self, size: int, rng: np.random.Generator) -> np.ndarray:
        """(size, N) partner arrays of i.i.d. matchings. The greedy scan and the partner arrays are compiled
        (`gikf_compiled`) when `use_compiled`: the same draws from `rng`, the same partners."""
        E = len(self.edges)
        priority = rng.random((size, E))
        if use_compiled(size, item_s=25e-9 * E):            # numpy: ~25 ns per edge and row
            from . import gikf_compiled

            u, v = (np.ascontiguousarray(a) for a in self._ends)
            order, chosen = np.argsort(priority, axis=1), np.zeros(priority.shape, bool)
            if self.n_nodes <= 64:
                one = np.uint64(1)
                gikf_compiled.greedy_chosen_words(order, (one << u.astype(np.uint64)) | (one << v.astype(np.uint64)),
                                                  chosen)
            else:
                gikf_compiled.greedy_chosen_flags(order, u, v, self.n_nodes, chosen)
            n_chosen = int(np.count_nonzero(chosen))
            works = rng.random(n_chosen) < self.p_link if self.p_link < 1.0 else np.ones(n_chosen, bool)
            out = np.tile(np.arange(self.n_nodes), (size, 1))
            gikf_compiled.matching_partners(chosen, works, u, v, out)
            return out
        return self._partners(self.greedy_chosen(priority), rng)

    def _partners(self, chosen: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """The partner arrays of greedy matchings (B, E) after the link failures (drawn from `rng`)."""
        size = len(chosen)
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

