"""The random-comm-filter scenario file, declared once: a continuous-time plant, N sensor nodes with
constant-gain filters (5), a graph whose edges carry Poisson clocks of rate λ (6).

Every key is declared below (type, default, bounds, unit, meaning); docs/scenarios.md is generated
from these declarations. The validated model is the scenario the stages read: the matrices, the
network of filters (`gossip`) and the grids are cached properties, and the rules that tie keys of
different tables together (dimensions, one sensor per node, gains, steps) are checked by the file's
validator, each error naming its key.
"""
from __future__ import annotations

import math
import warnings
from functools import cached_property
from pathlib import Path
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import Field, model_validator

from dse.errors import ScenarioError, printable
from dse.estimators.gossip_filter import MODES, GossipSystem, kalman_bucy_split_gains
from dse.scenario.declare import (Matrix, Real, ScenarioFile, Section, computed_default, covariance, derived_default,
                                  key, matrix, name_key, parse)
from dse.scenario.fields import load_toml
from dse.scenario.graphs import GraphSection, GraphSpec, graph_from_section

GAIN_RULES = ("kalman-bucy-split", "given")
#: the exact joint covariance of the N errors is a dense (Nn)² system: these bound its size
MAX_STATE = 8
MAX_JOINT = 40
MAX_RATES = 4
MAX_RATE = 1e4
MAX_SWEEP_RATE = 1e9       # above it the abscissa of M_9 cannot be told from 0 (rounding ~ eps·λ)
MAX_HORIZON = 1e3
MAX_OUTPUTS = 2000
#: grid steps of one gridded run (its time grows with them; its memory does not)
MAX_GRID_STEPS = 2_000_000
#: the gridded step when the rates allow it, and the largest h·(max‖A_i‖₂ + λ d_max) the automatic step keeps
BASE_GRID_STEP = 0.01
GRID_ASYMPTOTIC = 1.0
#: a step given by hand must keep λ·h·d_max below this (at most about one ring per clock and step)
MAX_RINGS_PER_STEP = 0.5
SCENARIO_DIR = Path(__file__).with_name("scenarios")

Rate = Annotated[float, Field(allow_inf_nan=False, gt=0, le=MAX_RATE)]


def _alpha(sc: "RandomCommFile") -> float:
    """min(1/2, 1/d_max)"""
    return min(0.5, 1.0 / sc.d_max)


def _P_init(sc: "RandomCommFile") -> np.ndarray:
    """system.P0"""
    return sc.plant[2]


def _grid_step(sc: "RandomCommFile") -> tuple[float, str]:
    """the largest h = output_step/k <= 0.01 with h·(max‖A_i‖₂ + λ d_max) <= 1 and λ·h·d_max <= 0.5 for every simulated λ (at most 2,000,000 steps)

    h·(max‖A_i‖₂ + λ d_max) <= 1 keeps the gridded simulator in its asymptotic regime (hypothesis
    grid_asymptotic); returns h and the rule in words."""
    lam = max(sc.rates)
    stiff = max(float(np.linalg.norm(A, 2)) for A in sc.gossip.Ai) + lam * sc.d_max
    limits = [BASE_GRID_STEP, GRID_ASYMPTOTIC / stiff] + ([MAX_RINGS_PER_STEP / (lam * sc.d_max)] if lam else [])
    k = max(1, math.ceil(sc.output_step / min(limits) * (1 - 1e-12)))
    k_cap = max(1, MAX_GRID_STEPS // max(sc.n_outputs, 1))
    rule = (f"automatic: the largest output_step/k <= min({BASE_GRID_STEP:g}, {GRID_ASYMPTOTIC:g}/(max‖A_i‖₂ + λd_max) = "
            f"{GRID_ASYMPTOTIC / stiff:.4g}, {MAX_RINGS_PER_STEP:g}/(λd_max)) at λ = {lam:g}, k = {min(k, k_cap)}")
    if k > k_cap:
        rule += f" (capped at {MAX_GRID_STEPS:,} steps: the step is larger than the rule asks)"
        k = k_cap
    return sc.output_step / k, rule


class SystemSection(Section):
    """The plant (1), dx = A x dt + B dω (ω a standard Wiener process), and its initial state
    x(0) ~ N(m0, P0); every node's estimate starts at x̂_i(0) = m0."""

    A: Matrix = key(doc="state matrix A (n x n)", constraint=f"square, n <= {MAX_STATE}; N·n <= {MAX_JOINT} for N "
                    "nodes (the exact joint error covariance is a dense (Nn)² system)")
    B: Matrix = key(doc="noise input matrix B (n x m): the process noise intensity is BBᵀ", constraint="n rows")

    @computed_default
    def _identity(data):
        """identity"""
        return np.eye(len(data["A"])).tolist()

    @computed_default
    def _zeros(data):
        """zeros"""
        return [0.0] * len(data["A"])

    P0: Matrix = key(_identity, doc="covariance of x(0), hence E[e_i(0)e_i(0)ᵀ] of every node", unit="state²",
                     constraint="n x n, symmetric positive semidefinite")
    m0: list[Real] = key(_zeros, doc="mean of x(0), also every node's initial estimate x̂_i(0)", unit="state",
                         constraint="n entries")


class SensorSection(Section):
    """One sensor node i (one table per node, in node order): its measurement (2), dy_i = H_i x dt +
    dv_i with E[dv_i dv_iᵀ] = V_i dt, its gain L_i of the filter (5), and the initial value of its
    covariance bound."""

    H: Matrix = key(doc="output matrix H_i (p_i x n)", constraint="n columns")
    V: Matrix = key(doc="measurement noise intensity V_i (p_i x p_i)", unit="output²·s",
                    constraint="symmetric positive definite")
    L: Matrix | None = key(None, doc="filter gain L_i (n x p_i) of (5)", constraint="required with gains.rule = "
                           "'given', only then")
    P_init: Matrix | None = key(derived_default(_P_init), doc="P_i(0): the initial value of the node's per-path bound "
                                "(14) and of its mean (9). Prop. III.2 and Thm. III.1 need P_i(0) ⪰ E[e_i(0)e_i(0)ᵀ] = "
                                "P0 (reported as the hypothesis 'initial'); the simulated errors start from x(0) − m0 "
                                "whatever P_i(0) is", unit="state²", constraint="n x n, symmetric positive semidefinite")


class CommunicationSection(Section):
    """The communication: one Poisson clock of rate λ per undirected edge (both endpoints fuse at its
    rings, `edge`) or per ordered pair (only the receiver fuses, `ordered`); a ring moves x̂_i to
    (1 − α)x̂_i + αx̂_j (6), Π = I − α𝓛 (3)."""

    alpha: Real | None = key(derived_default(_alpha), doc="fusion weight α of (3) and (6)", gt=0,
                             constraint="<= 1/d_max (d_max the largest node degree)")
    mode: Literal[MODES] = key("edge", doc="edge: one clock per undirected edge, both endpoints update with the "  # type: ignore[valid-type]
                               "pre-jump values; ordered: one clock per ordered pair, only the receiver updates")
    rates: list[Rate] = key([2.0], doc="the Poisson rates λ simulated by Monte Carlo (the first is the main "
                            "rate of the exact simulator and of the statistical claims)", unit="1/s",
                            min_length=1, max_length=MAX_RATES)
    sweep: list[Real] = key([0.1, 1e4, 40], doc="the λ sweep of the steady states [λ_min, λ_max, points] "
                            "(log-spaced; points at multiples of the explicit threshold of (12) are added)",
                            constraint=f"0 < λ_min < λ_max <= {MAX_SWEEP_RATE:g}, points an integer in 5..400",
                            min_length=3, max_length=3)

    @model_validator(mode="after")
    def _sweep_rule(self):
        lo, hi, pts = self.sweep
        if not 0 < lo < hi <= MAX_SWEEP_RATE:
            raise ScenarioError("sweep", f"must be [λ_min, λ_max, points] with 0 < λ_min < λ_max <= "
                                         f"{MAX_SWEEP_RATE:g}, got {list(self.sweep)}")
        if pts != int(pts) or not 5 <= pts <= 400:
            raise ScenarioError("sweep", f"points (the third entry) must be an integer in 5..400, got {pts:g}")
        return self


class GainsSection(Section):
    """The filter gains L_i of (5)."""

    rule: Literal[GAIN_RULES] = key("kalman-bucy-split", doc="kalman-bucy-split: the centralized steady-state "  # type: ignore[valid-type]
                                    "Kalman–Bucy gain K = [K_1 … K_N] cut by columns, L_i = N K_i (so that Ā = A − "
                                    "KH); given: each sensor's L")


class SimulationSection(Section):
    """Horizon, output grid and Monte Carlo sizes. Two simulators: an exact event-driven one (every
    trial its own Poisson clocks, exact Gaussian transitions) at the main rate, and a gridded one
    (exact flow over h/2, Poisson ring counts, exact flow over h/2) at every rate."""

    horizon: Real = key(10.0, doc="horizon T of the transients and the Monte Carlo", unit="s", gt=0, le=MAX_HORIZON)
    output_step: Real = key(0.1, doc="spacing of the output grid (every transient, Monte Carlo moment and table "
                            "series is on it)", unit="s", gt=0,
                            constraint=f"divides the horizon into at most {MAX_OUTPUTS} steps")
    grid_step: Real | None = key(derived_default(_grid_step), doc="step h of the gridded simulator", unit="s", gt=0,
                                 constraint=f"divides output_step; λ·h·d_max <= {MAX_RINGS_PER_STEP:g}; at most "
                                            f"{MAX_GRID_STEPS:,} steps over the horizon")
    trials: int = key(10_000, doc="gridded Monte Carlo trials per rate", ge=100, le=10_000_000)
    event_trials: int = key(2_000, doc="event-driven Monte Carlo trials (main rate), also those of the frozen clock "
                            "path", ge=50, le=1_000_000)

    @computed_default
    def _quick(data):
        """min(trials, 2000)"""
        return min(data["trials"], 2_000)

    @computed_default
    def _quick_event(data):
        """min(event_trials, 300)"""
        return min(data["event_trials"], 300)

    quick_trials: int = key(_quick, doc="gridded trials in quick runs", ge=100, le=10_000_000)
    quick_event_trials: int = key(_quick_event, doc="event-driven trials in quick runs", ge=50, le=1_000_000)
    sample_trials: int = key(3, doc="trials kept whole for the figures and recordings (and stored clock paths)",
                             ge=1, le=20)


class RandomCommFile(ScenarioFile):
    """A random-comm-filter scenario file."""

    #: the stages receive the trial counts as arguments; the title changes no number (the name seeds the streams)
    unkeyed = {"title": True, "simulation": {"trials": True, "event_trials": True, "quick_trials": True,
                                             "quick_event_trials": True}}

    name: str = name_key()

    @computed_default
    def _title(data):
        """the name"""
        return data["name"]

    title: str = key(_title, doc="one line on what the scenario shows (reports, figures, recordings)", max_length=200,
                     constraint="no control or format characters")
    system: SystemSection = key(doc="the plant")
    sensors: list[SensorSection] = key(doc="the sensor nodes, one [[sensors]] table per graph node", min_length=2)
    graph: GraphSection = key(doc="the communication graph (a disconnected one is accepted: item 2 of Theorem III.1 "
                              "then rests on a hypothesis that fails, and is reported so)")
    communication: CommunicationSection = key(CommunicationSection, doc="the Poisson clocks and the fusion")
    gains: GainsSection = key(GainsSection, doc="the filter gains")
    simulation: SimulationSection = key(SimulationSection, doc="horizon, grids and Monte Carlo sizes")

    @model_validator(mode="after")
    def _cross_rules(self):
        """The rules across tables, in this order (each raises one ScenarioError naming its key)."""
        if printable(self.title) != self.title:
            raise ScenarioError("title", f"must not contain control or format characters, got '{printable(self.title)}'")
        for rule in ("plant", "network", "edges", "sensor_matrices", "gains_L", "alpha", "rates", "n_outputs", "grid"):
            getattr(self, rule)
        # the derived defaults, filled in once the rules hold
        for s, P in zip(self.sensors, self.sensor_matrices[3]):
            if s.P_init is None:
                object.__setattr__(s, "P_init", P.tolist())
        object.__setattr__(self.communication, "alpha", self.alpha)
        object.__setattr__(self.simulation, "grid_step", self.grid_step)
        return self

    # -- the plant, the network and the sensors ----------------------------------------------------------------

    @cached_property
    def plant(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(A, B, P0, m0), checked: A square with n <= MAX_STATE, B with n rows, P0 a covariance, m0 n entries."""
        sy = self.system
        A = matrix(sy.A, "system.A")
        n = A.shape[0]
        if A.shape[1] != n:
            raise ScenarioError("system.A", f"must be square, got {A.shape[0]}x{A.shape[1]}")
        if n > MAX_STATE:
            raise ScenarioError("system.A", f"state dimension {n} > {MAX_STATE} is not supported")
        B = matrix(sy.B, "system.B")
        if B.shape[0] != n:
            raise ScenarioError("system.B", f"must have {n} rows (the state dimension), got {B.shape[0]}")
        m0 = np.array(sy.m0, float)
        P0 = covariance(sy.P0, "system.P0", n=n)
        if m0.shape != (n,):
            raise ScenarioError("system.m0", f"must have {n} entries, got {m0.size}")
        return A, B, P0, m0

    @cached_property
    def network(self) -> GraphSpec:
        """The graph (item 1 of Theorem III.1 holds on any graph; item 2 needs connectivity, a hypothesis)."""
        graph = graph_from_section(self.graph, "graph", connected=False, min_nodes=2)
        N, n = graph.n, self.plant[0].shape[0]
        if N * n > MAX_JOINT:
            raise ScenarioError("graph.rows" if graph.kind == "grid" else "graph.n",
                                f"N·n = {N * n} > {MAX_JOINT}: the exact joint covariance of the errors (a dense "
                                f"(Nn)² system) would be too large")
        return graph

    @cached_property
    def edges(self) -> tuple[tuple[int, int], ...]:
        """The undirected edges (u < v), sorted."""
        edges = tuple(sorted({(int(u), int(v)) for u, v in self.network.edge_array()}))
        if not edges:
            raise ScenarioError("graph", "has no edge: there is no communication to study")
        return edges

    @cached_property
    def d_max(self) -> int:
        return int(np.bincount(np.ravel(self.edges), minlength=self.network.n).max())

    @cached_property
    def sensor_matrices(self) -> tuple[list, list, list, list]:
        """(H_i, V_i, given L_i, P_i(0)) of every node, checked against the plant and the gain rule."""
        n, rule = self.plant[0].shape[0], self.gains.rule
        if len(self.sensors) != self.network.n:
            raise ScenarioError("sensors", f"must list one sensor per graph node ({self.network.n}), got "
                                           f"{len(self.sensors)}")
        H, V, L, P_init = [], [], [], []
        for i, s in enumerate(self.sensors):
            fld = f"sensors[{i}]"
            Hi = matrix(s.H, f"{fld}.H")
            if Hi.shape[1] != n:
                raise ScenarioError(f"{fld}.H", f"must have {n} columns, got {Hi.shape[1]}")
            V.append(covariance(s.V, f"{fld}.V", n=Hi.shape[0], definite=True))
            if rule == "given":
                if s.L is None:
                    raise ScenarioError(f"{fld}.L", "missing (needed for gains.rule = 'given')")
                L.append(matrix(s.L, f"{fld}.L", shape=(n, Hi.shape[0])))
            elif s.L is not None:
                raise ScenarioError(f"{fld}.L", "only allowed with gains.rule = 'given'")
            H.append(Hi)
            P_init.append(covariance(s.P_init, f"{fld}.P_init", n=n) if s.P_init is not None else _P_init(self))
        return H, V, L, P_init

    @cached_property
    def gains_L(self) -> tuple[np.ndarray, ...]:
        """The gains L_i: as given, or the centralized Kalman–Bucy gain cut by columns (L_i = N K_i)."""
        H, V, L, _ = self.sensor_matrices
        if self.gains.rule == "kalman-bucy-split":
            A, B = self.plant[:2]
            try:
                with warnings.catch_warnings():
                    warnings.simplefilter("error", RuntimeWarning)     # overflow inside the solver (entries near 1e40)
                    L, _ = kalman_bucy_split_gains(A, B, H, V)
            except RuntimeWarning as exc:
                raise ScenarioError("gains.rule", f"the Kalman–Bucy Riccati equation overflows in float64 ({exc}); "
                                                  f"rescale the system's matrices") from None
            except (np.linalg.LinAlgError, ValueError) as exc:
                raise ScenarioError("gains.rule", f"the Kalman–Bucy Riccati equation has no stabilising solution "
                                                  f"((A, H) not detectable or (A, B) not stabilisable?): {exc}") from None
            if not np.all(np.isfinite(np.concatenate([l.ravel() for l in L]))):
                raise ScenarioError("gains.rule", "the Kalman–Bucy Riccati solution is not finite")
        return tuple(np.asarray(l, float) for l in L)

    @cached_property
    def alpha(self) -> float:
        alpha = float(self.communication.alpha) if self.communication.alpha is not None else _alpha(self)
        if alpha > 1.0 / self.d_max * (1 + 1e-12):
            raise ScenarioError("communication.alpha", f"must be <= {1.0 / self.d_max:.6g} (1/d_max), got {alpha:g}")
        return alpha

    @cached_property
    def gossip(self) -> GossipSystem:
        """The network of filters: plant, sensors, gains, clocks and fusion weight."""
        A, B, P0, m0 = self.plant
        H, V, _, P_init = self.sensor_matrices
        return GossipSystem(A, B, tuple(H), tuple(V), self.gains_L, self.edges, self.alpha, self.communication.mode,
                            P0, m0, np.array(P_init))

    # -- rates and grids ------------------------------------------------------------------------------------------

    @cached_property
    def rates(self) -> tuple[float, ...]:
        rates = tuple(float(r) for r in self.communication.rates)
        if len(set(rates)) != len(rates):
            raise ScenarioError("communication.rates", f"must not repeat a rate, got {list(rates)}")
        return rates

    @property
    def main_rate(self) -> float:
        """The first rate: the exact event-driven simulator's and the statistical claims'."""
        return self.rates[0]

    @property
    def sweep(self) -> tuple[float, float, int]:
        lo, hi, pts = self.communication.sweep
        return float(lo), float(hi), int(pts)

    @property
    def horizon(self) -> float:
        return float(self.simulation.horizon)

    @property
    def output_step(self) -> float:
        return float(self.simulation.output_step)

    @cached_property
    def n_outputs(self) -> int:
        horizon, step = self.horizon, self.output_step
        if step > horizon:
            raise ScenarioError("simulation.output_step", f"must be <= horizon = {horizon:g}, got {step:g}")
        if not _divides(step, horizon) or round(horizon / step) > MAX_OUTPUTS:
            raise ScenarioError("simulation.output_step", f"must divide the horizon into at most {MAX_OUTPUTS} steps")
        return int(round(horizon / step))

    @property
    def output_times(self) -> np.ndarray:
        return np.arange(self.n_outputs + 1) * self.output_step

    @cached_property
    def grid(self) -> tuple[float, str]:
        """(step h of the gridded simulator, how it was chosen: "given", or the automatic rule in words)."""
        h = self.simulation.grid_step
        if h is None:
            return _grid_step(self)
        h, rings = float(h), max(self.rates) * float(h) * self.d_max
        if h > self.output_step or not _divides(h, self.output_step):
            raise ScenarioError("simulation.grid_step", "must divide simulation.output_step")
        if round(self.horizon / h) > MAX_GRID_STEPS:
            raise ScenarioError("simulation.grid_step", f"more than {MAX_GRID_STEPS:,} steps over the horizon")
        if rings > MAX_RINGS_PER_STEP:
            raise ScenarioError("simulation.grid_step", f"λ·h·d_max = {rings:.3g} must be <= {MAX_RINGS_PER_STEP:g} for "
                                                        "the gridded simulator (make the step smaller, or leave "
                                                        "grid_step out to have it chosen)")
        return h, "given"

    @property
    def grid_step(self) -> float:
        return self.grid[0]

    @property
    def grid_rule(self) -> str:
        return self.grid[1]

    @property
    def grid_steps(self) -> int:
        return int(round(self.horizon / self.grid_step))

    def trial_counts(self, trials: int | None, quick: bool) -> tuple[int, int]:
        """(gridded, event-driven) trials of a run: a count given for the run and a fifth of it (at least 50),
        or the file's (quick or default)."""
        if trials is not None:
            return trials, max(50, trials // 5)
        sim = self.simulation
        return (sim.quick_trials, sim.quick_event_trials) if quick else (sim.trials, sim.event_trials)


def _divides(b: float, a: float) -> bool:
    k = a / b
    return abs(k - round(k)) <= 1e-9 * max(1.0, k) and round(k) >= 1


def scenario_from_dict(data: Any) -> RandomCommFile:
    """A validated scenario (one ScenarioError naming the field)."""
    return parse(RandomCommFile, data)


def load_scenario(name: str) -> RandomCommFile:
    """One of the paper's scenario files (scenarios/<name>.toml)."""
    data = load_toml(SCENARIO_DIR / f"{name}.toml")
    data.pop("family", None)
    return scenario_from_dict(data)
