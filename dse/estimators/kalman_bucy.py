"""The centralized continuous-time reference: the Kalman–Bucy filter using every sensor.

* `kalman_bucy_steady`: the filter CARE AP + PAᵀ + BBᵀ − PHᵀV⁻¹HP = 0 (scipy), its gain;
* `kalman_bucy_riccati`: the Riccati ODE Ṗ = AP + PAᵀ + BBᵀ − PHᵀV⁻¹HP, P(0) = P0, solved
  exactly on a grid (closed form of the deviation from the steady state);
* `discretised_kalman_covariances`: filterpy's discrete Kalman filter on the sampled model
  F = e^{Ah}, Q_d = ∫_0^h e^{As}BBᵀe^{Aᵀs}ds (Van Loan), measurements Δy_k/h with R = V/h;
  its covariances converge to the continuous ones as h → 0 (error O(h));
* `sampled_filter_reference`: that filter at a few sampling steps, with scipy's DARE solution and
  the difference the residuals of both allow; `care_condition`: the CARE's condition number.
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


def care_condition(A, B, H, V, P) -> float:
    """First-order relative condition number of the filter CARE at its solution P:
    ‖L⁻¹‖₂(2‖A‖‖P‖ + ‖BBᵀ‖ + ‖PSP‖)/‖P‖ with L(Y) = A_cY + YA_cᵀ the closed-loop Lyapunov operator."""
    S = H.T @ np.linalg.solve(V, H)
    Ac = A - P @ S
    I = np.eye(len(Ac))
    inv_norm = 1.0 / float(np.linalg.svd(np.kron(I, Ac) + np.kron(Ac, I), compute_uv=False)[-1])
    terms = 2 * np.linalg.norm(A, 2) * np.linalg.norm(P, 2) + np.linalg.norm(B @ B.T, 2) + np.linalg.norm(P @ S @ P, 2)
    return float(inv_norm * terms / np.linalg.norm(P, 2))


def dare_residual(F, Qd, H, R, X) -> np.ndarray:
    """R(X) = FXFᵀ − FXHᵀ(HXHᵀ + R)⁻¹HXFᵀ + Q_d − X of the filter DARE."""
    Inn = H @ X @ H.T + R
    return F @ X @ F.T - F @ X @ H.T @ np.linalg.solve(Inn, H @ X @ F.T) + Qd - X


def sampled_filter_reference(A, B, H, V, P0, P_kb, fractions, max_steps: int) -> dict[str, np.ndarray]:
    """filterpy's discrete filter on the sampled model at the sampling steps h = min(0.1, 0.5/ν)·`fractions`,
    ν the fastest mode of the Kalman–Bucy closed loop A − P_KB HᵀV⁻¹H (so that hν ≤ 1/2, the first-order
    regime of the sampled filter), each run until its covariance stops changing (at most `max_steps` steps;
    `filterpy_steady` says whether it did), with scipy's DARE solution X and what their difference may be:
    to first order an approximate solution Y of the DARE differs from the exact one by 𝒮⁻¹(R(Y)),
    𝒮(Z) = Z − F_cZF_cᵀ (F_c the closed loop) and R the residual, so two approximate solutions differ by at
    most ‖𝒮⁻¹‖(‖R(X)‖ + ‖R(Y)‖), doubled for second-order terms, plus rounding (`filterpy_allow`)."""
    n, eps = A.shape[0], float(np.finfo(float).eps)
    Ac = A - P_kb @ H.T @ np.linalg.solve(V, H)
    nu = float(np.abs(np.linalg.eigvals(Ac)).max())
    hs = min(0.1, 0.5 / max(nu, 1e-12)) * np.array(fractions)
    pri, post, dare, steady, allow = [], [], [], [], []
    for h in hs:
        F, Qd = van_loan(A, B @ B.T, h)
        X = scipy.linalg.solve_discrete_are(F.T, H.T, Qd, V / h)
        Kd = X @ H.T @ np.linalg.inv(H @ X @ H.T + V / h)
        Fc = F @ (np.eye(n) - Kd @ H)
        inv_norm = 1.0 / float(np.linalg.svd(np.eye(n * n) - np.kron(Fc, Fc), compute_uv=False)[-1])
        prior, posterior = discretised_kalman_covariances(A, B, H, V, P0, h, max_steps, until_steady=True)
        res = [float(np.linalg.norm(dare_residual(F, Qd, H, V / h, Y), 2)) for Y in (X, prior[-1])]
        allow.append(2 * inv_norm * sum(res) + 10 * 4 * n * eps * float(np.linalg.norm(X, 2)))
        pri.append(prior[-1]), post.append(posterior[-1]), dare.append(X)
        steady.append(len(prior) < max_steps)
    return {"filterpy_h": hs, "filterpy_prior": np.array(pri), "filterpy_post": np.array(post),
            "dare_prior": np.array(dare), "filterpy_steady": np.array(steady), "filterpy_allow": np.array(allow),
            "kb_fastest_mode": np.array(nu)}
