"""Tanwani's constant-gain filters with pairwise averaging, (5)-(6), in discrete time (`constant_gain_fusion`,
rule "pairwise"): the local correction with ℓ·G_i (`gains.pairwise_scale`, 1: Tanwani's split gains), then
at every exchange the active nodes move to x̂_i + α Σ_{j active} (x̂_j − x̂_i), Π = I − α L (3), α =
`weights.alpha`. Poisson exchanges apply it one pair at a time in time order; a synchronous round lets every
working link exchange at once. Sends n numbers per exchange and direction.
"""
from __future__ import annotations

from dse.estimators.network._constant_gain import base_gains, build, communication, exact, finish
from dse.estimators.protocol import NetworkEstimator


def design(est) -> None:
    G, why = base_gains(est.network)
    if G is None:
        est.reason = why
        return
    finish(est, "pairwise", est.network.scenario.gains.pairwise_scale)


ESTIMATOR = NetworkEstimator(
    name="pairwise", title="pairwise averaging (Tanwani)", rank=50, design=design, build=build, exact=exact,
    communication=communication, joint_moments=True, per_exchange=True)
