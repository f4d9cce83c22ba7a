"""Random communication over the edges of a graph, one time step at a time.

Four link models, each drawn for a batch of Monte Carlo trials at once:

* ``reliable``: every edge works in each of the step's ``rounds`` synchronous rounds;
* ``failures``: in each round every edge works independently with probability 1 − p
  (both directions together);
* ``matchings``: in each round a random maximal matching (edges scanned in the order of
  i.i.d. uniform priorities and kept when both endpoints are still free; Kar & Moura's
  graph-matching protocol), each of its edges then failing independently with probability p;
* ``poisson``: every edge carries a Poisson clock of rate λ per step; the step's exchanges
  are the rings of all clocks in time order, i.e. a Poisson(λ E) number of exchanges, each
  on a uniformly random edge (the superposition of independent clocks). The count is drawn by
  inverting the Poisson CDF, truncated at `max_events` where the omitted tail is below 1e-16.

Communication noise (``noise_std`` σ_c) is not drawn here; see the estimators.

Layout: trials on the last axis. A round's activity is an (E, B) bool mask; Poisson
exchanges are (C, B) edge ids with −1 for "no exchange". The draws are made through a
`dse.simulate.units.UnitStreams`-like object (`random(tail)`, `integers(low, high, tail)`,
returning arrays with trials leading), so that a trial's draws do not depend on the chunk
it is simulated in.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property
from typing import Protocol

import numpy as np

__all__ = ["LINK_KINDS", "Topology", "LinkModel", "StepLinks", "greedy_matching", "swap_permutation",
           "step_permutation"]

LINK_KINDS = ("reliable", "failures", "matchings", "poisson")
#: the Poisson count is truncated where the omitted probability is below this
POISSON_TAIL = 1e-16


class Draws(Protocol):
    def random(self, tail: tuple[int, ...] = ()) -> np.ndarray: ...

    def integers(self, low: int, high: int, tail: tuple[int, ...] = ()) -> np.ndarray: ...


@dataclass(frozen=True, eq=False)
class Topology:
    """An undirected graph on nodes 0..N−1 with edges (E, 2), u < v."""

    n_nodes: int
    edges: np.ndarray

    @classmethod
    def from_edges(cls, n_nodes: int, edges) -> "Topology":
        e = np.array(sorted((min(a, b), max(a, b)) for a, b in edges), dtype=np.int64).reshape(-1, 2)
        return cls(int(n_nodes), e)

    @property
    def E(self) -> int:
        return len(self.edges)

    @cached_property
    def incidence(self) -> np.ndarray:
        """(N, E): +1 at the first endpoint, −1 at the second (D_e = b_e b_eᵀ for column b_e)."""
        B = np.zeros((self.n_nodes, self.E))
        B[self.edges[:, 0], np.arange(self.E)] = 1.0
        B[self.edges[:, 1], np.arange(self.E)] = -1.0
        return B

    @cached_property
    def degrees(self) -> np.ndarray:
        return np.bincount(self.edges.ravel(), minlength=self.n_nodes)

    @cached_property
    def node_edges(self) -> np.ndarray:
        """(N, E) bool: edge e touches node i."""
        return self.incidence != 0

    def laplacian(self, weights=None) -> np.ndarray:
        w = np.ones(self.E) if weights is None else np.asarray(weights, float)
        return (self.incidence * w) @ self.incidence.T

    def metropolis_weights(self) -> np.ndarray:
        """(E,): 1/(1 + max(d_u, d_v)) per edge (Metropolis–Hastings)."""
        d = self.degrees
        return 1.0 / (1.0 + np.maximum(d[self.edges[:, 0]], d[self.edges[:, 1]]))

    def neighbours(self) -> list[list[int]]:
        out: list[list[int]] = [[] for _ in range(self.n_nodes)]
        for u, v in self.edges:
            out[u].append(int(v))
            out[v].append(int(u))
        return out

    def covering_walk(self, stay: int = 1) -> list[int]:
        """A walk from node 0 that visits every node (depth-first, backtracking along the way it came),
        staying `stay` steps at each node it reaches."""
        nb = self.neighbours()
        seen: set[int] = set()
        walk: list[int] = []

        def visit(i: int) -> None:
            seen.add(i)
            walk.extend([i] * stay)
            for j in sorted(nb[i]):
                if j not in seen:
                    visit(j)
                    walk.append(i)

        visit(0)
        return walk

    def is_bipartite(self) -> bool:
        """Whether the nodes split into two sides with every edge across: a breadth-first two-colouring of each
        component finds no edge inside a colour (no odd cycle). Tested against networkx's `is_bipartite`."""
        nb: list[list[int]] = [[] for _ in range(self.n_nodes)]
        for u, v in self.edges.tolist():
            nb[u].append(v)
            nb[v].append(u)
        colour = [-1] * self.n_nodes
        for start in range(self.n_nodes):
            if colour[start] >= 0:
                continue
            colour[start] = 0
            frontier = [start]
            while frontier:
                nxt = []
                for i in frontier:
                    for j in nb[i]:
                        if colour[j] < 0:
                            colour[j] = 1 - colour[i]
                            nxt.append(j)
                        elif colour[j] == colour[i]:
                            return False
                frontier = nxt
        return True


@dataclass
class StepLinks:
    """One step's communication for B trials.

    rounds: per synchronous round an (E, B) bool mask of working edges, or None when every edge
    works (reliable links: the estimators then use fixed weights). events: (C, B) edge ids of
    the step's Poisson exchanges in time order, −1 = none. step_mask: the edges an estimator that
    exchanges once per step uses (the first round's, or every edge that rang at least once)."""

    rounds: list = field(default_factory=list)
    events: np.ndarray | None = None
    step_mask: np.ndarray | None = None


@dataclass(frozen=True, eq=False)
class LinkModel:
    topology: Topology
    kind: str = "reliable"
    rounds: int = 1
    p_fail: float = 0.0
    rate: float = 0.0
    noise_std: float = 0.0

    def __post_init__(self):
        if self.kind not in LINK_KINDS:
            raise ValueError(f"unknown link model {self.kind!r}")
        if not 0.0 <= self.p_fail < 1.0:
            raise ValueError(f"p_fail must be in [0, 1), got {self.p_fail}")
        if self.kind == "poisson" and not self.rate > 0:
            raise ValueError("a Poisson link model needs rate > 0")
        if self.rounds < 1:
            raise ValueError("rounds must be >= 1")

    @property
    def synchronous(self) -> bool:
        return self.kind != "poisson"

    @property
    def random(self) -> bool:
        return self.kind != "reliable" and not (self.kind == "failures" and self.p_fail == 0.0)

    @property
    def n_rounds(self) -> int:
        """Synchronous rounds per step (0 for Poisson exchanges)."""
        return self.rounds if self.synchronous else 0

    @cached_property
    def poisson_cdf(self) -> np.ndarray:
        from scipy.stats import poisson

        mu = self.rate * self.topology.E
        c = int(poisson.isf(POISSON_TAIL, mu)) + 1
        return poisson.cdf(np.arange(c + 1), mu)

    @property
    def max_events(self) -> int:
        return len(self.poisson_cdf) - 1 if self.kind == "poisson" else 0

    def poisson_count_law(self) -> np.ndarray:
        """P(count = c), c = 0..max_events, of the truncated law actually simulated."""
        cdf = self.poisson_cdf.copy()
        cdf[-1] = 1.0
        return np.diff(np.concatenate([[0.0], cdf]))

    # -- one step ----------------------------------------------------------------------------------
    def draw(self, draws: Draws) -> StepLinks:
        topo = self.topology
        out = StepLinks()
        if self.kind == "reliable" or (self.kind == "failures" and self.p_fail == 0.0):
            out.rounds = [None] * self.rounds
            return out
        if self.kind == "failures":
            out.rounds = [draws.random((topo.E,)).T >= self.p_fail for _ in range(self.rounds)]
        elif self.kind == "matchings":
            for _ in range(self.rounds):
                chosen = greedy_matching(topo, draws.random((topo.E,)).T)
                if self.p_fail > 0:
                    chosen &= draws.random((topo.E,)).T >= self.p_fail
                out.rounds.append(chosen)
        else:
            count = np.searchsorted(self.poisson_cdf, draws.random(), side="right")   # (B,), ≤ max_events
            C = self.max_events
            ids = draws.integers(0, topo.E, (C,)).T                                     # (C, B)
            ids[np.arange(C)[:, None] >= count[None, :]] = -1
            out.events = ids
            B = ids.shape[1]
            rang = np.zeros((topo.E + 1, B), bool)
            rang[ids, np.arange(B)[None, :]] = True
            out.step_mask = rang[:topo.E]
            return out
        out.step_mask = out.rounds[0]
        return out

    def stay_witness(self) -> tuple[bool | None, str]:
        """Can a node go through a step without exchanging (a diagonal entry of the mean permutation of a
        filter that swaps states over matchings)? True with the reason, or None when no witness was found."""
        if self.kind == "poisson":
            return True, "with positive probability no link of a node rings in a step"
        if self.kind in ("failures", "matchings") and self.p_fail > 0:
            return True, "with positive probability every link of a node fails"
        topo = self.topology
        rng = np.random.default_rng(0)
        for _ in range(200):      # a maximal matching that leaves some node unmatched (greedy from random orders)
            chosen = greedy_matching(topo, rng.random((topo.E, 1)))[:, 0]
            covered = (topo.node_edges[:, chosen]).any(axis=1)
            if not covered.all():
                return True, (f"the maximal matching {topo.edges[chosen].tolist()} leaves node "
                              f"{int(np.argmin(covered))} alone")
        return None, "no maximal matching leaving a node unmatched was found in 200 random orders"

    # -- exact moments of a synchronous round ------------------------------------------------------
    def edge_activity(self) -> np.ndarray | None:
        """(E,) P(edge works in a round) when rounds are independent edge by edge (reliable,
        failures); None when the edges of a round are dependent (matchings) or not synchronous."""
        if self.kind == "reliable":
            return np.ones(self.topology.E)
        if self.kind == "failures":
            return np.full(self.topology.E, 1.0 - self.p_fail)
        return None


def greedy_matching(topo: Topology, priority: np.ndarray, allowed: np.ndarray | None = None) -> np.ndarray:
    """(E, B) bool: for each trial, the maximal matching of the allowed edges built by scanning
    them in increasing `priority` (E, B) and keeping an edge when both endpoints are free.

    Every maximal matching has positive probability under i.i.d. uniform priorities (give its
    edges the lowest ones). The scan is a loop over the E positions, vectorised over trials."""
    E, B = priority.shape
    N = topo.n_nodes
    order = np.argsort(priority, axis=0)                 # (E, B): k-th edge of each trial
    u, v = topo.edges[:, 0], topo.edges[:, 1]
    cols = np.arange(B)
    fa = u[order] * B + cols                             # flat indices into a (N, B) free mask
    fb = v[order] * B + cols
    ok_edge = np.ones((E, B), bool) if allowed is None else np.take_along_axis(allowed, order, axis=0)
    free = np.ones(N * B, bool)
    taken = np.empty((E, B), bool)
    for k in range(E):
        a, b = fa[k], fb[k]
        ok = free[a] & free[b] & ok_edge[k]
        free[a] &= ~ok
        free[b] &= ~ok
        taken[k] = ok
    chosen = np.empty((E, B), bool)
    np.put_along_axis(chosen, order, taken, axis=0)
    return chosen


def swap_permutation(topo: Topology, links: StepLinks, B: int, *, matching: np.ndarray | None = None
                     ) -> tuple[np.ndarray, np.ndarray]:
    """Where each node's state comes from after the step's swaps, and over how many hops.

    Returns (source (N, B), hops (N, B)): node i holds, after the swaps, the state that node
    source[i] held before them, moved over hops[i] links. A matching (E, B) swaps its pairs
    simultaneously; Poisson exchanges swap one pair each, in time order."""
    N = topo.n_nodes
    src = np.repeat(np.arange(N)[:, None], B, axis=1)
    hops = np.zeros((N, B), np.int64)
    cols = np.arange(B)
    u, v = topo.edges[:, 0], topo.edges[:, 1]
    if matching is not None:
        e, b = np.nonzero(matching)
        src[u[e], b], src[v[e], b] = v[e], u[e]
        hops[u[e], b] = hops[v[e], b] = 1
        return src, hops
    for ids in links.events:
        live = ids >= 0
        if not live.any():
            break
        bb = cols[live]
        i, j = u[ids[live]], v[ids[live]]
        si, sj = src[i, bb], src[j, bb]
        src[i, bb], src[j, bb] = sj, si
        hi, hj = hops[i, bb], hops[j, bb]
        hops[i, bb], hops[j, bb] = hj + 1, hi + 1
    return src, hops


def step_permutation(links: LinkModel, step: StepLinks, B: int, priority: np.ndarray | None
                     ) -> tuple[np.ndarray, np.ndarray]:
    """(source, hops), each (N, B): the state node i holds after the step's swaps came from
    source[i], over hops[i] links."""
    topo = links.topology
    if not links.synchronous:
        return swap_permutation(topo, step, B)
    if links.kind == "matchings":
        matching = step.rounds[0]
    else:
        matching = greedy_matching(topo, priority, step.rounds[0])
    return swap_permutation(topo, step, B, matching=matching)
