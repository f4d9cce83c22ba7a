"""The `compare` scenario family: one discrete-time linear-Gaussian plant, one graph and one link
model, given to every estimator that applies.

Every key is declared once below (type, default, bounds, unit, meaning); `docs/scenarios.md` is
generated from the declarations. Rules that tie keys of different tables together (matrix sizes
against the state dimension, the link model's own keys, gains given per sensor type) are checked
when the file is read, each naming its key.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
from pydantic import model_validator

from dse.scenario.declare import Matrix, Real, Section, computed, covariance, key, matrix, parse
from dse.errors import ScenarioError
from dse.scenario.graphs import GraphSection, GraphSpec, graph_from_section, max_degree

#: every estimator of the family, in the order of the tables
ESTIMATORS = ("central", "local", "gikf", "carli", "reinjection", "pairwise", "kcf", "diffusion", "ci")
LABELS = {"central": "centralized KF", "local": "local KF (no communication)", "gikf": "GIKF (Kar & Moura)",
          "carli": "two-stage consensus (Carli et al.)", "reinjection": "re-injection (Savas et al.)",
          "pairwise": "pairwise averaging (Tanwani)", "kcf": "Kalman-consensus (Olfati-Saber)",
          "diffusion": "diffusion KF, ATC (Cattivelli & Sayed)", "ci": "consensus on information (Battistelli & Chisci)"}
MAX_NODES = 500
MAX_STATE = 10
MAX_ROWS = 4
MAX_STEPS = 20_000


class PlantSection(Section):
    """The plant x(k+1) = F x(k) + w(k), w ~ N(0, Q), x(0) ~ N(x0, P0)."""

    F: Matrix = key(doc="state transition matrix (n x n)", constraint=f"square, n <= {MAX_STATE}")
    Q: Matrix = key(doc="process noise covariance (n x n)", unit="state²", constraint="symmetric, positive semidefinite")
    P0: Matrix | None = key(computed("identity"), doc="covariance of x(0) (n x n); every filter starts from it",
                            unit="state²", constraint="symmetric, positive definite (the information filters start "
                                                      "from its inverse)")
    x0: list[Real] | None = key(computed("zeros"), doc="mean of x(0), every node's first estimate", unit="state",
                                constraint="n entries")


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
        if self.model == "poisson" and self.rate is None:
            raise ScenarioError("rate", "missing (needed for model = 'poisson')")
        if self.model != "poisson" and self.rate is not None:
            raise ScenarioError("rate", f"only with model = 'poisson' (model is '{self.model}')")
        if self.model in ("reliable", "poisson") and self.p_fail != 0.0:
            raise ScenarioError("p_fail", f"only with model = 'failures' or 'matchings' (model is '{self.model}')")
        return self


class WeightsSection(Section):
    """Consensus and combination weights on the links (a failed link's weight stays with the node)."""

    kind: Literal["metropolis", "laplacian"] = key(
        "metropolis", doc="metropolis: q_ij = 1/(1 + max(d_i, d_j)); laplacian: q_ij = eps on every link")
    eps: Real | None = key(None, doc="the Laplacian weight (kind = laplacian)", gt=0,
                           constraint="required with kind = laplacian, only then; < 1/d_max")
    alpha: Real | None = key(computed("1/(1 + d_max)"), doc="weight α of Tanwani's pairwise averaging (6), "
                             "Π = I − α L (the paper allows up to 1/d_max; at 1/d_max a synchronous round on a "
                             "bipartite graph has an eigenvalue −1 that never averages out)", gt=0, le=0.5,
                             constraint="<= 1/d_max")
    kcf_epsilon: Real = key(0.1, doc="ε of the Kalman-consensus filter's consensus gain γ = ε/(1 + ‖M‖)", gt=0, le=10)

    @model_validator(mode="after")
    def _kind(self):
        if self.kind == "laplacian" and self.eps is None:
            raise ScenarioError("eps", "missing (needed for kind = 'laplacian')")
        if self.kind != "laplacian" and self.eps is not None:
            raise ScenarioError("eps", f"only with kind = 'laplacian' (kind is '{self.kind}')")
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
                             "steady-state mean-square error, as Carli et al. tune their gain)")
    reinjection_scale: Scale = key("optimal", doc="ℓ of the re-injection filter: a number, or optimal (jointly "
                                   "with ζ, Savas et al. §V-B)")
    reinjection_zeta: Scale = key("optimal", doc="ζ of the re-injection filter (13): a number in [0, 1], or optimal",
                                  constraint="a number must be in [0, 1]")
    pairwise_scale: Real = key(1.0, doc="ℓ of the pairwise-averaging filter (1: Tanwani's split gains)", gt=0)

    @model_validator(mode="after")
    def _given(self):
        if self.base == "given" and self.given is None:
            raise ScenarioError("given", "missing (needed for base = 'given')")
        if self.base != "given" and self.given is not None:
            raise ScenarioError("given", f"only with base = 'given' (base is '{self.base}')")
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
    with the reason)."""

    include: list[Literal[ESTIMATORS]] | None = key(  # type: ignore[valid-type]
        computed("all"), doc="estimator ids: " + ", ".join(ESTIMATORS), min_length=1,
        constraint="the centralized filter always runs (it is the reference)")


class SimulationSection(Section):
    """The horizon and the Monte Carlo simulation (trials in units of 1,000, common random numbers)."""

    steps: int = key(100, doc="steps k = 0..steps−1", ge=2, le=MAX_STEPS)
    trials: int = key(4000, doc="Monte Carlo trials", ge=100, le=10_000_000)
    quick_trials: int | None = key(computed("min(trials, 1000)"), doc="trials in quick runs", ge=100,
                                   le=10_000_000)
    eval_step: int | None = key(computed("steps − 1"), doc="step at which the node tables and the claims "
                                "compare the estimators", ge=1, constraint="< steps")
    paths: int = key(1, doc="sample trials kept whole for the recording", ge=0, le=20)
    exact_max_dimension: int = key(400, doc="exact joint recursions run when N n is at most this (their cost "
                                   "grows as (N n)³ per step)", ge=2, le=5000)

    @model_validator(mode="after")
    def _eval(self):
        if self.eval_step is not None and self.eval_step >= self.steps:
            raise ScenarioError("eval_step", f"must be < steps = {self.steps}, got {self.eval_step}")
        return self


class CompareFile(Section):
    """A compare scenario file."""

    name: str = key("scenario", doc="scenario name: the output directory OUT/run/<name>/",
                    pattern=r"^[A-Za-z0-9_-]{1,64}$")
    plant: PlantSection = key(doc="the plant")
    sensors: SensorsSection = key(doc="the sensors")
    graph: GraphSection = key(doc="the communication graph")
    links: LinksSection = key(LinksSection, doc="the link model")
    weights: WeightsSection = key(WeightsSection, doc="consensus weights")
    gains: GainsSection = key(GainsSection, doc="constant gains")
    estimators: EstimatorsSection = key(EstimatorsSection, doc="the estimators")
    simulation: SimulationSection = key(SimulationSection, doc="horizon and Monte Carlo")


@dataclass(frozen=True)
class CompareScenario:
    name: str
    F: np.ndarray
    Q: np.ndarray
    P0: np.ndarray
    x0: np.ndarray
    H_types: tuple
    R_types: tuple
    assign: tuple[int, ...]
    graph: GraphSpec
    link_model: str
    p_fail: float
    rate: float
    rounds: int
    noise_std: float
    weights_kind: str
    eps: float
    alpha: float
    kcf_epsilon: float
    gain_base: str
    given_gains: tuple
    carli_scale: float | str
    reinjection_scale: float | str
    reinjection_zeta: float | str
    pairwise_scale: float
    include: tuple[str, ...]
    steps: int
    trials: int
    quick_trials: int
    eval_step: int
    paths: int
    exact_max_dimension: int

    @property
    def N(self) -> int:
        return self.graph.n

    @property
    def n(self) -> int:
        return self.F.shape[0]

    def key(self) -> dict[str, Any]:
        """Everything that determines the numbers (for the stage cache)."""
        out = {}
        for f in self.__dataclass_fields__:
            if f in ("name", "trials", "quick_trials", "paths"):
                continue
            v = getattr(self, f)
            out[f] = [np.asarray(a).tolist() for a in v] if f in ("H_types", "R_types", "given_gains") else \
                (v.tolist() if isinstance(v, np.ndarray) else v)
        return out

    @classmethod
    def from_dict(cls, data: Any) -> "CompareScenario":
        f = parse(CompareFile, data)
        graph = graph_from_section(f.graph, "graph", connected=True, min_nodes=2)
        N = graph.n
        if N > MAX_NODES:
            raise ScenarioError("graph.n", f"{N} nodes; this family handles at most {MAX_NODES}")
        F = matrix(f.plant.F, "plant.F")
        n = F.shape[0]
        if F.shape != (n, n):
            raise ScenarioError("plant.F", f"must be square, got {F.shape[0]}x{F.shape[1]}")
        if n > MAX_STATE:
            raise ScenarioError("plant.F", f"state dimension {n} > {MAX_STATE}")
        Q = covariance(f.plant.Q, "plant.Q", n=n)
        P0 = covariance(f.plant.P0, "plant.P0", n=n, definite=True) if f.plant.P0 is not None else np.eye(n)
        x0 = np.zeros(n) if f.plant.x0 is None else np.asarray(f.plant.x0, float)
        if x0.shape != (n,):
            raise ScenarioError("plant.x0", f"must have {n} entries, got {x0.size}")
        Hs, Rs = [], []
        for t, st in enumerate(f.sensors.types):
            H = matrix(st.H, f"sensors.types[{t}].H", shape=(None, n))
            if H.shape[0] > MAX_ROWS:
                raise ScenarioError(f"sensors.types[{t}].H", f"{H.shape[0]} rows; at most {MAX_ROWS}")
            Hs.append(H)
            Rs.append(covariance(st.R, f"sensors.types[{t}].R", n=H.shape[0], definite=True))
        T = len(Hs)
        if f.sensors.assign is None:
            assign = tuple(i % T for i in range(N))
        else:
            assign = tuple(f.sensors.assign)
            if len(assign) != N:
                raise ScenarioError("sensors.assign", f"must have one entry per node ({N}), got {len(assign)}")
            bad = [a for a in assign if not 0 <= a < T]
            if bad:
                raise ScenarioError("sensors.assign", f"type index {bad[0]} out of range 0..{T - 1}")
        G = graph.build()
        dmax = max_degree(G)
        w = f.weights
        if w.kind == "laplacian" and w.eps >= 1.0 / dmax:
            raise ScenarioError("weights.eps", f"must be < 1/d_max = {1.0 / dmax:.6g}, got {w.eps:g}")
        alpha = w.alpha if w.alpha is not None else 1.0 / (1.0 + dmax)
        if alpha > 1.0 / dmax + 1e-15:
            raise ScenarioError("weights.alpha", f"must be <= 1/d_max = {1.0 / dmax:.6g}, got {alpha:g}")
        g = f.gains
        given = ()
        if g.base == "given":
            if len(g.given) != T:
                raise ScenarioError("gains.given", f"one gain per sensor type ({T}), got {len(g.given)}")
            given = tuple(matrix(K, f"gains.given[{t}]", shape=(n, Hs[t].shape[0])) for t, K in enumerate(g.given))
        include = tuple(e for e in ESTIMATORS if f.estimators.include is None or e in f.estimators.include
                        or e == "central")
        s = f.simulation
        lk = f.links
        return cls(name=f.name, F=F, Q=Q, P0=P0, x0=x0, H_types=tuple(Hs), R_types=tuple(Rs), assign=assign,
                   graph=graph, link_model=lk.model, p_fail=float(lk.p_fail), rate=float(lk.rate or 0.0),
                   rounds=lk.rounds, noise_std=float(lk.noise_std), weights_kind=w.kind, eps=float(w.eps or 0.0),
                   alpha=float(alpha), kcf_epsilon=float(w.kcf_epsilon), gain_base=g.base, given_gains=given,
                   carli_scale=g.carli_scale, reinjection_scale=g.reinjection_scale,
                   reinjection_zeta=g.reinjection_zeta, pairwise_scale=float(g.pairwise_scale), include=include,
                   steps=s.steps, trials=s.trials,
                   quick_trials=s.quick_trials if s.quick_trials is not None else min(s.trials, 1000),
                   eval_step=s.eval_step if s.eval_step is not None else s.steps - 1, paths=s.paths,
                   exact_max_dimension=s.exact_max_dimension)
