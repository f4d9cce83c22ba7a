"""Local Kalman filters: every node filters its own measurements and sends nothing (the arena's floor).

Node i runs `dse.estimators.kalman` on (F, H_i, Q, R_i); its error is bounded only where (F, H_i) is
detectable (`compare.hyp.local_detectability`).
"""
from __future__ import annotations

import numpy as np

from dse.estimators.network_step import apply_gain, innovation, predict
from dse.estimators.protocol import NetworkEstimator, BatchedFilter


class LocalKalman(BatchedFilter):
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


def joint_disagreement(model, covs, K: int) -> np.ndarray:
    """(K,) the exact disagreement E (1/N) Σ_i ‖x̂_i − mean_j x̂_j‖² of the local filters.

    The nodes' errors are correlated through x(0) and w, which they all filter: the joint second moment of
    the stacked errors (`joint_moments`) starts at 1 1ᵀ ⊗ P0, each correction maps e_i to (I − K_i H_i) e_i
    plus the node's own K_i v_i (independent across nodes), and the prediction is common to every node."""
    from dse.estimators import joint_moments as jm

    eye = np.eye(model.n)
    S = jm.common_start(model.N, model.P0)
    out = np.empty(K)
    for k in range(K):
        gains = np.stack([c.gains[k] for c in covs])                                  # (N, n, m)
        S = jm.add_block_diagonal(jm.node_wise(eye - gains @ model.H, S),
                                  gains @ model.R @ np.swapaxes(gains, 1, 2))
        out[k] = jm.disagreement(S)
        S = jm.state_wise(model.F, S, model.Q)
    return out


def exact(est, K: int) -> dict[str, np.ndarray]:
    """The nodes' own Riccati covariances (``blocks``, ``mse``) and, within the size of the joint recursion
    (`Network.joint_size_reason`), the ``disagreement``."""
    model = est.network.model
    covs = model.local_covariances(K)
    blocks = np.stack([c.P_post for c in covs], axis=1)
    out = {"blocks": blocks, "mse": np.einsum("kiaa->ki", blocks)}
    if not est.network.joint_size_reason():
        out["disagreement"] = joint_disagreement(model, covs, K)
    return out


ESTIMATOR = NetworkEstimator(
    name="local", title="local KF (no communication)", rank=10, exact=exact, cost_weight=1,
    covariance_law="conditional",
    build=lambda est, B, peers: LocalKalman(est.network.model, est.network.steps, B))
