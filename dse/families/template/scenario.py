"""The template family's scenario file, declared once: a constant θ measured once by every node,
y_i = θ + v_i with v_i ~ N(0, r), then `rounds` rounds of average consensus x(t+1) = W x(t) over
the graph with Metropolis weights W (symmetric, doubly stochastic), starting from x(0) = y.

Every key is declared here with its type, default, bounds, unit and meaning; docs/scenarios.md is
generated from these declarations, and an invalid value is one error naming its key. Derived
quantities are cached properties of the validated model (no second declaration of the scenario).
"""
from __future__ import annotations

from functools import cached_property

import numpy as np
from pydantic import model_validator

from dse.scenario.declare import Real, ScenarioFile, Section, computed_default, key, name_key
from dse.scenario.graphs import GraphSection, GraphSpec, graph_from_section, metropolis_weights


class ModelSection(Section):
    """The measurement y_i = θ + v_i of every node and the consensus rounds that follow it."""

    r: Real = key(doc="variance of each node's measurement noise v_i", unit="θ²", gt=0)
    rounds: int = key(20, doc="consensus rounds t = 1..rounds after the measurement", ge=1, le=10_000)


class MonteCarloSection(Section):
    """Independent trials (draws of the noises v), in seeded units of 1,000."""

    trials: int = key(10_000, doc="Monte Carlo trials", ge=100, le=10_000_000)

    @computed_default
    def _quick(data):
        """min(trials, 2000)"""
        return min(data["trials"], 2000)

    quick_trials: int = key(_quick, doc="trials in a --quick run", ge=100, le=10_000_000)


class ConsensusFile(ScenarioFile):
    """A template scenario file: one measurement per node, then average consensus."""

    unkeyed = {"name": True, "monte_carlo": True}

    name: str = name_key()
    graph: GraphSection = key(doc="the communication graph (a disconnected one is accepted: connectivity is "
                                  "the hypothesis `connected`)")
    model: ModelSection = key(doc="the measurement and the consensus rounds")
    monte_carlo: MonteCarloSection = key(MonteCarloSection, doc="the Monte Carlo simulation")

    @model_validator(mode="after")
    def _graph(self):
        self.network                     # a graph of fewer than two nodes: one error naming graph.<key>
        return self

    @cached_property
    def network(self) -> GraphSpec:
        return graph_from_section(self.graph, "graph", connected=False, min_nodes=2)

    @cached_property
    def W(self) -> np.ndarray:
        """The Metropolis consensus weights w_ij = 1/(1 + max(d_i, d_j)) on the edges."""
        return metropolis_weights(self.network)

    @property
    def n(self) -> int:
        return self.network.n
