"""Communication graphs: construction from a scenario, Laplacians, consensus weights.

Nodes are always the integers 0..n-1. Graph kinds: ``line`` (path), ``ring``, ``grid``
(rows x cols lattice), ``complete``, ``random_geometric`` (unit square, seeded) and
``edges`` (an explicit undirected edge list).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Literal, Mapping

import numpy as np
from pydantic import model_validator

from dse.scenario.declare import Real, Section, key
from dse.errors import ScenarioError
from dse.scenario.fields import join

GRAPH_KINDS = ("line", "ring", "grid", "complete", "random_geometric", "edges")
MAX_NODES = 10_000


@dataclass(frozen=True)
class GraphSpec:
    """A declarative undirected graph on nodes 0..n-1."""

    kind: str
    n: int
    rows: int = 0
    cols: int = 0
    radius: float = 0.0
    seed: int = 0
    edges: tuple[tuple[int, int], ...] = ()

    def edge_array(self) -> np.ndarray:
        """The undirected edges (u < v) as an (E, 2) integer array, without building a networkx
        graph for the deterministic kinds (the same edges as `build`)."""
        n = self.n
        if self.kind == "line":
            e = np.column_stack([np.arange(n - 1), np.arange(1, n)])
        elif self.kind == "ring":
            e = np.column_stack([np.arange(n), (np.arange(n) + 1) % n])
        elif self.kind == "complete":
            e = np.column_stack(np.triu_indices(n, 1))
        elif self.kind == "grid":
            idx = np.arange(n).reshape(self.rows, self.cols)
            e = np.concatenate([np.column_stack([idx[:, :-1].ravel(), idx[:, 1:].ravel()]),
                                np.column_stack([idx[:-1, :].ravel(), idx[1:, :].ravel()])])
        elif self.kind == "edges":
            e = np.array(self.edges, dtype=int).reshape(-1, 2)
        else:
            e = np.array(sorted(self.build().edges()), dtype=int).reshape(-1, 2)
        e = np.sort(e.astype(int), axis=1)
        return e[np.lexsort((e[:, 1], e[:, 0]))] if len(e) else e.reshape(0, 2)

    def is_connected(self) -> bool:
        """Connectivity by union-find over `edge_array` (no networkx needed)."""
        parent = np.arange(self.n)

        def root(i):
            while parent[i] != i:
                parent[i] = parent[parent[i]]
                i = parent[i]
            return i

        for u, v in self.edge_array():
            ru, rv = root(u), root(v)
            if ru != rv:
                parent[ru] = rv
        return len({root(i) for i in range(self.n)}) == 1

    def build(self) -> "nx.Graph":
        """The networkx graph with integer nodes 0..n-1 (and a 'pos' attribute when natural)."""
        import networkx as nx

        if self.kind == "line":
            G = nx.path_graph(self.n)
        elif self.kind == "ring":
            G = nx.cycle_graph(self.n)
        elif self.kind == "complete":
            G = nx.complete_graph(self.n)
        elif self.kind == "grid":
            G = nx.convert_node_labels_to_integers(nx.grid_2d_graph(self.rows, self.cols), ordering="sorted")
        elif self.kind == "random_geometric":
            G = nx.random_geometric_graph(self.n, self.radius, seed=self.seed)
        elif self.kind == "edges":
            G = nx.Graph()
            G.add_nodes_from(range(self.n))
            G.add_edges_from(self.edges)
        else:  # pragma: no cover - from_dict rejects other kinds
            raise ValueError(f"unknown graph kind {self.kind!r}")
        return G

    def positions(self) -> np.ndarray:
        """Fixed drawing positions (n, 2), deterministic, for figures and recordings (networkx only
        for the random kinds and explicit edge lists)."""
        if self.kind == "line":
            return np.column_stack([np.arange(self.n, dtype=float), np.zeros(self.n)])
        if self.kind in ("ring", "complete"):
            angle = 2 * np.pi * np.arange(self.n) / self.n
            return np.column_stack([np.cos(angle), np.sin(angle)])
        if self.kind == "grid":
            idx = np.arange(self.n)
            return np.column_stack([idx % self.cols, -(idx // self.cols)]).astype(float)
        G = self.build()
        if self.kind == "random_geometric":
            return np.array([G.nodes[i]["pos"] for i in range(self.n)], dtype=float)
        import networkx as nx

        pos = nx.spring_layout(G, seed=0)
        return np.array([pos[i] for i in range(self.n)], dtype=float)


def nodes_and_edges(G: "nx.Graph | GraphSpec") -> tuple[int, np.ndarray]:
    """(n, (E, 2) edges) of a networkx graph or of a GraphSpec (whose deterministic kinds need no networkx)."""
    if hasattr(G, "edge_array"):
        return G.n, G.edge_array()
    return G.number_of_nodes(), np.array(list(G.edges()), dtype=int).reshape(-1, 2)


def degrees(G: "nx.Graph | GraphSpec") -> np.ndarray:
    n, e = nodes_and_edges(G)
    return np.bincount(e.ravel(), minlength=n)


def laplacian(G: "nx.Graph | GraphSpec") -> np.ndarray:
    """Combinatorial Laplacian L = D - A with unit edge weights, nodes in order 0..n-1 (dense)."""
    n, e = nodes_and_edges(G)
    A = np.zeros((n, n))
    A[e[:, 0], e[:, 1]] = A[e[:, 1], e[:, 0]] = 1.0
    return np.diag(A.sum(axis=1)) - A


def laplacian_consensus_weights(G: "nx.Graph | GraphSpec", eps: float) -> np.ndarray:
    """Q = I - eps L: symmetric and doubly stochastic; nonnegative and primitive iff 0 < eps < 1/d_max."""
    L = laplacian(G)
    return np.eye(len(L)) - eps * L


def metropolis_weights(G: "nx.Graph | GraphSpec") -> np.ndarray:
    """Metropolis-Hastings weights: q_ij = 1/(1 + max(d_i, d_j)) on edges; symmetric, doubly stochastic."""
    n, e = nodes_and_edges(G)
    deg = np.bincount(e.ravel(), minlength=n)
    Q = np.zeros((n, n))
    w = 1.0 / (1.0 + np.maximum(deg[e[:, 0]], deg[e[:, 1]]))
    Q[e[:, 0], e[:, 1]] = Q[e[:, 1], e[:, 0]] = w
    Q[np.diag_indices(n)] = 1.0 - Q.sum(axis=1)
    return Q


def max_degree(G: "nx.Graph | GraphSpec") -> int:
    return int(degrees(G).max(initial=0))


def check_consensus_matrix(Q: np.ndarray, field: str, *, tol: float = 1e-10, primitive: bool = True) -> None:
    """Raise ScenarioError unless Q is square, nonnegative and doubly stochastic (and, with
    `primitive`, has a simple unit eigenvalue and all others strictly inside the unit disk)."""
    if Q.ndim != 2 or Q.shape[0] != Q.shape[1]:
        raise ScenarioError(field, f"must be square, got shape {Q.shape}")
    if Q.min() < -tol:
        raise ScenarioError(field, f"must be nonnegative (min entry {Q.min():.3g})")
    if np.abs(Q.sum(axis=1) - 1).max() > tol:
        raise ScenarioError(field, "rows must sum to 1 (row stochastic)")
    if np.abs(Q.sum(axis=0) - 1).max() > tol:
        raise ScenarioError(field, "columns must sum to 1 (doubly stochastic)")
    if primitive and len(Q) > 1:
        second = np.sort(np.abs(np.linalg.eigvals(Q)))[-2]
        if second > 1 - 1e-9:
            raise ScenarioError(field, f"must be primitive (consensus needs |λ| < 1 for every eigenvalue but one; "
                                       f"second largest |λ| = {second:.6g})")


# -- the [graph] and [consensus] tables, declared once for every family ------------------------------------

class GraphSection(Section):
    """The communication graph on nodes 0..n-1. Edges are undirected; self-loops and repeated
    edges (also reversed, [1, 0] after [0, 1]) are rejected; whether a disconnected graph is
    accepted is up to the family (see its `connected` rule)."""

    kind: Literal[GRAPH_KINDS] = key(doc="line (path), ring, grid (rows x cols lattice), complete, "  # type: ignore[valid-type]
                                         "random_geometric (unit square, seeded) or edges (an explicit list)")
    n: int | None = key(None, doc="number of nodes (every kind but grid)", ge=2, le=MAX_NODES,
                        constraint="required unless kind = grid; a ring needs n >= 3")
    rows: int | None = key(None, doc="lattice rows (kind = grid)", ge=1, le=MAX_NODES)
    cols: int | None = key(None, doc="lattice columns (kind = grid)", ge=1, le=MAX_NODES,
                           constraint=f"2 <= rows x cols <= {MAX_NODES}")
    radius: Real | None = key(None, doc="connection radius in the unit square (kind = random_geometric)", gt=0,
                              unit="unit-square lengths")
    seed: int | None = key(None, doc="seed of the random node positions (kind = random_geometric; default 0)", ge=0)
    edges: list[list[int]] | None = key(None, doc="undirected edges as pairs [u, v] of node indices (kind = edges)")

    @model_validator(mode="after")
    def _kind_rules(self):
        needs = {"line": {"n"}, "ring": {"n"}, "complete": {"n"}, "grid": {"rows", "cols"},
                 "random_geometric": {"n", "radius"}, "edges": {"n", "edges"}}[self.kind]
        optional = {"seed"} if self.kind == "random_geometric" else set()
        for name in ("n", "rows", "cols", "radius", "seed", "edges"):
            given = getattr(self, name) is not None
            if name in needs and not given:
                raise ScenarioError(name, f"missing (needed for kind '{self.kind}')")
            if given and name not in needs | optional:
                raise ScenarioError(name, f"not a key of kind '{self.kind}'")
        if self.kind == "ring" and self.n < 3:
            raise ScenarioError("n", "a ring needs at least 3 nodes")
        if self.kind == "grid" and self.rows * self.cols > MAX_NODES:
            raise ScenarioError("rows", f"rows x cols = {self.rows * self.cols} nodes, more than the supported {MAX_NODES}")
        if self.kind == "grid" and self.rows * self.cols < 2:
            raise ScenarioError("cols", "rows x cols = 1 node; a network has at least 2 nodes")
        if self.kind == "edges":
            seen: dict[tuple[int, int], int] = {}
            for i, e in enumerate(self.edges):
                if len(e) != 2:
                    raise ScenarioError(f"edges[{i}]", "each edge must be a pair [u, v]")
                u, v = e
                if not (0 <= u < self.n and 0 <= v < self.n):
                    raise ScenarioError(f"edges[{i}]", f"node indices must be in 0..{self.n - 1}, got {e}")
                if u == v:
                    raise ScenarioError(f"edges[{i}]", f"self-loop at node {u} is not allowed")
                pair = (min(u, v), max(u, v))
                if pair in seen:
                    raise ScenarioError(f"edges[{i}]", f"repeats edge {list(self.edges[seen[pair]])} (edges[{seen[pair]}]); "
                                                        "edges are undirected and listed once")
                seen[pair] = i
        return self

    def spec(self) -> GraphSpec:
        if self.kind == "grid":
            return GraphSpec("grid", self.rows * self.cols, rows=self.rows, cols=self.cols)
        return GraphSpec(self.kind, self.n, radius=self.radius or 0.0, seed=self.seed or 0,
                         edges=tuple(sorted((min(u, v), max(u, v)) for u, v in self.edges or ())))


def graph_from_section(section: Any, field: str = "graph", *, connected: bool = True, min_nodes: int = 2) -> GraphSpec:
    """The graph of a declared `[graph]` table, with the project's one policy for degenerate
    networks: at least `min_nodes` nodes, and connected unless the family states that a
    disconnected network is meaningful for it (then connectivity is a hypothesis it reports)."""
    spec = section.spec()
    if spec.n < min_nodes:
        raise ScenarioError(join(field, "n"), f"a network needs at least {min_nodes} nodes, got {spec.n}")
    if connected and not spec.is_connected():
        raise ScenarioError(field, "graph is not connected (the theorems need a connected graph)")
    return spec


def graph(data: Mapping[str, Any], field: str = "graph", *, connected: bool = True, min_nodes: int = 2) -> GraphSpec:
    """The graph of a plain `[graph]` table (a dict), validated by its declaration (`GraphSection`)."""
    from dse.scenario.declare import parse

    return graph_from_section(parse(GraphSection, data, field), field, connected=connected, min_nodes=min_nodes)


def random_graph_table(rng: np.random.Generator, n_min: int, n_max: int,
                       kinds: tuple[str, ...] = GRAPH_KINDS) -> dict[str, Any]:
    """A `[graph]` table of a connected graph of a kind drawn from `kinds`, with n_min..n_max nodes (n_min >= 2;
    a ring gets at least 3, a grid as many as rows x cols allows): what the scenario generators draw so that
    every kind and its keys (grid rows and cols, a random geometric graph's radius and seed, an explicit edge
    list) are exercised. A random geometric radius grows until the graph is connected; an edge list is a
    random spanning tree plus a few random chords."""
    kind = str(kinds[int(rng.integers(0, len(kinds)))])
    n = int(rng.integers(n_min, n_max + 1))
    if kind == "ring":
        return {"kind": kind, "n": max(n, 3)}
    if kind in ("line", "complete"):
        return {"kind": kind, "n": n}
    if kind == "grid":
        rows = int(rng.integers(1, math.isqrt(n_max) + 1))
        lo = max(-(-n_min // rows), 2 if rows == 1 else 1)
        return {"kind": kind, "rows": rows, "cols": int(rng.integers(lo, max(lo, n_max // rows) + 1))}
    if kind == "random_geometric":
        seed, radius = int(rng.integers(0, 10_000)), float(np.round(rng.uniform(0.3, 0.7), 3))
        while not GraphSpec(kind, n, radius=radius, seed=seed).is_connected():
            radius = float(np.round(radius * 1.25, 3))
        return {"kind": kind, "n": n, "radius": radius, "seed": seed}
    order = rng.permutation(n)
    edges = {tuple(sorted((int(order[i]), int(order[rng.integers(0, i)])))) for i in range(1, n)}
    for _ in range(int(rng.integers(0, n))):
        u, v = (int(x) for x in rng.choice(n, 2, replace=False))
        edges.add((min(u, v), max(u, v)))
    return {"kind": "edges", "n": n, "edges": [list(e) for e in sorted(edges)]}
