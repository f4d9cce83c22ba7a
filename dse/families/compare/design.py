"""The deterministic design of a compare scenario: every registered estimator designed for it (whether it
applies to the link model and why not, its gains tuned where asked, whether its exact moments are
computed; `dse.estimators.network`), and the numbers the hypotheses are decided by (detectability, the
GIKF's mean communication). No Monte Carlo: `dse check` computes it alone. The estimators' searches are the
design stage (`stages.tune`); the design is rebuilt from their numbers wherever a stage needs it.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import Any, Mapping, Sequence

from dse.estimators.protocol import DesignedEstimator, Network, NetworkEstimator

from .scenario import CompareFile

NOT_REQUESTED = "not requested (dse.estimators.include)"


@dataclass(eq=False)
class Design:
    scenario: CompareFile
    network: Network
    estimators: dict[str, DesignedEstimator]      # every registered estimator, applicable or not
    specs: tuple[NetworkEstimator, ...]
    tuning_stage: Any = None                      # the design stage's result (what later stages are keyed by)

    @property
    def model(self):
        return self.network.model

    @property
    def links(self):
        return self.network.links

    @cached_property
    def running(self) -> dict[str, DesignedEstimator]:
        """The estimators that apply, in the registry's order."""
        return {name: est for name, est in self.estimators.items() if est.applies}

    @property
    def gains(self) -> dict[str, dict[str, Any]]:
        """name -> scale, zeta, rho, steady_mse, surrogate of every running estimator with tuned gains."""
        return {name: est.tuning for name, est in self.running.items() if est.tuning}

    @cached_property
    def numbers(self) -> dict[str, Any]:
        """What the hypotheses are decided by: detectability of the nodes and of the network, and Kar & Moura's
        conditions for the GIKF's weak consensus (`gossip_swap_kalman.weak_consensus_conditions`)."""
        from dse.estimators.gossip_swap_kalman import weak_consensus_conditions

        m = self.model
        return {"local_detectable": m.locally_detectable(), "collective_detectable": m.collectively_detectable(),
                **weak_consensus_conditions(m, self.links)}


def design_of(sc: CompareFile, quick: bool, tuned: Mapping[str, float], specs: Sequence[NetworkEstimator]) -> Design:
    """Every estimator of `specs` designed for the scenario; `tuned` holds the numbers of searches already
    made (the design stage's), the others are searched (coarser grids when `quick`)."""
    net = Network(sc.model, sc.link_model, sc.edge_weights, sc.simulation.steps, sc.simulation.exact_max_dimension,
                  sc, quick, dict(tuned))
    out = {}
    for spec in specs:
        est = DesignedEstimator(spec, net)
        est.reason = NOT_REQUESTED if spec.name not in sc.estimator_names else spec.applies(net.links)
        if est.applies:
            spec.design(est)
        out[spec.name] = est
    return Design(sc, net, out, tuple(specs))
