"""Random valid scenarios of the noisy-consensus-filter family, biased towards its edge cases.

`generate(seed, edge)` returns a scenario dict as a user's TOML file would give it. Every
draw is small (a quick run takes a few seconds) and deterministic in (seed, edge). The edge
cases are the ones that broke or could break the checks: no or one consensus round with the
default `gains.rounds_max`, no communication noise, consensus matrices that are doubly
stochastic but not normal (or normal but not symmetric), eigenvalues near −1, extreme noise
intensities and ratios q/r, two agents, larger networks (where scipy's Lyapunov solver
switches method), ℓ = 1, σ0 = 0, the evaluation step k = 0, and a horizon longer than the
recorded steps (statistics kept at a subset of the steps). Every scenario has a prior mean x0_mean ≠ 0.
"""
from __future__ import annotations

from typing import Any

import numpy as np

FAMILY = "noisy-consensus-filter"

EDGES: tuple[str, ...] = (
    "m0_default_rounds_max", "m1_default_rounds_max", "m01_with_rounds_max", "sigma_c_zero", "non_normal_Q",
    "normal_nonsymmetric_Q", "eigenvalue_near_minus_one", "tiny_noise", "huge_noise", "extreme_ratio_q_over_r",
    "two_agents", "larger_network", "complete_metropolis", "grid_laplacian", "random_geometric", "ell_one_sigma0_zero",
    "eval_step_zero", "large_sigma_c", "long_horizon",
)


def _permutation_matrix(perm) -> np.ndarray:
    n = len(perm)
    P = np.zeros((n, n))
    P[np.arange(n), perm] = 1.0
    return P


def _matrix_scenario(rng: np.random.Generator, n: int, normal: bool) -> tuple[dict, dict]:
    """A doubly stochastic, primitive Q with dyadic weights (exact row and column sums): a·I + b·C (+ c·P),
    C the cyclic shift (a circulant, normal but not symmetric) and P a random permutation (then
    usually not normal). The graph is the union of the supports."""
    shift = _permutation_matrix((np.arange(n) + 1) % n)
    a = int(rng.integers(4, 9)) / 16
    if normal:
        Q = a * np.eye(n) + (1 - a) * shift
    else:
        other = _permutation_matrix(rng.permutation(n))
        b = int(rng.integers(2, 16 - int(16 * a))) / 16
        Q = a * np.eye(n) + b * shift + (1 - a - b) * other
    support = (Q > 0) | (Q.T > 0)
    edges = sorted({(int(min(i, j)), int(max(i, j))) for i, j in zip(*np.nonzero(support)) if i != j})
    return ({"kind": "edges", "n": n, "edges": [list(e) for e in edges]},
            {"weights": "matrix", "matrix": Q.tolist()})


def _random_geometric(rng: np.random.Generator, n: int) -> dict:
    """A connected random geometric graph: the first drawn graph seed whose graph is connected."""
    import networkx as nx

    while True:
        seed = int(rng.integers(0, 10_000))
        if nx.is_connected(nx.random_geometric_graph(n, 0.9, seed=seed)):
            return {"kind": "random_geometric", "n": n, "radius": 0.9, "seed": seed}


def _graph(rng: np.random.Generator, kind: str, n: int) -> dict:
    if kind == "grid":
        rows = int(rng.integers(2, 4))
        return {"kind": "grid", "rows": rows, "cols": max(2, n // rows)}
    if kind == "random_geometric":
        return _random_geometric(rng, n)
    return {"kind": kind, "n": n}


def _max_degree(graph: dict) -> int:
    kind, n = graph["kind"], graph.get("n", 0)
    return {"line": 2 if n > 2 else 1, "ring": 2, "complete": n - 1, "grid": 4}.get(kind, n - 1)


def _weights(rng: np.random.Generator, graph: dict, kind: str, near_limit: bool = False) -> dict:
    if kind == "metropolis":
        return {"weights": "metropolis"}
    dmax = max(_max_degree(graph), 1)
    frac = float(rng.uniform(0.97, 0.995)) if near_limit else float(rng.uniform(0.2, 0.9))
    return {"weights": "laplacian", "eps": round(frac / dmax, 6)}


def _draws(rng: np.random.Generator) -> dict[str, Any]:
    """The features of a random scenario (drawn in a fixed order: the generator is a function of its seed)."""
    d: dict[str, Any] = {"n": int(rng.integers(3, 7)),
                         "graph_kind": str(rng.choice(["line", "ring", "complete", "grid", "random_geometric"])),
                         "weight_kind": str(rng.choice(["metropolis", "laplacian"])),
                         "q": float(10 ** rng.uniform(-1, 1)), "r": float(10 ** rng.uniform(0, 2)),
                         "sigma_c": sorted({0.0, round(float(rng.uniform(0.1, 3.0)), 3)})}
    d["rounds"] = sorted({int(x) for x in rng.choice(np.arange(0, 6), size=int(rng.integers(2, 4)), replace=False)})
    d["n_steps"] = int(rng.integers(4, 9))
    d["eval_step"] = int(rng.integers(1, d["n_steps"]))
    d.update(gains={"gains": "optimal-corrected"}, extra={}, sigma0=round(float(rng.uniform(0.0, 2.0)), 3),
             carli_ell=round(float(rng.uniform(0.1, 0.9)), 3), consensus=None, graph=None)
    return d


def _edge_case(rng: np.random.Generator, edge: str, d: dict[str, Any]) -> None:
    """Bend the draws `d` towards one edge case."""
    if edge == "m0_default_rounds_max":
        d["rounds"] = [0]
    elif edge == "m1_default_rounds_max":
        d["rounds"] = [1]
    elif edge == "m01_with_rounds_max":
        d["rounds"], d["extra"] = [0, 1], {"gains": {"rounds_max": int(rng.integers(2, 6))}}
    elif edge == "sigma_c_zero":
        d["sigma_c"] = [0.0]
    elif edge in ("non_normal_Q", "normal_nonsymmetric_Q"):
        n = int(rng.integers(3, 6)) if edge == "normal_nonsymmetric_Q" else int(rng.integers(4, 7))
        d["graph"], d["consensus"] = _matrix_scenario(rng, n, normal=edge == "normal_nonsymmetric_Q")
        d["gains"] = {"gains": "fixed", "ell": round(float(rng.uniform(0.05, 1.0)), 3),
                      "zeta": round(float(rng.uniform(0.0, 1.0)), 3)}
    elif edge == "eigenvalue_near_minus_one":  # Q = I − εL on a bipartite graph with ε close to 1/d_max
        d["graph"] = {"kind": str(rng.choice(["line", "ring"])), "n": 2 * int(rng.integers(2, 4))}
        d["consensus"] = _weights(rng, d["graph"], "laplacian", near_limit=True)
    elif edge == "tiny_noise":
        d["q"], d["r"] = float(10 ** rng.uniform(-6, -3)), float(10 ** rng.uniform(-6, -3))
    elif edge == "huge_noise":
        d["q"], d["r"] = float(10 ** rng.uniform(3, 5)), float(10 ** rng.uniform(3, 6))
        d["sigma_c"] = sorted({0.0, round(float(10 ** rng.uniform(1, 2.5)), 3)})
    elif edge == "extreme_ratio_q_over_r":
        if rng.uniform() < 0.5:
            d["q"], d["r"] = float(10 ** rng.uniform(-4, -2)), float(10 ** rng.uniform(3, 4))
        else:
            d["q"], d["r"] = float(10 ** rng.uniform(2, 4)), float(10 ** rng.uniform(-3, -1))
    elif edge == "two_agents":
        d["graph"] = {"kind": "line", "n": 2}
    elif edge == "larger_network":
        d["graph"] = {"kind": str(rng.choice(["ring", "line"])), "n": int(rng.integers(10, 13))}
        d["rounds"] = sorted({int(rng.integers(0, 2)), int(rng.integers(2, 5))})
        d["sigma_c"] = [round(float(rng.uniform(0.2, 2.0)), 3)]
    elif edge == "complete_metropolis":
        d["graph"], d["consensus"] = {"kind": "complete", "n": d["n"]}, {"weights": "metropolis"}
    elif edge == "grid_laplacian":
        d["graph"] = {"kind": "grid", "rows": 2, "cols": int(rng.integers(2, 4))}
        d["consensus"] = _weights(rng, d["graph"], "laplacian")
    elif edge == "random_geometric":
        d["graph"], d["consensus"] = _random_geometric(rng, d["n"]), {"weights": "metropolis"}
    elif edge == "ell_one_sigma0_zero":
        d["sigma0"], d["carli_ell"] = 0.0, 1.0
        d["gains"] = {"gains": "fixed", "ell": 1.0, "zeta": round(float(rng.uniform(0.0, 1.0)), 3)}
    elif edge == "eval_step_zero":
        d["eval_step"] = 0
    elif edge == "large_sigma_c":
        d["sigma_c"] = [round(float(rng.uniform(5.0, 20.0)), 3)]
        d["rounds"] = sorted({1, int(rng.integers(2, 6))})
    elif edge == "long_horizon":
        d["n_steps"], d["eval_step"] = int(rng.integers(200, 400)), int(rng.integers(1, 10))
        d["extra"] = {"sweep_extra": {"recorded_steps": int(rng.integers(10, 40))}}


def generate(seed: int, edge: str | None = None) -> dict[str, Any]:
    """A valid scenario dict; `edge` picks one of EDGES, None draws every feature at random."""
    if edge is not None and edge not in EDGES:
        raise ValueError(f"unknown edge case {edge!r}; one of {', '.join(EDGES)}")
    rng = np.random.default_rng([seed, EDGES.index(edge) + 1 if edge else 0])
    d = _draws(rng)
    if edge is None:
        edge_like = str(rng.choice(["plain", "non_normal_Q", "normal_nonsymmetric_Q", "eigenvalue_near_minus_one"]))
        if edge_like != "plain":
            edge = edge_like  # the matrix cases below, with the random draws above
        if rng.uniform() < 0.3:
            d["gains"] = {"gains": "optimal-printed"}
    if edge is not None:
        _edge_case(rng, edge, d)
    graph = d["graph"] if d["graph"] is not None else _graph(rng, d["graph_kind"], d["n"])
    consensus = d["consensus"] if d["consensus"] is not None else _weights(rng, graph, d["weight_kind"])
    extra = d["extra"]
    sweep = {"rounds": d["rounds"], "sigma_c": d["sigma_c"], "n_steps": d["n_steps"], "eval_step": d["eval_step"],
             **extra.pop("sweep_extra", {})}
    data = {"family": FAMILY, "name": f"gen-{edge or 'random'}-{seed}", "graph": graph, "consensus": consensus,
            "model": {"q": d["q"], "r": d["r"], "sigma0": d["sigma0"]}, "sweep": sweep, "carli": {"ell": d["carli_ell"]},
            "reinjection": d["gains"], "monte_carlo": {"trials": int(rng.integers(200, 3001)),
                                                      "sample_paths": int(rng.integers(0, 3))}, **extra}
    _draw_the_rest(np.random.default_rng([seed, EDGES.index(edge) + 1 if edge else 0, 1]), data)
    return data


def _draw_the_rest(rng: np.random.Generator, data: dict[str, Any]) -> None:
    """The keys the draws above leave at their defaults, from a stream of their own (so that the draws above do
    not move): the prior mean x0_mean ≠ 0 always; in some draws the gain grid, how long the sample trials are kept
    and the quick runs' trials (equal to the trials, which stay below the default's cap)."""
    data["model"]["x0_mean"] = float(np.round(rng.normal(0.0, 5.0) + np.sign(rng.normal()), 3))
    if rng.random() < 0.3:
        data.setdefault("gains", {})["grid"] = [int(rng.integers(41, 401)), int(rng.integers(41, 401))]
    mc = data["monte_carlo"]
    if rng.random() < 0.3:
        mc["sample_steps"] = int(rng.integers(2, 101))
    if rng.random() < 0.3:
        mc["quick_trials"] = mc["trials"]
