"""The coestimation scenario family: a linear process with an unknown input, N nodes with
per-type modalities and gains on an undirected graph, active/passive roles (fixed or by
proximity to the target), the comparison architecture, and the stochastic variant.

Every key is declared once below (type, default, bounds, unit, meaning); `docs/scenarios.md` is
generated from these declarations. Rules that tie keys of different tables together (dimensions,
one entry per node, step multiples) are checked when the scenario is built, each error naming
its key.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import Field, model_validator

from dse.scenario.declare import Matrix, Real, Section, computed, covariance, key, matrix, parse
from dse.errors import ScenarioError, printable
from dse.scenario.graphs import GraphSection, GraphSpec, graph_from_section, laplacian
from dse.scenario.fields import load_toml

P_MODES = ("given", "lmi", "lyapunov")
#: the integrator, the exact noise factors and the eigen-decompositions work with dense matrices of
#: the stacked dimension n + N(n + p): beyond these sizes a run takes hours and gigabytes
MAX_NODES = 40
MAX_STACKED = 240
MAX_STATE = 12
MAX_INPUT = 6
MAX_OUTPUT = 12
MAX_SINUSOIDS = 50
#: the horizon and step limits: at most 10⁹ integration steps (the run streams over time; its time grows)
MAX_T_END = 1e4
MIN_STEP = 1e-5
MAX_STEP = 0.05
#: the default recording interval keeps at most this many samples of every stored trajectory
DEFAULT_RECORDS = 10_000
#: default recording interval and centralized-filter step when the horizon allows them
BASE_RECORD_DT = 0.01
#: default horizon of the stochastic runs in quick mode
QUICK_T_END = 20.0


#: a role g_i ∈ [0, 1]
Role = Annotated[float, Field(allow_inf_nan=False, ge=0, le=1)]


class ProcessSection(Section):
    """The process (1): ẋ = A x + B w(t), x(0) = x0, with A Hurwitz (passive nodes run open loop)."""

    A: Matrix = key(doc="state matrix (n x n)", constraint=f"square, Hurwitz (every eigenvalue with negative real "
                    f"part), n <= {MAX_STATE}")
    B: Matrix = key(doc="input matrix (n x p)", constraint=f"n rows, p <= {MAX_INPUT} columns")
    x0: list[Real] = key(doc="initial state x(0) (deterministic; also in the stochastic runs)", unit="state",
                         constraint="n entries")


class InputSection(Section):
    """The unknown input, a sum of sinusoids per component: w_k(t) = offset_k + Σ_j amplitude_kj
    sin(frequency_kj t + phase_kj). Its bounds sup‖w‖ and sup‖ẇ‖ over all t ≥ 0 (the w̄ of (15)) are
    certified from these values."""

    offset: list[Real] | None = key(computed("zeros"), doc="constant part of each input component", unit="input",
                                    constraint="p entries")
    amplitude: Matrix = key(doc="amplitudes, one row per input component", unit="input",
                            constraint=f"p rows of J entries, J <= {MAX_SINUSOIDS}")
    frequency: Matrix = key(doc="angular frequencies, the same shape as amplitude", unit="rad/s", constraint=">= 0")
    phase: Matrix = key(doc="phases, the same shape as amplitude", unit="rad")


class NodesSection(Section):
    """The nodes: the type of each (its sensing modality and gains), where it is, and where its
    estimates start."""

    type: list[str] = key(doc="node type of each node, by the name of its [node_type.<name>] table",
                          constraint="one entry per node")
    positions: Matrix | None = key(computed("the graph's drawing positions"), doc="positions c_i in the plane (the "
                                   "centres of the sensing discs of proximity roles; also where figures draw the "
                                   "nodes)", unit="position", constraint="N rows of 2 entries")
    xhat0: Matrix | None = key(computed("zeros"), doc="initial state estimates x̂_i(0) of (3)/(22): one row for every "
                               "node, or one row per node", unit="state", constraint="1 or N rows of n entries")
    what0: Matrix | None = key(computed("zeros"), doc="initial input estimates ŵ_i(0) of (4)/(23): one row for every "
                               "node, or one row per node", unit="input", constraint="1 or N rows of p entries")


class NodeTypeSection(Section):
    """A node type: what its nodes measure, y_i = C_i x (2), and the gains of (3)-(4). The tables are
    named freely ([node_type.position], [node_type.velocity], ...) and referred to by nodes.type."""

    name: str | None = key(computed("the table's name"), doc="name shown in the figures and tables",
                           max_length=80, constraint="no control or format characters (also in the table's name)")
    C: Matrix = key(doc="output matrix C_i (m x n); every type has the same m", constraint=f"n columns, m <= {MAX_OUTPUT}")
    L: Matrix = key(doc="state injection gain L_i (n x m) of (3)", constraint="n x m")
    J: Matrix = key(doc="input injection gain J_i (p x m) of (4)", constraint="p x m")
    K: Matrix = key(doc="input leakage matrix K_i (p x p) of (4)", constraint="p x p; σ_i K_i with eigenvalues of "
                    "positive real part (the leakage −σ_i K_i Hurwitz)")
    sigma: Real = key(doc="leakage coefficient σ_i of (4)", gt=0)
    eps: Real = key(1e-6, doc="ε_i of the vertex LMIs (28)-(29): Ā_i(g)ᵀP_i + P_iĀ_i(g) ≤ −ε_i I at g = 0 and 1", gt=0)
    P: Matrix | None = key(None, doc="P_i ((n+p) x (n+p)) used with coupling.P = 'given': H_i = P_i⁻¹ (34)",
                           constraint="symmetric, positive definite")
    Q: Matrix | None = key(computed("identity"), doc="Q_i ((n+p) x (n+p)) of the Lyapunov equation (10), "
                           "Ā_iᵀP_i + P_iĀ_i + Q_i = 0 at the fixed roles, used with coupling.P = 'lyapunov'",
                           constraint="symmetric, positive definite")
    comparison_sigma: Real | None = key(computed("sigma"), doc="σ_i of the comparison architecture (36)-(37)", gt=0)


class CouplingSection(Section):
    """The coupling of (3)-(4): α Σ_j a_ij with H_i = P_i⁻¹ (34)."""

    alpha: Real = key(doc="coupling strength α (one value for every node)", gt=0)
    P: Literal[P_MODES] = key("lmi", doc="where the P_i come from: given (node_type.<name>.P); lmi (the max-margin "  # type: ignore[valid-type]
                              "solution of (28)-(29) per type, Clarabel); lyapunov (the Lyapunov equation "
                              "(10) at the fixed roles with node_type.<name>.Q)",
                              constraint="lyapunov needs roles.mode = fixed")


class RolesSection(Section):
    """The roles g_i(t) ∈ [0, 1] of the estimator (22)-(23): fixed, or by proximity to the target, ġ_i =
    β (a_i(t) − g_i) with a_i = 1 while the target position is within radius of node i (g_i(0) = a_i(0))."""

    mode: Literal["fixed", "proximity"] = key("fixed", doc="fixed: g_i = active[i]; proximity: the law above")
    active: list[Role] | None = key(computed("all ones"), doc="g_i of every node (mode = fixed)",
                                    constraint="one entry per node, each in [0, 1]; only with mode = fixed")
    radius: Real | None = key(None, doc="sensing radius r (mode = proximity)", unit="position", gt=0,
                              constraint="required with mode = proximity, only then")
    beta: Real | None = key(None, doc="rate β of the role transitions (mode = proximity)", unit="1/s", gt=0,
                            constraint="required with mode = proximity, only then")
    position_states: list[int] | None = key(computed("[0, 2] (or [0, 1] when n = 2)"),
                                            doc="the two state indices that are the target's position in the plane "
                                                "(mode = proximity)",
                                            constraint="two distinct indices in 0..n−1; only with mode = proximity")

    @model_validator(mode="after")
    def _mode_rules(self):
        for name in ("radius", "beta"):
            given = getattr(self, name) is not None
            if self.mode == "proximity" and not given:
                raise ScenarioError(name, "missing (needed for mode = 'proximity')")
            if self.mode == "fixed" and given:
                raise ScenarioError(name, "only with mode = 'proximity'")
        if self.mode == "fixed" and self.position_states is not None:
            raise ScenarioError("position_states", "only with mode = 'proximity'")
        if self.mode == "proximity" and self.active is not None:
            raise ScenarioError("active", "only with mode = 'fixed'")
        return self


class FixedRolesSection(Section):
    """The fixed-role scenario of Thm 2.1, Cor 2.1 and Prop 4.1 (run besides the scenario's own roles)."""

    active: list[Role] | None = key(computed("roles.active with fixed roles, else all ones"),
                                    doc="g_i of every node", constraint="one entry per node, each in [0, 1]")


class ComparisonSection(Section):
    """The comparison ("estimation") architecture (36)-(37), run on the same process with the scenario's roles."""

    gamma: Real = key(0.1, doc="leakage γ of (36)-(37)", gt=0)
    alpha: Real | None = key(computed("coupling.alpha"), doc="its coupling strength", gt=0)
    P_lower: Real = key(1e-3, doc="lower bound P_i ⪰ P_lower·I of its LMIs (38)-(39) (max-margin solution)", gt=0)


class SimulationSection(Section):
    """The deterministic runs: ETD2RK with the stiff linear part integrated exactly, each also at half the
    step (the integration check)."""

    t_end: Real = key(40.0, doc="horizon T", unit="s", gt=0, le=MAX_T_END,
                      constraint="a multiple of step, of stochastic.step and of record_dt")
    step: Real = key(0.005, doc="integration step h", unit="s", ge=MIN_STEP, le=MAX_STEP)
    record_dt: Real | None = key(computed(f"{BASE_RECORD_DT:g}, or the smallest common multiple of the two steps that "
                                           f"divides t_end and keeps at most {DEFAULT_RECORDS:,} samples"),
                                 doc="interval of the recorded samples: the trajectories, tables, figures and every "
                                     "check along a run use these samples", unit="s",
                                 constraint="a multiple of step and of stochastic.step, dividing t_end")
    tail_start: Real | None = key(computed("t_end / 4"), doc="start of the tail window (RMS errors, ultimate bounds)",
                                  unit="s", ge=0, constraint="< t_end")


class StochasticSection(Section):
    """The stochastic variant (40)-(41): dx = (Ax + Bw)dt + v dW_v, y_i dt = C_i x dt + h_i dS_i, with the
    intensities v ~ U(0, process_range)ⁿ and h_i ~ U(0, measurement_range)ᵐ drawn once per seed."""

    process_range: Real = key(0.2, doc="upper end of the uniform draws of the process-noise intensity v", unit="state/√s",
                              ge=0)
    measurement_range: Real = key(0.5, doc="upper end of the uniform draws of each h_i", unit="output·√s", ge=0)
    runs: int = key(5, doc="trials stored whole (the repeated runs of the figures)", ge=1, le=50)
    trials: int = key(200, doc="Monte Carlo trials of each stochastic run (time-varying roles, fixed roles, fixed "
                      "roles at half the step)", ge=10, le=100_000, constraint=">= runs")
    quick_trials: int | None = key(computed("max(min(trials, 40), runs)"), doc="trials in quick runs", ge=10, le=100_000,
                                   constraint=">= runs")
    step: Real | None = key(computed("simulation.step"), doc="integration step of the stochastic runs", unit="s",
                            ge=MIN_STEP, le=MAX_STEP)
    quick_t_end: Real | None = key(computed(f"min(t_end, {QUICK_T_END:g}), a multiple of record_dt"),
                                   doc="horizon of the stochastic runs in quick mode", unit="s", gt=0,
                                   constraint="<= t_end, a multiple of record_dt")


class ReferenceSection(Section):
    """The centralized reference (a project addition): a Kalman filter on (x, w) with every active sensor,
    w modelled as a random walk, discretised exactly at dt."""

    dt: Real | None = key(computed(f"the smallest multiple of record_dt >= {BASE_RECORD_DT:g}"),
                          doc="its step", unit="s", constraint="a multiple of record_dt")
    q_w: Real = key(1.0, doc="intensity of the random walk that models w", unit="input²/s", gt=0)
    r_deterministic: Real = key(1e-4, doc="fictitious measurement noise covariance r·I of the noise-free runs",
                                unit="output²", gt=0)


class CoestimationFile(Section):
    """A coestimation scenario file."""

    name: str = key("scenario", doc="scenario name: the output directory OUT/run/<name>/",
                    pattern=r"^[A-Za-z0-9_-]{1,64}$", constraint="1 to 64 letters, digits, '-' or '_'")
    process: ProcessSection = key(doc="the process")
    input: InputSection = key(doc="the unknown input")
    graph: GraphSection = key(doc="the communication graph")
    nodes: NodesSection = key(doc="the nodes")
    node_type: dict[str, NodeTypeSection] = key(doc="the node types", min_length=1, max_length=MAX_NODES)
    coupling: CouplingSection = key(doc="the coupling")
    roles: RolesSection = key(RolesSection, doc="the roles of the scenario's runs")
    fixed_roles: FixedRolesSection = key(FixedRolesSection, doc="the fixed-role runs")
    comparison: ComparisonSection = key(ComparisonSection, doc="the comparison architecture")
    simulation: SimulationSection = key(SimulationSection, doc="the deterministic runs")
    stochastic: StochasticSection = key(StochasticSection, doc="the stochastic runs")
    reference: ReferenceSection = key(ReferenceSection, doc="the centralized reference")


# -- the scenario compute works with ------------------------------------------------------------------

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
    Q: np.ndarray
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
    xhat0: np.ndarray
    what0: np.ndarray
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
    def q(self) -> int:
        return self.n + self.p

    @property
    def lap(self) -> np.ndarray:
        return laplacian(self.graph.build())

    @property
    def e0(self) -> np.ndarray:
        """The nodes' initial estimates [x̂_i(0); ŵ_i(0)], (N, n + p)."""
        return np.concatenate([self.xhat0, self.what0], axis=1)

    def per_node(self, attr: str) -> np.ndarray:
        return np.stack([np.asarray(getattr(self.types[t], attr), float) for t in self.node_type])

    def key(self) -> dict[str, Any]:
        """Everything that determines the numbers (for the stage cache)."""
        d = {}
        for f in self.__dataclass_fields__:
            if f in ("name", "flags", "trials", "quick_trials"):
                continue
            v = getattr(self, f)
            if f == "types":
                v = [{k: (np.asarray(x).tolist() if isinstance(x, np.ndarray) else x) for k, x in t.__dict__.items()}
                     for t in v]
            elif isinstance(v, np.ndarray):
                v = v.tolist()
            d[f] = v
        return d


def _multiple(a: float, b: float, fa: str, fb: str) -> None:
    if not _divides(b, a):
        raise ScenarioError(fa, f"must be an integer multiple of {fb} = {b:g}, got {a:g}")


def _divides(b: float, a: float) -> bool:
    k = a / b
    return abs(k - round(k)) <= 1e-6 * max(1.0, k) and round(k) >= 1


def _per_node_rows(rows, field: str, N: int, width: int) -> np.ndarray:
    """One row for every node or one row per node (None: zeros), as an (N, width) array."""
    if rows is None:
        return np.zeros((N, width))
    M = matrix(rows, field, shape=(None, width))
    if len(M) not in (1, N):
        raise ScenarioError(field, f"must have 1 row (every node) or one row per node ({N}), got {len(M)}")
    return np.broadcast_to(M, (N, width)).copy()


def _roles_vector(values, field: str, N: int) -> tuple[float, ...]:
    if len(values) != N:
        raise ScenarioError(field, f"must have one entry per node ({N}), got {len(values)}")
    return tuple(float(v) for v in values)


def _node_type(t: NodeTypeSection, field: str, key_name: str, n: int, p: int, m: int | None) -> NodeType:
    C = matrix(t.C, f"{field}.C", shape=(None, n))
    if m is not None and C.shape[0] != m:
        raise ScenarioError(f"{field}.C", f"every node type needs the same output dimension m = {m}, got {C.shape[0]}")
    mm = C.shape[0]
    if mm > MAX_OUTPUT:
        raise ScenarioError(f"{field}.C", f"m = {mm} outputs; this family handles at most {MAX_OUTPUT}")
    L = matrix(t.L, f"{field}.L", shape=(n, mm))
    J = matrix(t.J, f"{field}.J", shape=(p, mm))
    K = matrix(t.K, f"{field}.K", shape=(p, p))
    if np.linalg.eigvals(t.sigma * K).real.min() <= 0:
        raise ScenarioError(f"{field}.K", "sigma*K must have eigenvalues with positive real part (the input leakage "
                                          "-sigma K must be Hurwitz)")
    P = covariance(t.P, f"{field}.P", n=n + p, definite=True) if t.P is not None else None
    Q = covariance(t.Q, f"{field}.Q", n=n + p, definite=True) if t.Q is not None else np.eye(n + p)
    cs = t.comparison_sigma if t.comparison_sigma is not None else t.sigma
    return NodeType(t.name if t.name is not None else key_name, C, L, J, K, float(t.sigma), float(t.eps), P, Q, float(cs))


def _default_record_dt(t_end: float, step: float, sde_step: float) -> float:
    """0.01 when the horizon has at most DEFAULT_RECORDS such samples, else the smallest multiple of both
    steps that divides t_end and keeps at most DEFAULT_RECORDS samples."""
    candidates = [BASE_RECORD_DT] if t_end / BASE_RECORD_DT <= DEFAULT_RECORDS else []
    k0 = max(1, int(np.ceil(t_end / (DEFAULT_RECORDS * step) - 1e-9)))
    candidates += [k * step for k in range(k0, k0 + 100_000)]
    for dt in candidates:
        if t_end / dt <= DEFAULT_RECORDS * (1 + 1e-9) and _divides(dt, t_end) and _divides(step, dt) and _divides(sde_step, dt):
            return float(dt)
    raise ScenarioError("simulation.record_dt", "no default fits t_end and the steps: give a record_dt that is a "
                                                "multiple of step and divides t_end")


def scenario_from_dict(data: Any) -> CoestimationScenario:
    f = parse(CoestimationFile, data)
    proc, inp = f.process, f.input
    A = matrix(proc.A, "process.A")
    if A.shape[0] != A.shape[1]:
        raise ScenarioError("process.A", f"must be square, got {A.shape[0]}x{A.shape[1]}")
    n = A.shape[0]
    if n > MAX_STATE:
        raise ScenarioError("process.A", f"n = {n} states; this family handles at most {MAX_STATE}")
    if np.linalg.eigvals(A).real.max() >= 0:
        raise ScenarioError("process.A", "must be Hurwitz (passive nodes run open loop; a standing assumption)")
    B = matrix(proc.B, "process.B")
    if B.shape[0] != n:
        raise ScenarioError("process.B", f"must have {n} rows, got {B.shape[0]}")
    p = B.shape[1]
    if p > MAX_INPUT:
        raise ScenarioError("process.B", f"p = {p} inputs; this family handles at most {MAX_INPUT}")
    x0 = np.array(proc.x0, float)
    if len(x0) != n:
        raise ScenarioError("process.x0", f"must have {n} entries, got {len(x0)}")

    offset = np.zeros(p) if inp.offset is None else np.array(inp.offset, float)
    if len(offset) != p:
        raise ScenarioError("input.offset", f"must have p = {p} entries, got {len(offset)}")
    mats = {}
    for name in ("amplitude", "frequency", "phase"):
        mats[name] = matrix(getattr(inp, name), f"input.{name}")
        if mats[name].shape[0] != p:
            raise ScenarioError(f"input.{name}", f"must have p = {p} rows, got {mats[name].shape[0]}")
    if not (mats["amplitude"].shape == mats["frequency"].shape == mats["phase"].shape):
        raise ScenarioError("input.frequency", "amplitude, frequency and phase must have the same shape")
    if mats["frequency"].shape[1] > MAX_SINUSOIDS:
        raise ScenarioError("input.frequency", f"at most {MAX_SINUSOIDS} sinusoids per component")
    if mats["frequency"].min() < 0:
        raise ScenarioError("input.frequency", "must be >= 0")

    # the theorems use L ⪰ 0 only: a disconnected network is meaningful, connectivity is a reported hypothesis
    graph = graph_from_section(f.graph, "graph", connected=False, min_nodes=2)
    N = graph.n
    n_field = "graph.rows" if graph.kind == "grid" else "graph.n"
    if N > MAX_NODES:
        raise ScenarioError(n_field, f"{N} nodes; this family handles at most {MAX_NODES} (dense matrices of the stacked "
                                     "dimension n + N(n + p) in the integrator, the noise factors and the spectra)")
    if N * (n + p) > MAX_STACKED:
        raise ScenarioError(n_field, f"N(n + p) = {N * (n + p)}; this family handles at most {MAX_STACKED} (dense "
                                     "matrices of the stacked dimension)")

    names = list(f.node_type)
    types: list[NodeType] = []
    for k, t in f.node_type.items():
        for field, text in ((f"node_type.{printable(k)}", k), (f"node_type.{printable(k)}.name", t.name or "")):
            if printable(text) != text:
                raise ScenarioError(field, f"must not contain control or format characters, got '{printable(text)}'")
        types.append(_node_type(t, f"node_type.{k}", k, n, p, types[0].C.shape[0] if types else None))
    nodes = f.nodes
    if len(nodes.type) != N:
        raise ScenarioError("nodes.type", f"must have one entry per node ({N}), got {len(nodes.type)}")
    for i, name in enumerate(nodes.type):
        if name not in names:
            raise ScenarioError(f"nodes.type[{i}]", f"must be one of {', '.join(names)}; got '{name}'")
    node_type = tuple(names.index(name) for name in nodes.type)
    positions = matrix(nodes.positions, "nodes.positions", shape=(N, 2)) if nodes.positions is not None \
        else graph.positions()
    xhat0 = _per_node_rows(nodes.xhat0, "nodes.xhat0", N, n)
    what0 = _per_node_rows(nodes.what0, "nodes.what0", N, p)

    coup = f.coupling
    if coup.P == "given":
        for k, t in zip(names, types):
            if t.P is None:
                raise ScenarioError(f"node_type.{k}.P", "missing (needed for coupling.P = 'given')")

    roles = f.roles
    if roles.mode == "proximity":
        ps = tuple(roles.position_states) if roles.position_states is not None else (0, 2 if n > 2 else 1)
        if len(ps) != 2 or ps[0] == ps[1] or not all(0 <= s < n for s in ps):
            raise ScenarioError("roles.position_states", f"must be two distinct state indices in 0..{n - 1} (the target's "
                                                         "plane position)")
        roles_active = (1.0,) * N
        radius, beta = float(roles.radius), float(roles.beta)
    else:
        roles_active = _roles_vector(roles.active, "roles.active", N) if roles.active is not None else (1.0,) * N
        radius, beta, ps = 1.0, 1.0, (0, 2 if n > 2 else 1)
    if coup.P == "lyapunov" and roles.mode != "fixed":
        raise ScenarioError("coupling.P", "'lyapunov' (solving (10)) needs fixed roles; use 'lmi' or 'given'")
    fixed_active = _roles_vector(f.fixed_roles.active, "fixed_roles.active", N) if f.fixed_roles.active is not None \
        else roles_active

    comp = f.comparison
    sim, st, ref = f.simulation, f.stochastic, f.reference
    step, t_end = float(sim.step), float(sim.t_end)
    sde_step = float(st.step) if st.step is not None else step
    _multiple(t_end, step, "simulation.t_end", "simulation.step")
    _multiple(t_end, sde_step, "simulation.t_end", "stochastic.step")
    record_dt = float(sim.record_dt) if sim.record_dt is not None else _default_record_dt(t_end, step, sde_step)
    if record_dt < step:
        raise ScenarioError("simulation.record_dt", f"must be >= simulation.step = {step:g}, got {record_dt:g}")
    _multiple(record_dt, step, "simulation.record_dt", "simulation.step")
    _multiple(record_dt, sde_step, "simulation.record_dt", "stochastic.step")
    _multiple(t_end, record_dt, "simulation.t_end", "simulation.record_dt")
    tail_start = float(sim.tail_start) if sim.tail_start is not None else 0.25 * t_end
    if tail_start >= t_end:
        raise ScenarioError("simulation.tail_start", f"must be < t_end = {t_end:g}, got {tail_start:g}")

    if st.trials < st.runs:
        raise ScenarioError("stochastic.trials", f"must be >= runs = {st.runs}, got {st.trials}")
    quick_trials = st.quick_trials if st.quick_trials is not None else max(min(st.trials, 40), st.runs)
    if quick_trials < st.runs:
        raise ScenarioError("stochastic.quick_trials", f"must be >= runs = {st.runs}, got {quick_trials}")
    if st.quick_t_end is not None:
        quick_t_end = float(st.quick_t_end)
        if quick_t_end > t_end:
            raise ScenarioError("stochastic.quick_t_end", f"must be <= t_end = {t_end:g}, got {quick_t_end:g}")
        _multiple(quick_t_end, record_dt, "stochastic.quick_t_end", "simulation.record_dt")
    else:
        quick_t_end = max(1, int(np.floor(min(t_end, QUICK_T_END) / record_dt + 1e-9))) * record_dt
    if ref.dt is not None:
        kf_dt = float(ref.dt)
        _multiple(kf_dt, record_dt, "reference.dt", "simulation.record_dt")
    else:
        kf_dt = record_dt * max(1, int(np.ceil(BASE_RECORD_DT / record_dt - 1e-9)))

    return CoestimationScenario(
        f.name, A, B, x0, offset, mats["amplitude"], mats["frequency"], mats["phase"], graph, positions, node_type,
        tuple(types), xhat0, what0, float(coup.alpha), coup.P, roles.mode, radius, beta, (int(ps[0]), int(ps[1])),
        fixed_active, roles_active, float(comp.gamma), float(comp.alpha if comp.alpha is not None else coup.alpha),
        float(comp.P_lower), t_end, step, record_dt, tail_start, float(st.process_range), float(st.measurement_range),
        st.runs, st.trials, quick_trials, sde_step, quick_t_end, kf_dt, float(ref.q_w), float(ref.r_deterministic))


def paper_scenario() -> CoestimationScenario:
    data = load_toml(Path(__file__).with_name("paper.toml"))
    data.pop("family")
    return scenario_from_dict(data)
