"""The random-comm-filter scenario family: a continuous-time plant, N sensor nodes with
constant-gain filters, a graph whose edges carry Poisson clocks of rate λ.

Every key is declared once below (type, default, bounds, unit, meaning); `docs/scenarios.md` is
generated from these declarations. Rules that tie keys of different tables together
(dimensions, one sensor per node, gains, steps) are checked when the scenario is built, each
error naming its key.
"""
from __future__ import annotations

import math
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import Field, model_validator

from dse.estimators.gossip_filter import MODES, GossipSystem, kalman_bucy_split_gains
from dse.scenario.declare import Matrix, Real, Section, computed, covariance, key, matrix, parse
from dse.errors import ScenarioError, printable
from dse.scenario.graphs import GraphSection, GraphSpec, graph_from_section
from dse.scenario.fields import load_toml

GAIN_RULES = ("kalman-bucy-split", "given")
#: the exact joint covariance of the N errors is a dense (Nn)² system: these bound its size
MAX_STATE = 8
MAX_JOINT = 40
MAX_RATES = 4
MAX_RATE = 1e4
MAX_SWEEP_RATE = 1e9
MAX_HORIZON = 1e3
MAX_OUTPUTS = 2000
#: grid steps of one gridded run (its time grows with them; its memory does not)
MAX_GRID_STEPS = 2_000_000
#: the gridded step when the rates allow it, and the largest h·(max‖A_i‖₂ + λ d_max) the automatic step keeps
BASE_GRID_STEP = 0.01
GRID_ASYMPTOTIC = 1.0
#: a step given by hand must keep λ·h·d_max below this (at most about one ring per clock and step)
MAX_RINGS_PER_STEP = 0.5

Rate = Annotated[float, Field(allow_inf_nan=False, gt=0, le=MAX_RATE)]


class SystemSection(Section):
    """The plant (1), dx = A x dt + B dω (ω a standard Wiener process), and its initial state
    x(0) ~ N(m0, P0); every node's estimate starts at x̂_i(0) = m0."""

    A: Matrix = key(doc="state matrix A (n x n)", constraint=f"square, n <= {MAX_STATE}")
    B: Matrix = key(doc="noise input matrix B (n x m): the process noise intensity is BBᵀ", constraint="n rows")
    P0: Matrix | None = key(computed("identity"), doc="covariance of x(0), hence E[e_i(0)e_i(0)ᵀ] of every node",
                            unit="state²", constraint="n x n, symmetric positive semidefinite")
    m0: list[Real] | None = key(computed("zeros"), doc="mean of x(0), also every node's initial estimate x̂_i(0)",
                                unit="state", constraint="n entries")


class SensorSection(Section):
    """One sensor node i (one table per node, in node order): its measurement (2), dy_i = H_i x dt +
    dv_i with E[dv_i dv_iᵀ] = V_i dt, its gain L_i of the filter (5), and the initial value of its
    covariance bound."""

    H: Matrix = key(doc="output matrix H_i (p_i x n)", constraint="n columns")
    V: Matrix = key(doc="measurement noise intensity V_i (p_i x p_i)", unit="output²·s",
                    constraint="symmetric positive definite")
    L: Matrix | None = key(None, doc="filter gain L_i (n x p_i) of (5)", constraint="required with gains.rule = "
                           "'given', only then")
    P_init: Matrix | None = key(computed("system.P0"), doc="P_i(0): the initial value of the node's per-path bound "
                                "(14) and of its mean (9). Prop. III.2 and Thm. III.1 need P_i(0) ⪰ E[e_i(0)e_i(0)ᵀ] = "
                                "P0 (reported as the hypothesis 'initial'); the simulated errors start from x(0) − m0 "
                                "whatever P_i(0) is", unit="state²", constraint="n x n, symmetric positive semidefinite")


class CommunicationSection(Section):
    """The communication: one Poisson clock of rate λ per undirected edge (both endpoints fuse at its
    rings, `edge`) or per ordered pair (only the receiver fuses, `ordered`); a ring moves x̂_i to
    (1 − α)x̂_i + αx̂_j (6), Π = I − α𝓛 (3)."""

    alpha: Real | None = key(computed("min(1/2, 1/d_max)"), doc="fusion weight α of (3) and (6)", gt=0,
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
    grid_step: Real | None = key(computed(f"the largest h = output_step/k <= {BASE_GRID_STEP:g} with "
                                           f"h·(max‖A_i‖₂ + λ d_max) <= {GRID_ASYMPTOTIC:g} and λ·h·d_max <= "
                                           f"{MAX_RINGS_PER_STEP:g} for every simulated λ (at most "
                                           f"{MAX_GRID_STEPS:,} steps)"),
                                 doc="step h of the gridded simulator", unit="s", gt=0,
                                 constraint=f"divides output_step; λ·h·d_max <= {MAX_RINGS_PER_STEP:g}; at most "
                                            f"{MAX_GRID_STEPS:,} steps over the horizon")
    trials: int = key(10_000, doc="gridded Monte Carlo trials per rate", ge=100, le=10_000_000)
    event_trials: int = key(2_000, doc="event-driven Monte Carlo trials (main rate), also those of the frozen clock "
                            "path", ge=50, le=1_000_000)
    quick_trials: int | None = key(computed("min(trials, 2000)"), doc="gridded trials in quick runs", ge=100,
                                   le=10_000_000)
    quick_event_trials: int | None = key(computed("min(event_trials, 300)"), doc="event-driven trials in quick runs",
                                         ge=50, le=1_000_000)
    sample_trials: int = key(3, doc="trials kept whole for the figures and recordings (and stored clock paths)",
                             ge=1, le=20)


class RandomCommFile(Section):
    """A random-comm-filter scenario file."""

    name: str = key("scenario", doc="scenario name: the output directory OUT/run/<name>/",
                    pattern=r"^[A-Za-z0-9_-]{1,64}$", constraint="1 to 64 letters, digits, '-' or '_'")
    title: str | None = key(computed("the name"), doc="one line on what the scenario shows (reports, figures, "
                            "recordings)", max_length=200, constraint="no control or format characters")
    system: SystemSection = key(doc="the plant")
    sensors: list[SensorSection] = key(doc="the sensor nodes, one [[sensors]] table per graph node", min_length=2)
    graph: GraphSection = key(doc="the communication graph (a disconnected one is accepted: item 2 of Theorem III.1 "
                              "then rests on a hypothesis that fails, and is reported so)")
    communication: CommunicationSection = key(CommunicationSection, doc="the Poisson clocks and the fusion")
    gains: GainsSection = key(GainsSection, doc="the filter gains")
    simulation: SimulationSection = key(SimulationSection, doc="horizon, grids and Monte Carlo sizes")


# -- the scenario compute works with ------------------------------------------------------------------

@dataclass(frozen=True)
class FilterNetworkScenario:
    name: str
    title: str
    graph: GraphSpec
    system: GossipSystem
    gain_rule: str
    rates: tuple[float, ...]
    sweep: tuple[float, float, int]
    horizon: float
    output_step: float
    grid_step: float
    trials: int
    event_trials: int
    quick_trials: int
    quick_event_trials: int
    sample_trials: int
    #: how grid_step was set: "given", or "automatic" with the rule it satisfies
    grid_rule: str = "given"

    @property
    def main_rate(self) -> float:
        return self.rates[0]

    @property
    def n_outputs(self) -> int:
        return int(round(self.horizon / self.output_step))

    @property
    def output_times(self) -> np.ndarray:
        return np.arange(self.n_outputs + 1) * self.output_step

    @property
    def grid_steps(self) -> int:
        return int(round(self.horizon / self.grid_step))

    def key(self) -> dict[str, Any]:
        """Everything that determines the numbers (for the stage cache)."""
        s = self.system
        return {"A": s.A, "B": s.B, "H": list(s.H), "V": list(s.V), "L": list(s.L), "edges": s.edges,
                "alpha": s.alpha, "mode": s.mode, "P0": s.P0, "m0": s.m0, "P_init": s.P_init, "rates": self.rates,
                "sweep": self.sweep, "horizon": self.horizon, "output_step": self.output_step,
                "grid_step": self.grid_step}

    @classmethod
    def from_dict(cls, data: Any) -> "FilterNetworkScenario":
        return scenario_from_dict(data)


def _edges(graph: GraphSpec) -> tuple[tuple[int, int], ...]:
    """The undirected edges (u < v), sorted (networkx only for random geometric graphs)."""
    return tuple(sorted({(int(u), int(v)) for u, v in graph.edge_array()}))


def _degrees(N: int, edges) -> np.ndarray:
    d = np.zeros(N, dtype=int)
    for i, j in edges:
        d[i] += 1
        d[j] += 1
    return d


def automatic_grid_step(output_step: float, horizon: float, rates, Ai: np.ndarray, dmax: int) -> tuple[float, str]:
    """The largest h = output_step/k (k ≥ 1 an integer) with h <= BASE_GRID_STEP, h·(max‖A_i‖₂ + λ d_max) <=
    GRID_ASYMPTOTIC (the gridded simulator's asymptotic regime, hypothesis grid_asymptotic) and λ·h·d_max <=
    MAX_RINGS_PER_STEP for every simulated λ, within MAX_GRID_STEPS steps; and the rule, said in words."""
    lam = max(rates)
    stiff = max(float(np.linalg.norm(A, 2)) for A in Ai) + lam * dmax
    limits = [BASE_GRID_STEP, GRID_ASYMPTOTIC / stiff]
    if lam * dmax > 0:
        limits.append(MAX_RINGS_PER_STEP / (lam * dmax))
    h_max = min(limits)
    k = max(1, math.ceil(output_step / h_max * (1 - 1e-12)))
    n_out = int(round(horizon / output_step))
    k_cap = max(1, MAX_GRID_STEPS // max(n_out, 1))
    rule = (f"automatic: the largest output_step/k <= min({BASE_GRID_STEP:g}, {GRID_ASYMPTOTIC:g}/(max‖A_i‖₂ + λd_max) = "
            f"{GRID_ASYMPTOTIC / stiff:.4g}, {MAX_RINGS_PER_STEP:g}/(λd_max)) at λ = {lam:g}, k = {min(k, k_cap)}")
    if k > k_cap:
        rule += f" (capped at {MAX_GRID_STEPS:,} steps: the step is larger than the rule asks)"
        k = k_cap
    return output_step / k, rule


def _divides(b: float, a: float) -> bool:
    k = a / b
    return abs(k - round(k)) <= 1e-9 * max(1.0, k) and round(k) >= 1


def scenario_from_dict(data: Any) -> FilterNetworkScenario:
    f = parse(RandomCommFile, data)
    name = f.name
    title = f.title if f.title is not None else name
    if printable(title) != title:
        raise ScenarioError("title", f"must not contain control or format characters, got '{printable(title)}'")
    sy = f.system
    A = matrix(sy.A, "system.A")
    n = A.shape[0]
    if A.shape[1] != n:
        raise ScenarioError("system.A", f"must be square, got {A.shape[0]}x{A.shape[1]}")
    if n > MAX_STATE:
        raise ScenarioError("system.A", f"state dimension {n} > {MAX_STATE} is not supported")
    B = matrix(sy.B, "system.B")
    if B.shape[0] != n:
        raise ScenarioError("system.B", f"must have {n} rows (the state dimension), got {B.shape[0]}")
    P0 = covariance(sy.P0, "system.P0", n=n) if sy.P0 is not None else np.eye(n)
    m0 = np.array(sy.m0, float) if sy.m0 is not None else np.zeros(n)
    if m0.shape != (n,):
        raise ScenarioError("system.m0", f"must have {n} entries, got {m0.size}")

    # item 1 of Theorem III.1 holds on any graph; item 2 needs connectivity, a hypothesis reported per scenario
    graph = graph_from_section(f.graph, "graph", connected=False, min_nodes=2)
    N = graph.n
    n_field = "graph.rows" if graph.kind == "grid" else "graph.n"
    if N * n > MAX_JOINT:
        raise ScenarioError(n_field, f"N·n = {N * n} > {MAX_JOINT}: the exact joint covariance of the errors (a dense "
                                     f"(Nn)² system) would be too large")
    edges = _edges(graph)
    if not edges:
        raise ScenarioError("graph", "has no edge: there is no communication to study")
    dmax = int(_degrees(N, edges).max())

    rule = f.gains.rule
    if len(f.sensors) != N:
        raise ScenarioError("sensors", f"must list one sensor per graph node ({N}), got {len(f.sensors)}")
    H, V, L, P_init = [], [], [], []
    for i, s in enumerate(f.sensors):
        fld = f"sensors[{i}]"
        Hi = matrix(s.H, f"{fld}.H")
        if Hi.shape[1] != n:
            raise ScenarioError(f"{fld}.H", f"must have {n} columns, got {Hi.shape[1]}")
        p = Hi.shape[0]
        V.append(covariance(s.V, f"{fld}.V", n=p, definite=True))
        if rule == "given":
            if s.L is None:
                raise ScenarioError(f"{fld}.L", "missing (needed for gains.rule = 'given')")
            L.append(matrix(s.L, f"{fld}.L", shape=(n, p)))
        elif s.L is not None:
            raise ScenarioError(f"{fld}.L", "only allowed with gains.rule = 'given'")
        H.append(Hi)
        P_init.append(covariance(s.P_init, f"{fld}.P_init", n=n) if s.P_init is not None else P0)
    if rule == "kalman-bucy-split":
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

    comm = f.communication
    alpha = float(comm.alpha) if comm.alpha is not None else min(0.5, 1.0 / dmax)
    if alpha > 1.0 / dmax * (1 + 1e-12):
        raise ScenarioError("communication.alpha", f"must be <= {1.0 / dmax:.6g} (1/d_max), got {alpha:g}")
    rates = tuple(float(r) for r in comm.rates)
    if len(set(rates)) != len(rates):
        raise ScenarioError("communication.rates", f"must not repeat a rate, got {list(rates)}")
    lo, hi, pts = comm.sweep

    sim = f.simulation
    horizon, output_step = float(sim.horizon), float(sim.output_step)
    if output_step > horizon:
        raise ScenarioError("simulation.output_step", f"must be <= horizon = {horizon:g}, got {output_step:g}")
    n_out = horizon / output_step
    if not _divides(output_step, horizon) or round(n_out) > MAX_OUTPUTS:
        raise ScenarioError("simulation.output_step", f"must divide the horizon into at most {MAX_OUTPUTS} steps")
    system = GossipSystem(A, B, tuple(H), tuple(V), tuple(np.asarray(l, float) for l in L), edges, alpha, comm.mode,
                          P0, m0, np.array(P_init))
    if sim.grid_step is None:
        grid_step, grid_rule = automatic_grid_step(output_step, horizon, rates, system.Ai, dmax)
    else:
        grid_step, grid_rule = float(sim.grid_step), "given"
        if grid_step > output_step or not _divides(grid_step, output_step):
            raise ScenarioError("simulation.grid_step", "must divide simulation.output_step")
        if round(horizon / grid_step) > MAX_GRID_STEPS:
            raise ScenarioError("simulation.grid_step", f"more than {MAX_GRID_STEPS:,} steps over the horizon")
        if max(rates) * grid_step * dmax > MAX_RINGS_PER_STEP:
            raise ScenarioError("simulation.grid_step", f"λ·h·d_max = {max(rates) * grid_step * dmax:.3g} must be <= "
                                                        f"{MAX_RINGS_PER_STEP:g} for the gridded simulator (make the step "
                                                        "smaller, or leave grid_step out to have it chosen)")
    quick_trials = sim.quick_trials if sim.quick_trials is not None else min(sim.trials, 2_000)
    quick_event = sim.quick_event_trials if sim.quick_event_trials is not None else min(sim.event_trials, 300)
    return FilterNetworkScenario(name, title, graph, system, rule, rates, (float(lo), float(hi), int(pts)), horizon,
                                 output_step, grid_step, sim.trials, sim.event_trials, quick_trials, quick_event,
                                 sim.sample_trials, grid_rule)


SCENARIO_DIR = Path(__file__).with_name("scenarios")
PAPER_SCENARIOS = ("s1a", "s1b", "s1c", "s2", "s3")


def load_scenario(name: str) -> FilterNetworkScenario:
    data = load_toml(SCENARIO_DIR / f"{name}.toml")
    data.pop("family", None)
    return scenario_from_dict(data)


def paper_scenarios() -> list[FilterNetworkScenario]:
    return [load_scenario(n) for n in PAPER_SCENARIOS]


def with_graph(sc: FilterNetworkScenario, graph: GraphSpec, name: str) -> GossipSystem:
    """The same plant and sensors on another graph (α = min(1/2, 1/d_max)), for the topology sweep."""
    edges = _edges(graph)
    dmax = int(_degrees(graph.n, edges).max())
    s = sc.system
    return GossipSystem(s.A, s.B, s.H, s.V, s.L, edges, min(0.5, 1.0 / dmax), s.mode, s.P0, s.m0, s.P_init)
