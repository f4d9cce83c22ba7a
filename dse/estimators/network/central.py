"""The centralized Kalman filter: every measurement at one place, the reference of the arena.

On the stacked model H = [H_0; …; H_{N−1}], R = diag(R_i) (`sensor_network.SensorNetworkModel.H_all`,
`R_all`), with the gains and covariances of `dse.estimators.kalman`:

    x̂(k|k) = x̄(k) + K(k) (y(k) − H x̄(k)),    x̄(k+1) = F x̂(k|k).

Its estimate is E[x(k) | every measurement up to k], so its error P(k|k) is the smallest of any estimator
(the `compare.central.*` claims). It sends nothing: collecting every measurement is not a network protocol.
"""
from __future__ import annotations

import numpy as np

from dse.estimators.protocol import NetworkEstimator, BatchedFilter


class CentralizedKalman(BatchedFilter):
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


def filterpy_differences(m, K: int, trials: int = 3, seed: int = 12345) -> dict[str, np.ndarray]:
    """The filter against filterpy's KalmanFilter (an independent implementation) on `trials` simulated
    trials of K steps: the largest differences of the estimates (dx) and covariances (dP), the largest
    entries of filterpy's (sx, sP), K, and the condition of the first innovation covariance."""
    from filterpy.kalman import KalmanFilter

    from dse.estimators.network_step import StepContext

    rng = np.random.default_rng(seed)
    B = trials
    x = m.x0[:, None] + np.linalg.cholesky(m.P0) @ rng.standard_normal((m.n, B))
    lam, V = np.linalg.eigh(m.Q)
    Lq = V * np.sqrt(np.maximum(lam, 0))
    c = CentralizedKalman(m, K, B)
    kfs = []
    for b in range(B):
        kf = KalmanFilter(dim_x=m.n, dim_z=m.N * m.m)
        kf.F, kf.H, kf.Q, kf.R = m.F, m.H_all, m.Q, m.R_all
        kf.P, kf.x = m.P0.copy(), m.x0.copy()
        kfs.append(kf)
    dx = dP = sx = sP = 0.0
    for k in range(K):
        y = np.einsum("imn,nb->imb", m.H, x) + np.einsum("iab,ibc->iac", m.R_chol, rng.standard_normal((m.N, m.m, B)))
        est = c.step(StepContext(k, y, None))[0]
        for b, kf in enumerate(kfs):
            kf.update(y[:, :, b].reshape(-1))
            dx = max(dx, float(np.abs(est[:, b] - kf.x).max()))
            dP = max(dP, float(np.abs(c.P_post[k] - kf.P).max()))
            sx = max(sx, float(np.abs(kf.x).max()))
            sP = max(sP, float(np.abs(kf.P).max()))
            kf.predict()
        x = m.F @ x + Lq @ rng.standard_normal((m.n, B))
    cond = float(np.linalg.cond(m.H_all @ m.P0 @ m.H_all.T + m.R_all))
    return {"dx": np.array(dx), "dP": np.array(dP), "sx": np.array(sx), "sP": np.array(sP), "steps": np.array(K),
            "cond": np.array(cond)}


def exact(est, K: int) -> dict[str, np.ndarray]:
    cov = est.network.model.central_covariances(K)
    return {"blocks": cov.P_post[:, None], "mse": np.trace(cov.P_post, axis1=1, axis2=2)[:, None]}


ESTIMATOR = NetworkEstimator(
    name="central", title="centralized KF", rank=0, reference=True, exact=exact, cost_weight=0.5,
    covariance_law="conditional",
    build=lambda est, B, peers: CentralizedKalman(est.network.model, est.network.steps, B))
