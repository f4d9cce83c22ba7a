"""What the stages of a gossip-kalman run give the hypotheses, the claims and the tables: per
scenario its design (sizes, hypotheses, the `bounds` stage) and its Monte Carlo samples; and the
sizes of a run (runs, Theorem-8 runs, horizon, record times) from the scenario and the options.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from dse.contract.options import RunOptions

from .assumptions import Assumptions
from .scenario import GossipKalmanFile

#: horizons of the pull-back's law (Lemma 23): the Theorem-8 process records them too
PULLBACK_LAW_T = (5, 20, 100)


def sizes(sc: GossipKalmanFile, opts: RunOptions) -> tuple[int, int, int]:
    """(GIKF runs, Theorem-8 runs, horizon) of a run, before the horizon is cut where a class diverges."""
    sim = sc.simulation
    runs = opts.trials if opts.trials is not None else (sim.quick_runs if opts.quick else sim.runs)
    ref = sim.quick_reference_runs if opts.quick else sim.reference_runs
    if opts.trials is not None:
        ref = max(ref, runs)
    return runs, ref, sim.quick_slots if opts.quick else sim.slots


def record_times(sc: GossipKalmanFile, slots: int) -> list[int]:
    """The slots at which every run's covariance features are kept: the scenario's, the horizon, the pull-back's."""
    return sorted({t for t in sc.simulation.record_times if t <= slots} | {slots}
                  | {t for t in PULLBACK_LAW_T if t <= slots})


@dataclass
class ScenarioDesign:
    """The deterministic quantities of one scenario (no Monte Carlo): the hypotheses' decisions
    (`assume`) and the `bounds` stage (Ā, spectra, witness walks and the constants of the bounds, the
    centralized filter, the class floors, the Lyapunov envelope)."""

    scenario: GossipKalmanFile
    slots: int
    runs: int
    reference_runs: int
    quick: bool
    bounds: dict[str, np.ndarray]

    @property
    def name(self) -> str:
        return self.scenario.name

    @property
    def assume(self) -> Assumptions:
        return self.scenario.assumptions

    @property
    def c1(self) -> bool:
        return bool(self.bounds["c1"])

    @property
    def d1(self) -> bool:
        """D.1 holds (decided); False when it fails or cannot be decided."""
        return bool(self.bounds["d1"])

    def witness(self) -> tuple[int, ...] | None:
        w = self.bounds["witness"]
        return tuple(int(x) for x in w) if len(w) else None


@dataclass
class ScenarioResults(ScenarioDesign):
    """A scenario's design and its Monte Carlo samples: the GIKF runs (`gikf`, and `comparison` under the second
    protocol), the Theorem-8 process (`reference`), the auxiliary samples of the theorem's conclusions and of
    Theorem 26(a) (`aux`), and the Riccati sequences of eq (74) (`eq74`, on the scenarios with the structural
    checks)."""

    seed: int = 0
    gikf: dict[str, np.ndarray] = field(default_factory=dict)
    reference: dict[str, np.ndarray] = field(default_factory=dict)
    aux: dict[str, np.ndarray] = field(default_factory=dict)
    comparison: dict[str, np.ndarray] | None = None
    eq74: dict[str, np.ndarray] | None = None

    def design(self) -> ScenarioDesign:
        return ScenarioDesign(self.scenario, self.slots, self.runs, self.reference_runs, self.quick, self.bounds)


@dataclass
class Design:
    """The design of every scenario of a run (what `dse check` computes; hypotheses evaluate on it)."""

    quick: bool
    scenarios: dict[str, ScenarioDesign]

    def get(self, name: str) -> ScenarioDesign | None:
        return self.scenarios.get(name)


@dataclass
class Results:
    seed: int
    quick: bool
    scenarios: dict[str, ScenarioResults]

    def get(self, name: str) -> ScenarioResults | None:
        return self.scenarios.get(name)

    def design(self) -> Design:
        return Design(self.quick, {k: r.design() for k, r in self.scenarios.items()})
