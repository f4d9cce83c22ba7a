"""Random valid scenarios of the gossip-kalman family, biased towards the hard cases.

`generate(seed, edge)` returns a scenario dict as a user's TOML file would give it. The
edge cases (`EDGES`) are the situations in which a check can mistake something else for a
counterexample:

* ``c1-fail-oblique`` / ``d1-fail-oblique``: C.1 (a disconnected graph) or D.1 fails, and the
  unstable direction that some sensors cannot see is not a coordinate axis (F = V Λ Vᵀ with a
  random rotation V, and every C row of the blind sensors orthogonal to that eigenvector);
* ``shared-unobserved``: one unstable mode no sensor sees, so every sensor diverges alike;
* ``shared-c-different-r``: sensor types with the same C and different R;
* ``periodic``: a protocol whose Ā is periodic (perfect matchings of an even ring);
* ``node-initiated``, ``greedy-links`` (greedy maximal matching with link failures),
  ``greedy-perfect`` (no failures: Ā_nn may vanish) and ``greedy-estimated`` (a complete graph of
  10 nodes, 45 edges: Ā has no exact form and is estimated, the chains are driven by the protocol);
* ``small-noise`` / ``large-noise`` (Q, R, P0 scaled by 1e-6 or 1e4, P0 up to 1e6);
* ``stable-f``, ``unstable-f`` (|λ| up to 1.3), ``marginal-f`` (a rotation on the unit circle) and
  ``singular-f`` (an unstable mode plus a null space that every sensor sees only in part: D.1 can
  fail although (F, C_all) is observable);
* ``actuators``: some nodes observe nothing (C = []), others have two-row sensors;
* ``comparison``: a second protocol with the same Ā (single edges against matchings);
* ``sequence``: a replayed cycle of random matchings (nothing random: the law claims are not checkable,
  the pathwise ones are).

Every scenario has a random prior mean x0 (drawn from its own stream, so the other draws do not move), and
some have a random geometric or grid graph, a sensor `pattern`, other comparison protocols or expectations
(`_draw_the_rest`).

Scenarios are small (N ≤ 6, M ≤ 3, ≤ 60 slots, a few hundred runs) so that a quick run takes
a few seconds.
"""
from __future__ import annotations

import numpy as np

FAMILY = "gossip-kalman"
EDGES = ("c1-fail-oblique", "d1-fail-oblique", "shared-unobserved", "shared-c-different-r", "periodic",
         "node-initiated", "greedy-links", "greedy-perfect", "greedy-estimated", "small-noise", "large-noise",
         "stable-f", "unstable-f", "marginal-f", "singular-f", "actuators", "comparison", "sequence")


def _rotation(rng: np.random.Generator, M: int) -> np.ndarray:
    """A random orthogonal matrix (QR of a Gaussian, signs fixed)."""
    Z = rng.standard_normal((M, M))
    Qm, Rm = np.linalg.qr(Z)
    return Qm * np.sign(np.diag(Rm))


def _spd(rng: np.random.Generator, M: int, scale: float) -> np.ndarray:
    Z = rng.standard_normal((M, M + 2))
    S = Z @ Z.T / (M + 2) + 0.2 * np.eye(M)
    return scale * S / np.trace(S) * M


def _dynamics(rng: np.random.Generator, M: int, regime: str) -> tuple[np.ndarray, np.ndarray]:
    """F = V Λ Vᵀ (V random orthogonal) and V. regime: stable, unstable, mixed or marginal."""
    V = _rotation(rng, M)
    if regime == "stable":
        lam = rng.uniform(0.3, 0.95, M)
    elif regime == "singular":
        lam = np.array([rng.uniform(1.05, 1.3)] + [0.0] * (M - 1))
    elif regime == "unstable":
        lam = rng.uniform(1.02, 1.3, M)
    elif regime == "marginal":
        lam = np.append(rng.uniform(0.5, 1.1, M - 2), [0.0, 0.0]) if M >= 2 else np.array([1.0])
    else:
        lam = rng.uniform(0.6, 1.2, M)
    F = V @ np.diag(lam) @ V.T
    if regime == "marginal" and M >= 2:  # a rotation by θ on the plane of the last two eigenvectors: |λ| = 1
        th = rng.uniform(0.2, 1.2)
        P = V[:, -2:]
        F = F + P @ np.array([[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]]) @ P.T
    return F, V


def _rows(rng: np.random.Generator, M: int, m: int, blind: np.ndarray | None = None) -> np.ndarray:
    """m random unit rows, orthogonal to the columns of `blind` (directions this sensor cannot see)."""
    C = rng.standard_normal((m, M))
    if blind is not None and blind.size:
        C = C - (C @ blind) @ blind.T
    return C / np.maximum(np.linalg.norm(C, axis=1, keepdims=True), 1e-12)


def _tolist(a: np.ndarray) -> list:
    return [[float(x) for x in row] for row in np.atleast_2d(a)]


def _ring_matchings(n: int) -> list[list[list[int]]]:
    even = [[i, i + 1] for i in range(0, n - 1, 2)]
    odd = [[i, (i + 1) % n] for i in range(1, n, 2)]
    return [even, odd]


def generate(seed: int, edge: str | None = None) -> dict:
    """A valid gossip-kalman scenario, deterministic in (seed, edge)."""
    if edge is not None and edge not in EDGES:
        raise ValueError(f"unknown edge case {edge!r} (one of {', '.join(EDGES)})")
    rng = np.random.default_rng([seed, EDGES.index(edge) + 1 if edge else 0, 13])
    M, N, regime, noise, P0_scale = _sizes(rng, edge)
    F, V = _dynamics(rng, M, regime)
    Q = _spd(rng, M, 0.1 * noise)
    P0 = _spd(rng, M, P0_scale)
    graph, N = _graph(rng, edge, N)
    protocol = _protocol(rng, edge, graph, N)
    C_types, R_types, types = _sensors(rng, edge, F, regime, M, N, noise)
    data = {"family": FAMILY, "name": f"gen-{edge or 'random'}-{seed}",
            "description": f"generated scenario (seed {seed}, edge case {edge or 'none'})",
            "model": {"F": _tolist(F), "Q": _tolist(Q), "P0": _tolist(P0)},
            "sensors": {"types": types, "C": C_types, "R": R_types},
            "graph": graph, "protocol": protocol,
            "simulation": {"slots": 60, "runs": 400, "reference_runs": 1200, "quick_runs": 200,
                           "quick_reference_runs": 600, "quick_slots": 40,
                           "record_times": [1, 2, 3, 5, 10, 20, 40, 60], "sample_paths": 2}}
    if edge == "comparison":
        _comparison(rng, data, graph, N, len(C_types))
    extra = np.random.default_rng([seed, 7])
    data["model"]["x0"] = [float(v) for v in extra.normal(0.0, 10.0, M)]
    if edge == "sequence":
        data["protocol"] = _sequence(extra, graph)
    _draw_the_rest(np.random.default_rng([seed, 8]), data, edge)
    return data


def _draw_the_rest(rng: np.random.Generator, data: dict, edge: str | None) -> None:
    """The keys the draws above leave at their defaults, from a stream of their own (so that the draws above do
    not move), each in some draws: a random geometric or grid graph of the same N (unbiased draws; a single-edge
    protocol's edge_prob redrawn for its edges), the sensor types as a repeated `pattern`, the comparison's two
    protocols swapped or a greedy-matching comparison (whose Ā differs: the hypothesis says so), and the
    author's expectations (a wrong one makes the assumption checks not checkable, by design)."""
    from dse.scenario.graphs import graph as graph_spec, random_graph_table

    N = len(data["sensors"]["types"])
    if edge is None and rng.random() < 0.5:
        data["graph"] = random_graph_table(rng, N, N, kinds=("random_geometric",)) if N > 2 and rng.random() < 0.6 \
            else {"kind": "grid", "rows": 2 if N % 2 == 0 and N > 2 else 1, "cols": N // 2 if N % 2 == 0 and N > 2 else N}
        E = len(graph_spec(data["graph"], min_nodes=2).edge_array())
        if data["protocol"]["kind"] == "single-edge":
            data["protocol"]["edge_prob"] = float(rng.uniform(0.3, 1.0) / E)
    if edge is None and rng.random() < 0.3:
        types = data["sensors"].pop("types")
        data["sensors"]["pattern"] = types[:int(rng.integers(1, len(types) + 1))]
    if edge == "comparison" and rng.random() < 0.6:
        if rng.random() < 0.5:
            data["protocol"], data["comparison_protocol"] = data["comparison_protocol"], data["protocol"]
        else:
            data["comparison_protocol"] = {"kind": "greedy-matching", "p_link": float(rng.uniform(0.2, 0.9))}
    if rng.random() < 0.2:
        data["expect"] = {"c1": bool(rng.random() < 0.5), "d1": bool(rng.random() < 0.5),
                          "diverges": bool(rng.random() < 0.5)}


def _sizes(rng: np.random.Generator, edge: str | None) -> tuple[int, int, str, float, float]:
    """(M, N, regime of F, noise scale, P0 scale)."""
    M = int(rng.integers(1, 4))
    N = int(rng.integers(2, 7))
    regime = str(rng.choice(["stable", "unstable", "mixed", "marginal"]))
    noise = 1.0
    P0_scale = float(10 ** rng.uniform(-1, 1))
    if edge in ("c1-fail-oblique", "d1-fail-oblique", "shared-unobserved", "unstable-f"):
        regime, M = "unstable", max(M, 2)
    elif edge == "singular-f":
        regime, M = "singular", 3
    elif edge == "stable-f":
        regime = "stable"
    elif edge == "marginal-f":
        regime, M = "marginal", max(M, 2)
    if edge == "small-noise":
        noise, P0_scale = 1e-6, 1e-6
    elif edge == "large-noise":
        noise, P0_scale = 1e4, 1e6
    return M, N, regime, noise, P0_scale


def _graph(rng: np.random.Generator, edge: str | None, N: int) -> tuple[dict, int]:
    graph: dict = {"kind": str(rng.choice(["line", "ring", "complete"])) if N >= 3 else "line", "n": N}
    if edge == "c1-fail-oblique":  # two components: [0, k) and [k, N)
        N = max(N, 4)
        k = N // 2
        edges = [[i, i + 1] for i in range(k - 1)] + [[i, i + 1] for i in range(k, N - 1)]
        graph = {"kind": "edges", "n": N, "edges": edges}
    elif edge == "periodic":
        N = 2 * int(rng.integers(1, 4))
        graph = {"kind": "ring", "n": N} if N >= 4 else {"kind": "line", "n": 2}
    elif edge == "greedy-estimated":
        N = 10
        graph = {"kind": "complete", "n": N}
    return graph, N


def _protocol(rng: np.random.Generator, edge: str | None, graph: dict, N: int) -> dict:
    n_edges = {"line": N - 1, "ring": N, "complete": N * (N - 1) // 2}.get(graph["kind"], len(graph.get("edges", [])))
    kind = str(rng.choice(["single-edge", "node-initiated", "greedy-matching"]))
    if edge == "node-initiated":
        kind = "node-initiated"
    elif edge in ("greedy-links", "greedy-perfect", "greedy-estimated"):
        kind = "greedy-matching"
    elif edge in ("c1-fail-oblique",):
        kind = "single-edge"
    protocol: dict = {"kind": kind}
    if kind == "single-edge":
        protocol["edge_prob"] = float(rng.uniform(0.3, 1.0) / n_edges)
    elif kind == "greedy-matching":
        protocol["p_link"] = 1.0 if edge == "greedy-perfect" else float(rng.uniform(0.2, 0.9))
    if edge == "periodic":
        if N == 2:
            protocol = {"kind": "matchings", "matchings": [[[0, 1]]], "probs": [1.0]}
        else:
            protocol = {"kind": "matchings", "matchings": _ring_matchings(N), "probs": [0.5, 0.5]}
    if kind == "node-initiated" and graph["kind"] == "edges":
        protocol = {"kind": "single-edge", "edge_prob": float(0.8 / n_edges)}
    return protocol


def _sensors(rng: np.random.Generator, edge: str | None, F: np.ndarray, regime: str, M: int, N: int,
             noise: float) -> tuple[list, list, list[int]]:
    """(C of each type, R of each type, the type of each node), with the edge case's blind directions."""
    evals, evecs = np.linalg.eigh(0.5 * (F + F.T)) if regime not in ("marginal",) else (None, None)
    n_types = int(rng.integers(1, min(N, 3) + 1))
    C_types, R_types = [], []
    blind = None
    if edge in ("d1-fail-oblique", "shared-unobserved", "c1-fail-oblique"):
        i = int(np.argmax(np.abs(evals)))
        blind = evecs[:, [i]]  # the largest unstable eigenvector (oblique: V is a random rotation)
    for k in range(n_types):
        m = int(rng.integers(1, min(M, 2) + 1))
        C = _rows(rng, M, m, blind if edge in ("d1-fail-oblique", "shared-unobserved") else None)
        C_types.append(_tolist(C))
        R_types.append(_tolist(_spd(rng, m, noise * float(10 ** rng.uniform(-1, 1)))))
    types = [int(rng.integers(0, n_types)) for _ in range(N)]
    if edge == "c1-fail-oblique":  # component [k, N) sees nothing along the blind eigenvector
        C_types = [_tolist(_rows(rng, M, M, None)), _tolist(_rows(rng, M, 1, blind))]
        R_types = [_tolist(_spd(rng, M, noise)), _tolist(_spd(rng, 1, noise))]
        k = N // 2
        types = [0] * k + [1] * (N - k)
    elif edge == "shared-c-different-r":
        m = len(C_types[0])
        C_types = [C_types[0]] * 3
        R_types = [_tolist(_spd(rng, m, noise * s)) for s in (0.1, 1.0, 10.0)]
        types = [i % 3 for i in range(N)]
    elif edge == "singular-f":  # every sensor sees one direction of the null space of F and the unstable mode
        null = evecs[:, np.abs(evals) < 1e-12]
        C_types = [_tolist(_rows(rng, M, 1, null[:, [1]])), _tolist(_rows(rng, M, 1, null[:, [0]]))]
        R_types = [_tolist(_spd(rng, 1, noise)), _tolist(_spd(rng, 1, noise))]
        types = [i % 2 for i in range(N)]
    elif edge == "actuators":
        C_types.append([])
        R_types.append([])
        C_types.append(_tolist(_rows(rng, M, min(M, 2))))
        R_types.append(_tolist(_spd(rng, min(M, 2), noise)))
        types = [int(rng.integers(0, len(C_types))) for _ in range(N)]
        types[0] = len(C_types) - 2
    return C_types, R_types, types


def _comparison(rng: np.random.Generator, data: dict, graph: dict, N: int, n_types: int) -> None:
    """Single edges against ring matchings with the same Ā (on an even ring)."""
    if graph["kind"] != "ring" or N % 2:
        N = 2 * int(rng.integers(2, 4))
        data["graph"] = {"kind": "ring", "n": N}
        data["sensors"]["types"] = [i % n_types for i in range(N)]
    gamma = float(rng.uniform(0.2, 1.0) / N)
    data["protocol"] = {"kind": "single-edge", "edge_prob": gamma}
    data["comparison_protocol"] = {"kind": "matchings", "matchings": _ring_matchings(N), "probs": [gamma, gamma]}


def _sequence(extra: np.random.Generator, graph: dict) -> dict:
    """A replayed cycle of random maximal matchings of the graph."""
    import networkx as nx

    from dse.scenario.graphs import GraphSection

    G = GraphSection(**graph).spec().build()
    slots = []
    for _ in range(int(extra.integers(1, 8))):
        order = extra.permutation(G.number_of_edges())
        edges = [sorted(e) for e in G.edges()]
        slots.append([edges[i] for i in order[: int(extra.integers(0, len(edges) + 1))]])
    return {"kind": "sequence", "sequence": [[list(map(int, e)) for e in nx.maximal_matching(
        nx.Graph([tuple(e) for e in slot]))] for slot in slots]}
