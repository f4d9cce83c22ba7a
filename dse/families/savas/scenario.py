"""The noisy-consensus-filter scenario file, declared once: a scalar random walk observed by N
agents that average their estimates over a doubly stochastic Q with noisy links. The paper's
example (`paper.toml`) and any user scenario of the same kind.

Every key is declared below (type, default, bounds, unit, meaning); `docs/scenarios.md` is
generated from these declarations. Rules that tie keys of different tables together (the
evaluation step against the horizon, the gain tables against the rounds, Q against the graph)
are validators, each naming its key. The validated model is the scenario the stages read: Q,
the graph and the other derived quantities are its cached properties.
"""
from __future__ import annotations

from functools import cached_property
from typing import Annotated, Literal

import numpy as np
from pydantic import Field, model_validator

from dse.errors import ScenarioError
from dse.scenario.declare import Matrix, Real, ScenarioFile, Section, computed_default, key, matrix, name_key
from dse.scenario.graphs import (GraphSection, GraphSpec, check_consensus_matrix, graph_from_section,
                                 laplacian_consensus_weights, max_degree, metropolis_weights)

GAIN_CHOICES = ("optimal-corrected", "optimal-printed", "fixed")
#: the exact covariances are dense N x N recursions and the optimal gains a grid per mode: beyond
#: this many agents a run takes hours and its N x N tables gigabytes
MAX_AGENTS = 1000
#: longest horizon: the Monte Carlo streams over time, so memory does not grow with it, time does
MAX_STEPS = 100_000
MAX_ROUNDS = 1000


class ConsensusSection(Section):
    """The consensus matrix Q: agent i's new value is Σ_j q_ij z_j (eqs. (6), (8)). The paper assumes
    Q doubly stochastic, nonnegative and primitive (one eigenvalue 1, the others inside the unit disk)."""

    weights: Literal["laplacian", "metropolis", "matrix"] = key(
        "metropolis", doc="laplacian: Q = I − εL (the paper's example, ε = 0.4 on the 3-node line); metropolis: "
        "q_ij = 1/(1 + max(d_i, d_j)) on edges; matrix: Q given entry by entry")
    eps: Real | None = key(None, doc="step ε of Q = I − εL", gt=0,
                           constraint="required with weights = laplacian, and < 1/d_max (Q nonnegative and primitive)")
    matrix: Matrix | None = key(None, doc="Q, row i holding agent i's weights",
                                constraint="with weights = matrix: N x N, nonnegative, rows and columns summing to 1 "
                                           "within 1e-10, zero where (i, j) is not an edge, primitive")

    @model_validator(mode="after")
    def _kind_rules(self):
        for name, kind in (("eps", "laplacian"), ("matrix", "matrix")):
            if self.weights == kind and getattr(self, name) is None:
                raise ScenarioError(name, f"missing (needed for weights = '{kind}')")
            if self.weights != kind and getattr(self, name) is not None:
                raise ScenarioError(name, f"only with weights = '{kind}' (weights is '{self.weights}')")
        return self

    def weights_on(self, graph: GraphSpec) -> np.ndarray:
        """Q on the scenario's graph (errors name consensus.<key>)."""
        if self.weights == "laplacian":
            dmax = max_degree(graph)
            if dmax and self.eps >= 1.0 / dmax:
                raise ScenarioError("consensus.eps", f"must be < 1/d_max = {1.0 / dmax:.6g} so that Q is nonnegative "
                                                     f"and primitive, got {self.eps:g}")
            Q = laplacian_consensus_weights(graph, self.eps)
        elif self.weights == "metropolis":
            Q = metropolis_weights(graph)
        else:
            Q = matrix(self.matrix, "consensus.matrix", shape=(graph.n, graph.n))
            edges = np.zeros((graph.n, graph.n), bool)
            for u, v in graph.edge_array():
                edges[u, v] = edges[v, u] = True
            off_graph = (Q != 0) & ~edges & ~np.eye(graph.n, dtype=bool)
            if off_graph.any():
                i, j = map(int, np.argwhere(off_graph)[0])
                raise ScenarioError("consensus.matrix", f"entry [{i}][{j}] is nonzero but ({i},{j}) is not an edge")
        check_consensus_matrix(Q, "consensus.matrix" if self.weights == "matrix" else "consensus")
        return Q


class ModelSection(Section):
    """The process x(k+1) = x(k) + w(k) (eq. (3)) and the agents' measurements y_i(k) = x(k) + n_i(k)
    (eq. (4)); X₀ ~ N(x0_mean, sigma0), w ~ N(0, q), n_i ~ N(0, r), all independent."""

    q: Real = key(doc="variance of the process noise w(k)", unit="state²", gt=0)
    r: Real = key(doc="variance of each agent's measurement noise n_i(k)", unit="state²", gt=0)
    sigma0: Real = key(1.0, doc="variance σ of the initial state X₀ (the paper's σ; not given there, 1 is our "
                       "choice)", unit="state²", ge=0)
    x0_mean: Real = key(0.0, doc="mean of X₀, and every agent's first estimate x̂(0|−1) (no effect on the errors' "
                        "statistics)", unit="state")


Round = Annotated[int, Field(ge=0, le=MAX_ROUNDS)]
NoiseLevel = Annotated[float, Field(allow_inf_nan=False, ge=0, le=1e100)]


class SweepSection(Section):
    """The cells simulated and checked: both filters at every number of rounds m and noise level σ_c,
    over k = 0..n_steps−1."""

    rounds: list[Round] = key([0, 1, 2, 3, 4, 5], doc="numbers m of consensus rounds between two "
                              "measurements", min_length=1, constraint=f"each 0..{MAX_ROUNDS}; strictly increasing")
    sigma_c: list[NoiseLevel] = key([0.0, 1.0], doc="standard deviations σ_c of the communication noise "
                                    "added at every round (eq. (6))", unit="state", min_length=1,
                                    constraint="each >= 0; strictly increasing")
    n_steps: int = key(10, doc="horizon: steps k = 0..n_steps−1 are simulated", ge=1, le=MAX_STEPS)

    @computed_default
    def _paper_eval_step(data):
        """min(4, n_steps − 1)"""
        return min(4, data["n_steps"] - 1)

    eval_step: int = key(_paper_eval_step, doc="step k of the figures' metric Σ_i var x̃_i(k|k−1) = tr P(k|k−1) "
                         "(the paper's k = 4)", ge=0, constraint="< n_steps")
    recorded_steps: int = key(1000, doc="per-step statistics (Monte Carlo moments, exact covariances) are kept at "
                              "this many steps: all when n_steps is at most this, else the first half of them, "
                              "then evenly spaced to the last step, plus eval_step", ge=2, le=MAX_STEPS)

    @model_validator(mode="after")
    def _order(self):
        for name in ("rounds", "sigma_c"):
            values = getattr(self, name)
            if any(b <= a for a, b in zip(values, values[1:])):
                raise ScenarioError(name, "must be strictly increasing")
        if self.eval_step >= self.n_steps:
            raise ScenarioError("eval_step", f"must be < n_steps = {self.n_steps}, got {self.eval_step}")
        return self


class CarliSection(Section):
    """Carli et al.'s two-stage filter (7)+(9) run under noisy communication (Fig. 1)."""

    ell: Real = key(0.25, doc="its constant gain ℓ (Fig. 1 uses 0.25)", gt=0, le=1)


class ReinjectionSection(Section):
    """The paper's filter with re-injection (11)-(13): gains per (m, σ_c) cell."""

    gains: Literal[GAIN_CHOICES] = key(  # type: ignore[valid-type]
        "optimal-corrected", doc="optimal-corrected: (ℓ*, ζ*) minimising the corrected trace formula (16) (the exact "
        "steady-state trace); optimal-printed: minimising (16) as printed; fixed: ell and zeta below",
        constraint="optimal gains need a symmetric Q")
    ell: Real | None = key(None, doc="fixed gain ℓ (gains = fixed)", gt=0, le=1,
                           constraint="required with gains = fixed, only then")
    zeta: Real | None = key(None, doc="fixed weight ζ of the local estimate in (13) (gains = fixed)", ge=0, le=1,
                            constraint="required with gains = fixed, only then")

    @model_validator(mode="after")
    def _fixed(self):
        for name in ("ell", "zeta"):
            given = getattr(self, name) is not None
            if self.gains == "fixed" and not given:
                raise ScenarioError(name, "missing (needed for gains = 'fixed')")
            if self.gains != "fixed" and given:
                raise ScenarioError(name, "only allowed with gains = 'fixed'")
        return self


GridSize = Annotated[int, Field(ge=11, le=5000)]


class GainsSection(Section):
    """The optimal-gain tables (Fig. 2): (ℓ*, ζ*) minimising (16) for m = 0..rounds_max at every σ_c."""

    rounds_max: int | None = key(None, doc="largest m of the gain tables (none: max(sweep.rounds))", ge=0,
                                 le=MAX_ROUNDS, constraint=">= max(sweep.rounds)")
    grid: list[GridSize] = key([400, 401], doc="[n_ell, n_zeta]: the grid of (ℓ, ζ) on which J is evaluated "
                               "before the local search ([100, 101] in quick runs)", min_length=2, max_length=2,
                               constraint="each 11..5000")


class MonteCarloSection(Section):
    """The simulation: independent trials per cell, streamed in units of 1,000 trials."""

    trials: int = key(200_000, doc="trials per (filter, m, σ_c) cell (the paper: 200,000)", ge=100, le=100_000_000)

    @computed_default
    def _quick(data):
        """min(trials, 20000)"""
        return min(data["trials"], 20_000)

    quick_trials: int = key(_quick, doc="trials per cell in quick runs", ge=100, le=100_000_000)
    sample_paths: int = key(3, doc="sample trials kept whole (estimates, consensus iterates) for the recordings and "
                            "the pathwise identities", ge=0, le=50)
    sample_steps: int = key(100, doc="the sample trials are kept over the first min(n_steps, sample_steps) steps",
                            ge=2, le=10_000)


class NoisyConsensusFile(ScenarioFile):
    """A noisy-consensus-filter scenario file."""

    unkeyed = {"name": True, "monte_carlo": {"trials": True, "quick_trials": True}}

    name: str = name_key()
    graph: GraphSection = key(doc="the communication graph")
    consensus: ConsensusSection = key(ConsensusSection, doc="the consensus weights")
    model: ModelSection = key(doc="the process and the measurements")
    sweep: SweepSection = key(SweepSection, doc="the cells and the horizon")
    carli: CarliSection = key(CarliSection, doc="Carli et al.'s filter")
    reinjection: ReinjectionSection = key(ReinjectionSection, doc="the re-injection filter")
    gains: GainsSection = key(GainsSection, doc="the optimal-gain tables")
    monte_carlo: MonteCarloSection = key(MonteCarloSection, doc="the Monte Carlo simulation")

    @model_validator(mode="after")
    def _across_tables(self):
        top = max(self.sweep.rounds)
        if self.gains.rounds_max is not None and self.gains.rounds_max < top:
            raise ScenarioError("gains.rounds_max", f"must be >= max(sweep.rounds) = {top}, got {self.gains.rounds_max}")
        if self.network.n > MAX_AGENTS:
            raise ScenarioError("graph.rows" if self.network.kind == "grid" else "graph.n",
                                f"{self.network.n} agents; this family handles at most {MAX_AGENTS} (dense N x N "
                                "covariance recursions and optimal-gain grids per mode)")
        if self.reinjection.gains != "fixed" and not self.symmetric:
            raise ScenarioError("reinjection.gains", "optimal gains use eq. (16), which needs a symmetric Q; use 'fixed'")
        return self

    @cached_property
    def network(self) -> GraphSpec:
        """The graph: connected, of at least 2 agents."""
        return graph_from_section(self.graph, "graph", connected=True, min_nodes=2)

    @cached_property
    def Q(self) -> np.ndarray:
        """The consensus matrix, validated: nonnegative, doubly stochastic, primitive, on the graph's edges."""
        return self.consensus.weights_on(self.network)

    @property
    def n(self) -> int:
        return self.network.n

    @property
    def symmetric(self) -> bool:
        return bool(np.array_equal(self.Q, self.Q.T))

    @property
    def rounds_max(self) -> int:
        """The largest m of the gain tables: gains.rounds_max, or max(sweep.rounds) when not given."""
        return self.gains.rounds_max if self.gains.rounds_max is not None else max(self.sweep.rounds)
