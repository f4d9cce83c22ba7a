"""The coestimation scenario family: a linear process with an unknown input, N nodes with
per-type modalities and gains on an undirected graph, active/passive roles (fixed or by
proximity to the target), the comparison architecture, and the stochastic variant."""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from pipeline.errors import ScenarioError
from pipeline.graphs import GraphSpec, laplacian
from pipeline.scenario import (scenario_root, as_float, as_int, as_int_tuple, as_list, as_matrix, as_str, join, load_toml,
                               reject_unknown, section)

SECTIONS = ("name", "process", "input", "graph", "nodes", "node_type", "coupling", "roles", "fixed_roles",
            "comparison", "simulation", "stochastic", "reference")
P_MODES = ("given", "lmi", "lyapunov")


@dataclass(frozen=True)
class NodeType:
    name: str
    C: np.ndarray
    L: np.ndarray
    J: np.ndarray
    K: np.ndarray
    sigma: float
    eps: float
    P: np.ndarray | None
    comparison_sigma: float


@dataclass(frozen=True)
class CoestimationScenario:
    name: str
    A: np.ndarray
    B: np.ndarray
    x0: np.ndarray
    w_offset: np.ndarray
    w_amplitude: np.ndarray
    w_frequency: np.ndarray
    w_phase: np.ndarray
    graph: GraphSpec
    positions: np.ndarray
    node_type: tuple[int, ...]
    types: tuple[NodeType, ...]
    alpha: float
    P_mode: str
    role_mode: str
    radius: float
    beta: float
    position_states: tuple[int, int]
    fixed_active: tuple[float, ...]
    roles_active: tuple[float, ...]
    gamma: float
    comparison_alpha: float
    comparison_P_lower: float
    t_end: float
    step: float
    record_dt: float
    tail_start: float
    process_range: float
    measurement_range: float
    runs: int
    trials: int
    quick_trials: int
    sde_step: float
    quick_t_end: float
    kf_dt: float
    kf_q_w: float
    kf_r: float
    flags: dict = field(default_factory=dict, compare=False)

    @property
    def n(self) -> int:
        return self.A.shape[0]

    @property
    def p(self) -> int:
        return self.B.shape[1]

    @property
    def m(self) -> int:
        return self.types[0].C.shape[0]

    @property
    def N(self) -> int:
        return self.graph.n

    @property
    def lap(self) -> np.ndarray:
        return laplacian(self.graph.build())

    def per_node(self, attr: str) -> np.ndarray:
        return np.stack([np.asarray(getattr(self.types[t], attr), float) for t in self.node_type])

    def key(self) -> dict[str, Any]:
        d = {}
        for f in self.__dataclass_fields__:
            if f in ("name", "flags"):
                continue
            v = getattr(self, f)
            if f == "types":
                v = [{k: (np.asarray(x).tolist() if isinstance(x, np.ndarray) else x) for k, x in t.__dict__.items()}
                     for t in v]
            d[f] = v
        return d


def _node_type(data: Any, field: str, n: int, p: int, m: int | None, key: str) -> NodeType:
    data = section(data, field)
    reject_unknown(data, ("name", "C", "L", "J", "K", "sigma", "eps", "P", "comparison_sigma"), field)
    for key in ("C", "L", "J", "K", "sigma"):
        if key not in data:
            raise ScenarioError(join(field, key), "missing")
    C = as_matrix(data["C"], join(field, "C"))
    if C.shape[1] != n:
        raise ScenarioError(join(field, "C"), f"must have {n} columns (the state dimension), got {C.shape[1]}")
    if m is not None and C.shape[0] != m:
        raise ScenarioError(join(field, "C"), f"every node type needs the same output dimension m = {m}, got {C.shape[0]}")
    mm = C.shape[0]
    L = as_matrix(data["L"], join(field, "L"), shape=(n, mm))
    J = as_matrix(data["J"], join(field, "J"), shape=(p, mm))
    K = as_matrix(data["K"], join(field, "K"), shape=(p, p))
    sigma = as_float(data["sigma"], join(field, "sigma"), low=0.0, low_open=True)
    if np.linalg.eigvals(sigma * K).real.min() <= 0:
        raise ScenarioError(join(field, "K"), "sigma*K must have eigenvalues with positive real part (the input "
                                             "leakage -sigma K must be Hurwitz)")
    eps = as_float(data.get("eps", 1e-6), join(field, "eps"), low=0.0, low_open=True)
    P = None
    if "P" in data:
        P = as_matrix(data["P"], join(field, "P"), shape=(n + p, n + p), symmetric=True)
        if np.linalg.eigvalsh(P).min() <= 0:
            raise ScenarioError(join(field, "P"), "must be positive definite")
    cs = as_float(data.get("comparison_sigma", sigma), join(field, "comparison_sigma"), low=0.0, low_open=True)
    name = as_str(data.get("name", key), join(field, "name"))
    return NodeType(name, C, L, J, K, sigma, eps, P, cs)


def _binary_vector(value: Any, field: str, N: int) -> tuple[float, ...]:
    v = tuple(as_float(x, f"{field}[{i}]", low=0.0, high=1.0) for i, x in enumerate(as_list(value, field)))
    if len(v) != N:
        raise ScenarioError(field, f"must have one entry per node ({N}), got {len(v)}")
    return v


def scenario_from_dict(data: Any) -> CoestimationScenario:
    data, name = scenario_root(data, allowed=SECTIONS, required=("process", "input", "graph", "nodes", "node_type", "coupling"))

    proc = section(data["process"], "process")
    reject_unknown(proc, ("A", "B", "x0"), "process")
    for key in ("A", "B", "x0"):
        if key not in proc:
            raise ScenarioError(f"process.{key}", "missing")
    A = as_matrix(proc["A"], "process.A")
    if A.shape[0] != A.shape[1]:
        raise ScenarioError("process.A", f"must be square, got {A.shape[0]}x{A.shape[1]}")
    n = A.shape[0]
    if np.linalg.eigvals(A).real.max() >= 0:
        raise ScenarioError("process.A", "must be Hurwitz (passive nodes run open loop; a standing assumption)")
    B = as_matrix(proc["B"], "process.B")
    if B.shape[0] != n:
        raise ScenarioError("process.B", f"must have {n} rows, got {B.shape[0]}")
    p = B.shape[1]
    x0 = np.array([as_float(v, f"process.x0[{i}]") for i, v in enumerate(as_list(proc["x0"], "process.x0"))])
    if len(x0) != n:
        raise ScenarioError("process.x0", f"must have {n} entries, got {len(x0)}")

    inp = section(data["input"], "input")
    reject_unknown(inp, ("offset", "amplitude", "frequency", "phase"), "input")
    offset = np.array([as_float(v, f"input.offset[{i}]") for i, v in enumerate(as_list(inp.get("offset", [0.0] * p), "input.offset"))])
    if len(offset) != p:
        raise ScenarioError("input.offset", f"must have p = {p} entries, got {len(offset)}")
    mats = {}
    for key in ("amplitude", "frequency", "phase"):
        if key not in inp:
            raise ScenarioError(f"input.{key}", "missing (a p x J matrix; one row per input component)")
        mats[key] = as_matrix(inp[key], f"input.{key}")
        if mats[key].shape[0] != p:
            raise ScenarioError(f"input.{key}", f"must have p = {p} rows, got {mats[key].shape[0]}")
    if not (mats["amplitude"].shape == mats["frequency"].shape == mats["phase"].shape):
        raise ScenarioError("input.frequency", "amplitude, frequency and phase must have the same shape")
    if mats["frequency"].min() < 0:
        raise ScenarioError("input.frequency", "must be >= 0")

    graph = GraphSpec.from_dict(data["graph"], "graph", require_connected=False)
    N = graph.n
    nodes = section(data["nodes"], "nodes")
    reject_unknown(nodes, ("positions", "type"), "nodes")
    if "type" not in nodes:
        raise ScenarioError("nodes.type", "missing (one node-type index per node)")
    types_raw = section(data["node_type"], "node_type")
    if not types_raw:
        raise ScenarioError("node_type", "must define at least one node type ([node_type.<name>] tables)")
    types: list[NodeType] = []
    for key, t in types_raw.items():
        types.append(_node_type(t, f"node_type.{key}", n, p, types[0].C.shape[0] if types else None, key))
    names = list(types_raw)
    type_list = as_list(nodes["type"], "nodes.type")
    node_type = tuple(names.index(as_str(v, f"nodes.type[{i}]", names)) for i, v in enumerate(type_list))
    if len(node_type) != N:
        raise ScenarioError("nodes.type", f"must have one entry per node ({N}), got {len(node_type)}")
    if "positions" in nodes:
        positions = as_matrix(nodes["positions"], "nodes.positions", shape=(N, 2))
    else:
        positions = graph.positions()

    coup = section(data["coupling"], "coupling")
    reject_unknown(coup, ("alpha", "P"), "coupling")
    if "alpha" not in coup:
        raise ScenarioError("coupling.alpha", "missing")
    alpha = as_float(coup["alpha"], "coupling.alpha", low=0.0, low_open=True)
    P_mode = as_str(coup.get("P", "lmi"), "coupling.P", P_MODES)
    if P_mode == "given":
        for k, t in enumerate(types):
            if t.P is None:
                raise ScenarioError(f"node_type.{list(types_raw)[k]}.P", "missing (needed for coupling.P = 'given')")

    roles = section(data.get("roles", {"mode": "fixed", "active": [1.0] * N}), "roles")
    role_mode = as_str(roles.get("mode", "proximity"), "roles.mode", ("proximity", "fixed"))
    if role_mode == "proximity":
        reject_unknown(roles, ("mode", "radius", "beta", "position_states"), "roles")
        for key in ("radius", "beta"):
            if key not in roles:
                raise ScenarioError(f"roles.{key}", "missing (needed for mode = 'proximity')")
        radius = as_float(roles["radius"], "roles.radius", low=0.0, low_open=True)
        beta = as_float(roles["beta"], "roles.beta", low=0.0, low_open=True)
        ps = as_int_tuple(roles.get("position_states", [0, 2 if n > 2 else 1]), "roles.position_states", low=0, high=n - 1)
        if len(ps) != 2 or ps[0] == ps[1]:
            raise ScenarioError("roles.position_states", "must be two distinct state indices (the target's plane position)")
        roles_active = (1.0,) * N
    else:
        reject_unknown(roles, ("mode", "active"), "roles")
        if "active" not in roles:
            raise ScenarioError("roles.active", "missing (one g_i in [0, 1] per node, needed for mode = 'fixed')")
        roles_active = _binary_vector(roles["active"], "roles.active", N)
        radius, beta, ps = 1.0, 1.0, (0, 2 if n > 2 else 1)
    if P_mode == "lyapunov" and role_mode != "fixed":
        raise ScenarioError("coupling.P", "'lyapunov' (solving (10)) needs fixed roles; use 'lmi' or 'given'")

    fr = section(data.get("fixed_roles", {}), "fixed_roles")
    reject_unknown(fr, ("active",), "fixed_roles")
    fixed_active = _binary_vector(fr["active"], "fixed_roles.active", N) if "active" in fr else roles_active

    comp = section(data.get("comparison", {}), "comparison")
    reject_unknown(comp, ("gamma", "alpha", "P_lower"), "comparison")
    gamma = as_float(comp.get("gamma", 0.1), "comparison.gamma", low=0.0, low_open=True)
    comparison_alpha = as_float(comp.get("alpha", alpha), "comparison.alpha", low=0.0, low_open=True)
    P_lower = as_float(comp.get("P_lower", 1e-3), "comparison.P_lower", low=0.0, low_open=True)

    s = section(data.get("simulation", {}), "simulation")
    reject_unknown(s, ("t_end", "step", "record_dt", "tail_start"), "simulation")
    t_end = as_float(s.get("t_end", 40.0), "simulation.t_end", low=0.0, low_open=True, high=1e4)
    step = as_float(s.get("step", 0.005), "simulation.step", low=1e-5, high=0.05)
    record_dt = as_float(s.get("record_dt", 0.01), "simulation.record_dt", low=step)
    _multiple(record_dt, step, "simulation.record_dt", "simulation.step")
    _multiple(record_dt, step / 2, "simulation.record_dt", "simulation.step / 2")
    _multiple(t_end, record_dt, "simulation.t_end", "simulation.record_dt")
    tail_start = as_float(s.get("tail_start", 0.25 * t_end), "simulation.tail_start", low=0.0, high=t_end, high_open=True)

    st = section(data.get("stochastic", {}), "stochastic")
    reject_unknown(st, ("process_range", "measurement_range", "runs", "trials", "quick_trials", "step",
                        "quick_t_end"), "stochastic")
    process_range = as_float(st.get("process_range", 0.2), "stochastic.process_range", low=0.0)
    measurement_range = as_float(st.get("measurement_range", 0.5), "stochastic.measurement_range", low=0.0)
    runs = as_int(st.get("runs", 5), "stochastic.runs", low=1, high=50)
    trials = as_int(st.get("trials", 200), "stochastic.trials", low=max(runs, 10), high=100_000)
    quick_trials = as_int(st.get("quick_trials", min(trials, 40)), "stochastic.quick_trials", low=max(runs, 10))
    sde_step = as_float(st.get("step", step), "stochastic.step", low=1e-5, high=0.05)
    _multiple(record_dt, sde_step, "simulation.record_dt", "stochastic.step")
    _multiple(record_dt, sde_step / 2, "simulation.record_dt", "stochastic.step / 2")
    quick_t_end = as_float(st.get("quick_t_end", min(t_end, 20.0)), "stochastic.quick_t_end", low=0.0, low_open=True, high=t_end)
    _multiple(quick_t_end, record_dt, "stochastic.quick_t_end", "simulation.record_dt")

    ref = section(data.get("reference", {}), "reference")
    reject_unknown(ref, ("dt", "q_w", "r_deterministic"), "reference")
    kf_dt = as_float(ref.get("dt", 0.01), "reference.dt", low=record_dt)
    _multiple(kf_dt, record_dt, "reference.dt", "simulation.record_dt")
    kf_q_w = as_float(ref.get("q_w", 1.0), "reference.q_w", low=0.0, low_open=True)
    kf_r = as_float(ref.get("r_deterministic", 1e-4), "reference.r_deterministic", low=0.0, low_open=True)

    return CoestimationScenario(name, A, B, x0, offset, mats["amplitude"], mats["frequency"], mats["phase"], graph,
                                positions, node_type, tuple(types), alpha, P_mode, role_mode, radius, beta,
                                (ps[0], ps[1]), fixed_active, roles_active, gamma, comparison_alpha, P_lower, t_end,
                                step, record_dt, tail_start, process_range, measurement_range, runs, trials,
                                quick_trials, sde_step, quick_t_end, kf_dt, kf_q_w, kf_r)


def _multiple(a: float, b: float, fa: str, fb: str) -> None:
    k = a / b
    if abs(k - round(k)) > 1e-6 * max(1.0, k):
        raise ScenarioError(fa, f"must be an integer multiple of {fb} = {b:g}, got {a:g}")


def paper_scenario() -> CoestimationScenario:
    data = load_toml(Path(__file__).with_name("paper.toml"))
    data.pop("family")
    return scenario_from_dict(data)
