"""The hybrid-observer scenario file, declared once (docs/scenarios.md is generated from it): a
jointly observable (A, C_1..C_m), local observer gains, neighbour graphs, and runs (synchronous,
jittered, with event-time offsets, an agent leaving and re-joining). The rules that tie tables
together are the file's validator (`validation`), each error naming its key; it also fills in the
defaults that depend on other tables. The validated model is the scenario the stages read, its
matrices and designs cached properties. Agents are 1..m in files, as in the paper; 0..m-1 inside.
"""
from __future__ import annotations

from functools import cached_property
from pathlib import Path
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import Field, PrivateAttr, model_validator

import dse.estimators.hybrid_observer as ho
import dse.estimators.jointly_observable_design as jd
from dse.errors import ScenarioError
from dse.scenario.declare import (Matrix, Real, ScenarioFile, Section, computed_default, derived_default, key,
                                  matrix, name_key, parse)
from dse.scenario.fields import load_toml

TIMINGS = ("sync", "async", "offset")
SWITCHINGS = ("fixed", "alternate_interval", "alternate_iteration")
RULES = ("mean", "symmetric")
POLICIES = ("reinit", "resume", "open_loop")
#: iterations per event interval: the simulation costs q matrix-vector products per interval and trial
MAX_Q = 20_000
#: event intervals of one run (memory does not grow with them; time does)
MAX_INTERVALS = 20_000
#: agents, state dimension, and their product (the parameter estimator works on m·n numbers per trial)
MAX_AGENTS = 64
MAX_STATE = 32
MAX_AGENT_STATES = 512
MAX_TRIALS = 1_000_000
#: samples of the continuous-time errors per event interval
MAX_SAMPLES_PER_INTERVAL = 100_000
#: σ of (26) enumerates every connected graph on m vertices (26,704 for m = 6)
SIGMA_MAX_AGENTS = 6
#: an unstable plant grows like e^(αt): α·horizon is kept below this, so that states (and their
#: squares in the norms) stay inside the floating-point range (e^300 ≈ 1e130)
MAX_GROWTH_EXPONENT = 300.0


def default_poles(lam_bar: float, k: int) -> tuple[float, ...]:
    """Distinct real poles strictly beyond -λ̄: -λ̄(1.25 + 0.25 j), j = 0..k-1."""
    return tuple(-lam_bar * (1.25 + 0.25 * j) for j in range(k))


def default_central_poles(sc: "HybridFile") -> list[float]:
    """-λ̄(1.25 + 0.25 j), j = 0..n-1"""
    return list(default_poles(sc.lam_bar, sc.n))


def default_runs(sc: "HybridFile") -> list["RunSection"]:
    """sync, ideal, async (and symmetric when every graph is symmetric and m <= 6)"""
    runs = [RunSection(name="sync", monte_carlo=True), RunSection(name="ideal", ideal=True, monte_carlo=True),
            RunSection(name="async", timing="async", reference_run="sync", monte_carlo=True)]
    if all(np.array_equal(G, G.T) for G in sc.graph_masks) and sc.m <= SIGMA_MAX_AGENTS:
        runs.append(RunSection(name="symmetric", rule="symmetric", q="symmetric", monte_carlo=True))
    return runs


def default_run_name(index: int) -> str:
    """run<index>"""
    return f"run{index}"


def default_switching(sc: "HybridFile") -> str:
    """fixed with one graph, else alternate_interval"""
    return "alternate_interval" if len(sc.graph_masks) > 1 else "fixed"


def default_Delta(sc: "HybridFile", q: int) -> float:
    """T / q"""
    return sc.T / q


class SystemSection(Section):
    """The plant x' = A x and what each agent senses, y_i = C_i x."""

    A: Matrix = key(doc="system matrix (n x n)", constraint=f"square; n <= {MAX_STATE}")
    C: list[Matrix] = key(doc="one output matrix C_i (s_i x n) per agent, in agent order 1..m", min_length=1,
                          constraint=f"2 <= m <= {MAX_AGENTS}, m·n <= {MAX_AGENT_STATES}; every C_i nonzero; "
                                     "(C, A) jointly observable (16)")
    rank_tol: Real = key(1e-9, doc="relative tolerance of the rank decisions that give each agent's observable "
                         "space (and decide (16))", gt=0, le=1e-2)


class DesignSection(Section):
    """The hybrid observer's design: event spacing T, iterations q per interval, rates λ < λ̄,
    and the local observer gains (given, or placed at poles beyond -λ̄)."""

    T: Real = key(doc="spacing of the event times t_is = t_i0 + sT", unit="time", ge=1e-6)
    q: Annotated[int, Field(ge=1, le=MAX_Q)] | Literal["theory", "symmetric"] = key(
        doc="estimator iterations per event interval: an integer, 'theory' (the smallest q of (22) with the "
        "Lemma-5 α and the proven upper bound of ρ) or 'symmetric' (the smallest q of (27))",
        constraint=f"an integer 1..{MAX_Q}; 'theory' and 'symmetric' must give at most {MAX_Q:,}; "
                   f"'symmetric' needs m <= {SIGMA_MAX_AGENTS}")
    lam: Real = key(doc="the convergence rate λ the theorems are checked for", unit="1/time", gt=0,
                    alias="lambda", constraint="< lambda_bar")
    lambda_bar: Real = key(doc="λ̄ of (15): every local observer decays at least as fast as e^(-λ̄t)", unit="1/time",
                           gt=0, constraint="every Ā_i + K_i C̄_i must have spectral abscissa < -λ̄")
    gains: Literal["given", "place"] = key("place", doc="place: K_i places the poles of Ā_i + K_i C̄_i at `poles` "
                                           "(default -λ̄(1.25 + 0.25 j), j = 0..n_i-1); given: K_i from `K`")
    L: list[Matrix] | None = key(None, doc="one L_i (n_i x n) per agent: full row rank, kernel = the unobservable space "
                                 "of (C_i, A); default: orthonormal rows of the observable space",
                                 constraint="required with gains = 'given' and with initial.w0")
    K: list[Matrix] | None = key(None, doc="one local observer gain K_i (n_i x s_i) per agent, in the basis L_i "
                                 "(gains = 'given'); the local observer is w_i' = (Ā_i + K_i C̄_i) w_i - K_i y_i (3)",
                                 constraint="required with gains = 'given', only then")
    poles: list[list[Real]] | None = key(None, doc="the poles of Ā_i + K_i C̄_i, n_i per agent (gains = 'place')",
                                         unit="1/time", constraint="only with gains = 'place'")
    central_poles: list[Real] | None = key(derived_default(default_central_poles),
                                           doc="poles of the centralized reference observer on the stacked outputs",
                                           unit="1/time", constraint="n negative real poles")


class GraphsSection(Section):
    """The neighbour graphs N(t) the runs switch between. Directed: j ∈ N_i means that agent i
    receives from agent j (an arc j -> i); every agent is its own neighbour (not listed). The
    theorems need N(t) strongly connected at every t: a graph that is not is accepted and
    reported as the hypothesis `strong_connectivity` that does not hold (its theorem claims are
    then not checkable); this family does not use the shared undirected [graph] table."""

    neighbors: list[list[list[int]]] = key(doc="per graph, per agent i = 1..m, the labels j of its neighbours "
                                           "(1..m, without i itself, each at most once)", min_length=1,
                                           constraint="m rows per graph")

    @computed_default
    def _graph_names(data):
        """G1, G2, ..."""
        return [f"G{k + 1}" for k in range(len(data["neighbors"]))]

    names: list[str] = key(_graph_names, doc="a name per graph (figures, tables)",
                           constraint="1 to 64 characters, no control or format characters")


class InitialSection(Section):
    """Initial conditions of trial 0 (the other Monte Carlo trials draw theirs, see [monte_carlo])."""

    x0: list[Real] = key(doc="plant state x(0) (n entries)", unit="state")
    xhat0: Matrix = key(doc="each agent's initial estimate x_i(0) (m rows of n entries)", unit="state")
    w0: list[list[Real]] | None = key(None, doc="each agent's local observer state w_i(0) (n_i entries, in the "
                                      "coordinates of design.L); default 0", unit="state",
                                      constraint="needs design.L")


class MonteCarloSection(Section):
    """Monte Carlo over initial conditions: trial 0 uses [initial]; trials 1.. draw x(0), w_i(0)
    and x_i(0) with independent N(0, scale²) entries (runs with monte_carlo = true)."""

    trials: int = key(64, doc="trials of the runs with monte_carlo = true", ge=1, le=MAX_TRIALS)

    @computed_default
    def _quick_trials(data):
        """min(trials, 16)"""
        return min(data["trials"], 16)

    quick_trials: int = key(_quick_trials, doc="trials in quick runs", ge=1, le=MAX_TRIALS, constraint="<= trials")
    scale: Real = key(5.0, doc="standard deviation of the random initial conditions", unit="state", gt=0)


class NoiseSection(Section):
    """The 'system noise' of the paper's first simulation: x' = A x + b cos(ω t), unknown to the
    observers (runs with noise = true)."""

    b: list[Real] | None = key(None, doc="input direction b (n entries)", unit="state/time")
    omega: Real = key(10.0, doc="angular frequency ω of the input", unit="rad/time", ge=0)


class SamplingSection(Section):
    """Where the continuous-time errors are evaluated: the continuous bound of Theorem 1, the
    series tables, figures and recordings (the simulation itself is exact between any instants)."""

    step: Real = key(0.01, doc="time between samples of the continuous-time errors", unit="time", ge=1e-6,
                     constraint=f"T / step <= {MAX_SAMPLES_PER_INTERVAL:,}")
    stored: int = key(20_001, doc="at most this many samples per run are stored (tables, recordings, figures; "
                      "every k-th sample when there are more); every sample is still checked", ge=101,
                      le=1_000_001)


class LeaveSection(Section):
    """One agent leaves the network and re-joins."""

    agent: int = key(doc="the agent that leaves (1..m)", ge=1)
    at: Real = key(doc="when it leaves: one of its event times t_i0 + sT", unit="time", gt=0)
    rejoin: Real = key(doc="when it re-joins: a later event time of its own, inside the horizon", unit="time", ge=0)
    policy: Literal[POLICIES] = key("reinit", doc="at re-joining: reinit (back to its initial x_i, w_i), resume "  # type: ignore[valid-type]
                                    "(its state frozen while away), open_loop (its local observer and "
                                    "propagation kept running, no communication)")

    @property
    def index(self) -> int:
        """The agent, 0-based."""
        return self.agent - 1


class RunSection(Section):
    """One simulated run (the claims check every run of the kind they are about)."""

    name: str = key(derived_default(default_run_name), doc="run name (unique)", pattern=r"^[A-Za-z0-9_-]{1,64}$",
                    constraint="1 to 64 letters, digits, '-' or '_'; unique among the runs")
    timing: Literal[TIMINGS] = key("sync", doc="sync: iterations at t_i(s-1) + kΔ; async: jittered by δ_is(k) "  # type: ignore[valid-type]
                                   "∈ [-ε_i, ε_i] (Theorem 2); offset: event times t_is = t_i0 + sT (Section 4)")
    switching: Literal[SWITCHINGS] | None = key(
        derived_default(default_switching),
        doc="fixed: graph `graph` throughout; alternate_interval: the graphs in turn, one per period T; "
        "alternate_iteration: one per iteration, switching at (s-1)T + (k-1)Δ + β + Δ/2")
    graph: int = key(1, doc="the graph of switching = fixed (1-based)", ge=1)
    intervals: int = key(15, doc="event intervals simulated (the horizon is intervals·T)", ge=1, le=MAX_INTERVALS)
    noise: bool = key(False, doc="add the input b cos(ω t) of [noise] (the theorems do not cover it)")
    rule: Literal[RULES] = key("mean", doc="mean: averaging (13) over the sources; symmetric: the convex rule (25) "  # type: ignore[valid-type]
                               "for symmetric graphs")
    q: Annotated[int, Field(ge=1, le=MAX_Q)] | Literal["design", "symmetric"] = key(
        "design", doc="iterations per interval: design (design.q), symmetric (q of (27)) or an integer",
        constraint=f"an integer 1..{MAX_Q}")
    monte_carlo: bool = key(False, doc="simulate [monte_carlo] trials (else trial 0 only)")
    ideal: bool = key(False, doc="start the local observers exact, w_i(0) = L_i x(0) (ē ≡ 0; synchronous runs)")
    epsilon: list[Real] | None = key(None, doc="jitter bounds ε_i of the iteration times, one per agent (timing = "
                                     "async)", unit="time", constraint=">= 0")
    beta: Real = key(0.0, doc="broadcast delay β: agent j sends z_j(k-1) at τ_j(k-1) + β", unit="time", ge=0,
                     constraint="< Delta")
    Delta: Real | None = key(derived_default(default_Delta), doc="nominal spacing Δ of the iterations", unit="time",
                             gt=0, constraint="q·Δ + max ε <= T")
    offsets: list[Real] | None = key(None, doc="event-time offsets t_i0, one per agent (timing = offset)",
                                     unit="time", constraint="spread < T")
    leave: LeaveSection | None = key(None, doc="an agent that leaves and re-joins")
    reference_run: str = key("", doc="an earlier run of the same observer with synchronous timing: an asynchronous "
                             "run must reproduce it exactly (Theorem 2)")
    #: where the validated q comes from: given, theory (22) or symmetric (27)
    _q_label: str = PrivateAttr("given")

    @property
    def q_label(self) -> str:
        return self._q_label

    @property
    def graph_index(self) -> int:
        """The graph of switching = fixed, 0-based."""
        return self.graph - 1


class PaperValuesSection(Section):
    """Printed values of the paper's own example that claims compare with (paper reproduction)."""

    lam: Real | None = key(None, doc="the printed convergence rate λ", unit="1/time", alias="lambda", gt=0)
    lambda_bar: Real | None = key(None, doc="the printed λ̄", unit="1/time", gt=0)


class HybridFile(ScenarioFile):
    """A hybrid-observer scenario file."""

    unkeyed = {"name": True, "monte_carlo": {"trials": True, "quick_trials": True}, "graphs": {"names": True}}

    name: str = name_key()
    system: SystemSection = key(doc="the plant and the agents' outputs")
    design: DesignSection = key(doc="the observer design")
    graphs: GraphsSection = key(doc="the neighbour graphs")
    initial: InitialSection = key(doc="initial conditions")
    monte_carlo: MonteCarloSection = key(MonteCarloSection, doc="random initial conditions")
    noise: NoiseSection = key(NoiseSection, doc="the input of runs with noise = true")
    sampling: SamplingSection = key(SamplingSection, doc="sampling of the continuous-time errors")
    runs: list[RunSection] | None = key(derived_default(default_runs), doc="the simulated runs", min_length=1,
                                        max_length=64)
    paper_values: PaperValuesSection = key(PaperValuesSection, doc="printed values (paper reproduction only)")

    @model_validator(mode="after")
    def _tie_tables(self) -> "HybridFile":
        """The rules across tables, in the order their errors are reported, then the derived defaults."""
        from . import validation as v

        self.C                                                     # sizes, m, n, (16)
        if self.lam >= self.lam_bar:
            raise ScenarioError("design.lambda", f"must be < lambda_bar = {self.lam_bar:g} (the constant d of Theorem 1 "
                                                 f"divides by 1 - e^(-(λ̄-λ)T)), got {self.lam:g}")
        self.local_gains                                           # L_i, K_i or poles, (15)
        _set(self.design, central_poles=v.central_poles(self))
        self.graph_masks, self.q_design, self.x0, self.xhat0, self.w0
        mc = self.monte_carlo
        if mc.quick_trials > mc.trials:
            raise ScenarioError("monte_carlo.quick_trials", f"must be <= trials = {mc.trials}, got {mc.quick_trials}")
        self.noise_b
        if self.T / self.sampling.step > MAX_SAMPLES_PER_INTERVAL:
            raise ScenarioError("sampling.step", f"T / step = {self.T / self.sampling.step:,.0f} samples per interval, "
                                                 f"more than the supported {MAX_SAMPLES_PER_INTERVAL:,}")
        _set(self, runs=v.settled_runs(self, self.runs if self.runs is not None else default_runs(self)))
        return self

    @cached_property
    def A(self) -> np.ndarray:
        A = matrix(self.system.A, "system.A")
        if A.shape[0] != A.shape[1]:
            raise ScenarioError("system.A", f"must be square, got {A.shape[0]}x{A.shape[1]}")
        if A.shape[0] > MAX_STATE:
            raise ScenarioError("system.A", f"state dimension n = {A.shape[0]}; this family handles at most {MAX_STATE}")
        return A

    @cached_property
    def C(self) -> tuple[np.ndarray, ...]:
        """The output matrices; (C, A) jointly observable (16) at the rank tolerance."""
        from .validation import output_matrices

        return output_matrices(self)

    @property
    def n(self) -> int:
        return self.A.shape[0]

    @property
    def m(self) -> int:
        return len(self.C)

    @property
    def rank_tol(self) -> float:
        return self.system.rank_tol

    @property
    def T(self) -> float:
        return self.design.T

    @property
    def lam(self) -> float:
        return self.design.lam

    @property
    def lam_bar(self) -> float:
        return self.design.lambda_bar

    @property
    def printed_lam(self) -> float:
        """The printed λ when the file gives one, else the design's."""
        return self.paper_values.lam if self.paper_values.lam is not None else self.lam

    @cached_property
    def norm_A(self) -> float:
        return float(np.linalg.norm(self.A, 2))

    @cached_property
    def L_given(self) -> tuple[np.ndarray, ...] | None:
        from .validation import given_bases

        return given_bases(self)

    @cached_property
    def locs(self) -> list:
        """Each agent's L_i, Ā_i, C̄_i, Q_i, P_i (`jd.local_design`)."""
        L = self.L_given
        return [jd.local_design(self.A, C, rank_tol=self.rank_tol, L=None if L is None else L[i])
                for i, C in enumerate(self.C)]

    @cached_property
    def local_gains(self) -> tuple[tuple | None, tuple | None]:
        """(the given K_i, None) or (None, the poles to place), (15) reachable (`validation.gains_choice`)."""
        from .validation import gains_choice

        return gains_choice(self)

    @cached_property
    def observer(self) -> ho.ObserverDesign:
        """The hybrid observer's design: L_i, Ā_i, C̄_i, K_i (given, or placed now), Q_i, P_i."""
        K, poles = self.local_gains
        if K is None:
            K = tuple(_placed(f"design.poles[{i}]", jd.place_gain, loc.Abar, loc.Cbar, p)
                      for i, (loc, p) in enumerate(zip(self.locs, poles)))
        locs = self.locs
        return ho.ObserverDesign(self.A, self.C, tuple(loc.L for loc in locs), tuple(loc.Abar for loc in locs),
                                 tuple(loc.Cbar for loc in locs), tuple(K), tuple(loc.Q for loc in locs),
                                 np.array([loc.P for loc in locs]))

    @cached_property
    def central_gain(self) -> np.ndarray:
        """Centralized observer on the stacked outputs: x_c' = (A + K_c C) x_c - K_c y (`jd.stacked_gain`)."""
        return _placed("design.central_poles", jd.stacked_gain, self.A, np.vstack(self.C), self.design.central_poles,
                       self.rank_tol)

    @cached_property
    def graph_masks(self) -> np.ndarray:
        """The neighbour graphs as masks N[i, j] (i receives from j; self-arcs set), (graphs, m, m)."""
        from .validation import graph_masks

        return graph_masks(self.graphs, self.m)

    @cached_property
    def all_strongly_connected(self) -> bool:
        return all(jd.is_strongly_connected(g) for g in self.graph_masks)

    @cached_property
    def q_design(self) -> int:
        """The design q: given, or the smallest q of (22) ('theory') or of (27) ('symmetric')."""
        from .validation import design_q

        return design_q(self)

    @property
    def q_label(self) -> str:
        return self.design.q if isinstance(self.design.q, str) else "given"

    @cached_property
    def x0(self) -> np.ndarray:
        x0 = np.array(self.initial.x0, float)
        if x0.shape != (self.n,):
            raise ScenarioError("initial.x0", f"must have n = {self.n} entries, got {x0.size}")
        return x0

    @cached_property
    def xhat0(self) -> np.ndarray:
        return matrix(self.initial.xhat0, "initial.xhat0", shape=(self.m, self.n))

    @cached_property
    def w0(self) -> np.ndarray | None:
        """The stacked w_i(0) of trial 0 (None: 0)."""
        from .validation import initial_w

        return initial_w(self)

    @cached_property
    def noise_b(self) -> np.ndarray | None:
        if self.noise.b is None:
            return None
        b = np.array(self.noise.b, float)
        if b.shape != (self.n,):
            raise ScenarioError("noise.b", f"must have n = {self.n} entries, got {b.size}")
        return b

    def trials_for(self, opts) -> int:
        """Monte Carlo trials of the runs with monte_carlo = true under these options (`--trials` wins)."""
        mc = self.monte_carlo
        return opts.trials if opts.trials is not None else (mc.quick_trials if opts.quick else mc.trials)

    def spec(self, name: str) -> RunSection:
        """The run of this name."""
        return next(r for r in self.runs if r.name == name)


def _set(section: Section, **values: Any) -> None:
    """Fill in derived defaults on a validated (frozen) section, once, from its file's validator."""
    for name, value in values.items():
        object.__setattr__(section, name, value)


def _placed(field: str, place, *args) -> np.ndarray:
    """A gain placed with the design (the file's validation checked that the poles can be placed,
    without placing them); a numerical failure of the placement names the field."""
    try:
        return place(*args)
    except ValueError as exc:
        raise ScenarioError(field, f"pole placement failed: {exc}") from None


def paper_scenarios() -> tuple[HybridFile, HybridFile]:
    """The paper's Section 6 example and the generic system on which Theorem 1's hypotheses hold."""
    def load(name: str) -> HybridFile:
        data = load_toml(Path(__file__).with_name(name))
        data.pop("family", None)
        return parse(HybridFile, data)

    return load("paper.toml"), load("generic.toml")
