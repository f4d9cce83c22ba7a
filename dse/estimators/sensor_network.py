"""A discrete-time linear-Gaussian plant seen by the sensors at the nodes of a graph.

    x(k+1) = F x(k) + w(k),        w(k) ~ N(0, Q)
    y_i(k) = H_i x(k) + v_i(k),    v_i(k) ~ N(0, R_i),  node i = 0..N-1
    x(0)   ~ N(x0, P0)

Every node has the same number m of measurement rows: a node with fewer rows is padded with
zero rows of unit noise, which carry no information, so every filter below is unchanged by
the padding (a zero row adds Hᵀ R⁻¹ H = 0 to the information and a zero gain column).

Also here: the quantities several estimators share (the information of each sensor
Hᵢᵀ Rᵢ⁻¹ Hᵢ, the centralized filter's stacked model and steady-state gain, per-node and
collective detectability).
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import Sequence

import numpy as np
import scipy  # scipy.linalg loads on first use (scipy imports submodules lazily): `dse list` skips it

from .kalman import kalman_covariances, steady_state_gain

__all__ = ["SensorNetworkModel", "detectable", "observable", "stabilizable", "split_gains", "walk_gramian_ratio"]


@dataclass(frozen=True, eq=False)
class SensorNetworkModel:
    """F (n, n), Q (n, n), H (N, m, n) zero-padded, R (N, m, m) with unit noise on padded rows,
    P0 (n, n), x0 (n,); `rows[i]` is the number of real measurement rows of node i."""

    F: np.ndarray
    Q: np.ndarray
    H: np.ndarray
    R: np.ndarray
    P0: np.ndarray
    x0: np.ndarray
    rows: tuple[int, ...]

    @classmethod
    def build(cls, F, Q, H_list: Sequence, R_list: Sequence, P0, x0=None) -> "SensorNetworkModel":
        F, Q, P0 = (np.atleast_2d(np.asarray(a, float)) for a in (F, Q, P0))
        n = F.shape[0]
        N = len(H_list)
        rows = [0 if np.size(h) == 0 else np.atleast_2d(h).shape[0] for h in H_list]
        m = max([1] + rows)
        H = np.zeros((N, m, n))
        R = np.tile(np.eye(m), (N, 1, 1))
        for i, (h, r) in enumerate(zip(H_list, R_list)):
            if rows[i]:
                H[i, :rows[i]] = np.atleast_2d(np.asarray(h, float))
                R[i, :rows[i], :rows[i]] = np.atleast_2d(np.asarray(r, float))
        x0 = np.zeros(n) if x0 is None else np.asarray(x0, float).reshape(n)
        return cls(F, Q, H, R, P0, x0, tuple(rows))

    @property
    def N(self) -> int:
        return self.H.shape[0]

    @property
    def n(self) -> int:
        return self.F.shape[0]

    @property
    def m(self) -> int:
        return self.H.shape[1]

    @cached_property
    def R_chol(self) -> np.ndarray:
        """(N, m, m) lower Cholesky factors: v_i = R_chol[i] @ standard normal."""
        return np.linalg.cholesky(self.R)

    @cached_property
    def info_weight(self) -> np.ndarray:
        """Hᵢᵀ Rᵢ⁻¹, (N, n, m): maps a measurement to its information vector."""
        return np.swapaxes(np.linalg.solve(self.R, self.H), 1, 2)

    @cached_property
    def info_matrix(self) -> np.ndarray:
        """Uᵢ = Hᵢᵀ Rᵢ⁻¹ Hᵢ, (N, n, n), exactly symmetric."""
        U = self.info_weight @ self.H
        return 0.5 * (U + np.swapaxes(U, 1, 2))

    @property
    def H_all(self) -> np.ndarray:
        """The centralized filter's stacked measurement matrix (N m, n)."""
        return self.H.reshape(-1, self.n)

    @property
    def R_all(self) -> np.ndarray:
        return scipy.linalg.block_diag(*self.R)

    def central_covariances(self, n_steps: int):
        """The centralized Kalman filter's covariances and gains (dse.estimators.kalman)."""
        return kalman_covariances(self.F, self.H_all, self.Q, self.R_all, self.P0, n_steps)

    def local_covariances(self, n_steps: int) -> list:
        """Each node's Kalman filter on its own measurements alone (no communication)."""
        return [kalman_covariances(self.F, self.H[i], self.Q, self.R[i], self.P0, n_steps) for i in range(self.N)]

    def state_rms(self, n_steps: int) -> np.ndarray:
        """√E‖x(k)‖² of the plant at every step k = 0..n_steps−1: S(0) = P0 + x0x0ᵀ, S(k+1) = F S(k) Fᵀ + Q."""
        S = self.P0 + np.outer(self.x0, self.x0)
        out = []
        for _ in range(n_steps):
            out.append(np.sqrt(max(float(np.trace(S)), 0.0)))
            S = self.F @ S @ self.F.T + self.Q
        return np.array(out)

    def locally_detectable(self) -> np.ndarray:
        """(N,) bool: (F, H_i) detectable, i.e. node i's own Kalman filter has a bounded error."""
        return np.array([detectable(self.F, self.H[i]) for i in range(self.N)])

    def collectively_detectable(self) -> bool:
        return detectable(self.F, self.H_all)


def _unstable_modes(F: np.ndarray, tol: float = 1e-9):
    lam, V = np.linalg.eig(F)
    return [(lam[k], V[:, k]) for k in range(len(lam)) if abs(lam[k]) >= 1 - tol]


def _pbh_rank_ok(F: np.ndarray, H: np.ndarray, lam: complex) -> bool:
    n = F.shape[0]
    M = np.vstack([lam * np.eye(n) - F, H.astype(complex)])
    s = np.linalg.svd(M, compute_uv=False)
    return bool(s[-1] > 1e-9 * max(1.0, s[0]))


def detectable(F: np.ndarray, H: np.ndarray) -> bool:
    """PBH test: rank [λI − F; H] = n for every eigenvalue |λ| ≥ 1 of F."""
    return all(_pbh_rank_ok(F, H, lam) for lam, _ in _unstable_modes(F))


def observable(F: np.ndarray, H: np.ndarray) -> bool:
    """PBH test for every eigenvalue of F."""
    return all(_pbh_rank_ok(F, H, lam) for lam in np.linalg.eigvals(F))


def stabilizable(F: np.ndarray, Q: np.ndarray) -> bool:
    """(F, Q^½) stabilizable: (Fᵀ, Q^½ᵀ) detectable (PBH test on the modes |λ| ≥ 1)."""
    lam, V = np.linalg.eigh(0.5 * (Q + Q.T))
    half = V * np.sqrt(np.maximum(lam, 0))
    return detectable(F.T, half.T)


def walk_gramian_ratio(model: SensorNetworkModel, walk: Sequence[int]) -> float:
    """λ_min/λ_max of the observability Gramian Σ_i (F^i)ᵀ H_{w_i}ᵀ H_{w_i} F^i along a walk w of nodes
    (Kar & Moura's weak detectability D.1 holds when it is invertible); the sum stops when F^i exceeds 1e150."""
    Gram = np.zeros((model.n, model.n))
    Fi = np.eye(model.n)
    for node in walk:
        Hf = model.H[node] @ Fi
        Gram += Hf.T @ Hf
        Fi = model.F @ Fi
        if np.abs(Fi).max() > 1e150:
            break
    ev = np.linalg.eigvalsh(0.5 * (Gram + Gram.T))
    return float(ev[0] / max(ev[-1], 1e-300))


def split_gains(model: SensorNetworkModel) -> np.ndarray:
    """(N, n, m): L_i = N K_i, where [K_0 … K_{N−1}] = K is the centralized steady-state Kalman
    gain cut by the columns of each node's measurement rows.

    Tanwani's gain rule (7) in discrete time: with L = (1/N)[L_0 … L_{N−1}] the network-average
    error of constant-gain local filters whose estimates are averaged fast enough evolves as
    (I − (1/N) Σ L_i H_i) = (I − K H): the centralized filter's steady-state closed loop."""
    K = steady_state_gain(model.F, model.H_all, model.Q, model.R_all)   # (n, N m)
    N, m, n = model.N, model.m, model.n
    return N * np.transpose(K.reshape(n, N, m), (1, 0, 2))
