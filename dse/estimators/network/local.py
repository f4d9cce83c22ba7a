"""Local Kalman filters: every node filters its own measurements and sends nothing (the arena's floor).

Node i runs `dse.estimators.kalman` on (F, H_i, Q, R_i); its error is bounded only where (F, H_i) is
detectable (`compare.hyp.local_detectability`).
"""
from __future__ import annotations

import numpy as np

from dse.estimators.network_step import apply_gain, innovation, predict
from dse.estimators.protocol import NetworkEstimator, NetworkFilter


class LocalKalman(NetworkFilter):
    """B trials of N independent Kalman filters; covariances shared by the trials."""

    def __init__(self, model, K: int, B: int):
        self.model = model
        covs = model.local_covariances(K)
        self.gains = np.stack([c.gains for c in covs], axis=1)          # (K, N, n, m)
        self.P_post = np.stack([c.P_post for c in covs], axis=1)        # (K, N, n, n)
        self.P_inv = np.linalg.inv(self.P_post)
        self.xbar = np.broadcast_to(model.x0[None, :, None], (model.N, model.n, B)).copy()
        self.k = 0

    def step(self, ctx) -> np.ndarray:
        m = self.model
        est = self.xbar + apply_gain(self.gains[ctx.k], innovation(ctx.y, m.H, self.xbar))
        self.xbar = predict(m.F, est)
        self.k = ctx.k
        self.estimate = est
        return est

    def shift(self, delta: np.ndarray) -> None:
        self.xbar = self.xbar + delta[None]

    def nees(self, err: np.ndarray) -> np.ndarray:
        return np.einsum("inb,inm,imb->ib", err, self.P_inv[self.k], err)


def exact(est, K: int) -> dict[str, np.ndarray]:
    blocks = np.stack([c.P_post for c in est.network.model.local_covariances(K)], axis=1)
    return {"blocks": blocks, "mse": np.einsum("kiaa->ki", blocks)}


ESTIMATOR = NetworkEstimator(
    name="local", title="local KF (no communication)", rank=10, exact=exact, cost_weight=1,
    build=lambda est, B, peers: LocalKalman(est.network.model, est.network.steps, B))
