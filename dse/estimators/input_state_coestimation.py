"""Distributed input-and-state estimators on an undirected graph: matrices and error systems.

Process (1): ẋ = A x + B w, A Hurwitz, w unknown, bounded with bounded rate. Node i measures
y_i = C_i x weighted by its role g_i ∈ [0, 1] (1 active, 0 passive).

Two architectures share one structure. With e_i = [x̂_i; ŵ_i] ∈ R^{n+p},

    ė_i = F_i e_i − α Γ_i Σ_j L_ij e_j + g_i [L_i; J_i] (y_i − C_i x̂_i)            (*)

* coestimation (3)-(4) / (22)-(23):  F_i = [[A, B], [0, −σ_i K_i]],
  Γ_i = D H_i D with D = diag(−I_n, I_p) and H_i = [[M_i, S_i], [T_i, N_i]] = P_i⁻¹ (34);
  this reproduces the printed coupling signs −M, +S, +T, −N.
* estimation (36)-(37) (the comparison architecture with leakage γ and P_i ∈ R^{n×n}):
  F_i = [[A − γ P_i⁻¹, B], [0, −(σ_i K_i + γ I)]], Γ_i = diag(P_i⁻¹, I_p).

Errors are z_i = [x − x̂_i; ŵ_i − w] (note the opposite signs, (5)-(6)); for the coestimation
they obey (9)/(26): ż_i = Ā_i(g_i) z_i − α Σ_j L_ij H_i z_j + φ_i with
Ā_i(g) = [[A − g L_i C_i, −B], [g J_i C_i, −σ_i K_i]] (27) and φ_i = [0; −σ_i K_i w − ẇ].
Arrays are stacked per node: C (N, m, n), L (N, n, m), J (N, p, m), K (N, p, p), sigma (N,).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def _stack(x, N: int, ndim: int) -> np.ndarray:
    a = np.asarray(x, dtype=float)
    if a.ndim == ndim - 1:
        a = np.broadcast_to(a, (N,) + a.shape).copy()
    if a.ndim != ndim or a.shape[0] != N:
        raise ValueError(f"expected {N} stacked arrays of dimension {ndim - 1}, got shape {a.shape}")
    return a


def error_matrix(A, B, C_i, L_i, J_i, sigma_i: float, K_i, g: float) -> np.ndarray:
    """Ā_i(g) of (9)/(27): [[A − g L_i C_i, −B], [g J_i C_i, −σ_i K_i]]."""
    A, B, C_i, L_i, J_i, K_i = (np.asarray(a, float) for a in (A, B, C_i, L_i, J_i, K_i))
    return np.block([[A - g * L_i @ C_i, -B], [g * J_i @ C_i, -sigma_i * K_i]])


def error_vertices(A, B, C_i, L_i, J_i, sigma_i, K_i) -> tuple[np.ndarray, np.ndarray]:
    """(Ā_i(0), Ā_i(1)), the vertices of the LMIs (28)-(29)."""
    return (error_matrix(A, B, C_i, L_i, J_i, sigma_i, K_i, 0.0),
            error_matrix(A, B, C_i, L_i, J_i, sigma_i, K_i, 1.0))


def comparison_lmi_blocks(A, B, C_i, L_i, J_i, sigma_i, K_i, g: float):
    """The affine map P ↦ R_i(g)(P) of (21)/(38)-(39) as (P ↦ matrix) pieces: returns (Acl, c12, c22)
    with R = [[Aclᵀ P + P Acl, −P B + c12], [(·)ᵀ, c22]], Acl = A − g L C, c12 = g Cᵀ Jᵀ,
    c22 = −σ (K + Kᵀ). The printed (21) has g Cᵀ Kᵀ in c12, a typo for Jᵀ (the block matrix must be
    symmetric; (39) has Jᵀ)."""
    A, C_i, L_i, J_i, K_i = (np.asarray(a, float) for a in (A, C_i, L_i, J_i, K_i))
    return A - g * L_i @ C_i, g * C_i.T @ J_i.T, -sigma_i * (K_i + K_i.T)


def comparison_lmi_matrix(P, A, B, C_i, L_i, J_i, sigma_i, K_i, g: float) -> np.ndarray:
    """R_i(g) of (21) (with Jᵀ) for a given n×n P; (38) is g = 0 and (39) is g = 1."""
    Acl, c12, c22 = comparison_lmi_blocks(A, B, C_i, L_i, J_i, sigma_i, K_i, g)
    top = -P @ np.asarray(B, float) + c12
    return np.block([[Acl.T @ P + P @ Acl, top], [top.T, c22]])


@dataclass(frozen=True)
class NetworkObserver:
    """A network of observers of the form (*) above, stacked over N nodes (q = n + p).

    F (N, q, q): local drift; Gamma (N, q, q): coupling gain; LJ (N, q, m): injection gain
    [L_i; J_i]; C (N, m, n); lap (N, N): graph Laplacian; alpha: coupling strength;
    A (n, n), B (n, p): the process.
    """

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    F: np.ndarray
    Gamma: np.ndarray
    LJ: np.ndarray
    lap: np.ndarray
    alpha: float

    @property
    def n(self) -> int:
        return self.A.shape[0]

    @property
    def p(self) -> int:
        return self.B.shape[1]

    @property
    def N(self) -> int:
        return self.lap.shape[0]

    @property
    def q(self) -> int:
        return self.n + self.p

    def estimate_drift(self) -> np.ndarray:
        """The constant part of ė = M e (N q × N q): blockdiag(F_i) − α blockdiag(Γ_i)(L ⊗ I_q)."""
        N, q = self.N, self.q
        M = np.zeros((N * q, N * q))
        for i in range(N):
            M[i * q:(i + 1) * q, i * q:(i + 1) * q] += self.F[i]
            for j in range(N):
                if self.lap[i, j] != 0.0:
                    M[i * q:(i + 1) * q, j * q:(j + 1) * q] -= self.alpha * self.lap[i, j] * self.Gamma[i]
        return M

    def augmented_drift(self) -> np.ndarray:
        """The constant part of u̇ for u = [x; e_1; …; e_N] (the process first, then the nodes)."""
        n, D = self.n, self.n + self.N * self.q
        M = np.zeros((D, D))
        M[:n, :n] = self.A
        M[n:, n:] = self.estimate_drift()
        return M

    def injection(self, x: np.ndarray, e: np.ndarray, g: np.ndarray) -> np.ndarray:
        """g_i [L_i; J_i] C_i (x − x̂_i), batched: x (R, n), e (R, N, q), g (R, N) -> (R, N, q)."""
        innov = np.einsum("imn,rin->rim", self.C, x[:, None, :] - e[..., :self.n])
        return g[..., None] * np.einsum("iqm,rim->riq", self.LJ, innov)

    def estimate_rhs(self, x, e, g, w) -> np.ndarray:
        """ė of (*) for one state: x (n,), e (N, q), g (N,), w unused (the observers do not see w)."""
        del w
        drift = (self.estimate_drift() @ e.reshape(-1)).reshape(self.N, self.q)
        return drift + self.injection(x[None], e[None], np.asarray(g, float)[None])[0]


def coestimation_network(A, B, C, L, J, K, sigma, P, lap, alpha: float) -> NetworkObserver:
    """The coestimation architecture (22)-(23) with H_i = P_i⁻¹ (34). P (N, q, q)."""
    A, B = np.asarray(A, float), np.asarray(B, float)
    n, p = A.shape[0], B.shape[1]
    N = np.asarray(lap).shape[0]
    C, L, J, K = _stack(C, N, 3), _stack(L, N, 3), _stack(J, N, 3), _stack(K, N, 3)
    sigma, P = np.broadcast_to(np.asarray(sigma, float), (N,)), _stack(P, N, 3)
    D = np.diag(np.r_[-np.ones(n), np.ones(p)])
    H = np.linalg.inv(P)
    F = np.stack([np.block([[A, B], [np.zeros((p, n)), -sigma[i] * K[i]]]) for i in range(N)])
    return NetworkObserver(A, B, C, F, D @ H @ D, np.concatenate([L, J], axis=1), np.asarray(lap, float), float(alpha))


def estimation_network(A, B, C, L, J, K, sigma, P_state, lap, alpha: float, gamma: float) -> NetworkObserver:
    """The comparison architecture (36)-(37) with leakage γ; P_state (N, n, n)."""
    A, B = np.asarray(A, float), np.asarray(B, float)
    n, p = A.shape[0], B.shape[1]
    N = np.asarray(lap).shape[0]
    C, L, J, K = _stack(C, N, 3), _stack(L, N, 3), _stack(J, N, 3), _stack(K, N, 3)
    sigma, P = np.broadcast_to(np.asarray(sigma, float), (N,)), _stack(P_state, N, 3)
    Pinv = np.linalg.inv(P)
    F = np.stack([np.block([[A - gamma * Pinv[i], B], [np.zeros((p, n)), -(sigma[i] * K[i] + gamma * np.eye(p))]])
                  for i in range(N)])
    Gamma = np.stack([np.block([[Pinv[i], np.zeros((n, p))], [np.zeros((p, n)), np.eye(p)]]) for i in range(N)])
    return NetworkObserver(A, B, C, F, Gamma, np.concatenate([L, J], axis=1), np.asarray(lap, float), float(alpha))


# -- the coestimation error system ------------------------------------------------------------

def stacked_error_matrix(A, B, C, L, J, K, sigma, P, lap, alpha: float, g) -> np.ndarray:
    """S(g) = Ā(g) − α H (L(G) ⊗ I_{n+p}) of (33)/Remark 4.3, with H = P⁻¹ block-diagonal."""
    N = np.asarray(lap).shape[0]
    C, L, J, K, P = (_stack(a, N, 3) for a in (C, L, J, K, P))
    sigma, g = np.broadcast_to(np.asarray(sigma, float), (N,)), np.broadcast_to(np.asarray(g, float), (N,))
    q = P.shape[1]
    Abar = block_diag([error_matrix(A, B, C[i], L[i], J[i], sigma[i], K[i], g[i]) for i in range(N)])
    H = block_diag(list(np.linalg.inv(P)))
    return Abar - alpha * H @ np.kron(np.asarray(lap, float), np.eye(q))


def block_diag(blocks) -> np.ndarray:
    blocks = [np.asarray(b, float) for b in blocks]
    r, c = sum(b.shape[0] for b in blocks), sum(b.shape[1] for b in blocks)
    out = np.zeros((r, c))
    i = j = 0
    for b in blocks:
        out[i:i + b.shape[0], j:j + b.shape[1]] = b
        i, j = i + b.shape[0], j + b.shape[1]
    return out


def errors_from_estimates(x, w, e, n: int) -> np.ndarray:
    """z_i = [x − x̂_i; ŵ_i − w] (5)-(6): x (..., n), w (..., p), e (..., N, q) -> (..., N, q)."""
    x, w, e = (np.asarray(a, float) for a in (x, w, e))
    z = np.empty(np.broadcast_shapes(x.shape[:-1] + (1, n), e[..., :n].shape)[:-1] + (e.shape[-1],))
    np.subtract(x[..., None, :], e[..., :n], out=z[..., :n])
    np.subtract(e[..., n:], w[..., None, :], out=z[..., n:])
    return z


def input_forcing(K, sigma, w, wdot) -> np.ndarray:
    """φ_i = [0_n; −σ_i K_i w − ẇ] of (9), for w, ẇ (..., p) -> the input part (..., N, p)."""
    return -np.einsum("i,ipk,...k->...ip", np.asarray(sigma, float), np.asarray(K, float), w) - wdot[..., None, :]


def error_rate(A, B, C, L, J, K, sigma, P, lap, alpha: float, z, g, w, wdot) -> tuple[np.ndarray, np.ndarray]:
    """ż of the error system (26)/(33) along recorded samples, z (T, N, q), roles g (T, N), input w and ẇ
    (T, p): (ż, its scale), both (T, N, q). The scale is the sum of the magnitudes of the terms of each
    component (|Ā(g)||z| + α|H|(|L|⊗I)|z| + |φ|), the size of the inputs the rounding of ż is proportional to."""
    n, N = np.asarray(A).shape[0], np.asarray(lap).shape[0]
    Ab0, Ab1 = (np.stack([error_matrix(A, B, C[i], L[i], J[i], sigma[i], K[i], gv) for i in range(N)])
                for gv in (0.0, 1.0))
    dA = Ab1 - Ab0
    local = np.einsum("inm,tim->tin", Ab0, z) + g[..., None] * np.einsum("inm,tim->tin", dA, z)
    H = np.linalg.inv(P)
    coup = -alpha * np.einsum("ij,iab,tjb->tia", lap, H, z)
    phi = np.zeros_like(z)
    phi[..., n:] = input_forcing(K, sigma, w, wdot)
    az = np.abs(z)
    scale = (np.einsum("inm,tim->tin", np.abs(Ab0), az) + g[..., None] * np.einsum("inm,tim->tin", np.abs(dA), az)
             + alpha * np.einsum("ij,iab,tjb->tia", np.abs(lap), np.abs(H), az))
    scale[..., n:] -= input_forcing(np.abs(K), sigma, np.abs(w), np.abs(wdot))  # σ|K||w| + |ẇ|
    return local + coup + phi, scale


def error_map(n: int, p: int, N: int) -> np.ndarray:
    """Z with z = Z u + (terms in w): z_i = [x − x̂_i; ŵ_i − w] from the simulated state u = [x; e_1; …; e_N]."""
    q = n + p
    Z = np.zeros((N * q, n + N * q))
    for i in range(N):
        Z[i * q:i * q + n, :n] = np.eye(n)
        Z[i * q:i * q + n, n + i * q:n + i * q + n] = -np.eye(n)
        Z[i * q + n:(i + 1) * q, n + i * q + n:n + (i + 1) * q] = np.eye(p)
    return Z


def noise_input_matrix(L, J, v, h, g) -> np.ndarray:
    """G of the stochastic error system (44)-(45) (dimensions fixed): G = [1_N ⊗ v̄, blockdiag(r_i)] with
    v̄ = [v; 0] and r_i = g_i [−L_i h_i; J_i h_i], for the process-noise intensity v (n,) and the
    measurement-noise intensities h (N, m) (one scalar Brownian motion each)."""
    N, p = len(h), np.asarray(J).shape[1]
    vbar = np.concatenate([v, np.zeros(p)])
    q = len(vbar)
    Gm = np.zeros((N * q, 1 + N))
    Gm[:, 0] = np.tile(vbar, N)
    for i in range(N):
        Gm[i * q:(i + 1) * q, 1 + i] = g[i] * np.concatenate([-L[i] @ h[i], J[i] @ h[i]])
    return Gm


def node_blocks(M: np.ndarray, N: int, q: int) -> np.ndarray:
    """The N diagonal (q, q) blocks of a stacked (Nq, Nq) matrix."""
    return np.stack([M[i * q:(i + 1) * q, i * q:(i + 1) * q] for i in range(N)])
