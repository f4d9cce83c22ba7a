"""Random valid scenarios of the hybrid-observer family, biased towards its edge cases.

`generate(seed, edge)` returns a scenario dict as a user's TOML file would give it,
deterministic in (seed, edge) and small (a quick run takes a few seconds). Systems are
A = V J V^(-1) with J real block diagonal (chosen eigenvalues) and V not orthogonal, so that
the agents' unobservable spaces are oblique and ρ of (17) is strictly between 0 and 1; each
agent sees a random nonempty set of J's blocks (never all of them unless the edge asks), the
union covering every block (joint observability). Graphs are strongly connected digraphs (a
directed ring through a random order plus random arcs) or connected undirected graphs.

Edge cases: five agents with ρ > 0 (the q of (22) is far beyond simulation: the theorem
claims must say so), six agents (ρ only bracketed by the search), switching directed graphs
(per interval and per iteration, with jitter), marginal A (eigenvalues on the imaginary axis,
an integrator chain) and unstable A, q exactly at the bound of (22) and (27) and one below,
two agents, a scalar state and larger state sizes, a single estimator iteration per interval,
event-time offsets with a leaving agent, and an input.
"""
from __future__ import annotations

from typing import Any

import numpy as np

import dse.estimators.jointly_observable_design as jd

FAMILY = "hybrid-observer"
MAX_Q_GENERATED = 1500          # keep a quick run within a few seconds

EDGES: tuple[str, ...] = (
    "five_agents_rho_positive",
    "six_agents_shared_outputs",
    "switching_directed",
    "marginal_A",
    "integrator_chain",
    "unstable_A",
    "q_at_bound",
    "q_below_bound",
    "two_agents",
    "large_state",
    "symmetric_rule_at_bound",
    "offsets_and_leave",
    "with_input",
    "scalar_state",
    "one_iteration",
)


# -- systems --------------------------------------------------------------------------------------

def _blocks(rng: np.random.Generator, kind: str, n: int) -> list[np.ndarray]:
    """Real Jordan-form blocks with distinct eigenvalues, total size n."""
    blocks, size = [], 0
    used: set = set()
    while size < n:
        two = n - size >= 2 and rng.random() < 0.5
        if kind == "stable":
            re = -float(rng.uniform(0.05, 0.8))
        elif kind == "unstable":
            re = float(rng.uniform(0.05, 0.5)) if rng.random() < 0.6 else -float(rng.uniform(0.05, 0.5))
        elif kind == "marginal":
            re = 0.0 if rng.random() < 0.7 else -float(rng.uniform(0.05, 0.5))
        else:                                                        # mixed
            re = float(rng.uniform(-0.6, 0.4))
        re = round(re, 3)
        if two:
            om = round(float(rng.uniform(0.3, 1.5)), 3)
            key = (re, om)
            block = np.array([[re, om], [-om, re]])
        else:
            key = (re, 0.0)
            block = np.array([[re]])
        if key in used:
            continue
        used.add(key)
        blocks.append(block)
        size += len(block)
    return blocks


def _oblique_basis(rng: np.random.Generator, n: int) -> np.ndarray:
    """A random basis with condition number between about 2 and 10."""
    U, _ = np.linalg.qr(rng.standard_normal((n, n)))
    W, _ = np.linalg.qr(rng.standard_normal((n, n)))
    return U @ np.diag(np.geomspace(1.0, float(rng.uniform(2.0, 10.0)), n)) @ W


def _system(rng: np.random.Generator, n: int, m: int, kind: str, *, chain: bool = False,
            individually_observable: bool = False) -> tuple[np.ndarray, list[np.ndarray]]:
    """A = V J V^-1 and C_i = R_i W_i, W_i the rows of V^-1 of the blocks agent i sees."""
    if chain:                                   # a Jordan block at 0 (double integrator) plus the rest
        blocks = [np.array([[0.0, 1.0], [0.0, 0.0]])] + (_blocks(rng, "stable", n - 2) if n > 2 else [])
    else:
        blocks = _blocks(rng, kind, n)
    J = np.zeros((n, n))
    starts = np.cumsum([0] + [len(b) for b in blocks])
    for b, s in zip(blocks, starts):
        J[s:s + len(b), s:s + len(b)] = b
    V = _oblique_basis(rng, n)
    Vi = np.linalg.inv(V)
    A = V @ J @ Vi
    nb = len(blocks)
    sees = [set() for _ in range(m)]
    order = rng.permutation(nb)
    for k, b in enumerate(order):                # every block seen by someone
        sees[k % m].add(int(b))
    for i in range(m):
        for b in range(nb):
            if rng.random() < 0.3:
                sees[i].add(b)
        if not individually_observable and len(sees[i]) == nb and nb > 1:
            shared = [b for b in range(nb) if any(b in sees[j] for j in range(m) if j != i)]
            if shared:                            # drop a block someone else sees: coverage is kept
                sees[i].discard(int(rng.choice(shared)))
        if not sees[i]:
            sees[i].add(int(rng.integers(nb)))
    C = []
    for i in range(m):
        rows = np.vstack([Vi[starts[b]:starts[b + 1]] for b in sorted(sees[i])])
        k = 1 if rng.random() < 0.7 else min(2, rows.shape[0])
        if chain and 0 in sees[i]:
            k = max(k, 1)
        R = rng.standard_normal((k, rows.shape[0]))
        C.append(R @ rows)
    return A, C


# -- graphs ----------------------------------------------------------------------------------------------

def _directed_graph(rng: np.random.Generator, m: int, extra: float) -> list[list[int]]:
    """Neighbour lists (1-based, self excluded) of a strongly connected digraph."""
    order = rng.permutation(m)
    nb = [set() for _ in range(m)]
    for k in range(m):
        nb[int(order[(k + 1) % m])].add(int(order[k]))                 # order[k] -> order[k+1]
    for i in range(m):
        for j in range(m):
            if i != j and rng.random() < extra:
                nb[i].add(j)
    return [sorted(j + 1 for j in s if j != i) for i, s in enumerate(nb)]


def _undirected_graph(rng: np.random.Generator, m: int, extra: float) -> list[list[int]]:
    order = rng.permutation(m)
    nb = [set() for _ in range(m)]
    for k in range(1, m):                                                # a random spanning tree
        a, b = int(order[k]), int(order[int(rng.integers(k))])
        nb[a].add(b)
        nb[b].add(a)
    for i in range(m):
        for j in range(i + 1, m):
            if rng.random() < extra:
                nb[i].add(j)
                nb[j].add(i)
    return [sorted(j + 1 for j in s) for s in nb]


# -- design numbers the generator needs (valid q values) ---------------------------------------------------

def _design(A: np.ndarray, C: list[np.ndarray], lam: float, T: float) -> dict[str, Any]:
    locs = [jd.local_design(A, c) for c in C]
    P = np.array([l.P for l in locs])
    m = len(C)
    nA = float(np.linalg.norm(A, 2))
    q22 = None
    if m <= 3:               # for m >= 4 the q of (22) exceeds 10^4 whatever ρ, λ, T (1 - α <= 3/4^9)
        rho = jd.rho_exact(P)
        q22 = jd.sufficient_q(rho.upper, m, nA, lam, T).q_thm22 if rho.upper < 1 else None
    sig = jd.sigma_symmetric(P)[0] if m <= 5 else None
    q27 = jd.q_symmetric(sig, nA, lam, T) if sig is not None and sig < 1 else None
    return {"q22": q22, "q27": q27, "n_i": [l.n_i for l in locs]}


def _as_list(M: np.ndarray) -> list:
    return np.asarray(M, float).tolist()


# -- the generator -------------------------------------------------------------------------------------------

def generate(seed: int, edge: str | None = None) -> dict[str, Any]:
    if edge is not None and edge not in EDGES:
        raise ValueError(f"unknown edge case {edge!r}; one of {', '.join(EDGES)}")
    rng = np.random.default_rng([seed, EDGES.index(edge) + 1 if edge else 0])
    e = edge or ""
    # sizes
    if e == "five_agents_rho_positive":
        m, n = 5, int(rng.integers(3, 5))
    elif e == "six_agents_shared_outputs":
        m, n = 6, int(rng.integers(2, 4))
    elif e == "two_agents":
        m, n = 2, int(rng.integers(2, 5))
    elif e == "large_state":
        m, n = int(rng.integers(2, 4)), int(rng.integers(6, 9))
    elif e == "scalar_state":                     # n = 1: every agent sees everything, P_i = 0, ρ = σ = 0
        m, n = int(rng.integers(2, 5)), 1
    elif e in ("q_at_bound", "q_below_bound", "symmetric_rule_at_bound"):
        m, n = int(rng.integers(2, 4)), int(rng.integers(2, 5))
    else:
        m, n = int(rng.integers(2, 6)), int(rng.integers(2, 6))
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
    des = _design(A, C, lam, T)

    # graphs
    symmetric = e == "symmetric_rule_at_bound" or (not e and rng.random() < 0.3)
    n_graphs = 1 if (e == "symmetric_rule_at_bound" and rng.random() < 0.5) else int(rng.integers(1, 4))
    if e == "switching_directed":
        n_graphs = int(rng.integers(2, 4))
    graphs = [(_undirected_graph if symmetric else _directed_graph)(rng, m, float(rng.uniform(0.0, 0.5)))
              for _ in range(n_graphs)]
    switching = ("alternate_iteration" if (e == "switching_directed" or rng.random() < 0.3) else "alternate_interval") \
        if n_graphs > 1 else "fixed"

    # q: the bound of (22) when it can be simulated, else a q of a few tens
    q22, q27 = des["q22"], des["q27"]
    theory = q22 is not None and q22 <= MAX_Q_GENERATED
    if e == "one_iteration":
        q = 1
    elif e == "q_below_bound" and theory:
        q = q22 - 1
    elif theory and (e == "q_at_bound" or rng.random() < 0.6):
        q = q22
    else:
        q = int(rng.integers(1, 40)) if rng.random() < 0.2 else int(rng.integers(3, 40))
    intervals = int(max(4, min(24, round(8.0 / T))))
    if q > 600:
        intervals = min(intervals, 10)
    Delta = T / (q + 1)
    beta = Delta / 4
    eps_max = Delta / 10
    runs: list[dict[str, Any]] = [
        {"name": "sync", "timing": "sync", "switching": switching, "intervals": intervals, "monte_carlo": True,
         "Delta": Delta, "beta": beta},
        {"name": "ideal", "timing": "sync", "switching": switching, "ideal": True, "intervals": min(intervals, 6),
         "monte_carlo": True, "Delta": Delta, "beta": beta},
        {"name": "async", "timing": "async", "switching": switching, "intervals": intervals, "monte_carlo": True,
         "Delta": Delta, "beta": beta, "epsilon": [round(float(rng.uniform(0, eps_max)), 15) for _ in range(m)],
         "reference_run": "sync"},
    ]
    if e == "q_at_bound" and theory and q22 > 2:
        runs.append({"name": "below", "timing": "sync", "switching": switching, "q": q22 - 1,
                     "intervals": min(intervals, 8)})
    if q27 is not None and q27 <= MAX_Q_GENERATED:
        sym_graph = None
        if symmetric:
            sym_graph = 1
        if sym_graph is not None:
            runs.append({"name": "symmetric", "timing": "sync", "switching": "fixed", "graph": sym_graph,
                         "rule": "symmetric", "q": "symmetric", "intervals": min(intervals, 12), "monte_carlo": True})
            if e == "symmetric_rule_at_bound" and q27 > 1:
                runs.append({"name": "symmetric_below", "timing": "sync", "switching": "fixed", "graph": sym_graph,
                             "rule": "symmetric", "q": q27 - 1, "intervals": min(intervals, 8)})
    if e == "offsets_and_leave" or (not e and rng.random() < 0.4):
        offs = [round(float(rng.uniform(-eps_max, eps_max)), 15) for _ in range(m)]
        runs.append({"name": "offsets", "timing": "offset", "switching": switching, "offsets": offs,
                     "intervals": intervals, "Delta": Delta, "beta": beta})
        if e == "offsets_and_leave":
            runs.append({"name": "big_offset", "timing": "offset", "switching": switching,
                         "offsets": [0.0] * (m - 1) + [-round(0.2 * T, 6)], "intervals": intervals})
    if (e == "offsets_and_leave" or (not e and rng.random() < 0.3)) and m >= 3 and intervals >= 6:
        runs.append({"name": "leave", "timing": "sync", "switching": "fixed", "graph": 1, "intervals": intervals,
                     "leave": {"agent": m, "at": round(2 * T, 12), "rejoin": round(4 * T, 12),
                               "policy": str(rng.choice(["reinit", "resume", "open_loop"]))}})
    noise = None
    if e == "with_input" or (not e and rng.random() < 0.3):
        noise = {"b": _as_list(rng.standard_normal(n)), "omega": round(float(rng.uniform(1.0, 10.0)), 3)}
        runs.append({"name": "input", "timing": "sync", "switching": switching, "noise": True,
                     "intervals": min(intervals, 10)})

    data: dict[str, Any] = {
        "family": FAMILY,
        "name": f"gen_{e or 'random'}_{seed}",
        "system": {"A": _as_list(A), "C": [_as_list(c) for c in C]},
        "design": {"T": T, "q": q, "lambda": lam, "lambda_bar": lam_bar},
        "graphs": {"neighbors": graphs},
        "initial": {"x0": _as_list(rng.standard_normal(n)), "xhat0": _as_list(rng.standard_normal((m, n)))},
        "monte_carlo": {"trials": 8, "quick_trials": 4, "scale": 2.0},
        "runs": runs,
    }
    if noise is not None:
        data["noise"] = noise
    return data
