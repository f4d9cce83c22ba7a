"""Bounds of the coestimation error system from V = zᵀ P z (Thm 2.1, Cor 2.1, Thm 3.1, Prop 4.1).

Notation: P = blockdiag(P_i), Q̄ = Q + 2α (L ⊗ I) (fixed roles, Q_i = −(Ā_iᵀ P_i + P_i Ā_i)) or
Q̄_ε = diag(ε_i I) + 2α (L ⊗ I) (time-varying roles), φ̄ from (15)-(16),
μ = 2‖P‖ φ̄ / λ_min(Q̄) and the ultimate bound (18) ‖z‖ ≤ sqrt(λ_max(P)/λ_min(P)) μ.
"""
from __future__ import annotations

import numpy as np
import scipy  # scipy.linalg loads on first use (scipy imports submodules lazily): `dse list` skips it

from .input_state_coestimation import block_diag, error_matrix


def forcing_bound(sigma, K, w_sup: float, wdot_sup: float) -> tuple[np.ndarray, float]:
    """φ̄_i = σ_i ‖K_i‖ w_sup + wdot_sup (15) and φ̄ = sqrt(Σ φ̄_i²) (16, with the bars the
    printed formula drops). The paper uses one w̄ for both: pass w_sup = wdot_sup = w̄."""
    K = np.asarray(K, float)
    phi_i = np.asarray(sigma, float) * np.linalg.norm(K, ord=2, axis=(1, 2)) * w_sup + wdot_sup
    return phi_i, float(np.sqrt(np.sum(phi_i ** 2)))


def coupling_term(lap, alpha: float, q: int) -> np.ndarray:
    return 2.0 * alpha * np.kron(np.asarray(lap, float), np.eye(q))


def qbar_fixed(Abars, P, lap, alpha: float) -> np.ndarray:
    """Q̄ = blockdiag(−(Ā_iᵀ P_i + P_i Ā_i)) + 2α (L ⊗ I) (fixed roles; (10) defines Q_i)."""
    Q = block_diag([-(A.T @ Pi + Pi @ A) for A, Pi in zip(Abars, P)])
    return Q + coupling_term(lap, alpha, P[0].shape[0])


def qbar_eps(eps, lap, alpha: float, q: int) -> np.ndarray:
    """Q̄_ε = diag(ε_i I_q) + 2α (L ⊗ I_q) (Thm 3.1; a common ε is eps = [ε]*N)."""
    return np.kron(np.diag(np.asarray(eps, float)), np.eye(q)) + coupling_term(lap, alpha, q)


def ultimate_bound(P, qbar_min: float, phibar: float) -> tuple[float, float]:
    """(μ, bound (18)) for block-diagonal P given as (N, q, q)."""
    lam = np.concatenate([np.linalg.eigvalsh(Pi) for Pi in P])
    mu = 2.0 * lam.max() * phibar / qbar_min
    return float(mu), float(np.sqrt(lam.max() / lam.min()) * mu)


def vertex_eigen_extremes(const: np.ndarray, blocks, *, chunk: int = 256) -> tuple[float, np.ndarray, float, np.ndarray]:
    """Over every g ∈ {0,1}^N, the extreme eigenvalues of M(g) = const + blockdiag(blocks[i][g_i]).

    Returns (min λ_min, its g, max λ_max, its g); batched eigvalsh over chunks of vertices.
    """
    N = len(blocks)
    q = blocks[0][0].shape[0]
    lo, hi, arg_lo, arg_hi = np.inf, -np.inf, None, None
    total = 2 ** N
    for start in range(0, total, chunk):
        codes = np.arange(start, min(start + chunk, total))
        gs = (codes[:, None] >> np.arange(N)[None, :]) & 1
        M = np.broadcast_to(const, (len(codes),) + const.shape).copy()
        for i in range(N):
            M[:, i * q:(i + 1) * q, i * q:(i + 1) * q] += np.where(gs[:, i, None, None] == 1, blocks[i][1], blocks[i][0])
        ev = np.linalg.eigvalsh(M)
        k_lo, k_hi = int(np.argmin(ev[:, 0])), int(np.argmax(ev[:, -1]))
        if ev[k_lo, 0] < lo:
            lo, arg_lo = float(ev[k_lo, 0]), gs[k_lo].copy()
        if ev[k_hi, -1] > hi:
            hi, arg_hi = float(ev[k_hi, -1]), gs[k_hi].copy()
    return lo, arg_lo, hi, arg_hi


def vertex_dissipation(A, B, C, L, J, K, sigma, P, lap, alpha: float, *, max_nodes: int = 14) -> tuple[float, np.ndarray] | None:
    """q* = min over g ∈ {0,1}^N of λ_min(−(Ā(g)ᵀ P + P Ā(g)) + 2α (L ⊗ I)) and the minimising g.

    The function is concave in g (λ_min of an affine matrix), so its minimum over [0,1]^N is at a
    vertex; this gives a rigorous Q̄ for Thm 3.1's proof, tighter than ε. None when N > max_nodes.
    """
    N = len(P)
    if N > max_nodes:
        return None
    q = P[0].shape[0]
    blocks = []
    for i in range(N):
        pair = []
        for g in (0.0, 1.0):
            Ab = error_matrix(A, B, C[i], L[i], J[i], sigma[i], K[i], g)
            pair.append(-(Ab.T @ P[i] + P[i] @ Ab))
        blocks.append(pair)
    lo, arg, _, _ = vertex_eigen_extremes(coupling_term(lap, alpha, q), blocks)
    return lo, arg


def mean_square_constants(P, qbar_min: float, phibar: float, v_star: float, r_star: float, N: int) -> dict[str, float]:
    """Prop. 4.1: κ = λ_min(Q̄)/(2 λ_max(P)), η = 2 φ̄² ‖P‖² / λ_min(Q̄) + λ_max(P) ψ̄²,
    ψ̄ = sqrt(N (v*² + r*²)); and the limit (52) of E‖z‖. NaN constants when λ_min(Q̄) ≤ 0."""
    lam = np.concatenate([np.linalg.eigvalsh(Pi) for Pi in P])
    lmax, lmin = lam.max(), lam.min()
    psibar = float(np.sqrt(N * (v_star ** 2 + r_star ** 2)))
    if not qbar_min > 0:   # no dissipation: the proposition does not apply
        nan = float("nan")
        return {"kappa": nan, "eta": nan, "psibar": psibar, "limit52": nan}
    kappa = qbar_min / (2 * lmax)
    eta = 2 * phibar ** 2 * lmax ** 2 / qbar_min + lmax * psibar ** 2
    mu = 2 * lmax * phibar / qbar_min
    limit52 = np.sqrt(lmax / lmin * (mu ** 2 + 2 * lmax * psibar ** 2 / qbar_min))
    return {"kappa": float(kappa), "eta": float(eta), "psibar": psibar, "limit52": float(limit52)}


def mean_square_bound(t, V0: float, kappa: float, eta: float) -> np.ndarray:
    """(46): E{zᵀ P z}(t) ≤ e^{−κ t} V(0) + η/κ."""
    return np.exp(-kappa * np.asarray(t, float)) * V0 + eta / kappa


def discrete_noise(S: np.ndarray, Qc: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """(Φ, Q_d) = (e^{S dt}, ∫_0^dt e^{Ss} Q_c e^{Sᵀs} ds).

    Van Loan's block exponential at δ = dt/2^k with ‖S‖₁δ ≤ 1/2, then k doublings
    Q_{2δ} = Φ_δ Q_δ Φ_δᵀ + Q_δ, Φ_{2δ} = Φ_δ². At the full step the block exponential would multiply
    e^{+|λ|dt} by e^{−|λ|dt} for the stiff modes (|λ|dt ≈ 30 for the graph coupling) and lose
    |λ|dt/ln 10 digits to cancellation; the doublings only add positive semidefinite terms."""
    d = S.shape[0]
    norm = float(np.abs(S).sum(axis=0).max()) * dt
    k = max(0, int(np.ceil(np.log2(norm / 0.5)))) if norm > 0.5 else 0
    delta = dt / 2 ** k
    big = np.zeros((2 * d, 2 * d))
    big[:d, :d] = -S
    big[:d, d:] = Qc
    big[d:, d:] = S.T
    X = scipy.linalg.expm(big * delta)
    Phi = X[d:, d:].T
    Qd = Phi @ X[:d, d:]
    Qd = (Qd + Qd.T) / 2
    for _ in range(k):
        Qd = Phi @ Qd @ Phi.T + Qd
        Qd = (Qd + Qd.T) / 2
        Phi = Phi @ Phi
    return Phi, Qd


def discrete_noise_columns(S: np.ndarray, B: np.ndarray, dt: float, nodes: int = 10) -> tuple[np.ndarray, np.ndarray]:
    """(Φ, Q) with Q[c] = ∫_0^dt e^{Ss} b_c b_cᵀ e^{Sᵀs} ds for every column b_c of B, at once.

    As `discrete_noise`, at δ = dt/2^k with ‖S‖₁δ ≤ 1/2 and then k doublings Q ← ΦQΦᵀ + Q (positive
    semidefinite sums only); at δ the integral is taken by Gauss-Legendre with `nodes` points, e^{Ss}b_c
    being analytic with ‖S‖δ ≤ 1/2 (the quadrature error of 10 points is below 1e-30 relative), so one
    exponential per node serves every column instead of one block exponential per column."""
    S, B = np.asarray(S, float), np.asarray(B, float)
    norm = float(np.abs(S).sum(axis=0).max()) * dt
    k = max(0, int(np.ceil(np.log2(norm / 0.5)))) if norm > 0.5 else 0
    delta = dt / 2 ** k
    x, w = np.polynomial.legendre.leggauss(nodes)
    Y = np.stack([scipy.linalg.expm(S * (delta * (xj + 1) / 2)) @ B for xj in x])          # (nodes, d, C)
    Q = np.einsum("j,jdc,jec->cde", w * delta / 2, Y, Y)
    Phi = scipy.linalg.expm(S * delta)
    for _ in range(k):
        Q = np.matmul(np.matmul(Phi, Q), Phi.T) + Q
        Phi = Phi @ Phi
    return Phi, (Q + np.swapaxes(Q, 1, 2)) / 2


def noise_covariance_sequence(S: np.ndarray, G: np.ndarray, dt: float, n_steps: int) -> np.ndarray:
    """Σ(k dt) for dΣ/dt = S Σ + Σ Sᵀ + G Gᵀ, Σ(0) = 0 (the centred part of (60)), exactly:
    Σ_{k+1} = Φ Σ_k Φᵀ + Q_d with (Φ, Q_d) by Van Loan's matrix exponential. Returns (n_steps+1, d, d)."""
    d = S.shape[0]
    Phi, Qd = discrete_noise(S, G @ G.T, dt)
    out = np.zeros((n_steps + 1, d, d))
    for k in range(n_steps):
        out[k + 1] = Phi @ out[k] @ Phi.T + Qd
    return out


def noise_covariance_traces(S: np.ndarray, G: np.ndarray, dt: float, n_steps: int, P: np.ndarray,
                            keep) -> tuple[np.ndarray, np.ndarray]:
    """tr(P Σ(k dt)) for k = 0..n_steps and Σ at the steps `keep`, by the same exact recursion as
    `noise_covariance_sequence` without storing every Σ. Returns ((n_steps+1,), (len(keep), d, d))."""
    d = S.shape[0]
    Phi, Qd = discrete_noise(S, G @ G.T, dt)
    keep = [int(k) for k in keep]
    where = {k: j for j, k in enumerate(keep)}
    traces = np.zeros(n_steps + 1)
    kept = np.zeros((len(keep), d, d))
    Sig = np.zeros((d, d))
    with np.errstate(over="ignore", invalid="ignore"):
        for k in range(n_steps + 1):
            if k:
                Sig = Phi @ Sig @ Phi.T + Qd
            traces[k] = np.einsum("ij,ji->", P, Sig)
            if k in where:
                kept[where[k]] = Sig
    return traces, kept


def principal_directions(P: np.ndarray, covariances, k: int) -> tuple[np.ndarray, np.ndarray]:
    """The k principal directions of the quadratic form V = zᵀPz under each covariance Σ: u_j = P^{1/2}v_j,
    v_j the eigenvectors of P^{1/2}ΣP^{1/2} and λ_j = var(u_jᵀz) its largest eigenvalues (Σ_j λ_j = tr(PΣ)
    over all j), P = blockdiag(P_i) given by its blocks (N, q, q). Directions below the numerical rank of Σ
    (λ_j ≤ 1e-8 λ_1: eigh's relative error there is eps·λ_1/λ_j) carry round-off, not noise: NaN, λ_j = 0;
    a Σ that overflowed (an unstable system) gives NaN. Returns ((cells, k, Nq), (cells, k))."""
    root = block_diag([(U * np.sqrt(np.maximum(w, 0))) @ U.T for w, U in (np.linalg.eigh(Pi) for Pi in P)])
    dirs, lam = [], []
    for S in covariances:
        if not np.all(np.isfinite(S)):
            dirs.append(np.full((k, len(S)), np.nan))
            lam.append(np.full(k, np.nan))
            continue
        w, V = np.linalg.eigh(root @ S @ root)
        order = np.argsort(w)[::-1][:k]
        lost = w[order] <= 1e-8 * max(w[order[0]], 0.0)
        lam.append(np.where(lost, 0.0, w[order]))
        dirs.append(np.where(lost[:, None], np.nan, (root @ V[:, order]).T))
    return np.array(dirs), np.array(lam)
