"""Random valid scenarios of the random-comm-filter family, biased towards the hard cases.

`generate(seed, edge)` returns a scenario dict as a user's TOML file would give it
(deterministic in (seed, edge)). The edge cases (`EDGES`) are the situations in which a check
can mistake round-off, a heavy tail or an unmet hypothesis for a counterexample:

* ``marginal``: a plant with an eigenvalue on the imaginary axis and one node that sees
  nothing (L_i = 0), so the generator of (9) is only marginally stable at λ = 0 and the
  critical rate is 0;
* ``near-critical``: a node with unstable error dynamics and a rate 1.05–1.5 times the critical
  rate of (9) (heavy tails of the per-path quantities);
* ``divergent``: a rate below the critical rate of (9) (the bound diverges; sometimes the true
  covariance too);
* ``unstable-star``: five nodes on a star, an unstable non-normal plant, the leaves seeing
  little (the scenario of the issue's miscalibrated statistics);
* ``tiny-v`` / ``huge-v``: measurement noise intensities scaled by 1e-7 or 1e5 (gains up to
  ~1e4, very stiff node dynamics);
* ``tiny-w`` / ``huge-w``: process noise (B) scaled by 1e-4 or 1e3;
* ``two-nodes``: N = 2, one edge;
* ``blind-sensors``: most sensors see almost nothing (rows of size 1e-3 or zero), one sees all;
* ``abar-unstable``: given gains with every A_i Hurwitz or not, but Ā = mean(A_i) not Hurwitz
  (the hypothesis of Theorem III.1 item 2 fails);
* ``homogeneous``: identical sensors and gains (𝒫_i ≡ S for every λ);
* ``ordered-clocks``: one clock per ordered pair (receiver-only updates);
* ``fast-rate``: a rate of a few hundred (stiff jump terms, singular perturbation).

Graphs are drawn among lines, rings, stars, complete graphs and random trees with extra
edges (and, in some unbiased draws, random geometric graphs and grids). Every scenario has a prior
mean m0 ≠ 0; some have a full prior covariance P0, per-node P_i(0) ⪰ P0, a given α, λ sweep and title. Scenarios are small (n ≤ 3, N ≤ 5, horizon 2–3, a few hundred event-driven paths and a
thousand gridded trials in quick runs) so that a quick run takes a few seconds.
"""
from __future__ import annotations

import zlib

import numpy as np

FAMILY = "random-comm-filter"
EDGES = ("marginal", "near-critical", "divergent", "unstable-star", "tiny-v", "huge-v", "tiny-w", "huge-w",
         "two-nodes", "blind-sensors", "abar-unstable", "homogeneous", "ordered-clocks", "fast-rate")
GRAPH_KINDS = ("line", "ring", "star", "complete", "tree")
MAX_ATTEMPTS = 50
MAX_EVENTS = 80


def _rng(seed: int, edge: str | None, attempt: int) -> np.random.Generator:
    tag = zlib.crc32((edge or "random").encode())
    return np.random.default_rng([seed, tag, attempt])


def _m(X) -> list:
    return np.asarray(X, float).round(12).tolist()


# -- pieces ----------------------------------------------------------------------------------------

def _graph(rng: np.random.Generator, N: int, kind: str) -> dict:
    if N == 2 or kind == "line":
        return {"kind": "line", "n": N}
    if kind == "ring" and N >= 3:
        return {"kind": "ring", "n": N}
    if kind == "complete":
        return {"kind": "complete", "n": N}
    if kind == "star":
        return {"kind": "edges", "n": N, "edges": [[0, j] for j in range(1, N)]}
    edges = {(int(rng.integers(0, j)), j) for j in range(1, N)}          # a random tree, then a few chords
    for _ in range(int(rng.integers(0, N))):
        i, j = sorted(rng.choice(N, 2, replace=False).tolist())
        edges.add((i, j))
    return {"kind": "edges", "n": N, "edges": [list(e) for e in sorted(edges)]}


def _orthogonal(rng: np.random.Generator, n: int) -> np.ndarray:
    Q, R = np.linalg.qr(rng.standard_normal((n, n)))
    return Q * np.sign(np.diag(R))


def _plant(rng: np.random.Generator, n: int, regime: str) -> np.ndarray:
    """A with eigenvalues in a regime: stable, unstable (some Re > 0), marginal (an exact zero
    or an imaginary pair, written in a basis where it stays exact), nonnormal (unstable and
    strongly non-normal)."""
    if regime == "marginal":
        if n == 1:
            return np.zeros((1, 1))
        w = rng.uniform(0.5, 2.0)
        A = np.zeros((n, n))
        A[:2, :2] = [[0.0, w], [-w, 0.0]]
        for k in range(2, n):
            A[k, k] = -rng.uniform(0.3, 1.5)
            A[k, :k] = rng.uniform(-0.5, 0.5, k)
        return A
    if regime == "nonnormal":
        T = np.triu(rng.uniform(2.0, 6.0, (n, n)) * rng.choice([-1, 1], (n, n)), 1)
        T[np.diag_indices(n)] = rng.uniform(0.1, 0.6, n) * np.where(np.arange(n) == 0, 1, rng.choice([-1, 1], n))
        return T
    re = {"stable": (-1.5, -0.2), "unstable": (-0.5, 0.6)}[regime]
    d = rng.uniform(*re, n)
    if regime == "unstable":
        d[0] = rng.uniform(0.1, 0.6)
    Q = _orthogonal(rng, n)
    T = np.diag(d) + np.triu(rng.normal(0, 0.7, (n, n)), 1)
    return Q @ T @ Q.T


def _sensors(rng: np.random.Generator, n: int, N: int, *, v_scale: float = 1.0, blind: float = 0.0,
             zero_rows: int = 0) -> list[dict]:
    """N sensors with one measurement each (two for some when n ≥ 2); node 0 sees the whole state
    so that the stacked pair (A, H) is observable; `blind` rows are scaled down to that size,
    and `zero_rows` nodes (the last ones) measure nothing."""
    out = []
    for i in range(N):
        if i == 0:
            H = np.eye(n)
        else:
            p = 2 if n >= 2 and rng.random() < 0.25 else 1
            H = rng.normal(0, 1, (p, n))
            if blind:
                H *= blind
            if i >= N - zero_rows:
                H = np.zeros((1, n))
        p = H.shape[0]
        Z = rng.normal(0, 1, (p, p + 1))
        V = (Z @ Z.T / (p + 1) + 0.3 * np.eye(p)) * v_scale * 10 ** rng.uniform(-0.5, 0.5)
        out.append({"H": _m(H), "V": _m((V + V.T) / 2)})
    return out


def _simulation(rate: float, dmax: int, horizon: float) -> dict:
    out_step = horizon / 20
    per = max(1, int(np.ceil(out_step * rate * dmax / 0.25)))
    return {"horizon": horizon, "output_step": out_step, "grid_step": out_step / per, "trials": 4000,
            "event_trials": 1000, "quick_trials": 1000, "quick_event_trials": 300, "sample_trials": 2}


# -- assembly ------------------------------------------------------------------------------------------

def _draw(rng: np.random.Generator, edge: str | None) -> dict:
    n = int(rng.integers(1, 4))
    N = int(rng.integers(2, 6))
    kind = str(rng.choice(GRAPH_KINDS))
    regime = str(rng.choice(("stable", "unstable", "nonnormal", "marginal")))
    v_scale, w_scale, blind, zero_rows = 1.0, 1.0, 0.0, 0
    mode, gains, rate_factor, fixed_rate = "edge", "kalman-bucy-split", float(rng.uniform(1.5, 6.0)), None
    horizon = float(rng.choice((2.0, 3.0)))
    if edge == "marginal":
        regime, zero_rows, n = "marginal", 1, max(n, 2)
    elif edge == "near-critical":
        regime, blind, rate_factor = "unstable", 0.05, float(rng.uniform(1.05, 1.5))
    elif edge == "divergent":
        regime, blind, rate_factor, horizon = "unstable", 0.05, float(rng.uniform(0.3, 0.9)), 2.0
    elif edge == "unstable-star":
        regime, kind, N, n, blind, rate_factor = "nonnormal", "star", 5, int(rng.integers(2, 4)), 0.2, \
            float(rng.uniform(1.5, 3.0))
    elif edge == "tiny-v":
        v_scale = 1e-7
    elif edge == "huge-v":
        v_scale = 1e5
    elif edge == "tiny-w":
        w_scale = 1e-4
    elif edge == "huge-w":
        w_scale = 1e3
    elif edge == "two-nodes":
        N = 2
    elif edge == "blind-sensors":
        blind, zero_rows = 1e-3, int(rng.integers(0, N - 1))
    elif edge == "abar-unstable":
        gains = "given"
    elif edge == "homogeneous":
        regime = "unstable"
    elif edge == "ordered-clocks":
        mode, N, kind = "ordered", min(N, 4), str(rng.choice(("line", "ring", "star")))
    elif edge == "fast-rate":
        fixed_rate, N, horizon = float(rng.uniform(150.0, 400.0)), min(N, 3), 0.5
    A = _plant(rng, n, regime)
    m = n if rng.random() < 0.7 else max(1, n - 1)
    B = w_scale * (np.eye(n)[:, :m] + rng.normal(0, 0.3, (n, m)))
    graph = _graph(rng, N, kind)
    if edge == "homogeneous":
        H = rng.normal(0, 1, (1, n)) + np.eye(n)[:1]
        sensors = [{"H": _m(H), "V": [[float(rng.uniform(0.2, 2.0))]]}] * N
    else:
        sensors = _sensors(rng, n, N, v_scale=v_scale, blind=blind, zero_rows=zero_rows)
    data = {"family": FAMILY, "system": {"A": _m(A), "B": _m(B)}, "sensors": sensors, "graph": graph,
            "gains": {"rule": gains},
            "communication": {"mode": mode, "sweep": [0.1, 1e4, 15]}}
    if rng.random() < 0.3:
        data["system"]["P0"] = _m(np.diag(10 ** rng.uniform(-1, 1, n)))
    if gains == "given":
        _given_gains(rng, data, A)
    _draw_the_rest(np.random.default_rng(rng.integers(2 ** 32)), data, edge)
    return {**data, "_rate": (fixed_rate, rate_factor), "_horizon": horizon}


def _spd(rng: np.random.Generator, n: int, scale: float) -> np.ndarray:
    Z = rng.normal(0, 1, (n, n + 1))
    return scale * (Z @ Z.T / (n + 1) + 0.2 * np.eye(n))


def _draw_the_rest(rng: np.random.Generator, data: dict, edge: str | None) -> None:
    """The keys the draws above leave at their defaults, from a stream of their own (drawn last, so that the
    draws above do not move): the prior mean m0 ≠ 0 always; in some draws a full prior covariance P0, every
    node's P_i(0) ⪰ P0, α, the λ sweep, a title, and (unbiased draws) a random geometric or grid graph."""
    from dse.scenario.graphs import graph as graph_spec, max_degree, random_graph_table

    system, sensors, N = data["system"], data["sensors"], len(data["sensors"])
    n = len(system["A"])
    system["m0"] = [float(v) for v in np.round(rng.normal(0.0, 2.0, n) + np.sign(rng.normal(size=n)), 3)]
    if "P0" not in system and rng.random() < 0.5:
        system["P0"] = _m(_spd(rng, n, 10 ** rng.uniform(-1, 1)))
    if edge is None and rng.random() < 0.5:
        data["graph"] = (random_graph_table(rng, N, N, kinds=("random_geometric",)) if N > 2 and rng.random() < 0.6
                         else {"kind": "grid", "rows": 2 if N % 2 == 0 and N > 2 else 1, "cols": N // 2 if N % 2 == 0
                               and N > 2 else N})
    if edge != "homogeneous" and rng.random() < 0.3:
        P0 = np.asarray(system.get("P0", np.eye(n)), float)
        for s in sensors:
            s["P_init"] = _m(P0 + _spd(rng, n, 10 ** rng.uniform(-2, 0)))
    if rng.random() < 0.3:
        dmax = max_degree(graph_spec(data["graph"], min_nodes=2))
        data["communication"]["alpha"] = round(float(rng.uniform(0.2, 1.0)) / dmax, 6)
    if rng.random() < 0.3:
        data["communication"]["sweep"] = [round(float(10 ** rng.uniform(-2, 0)), 4),
                                          round(float(10 ** rng.uniform(3, 4)), 1), int(rng.integers(5, 16))]
    if rng.random() < 0.3:
        data["title"] = f"generated: {n} states, {N} nodes"


def _given_gains(rng: np.random.Generator, data: dict, A: np.ndarray) -> None:
    """Gains with Ā = A − mean(L_iH_i) not Hurwitz: node 0 does not pull, the others pull along
    their own H_i; A is then shifted so that Ā has spectral abscissa ≥ 0.1."""
    n = A.shape[0]
    for i, s in enumerate(data["sensors"]):
        H = np.asarray(s["H"])
        L = np.zeros((n, H.shape[0])) if i == 0 else rng.uniform(0.2, 2.0) * H.T / max(np.sum(H * H), 1e-12)
        s["L"] = _m(L)
    Abar = A - sum(np.asarray(s["L"]) @ np.asarray(s["H"]) for s in data["sensors"]) / len(data["sensors"])
    shift = max(0.0, 0.1 - float(np.linalg.eigvals(Abar).real.max()))
    data["system"]["A"] = _m(A + shift * np.eye(n))     # Ā shifted so that its abscissa is ≥ 0.1


def _finish(data: dict, seed: int, edge: str | None) -> dict:
    """Pick the simulated rate from the critical rate of (9) and check that the family accepts it."""
    import dse.estimators.gossip_covariance as gc

    from .scenario import scenario_from_dict

    fixed, factor = data.pop("_rate")
    horizon = data.pop("_horizon")
    body = {k: v for k, v in data.items() if k != "family"}
    sc = scenario_from_dict({**body, "name": "probe"})
    crit = gc.critical_rate_bound(sc.gossip)
    if fixed is not None:
        rate = fixed
    elif crit == 0.0 or not np.isfinite(crit):
        rate = factor
    else:
        rate = factor * crit
    rate = float(np.clip(rate, 0.05, 500.0))
    dmax = int(sc.gossip.degrees.max())
    # about MAX_EVENTS rings per path at most (the exact simulator's cost grows with them)
    horizon = min(horizon, max(0.25, round(MAX_EVENTS / (rate * len(sc.gossip.clocks)), 2)))
    data["communication"]["rates"] = [round(rate, 6)]
    data["simulation"] = _simulation(rate, dmax, horizon)
    data["name"] = f"gen-{edge or 'random'}-{seed}"
    scenario_from_dict({k: v for k, v in data.items() if k != "family"})
    return data


def generate(seed: int, edge: str | None = None) -> dict:
    """A valid scenario dict of the family (with `family` and `name`), biased towards `edge`."""
    if edge is not None and edge not in EDGES:
        raise ValueError(f"unknown edge case {edge!r} (one of {', '.join(EDGES)})")
    from dse.errors import ScenarioError

    last = None
    for attempt in range(MAX_ATTEMPTS):
        rng = _rng(seed, edge, attempt)
        if edge is None and rng.random() < 0.5:
            pick = str(rng.choice(EDGES))
        else:
            pick = edge
        try:
            return _finish(_draw(rng, pick), seed, edge)
        except (ScenarioError, np.linalg.LinAlgError, ValueError) as exc:   # e.g. no stabilising CARE solution
            last = exc
    raise RuntimeError(f"no valid scenario for seed {seed}, edge {edge!r} in {MAX_ATTEMPTS} attempts: {last}")
