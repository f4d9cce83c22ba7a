"""The deterministic design of a compare scenario: every registered estimator designed for it (whether it
applies to the link model and why not, its gains tuned where asked, whether its exact moments are
computed; `dse.estimators.network`), and the numbers the hypotheses are decided by (detectability, the
GIKF's mean communication). No Monte Carlo: `dse check` computes it alone.

The estimators' searches (gain scales, steady states) are the design stage (`stages.tune`); the design is
rebuilt from their numbers wherever a stage needs it.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import Any, Mapping, Sequence

import numpy as np

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

    @property
    def topology(self):
        return self.network.links.topology

    @property
    def weights(self) -> np.ndarray:
        return self.network.weights

    @property
    def tuned(self) -> dict[str, float]:
        return self.network.tuned

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
        """What the hypotheses are decided by. C.1: the GIKF's token moves along the edges of the graph and
        stays put with positive probability when the link model allows it: irreducible because the graph
        is connected, aperiodic with an odd cycle or a self-loop. D.1: the Gramian along a covering walk
        (depth first, staying n steps at each node when self-loops are possible) repeated n times."""
        from dse.estimators.sensor_network import observable, stabilizable, walk_gramian_ratio

        m, links = self.model, self.links
        loops, why = links.stay_witness()
        bipartite = links.topology.is_bipartite()
        walk = links.topology.covering_walk(stay=m.n if loops else 1) * m.n
        ratio = walk_gramian_ratio(m, walk)
        observable_ = observable(m.F, m.H_all)
        return {"local_detectable": m.locally_detectable(), "collective_detectable": m.collectively_detectable(),
                "collective_observable": observable_, "stabilizable": stabilizable(m.F, m.Q),
                "c1": True if (not bipartite or loops) else (None if loops is None else False),
                "c1_detail": "the graph is connected (irreducible) and " + (
                    "has an odd cycle (aperiodic)" if not bipartite else f"bipartite; self-loops: {why}"),
                "d1_ratio": ratio, "d1_walk_length": len(walk),
                "d1": True if ratio > 1e-10 else (False if not observable_ else None)}


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
