"""The gossip interactive Kalman filter (Kar & Moura (8)-(10)): the nodes matched in a step swap their whole
filter states, then each corrects the state it holds with its own measurement (`gossip_swap_kalman`).

It applies to every link model: the swaps are the link model's own matching, the random greedy maximal
matching of the working links, or, with Poisson exchanges, one transposition per exchange in time order.
Its covariance is the exact conditional covariance given the swap path, so its NEES has an exact χ² law;
the mean over swap paths has no closed form. Sends, per swapped link and direction, the estimate and the
covariance: n + n(n+1)/2 numbers.
"""
from __future__ import annotations

from dse.estimators.protocol import Communication, NetworkEstimator


def build(est, B: int, peers):
    from dse.estimators.gossip_swap_kalman import GossipSwapRun

    return GossipSwapRun(est.network.model, est.network.links, B)


def design(est) -> None:
    est.exact_reason = ("its covariance is exact given the swap path (the NEES law checks it trial by trial); the "
                        "mean over swap paths has no closed form (Monte Carlo)")


ESTIMATOR = NetworkEstimator(
    name="gikf", title="GIKF (Kar & Moura)", rank=20, build=build, design=design, cost_weight=18, swaps=True,
    covariance_law="conditional",
    communication=lambda links, n: Communication("swap", 1, n + n * (n + 1) // 2),
    trialwise_covariance=lambda links: True, per_exchange=True)
