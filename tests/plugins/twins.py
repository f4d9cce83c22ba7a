"""Filters written against the public protocol only (`dse.plugin`) that are algebraically identical to built-in
estimators, and one that is deliberately biased."""
from __future__ import annotations

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from dse.plugin import LinearStep, Messages, NetworkFilter


def local_gains(problem):
    """(K, N, n, m) gains and (K, N, n, n) covariances of every node's own Kalman filter, computed by the same
    code as the built-in local filter."""
    from dse.estimators.sensor_network import SensorNetworkModel

    p = problem
    model = SensorNetworkModel(np.array(p.F), np.array(p.Q), np.array(p.H), np.array(p.R), np.array(p.P0),
                               np.array(p.x0), tuple([p.m] * p.N))
    covs = model.local_covariances(p.steps)
    return np.stack([c.gains for c in covs], axis=1), np.stack([c.P_post for c in covs], axis=1)


class LocalTwin(NetworkFilter):
    """Every node's own Kalman filter, as the built-in `local`: linear, equivariant, Kalman covariances."""

    title = "local KF (plug-in twin)"
    equivariant = True
    linear = True
    covariance_law = "conditional"
    cost_weight = 1.0

    def __init__(self, problem, params, trials):
        super().__init__(problem, params, trials)
        self.gains, self.P = local_gains(problem)
        self.xbar = np.broadcast_to(problem.x0[None, :, None], (problem.N, problem.n, trials)).copy()
        self.k = 0

    def step(self, k, y, network):
        # one expression, as the built-in: each temporary is freed as soon as it is used, so that numpy reuses its
        # memory (with the innovation, the gain and the estimate all alive at once the step took 50 % longer)
        est = self.xbar + self.gain(k, y - np.einsum("imn,inb->imb", self.problem.H, self.xbar))
        self.xbar = np.matmul(self.problem.F, est)
        self.k = k
        return est

    def gain(self, k, r):
        """K_i(k) r_i for every node: the correction of the innovations r (N, m, B)."""
        K = self.gains[k]
        return K[:, :, 0, None] * r[:, 0, None, :] if K.shape[2] == 1 else np.einsum("inm,imb->inb", K, r)

    def shift(self, delta):
        self.xbar = self.xbar + delta[None]

    def covariance(self):
        return self.P[self.k]

    def matrices(self, k):
        p = self.problem
        N, n, m = p.N, p.n, p.m
        A = np.zeros((N * n, N * n))
        B = np.zeros((N * n, N * m))
        for i in range(N):
            K = self.gains[k, i]
            A[i * n:(i + 1) * n, i * n:(i + 1) * n] = np.eye(n) - K @ p.H[i]
            B[i * n:(i + 1) * n, i * m:(i + 1) * m] = K
        return LinearStep(A, B)


class DiffusionTwin(NetworkFilter):
    """The diffusion Kalman filter, adapt then combine, through messages: each node sends its measurement
    information u_i = H_iᵀ R_i⁻¹ y_i, then its intermediate estimate ψ_i (two exchanges of n numbers per step),
    as the built-in `diffusion` does."""

    title = "diffusion KF (plug-in twin)"
    equivariant = True
    covariance_law = None
    cost_weight = 20.0

    @classmethod
    def sends(cls, problem, params):
        return Messages(problem.n, per="step", exchanges=2)

    def __init__(self, problem, params, trials):
        super().__init__(problem, params, trials)
        p = problem
        Rinv = np.linalg.inv(p.R)
        self.info_weight = np.einsum("imn,imk->ink", p.H, Rinv)                   # H_iᵀ R_i⁻¹ (N, n, m)
        self.U = self.info_weight @ p.H                                           # (N, n, n)
        self.xbar = np.broadcast_to(p.x0[None, :, None], (p.N, p.n, trials)).copy()
        self.Pbar = np.broadcast_to(p.P0, (p.N, p.n, p.n)).copy()[..., None]     # (N, n, n, 1 or B)

    def step(self, k, y, network):
        p = self.problem
        u = np.einsum("inm,imb->inb", self.info_weight, y)
        inbox = network.exchange(u)
        ybar = u + inbox.total()
        S = self.U[..., None] + np.einsum("idb,idnk->inkb", inbox.delivered.astype(float),
                                          self.U[np.maximum(p.neighbours, 0)] * (p.neighbours >= 0)[..., None, None])
        Pinv = np.linalg.inv(np.moveaxis(self.Pbar, -1, 1))                      # (N, B', n, n)
        M = np.linalg.inv(Pinv + np.moveaxis(S, -1, 1))                          # (N, B, n, n)
        resid = ybar - np.einsum("inkb,ikb->inb", S, self.xbar)
        psi = self.xbar + np.einsum("ibnk,ikb->inb", M, resid)
        got = network.exchange(psi)
        q = p.weights[..., None] * got.delivered                                  # (N, D, B)
        est = (1.0 - q.sum(axis=1))[:, None, :] * psi + np.einsum("idb,idnb->inb", q, got.values)
        est = est + got.noise
        self.xbar = np.matmul(p.F, est)
        self.Pbar = np.moveaxis(p.F @ M @ p.F.T + p.Q, 1, -1)
        return est

    def shift(self, delta):
        self.xbar = self.xbar + delta[None]


class ShrunkLocal(LocalTwin):
    """Deliberately wrong: the local filter's estimate pulled halfway towards the origin, and declared
    equivariant although it is not (in error coordinates its error shrinks: it claims to beat the centralized
    filter)."""

    title = "shrunk local KF (biased)"
    linear = False
    covariance_law = None

    def step(self, k, y, network):
        return 0.5 * super().step(k, y, network)
