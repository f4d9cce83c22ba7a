"""The centralized Kalman filter: every measurement at one place, the reference of the arena.

On the stacked model H = [H_0; …; H_{N−1}], R = diag(R_i) (`sensor_network.SensorNetworkModel.H_all`,
`R_all`), with the gains and covariances of `dse.estimators.kalman`:

    x̂(k|k) = x̄(k) + K(k) (y(k) − H x̄(k)),    x̄(k+1) = F x̂(k|k).

Its estimate is E[x(k) | every measurement up to k], so its error P(k|k) is the smallest of any estimator
(the `compare.central.*` claims). It sends nothing: collecting every measurement is not a network protocol.
"""
from __future__ import annotations

import numpy as np

from dse.estimators.protocol import NetworkEstimator, NetworkFilter


class CentralizedKalman(NetworkFilter):
    """B trials; one estimate (W = 1), covariances shared by the trials."""

    def __init__(self, model, K: int, B: int):
        self.model = model
        cov = model.central_covariances(K)
        self.gains, self.P_post = cov.gains, cov.P_post
        self.P_inv = np.linalg.inv(cov.P_post)
        self.xbar = np.broadcast_to(model.x0[:, None], (model.n, B)).copy()
        self.k = 0

    def step(self, ctx) -> np.ndarray:
        m = self.model
        y = ctx.y.reshape(-1, ctx.y.shape[-1])
        est = self.xbar + self.gains[ctx.k] @ (y - m.H_all @ self.xbar)
        self.xbar = m.F @ est
        self.k = ctx.k
        self.estimate = est[None]
        return self.estimate

    def shift(self, delta: np.ndarray) -> None:
        self.xbar = self.xbar + delta

    def nees(self, err: np.ndarray) -> np.ndarray:
        return np.einsum("inb,nm,imb->ib", err, self.P_inv[self.k], err)


def exact(est, K: int) -> dict[str, np.ndarray]:
    cov = est.network.model.central_covariances(K)
    return {"blocks": cov.P_post[:, None], "mse": np.trace(cov.P_post, axis1=1, axis2=2)[:, None]}


ESTIMATOR = NetworkEstimator(
    name="central", title="centralized KF", rank=0, reference=True, exact=exact, cost_weight=0.5,
    build=lambda est, B, peers: CentralizedKalman(est.network.model, est.network.steps, B))
