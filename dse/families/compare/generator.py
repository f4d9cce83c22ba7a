"""Random valid scenarios of the compare family, biased towards its edge cases.

`generate(seed, edge)` returns a scenario dict as a user's TOML file would give it, small enough for
a quick run of a couple of seconds, deterministic in (seed, edge). The edge cases: every link model;
communication noise strong enough that it dominates Carli's filter; nodes that cannot detect the
state alone (weak detectability); an unstable plant; two nodes; sensors with two rows; gains given
by hand; Laplacian weights; exact recursions switched off by size; a restricted set of the registered
estimators. Every scenario also draws what the edge cases leave at their defaults (`_draw_the_rest`): a prior
mean x0 ≠ 0 and a prior covariance P0 ≠ I, a graph of any kind, and, each in some draws, the sensors' assignment,
the pairwise weight α, the Kalman-consensus ε, the gain scales, the evaluation step and the sample paths.
"""
from __future__ import annotations

import zlib
from typing import Any

import numpy as np

from dse.estimators.network import registry
from dse.scenario.graphs import graph, max_degree, random_graph_table

EDGES: tuple[str, ...] = ("reliable_noisy_scalar", "failures", "matchings", "poisson", "poisson_noisy",
                          "weak_detectability", "unstable_plant", "two_nodes", "two_row_sensors", "given_gains",
                          "laplacian_weights", "no_exact", "few_estimators")


def _plant(rng, n: int, unstable: bool = False):
    if n == 1:
        F = np.array([[1.0 if unstable else rng.uniform(0.8, 1.0)]])
    else:
        dt = rng.uniform(0.1, 0.5)
        F = np.eye(n)
        for i in range(n - 1):
            F[i, i + 1] = dt
        F *= 1.01 if unstable else rng.uniform(0.95, 1.0)
    A = rng.standard_normal((n, n)) * 0.3
    Q = A @ A.T + 0.05 * np.eye(n)
    return np.round(F, 4), np.round(Q, 4)


def _matrix(a) -> list:
    return [[float(x) for x in row] for row in np.atleast_2d(a)]


def generate(seed: int, edge: str | None = None) -> dict[str, Any]:
    rng = np.random.default_rng([seed, zlib.crc32((edge or "random").encode())])
    e = edge or ""
    n = 1 if e == "reliable_noisy_scalar" else int(rng.integers(2, 4))
    N = 2 if e == "two_nodes" else int(rng.integers(3, 7))
    F, Q = _plant(rng, n, unstable=e in ("unstable_plant", "weak_detectability"))
    rows = 2 if e == "two_row_sensors" else 1
    types = []
    n_types = 2 if e == "weak_detectability" else int(rng.integers(1, 3))
    for t in range(n_types):
        if e == "weak_detectability":
            H = np.zeros((1, n))
            H[0, t % n] = 1.0              # each type sees one coordinate only
            if n > 1:
                F = np.diag(np.round(rng.uniform(1.0, 1.03, n), 4))
        else:
            H = np.round(rng.standard_normal((rows, n)), 3)
        B = rng.standard_normal((rows, rows))
        R = np.round(B @ B.T + rng.uniform(0.3, 2.0) * np.eye(rows), 4)
        types.append({"H": _matrix(H), "R": _matrix(R)})
    kind = "line" if N < 3 or rng.random() < 0.4 else "ring"
    data: dict[str, Any] = {
        "family": "compare", "name": f"gen-{edge or 'random'}-{seed}",
        "plant": {"F": _matrix(F), "Q": _matrix(Q)},
        "sensors": {"types": types},
        "graph": {"kind": kind, "n": N},
        "simulation": {"steps": int(rng.integers(12, 25)), "trials": 600, "quick_trials": 600},
    }
    _draw_the_rest(np.random.default_rng([seed, zlib.crc32((edge or "random").encode()), 1]), data, e)
    model = {"failures": "failures", "matchings": "matchings", "poisson": "poisson", "poisson_noisy": "poisson",
             "weak_detectability": "matchings"}.get(e) or ["reliable", "failures", "matchings", "poisson"][
        int(rng.integers(0, 4)) if not e else 0]
    links: dict[str, Any] = {"model": model, "rounds": int(rng.integers(1, 4)) if model != "poisson" else 1}
    if model in ("failures", "matchings"):
        links["p_fail"] = float(np.round(rng.uniform(0.05, 0.4), 3))
    if model == "poisson":
        links["rate"] = float(np.round(rng.uniform(0.2, 1.0), 3))
    if e in ("reliable_noisy_scalar", "poisson_noisy") or (not e and rng.random() < 0.3):
        links["noise_std"] = float(np.round(rng.uniform(0.5, 2.0), 3))
    if e == "reliable_noisy_scalar":           # noise that dominates Carli's filter (Savas et al.'s Fig. 1 regime)
        links["rounds"] = 6
        links["noise_std"] = float(np.round(rng.uniform(2.5, 4.0), 3))
        data["plant"].update(F=[[1.0]], Q=[[1.0]])
        data["sensors"] = {"types": [{"H": [[1.0]], "R": [[25.0]]}]}
    data["links"] = links
    if e == "given_gains":
        data["gains"] = {"base": "given", "given": [_matrix(0.3 * np.ones((n, len(t["H"])))) for t in types],
                         "carli_scale": 1.0, "reinjection_scale": 1.0, "reinjection_zeta": 0.5}
    if e == "laplacian_weights":
        data["weights"] = {"kind": "laplacian", "eps": 0.3}
    if e == "no_exact":
        data["simulation"]["exact_max_dimension"] = 2
    if e == "few_estimators":             # three of the registered estimators besides the reference
        names = [name for name, est in registry().items() if not est.reference]
        chosen = sorted(rng.choice(len(names), size=min(3, len(names)), replace=False))
        data["estimators"] = {"include": [names[i] for i in chosen]}
    return data


def _spd(rng, n: int) -> list:
    """A random prior covariance, neither the identity nor diagonal."""
    A = rng.standard_normal((n, n))
    return _matrix(np.round(rng.uniform(0.2, 4.0) * (A @ A.T / n + 0.3 * np.eye(n)), 4))


def _draw_the_rest(rng, data: dict[str, Any], e: str) -> None:
    """The keys the edge cases do not set, from their own stream (so that the draws above do not move): the
    prior (x0 ≠ 0, P0 ≠ I) always; the graph's kind on unbiased draws (the edge cases keep their small
    line or ring); the sensors' assignment, α, the Kalman-consensus ε, numeric gain scales, the evaluation
    step and the sample paths in some draws each."""
    n, plant, sim = len(data["plant"]["F"]), data["plant"], data["simulation"]
    plant["x0"] = [float(v) for v in np.round(rng.normal(0.0, 3.0, n) + np.sign(rng.normal(size=n)), 3)]
    plant["P0"] = _spd(rng, n)
    if not e:
        data["graph"] = random_graph_table(rng, 3, 7)
    N = graph(data["graph"], min_nodes=2).n
    if rng.random() < 0.3:
        data["sensors"]["assign"] = [int(t) for t in rng.integers(0, len(data["sensors"]["types"]), N)]
    weights, gains = data.setdefault("weights", {}), data.setdefault("gains", {})
    if rng.random() < 0.3:
        dmax = max_degree(graph(data["graph"], min_nodes=2))
        weights["alpha"] = float(np.round(rng.uniform(0.2, 1.0) * min(0.5, 1.0 / dmax), 4))      # α <= 1/2, 1/d_max
    if rng.random() < 0.3:
        weights["kcf_epsilon"] = float(np.round(rng.uniform(0.02, 2.0), 3))
    if rng.random() < 0.3:
        gains["pairwise_scale"] = float(np.round(rng.uniform(0.3, 1.5), 3))
    if "carli_scale" not in gains and rng.random() < 0.25:
        gains.update(carli_scale=float(np.round(rng.uniform(0.2, 1.0), 3)),
                     reinjection_scale=float(np.round(rng.uniform(0.2, 1.0), 3)),
                     reinjection_zeta=float(np.round(rng.uniform(0.0, 1.0), 3)))
    if rng.random() < 0.3:
        sim["eval_step"] = int(rng.integers(1, sim["steps"]))
    sim["paths"] = int(rng.integers(0, 3))
