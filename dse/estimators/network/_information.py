"""What the three information filters (kcf, diffusion, ci) share as estimators of the arena
(`information_fusion`): their design on the scenario's links and consensus weights, construction and exact
moments. The algorithm module is imported on first use, so that scanning the registry stays light.
"""
from __future__ import annotations


def design_on(est, kind: str, epsilon: float = 0.1) -> None:
    """Design a `DesignedEstimator` as the filter of `kind`; its exact moments exist with every link working,
    within the size of the joint recursion."""
    from dse.estimators.information_fusion import InformationFilter

    net = est.network
    est.config = InformationFilter(net.model, net.links, kind, net.weights, epsilon)
    ok, why = est.config.exact_available
    est.exact_reason = why if not ok else net.joint_size_reason()


def build(est, B: int, peers, twin: str | None = None):
    """The filter for B trials; `twin`: the peer whose covariance recursion it reuses (when built)."""
    from dse.estimators.information_fusion import InformationRun

    return InformationRun(est.config, B, twin=peers.get(twin) if twin else None)


def exact(est, n_steps: int):
    from dse.estimators.information_fusion import exact_moments

    return exact_moments(est.config, n_steps)


def trialwise(links) -> bool:
    """With random links the gains depend on which links worked: a covariance per node and trial."""
    return links.random
