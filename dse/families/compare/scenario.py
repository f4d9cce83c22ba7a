"""The `compare` scenario file, declared once: one discrete-time linear-Gaussian plant, one graph and one link
model, given to every registered estimator that applies.

Every key is declared below (type, default, bounds, unit, meaning); docs/scenarios.md is generated from the
declarations. Rules that tie keys of different tables together (matrix sizes against the state dimension,
the graph's degrees against the weights, gains given per sensor type) are the file's validator, each error
naming its key. The validated file is the scenario the stages read: the matrices, the sensor network model,
the link model and the consensus weights are its cached properties.
"""
from __future__ import annotations

import re
from functools import cached_property
from typing import Literal

import numpy as np
from pydantic import model_validator

from dse.errors import ScenarioError
from dse.estimators.network import EstimatorName, registry
from dse.plugin.declare import PluginTable
from dse.scenario.declare import (Matrix, Real, ScenarioFile, Section, computed_default, covariance, key, matrix,
                                  name_key, only_with)
from dse.scenario.graphs import GraphSection, GraphSpec, graph_from_section, max_degree

MAX_NODES = 500
MAX_STATE = 10
MAX_ROWS = 4
PLUGIN_NAME = r"[A-Za-z0-9_-]{1,40}"


class PlantSection(Section):
    """The plant x(k+1) = F x(k) + w(k), w ~ N(0, Q), x(0) ~ N(x0, P0)."""

    F: Matrix = key(doc="state transition matrix (n x n)", constraint=f"square, n <= {MAX_STATE}")
    Q: Matrix = key(doc="process noise covariance (n x n)", unit="state²", constraint="symmetric, positive semidefinite")

    @computed_default
    def _identity(data):
        """identity"""
        return [[float(i == j) for j in range(len(data["F"]))] for i in range(len(data["F"]))]

    P0: Matrix = key(_identity, doc="covariance of x(0) (n x n); every filter starts from it", unit="state²",
                     constraint="symmetric, positive definite (the information filters start from its inverse)")

    @computed_default
    def _zeros(data):
        """zeros"""
        return [0.0] * len(data["F"])

    x0: list[Real] = key(_zeros, doc="mean of x(0), every node's first estimate", unit="state", constraint="n entries")


class SensorType(Section):
    """One kind of sensor: y_i(k) = H x(k) + v_i(k), v_i ~ N(0, R)."""

    H: Matrix = key(doc="measurement matrix (m x n)", constraint=f"m <= {MAX_ROWS} rows of n entries")
    R: Matrix = key(doc="measurement noise covariance (m x m)", unit="measurement²",
                    constraint="symmetric, positive definite")


class SensorsSection(Section):
    """The sensors at the nodes: node i carries sensor type `assign[i]` (by default types repeat over the
    nodes: node i has type i mod len(types))."""

    types: list[SensorType] = key(doc="the sensor types", min_length=1, max_length=64)
    assign: list[int] | None = key(None, doc="type index of every node (N entries)",
                                   constraint="one entry per node, each a valid index into types")


class LinksSection(Section):
    """The communication: which links work in each step, and the noise on what is sent."""

    model: Literal["reliable", "failures", "matchings", "poisson"] = key(
        "reliable", doc="reliable: every link works in every round; failures: each link fails independently with "
        "probability p_fail in each round; matchings: each round is a random maximal matching (random priorities, "
        "greedy) whose links then fail with probability p_fail; poisson: every link carries a Poisson clock of "
        "rate `rate` per step and each ring is one pairwise exchange")
    p_fail: Real = key(0.0, doc="probability that a link fails in a round (failures, matchings)", ge=0, lt=1)
    rate: Real | None = key(None, doc="expected exchanges per link per step (poisson)", gt=0, le=50,
                            constraint="required with model = poisson, only then")
    rounds: int = key(1, doc="synchronous communication rounds per step (consensus rounds of Carli's, the "
                      "re-injection, the pairwise-averaging and the CI filters; the others exchange once per step)",
                      ge=1, le=100)
    noise_std: Real = key(0.0, doc="σ_c: a node that fused what it heard in a round has its fused state estimate "
                          "corrupted by N(0, σ_c² I) (Savas et al.'s noise model, applied to every filter)",
                          unit="state", ge=0)

    @model_validator(mode="after")
    def _model_keys(self):
        only_with(self, "rate", "model", "poisson")
        if self.model in ("reliable", "poisson") and self.p_fail != 0.0:
            raise ScenarioError("p_fail", f"only with model = 'failures' or 'matchings' (model is '{self.model}')")
        return self


class WeightsSection(Section):
    """Consensus and combination weights on the links (a failed link's weight stays with the node)."""

    kind: Literal["metropolis", "laplacian"] = key(
        "metropolis", doc="metropolis: q_ij = 1/(1 + max(d_i, d_j)); laplacian: q_ij = eps on every link")
    eps: Real | None = key(None, doc="the Laplacian weight (kind = laplacian)", gt=0,
                           constraint="required with kind = laplacian, only then; < 1/d_max")
    alpha: Real | None = key(None, doc="weight α of Tanwani's pairwise averaging (6), Π = I − α L; none: 1/(1 + "
                             "d_max) (the paper allows up to 1/d_max; at 1/d_max a synchronous round on a bipartite "
                             "graph has an eigenvalue −1 that never averages out)", gt=0, le=0.5,
                             constraint="<= 1/d_max")
    kcf_epsilon: Real = key(0.1, doc="ε of the Kalman-consensus filter's consensus gain γ = ε/(1 + ‖M‖)", gt=0, le=10)

    @model_validator(mode="after")
    def _kind(self):
        only_with(self, "eps", "kind", "laplacian")
        return self


Scale = Literal["optimal"] | Real


class GainsSection(Section):
    """Gains of the constant-gain filters (Carli's, the re-injection and the pairwise-averaging filters):
    node i uses ℓ·G_i, G_i its base gain and ℓ the filter's scale."""

    base: Literal["split", "given"] = key(
        "split", doc="split: G_i = N K_i, the centralized steady-state Kalman gain cut by each node's columns "
        "(Tanwani's (7)); given: per sensor type, `given`")
    given: list[Matrix] | None = key(None, doc="base gain of every sensor type (n x m each; base = given)",
                                     constraint="one per sensor type, required with base = given, only then")
    carli_scale: Scale = key("optimal", doc="ℓ of Carli's filter: a number, or optimal (minimises the exact "
                             "steady-state mean-square error, as Carli et al. tune their gain)",
                             constraint="a number must be > 0")
    reinjection_scale: Scale = key("optimal", doc="ℓ of the re-injection filter: a number, or optimal (jointly "
                                   "with ζ, Savas et al. §V-B)", constraint="a number must be > 0")
    reinjection_zeta: Scale = key("optimal", doc="ζ of the re-injection filter (13): a number in [0, 1], or optimal",
                                  constraint="a number must be in [0, 1]")
    pairwise_scale: Real = key(1.0, doc="ℓ of the pairwise-averaging filter (1: Tanwani's split gains)", gt=0)

    @model_validator(mode="after")
    def _given(self):
        only_with(self, "given", "base", "given")
        for name in ("carli_scale", "reinjection_scale"):
            v = getattr(self, name)
            if not isinstance(v, str) and not v > 0:
                raise ScenarioError(name, f"must be > 0, got {v:g}")
        z = self.reinjection_zeta
        if not isinstance(z, str) and not 0 <= z <= 1:
            raise ScenarioError("reinjection_zeta", f"must be in [0, 1], got {z:g}")
        return self


class EstimatorsSection(Section):
    """Which estimators run (each one that does not apply to the link model is reported as not applicable,
    with the reason): the built-in ones in `include`, and every plug-in filter with a table
    `[estimators.<name>]` (docs/plugins.md)."""

    @computed_default
    def _every(data):
        """every built-in estimator"""
        return list(registry())

    include: list[EstimatorName] = key(_every, doc="ids of the built-in estimators to run (one module each in "
                                       "dse/estimators/network/; the `applicability` table lists them)", min_length=1,
                                       constraint="registered estimator ids; the centralized filter always runs (it "
                                       "is the reference)")
    plugins: dict[str, PluginTable] = key(dict, doc="plug-in filters, one table each", inline=True,
                                          constraint="names of 1 to 40 letters, digits, '-' or '_', not a built-in's, "
                                          "without '__', none of token, path, fault, steps")

    @model_validator(mode="before")
    @classmethod
    def _plugin_tables(cls, data):
        """`[estimators.<name>]` tables are the plug-ins (declared as `plugins`, written inline)."""
        if not isinstance(data, dict):
            return data
        data = dict(data)
        tables = {k: data.pop(k) for k in list(data) if k not in cls.model_fields and isinstance(data[k], dict)}
        if tables:
            data["plugins"] = {**data.get("plugins", {}), **tables}
        return data

    @model_validator(mode="after")
    def _plugin_names(self):
        for name in self.plugins:
            if name in registry():
                raise ScenarioError(name, f"{name!r} is a built-in estimator's id; give the plug-in "
                                                          "another name")
            if not re.fullmatch(PLUGIN_NAME, name):
                raise ScenarioError(name, "a plug-in's name has 1 to 40 letters, digits, '-' or '_'")
        return self


class SimulationSection(Section):
    """The horizon and the Monte Carlo simulation (trials in units of 1,000, common random numbers)."""

    steps: int = key(100, doc="steps k = 0..steps−1", ge=2, le=20_000)
    trials: int = key(4000, doc="Monte Carlo trials", ge=100, le=10_000_000)

    @computed_default
    def _quick(data):
        """min(trials, 1000)"""
        return min(data["trials"], 1000)

    quick_trials: int = key(_quick, doc="trials in quick runs", ge=100, le=10_000_000)

    @computed_default
    def _last(data):
        """steps − 1"""
        return data["steps"] - 1

    eval_step: int = key(_last, doc="step at which the node tables and the claims compare the estimators", ge=1,
                         constraint="< steps")
    paths: int = key(1, doc="sample trials kept whole for the recording", ge=0, le=20)
    exact_max_dimension: int = key(400, doc="exact joint recursions run when N n is at most this (their cost "
                                   "grows as (N n)³ per step)", ge=2, le=5000)

    @model_validator(mode="after")
    def _eval(self):
        if self.eval_step >= self.steps:
            raise ScenarioError("eval_step", f"must be < steps = {self.steps}, got {self.eval_step}")
        return self


class CompareFile(ScenarioFile):
    """A compare scenario file."""

    unkeyed = {"name": True, "simulation": {"trials": True, "quick_trials": True}}

    name: str = name_key()
    plant: PlantSection = key(doc="the plant")
    sensors: SensorsSection = key(doc="the sensors")
    graph: GraphSection = key(doc="the communication graph")
    links: LinksSection = key(LinksSection, doc="the link model")
    weights: WeightsSection = key(WeightsSection, doc="consensus weights")
    gains: GainsSection = key(GainsSection, doc="constant gains")
    estimators: EstimatorsSection = key(EstimatorsSection, doc="the estimators")
    simulation: SimulationSection = key(SimulationSection, doc="horizon and Monte Carlo")

    @model_validator(mode="after")
    def _cross_table_rules(self):
        """Sizes against the state dimension and the graph, weights against the degrees, gains per sensor
        type; every property below is computed here once, so that an invalid file fails when read."""
        if self.N > MAX_NODES:
            raise ScenarioError("graph.n", f"{self.N} nodes; this family handles at most {MAX_NODES}")
        if self.n > MAX_STATE:
            raise ScenarioError("plant.F", f"state dimension {self.n} > {MAX_STATE}")
        self.Q, self.P0, self.x0, self.sensor_types, self.assign      # each raises naming its key
        dmax = self.max_degree
        w = self.weights
        if w.kind == "laplacian" and w.eps >= 1.0 / dmax:
            raise ScenarioError("weights.eps", f"must be < 1/d_max = {1.0 / dmax:.6g}, got {w.eps:g}")
        if self.alpha > 1.0 / dmax + 1e-15:
            raise ScenarioError("weights.alpha", f"must be <= 1/d_max = {1.0 / dmax:.6g}, got {self.alpha:g}")
        self.given_gains
        self.estimator_specs                     # a plug-in that cannot be loaded names its table
        return self

    # -- the scenario the stages read ----------------------------------------------------------------------

    @cached_property
    def network(self) -> GraphSpec:
        return graph_from_section(self.graph, "graph", connected=True, min_nodes=2)

    @property
    def N(self) -> int:
        return self.network.n

    @cached_property
    def F(self) -> np.ndarray:
        F = matrix(self.plant.F, "plant.F")
        if F.shape[0] != F.shape[1]:
            raise ScenarioError("plant.F", f"must be square, got {F.shape[0]}x{F.shape[1]}")
        return F

    @property
    def n(self) -> int:
        return self.F.shape[0]

    @cached_property
    def Q(self) -> np.ndarray:
        return covariance(self.plant.Q, "plant.Q", n=self.n)

    @cached_property
    def P0(self) -> np.ndarray:
        return covariance(self.plant.P0, "plant.P0", n=self.n, definite=True)

    @cached_property
    def x0(self) -> np.ndarray:
        x0 = np.asarray(self.plant.x0, float)
        if x0.shape != (self.n,):
            raise ScenarioError("plant.x0", f"must have {self.n} entries, got {x0.size}")
        return x0

    @cached_property
    def sensor_types(self) -> tuple[tuple[np.ndarray, np.ndarray], ...]:
        """(H, R) of every sensor type."""
        out = []
        for t, st in enumerate(self.sensors.types):
            H = matrix(st.H, f"sensors.types[{t}].H", shape=(None, self.n))
            if H.shape[0] > MAX_ROWS:
                raise ScenarioError(f"sensors.types[{t}].H", f"{H.shape[0]} rows; at most {MAX_ROWS}")
            out.append((H, covariance(st.R, f"sensors.types[{t}].R", n=H.shape[0], definite=True)))
        return tuple(out)

    @cached_property
    def assign(self) -> tuple[int, ...]:
        """The sensor type of every node (types repeat over the nodes by default)."""
        T = len(self.sensors.types)
        if self.sensors.assign is None:
            return tuple(i % T for i in range(self.N))
        assign = tuple(self.sensors.assign)
        if len(assign) != self.N:
            raise ScenarioError("sensors.assign", f"must have one entry per node ({self.N}), got {len(assign)}")
        bad = [a for a in assign if not 0 <= a < T]
        if bad:
            raise ScenarioError("sensors.assign", f"type index {bad[0]} out of range 0..{T - 1}")
        return assign

    @cached_property
    def max_degree(self) -> int:
        return max_degree(self.network)          # from the edge list (networkx only for random graphs)

    @cached_property
    def alpha(self) -> float:
        """α of the pairwise averaging: `weights.alpha`, by default 1/(1 + d_max)."""
        return float(self.weights.alpha if self.weights.alpha is not None else 1.0 / (1.0 + self.max_degree))

    @cached_property
    def given_gains(self) -> tuple[np.ndarray, ...]:
        """The base gain of every sensor type (base = given), n x m_t each."""
        g = self.gains
        if g.base != "given":
            return ()
        if len(g.given) != len(self.sensor_types):
            raise ScenarioError("gains.given", f"one gain per sensor type ({len(self.sensor_types)}), "
                                               f"got {len(g.given)}")
        return tuple(matrix(K, f"gains.given[{t}]", shape=(self.n, self.sensor_types[t][0].shape[0]))
                     for t, K in enumerate(g.given))

    @cached_property
    def estimator_specs(self) -> dict:
        """name -> declaration of every built-in estimator (the registry's order) and every plug-in filter of
        the file (in its order), whether it runs or not."""
        from dse.plugin.declare import from_table

        plugins = {name: from_table(name, table, i) for i, (name, table) in enumerate(self.estimators.plugins.items())}
        return {**registry(), **plugins}

    @property
    def plugin_names(self) -> tuple[str, ...]:
        """The plug-in filters of the file (`[estimators.<name>]`), in its order."""
        return tuple(self.estimators.plugins)

    @cached_property
    def estimator_names(self) -> tuple[str, ...]:
        """The estimators that run, in the registry's order (the reference always), then the plug-ins."""
        return tuple(name for name, est in self.estimator_specs.items()
                     if name in self.estimators.include or est.reference or est.plugin)

    @cached_property
    def model(self):
        """The plant and the sensors at the nodes (`sensor_network.SensorNetworkModel`)."""
        from dse.estimators.sensor_network import SensorNetworkModel

        return SensorNetworkModel.build(self.F, self.Q, [self.sensor_types[t][0] for t in self.assign],
                                        [self.sensor_types[t][1] for t in self.assign], self.P0, self.x0)

    @cached_property
    def link_model(self):
        """The graph's links under the link model (`link_models.LinkModel`)."""
        from dse.estimators.link_models import LinkModel, Topology

        lk = self.links
        # the graph's edge list without networkx for the deterministic kinds (the same sorted edges as
        # `build().edges()`: tests/test_graph_edges.py)
        topo = Topology.from_edges(self.N, self.network.edge_array().tolist())
        return LinkModel(topo, lk.model, rounds=lk.rounds, p_fail=float(lk.p_fail), rate=float(lk.rate or 0.0),
                         noise_std=float(lk.noise_std))

    @cached_property
    def edge_weights(self) -> np.ndarray:
        """q_e of the consensus and combination rounds on every edge."""
        topo = self.link_model.topology
        return topo.metropolis_weights() if self.weights.kind == "metropolis" else np.full(topo.E, self.weights.eps)
