"""`GraphSpec.edge_array` (numpy, no networkx for the deterministic kinds) against networkx's `build()`: the same
undirected edges in the same sorted order for every valid `[graph]` table, so that a stage that switches from one to
the other (compare's link model, whose Topology sorts its edges) computes the same numbers."""
from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from dse.estimators.link_models import Topology
from dse.scenario.graphs import graph


def _sorted_build_edges(spec) -> np.ndarray:
    return np.array(sorted((min(u, v), max(u, v)) for u, v in spec.build().edges()), dtype=np.int64).reshape(-1, 2)


@st.composite
def graph_tables(draw):
    kind = draw(st.sampled_from(["line", "ring", "complete", "grid", "random_geometric", "edges"]))
    if kind == "grid":
        return {"kind": kind, "rows": draw(st.integers(1, 6)), "cols": draw(st.integers(2, 6))}
    n = draw(st.integers(3 if kind == "ring" else 2, 12))
    if kind == "random_geometric":
        return {"kind": kind, "n": n, "radius": draw(st.floats(0.05, 1.5)), "seed": draw(st.integers(0, 50))}
    if kind == "edges":
        pairs = [(u, v) for u in range(n) for v in range(u + 1, n)]
        chosen = draw(st.lists(st.sampled_from(pairs), unique=True, max_size=len(pairs)))
        flipped = draw(st.lists(st.booleans(), min_size=len(chosen), max_size=len(chosen)))
        return {"kind": kind, "n": n, "edges": [[v, u] if f else [u, v] for (u, v), f in zip(chosen, flipped)]}
    return {"kind": kind, "n": n}


@settings(max_examples=150, deadline=None)
@given(graph_tables())
def test_edge_array_is_the_sorted_edge_list_of_the_networkx_graph(table):
    spec = graph(table, connected=False)
    assert np.array_equal(spec.edge_array(), _sorted_build_edges(spec))
    from_numpy = Topology.from_edges(spec.n, spec.edge_array().tolist())
    from_networkx = Topology.from_edges(spec.n, list(spec.build().edges()))
    assert from_numpy.n_nodes == from_networkx.n_nodes
    assert from_numpy.edges.dtype == from_networkx.edges.dtype
    assert np.array_equal(from_numpy.edges, from_networkx.edges)


@settings(max_examples=150, deadline=None)
@given(graph_tables())
def test_bipartite_test_agrees_with_networkx(table):
    import networkx as nx

    spec = graph(table, connected=False)
    assert Topology.from_edges(spec.n, spec.edge_array().tolist()).is_bipartite() == nx.is_bipartite(spec.build())
