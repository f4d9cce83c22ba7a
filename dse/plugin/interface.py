"""What a researcher's distributed filter implements to run in the compare arena, and what it is given.

The setting: a plant seen by the N nodes of a graph,

    x(k+1) = F x(k) + w(k),   w ~ N(0, Q),   x(0) ~ N(x0, P0),
    y_i(k) = H_i x(k) + v_i(k),   v_i ~ N(0, R_i),

whose links deliver, in each step, what the scenario's link model draws: synchronous rounds of working
links (reliable, independent failures, random matchings) or Poisson-clocked pairwise exchanges in time
order, with optional communication noise of standard deviation σ_c.

A filter is a subclass of `NetworkFilter`, batched over Monte Carlo trials (trials on the last axis of
every array). It is constructed once per batch, `NetworkFilter(problem, params, trials)`, and at every step
k = 0, 1, ... its `step(k, y, network)` receives the measurements y(k) (N, m, B) and returns x̂_i(k|k)
(N, n, B), every node's estimate of x(k) after the step's communication. Between steps it predicts on its
own (x̄_i(k+1) = F x̂_i(k|k) for a Kalman-like filter).

Nodes talk only through `network.exchange(payload)`: every node broadcasts its row of `payload` (N, s, B)
(s real numbers) to its neighbours, and the returned `Inbox` holds what the link model delivered to each
node in that communication: the neighbours' messages over working links, which of them arrived, and the
communication noise. A filter never reads another node's variables directly. How many exchanges a step
allows and how wide a message may be is what the filter declares in `sends` (a `Messages`); the harness
counts the messages and the real numbers actually sent (per node and step: the node's working links in
each exchange times the message's width), and stops a filter that sends more than it declared.

Communication noise, the convention of every built-in filter (Savas, Srivastava & Leonard 2017, (6)): a
node that fused what it heard in an exchange has its fused state estimate corrupted by an independent
N(0, σ_c² I_n) vector. `Inbox.noise` is that vector (σ_c already applied; zero at nodes that heard nothing),
drawn from the same random numbers the built-in filters use; the filter adds it to the state estimate it
fuses (matrices and measurements travel without noise). With σ_c = 0 it is zero.

Optional members: `covariance()` (the filter's own covariance of x̂_i, for the NEES checks), `shift(delta)`
(for filters declared `equivariant`, which the harness then runs in error coordinates, as the built-ins),
`matrices(k)` (for filters declared `linear`: their exact second moments are then computed and checked
against the simulation).
"""
from __future__ import annotations

from dataclasses import dataclass
from abc import ABC, abstractmethod
from typing import ClassVar, Literal, Protocol

import numpy as np
from pydantic import BaseModel, ConfigDict

__all__ = ["Messages", "Problem", "Inbox", "Network", "LinearStep", "NetworkFilter", "NoParameters"]


@dataclass(frozen=True)
class Messages:
    """What a filter sends: messages of `scalars` real numbers, one from a node to each neighbour it
    reaches in an exchange; `exchanges` exchanges `per` "round" (in each synchronous round of the step, or
    at each Poisson exchange) or "step" (over the step's links: the first round's, or every link that rang
    during the step). The communication noise is drawn once per round (per step), the same in each of its
    exchanges."""

    scalars: int
    per: Literal["round", "step"] = "round"
    exchanges: int = 1

    def __post_init__(self):
        for key in ("scalars", "exchanges"):
            value = getattr(self, key)
            if not (isinstance(value, (int, np.integer)) and not isinstance(value, bool) and value >= 1):
                raise ValueError(f"Messages.{key} must be a positive integer, got {value!r}")
        if self.per not in ("round", "step"):
            raise ValueError(f"Messages.per must be 'round' or 'step', got {self.per!r}")


class NoParameters(BaseModel):
    """A filter without parameters: its scenario table accepts no key besides `factory`."""

    model_config = ConfigDict(extra="forbid", frozen=True)


@dataclass(frozen=True, eq=False)
class Problem:
    """What a filter is built for (read-only arrays).

    Plant and sensors: F (n, n), Q (n, n), P0 (n, n), x0 (n,), H (N, m, n), R (N, m, m) (a node with fewer
    than m measurement rows has zero rows of unit noise, which carry no information). Graph: `neighbours`
    (N, D) the ids of each node's neighbours, padded with −1 (D the largest degree), `weights` (N, D) the
    scenario's consensus weights q_ij on those links (0 on padding; 1 − Σ_j q_ij stays with the node),
    `degrees` (N,), `edges` (E, 2). Links: `link_model` ("reliable", "failures", "matchings", "poisson"),
    `rounds` (synchronous rounds per step), `noise_std` σ_c. Horizon: `steps`."""

    F: np.ndarray
    Q: np.ndarray
    P0: np.ndarray
    x0: np.ndarray
    H: np.ndarray
    R: np.ndarray
    neighbours: np.ndarray
    weights: np.ndarray
    degrees: np.ndarray
    edges: np.ndarray
    link_model: str
    rounds: int
    noise_std: float
    steps: int

    @property
    def N(self) -> int:
        return self.H.shape[0]

    @property
    def n(self) -> int:
        return self.F.shape[0]

    @property
    def m(self) -> int:
        return self.H.shape[1]

    @property
    def synchronous(self) -> bool:
        return self.link_model != "poisson"


@dataclass(frozen=True, eq=False)
class Inbox:
    """What one exchange delivered, for B trials: `values` (N, D, s, B) the message of neighbour
    `Problem.neighbours[i, d]` where it arrived (0 elsewhere), `delivered` (N, D, B) bool, `heard` (N, B)
    bool (at least one message arrived), `noise` (N, n, B) the communication noise of the node's fused state
    estimate (module doc). Read-only."""

    values: np.ndarray
    delivered: np.ndarray
    heard: np.ndarray
    noise: np.ndarray

    @property
    def count(self) -> np.ndarray:
        """(N, B) how many messages each node received."""
        return self.delivered.sum(axis=1)

    def total(self) -> np.ndarray:
        """(N, s, B) Σ over the messages each node received."""
        return self.values.sum(axis=1)

    def weighted(self, weights: np.ndarray) -> np.ndarray:
        """(N, s, B) Σ_d weights[i, d] · message of neighbour d, over the messages that arrived."""
        return np.einsum("id,idsb->isb", weights, self.values)


class Network(Protocol):
    """One step's communication as a filter sees it: `k`, `exchanges` (how many `exchange` calls the step
    allows under the filter's declaration), and `exchange(payload)` (`dse.plugin.harness.StepNetwork`)."""

    k: int
    exchanges: int

    def exchange(self, payload: np.ndarray) -> Inbox:
        """Broadcast row i of `payload` (N, s, B) from node i to its neighbours; return what arrived."""
        ...


@dataclass(frozen=True)
class LinearStep:
    """One step of a linear filter in error coordinates (`NetworkFilter.matrices`): with ē(k) (N n) the
    stacked errors of the predictions, v(k) (N m) the stacked measurement noises and ξ(k) the stacked
    communication noises of the step's exchanges (`Inbox.noise`, N n per exchange, divided by σ_c),

        ê(k) = A ē(k) + B v(k) + σ_c C ξ(k),      ē(k+1) = (I ⊗ F) ê(k) − 1 ⊗ w(k),

    A (N n, N n), B (N n, N m), C (N n, exchanges · N n) or None without communication noise. The filter
    must be unbiased: A (1 ⊗ I_n) + B (H_0; ...; H_{N−1}) = 1 ⊗ I_n (checked)."""

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray | None = None


class NetworkFilter(ABC):
    """Base class of a researcher's distributed filter (module doc). Declare:

    - `title`: one line for tables and figures;
    - `Parameters`: a pydantic model of its parameters (the keys of its scenario table: type, default,
      bounds and meaning in one place); `NoParameters` by default;
    - `sends(problem, params)` (classmethod): its `Messages`, or None for a filter that sends nothing;
    - `linear` (True: it also implements `matrices`), `equivariant` (True: adding c to the state, to its
      prediction and to every estimate adds c to every later estimate; it then implements `shift` and runs
      in error coordinates, as the built-ins do; False: it runs on the true measurements),
      `covariance_law`: "conditional" when `covariance()` is its error's covariance given the link draws
      (Kalman-like), "bound" when it bounds it (covariance intersection), None when it reports none;
    - `cost_weight`: its CPU time per step relative to a local Kalman filter on every node (to balance the
      workers and estimate the run's time); `per_trial_matrices`: it keeps n x n matrices per node and trial
      (gains that depend on the link draws), which the memory estimate then counts;
    - `link_models` (optional): the link models it runs on (by default all four); on another it is reported
      as not applicable.

    Implement `__init__(problem, params, trials)` and `step(k, y, network)`; and, as declared,

    - `shift(delta)` (equivariant filters): add delta (n, B) to every node's prediction of the next state;
    - `matrices(k)` (linear filters): the `LinearStep` of step k on reliable links, computed without data
      (called on a filter built for one trial, for k = 0, 1, ... in order, without `step`)."""

    title: ClassVar[str] = ""
    Parameters: ClassVar[type[BaseModel]] = NoParameters
    linear: ClassVar[bool] = False
    equivariant: ClassVar[bool] = False
    covariance_law: ClassVar[str | None] = None
    cost_weight: ClassVar[float] = 5.0
    per_trial_matrices: ClassVar[bool] = False

    def __init__(self, problem: Problem, params: BaseModel, trials: int):
        self.problem, self.params, self.trials = problem, params, trials

    @classmethod
    def sends(cls, problem: Problem, params: BaseModel) -> Messages | None:
        """What it sends (None: nothing)."""
        return None

    @abstractmethod
    def step(self, k: int, y: np.ndarray, network: Network) -> np.ndarray:
        """x̂_i(k|k) (N, n, B) from the measurements y(k) (N, m, B) and what `network.exchange` delivers."""

    def covariance(self) -> np.ndarray | None:
        """Its own covariance of the last step's estimates, (N, n, n) shared by the trials or (N, n, n, B);
        None when it has none."""
        return None
