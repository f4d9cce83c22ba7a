"""Random valid scenarios of the coestimation family, biased towards its edge cases.

`generate(seed, edge)` returns a scenario dict as a user's TOML file would give it, small enough
for a quick run of a few seconds, deterministic in (seed, edge). Gains are drawn the way a
designer would pick them: L_i and J_i from an observer design of the augmented system
(ẋ = Ax + Bw, ẇ = 0, y = C_ix) by a Riccati equation, σ_iK_i a small leakage; the LMIs
(28)-(29) are then usually, not always, feasible. The edge cases: gains that make (28)-(29)
infeasible (J_i far too large, or an unstable Ā_i(1)); inputs with several frequencies whose norm
repeats long after t_end (beats, incommensurate frequencies); fixed and time-varying roles; 2 to 6
nodes; P from the LMI, from (10) (with a random Q_i) or given; no noise (the stochastic runs are
deterministic), very small and very large noise; a disconnected graph. Some scenarios start the nodes'
estimates away from zero, and some draw the graph's kind, the comparison architecture, the steps and the
reference's settings (`_draw_the_rest`).
"""
from __future__ import annotations

import zlib
from typing import Any

import numpy as np

FAMILY = "coestimation"

EDGES: tuple[str, ...] = ("infeasible_lmi_large_J", "infeasible_lmi_unstable_vertex", "beat_frequencies",
                          "incommensurate_frequencies", "fixed_roles", "proximity_roles", "two_nodes", "six_nodes",
                          "lyapunov_P", "given_P", "zero_noise", "small_noise", "large_noise", "disconnected_graph")


def _process(rng: np.random.Generator, n: int, p: int) -> tuple[np.ndarray, np.ndarray]:
    """A Hurwitz A from damped oscillators (and a first-order pole when n is odd) in a random,
    well-conditioned basis, and a random B."""
    blocks = []
    for _ in range(n // 2):
        wn, zeta = rng.uniform(0.6, 2.0), rng.uniform(0.2, 1.0)
        blocks.append(np.array([[0.0, 1.0], [-wn ** 2, -2 * zeta * wn]]))
    if n % 2:
        blocks.append(np.array([[-rng.uniform(0.3, 2.0)]]))
    A = np.zeros((n, n))
    k = 0
    for b in blocks:
        A[k:k + len(b), k:k + len(b)] = b
        k += len(b)
    T = np.eye(n) + 0.3 * rng.standard_normal((n, n))
    A = np.linalg.solve(T, A @ T)
    B = rng.standard_normal((n, p))
    return np.round(A, 4), np.round(B, 4)


def _augmented_gains(rng, A, B, C, weight: float) -> tuple[np.ndarray, np.ndarray]:
    """[L; J] from the Riccati equation of the observer of (x, w) (w constant): it makes the error matrix
    [[A − LC, −B], [JC, 0]] Hurwitz when the augmented pair is detectable."""
    from scipy.linalg import solve_continuous_are

    n, p = B.shape
    m = C.shape[0]
    Aa = np.block([[A, B], [np.zeros((p, n + p))]])
    Ca = np.hstack([C, np.zeros((m, p))])
    Q = weight * np.eye(n + p)
    try:
        X = solve_continuous_are(Aa.T, Ca.T, Q, np.eye(m))
        G = X @ Ca.T
    except (np.linalg.LinAlgError, ValueError):   # not detectable: a plain state observer and a small J
        X = solve_continuous_are(A.T, C.T, weight * np.eye(n), np.eye(m))
        G = np.vstack([X @ C.T, 0.5 * rng.standard_normal((p, m))])
    return G[:n], G[n:]


def _feasible_gains(rng, A, B, C, sigma: float, K: np.ndarray, tries: int) -> tuple[np.ndarray, np.ndarray]:
    """Observer gains with J scaled down by a random factor; redrawn (up to `tries` times) until (28)-(29)
    are feasible (normalised margin > 0), so that most draws exercise the theorems."""
    import dse.estimators.common_lyapunov as cl
    import dse.estimators.input_state_coestimation as ce

    for _ in range(tries):
        L, J = _augmented_gains(rng, A, B, C, float(rng.uniform(1.0, 30.0)))
        J = J * float(rng.uniform(0.1, 0.5))
        margin = cl.common_lyapunov(ce.error_vertices(A, B, C, L, J, sigma, K), 1e-6, feasibility=False).margin
        if np.isfinite(margin) and margin > 0:
            break
    return L, J


def _input(rng, p: int, edge: str | None, t_end: float) -> dict[str, Any]:
    if edge == "beat_frequencies":
        f = rng.uniform(0.5, 2.0)
        delta = rng.uniform(0.02, 0.08)                  # beat period 2π/(fδ) ≫ t_end
        freq = [[f, round(f * (1 + delta), 4)]] + [[rng.uniform(0.2, 1.5), 0.0] for _ in range(p - 1)]
        amp = [[1.0, rng.uniform(0.6, 1.0)]] + [[rng.uniform(0.2, 1.0), 0.0] for _ in range(p - 1)]
    elif edge == "incommensurate_frequencies":
        base = rng.uniform(0.3, 1.0)
        freq = [[base, base * np.sqrt(2)]] + [[base * np.pi / 3, base * np.sqrt(3)] for _ in range(p - 1)]
        amp = [list(rng.uniform(0.3, 1.0, 2)) for _ in range(p)]
    else:
        k = int(rng.integers(1, 3))
        freq = [list(np.round(rng.uniform(0.1, 2.0, k), 3)) for _ in range(p)]
        amp = [list(np.round(rng.uniform(0.0, 1.5, k), 3)) for _ in range(p)]
    J = len(freq[0])
    phase = [list(np.round(rng.uniform(0, 2 * np.pi, J), 3)) for _ in range(p)]
    return {"offset": list(np.round(rng.uniform(-1.0, 1.0, p), 3)), "amplitude": _f(amp), "frequency": _f(freq),
            "phase": _f(phase)}


def _f(x) -> list:
    return np.asarray(x, float).tolist()


def _graph(rng, N: int, edge: str | None) -> dict[str, Any]:
    if edge == "disconnected_graph" and N >= 3:
        cut = int(rng.integers(1, N))
        edges = [[i, i + 1] for i in range(N - 1) if i + 1 != cut]
        return {"kind": "edges", "n": N, "edges": edges}
    kind = str(rng.choice(["line", "ring", "complete", "edges"])) if N >= 3 else "line"
    if kind == "edges":
        chords = [[int(a), int(b)] for a, b in rng.choice(N, size=(2, 2)) if a < b - 1]
        edges = [[i, i + 1] for i in range(N - 1)] + [c for k, c in enumerate(chords) if c not in chords[:k]]
        return {"kind": "edges", "n": N, "edges": edges}      # a chord drawn twice is listed once
    return {"kind": kind, "n": N}


def _types(rng, A, B, n: int, p: int, m: int, n_types: int, edge: str | None) -> dict[str, dict[str, Any]]:
    """Node types: C_i picks m states (sometimes mixed), σ_iK_i a small leakage, observer gains (28)-(29)
    usually feasible; the infeasible edge cases spoil the first type's J or L."""
    types = {}
    for k in range(n_types):
        C = np.zeros((m, n))
        C[np.arange(m), rng.choice(n, size=m, replace=False)] = 1.0
        C += np.round(0.3 * rng.standard_normal((m, n)), 3) * (rng.random() < 0.3)
        K = np.eye(p) * float(rng.uniform(0.5, 2.0))
        sigma = float(np.round(rng.uniform(0.005, 0.5), 4))
        L, J = _feasible_gains(rng, A, B, C, sigma, K, tries=1 if edge is None and rng.random() < 0.3 else 6)
        if edge == "infeasible_lmi_large_J" and k == 0:
            J = J * 60.0 + 20.0 * np.sign(J + 1e-9)
        if edge == "infeasible_lmi_unstable_vertex" and k == 0:
            L = -3.0 * L - 2.0 * np.ones_like(L)            # A − LC unstable: no common P exists
        types[f"t{k}"] = {"name": f"type {k}", "C": _f(np.round(C, 4)), "L": _f(np.round(L, 4)),
                          "J": _f(np.round(J, 4)), "K": _f(K), "sigma": sigma,
                          "eps": float(rng.choice([1e-6, 1e-4, 1e-2])),
                          "comparison_sigma": float(np.round(rng.uniform(0.2, 2.0), 3))}
    return types


def _given_P(types: dict, A, B, n: int, p: int) -> None:
    """What a user would paste: a solution of (28)-(29) when there is one, else (10) at g = 1."""
    import dse.estimators.common_lyapunov as cl
    from scipy.linalg import solve_continuous_lyapunov

    for ty in types.values():
        C, L, J, K = (np.array(ty[k]) for k in ("C", "L", "J", "K"))
        Ab0 = np.block([[A, -B], [np.zeros((p, n)), -ty["sigma"] * K]])
        Ab1 = np.block([[A - L @ C, -B], [J @ C, -ty["sigma"] * K]])
        r = cl.common_lyapunov((Ab0, Ab1), ty["eps"], feasibility=False)   # its maximiser and margin only
        if r.P is not None and r.margin > 0:
            X = r.P * max(1.0, 2.0 * ty["eps"] / r.margin)
        elif np.linalg.eigvals(Ab1).real.max() < 0:
            X = solve_continuous_lyapunov(Ab1.T, -np.eye(n + p))
        else:
            X = np.eye(n + p)
        X = np.round((X + X.T) / 2, 6)
        ty["P"] = _f(X if np.linalg.eigvalsh(X).min() > 0 else np.eye(n + p))


def generate(seed: int, edge: str | None = None) -> dict[str, Any]:
    if edge is not None and edge not in EDGES:
        raise ValueError(f"unknown edge case {edge!r}; one of {', '.join(EDGES)}")
    rng = np.random.default_rng([seed, zlib.crc32((edge or "random").encode())])
    N = {"two_nodes": 2, "six_nodes": 6}.get(edge, int(rng.integers(2, 7)))
    n = int(rng.integers(2, 5))
    p = int(rng.integers(1, 3))
    m = int(rng.integers(1, min(n, 2) + 1))
    A, B = _process(rng, n, p)
    t_end = float(rng.choice([2.0, 3.0, 4.0]))
    n_types = 1 if N == 2 and rng.random() < 0.5 else 2
    types = _types(rng, A, B, n, p, m, n_types, edge)
    type_list = [f"t{int(i) % n_types}" for i in range(N)]
    role_mode = {"fixed_roles": "fixed", "proximity_roles": "proximity", "lyapunov_P": "fixed"}.get(
        edge, str(rng.choice(["fixed", "proximity"])))
    P_mode = {"lyapunov_P": "lyapunov", "given_P": "given"}.get(edge, "lmi")
    active = [float(x) for x in rng.choice([0.0, 1.0, 0.5], size=N, p=[0.4, 0.5, 0.1])]
    if P_mode == "given":
        _given_P(types, A, B, n, p)
    positions = np.round(rng.uniform(-2.0, 2.0, size=(N, 2)), 3)
    if role_mode == "proximity":
        ps = [int(x) for x in rng.choice(n, size=2, replace=False)]
        roles = {"mode": "proximity", "radius": float(np.round(rng.uniform(0.8, 2.5), 3)),
                 "beta": float(np.round(rng.uniform(0.5, 10.0), 3)), "position_states": ps}
    else:
        roles = {"mode": "fixed", "active": active}
    noise = {"zero_noise": (0.0, 0.0), "small_noise": (1e-5, 1e-5), "large_noise": (5.0, 5.0)}.get(
        edge, (float(np.round(rng.uniform(0.01, 0.4), 3)), float(np.round(rng.uniform(0.01, 0.8), 3))))
    quick_trials = int(rng.choice([10, 16, 24]))
    data = {
        "family": FAMILY,
        "name": f"gen-{edge or 'random'}-{seed}",
        "process": {"A": _f(A), "B": _f(B), "x0": _f(np.round(rng.uniform(-1.5, 1.5, n), 3))},
        "input": _input(rng, p, edge, t_end),
        "graph": _graph(rng, N, edge),
        "nodes": {"positions": _f(positions), "type": type_list},
        "node_type": types,
        "coupling": {"alpha": float(np.round(rng.uniform(0.5, 30.0), 3)), "P": P_mode},
        "roles": roles,
        "fixed_roles": {"active": [float(x) for x in rng.choice([0.0, 1.0], size=N)]},
        "simulation": {"t_end": t_end, "step": 0.005, "record_dt": 0.01, "tail_start": t_end / 2},
        "stochastic": {"process_range": noise[0], "measurement_range": noise[1], "runs": 2,
                       "trials": int(rng.choice([20, 40])), "quick_trials": quick_trials,
                       "quick_t_end": float(np.round(t_end / 2, 2))},
    }
    if P_mode == "lyapunov":   # (10) is solved at the roles of the run
        data["fixed_roles"] = {"active": active}
    _initial_estimates_and_Q(data, seed, edge, types, N, n, p, P_mode)
    _draw_the_rest(np.random.default_rng([seed, zlib.crc32((edge or "random").encode()), 2]), data, edge)
    return data


def _draw_the_rest(rng: np.random.Generator, data: dict[str, Any], edge: str | None) -> None:
    """The keys the draws above leave at their defaults, from a stream of their own (so that the draws above do
    not move), each in some draws: a random geometric or grid graph of the same N (unbiased draws), the
    comparison architecture's γ, α and P_lower, the integration steps (deterministic 0.005 or 0.01 s, stochastic
    the same or twice it) and the recording interval (a multiple of both, dividing every horizon drawn), the
    stored runs, and the centralized reference's step, random-walk intensity and fictitious noise."""
    from dse.scenario.graphs import random_graph_table

    N = len(data["nodes"]["type"])
    if edge is None and rng.random() < 0.5:
        data["graph"] = random_graph_table(rng, N, N, kinds=("random_geometric",)) if N > 2 and rng.random() < 0.6 \
            else {"kind": "grid", "rows": 2 if N % 2 == 0 and N > 2 else 1, "cols": N // 2 if N % 2 == 0 and N > 2 else N}
    if rng.random() < 0.3:
        data["comparison"] = {"gamma": float(np.round(rng.uniform(0.02, 0.5), 3)),
                              "alpha": float(np.round(rng.uniform(0.5, 30.0), 3)),
                              "P_lower": float(np.round(10 ** rng.uniform(-4, -2), 6))}
    sim, st = data["simulation"], data["stochastic"]
    if rng.random() < 0.3:
        sim["step"] = float(rng.choice([0.005, 0.01]))
        st["step"] = float(sim["step"] * rng.choice([1, 2]))
        sim["record_dt"] = 0.02                               # divides t_end ∈ {2, 3, 4} and quick_t_end = t_end / 2
    if rng.random() < 0.3:
        st["runs"] = int(rng.integers(1, min(st["quick_trials"], st["trials"], 4) + 1))
    if rng.random() < 0.3:
        data["reference"] = {"dt": float(sim.get("record_dt", 0.01) * rng.choice([1, 2])),
                             "q_w": float(np.round(10 ** rng.uniform(-1, 1), 4)),
                             "r_deterministic": float(np.round(10 ** rng.uniform(-6, -3), 9))}


def _initial_estimates_and_Q(data: dict, seed: int, edge: str | None, types: dict, N: int, n: int, p: int,
                             P_mode: str) -> None:
    """The initial estimates and the Q_i of (10), from a stream of their own (the draws above do not change)."""
    extra = np.random.default_rng([seed, zlib.crc32((edge or "random").encode()), 1])
    if P_mode == "lyapunov":
        for ty in types.values():
            M = extra.standard_normal((n + p, n + p))
            ty["Q"] = _f(np.round(M @ M.T / (n + p) + 0.5 * np.eye(n + p), 4))
    if edge in ("lyapunov_P", "two_nodes", "six_nodes") or extra.random() < 0.3:
        data["nodes"]["xhat0"] = _f(np.round(extra.uniform(-1.0, 1.0, (N, n)), 3))
        data["nodes"]["what0"] = _f(np.round(extra.uniform(-1.0, 1.0, (1, p)), 3))
