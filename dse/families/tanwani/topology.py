"""The topology sweep S4 of the paper's reproduction (a stage of the paper run only): the main
scenario's plant, sensors and gains on the path, ring, star and complete graphs of 4 nodes, with
α = min(1/2, 1/d_max); per graph and rate λ the steady states of (9) and of the exact mean
covariance, the distance of (9)'s to S and the Loewner gap between them, and the critical rate."""
from __future__ import annotations

import numpy as np

import dse.estimators.gossip_covariance as gc
from dse.contract.stages import stage
from dse.estimators.gossip_filter import GossipSystem
from dse.scenario.graphs import GraphSpec, graph

from .scenario import RandomCommFile

TOPOLOGIES = {"path": {"kind": "line", "n": 4}, "ring": {"kind": "ring", "n": 4},
              "star": {"kind": "edges", "n": 4, "edges": [[0, 1], [0, 2], [0, 3]]}, "complete": {"kind": "complete", "n": 4}}
QUICK_TOPOLOGY_POINTS = 8


def with_graph(s: GossipSystem, graph: GraphSpec) -> GossipSystem:
    """The same plant, sensors and gains on another graph (α = min(1/2, 1/d_max))."""
    edges = tuple(sorted({(int(u), int(v)) for u, v in graph.edge_array()}))
    dmax = int(np.bincount(np.ravel(edges), minlength=graph.n).max())
    return GossipSystem(s.A, s.B, s.H, s.V, s.L, edges, min(0.5, 1.0 / dmax), s.mode, s.P0, s.m0, s.P_init)


@stage(name="topology", allow_nonfinite=tuple(f"{g}_{k}" for g in TOPOLOGIES for k in ("d", "trace_joint",
                                                                                          "crit_bound", "gap")))
def compute_topology(sc: RandomCommFile, quick: bool = False) -> dict[str, np.ndarray]:
    """S4: the main scenario's plant and sensors on the path, ring, star and complete graphs of 4 nodes."""
    lams = np.geomspace(0.3, 1e4, QUICK_TOPOLOGY_POINTS if quick else 20)
    out: dict[str, np.ndarray] = {"lams": lams}
    for name, g in TOPOLOGIES.items():
        s = with_graph(sc.gossip, graph(g))
        fied = float(np.sort(np.linalg.eigvalsh(s.laplacian))[1])
        out[f"{name}_alpha_fiedler"] = np.array(s.alpha * fied)
        S = gc.lyapunov_S(s)
        d, tr = np.full((len(lams), s.N), np.nan), np.full((len(lams), s.N), np.nan)
        gap = np.full(len(lams), np.nan)
        for k, lam in enumerate(lams):
            P = gc.bound_steady(s, lam)
            if P is not None:
                d[k] = np.linalg.norm(P - S, axis=(1, 2))
            Jm = gc.joint_steady(s, lam)
            if Jm is not None:
                Jd = gc.diagonal_blocks(Jm, s.N, s.n)
                tr[k] = np.trace(Jd, axis1=1, axis2=2)
                if P is not None:
                    gap[k] = np.linalg.eigvalsh(P - Jd)[:, 0].min()
        out[f"{name}_d"], out[f"{name}_trace_joint"], out[f"{name}_gap"] = d, tr, gap
        out[f"{name}_crit_bound"] = np.array(gc.critical_rate_bound(s))
    return out
