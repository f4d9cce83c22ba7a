"""The contract of an estimator of the compare arena: a `BatchedFilter` batched over Monte Carlo trials,
and its declaration, a `NetworkEstimator`, which says once everything the harness, the design, the cost
model, the claims and the tables need to know about it.

The setting (`sensor_network`, `link_models`): a plant seen by the N nodes of a graph,

    x(k+1) = F x(k) + w(k),   w ~ N(0, Q),        y_i(k) = H_i x(k) + v_i(k),   v_i ~ N(0, R_i),

whose links deliver, in each step k, what the link model draws (synchronous rounds of working links, or
Poisson exchanges in time order) with communication noise of standard deviation σ_c.

A network filter is constructed for the model, the link model and a batch of B trials (trials on the last
axis of every array). At step k, `step(ctx)` reads a `network_step.StepContext`: the measurements y(k)
(N, m, B) and what the links delivered (the working links of each round or the exchanges, which nodes heard
a neighbour, the standard normals of the communication noise, the step's swap permutation); it returns
x̂_i(k|k), every node's estimate of x(k) after the step's communication, as (W, n, B) with W = N (W = 1
for a filter with a single estimate, like the centralized one). Then

* `shift(δ)` adds δ (n, B) to every prediction x̄_i(k+1). The harness runs every filter in error
  coordinates: x ≡ 0, y = v, first prediction x0 − x(0), each prediction shifted by −w(k). A filter that is
  equivariant (adding c to the state, to its prediction and to every estimate adds c to every later
  estimate: gains act on innovations, fusion weights sum to one) then returns its errors x̂ − x exactly,
  with no cancellation when an unstable plant makes x huge.
* `nees(err)` (optional): e_iᵀ P_i⁻¹ e_i (W, B) with the filter's own covariance P_i of x̂_i(k|k), for the
  errors err (W, n, B) of the last step; None for a filter that carries no covariance.
* `prior_covariance()` (optional): P̄_i(k+1) (n, n, N, B), the covariance of the prediction each node holds
  for the next step (the state that travels when filters swap states); None when there is none per trial.
* `hops` (filters whose communication pattern is "swap"): (N, B) links the state node i holds after the
  step travelled over (0: it stayed).

What a filter sends is a `Communication`: the pattern of contacts it uses (a contact is one working link
seen from one of its ends; a message goes from a node to one neighbour), messages per contact and real
numbers per message. The harness counts them from the links, never from the filter's code.

A declaration is found by the registry (`dse.estimators.network`): one module per estimator.
"""
from __future__ import annotations

import hashlib
import inspect
import sys
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Callable, Mapping, Protocol

import numpy as np

if TYPE_CHECKING:
    from .link_models import LinkModel
    from .network_step import StepContext
    from .sensor_network import SensorNetworkModel

#: the contacts a filter's messages use: none; every synchronous round or every Poisson exchange; the
#: links of the step (once per step); the links over which states were swapped; or counted by the harness
#: from what the filter sent (`sent_messages`, `sent_scalars` (N, B) of the last step: plug-in filters)
PATTERNS = ("none", "rounds", "step", "swap", "sent")


@dataclass(frozen=True)
class Communication:
    """What a filter sends: `pattern` (PATTERNS), messages per contact and real numbers per message."""

    pattern: str
    messages_per_contact: int = 0
    scalars_per_message: int = 0

    def __post_init__(self):
        if self.pattern not in PATTERNS:
            raise ValueError(f"unknown communication pattern {self.pattern!r}")


SILENT = Communication("none")


class BatchedFilter(Protocol):
    """B trials of one network filter (module doc): `step`, `shift`, and optionally `nees`,
    `prior_covariance` and `hops`. Subclasses inherit the defaults of the optional members."""

    def step(self, ctx: "StepContext") -> np.ndarray:
        """x̂_i(k|k) (W, n, B) after the measurements and the communication of step ctx.k."""
        ...

    def shift(self, delta: np.ndarray) -> None:
        """Add delta (n, B) to every node's prediction (error coordinates)."""
        ...

    def nees(self, err: np.ndarray) -> np.ndarray | None:
        """(W, B) e_iᵀ P_i⁻¹ e_i with the filter's own covariance of the last step, or None."""
        return None

    def prior_covariance(self) -> np.ndarray | None:
        """(n, n, N, B) covariances of the predictions the nodes hold, or None."""
        return None


@dataclass(eq=False)
class Network:
    """What the estimators of one scenario are designed for: the model, the link model, the consensus and
    combination weights q_e (a failed link's weight stays with the node), the horizon, and the scenario
    itself (its `[gains]` and `[weights]` tables tune the estimators).

    `tuned`: numbers found by searches (gain scales, steady states), read when present (the design stage
    caches them by name) and else searched and stored; `shared`: work several estimators' designs share
    within one design (base gains, the links the steady states are computed on)."""

    model: "SensorNetworkModel"
    links: "LinkModel"
    weights: np.ndarray
    steps: int
    exact_max_dimension: int
    scenario: Any
    quick: bool = False
    tuned: dict[str, float] = field(default_factory=dict)
    shared: dict[str, Any] = field(default_factory=dict)

    def joint_size_reason(self) -> str:
        """Why the exact joint recursion of N n stacked errors is not run ("" when it is)."""
        Nn = self.model.N * self.model.n
        if Nn <= self.exact_max_dimension:
            return ""
        return (f"the joint recursion is (N n)² = {Nn}² entries per step, beyond simulation.exact_max_dimension = "
                f"{self.exact_max_dimension} (Monte Carlo only)")


@dataclass(eq=False)
class DesignedEstimator:
    """One estimator designed for one scenario: whether it applies (`reason` says why not), what its
    filter is built from (`config`), whether its exact moments are computed (`exact_reason` says why not),
    its tuned gains (`tuning`: scale, zeta, rho, steady_mse, surrogate) and constant gains (N, n, m)."""

    spec: "NetworkEstimator"
    network: Network
    config: Any = None
    reason: str = ""
    exact_reason: str = ""
    tuning: dict[str, Any] = field(default_factory=dict)
    gains: np.ndarray | None = None

    @property
    def name(self) -> str:
        return self.spec.name

    @property
    def applies(self) -> bool:
        return not self.reason

    @property
    def exact(self) -> bool:
        """Its exact mean second moments are computed."""
        return self.applies and self.spec.exact is not None and not self.exact_reason

    def build(self, trials: int, peers: Mapping[str, BatchedFilter]) -> BatchedFilter:
        """The filter for `trials` trials; `peers`: the filters already built for the same trials."""
        return self.spec.build(self, trials, peers)

    def exact_moments(self) -> dict[str, np.ndarray]:
        """``blocks`` (K, W, n, n) E[e_i e_iᵀ], ``mse`` (K, W), and where defined ``disagreement`` (K,) and
        ``own_cov`` (K, W, n, n), the filter's own covariance."""
        return self.spec.exact(self, self.network.steps)

    def communication(self) -> Communication:
        return self.spec.communication(self.network.links, self.network.model.n)

    def trialwise_covariance(self) -> bool:
        return self.spec.trialwise_covariance(self.network.links)


def _everywhere(links: "LinkModel") -> str:
    return ""


def _no_search(est: DesignedEstimator) -> None:
    return None


def _silent(links: "LinkModel", n: int) -> Communication:
    return SILENT


def _never(links: "LinkModel") -> bool:
    return False


@dataclass(frozen=True, eq=False)
class NetworkEstimator:
    """The one declaration of an estimator.

    - `name` (its id in scenario files and tables), `title`, `rank` (its place in tables and figures);
    - `build(designed, trials, peers)`: its `BatchedFilter` for a batch of trials;
    - `applies(links)`: "" when it applies to the link model, else why not;
    - `design(designed)`: fills in the `DesignedEstimator` (config, gain tuning, applicability found by
      the design, why there are no exact moments);
    - `exact(designed, K)`: its exact moments (`DesignedEstimator.exact_moments`), None when it has none;
    - `communication(links, n)`: what it sends;
    - `cost_weight`: its relative CPU time per step (50 nodes, 4 states, random links), to balance workers;
      `trialwise_covariance(links)`: it keeps a covariance per node and trial (memory and time);
      `per_exchange`: it works at every Poisson exchange;
    - `joint_moments`: a linear network filter with gains that do not depend on the data, whose exact
      moments come from the joint recursion of the stacked errors (their agreement with the simulation is
      a claim); the centralized and local filters' moments are their own Riccati covariances instead;
    - `swaps`: it exchanges whole filter states along the step's random matching (the harness draws that
      matching once for every such filter); `shares_with`: the estimator whose recursion it reuses when
      both run (kept in the same worker, built after it); `reference`: the estimator every other is
      compared with (distances, orthogonality); it always runs;
    - `covariance_law`: what its own covariance is, for the NEES claims: "conditional" (its error's covariance
      given the link draws, so the NEES sum is χ²), "bound" (an upper bound), None (no such claim);
    - `plugin`: a researcher's filter run through `dse.plugin` (its faults are its own, `PluginFault`);
      `true_coordinates`: it runs on the true measurements, not in error coordinates (the harness then calls
      its filter's `track(x)` with the true state (n, B) before each step); `code`: its code's hash for the
      stage keys (a plug-in's module and the harness), instead of `source_module`'s."""

    name: str
    title: str
    rank: float
    build: Callable[[DesignedEstimator, int, Mapping[str, BatchedFilter]], BatchedFilter]
    applies: Callable[["LinkModel"], str] = _everywhere
    design: Callable[[DesignedEstimator], None] = _no_search
    exact: Callable[[DesignedEstimator, int], dict[str, np.ndarray]] | None = None
    communication: Callable[["LinkModel", int], Communication] = _silent
    cost_weight: float = 5.0
    trialwise_covariance: Callable[["LinkModel"], bool] = _never
    per_exchange: bool = False
    joint_moments: bool = False
    swaps: bool = False
    shares_with: str | None = None
    reference: bool = False
    covariance_law: str | None = None
    plugin: bool = False
    true_coordinates: bool = False
    module: str = ""
    code: str = ""

    @property
    def source_module(self) -> str:
        """The module that declares it (set by the registry; else the module of `build`)."""
        return self.module or self.build.__module__

    def key(self) -> dict[str, str]:
        """What it contributes to a stage's cache key: its name and the source of its module and of every
        project module that one imports."""
        return {"estimator": self.name, "code": self.code or source_hash(self.source_module)}


def source_hash(module: str) -> str:
    """Hash of a module's code: a project module with everything it imports (`code_hash`), any other
    (a test's or a third party's estimator) by its own source."""
    from dse.contract.stages import code_hash, module_file

    if module_file(module) is not None:
        return code_hash(module)
    return hashlib.sha256(inspect.getsource(sys.modules[module]).encode()).hexdigest()[:16]
