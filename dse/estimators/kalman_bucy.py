"""The centralized continuous-time reference: the Kalman–Bucy filter using every sensor.

* `kalman_bucy_steady`: the filter CARE AP + PAᵀ + BBᵀ − PHᵀV⁻¹HP = 0 (scipy), its gain;
* `kalman_bucy_riccati`: the Riccati ODE Ṗ = AP + PAᵀ + BBᵀ − PHᵀV⁻¹HP, P(0) = P0, solved
  exactly on a grid (closed form of the deviation from the steady state);
* `discretised_kalman_covariances`: filterpy's discrete Kalman filter on the sampled model
  F = e^{Ah}, Q_d = ∫_0^h e^{As}BBᵀe^{Aᵀs}ds (Van Loan), measurements Δy_k/h with R = V/h;
  its covariances converge to the continuous ones as h → 0 (error O(h)).
"""
from __future__ import annotations

import numpy as np
import scipy  # scipy.linalg loads on first use (scipy imports submodules lazily): `dse list` skips it

from .linear_flows import van_loan


def kalman_bucy_steady(A, B, H, V) -> tuple[np.ndarray, np.ndarray]:
    """(P_KB, K = P_KB Hᵀ V⁻¹) of the stacked sensors H (p, n), V (p, p)."""
    P = scipy.linalg.solve_continuous_are(A.T, H.T, B @ B.T, V)
    P = (P + P.T) / 2
    return P, P @ H.T @ np.linalg.inv(V)


def kalman_bucy_riccati(A, B, H, V, P0, step: float, n_steps: int) -> np.ndarray:
    """P_KB(k·step), k = 0..n_steps: (n_steps + 1, n, n).

    With the stabilising steady state P∞ (CARE), the difference Δ = P − P∞ obeys
    Δ' = A_cΔ + ΔA_cᵀ − ΔSΔ (A_c = A − P∞S Hurwitz, S = HᵀV⁻¹H), whose exact solution is
    Δ(t) = Φ(t) Δ(0) (I + W(t)Δ(0))⁻¹ Φ(t)ᵀ with Φ = e^{A_c t} and the Gramian
    W(t) = ∫_0^t Φᵀ S Φ ds: only decaying exponentials and bounded Gramians appear, so the
    formula stays accurate for stiff problems (tiny V, huge gains) where the Hamiltonian
    exponential overflows. Without a stabilising P∞ (undetectable pairs, or a CARE that scipy
    cannot solve), the linear Hamiltonian flow P = Y X⁻¹ is used on sub-steps with ‖Ham‖δ ≤ 1;
    LinAlgError when that needs more than MAX_HAMILTONIAN_SUBSTEPS of them."""
    n = A.shape[0]
    S = H.T @ np.linalg.solve(V, H)
    S = (S + S.T) / 2
    P0 = np.asarray(P0, float)
    try:
        P_inf = scipy.linalg.solve_continuous_are(A.T, H.T, B @ B.T, V)
        P_inf = (P_inf + P_inf.T) / 2
        Ac = A - P_inf @ S
        if not np.all(np.isfinite(P_inf)) or np.max(np.linalg.eigvals(Ac).real) >= 0:
            raise np.linalg.LinAlgError("no stabilising solution")
    except (np.linalg.LinAlgError, ValueError):
        return _riccati_hamiltonian(A, B, S, P0, step, n_steps)
    D0 = P0 - P_inf
    out = np.empty((n_steps + 1, n, n))
    out[0] = P0
    Phi1, W1 = van_loan(Ac.T, S, step)          # e^{A_cᵀ h}, ∫_0^h e^{A_cᵀ s} S e^{A_c s} ds
    Phi1 = Phi1.T                               # e^{A_c h}
    Phi, W = np.eye(n), np.zeros((n, n))
    for k in range(1, n_steps + 1):
        W = W + Phi.T @ W1 @ Phi                # W(t + h) = W(t) + Φ(t)ᵀ W(h) Φ(t)
        Phi = Phi1 @ Phi
        Y = np.linalg.solve((np.eye(n) + W @ D0).T, D0.T).T
        P = P_inf + Phi @ Y @ Phi.T
        out[k] = (P + P.T) / 2
    return out


#: the Hamiltonian flow takes sub-steps with ‖Ham‖δ ≤ 1; a flow that needs more than this many in all is
#: refused (a nearly singular V makes ‖S‖ = ‖HᵀV⁻¹H‖ huge: 1e9 sub-steps would run for hours)
MAX_HAMILTONIAN_SUBSTEPS = 200_000


def _riccati_hamiltonian(A, B, S, P0, step: float, n_steps: int) -> np.ndarray:
    n = A.shape[0]
    Ham = np.block([[-A.T, S], [B @ B.T, A]])
    norm = float(np.abs(Ham).sum(axis=0).max()) * step
    sub = max(1, int(np.ceil(norm)))
    if sub * n_steps > MAX_HAMILTONIAN_SUBSTEPS:
        raise np.linalg.LinAlgError(f"the Riccati flow has no stabilising steady state to expand around and needs "
                                    f"{sub * n_steps:.3g} Hamiltonian sub-steps (‖Ham‖·step = {norm:.3g}; more than "
                                    f"{MAX_HAMILTONIAN_SUBSTEPS:,})")
    E = scipy.linalg.expm(Ham * (step / sub))
    out = np.empty((n_steps + 1, n, n))
    P = P0
    out[0] = P
    for k in range(n_steps):
        for _ in range(sub):
            X = E[:n, :n] + E[:n, n:] @ P
            Y = E[n:, :n] + E[n:, n:] @ P
            P = np.linalg.solve(X.T, Y.T).T
            P = (P + P.T) / 2
        out[k + 1] = P
    return out


def discretised_kalman_covariances(A, B, H, V, P0, h: float, n_steps: int,
                                   until_steady: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """filterpy KalmanFilter on the sampled model: (prior (k, n, n), posterior (k, n, n)), k ≤ n_steps.

    The prior of step k is the covariance at time k·h before the measurement Δy_k/h of the
    interval ((k−1)h, kh] (the first prior is at t = h). `until_steady`: stop as soon as the prior
    no longer changes beyond 10·n·eps of its size (a fixed point up to rounding)."""
    from filterpy.kalman import KalmanFilter

    n, p = A.shape[0], H.shape[0]
    F, Qd = van_loan(A, B @ B.T, h)
    kf = KalmanFilter(dim_x=n, dim_z=p)
    kf.F, kf.Q, kf.H, kf.R = F, Qd, np.asarray(H, float), np.asarray(V, float) / h
    kf.x = np.zeros((n, 1))
    kf.P = np.array(P0, float)
    prior, post = np.empty((n_steps, n, n)), np.empty((n_steps, n, n))
    z = np.zeros((p, 1))
    eps = float(np.finfo(float).eps)
    for k in range(n_steps):
        kf.predict()
        prior[k] = kf.P
        kf.update(z)
        post[k] = kf.P
        if until_steady and k and np.abs(prior[k] - prior[k - 1]).max() <= 10 * n * eps * np.abs(prior[k]).max():
            return prior[:k + 1], post[:k + 1]
    return prior, post
