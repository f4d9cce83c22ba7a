"""The hybrid-observer scenario family: a jointly observable (A, C_1..C_m), local observer
gains, a set of neighbour graphs, and a list of runs (synchronous, asynchronous with jittered
iteration times, event-time offsets, agents leaving and joining).

Every key is declared once below (type, default, bounds, unit, meaning); docs/scenarios.md
is generated from these declarations. Rules that tie keys of different tables together
(matrix sizes against n and m, q against the design, timing against T) are checked when the
file is read, each naming its key. Agents are labelled 1..m in scenario files, as in the
paper; internally 0..m-1.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import Field

import dse.estimators.jointly_observable_design as jd
from dse.scenario.declare import Matrix, Real, Section, computed, key, matrix, parse
from dse.errors import ScenarioError, printable
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


Positive = Annotated[int, Field(ge=1)]


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
    central_poles: list[Real] | None = key(computed("-λ̄(1.25 + 0.25 j), j = 0..n-1"),
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
    names: list[str] | None = key(computed("G1, G2, ..."), doc="a name per graph (figures, tables)",
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
    quick_trials: int | None = key(computed("min(trials, 16)"), doc="trials in quick runs", ge=1, le=MAX_TRIALS,
                                   constraint="<= trials")
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


class RunSection(Section):
    """One simulated run (the claims check every run of the kind they are about)."""

    name: str = key(computed("run<index>"), doc="run name (unique)", pattern=r"^[A-Za-z0-9_-]{1,64}$")
    timing: Literal[TIMINGS] = key("sync", doc="sync: iterations at t_i(s-1) + kΔ; async: jittered by δ_is(k) "  # type: ignore[valid-type]
                                   "∈ [-ε_i, ε_i] (Theorem 2); offset: event times t_is = t_i0 + sT (Section 4)")
    switching: Literal[SWITCHINGS] | None = key(
        computed("fixed with one graph, else alternate_interval"),
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
    Delta: Real | None = key(computed("T / q"), doc="nominal spacing Δ of the iterations", unit="time", gt=0,
                             constraint="q·Δ + max ε <= T")
    offsets: list[Real] | None = key(None, doc="event-time offsets t_i0, one per agent (timing = offset)",
                                     unit="time", constraint="spread < T")
    leave: LeaveSection | None = key(None, doc="an agent that leaves and re-joins")
    reference_run: str = key("", doc="an earlier run of the same observer with synchronous timing: an asynchronous "
                             "run must reproduce it exactly (Theorem 2)")


class PaperValuesSection(Section):
    """Printed values of the paper's own example that claims compare with (paper reproduction)."""

    lam: Real | None = key(None, doc="the printed convergence rate λ", unit="1/time", alias="lambda", gt=0)
    lambda_bar: Real | None = key(None, doc="the printed λ̄", unit="1/time", gt=0)


class HybridFile(Section):
    """A hybrid-observer scenario file."""

    name: str = key("scenario", doc="scenario name: the output directory OUT/run/<name>/",
                    pattern=r"^[A-Za-z0-9_-]{1,64}$")
    system: SystemSection = key(doc="the plant and the agents' outputs")
    design: DesignSection = key(doc="the observer design")
    graphs: GraphsSection = key(doc="the neighbour graphs")
    initial: InitialSection = key(doc="initial conditions")
    monte_carlo: MonteCarloSection = key(MonteCarloSection, doc="random initial conditions")
    noise: NoiseSection = key(NoiseSection, doc="the input of runs with noise = true")
    sampling: SamplingSection = key(SamplingSection, doc="sampling of the continuous-time errors")
    runs: list[RunSection] | None = key(
        computed("sync, ideal, async (and symmetric when every graph is symmetric and m <= 6)"),
        doc="the simulated runs", min_length=1, max_length=64)
    paper_values: PaperValuesSection = key(PaperValuesSection, doc="printed values (paper reproduction only)")


# -- the scenario as compute uses it ------------------------------------------------------------------

@dataclass(frozen=True)
class Leave:
    agent: int          # 0-based
    at: float
    rejoin: float
    policy: str


@dataclass(frozen=True)
class RunSpec:
    name: str
    timing: str
    switching: str
    graph: int
    intervals: int
    noise: bool
    rule: str
    q: int
    q_label: str
    mc: bool
    ideal: bool
    epsilon: tuple[float, ...]
    beta: float
    Delta: float
    offsets: tuple[float, ...]
    leave: Leave | None
    reference_run: str
    jitter_seed_label: str = ""

    def key(self) -> dict[str, Any]:
        return {k: (v.__dict__ if isinstance(v, Leave) else v) for k, v in self.__dict__.items()}


@dataclass(frozen=True)
class HybridScenario:
    name: str
    A: np.ndarray
    C: tuple
    rank_tol: float
    T: float
    q_design: int
    q_label: str
    lam: float
    lam_bar: float
    gains: str
    L_given: tuple | None
    K_given: tuple | None
    poles: tuple | None
    central_poles: tuple
    graph_names: tuple[str, ...]
    graphs: np.ndarray
    x0: np.ndarray
    w0: np.ndarray | None
    xhat0: np.ndarray
    trials: int
    quick_trials: int
    ic_scale: float
    noise_b: np.ndarray | None
    noise_omega: float
    runs: tuple[RunSpec, ...]
    paper_values: dict = field(default_factory=dict)
    sample_step: float = 0.01
    stored_samples: int = 20_001

    @property
    def m(self) -> int:
        return len(self.C)

    @property
    def n(self) -> int:
        return self.A.shape[0]

    def key(self) -> dict[str, Any]:
        d = {}
        for k, v in self.__dict__.items():
            if k in ("name", "quick_trials", "trials", "graph_names"):
                continue
            if k == "runs":
                d[k] = [r.key() for r in v]
            elif isinstance(v, np.ndarray):
                d[k] = v.tolist()
            elif isinstance(v, tuple) and v and isinstance(v[0], np.ndarray):
                d[k] = [x.tolist() for x in v]
            else:
                d[k] = v
        return d

    @classmethod
    def from_dict(cls, data: Any) -> "HybridScenario":
        f = parse(HybridFile, data)
        A, C, rank_tol = _system(f.system)
        n, m = A.shape[0], len(C)
        nA = float(np.linalg.norm(A, 2))
        des = f.design
        T, lam, lam_bar = float(des.T), float(des.lam), float(des.lambda_bar)
        if lam >= lam_bar:
            raise ScenarioError("design.lambda", f"must be < lambda_bar = {lam_bar:g} (the constant d of Theorem 1 "
                                                 f"divides by 1 - e^(-(λ̄-λ)T)), got {lam:g}")
        L_given, K_given, poles, locs = _local_design(des, A, C, rank_tol, lam_bar)
        central_poles = tuple(float(p) for p in des.central_poles) if des.central_poles is not None \
            else default_poles(lam_bar, n)
        if len(central_poles) != n or max(central_poles) >= 0:
            raise ScenarioError("design.central_poles", f"must be {n} negative real poles")
        why = jd.unplaceable(central_poles, jd.stacked_rank(np.vstack(C), rank_tol)[0])
        if why:
            raise ScenarioError("design.central_poles", f"pole placement for the centralized reference fails: {why}")
        graphs, names = _graphs(f.graphs, m)
        q_design, q_label = _design_q(des.q, m, nA, lam, T, locs)
        x0, w0, xh = _initial(f.initial, n, m, locs, L_given)
        mc = f.monte_carlo
        quick = mc.quick_trials if mc.quick_trials is not None else min(mc.trials, 16)
        if quick > mc.trials:
            raise ScenarioError("monte_carlo.quick_trials", f"must be <= trials = {mc.trials}, got {quick}")
        noise_b = None
        if f.noise.b is not None:
            noise_b = np.array(f.noise.b, float)
            if noise_b.shape != (n,):
                raise ScenarioError("noise.b", f"must have n = {n} entries, got {noise_b.size}")
        step = float(f.sampling.step)
        if T / step > MAX_SAMPLES_PER_INTERVAL:
            raise ScenarioError("sampling.step", f"T / step = {T / step:,.0f} samples per interval, more than the "
                                                 f"supported {MAX_SAMPLES_PER_INTERVAL:,}")
        runs = parse_runs(f.runs, m=m, T=T, q_design=q_design, q_label=q_label, graphs=graphs, noise_b=noise_b,
                          nA=nA, lam=lam, locs=locs, growth=float(np.max(np.linalg.eigvals(A).real)))
        pv = {k: v for k, v in (("lambda", f.paper_values.lam), ("lambda_bar", f.paper_values.lambda_bar))
              if v is not None}
        return cls(f.name, A, C, rank_tol, T, q_design, q_label, lam, lam_bar, des.gains, L_given, K_given, poles,
                   central_poles, names, graphs, x0, w0, xh, mc.trials, quick, float(mc.scale), noise_b,
                   float(f.noise.omega), runs, pv, step, f.sampling.stored)


def _system(s: SystemSection) -> tuple[np.ndarray, tuple, float]:
    A = matrix(s.A, "system.A")
    n = A.shape[0]
    if A.shape != (n, n):
        raise ScenarioError("system.A", f"must be square, got {A.shape[0]}x{A.shape[1]}")
    if n > MAX_STATE:
        raise ScenarioError("system.A", f"state dimension n = {n}; this family handles at most {MAX_STATE}")
    C = tuple(matrix(c, f"system.C[{i}]") for i, c in enumerate(s.C))
    for i, Ci in enumerate(C):
        if Ci.shape[1] != n:
            raise ScenarioError(f"system.C[{i}]", f"must have n = {n} columns, got {Ci.shape[1]}")
        if not np.any(Ci):
            raise ScenarioError(f"system.C[{i}]", "is zero (every agent must sense something: C_i != 0)")
    m = len(C)
    if m < 2:
        raise ScenarioError("system.C", "needs at least 2 agents (with one agent there is nothing to distribute)")
    if m > MAX_AGENTS:
        raise ScenarioError("system.C", f"{m} agents; this family handles at most {MAX_AGENTS}")
    if m * n > MAX_AGENT_STATES:
        raise ScenarioError("system.C", f"m·n = {m * n} estimator states per trial; this family handles at most "
                                        f"{MAX_AGENT_STATES}")
    rank_tol = float(s.rank_tol)
    rank = jd.observable_basis(A, np.vstack(C), rank_tol).rows.shape[0]
    if rank < n:
        raise ScenarioError("system.C", f"(C, A) is not jointly observable: the observable space of the stacked "
                                        f"outputs has dimension {rank} < n = {n} (relative rank tolerance "
                                        f"{rank_tol:g}); condition (16) fails")
    return A, C, rank_tol


def _local_design(des: DesignSection, A: np.ndarray, C: tuple, rank_tol: float, lam_bar: float):
    n, m = A.shape[0], len(C)
    L_given = None
    if des.L is not None:
        L_given = tuple(matrix(Li, f"design.L[{i}]") for i, Li in enumerate(des.L))
        if len(L_given) != m:
            raise ScenarioError("design.L", f"must list one matrix per agent ({m}), got {len(L_given)}")
        for i, Li in enumerate(L_given):
            if Li.shape[1] != n or not jd.same_kernel(Li, A, C[i], rank_tol):
                raise ScenarioError(f"design.L[{i}]", "must have full row rank and kernel equal to the unobservable "
                                                      f"space of (C_{i + 1}, A)")
    locs = [jd.local_design(A, C[i], rank_tol=rank_tol, L=None if L_given is None else L_given[i]) for i in range(m)]
    K_given = poles = None
    if des.gains == "given":
        if des.K is None:
            raise ScenarioError("design.K", "missing (needed for gains = 'given')")
        if L_given is None:
            raise ScenarioError("design.L", "missing (a given K is expressed in a given basis L)")
        if des.poles is not None:
            raise ScenarioError("design.poles", "only with gains = 'place'")
        K_given = tuple(matrix(Ki, f"design.K[{i}]") for i, Ki in enumerate(des.K))
        if len(K_given) != m:
            raise ScenarioError("design.K", f"must list one matrix per agent ({m}), got {len(K_given)}")
        for i, Ki in enumerate(K_given):
            if Ki.shape != (locs[i].n_i, C[i].shape[0]):
                raise ScenarioError(f"design.K[{i}]", f"must have shape {locs[i].n_i}x{C[i].shape[0]}, got "
                                                      f"{Ki.shape[0]}x{Ki.shape[1]}")
    else:
        if des.K is not None:
            raise ScenarioError("design.K", "only allowed with gains = 'given'")
        if des.poles is not None:
            if len(des.poles) != m:
                raise ScenarioError("design.poles", f"must list one pole set per agent ({m})")
            poles = tuple(tuple(float(x) for x in p) for p in des.poles)
            for i, p in enumerate(poles):
                if len(p) != locs[i].n_i:
                    raise ScenarioError(f"design.poles[{i}]", f"must have n_i = {locs[i].n_i} poles")
        else:
            poles = tuple(default_poles(lam_bar, loc.n_i) for loc in locs)
        for i in range(m):
            why = jd.unplaceable(poles[i], np.linalg.matrix_rank(locs[i].Cbar))
            if why:
                raise ScenarioError(f"design.poles[{i}]", f"pole placement fails: {why}")
    # placed gains are computed with the design (scipy.signal is slow to import): their observers' spectral
    # abscissa is the largest requested pole here, and the achieved one is the hypothesis local_observers
    abscissas = [jd.spectral_abscissa(locs[i].Abar + K_given[i] @ locs[i].Cbar) for i in range(m)] \
        if K_given is not None else [max(p) for p in poles]
    for i, sa in enumerate(abscissas):
        if sa > -lam_bar + 1e-9:
            raise ScenarioError("design.lambda_bar", f"agent {i + 1}'s local observer has spectral abscissa "
                                                     f"{sa:.6g} > -λ̄ = {-lam_bar:g}: (15) cannot hold")
    return L_given, K_given, poles, locs


def _graphs(g: GraphsSection, m: int) -> tuple[np.ndarray, tuple[str, ...]]:
    graphs = []
    for k, rows in enumerate(g.neighbors):
        f = f"graphs.neighbors[{k}]"
        if len(rows) != m:
            raise ScenarioError(f, f"must list the neighbours of each of the {m} agents, got {len(rows)}")
        for i, labels in enumerate(rows):
            for j in labels:
                if not 1 <= j <= m:
                    raise ScenarioError(f"{f}[{i}]", f"agent labels are 1..{m}, got {j}")
                if j == i + 1:
                    raise ScenarioError(f"{f}[{i}]", f"lists agent {j} as its own neighbour (every agent is; do not "
                                                     "list it)")
            if len(set(labels)) != len(labels):
                raise ScenarioError(f"{f}[{i}]", f"repeats a neighbour: {labels}")
        graphs.append(jd.neighbour_mask([[j - 1 for j in labels] for labels in rows], m))
    names = tuple(g.names) if g.names is not None else tuple(f"G{k + 1}" for k in range(len(graphs)))
    if len(names) != len(graphs):
        raise ScenarioError("graphs.names", f"must name each of the {len(graphs)} graphs, got {len(names)}")
    for k, label in enumerate(names):
        if not label.strip() or len(label) > 64 or printable(label) != label:
            raise ScenarioError(f"graphs.names[{k}]", "must be 1 to 64 characters without control or format "
                                                      f"(bidirectional, zero-width) characters, got '{label[:64]}'")
    return np.array(graphs), names


def _design_q(q_raw: int | str, m: int, nA: float, lam: float, T: float, locs) -> tuple[int, str]:
    if not isinstance(q_raw, str):
        return int(q_raw), "given"
    if q_raw == "theory":
        # (22) grows with ρ: its value at ρ = 0 is a lower bound, enough to refuse without computing ρ
        q = jd.sufficient_q(0.0, m, nA, lam, T).q_thm22
        if q > MAX_Q:
            raise ScenarioError("design.q", f"the theory q is {jd.readable_int(q)} or more (> {MAX_Q:,}): too many iterations to "
                                            "simulate; give an integer q (the hypotheses report the required q)")
        rho = jd.rho_exact(np.array([loc.P for loc in locs]))
        if rho.upper >= 1:
            raise ScenarioError("design.q", f"ρ of (17) is only bracketed in [{rho.rho:.6g}, {rho.upper:.6g}]: no "
                                            "sufficient q is known; give an integer q")
        q = jd.sufficient_q(rho.upper, m, nA, lam, T).q_thm22
    else:
        if m > SIGMA_MAX_AGENTS:
            raise ScenarioError("design.q", f"'symmetric' needs m <= {SIGMA_MAX_AGENTS} (σ of (26) by enumeration)")
        q = symmetric_q(jd.sigma_symmetric(np.array([loc.P for loc in locs]))[0], nA, lam, T, "design.q")
    if q > MAX_Q:
        raise ScenarioError("design.q", f"the {q_raw} q is {jd.readable_int(q)} (> {MAX_Q:,}): too many iterations to simulate; "
                                        "give an integer q (the hypotheses report the required q)")
    return q, q_raw


def _initial(ini: InitialSection, n: int, m: int, locs, L_given) -> tuple[np.ndarray, np.ndarray | None, np.ndarray]:
    x0 = np.array(ini.x0, float)
    if x0.shape != (n,):
        raise ScenarioError("initial.x0", f"must have n = {n} entries, got {x0.size}")
    xh = matrix(ini.xhat0, "initial.xhat0", shape=(m, n))
    w0 = None
    if ini.w0 is not None:
        if len(ini.w0) != m:
            raise ScenarioError("initial.w0", f"must list one vector per agent ({m}), got {len(ini.w0)}")
        for i, w in enumerate(ini.w0):
            if len(w) != locs[i].n_i:
                raise ScenarioError(f"initial.w0[{i}]", f"must have n_i = {locs[i].n_i} entries (rank of agent "
                                                        f"{i + 1}'s observability matrix), got {len(w)}")
        if L_given is None:
            raise ScenarioError("initial.w0", "needs design.L (w_i lives in the coordinates of L_i); omit w0 to start "
                                              "every local observer at w_i = 0")
        w0 = np.concatenate([np.array(w, float) for w in ini.w0])
    return x0, w0, xh


def symmetric_q(sigma: float, norm_A: float, lam: float, T: float, field: str) -> int:
    """q of (27), or a ScenarioError naming `field` when σ is not below 1."""
    try:
        return jd.q_symmetric(sigma, norm_A, lam, T)
    except ValueError as exc:
        raise ScenarioError(field, f"(27) gives no q: {exc}") from None


def default_poles(lam_bar: float, k: int) -> tuple[float, ...]:
    """Distinct real poles strictly beyond -λ̄: -λ̄(1.25 + 0.25 j), j = 0..k-1."""
    return tuple(-lam_bar * (1.25 + 0.25 * j) for j in range(k))


def default_runs(graphs: np.ndarray) -> list[RunSection]:
    runs = [RunSection(name="sync", monte_carlo=True), RunSection(name="ideal", ideal=True, monte_carlo=True),
            RunSection(name="async", timing="async", reference_run="sync", monte_carlo=True)]
    if all(np.array_equal(G, G.T) for G in graphs) and graphs.shape[1] <= SIGMA_MAX_AGENTS:
        runs.append(RunSection(name="symmetric", rule="symmetric", q="symmetric", monte_carlo=True))
    return runs


def parse_runs(value: list[RunSection] | None, *, m: int, T: float, q_design: int, q_label: str, graphs: np.ndarray,
               noise_b, nA: float, lam: float, locs, growth: float = 0.0) -> tuple[RunSpec, ...]:
    runs: list[RunSpec] = []
    names: set[str] = set()
    sigma = None
    for r_i, raw in enumerate(value if value is not None else default_runs(graphs)):
        f = f"runs[{r_i}]"
        name = raw.name if raw.name is not None else f"run{r_i}"
        if name in names:
            raise ScenarioError(f"{f}.name", f"must be unique, got '{name}' twice")
        names.add(name)
        switching = raw.switching or ("alternate_interval" if len(graphs) > 1 else "fixed")
        if raw.graph > len(graphs):
            raise ScenarioError(f"{f}.graph", f"must be <= the number of graphs ({len(graphs)}), got {raw.graph}")
        graph = raw.graph - 1
        if raw.noise and noise_b is None:
            raise ScenarioError(f"{f}.noise", "needs a [noise] table with b")
        used = [graphs[graph]] if switching == "fixed" else list(graphs)
        if raw.rule == "symmetric" and not all(np.array_equal(G, G.T) for G in used):
            raise ScenarioError(f"{f}.rule", "the convex rule (25) is for symmetric graphs; a graph this run uses is "
                                             "directed (use switching = 'fixed' with a symmetric graph)")
        if raw.q == "design":
            q, q_lab = q_design, q_label
        elif raw.q == "symmetric":
            if m > SIGMA_MAX_AGENTS:
                raise ScenarioError(f"{f}.q", f"'symmetric' needs m <= {SIGMA_MAX_AGENTS} (σ of (26) by enumeration)")
            if sigma is None:
                sigma = jd.sigma_symmetric(np.array([loc.P for loc in locs]))[0]
            q, q_lab = symmetric_q(sigma, nA, lam, T, f"{f}.q"), "symmetric"
            if q > MAX_Q:
                raise ScenarioError(f"{f}.q", f"q of (27) is {jd.readable_int(q)} (> {MAX_Q:,}); give an integer")
        else:
            q, q_lab = int(raw.q), "given"
        eps = tuple(float(x) for x in raw.epsilon) if raw.epsilon is not None else (0.0,) * m
        if len(eps) != m:
            raise ScenarioError(f"{f}.epsilon", f"must have one bound per agent ({m}), got {len(eps)}")
        if any(x < 0 for x in eps):
            raise ScenarioError(f"{f}.epsilon", "bounds must be >= 0")
        offsets = tuple(float(x) for x in raw.offsets) if raw.offsets is not None else (0.0,) * m
        if len(offsets) != m:
            raise ScenarioError(f"{f}.offsets", f"must have one offset per agent ({m}), got {len(offsets)}")
        if raw.timing != "async" and any(eps):
            raise ScenarioError(f"{f}.epsilon", "jitter bounds only apply to timing = 'async'")
        if raw.timing != "offset" and any(offsets):
            raise ScenarioError(f"{f}.offsets", "offsets only apply to timing = 'offset'")
        if raw.timing == "offset":
            eps = tuple(abs(o) for o in offsets)
            if max(offsets) - min(offsets) >= T:
                raise ScenarioError(f"{f}.offsets", f"the spread of the offsets must be < T = {T:g} (the index-aligned "
                                                    "exchange needs every agent's interval data before any reset)")
        beta = float(raw.beta)
        Delta = float(raw.Delta) if raw.Delta is not None else T / q
        if beta >= Delta:
            raise ScenarioError(f"{f}.beta", f"must be < Delta = {Delta:g}, got {beta:g}")
        jit = max(eps) if raw.timing == "async" else 0.0
        if Delta * q + jit > T * (1 + 1e-12):
            raise ScenarioError(f"{f}.Delta", f"q Δ + ε = {Delta * q + jit:.6g} must be <= T = {T:g} (all q iterations "
                                              "must fit in an event interval)")
        if raw.timing == "async" and jit > 0 and 2 * jit >= Delta:
            raise ScenarioError(f"{f}.epsilon", f"2ε = {2 * jit:g} must be < Δ = {Delta:g} (iteration times would "
                                                "reorder)")
        if raw.timing != "sync" and raw.ideal:
            raise ScenarioError(f"{f}.ideal", "only for synchronous runs")
        horizon = raw.intervals * T + max(abs(x) for x in offsets)
        if growth * horizon > MAX_GROWTH_EXPONENT:
            raise ScenarioError(f"{f}.intervals", f"the plant's state grows like e^({growth:.3g} t) (the largest real part "
                                                  f"of eig(A)); over the horizon {horizon:g} it would leave the "
                                                  f"floating-point range: at most "
                                                  f"{int(MAX_GROWTH_EXPONENT / growth / T):,} intervals of T = {T:g}")
        leave = _leave(raw.leave, f"{f}.leave", m, T, offsets, raw.intervals)
        if raw.reference_run and raw.reference_run not in names - {name}:
            raise ScenarioError(f"{f}.reference_run", f"must name an earlier run, got '{raw.reference_run}'")
        runs.append(RunSpec(name, raw.timing, switching, graph, raw.intervals, raw.noise, raw.rule, q, q_lab,
                            raw.monte_carlo, raw.ideal, eps, beta, Delta, offsets, leave, raw.reference_run, name))
    return tuple(runs)


def _leave(lv: LeaveSection | None, f: str, m: int, T: float, offsets, intervals: int) -> Leave | None:
    if lv is None:
        return None
    if lv.agent > m:
        raise ScenarioError(f"{f}.agent", f"must be <= m = {m}, got {lv.agent}")
    ag = lv.agent - 1
    if lv.rejoin <= lv.at:
        raise ScenarioError(f"{f}.rejoin", f"must be > leave.at = {lv.at:g}")
    for name, t in (("at", lv.at), ("rejoin", lv.rejoin)):
        s = (t - offsets[ag]) / T
        if abs(s - round(s)) > 1e-9:
            raise ScenarioError(f"{f}.{name}", f"must be an event time of agent {ag + 1} (t_i0 + sT), got {t:g}")
    if lv.rejoin > offsets[ag] + intervals * T:
        raise ScenarioError(f"{f}.rejoin", "must fall inside the run's horizon")
    return Leave(ag, float(lv.at), float(lv.rejoin), lv.policy)


def load(path: Path) -> HybridScenario:
    data = load_toml(path)
    data.pop("family", None)
    return HybridScenario.from_dict(data)


def paper_scenario() -> HybridScenario:
    return load(Path(__file__).with_name("paper.toml"))


def generic_scenario() -> HybridScenario:
    return load(Path(__file__).with_name("generic.toml"))
