"""Random valid hybrid-observer scenarios, biased towards the edge cases: `generate(seed, edge)`
is a scenario file as a dict, deterministic in (seed, edge), small (a quick run takes seconds).

Systems are A = V J V^(-1), J real block diagonal (chosen eigenvalues), V not orthogonal, so
that the agents' unobservable spaces are oblique and ρ of (17) is strictly between 0 and 1; each
agent sees a random nonempty set of J's blocks (rarely all of them), their union every block
(joint observability). Graphs are strongly connected digraphs (a directed ring through a random
order plus random arcs) or connected undirected graphs. The edge cases: five agents with ρ > 0
(the q of (22) beyond simulation), six agents sharing outputs (repeated projections), switching directed graphs,
marginal A (an integrator chain too) and unstable A, q at the bound of (22) and (27) and one
below, two agents, a scalar and a larger state, one iteration per interval, offsets with a
leaving agent, and an input. `generate_many_agents` draws a class apart from these: 6 to
8 agents of an oscillatory system in an orthonormal modal basis (ρ = 0 up to round-off). Every draw may also give its gains (or poles), the local observer states, the
centralized poles, graph names, the rank tolerance, the sampling and the Monte Carlo scale (`_draw_the_rest`).
"""
from __future__ import annotations

from typing import Any

import numpy as np

import dse.estimators.jointly_observable_design as jd

MAX_Q_GENERATED = 1500          # keep a quick run within a few seconds
EDGES: tuple[str, ...] = ("five_agents_rho_positive", "six_agents_shared_outputs", "switching_directed", "marginal_A",
                          "integrator_chain", "unstable_A", "q_at_bound", "q_below_bound", "two_agents", "large_state",
                          "symmetric_rule_at_bound", "offsets_and_leave", "with_input", "scalar_state", "one_iteration")
#: (m, n) of the edge cases that fix them: a number, or a (low, high) range drawn from
SIZES = {"five_agents_rho_positive": (5, (3, 5)), "six_agents_shared_outputs": (6, (2, 4)), "two_agents": (2, (2, 5)),
         "large_state": ((2, 4), (6, 9)), "scalar_state": ((2, 5), 1), "q_at_bound": ((2, 4), (2, 5)),
         "q_below_bound": ((2, 4), (2, 5)), "symmetric_rule_at_bound": ((2, 4), (2, 5))}
REAL_PART = {"stable": lambda rng: -float(rng.uniform(0.05, 0.8)),
             "unstable": lambda rng: (1 if rng.random() < 0.6 else -1) * float(rng.uniform(0.05, 0.5)),
             "marginal": lambda rng: 0.0 if rng.random() < 0.7 else -float(rng.uniform(0.05, 0.5)),
             "mixed": lambda rng: float(rng.uniform(-0.6, 0.4))}


def _blocks(rng: np.random.Generator, kind: str, n: int) -> list[np.ndarray]:
    """Real Jordan-form blocks with distinct eigenvalues, total size n."""
    blocks, size, used = [], 0, set()
    while size < n:
        two = n - size >= 2 and rng.random() < 0.5
        re = round(REAL_PART[kind](rng), 3)
        om = round(float(rng.uniform(0.3, 1.5)), 3) if two else 0.0
        if (re, om) in used:
            continue
        used.add((re, om))
        blocks.append(np.array([[re, om], [-om, re]]) if two else np.array([[re]]))
        size += len(blocks[-1])
    return blocks


def _system(rng: np.random.Generator, n: int, m: int, kind: str, chain: bool = False
            ) -> tuple[np.ndarray, list[np.ndarray]]:
    """A = V J V^-1 (V of condition 2 to 10) and C_i = R_i W_i, W_i the rows of V^-1 of the blocks agent i sees."""
    blocks = ([np.array([[0.0, 1.0], [0.0, 0.0]])] + (_blocks(rng, "stable", n - 2) if n > 2 else [])) if chain \
        else _blocks(rng, kind, n)                     # chain: a Jordan block at 0 (double integrator) and the rest
    starts = np.cumsum([0] + [len(b) for b in blocks])
    J = np.zeros((n, n))
    for b, s in zip(blocks, starts):
        J[s:s + len(b), s:s + len(b)] = b
    U, _ = np.linalg.qr(rng.standard_normal((n, n)))
    W, _ = np.linalg.qr(rng.standard_normal((n, n)))
    V = U @ np.diag(np.geomspace(1.0, float(rng.uniform(2.0, 10.0)), n)) @ W
    Vi = np.linalg.inv(V)
    nb = len(blocks)
    sees = [set() for _ in range(m)]
    for k, b in enumerate(rng.permutation(nb)):      # every block seen by someone
        sees[k % m].add(int(b))
    for i in range(m):
        sees[i].update(b for b in range(nb) if rng.random() < 0.3)
        if len(sees[i]) == nb and nb > 1:
            shared = [b for b in range(nb) if any(b in sees[j] for j in range(m) if j != i)]
            if shared:                                # drop a block someone else sees: coverage is kept
                sees[i].discard(int(rng.choice(shared)))
        if not sees[i]:
            sees[i].add(int(rng.integers(nb)))
    C = []
    for i in range(m):
        rows = np.vstack([Vi[starts[b]:starts[b + 1]] for b in sorted(sees[i])])
        C.append(rng.standard_normal((1 if rng.random() < 0.7 else min(2, rows.shape[0]), rows.shape[0])) @ rows)
    return V @ J @ Vi, C


def _graph(rng: np.random.Generator, m: int, extra: float, symmetric: bool) -> list[list[int]]:
    """Neighbour lists (1-based, self excluded): a random spanning tree plus random edges (symmetric),
    or a directed ring through a random order plus random arcs (strongly connected)."""
    order = rng.permutation(m)
    nb = [set() for _ in range(m)]
    if symmetric:
        for k in range(1, m):
            a, b = int(order[k]), int(order[int(rng.integers(k))])
            nb[a].add(b)
            nb[b].add(a)
        for i in range(m):
            for j in range(i + 1, m):
                if rng.random() < extra:
                    nb[i].add(j)
                    nb[j].add(i)
        return [sorted(j + 1 for j in s) for s in nb]
    for k in range(m):
        nb[int(order[(k + 1) % m])].add(int(order[k]))                 # order[k] -> order[k+1]
    for i in range(m):
        nb[i].update(j for j in range(m) if i != j and rng.random() < extra)
    return [sorted(j + 1 for j in s if j != i) for i, s in enumerate(nb)]


def _design_q(A: np.ndarray, C: list[np.ndarray], lam: float, T: float) -> tuple[int | None, int | None]:
    """The q of (22) (m <= 3: beyond 10^4 for m >= 4 whatever ρ, λ, T) and of (27) (m <= 5), None where none."""
    P = np.array([jd.local_design(A, c).P for c in C])
    m, nA = len(C), float(np.linalg.norm(A, 2))
    rho = jd.rho_exact(P).upper if m <= 3 else 1.0
    sig = jd.sigma_symmetric(P)[0] if m <= 5 else None
    return (jd.sufficient_q(rho, m, nA, lam, T).q_thm22 if rho < 1 else None,
            jd.q_symmetric(sig, nA, lam, T) if sig is not None and sig < 1 else None)


def _draw(rng: np.random.Generator, size) -> int:
    return int(rng.integers(*size)) if isinstance(size, tuple) else size


def generate(seed: int, edge: str | None = None) -> dict[str, Any]:
    if edge is not None and edge not in EDGES:
        raise ValueError(f"unknown edge case {edge!r}; one of {', '.join(EDGES)}")
    rng = np.random.default_rng([seed, EDGES.index(edge) + 1 if edge else 0])
    e = edge or ""
    m_size, n_size = SIZES.get(e, ((2, 6), (2, 6)))
    m = _draw(rng, m_size)
    n = _draw(rng, n_size)
    kind = {"marginal_A": "marginal", "unstable_A": "unstable"}.get(e) or str(
        rng.choice(["stable", "unstable", "marginal", "mixed"]))
    if e == "six_agents_shared_outputs":        # three pairs of agents with the same C_i: repeated projections
        A, C = _system(rng, n, 3, kind)
        C = [c for c in C for _ in range(2)]
    else:
        A, C = _system(rng, n, m, kind, chain=(e == "integrator_chain" and n >= 2))
    lam = round(float(rng.uniform(0.2, 1.2)), 3)
    lam_bar = round(lam * float(rng.uniform(1.2, 2.0)), 3)
    T = int(rng.integers(20, 101)) / 100         # a multiple of the 0.01 plotting step: few distinct time steps
    q22, q27 = _design_q(A, C, lam, T)
    symmetric = e == "symmetric_rule_at_bound" or (not e and rng.random() < 0.3)
    n_graphs = 1 if (e == "symmetric_rule_at_bound" and rng.random() < 0.5) else int(rng.integers(1, 4))
    if e == "switching_directed":
        n_graphs = int(rng.integers(2, 4))
    graphs = [_graph(rng, m, float(rng.uniform(0.0, 0.5)), symmetric) for _ in range(n_graphs)]
    switching = ("alternate_iteration" if (e == "switching_directed" or rng.random() < 0.3) else "alternate_interval") \
        if n_graphs > 1 else "fixed"
    theory = q22 is not None and q22 <= MAX_Q_GENERATED      # the bound of (22) when it can be simulated
    if e == "one_iteration":
        q = 1
    elif e == "q_below_bound" and theory:
        q = q22 - 1
    elif theory and (e == "q_at_bound" or rng.random() < 0.6):
        q = q22
    else:
        q = int(rng.integers(1, 40)) if rng.random() < 0.2 else int(rng.integers(3, 40))
    intervals = int(max(4, min(24, round(8.0 / T))))
    data: dict[str, Any] = {"family": "hybrid-observer", "name": f"gen_{e or 'random'}_{seed}",
                            "system": {"A": A.tolist(), "C": [c.tolist() for c in C]},
                            "design": {"T": T, "q": q, "lambda": lam, "lambda_bar": lam_bar},
                            "graphs": {"neighbors": graphs}}
    runs = _runs(rng, e, m, n, T, q, q22, q27, min(intervals, 10) if q > 600 else intervals, switching, symmetric,
                 theory, data)
    data["initial"] = {"x0": rng.standard_normal(n).tolist(), "xhat0": rng.standard_normal((m, n)).tolist()}
    data["monte_carlo"] = {"trials": 8, "quick_trials": 4, "scale": 2.0}
    data["runs"] = runs
    _draw_the_rest(np.random.default_rng([seed, EDGES.index(edge) + 1 if edge else 0, 1]), data)
    return data


def _runs(rng, e: str, m: int, n: int, T: float, q: int, q22, q27, intervals: int, switching: str, symmetric: bool,
          theory: bool, data: dict) -> list[dict[str, Any]]:
    """sync, ideal and async runs; and by edge case (or at random) runs below a bound, with the
    symmetric rule, event-time offsets, a leaving agent or an input (then `data` gets [noise])."""
    Delta = T / (q + 1)
    beta, eps_max = Delta / 4, Delta / 10
    common = {"switching": switching, "Delta": Delta, "beta": beta}
    runs: list[dict[str, Any]] = [
        {"name": "sync", "timing": "sync", **common, "intervals": intervals, "monte_carlo": True},
        {"name": "ideal", "timing": "sync", "switching": switching, "ideal": True, "intervals": min(intervals, 6),
         "monte_carlo": True, "Delta": Delta, "beta": beta},
        {"name": "async", "timing": "async", "switching": switching, "intervals": intervals, "monte_carlo": True,
         "Delta": Delta, "beta": beta, "epsilon": [round(float(rng.uniform(0, eps_max)), 15) for _ in range(m)],
         "reference_run": "sync"}]
    if e == "q_at_bound" and theory and q22 > 2:
        runs.append({"name": "below", "timing": "sync", "switching": switching, "q": q22 - 1,
                     "intervals": min(intervals, 8)})
    if q27 is not None and q27 <= MAX_Q_GENERATED and symmetric:
        runs.append({"name": "symmetric", "timing": "sync", "switching": "fixed", "graph": 1, "rule": "symmetric",
                     "q": "symmetric", "intervals": min(intervals, 12), "monte_carlo": True})
        if e == "symmetric_rule_at_bound" and q27 > 1:
            runs.append({"name": "symmetric_below", "timing": "sync", "switching": "fixed", "graph": 1,
                         "rule": "symmetric", "q": q27 - 1, "intervals": min(intervals, 8)})
    if e == "offsets_and_leave" or (not e and rng.random() < 0.4):
        runs.append({"name": "offsets", "timing": "offset", "switching": switching, "intervals": intervals,
                     "offsets": [round(float(rng.uniform(-eps_max, eps_max)), 15) for _ in range(m)],
                     "Delta": Delta, "beta": beta})
        if e == "offsets_and_leave":
            runs.append({"name": "big_offset", "timing": "offset", "switching": switching,
                         "offsets": [0.0] * (m - 1) + [-round(0.2 * T, 6)], "intervals": intervals})
    if (e == "offsets_and_leave" or (not e and rng.random() < 0.3)) and m >= 3 and intervals >= 6:
        runs.append({"name": "leave", "timing": "sync", "switching": "fixed", "graph": 1, "intervals": intervals,
                     "leave": {"agent": m, "at": round(2 * T, 12), "rejoin": round(4 * T, 12),
                               "policy": str(rng.choice(["reinit", "resume", "open_loop"]))}})
    if e == "with_input" or (not e and rng.random() < 0.3):
        data["noise"] = {"b": rng.standard_normal(n).tolist(),
                         "omega": round(float(rng.uniform(1.0, 10.0)), 3)}
        runs.append({"name": "input", "timing": "sync", "switching": switching, "noise": True,
                     "intervals": min(intervals, 10)})
    return runs


def generate_many_agents(seed: int, m: int | None = None, blocks: int | None = None) -> dict[str, Any]:
    """Issue 26's class: 6 to 8 agents of an oscillatory system (rotation blocks, damped or marginal)
    in an orthonormal modal basis, each agent observing a random proper subset of the blocks (every
    block observed by someone), so that ρ of (17) is 0 up to round-off and several agents share a
    projection; directed strongly connected graphs; q far below the N = (m-1)²+1 of (19) (p = 0).
    `m` and `blocks` fix the agents and the rotation blocks (σ of (26) over 26,704 graphs for 6 agents, and
    Lemma 5's sampled products of N = 50 steps for 8 agents with 6 states, take seconds)."""
    rng = np.random.default_rng([seed, 26])
    m = int(rng.integers(6, 9)) if m is None else m
    blocks = int(rng.integers(2, 4)) if blocks is None else blocks
    n = 2 * blocks
    V, _ = np.linalg.qr(rng.standard_normal((n, n)))
    J = np.zeros((n, n))
    for b in range(blocks):
        re, om = -round(float(rng.uniform(0.0, 0.3)), 3), round(0.4 + b + float(rng.uniform(0.0, 0.5)), 3)
        J[2 * b:2 * b + 2, 2 * b:2 * b + 2] = [[re, om], [-om, re]]
    sees = [{int(b)} for b in rng.permutation(m) % blocks]           # every block, at least twice over 6+ agents
    for s in sees:
        s.update(b for b in range(blocks) if rng.random() < 0.3)
        if len(s) == blocks:
            s.discard(int(rng.choice(sorted(s))))
    C = [(rng.standard_normal((1, 2 * len(s))) @ np.vstack([V.T[2 * b:2 * b + 2] for b in sorted(s)])).tolist()
         for s in sees]
    T = int(rng.integers(20, 61)) / 100
    lam = round(float(rng.uniform(0.2, 0.8)), 3)
    q = int(rng.integers(2, 12))
    graphs = [_graph(rng, m, float(rng.uniform(0.0, 0.3)), False) for _ in range(int(rng.integers(1, 3)))]
    switching = "alternate_interval" if len(graphs) > 1 else "fixed"
    Delta = T / (q + 1)
    common = {"switching": switching, "Delta": Delta, "beta": Delta / 4}
    return {"family": "hybrid-observer", "name": f"gen_many_agents_{seed}",
            "system": {"A": (V @ J @ V.T).tolist(), "C": C},
            "design": {"T": T, "q": q, "lambda": lam, "lambda_bar": round(lam * 1.5, 3)},
            "graphs": {"neighbors": graphs},
            "initial": {"x0": rng.standard_normal(n).tolist(), "xhat0": rng.standard_normal((m, n)).tolist()},
            "monte_carlo": {"trials": 4, "quick_trials": 4, "scale": 2.0},
            "runs": [{"name": "sync", "timing": "sync", **common, "intervals": 5, "monte_carlo": True},
                     {"name": "ideal", "timing": "sync", **common, "ideal": True, "intervals": 4},
                     {"name": "async", "timing": "async", **common, "intervals": 5, "reference_run": "sync",
                      "epsilon": [round(float(rng.uniform(0, Delta / 10)), 15) for _ in range(m)]}]}


def _distinct_poles(rng: np.random.Generator, lam_bar: float, k: int) -> list[float]:
    """k distinct real poles beyond −λ̄ (between −1.1λ̄ and −3λ̄, at least 0.05λ̄ apart)."""
    base = np.sort(rng.uniform(1.1, 2.9 - 0.05 * k, k)) + 0.05 * np.arange(k)
    return [round(-lam_bar * float(b), 6) for b in base]


def _draw_the_rest(rng: np.random.Generator, data: dict[str, Any]) -> None:
    """The keys the draws above leave at their defaults, from a stream of their own (so that the draws above do
    not move), each in some draws: given gains (the placed L_i and K_i written out) with local observer states
    w0, or placed poles of one's own; the centralized observer's poles; graph names; the rank tolerance; the
    sampling step and the stored samples; the Monte Carlo scale. The agents' observable dimensions n_i come from
    the scenario itself."""
    from .scenario import HybridFile

    sc = HybridFile.model_validate({k: v for k, v in data.items() if k != "family"})
    design, lam_bar, T = data["design"], float(data["design"]["lambda_bar"]), float(data["design"]["T"])
    dims = [loc.L.shape[0] for loc in sc.locs]
    u = rng.random()
    if u < 0.25:
        design.update(gains="given", L=[loc.L.tolist() for loc in sc.locs], K=[K.tolist() for K in sc.observer.K])
    elif u < 0.5:
        design["poles"] = [_distinct_poles(rng, lam_bar, k) for k in dims]
    if u < 0.25 or (u < 0.5 and rng.random() < 0.5):
        design["L"] = [loc.L.tolist() for loc in sc.locs]
        data["initial"]["w0"] = [rng.standard_normal(k).round(6).tolist() for k in dims]
    if rng.random() < 0.3:
        design["central_poles"] = _distinct_poles(rng, lam_bar, len(data["system"]["A"]))
    if rng.random() < 0.3:
        data["graphs"]["names"] = [f"N{k}" for k in range(len(data["graphs"]["neighbors"]))]
    if rng.random() < 0.3:
        data["system"]["rank_tol"] = float(10 ** rng.uniform(-11, -8))
    if rng.random() < 0.3:
        data["sampling"] = {"step": round(T / int(rng.integers(10, 101)), 12), "stored": int(rng.integers(200, 20_002))}
    if rng.random() < 0.3:
        data["monte_carlo"]["scale"] = round(float(rng.uniform(0.5, 4.0)), 3)
