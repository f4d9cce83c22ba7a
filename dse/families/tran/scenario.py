"""The coestimation scenario file, declared once: a linear process with an unknown input, N nodes
with per-type modalities and gains on an undirected graph, active/passive roles (fixed or by
proximity to the target), the comparison architecture and the stochastic variant.

Every key is declared below (type, default, bounds, unit, meaning); docs/scenarios.md is generated
from these declarations. Matrices are read as float arrays. Rules within a table are the
sections' validators; rules that tie tables together (dimensions, one entry per node, step
multiples) are `CoestimationFile`'s validator, each error naming its key. Defaults computed from
other tables are functions (beside their key, `derived_default`) whose docstring is the documented
default; the file's validator sets them. The
validated file is the scenario the stages read; derived quantities are its properties.
"""
from __future__ import annotations

from functools import cached_property
from typing import Annotated, Literal

import numpy as np
from pydantic import AfterValidator, Field, PlainSerializer, model_validator

from dse.errors import ScenarioError, printable
from dse.scenario.declare import (Matrix, Real, ScenarioFile, Section, computed_default, covariance, derived_default,
                                  key, matrix, name_key)
from dse.scenario.graphs import GraphSection, GraphSpec, graph_from_section, laplacian

P_MODES = ("given", "lmi", "lyapunov")
#: the integrator, the exact noise factors and the eigen-decompositions work with dense matrices of
#: the stacked dimension n + N(n + p): beyond these sizes a run takes hours and gigabytes
MAX_NODES, MAX_STACKED, MAX_STATE, MAX_INPUT, MAX_OUTPUT, MAX_SINUSOIDS = 40, 240, 12, 6, 12, 50
#: the horizon and step limits: at most 10⁹ integration steps (the run streams over time; its time grows)
MAX_T_END, MIN_STEP, MAX_STEP = 1e4, 1e-5, 0.05
#: the default recording interval keeps at most this many samples of every stored trajectory
DEFAULT_RECORDS = 10_000
#: default recording interval and centralized-filter step when the horizon allows them
BASE_RECORD_DT = 0.01
#: default horizon of the stochastic runs in quick mode
QUICK_T_END = 20.0

_LIST = PlainSerializer(lambda a: a.tolist())
#: a matrix given as a list of equal-length rows, read as a float array
Rows = Annotated[Matrix, AfterValidator(lambda rows: matrix(rows, "")), _LIST]
#: a vector, read as a float array
Vector = Annotated[list[Real], AfterValidator(lambda v: np.array(v, float)), _LIST]
#: a symmetric positive definite matrix (symmetrised exactly: the project's covariance policy)
Definite = Annotated[Matrix, AfterValidator(lambda rows: covariance(rows, "", definite=True)), _LIST]
#: a role g_i ∈ [0, 1]
Role = Annotated[float, Field(allow_inf_nan=False, ge=0, le=1)]


class ProcessSection(Section):
    """The process (1): ẋ = A x + B w(t), x(0) = x0, with A Hurwitz (passive nodes run open loop)."""

    A: Rows = key(doc="state matrix (n x n)", constraint=f"square, Hurwitz (every eigenvalue with negative real part), "
                  f"n <= {MAX_STATE}")
    B: Rows = key(doc="input matrix (n x p)", constraint=f"n rows, p <= {MAX_INPUT} columns")
    x0: Vector = key(doc="initial state x(0) (deterministic; also in the stochastic runs)", unit="state",
                     constraint="n entries")

    @model_validator(mode="after")
    def _dimensions(self):
        A, B, n = self.A, self.B, self.A.shape[0]
        if A.shape[0] != A.shape[1]:
            raise ScenarioError("A", f"must be square, got {A.shape[0]}x{A.shape[1]}")
        if n > MAX_STATE:
            raise ScenarioError("A", f"n = {n} states; this family handles at most {MAX_STATE}")
        if np.linalg.eigvals(A).real.max() >= 0:
            raise ScenarioError("A", "must be Hurwitz (passive nodes run open loop; a standing assumption)")
        if B.shape[0] != n:
            raise ScenarioError("B", f"must have {n} rows, got {B.shape[0]}")
        if B.shape[1] > MAX_INPUT:
            raise ScenarioError("B", f"p = {B.shape[1]} inputs; this family handles at most {MAX_INPUT}")
        if len(self.x0) != n:
            raise ScenarioError("x0", f"must have {n} entries, got {len(self.x0)}")
        return self


class InputSection(Section):
    """The unknown input, a sum of sinusoids per component: w_k(t) = offset_k + Σ_j amplitude_kj
    sin(frequency_kj t + phase_kj). Its bounds sup‖w‖ and sup‖ẇ‖ over all t ≥ 0 (the w̄ of (15)) are
    certified from these values."""

    def _zeros(sc):
        """zeros"""
        return np.zeros(sc.p)

    offset: Vector | None = key(derived_default(_zeros), doc="constant part of each input component", unit="input",
                                constraint="p entries")
    amplitude: Rows = key(doc="amplitudes, one row per input component", unit="input",
                          constraint=f"p rows of J entries, J <= {MAX_SINUSOIDS}")
    frequency: Rows = key(doc="angular frequencies, the same shape as amplitude", unit="rad/s", constraint=">= 0")
    phase: Rows = key(doc="phases, the same shape as amplitude", unit="rad")

    @model_validator(mode="after")
    def _sinusoids(self):
        if not (self.amplitude.shape == self.frequency.shape == self.phase.shape):
            raise ScenarioError("frequency", "amplitude, frequency and phase must have the same shape")
        if self.frequency.shape[1] > MAX_SINUSOIDS:
            raise ScenarioError("frequency", f"at most {MAX_SINUSOIDS} sinusoids per component")
        if self.frequency.min() < 0:
            raise ScenarioError("frequency", "must be >= 0")
        return self


class NodesSection(Section):
    """The nodes: the type of each (its sensing modality and gains), where it is, and where its
    estimates start."""

    def _graph_positions(sc):
        """the graph's drawing positions"""
        return sc.network.positions()

    def _zero_states(sc):
        """zeros"""
        return np.zeros((sc.N, sc.n))

    def _zero_inputs(sc):
        """zeros"""
        return np.zeros((sc.N, sc.p))

    type: list[str] = key(doc="node type of each node, by the name of its [node_type.<name>] table",
                          constraint="one entry per node")
    positions: Rows | None = key(derived_default(_graph_positions), doc="positions c_i in the plane (the centres of "
                                 "the sensing discs of proximity roles; also where figures draw the nodes)",
                                 unit="position", constraint="N rows of 2 entries")
    xhat0: Rows | None = key(derived_default(_zero_states), doc="initial state estimates x̂_i(0) of (3)/(22): one row "
                             "for every node, or one row per node", unit="state", constraint="1 or N rows of n entries")
    what0: Rows | None = key(derived_default(_zero_inputs), doc="initial input estimates ŵ_i(0) of (4)/(23): one row "
                             "for every node, or one row per node", unit="input", constraint="1 or N rows of p entries")


class NodeTypeSection(Section):
    """A node type: what its nodes measure, y_i = C_i x (2), and the gains of (3)-(4). The tables are
    named freely ([node_type.position], [node_type.velocity], ...) and referred to by nodes.type."""

    def _table_name(sc, name):
        """the table's name"""
        return name

    def _identity(sc, name):
        """identity"""
        return np.eye(sc.q)

    @computed_default
    def _own_sigma(data):
        """sigma"""
        return data["sigma"]

    name: str | None = key(derived_default(_table_name), doc="name shown in the figures and tables", max_length=80,
                           constraint="no control or format characters (also in the table's name)")
    C: Rows = key(doc="output matrix C_i (m x n); every type has the same m", constraint=f"n columns, m <= {MAX_OUTPUT}")
    L: Rows = key(doc="state injection gain L_i (n x m) of (3)", constraint="n x m")
    J: Rows = key(doc="input injection gain J_i (p x m) of (4)", constraint="p x m")
    K: Rows = key(doc="input leakage matrix K_i (p x p) of (4)", constraint="p x p; σ_i K_i with eigenvalues of "
                  "positive real part (the leakage −σ_i K_i Hurwitz)")
    sigma: Real = key(doc="leakage coefficient σ_i of (4)", gt=0)
    eps: Real = key(1e-6, doc="ε_i of the vertex LMIs (28)-(29): Ā_i(g)ᵀP_i + P_iĀ_i(g) ≤ −ε_i I at g = 0 and 1", gt=0)
    P: Definite | None = key(None, doc="P_i ((n+p) x (n+p)) used with coupling.P = 'given': H_i = P_i⁻¹ (34)",
                             constraint="symmetric, positive definite")
    Q: Definite | None = key(derived_default(_identity), doc="Q_i ((n+p) x (n+p)) of the Lyapunov equation (10), "
                             "Ā_iᵀP_i + P_iĀ_i + Q_i = 0 at the fixed roles, used with coupling.P = 'lyapunov'",
                             constraint="symmetric, positive definite")
    comparison_sigma: Real = key(_own_sigma, doc="σ_i of the comparison architecture (36)-(37)", gt=0)

    def check(self, field: str, n: int, p: int, m: int | None, given_P: bool) -> None:
        """Its dimensions against the process (n, p) and the other types (m), and σ_iK_i."""
        C = self.C
        if C.shape[1] != n:
            raise ScenarioError(f"{field}.C", f"must have shape {C.shape[0]}x{n}, got {C.shape[0]}x{C.shape[1]}")
        if m is not None and C.shape[0] != m:
            raise ScenarioError(f"{field}.C", f"every node type needs the same output dimension m = {m}, got {C.shape[0]}")
        m = C.shape[0]
        if m > MAX_OUTPUT:
            raise ScenarioError(f"{field}.C", f"m = {m} outputs; this family handles at most {MAX_OUTPUT}")
        for name, shape in (("L", (n, m)), ("J", (p, m)), ("K", (p, p)), ("P", (n + p,) * 2), ("Q", (n + p,) * 2)):
            M = getattr(self, name)
            if M is not None and M.shape != shape:
                raise ScenarioError(f"{field}.{name}", f"must have shape {shape[0]}x{shape[1]}, got {M.shape[0]}x{M.shape[1]}")
            if name == "K" and np.linalg.eigvals(self.sigma * self.K).real.min() <= 0:
                raise ScenarioError(f"{field}.K", "sigma*K must have eigenvalues with positive real part (the input "
                                                  "leakage -sigma K must be Hurwitz)")
        if given_P and self.P is None:
            raise ScenarioError(f"{field}.P", "missing (needed for coupling.P = 'given')")


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

    def _all_active(sc):
        """all ones"""
        return [1.0] * sc.N

    def _plane(sc):
        """[0, 2] (or [0, 1] when n = 2)"""
        return [0, 2 if sc.n > 2 else 1]

    mode: Literal["fixed", "proximity"] = key("fixed", doc="fixed: g_i = active[i]; proximity: the law above")
    active: list[Role] | None = key(derived_default(_all_active), doc="g_i of every node (mode = fixed)",
                                    constraint="one entry per node, each in [0, 1]; only with mode = fixed")
    radius: Real | None = key(None, doc="sensing radius r (mode = proximity)", unit="position", gt=0,
                              constraint="required with mode = proximity, only then")
    beta: Real | None = key(None, doc="rate β of the role transitions (mode = proximity)", unit="1/s", gt=0,
                            constraint="required with mode = proximity, only then")
    position_states: list[int] | None = key(derived_default(_plane), doc="the two state indices that are the target's "
                                            "position in the plane (mode = proximity)",
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

    def _scenario_roles(sc):
        """roles.active with fixed roles, else all ones"""
        return list(sc.roles.active)

    active: list[Role] | None = key(derived_default(_scenario_roles), doc="g_i of every node",
                                    constraint="one entry per node, each in [0, 1]")


class ComparisonSection(Section):
    """The comparison ("estimation") architecture (36)-(37), run on the same process with the scenario's roles."""

    def _coupling_alpha(sc):
        """coupling.alpha"""
        return sc.coupling.alpha

    gamma: Real = key(0.1, doc="leakage γ of (36)-(37)", gt=0)
    alpha: Real | None = key(derived_default(_coupling_alpha), doc="its coupling strength", gt=0)
    P_lower: Real = key(1e-3, doc="lower bound P_i ⪰ P_lower·I of its LMIs (38)-(39) (max-margin solution)", gt=0)


def _divides(b: float, a: float) -> bool:
    k = a / b
    return abs(k - round(k)) <= 1e-6 * max(1.0, k) and round(k) >= 1


def _multiple(a: float, b: float, fa: str, fb: str) -> None:
    if not _divides(b, a):
        raise ScenarioError(fa, f"must be an integer multiple of {fb} = {b:g}, got {a:g}")


class SimulationSection(Section):
    """The deterministic runs: ETD2RK with the stiff linear part integrated exactly, each also at half the
    step (the integration check)."""

    def _record_dt(sc):
        """0.01, or the smallest common multiple of the two steps that divides t_end and keeps at most 10,000 samples"""
        t_end, step = sc.simulation.t_end, sc.simulation.step
        sde_step = sc.stochastic.step if sc.stochastic.step is not None else step
        candidates = [BASE_RECORD_DT] if t_end / BASE_RECORD_DT <= DEFAULT_RECORDS else []
        k0 = max(1, int(np.ceil(t_end / (DEFAULT_RECORDS * step) - 1e-9)))
        for dt in candidates + [k * step for k in range(k0, k0 + 100_000)]:
            if t_end / dt <= DEFAULT_RECORDS * (1 + 1e-9) and _divides(dt, t_end) and _divides(step, dt) \
                    and _divides(sde_step, dt):
                return float(dt)
        raise ScenarioError("simulation.record_dt", "no default fits t_end and the steps: give a record_dt that is a "
                                                    "multiple of step and divides t_end")

    @computed_default
    def _quarter(data):
        """t_end / 4"""
        return 0.25 * data["t_end"]

    t_end: Real = key(40.0, doc="horizon T", unit="s", gt=0, le=MAX_T_END,
                      constraint="a multiple of step, of stochastic.step and of record_dt")
    step: Real = key(0.005, doc="integration step h", unit="s", ge=MIN_STEP, le=MAX_STEP)
    record_dt: Real | None = key(derived_default(_record_dt), doc="interval of the recorded samples: the trajectories, "
                                 "tables, figures and every check along a run use these samples", unit="s",
                                 constraint="a multiple of step and of stochastic.step, dividing t_end")
    tail_start: Real = key(_quarter, doc="start of the tail window (RMS errors, ultimate bounds)", unit="s", ge=0,
                           constraint="< t_end")

    @model_validator(mode="after")
    def _tail(self):
        if self.tail_start >= self.t_end:
            raise ScenarioError("tail_start", f"must be < t_end = {self.t_end:g}, got {self.tail_start:g}")
        return self


class StochasticSection(Section):
    """The stochastic variant (40)-(41): dx = (Ax + Bw)dt + v dW_v, y_i dt = C_i x dt + h_i dS_i, with the
    intensities v ~ U(0, process_range)ⁿ and h_i ~ U(0, measurement_range)ᵐ drawn once per seed."""

    @computed_default
    def _quick_trials(data):
        """max(min(trials, 40), runs)"""
        return max(min(data["trials"], 40), data["runs"])

    def _simulation_step(sc):
        """simulation.step"""
        return sc.simulation.step

    def _quick_horizon(sc):
        """min(t_end, 20), a multiple of record_dt"""
        dt = sc.simulation.record_dt
        return max(1, int(np.floor(min(sc.simulation.t_end, QUICK_T_END) / dt + 1e-9))) * dt

    process_range: Real = key(0.2, doc="upper end of the uniform draws of the process-noise intensity v", unit="state/√s",
                              ge=0)
    measurement_range: Real = key(0.5, doc="upper end of the uniform draws of each h_i", unit="output·√s", ge=0)
    runs: int = key(5, doc="trials stored whole (the repeated runs of the figures)", ge=1, le=50)
    trials: int = key(200, doc="Monte Carlo trials of each stochastic run (time-varying roles, fixed roles, fixed "
                      "roles at half the step)", ge=10, le=100_000, constraint=">= runs")
    quick_trials: int = key(_quick_trials, doc="trials in quick runs", ge=10, le=100_000, constraint=">= runs")
    step: Real | None = key(derived_default(_simulation_step), doc="integration step of the stochastic runs", unit="s",
                            ge=MIN_STEP, le=MAX_STEP)
    quick_t_end: Real | None = key(derived_default(_quick_horizon), doc="horizon of the stochastic runs in quick mode",
                                   unit="s", gt=0, constraint="<= t_end, a multiple of record_dt")

    @model_validator(mode="after")
    def _enough_trials(self):
        for name in ("trials", "quick_trials"):
            if getattr(self, name) < self.runs:
                raise ScenarioError(name, f"must be >= runs = {self.runs}, got {getattr(self, name)}")
        return self


class ReferenceSection(Section):
    """The centralized reference (a project addition): a Kalman filter on (x, w) with every active sensor,
    w modelled as a random walk, discretised exactly at dt."""

    def _reference_dt(sc):
        """the smallest multiple of record_dt >= 0.01"""
        dt = sc.simulation.record_dt
        return dt * max(1, int(np.ceil(BASE_RECORD_DT / dt - 1e-9)))

    dt: Real | None = key(derived_default(_reference_dt), doc="its step", unit="s", constraint="a multiple of record_dt")
    q_w: Real = key(1.0, doc="intensity of the random walk that models w", unit="input²/s", gt=0)
    r_deterministic: Real = key(1e-4, doc="fictitious measurement noise covariance r·I of the noise-free runs",
                                unit="output²", gt=0)


class CoestimationFile(ScenarioFile):
    """A coestimation scenario file."""

    unkeyed = {"name": True, "stochastic": {"trials": True, "quick_trials": True}}

    name: str = name_key()
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

    def _fill_defaults(self) -> None:
        """Set the keys the file leaves out whose defaults depend on other tables, in declaration order."""
        def fill(section, name, fn, *args):
            if getattr(section, name) is None:
                object.__setattr__(section, name, fn(self, *args))
        fill(self.input, "offset", InputSection._zeros)
        for name, fn in (("positions", NodesSection._graph_positions), ("xhat0", NodesSection._zero_states),
                         ("what0", NodesSection._zero_inputs)):
            fill(self.nodes, name, fn)
        for k, t in self.node_type.items():
            fill(t, "name", NodeTypeSection._table_name, k)
            fill(t, "Q", NodeTypeSection._identity, k)
        fill(self.roles, "active", RolesSection._all_active)
        fill(self.roles, "position_states", RolesSection._plane)
        fill(self.fixed_roles, "active", FixedRolesSection._scenario_roles)
        fill(self.comparison, "alpha", ComparisonSection._coupling_alpha)
        fill(self.simulation, "record_dt", SimulationSection._record_dt)
        fill(self.stochastic, "step", StochasticSection._simulation_step)
        fill(self.stochastic, "quick_t_end", StochasticSection._quick_horizon)
        fill(self.reference, "dt", ReferenceSection._reference_dt)

    @model_validator(mode="after")
    def _tables(self):
        """Dimensions and one entry per node (the network's size bounded by the dense matrices of the stacked
        dimension n + N(n + p); a disconnected graph is accepted: only L ⪰ 0 is used by the proofs, connectivity
        is a reported hypothesis), then the step multiples, with the defaults filled in between."""
        n, p, N, inp, nodes = self.n, self.p, self.N, self.input, self.nodes
        if inp.offset is not None and len(inp.offset) != p:
            raise ScenarioError("input.offset", f"must have p = {p} entries, got {len(inp.offset)}")
        for name in ("amplitude", "frequency", "phase"):
            if getattr(inp, name).shape[0] != p:
                raise ScenarioError(f"input.{name}", f"must have p = {p} rows, got {getattr(inp, name).shape[0]}")
        field = "graph.rows" if self.network.kind == "grid" else "graph.n"
        if N > MAX_NODES:
            raise ScenarioError(field, f"{N} nodes; this family handles at most {MAX_NODES} (dense matrices of the "
                                       "stacked dimension n + N(n + p) in the integrator, the noise factors and the spectra)")
        if N * self.q > MAX_STACKED:
            raise ScenarioError(field, f"N(n + p) = {N * self.q}; this family handles at most {MAX_STACKED} (dense "
                                       "matrices of the stacked dimension)")
        m = None
        for k, t in self.node_type.items():
            for field, text in ((f"node_type.{printable(k)}", k), (f"node_type.{printable(k)}.name", t.name or "")):
                if printable(text) != text:
                    raise ScenarioError(field, f"must not contain control or format characters, got '{printable(text)}'")
            t.check(f"node_type.{k}", n, p, m, self.coupling.P == "given")
            m = t.C.shape[0]
        if len(nodes.type) != N:
            raise ScenarioError("nodes.type", f"must have one entry per node ({N}), got {len(nodes.type)}")
        for i, name in enumerate(nodes.type):
            if name not in self.node_type:
                raise ScenarioError(f"nodes.type[{i}]", f"must be one of {', '.join(self.node_type)}; got '{name}'")
        if nodes.positions is not None and nodes.positions.shape != (N, 2):
            raise ScenarioError("nodes.positions", f"must have shape {N}x2, got {nodes.positions.shape[0]}x"
                                                   f"{nodes.positions.shape[1]}")
        for name, M, width in (("xhat0", nodes.xhat0, n), ("what0", nodes.what0, p)):
            if M is not None and M.shape[1] != width:
                raise ScenarioError(f"nodes.{name}", f"must have shape {M.shape[0]}x{width}, got {M.shape[0]}x{M.shape[1]}")
            if M is not None and len(M) not in (1, N):
                raise ScenarioError(f"nodes.{name}", f"must have 1 row (every node) or one row per node ({N}), got {len(M)}")
        for field, active in (("roles.active", self.roles.active), ("fixed_roles.active", self.fixed_roles.active)):
            if active is not None and len(active) != N:
                raise ScenarioError(field, f"must have one entry per node ({N}), got {len(active)}")
        if self.coupling.P == "lyapunov" and self.roles.mode != "fixed":
            raise ScenarioError("coupling.P", "'lyapunov' (solving (10)) needs fixed roles; use 'lmi' or 'given'")
        sim, st = self.simulation, self.stochastic
        _multiple(sim.t_end, sim.step, "simulation.t_end", "simulation.step")
        _multiple(sim.t_end, st.step if st.step is not None else sim.step, "simulation.t_end", "stochastic.step")
        self._fill_defaults()
        self._check_samples()
        return self

    def _check_samples(self) -> None:
        sim, st, ps = self.simulation, self.stochastic, self.roles.position_states
        if sim.record_dt < sim.step:
            raise ScenarioError("simulation.record_dt", f"must be >= simulation.step = {sim.step:g}, got {sim.record_dt:g}")
        _multiple(sim.record_dt, sim.step, "simulation.record_dt", "simulation.step")
        _multiple(sim.record_dt, st.step, "simulation.record_dt", "stochastic.step")
        _multiple(sim.t_end, sim.record_dt, "simulation.t_end", "simulation.record_dt")
        if st.quick_t_end > sim.t_end:
            raise ScenarioError("stochastic.quick_t_end", f"must be <= t_end = {sim.t_end:g}, got {st.quick_t_end:g}")
        _multiple(st.quick_t_end, sim.record_dt, "stochastic.quick_t_end", "simulation.record_dt")
        _multiple(self.reference.dt, sim.record_dt, "reference.dt", "simulation.record_dt")
        if self.roles.mode == "proximity" and (len(ps) != 2 or ps[0] == ps[1] or not all(0 <= s < self.n for s in ps)):
            raise ScenarioError("roles.position_states", f"must be two distinct state indices in 0..{self.n - 1} "
                                                         "(the target's plane position)")

    # -- derived quantities -------------------------------------------------------------------------------

    @property
    def A(self) -> np.ndarray:
        return self.process.A

    @property
    def B(self) -> np.ndarray:
        return self.process.B

    @property
    def n(self) -> int:
        return self.process.A.shape[0]

    @property
    def p(self) -> int:
        return self.process.B.shape[1]

    @property
    def q(self) -> int:
        return self.n + self.p

    @property
    def m(self) -> int:
        return self.types[0].C.shape[0]

    @property
    def N(self) -> int:
        return self.network.n

    @cached_property
    def network(self) -> GraphSpec:
        return graph_from_section(self.graph, "graph", connected=False, min_nodes=2)

    @cached_property
    def lap(self) -> np.ndarray:
        return laplacian(self.network)          # the same matrix as of the networkx graph, without importing networkx

    @cached_property
    def types(self) -> tuple[NodeTypeSection, ...]:
        return tuple(self.node_type.values())

    @cached_property
    def type_of(self) -> tuple[int, ...]:
        """The index (in `types`) of each node's type."""
        return tuple(list(self.node_type).index(name) for name in self.nodes.type)

    @cached_property
    def e0(self) -> np.ndarray:
        """The nodes' initial estimates [x̂_i(0); ŵ_i(0)], (N, n + p)."""
        N, nodes = self.N, self.nodes
        return np.concatenate([np.broadcast_to(nodes.xhat0, (N, self.n)), np.broadcast_to(nodes.what0, (N, self.p))], 1)

    def per_node(self, attr: str) -> np.ndarray:
        return np.stack([np.asarray(getattr(self.types[t], attr), float) for t in self.type_of])
