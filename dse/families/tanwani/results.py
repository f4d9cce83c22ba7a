"""What the claims, tables and views of a random-comm-filter run read: per scenario its design, the
exact references of the checks and the three Monte Carlo stages; the topology sweep of the paper run;
and which scenario is the run's main one (the errata and Fig. 1 are drawn on it)."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

import dse.estimators.gossip_filter as gf
from dse.simulate.matrix_moments import MatrixMoments

from .design import Design, ScenarioDesign
from .scenario import RandomCommFile


@dataclass
class ScenarioResults:
    scenario: RandomCommFile
    design: ScenarioDesign
    refs: dict[str, np.ndarray]
    gridded: dict[float, dict[str, np.ndarray]]
    event: dict[str, np.ndarray]
    frozen: dict[str, np.ndarray]
    trials: int
    event_trials: int
    #: the design arrays and the references of the checks, in one dict
    bounds: dict[str, np.ndarray] = field(default_factory=dict)

    def __post_init__(self):
        if not self.bounds:
            self.bounds = {**self.design.bounds, **self.refs}

    @property
    def sys(self) -> gf.GossipSystem:
        return self.scenario.gossip

    def grid_moments(self, rate: float) -> MatrixMoments:
        return MatrixMoments.from_arrays(self.gridded[rate], "e_")

    def event_moments(self) -> MatrixMoments:
        return MatrixMoments.from_arrays(self.event, "e_")

    def frozen_moments(self) -> MatrixMoments:
        return MatrixMoments.from_arrays(self.frozen, "e_")

    def bound(self, rate: float) -> np.ndarray:
        return self.bounds[f"bound_t_{self.scenario.rates.index(rate)}"]

    def joint(self, rate: float) -> np.ndarray | None:
        return self.bounds.get(f"joint_t_{self.scenario.rates.index(rate)}")


@dataclass
class Results:
    scenarios: dict[str, ScenarioResults]
    #: the run's main scenario (role "main": S2 in the paper's reproduction, the scenario of a user's run)
    main: str
    #: the topology sweep S4 (the paper's reproduction only)
    topology: dict[str, np.ndarray] | None = None

    def design(self) -> Design:
        return Design({name: r.design for name, r in self.scenarios.items()})
