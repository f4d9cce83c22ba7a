"""Consensus rounds over the working edges of one communication round, batched over trials.

A round with edge weights q_e (E,) and working edges b_e (a mask (E, B), or all edges) mixes
node values by W = I − Σ_e b_e q_e D_e, D_e = (u_a − u_b)(u_a − u_b)ᵀ for edge e = (a, b): the
weight of a failed link falls back on the node itself, so W stays symmetric and doubly
stochastic. A symmetric doubly stochastic consensus matrix Q with the graph's pattern is
exactly I − Σ_e Q_ab D_e, so fixed weights Q are the case "every edge works".

Values are arrays with the node axis first and trials last, (N, ..., B).
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from .link_models import Topology

__all__ = ["Mixer", "heard", "link_count"]


@dataclass(frozen=True, eq=False)
class Mixer:
    topology: Topology
    weights: np.ndarray     # (E,) q_e

    @cached_property
    def matrix(self) -> np.ndarray:
        """W with every edge working, (N, N)."""
        inc = self.topology.incidence
        return np.eye(self.topology.n_nodes) - (inc * self.weights) @ inc.T

    @cached_property
    def _sparse(self):
        import scipy.sparse as sp

        inc = self.topology.incidence
        return sp.csr_matrix(inc), sp.csr_matrix(inc.T)

    def mix(self, X: np.ndarray, mask: np.ndarray | None = None) -> np.ndarray:
        """W X for values X (N, ..., B) and a round's working edges (E, B) (None: all)."""
        N = X.shape[0]
        flat = X.reshape(N, -1)
        if mask is None:
            return (self.matrix @ flat).reshape(X.shape)
        inc, incT = self._sparse
        E = inc.shape[1]
        B = mask.shape[1]
        if X.shape[-1] != B:                                            # values shared by the trials
            X = np.broadcast_to(X, X.shape[:-1] + (B,))
            flat = np.ascontiguousarray(X).reshape(N, -1)
        diff = (incT @ flat).reshape((E,) + X.shape[1:])               # x_a − x_b per edge
        diff *= (self.weights[:, None] * mask).reshape((E,) + (1,) * (X.ndim - 2) + (B,))
        return X - (inc @ diff.reshape(E, -1)).reshape(X.shape)

    def matrix_of(self, mask_column: np.ndarray) -> np.ndarray:
        """W for one trial's working edges (E,) bool (tests, exact recursions)."""
        inc = self.topology.incidence
        return np.eye(self.topology.n_nodes) - (inc * (self.weights * mask_column)) @ inc.T


def link_count(topology: Topology, mask: np.ndarray | None, B: int) -> np.ndarray:
    """(N, B) float: the node's working links in the round."""
    if mask is None:
        return np.broadcast_to(topology.degrees.astype(float)[:, None], (topology.n_nodes, B))
    cache = topology.__dict__.setdefault("_sparse_node_edges", [])
    if not cache:
        import scipy.sparse as sp

        cache.append(sp.csr_matrix(topology.node_edges.astype(float)))
    return cache[0] @ mask.astype(float)


def heard(topology: Topology, mask: np.ndarray | None, B: int) -> np.ndarray:
    """(N, B) bool: the node had at least one working link in the round."""
    if mask is None:
        return np.broadcast_to((topology.degrees > 0)[:, None], (topology.n_nodes, B))
    return (topology.node_edges.astype(float) @ mask) > 0
