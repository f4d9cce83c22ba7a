"""The centralized continuous-time reference: the Kalman–Bucy filter using every sensor.

* `kalman_bucy_steady`: the filter CARE AP + PAᵀ + BBᵀ − PHᵀV⁻¹HP = 0 (scipy), its gain;
* `kalman_bucy_riccati`: the Riccati ODE Ṗ = AP + PAᵀ + BBᵀ − PHᵀV⁻¹HP, P(0) = P0, solved
  exactly on a grid through the linear Hamiltonian flow (P = Y X⁻¹, [X; Y]' = Ham [X; Y]);
* `discretised_kalman_covariances`: filterpy's discrete Kalman filter on the sampled model
  F = e^{Ah}, Q_d = ∫_0^h e^{As}BBᵀe^{Aᵀs}ds (Van Loan), measurements Δy_k/h with R = V/h;
  its covariances converge to the continuous ones as h → 0 (error O(h)).
"""
from __future__ import annotations

import numpy as np
import scipy.linalg as sla

from .linear_flows import van_loan


def kalman_bucy_steady(A, B, H, V) -> tuple[np.ndarray, np.ndarray]:
    """(P_KB, K = P_KB Hᵀ V⁻¹) of the stacked sensors H (p, n), V (p, p)."""
    P = sla.solve_continuous_are(A.T, H.T, B @ B.T, V)
    P = (P + P.T) / 2
    return P, P @ H.T @ np.linalg.inv(V)


def kalman_bucy_riccati(A, B, H, V, P0, step: float, n_steps: int) -> np.ndarray:
    """P_KB(k·step), k = 0..n_steps: (n_steps + 1, n, n)."""
    n = A.shape[0]
    S = H.T @ np.linalg.solve(V, H)
    Ham = np.block([[-A.T, S], [B @ B.T, A]])
    E = sla.expm(Ham * step)
    out = np.empty((n_steps + 1, n, n))
    P = np.asarray(P0, float)
    out[0] = P
    for k in range(n_steps):
        X = E[:n, :n] + E[:n, n:] @ P
        Y = E[n:, :n] + E[n:, n:] @ P
        P = np.linalg.solve(X.T, Y.T).T
        P = (P + P.T) / 2
        out[k + 1] = P
    return out


def discretised_kalman_covariances(A, B, H, V, P0, h: float, n_steps: int) -> tuple[np.ndarray, np.ndarray]:
    """filterpy KalmanFilter on the sampled model: (prior (n_steps, n, n), posterior (n_steps, n, n)).

    The prior of step k is the covariance at time k·h before the measurement Δy_k/h of the
    interval ((k−1)h, kh] (the first prior is at t = h)."""
    from filterpy.kalman import KalmanFilter

    n, p = A.shape[0], H.shape[0]
    F, Qd = van_loan(A, B @ B.T, h)
    kf = KalmanFilter(dim_x=n, dim_z=p)
    kf.F, kf.Q, kf.H, kf.R = F, Qd, np.asarray(H, float), np.asarray(V, float) / h
    kf.x = np.zeros((n, 1))
    kf.P = np.array(P0, float)
    prior, post = np.empty((n_steps, n, n)), np.empty((n_steps, n, n))
    z = np.zeros((p, 1))
    for k in range(n_steps):
        kf.predict()
        prior[k] = kf.P
        kf.update(z)
        post[k] = kf.P
    return prior, post
