"""Random valid template scenarios, biased towards the edge cases (`generate(seed, edge)`):
small enough for a quick run, deterministic in (seed, edge)."""
from __future__ import annotations

from typing import Any

import numpy as np

from dse.scenario.graphs import random_graph_table

EDGES = ("disconnected", "two_nodes", "one_round", "complete", "tiny_noise")


def generate(seed: int, edge: str | None = None) -> dict[str, Any]:
    rng = np.random.default_rng([seed, EDGES.index(edge) + 1 if edge else 0])
    n = int(rng.integers(3, 9))
    graph: dict[str, Any] = {"kind": str(rng.choice(["ring", "line", "complete"])), "n": n}
    r, rounds = float(10 ** rng.uniform(-2, 2)), int(rng.integers(2, 30))
    if edge == "disconnected":
        graph = {"kind": "edges", "n": 4, "edges": [[0, 1], [2, 3]]}
    elif edge == "two_nodes":
        graph = {"kind": "line", "n": 2}
    elif edge == "one_round":
        rounds = 1
    elif edge == "complete":
        graph = {"kind": "complete", "n": n}
    elif edge == "tiny_noise":
        r = 1e-12
    mc: dict[str, Any] = {"trials": 2000}
    extra = np.random.default_rng([seed, EDGES.index(edge) + 1 if edge else 0, 1])   # draws that move no other
    if edge is None and extra.random() < 0.5:
        graph = random_graph_table(extra, 3, 8)        # every kind: grid, random geometric, an edge list too
    if extra.random() < 0.3:
        mc["quick_trials"] = int(extra.integers(500, 2001))
    return {"family": "template", "name": f"template-{edge or 'random'}-{seed}", "graph": graph,
            "model": {"r": r, "rounds": rounds}, "monte_carlo": mc}
