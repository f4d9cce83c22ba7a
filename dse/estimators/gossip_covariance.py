"""Deterministic second-moment theory of the gossiping constant-gain filters
(see `dse.estimators.gossip_filter` for the model).

* eq. (9), the mean of the per-path bound P_i of eq. (14): 𝒫̇_i = A_i𝒫_i + 𝒫_iA_iᵀ + G_i
  + λ Σ_c [(J_c ⊗ I)𝒫 − 𝒫]_i, which is λα Σ_{j∈N_i}(𝒫_j − 𝒫_i) in both clock modes; its
  generator M_9(λ) on p = [vec 𝒫_1; …; vec 𝒫_N] (column-major vec), transient, steady state
  and critical rate;
* the exact mean joint error covariance Σ̄(t) = E[e eᵀ] (expectation over noise and clocks):
  Σ̄' = 𝒜Σ̄ + Σ̄𝒜ᵀ + 𝒢 + λ Σ_c (𝒥_cΣ̄𝒥_cᵀ − Σ̄), 𝒜 = blkdiag(A_i), 𝒥_c = J_c ⊗ I_n;
* the Lyapunov solutions R of (10) and S of (11), the large-rate limit S_true of the true
  covariance, and an explicit version of the bound (12) with computable constants;
* both steady states over a range of rates, with their deviations from S and S_true (`steady_state_sweep`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy  # scipy.linalg loads on first use (scipy imports submodules lazily): `dse list` skips it

from .gossip_filter import GossipSystem
from .linear_flows import (abscissa_tolerance, affine_flow_grid, critical_parameter_by_test, spectral_abscissa)

MAX_JOINT_DIM = 40     # N·n above which the dense (Nn)²×(Nn)² generator of Σ̄ is not formed
MAX_SECOND_DIM = 40    # N·n(n+1)/2 above which the second moments of the P-process are not formed
_EPS = float(np.finfo(float).eps)


def vec(X: np.ndarray) -> np.ndarray:
    """Column-major vec of the last two axes."""
    X = np.asarray(X)
    return np.swapaxes(X, -1, -2).reshape(*X.shape[:-2], -1)


def unvec(v: np.ndarray, n: int) -> np.ndarray:
    return np.swapaxes(np.asarray(v).reshape(*v.shape[:-1], n, n), -1, -2)


def lyapunov_generator(A: np.ndarray) -> np.ndarray:
    """I⊗A + A⊗I: vec(AX + XAᵀ) for column-major vec."""
    I = np.eye(len(A))
    return np.kron(I, A) + np.kron(A, I)


# -- eq. (9) ------------------------------------------------------------------------------------

def _memo(sys: GossipSystem, name: str, build):
    """A generator's λ-free parts, built once per system (the generators are affine in λ)."""
    memo = sys.__dict__.setdefault("_generator_parts", {})
    if name not in memo:
        memo[name] = build()
    return memo[name]


def bound_generator(sys: GossipSystem, rate: float) -> tuple[np.ndarray, np.ndarray]:
    """(M_9(λ), g) with ṗ = M_9 p + g: M_9(λ) = blkdiag(I⊗A_i + A_i⊗I) + λ Σ_c (J_c − I) ⊗ I_{n²}."""
    def build():
        n, N = sys.n, sys.N
        jump = sum(sys.jump(c) - np.eye(N) for c in range(len(sys.clocks)))
        return (scipy.linalg.block_diag(*[lyapunov_generator(Ai) for Ai in sys.Ai]), np.kron(jump, np.eye(n * n)),
                np.concatenate([vec(G) for G in sys.Gi]))

    M0, W, g = _memo(sys, "bound", build)
    return M0 + rate * W, g


def bound_transient(sys: GossipSystem, rate: float, step: float, n_steps: int, P_init=None) -> np.ndarray:
    """𝒫_i(k·step), (n_steps + 1, N, n, n), 𝒫_i(0) = P_init[i] (default the system's P_i(0))."""
    M, g = bound_generator(sys, rate)
    if P_init is None:
        P_init = sys.P_init
    p = affine_flow_grid(M, g, np.concatenate([vec(P) for P in P_init]), step, n_steps)
    return unvec(p.reshape(n_steps + 1, sys.N, -1), sys.n)


def bound_hurwitz(sys: GossipSystem, rate: float) -> bool:
    """Whether M_9(λ) is Hurwitz, by one linear solve: M_9 is resolvent positive on N-tuples of symmetric
    matrices (Lyapunov operators plus the positive coupling λαΣ_j𝒫_j), so it is Hurwitz if and only if
    −M_9⁻¹(I, …, I) has every block positive definite (see `joint_hurwitz`)."""
    M, _ = bound_generator(sys, rate)
    n, N = sys.n, sys.N
    try:
        with np.errstate(all="ignore"):
            X = unvec(np.linalg.solve(M, -np.tile(vec(np.eye(n)), N)).reshape(N, -1), n)
    except np.linalg.LinAlgError:
        return False
    return bool(np.all(np.isfinite(X)) and np.linalg.eigvalsh((X + np.swapaxes(X, 1, 2)) / 2)[:, 0].min() > 0)


def bound_steady(sys: GossipSystem, rate: float) -> np.ndarray | None:
    """𝒫_i^∞(λ) (N, n, n), or None when M_9(λ) is not Hurwitz (the bound diverges)."""
    if not bound_hurwitz(sys, rate):
        return None
    M, g = bound_generator(sys, rate)
    return unvec(np.linalg.solve(M, -g).reshape(sys.N, -1), sys.n)


def bound_abscissa(sys: GossipSystem, rate: float) -> float:
    return spectral_abscissa(bound_generator(sys, rate)[0])


def bound_abscissa_tolerance(sys: GossipSystem, rate: float) -> float:
    """Rounding level of `bound_abscissa` (see `linear_flows.abscissa_tolerance`)."""
    return abscissa_tolerance(bound_generator(sys, rate)[0])


def critical_rate_bound(sys: GossipSystem) -> float:
    """λ_crit of (9): inf{λ : M_9(λ) Hurwitz} (0 if every A_i is Hurwitz, or if M_9(0) is only
    marginally stable and every small λ > 0 is stable; inf if never)."""
    return critical_parameter_by_test(lambda lam: bound_hurwitz(sys, lam), bound_abscissa(sys, 0.0),
                                      bound_abscissa_tolerance(sys, 0.0))


def bound_steady_deviation(sys: GossipSystem, rate: float, S: np.ndarray) -> np.ndarray | None:
    """𝒫_i^∞(λ) − S (N, n, n) for any S, solved for directly (None when M_9(λ) is not Hurwitz).

    The constant stack 1⊗S is annihilated exactly by the jump terms (J_c1 = 1), so the
    deviation D solves M_9(λ) vec D = −r with the λ-free residual r_i = A_iS + SA_iᵀ + G_i: no
    term of size λ‖S‖ is formed and cancelled, and D = O(1/λ) keeps its relative accuracy at
    large λ (forming 𝒫^∞ and subtracting S loses ~log10(λ) digits)."""
    if not bound_hurwitz(sys, rate):
        return None
    M, _ = bound_generator(sys, rate)
    r = np.concatenate([vec(A @ S + S @ A.T + G) for A, G in zip(sys.Ai, sys.Gi)])
    return unvec(np.linalg.solve(M, -r).reshape(sys.N, -1), sys.n)


def first_order_deviation(sys: GossipSystem) -> np.ndarray:
    """C (N, n, n) with 𝒫_i^∞(λ) = S + C_i/λ + O(λ⁻²) as λ → ∞ (singular perturbation of (9)).

    With W = −Σ_c (J_c − I) (= α𝓛 in both clock modes) the deviation δ = Σ_k δ_k λ^(−k) of
    p = 1⊗vec S + δ solves (𝔄 − λW⊗I)δ = −r: at order λ⁰, (W⊗I)δ_1 = r, so
    δ_1 = (W⁺⊗I)r + 1⊗z (r sums to 0 over the nodes because S solves (11)); at order λ⁻¹ the
    consensus part of 𝔄δ_1 must vanish, which fixes z: ĀZ + ZĀᵀ = −(1/N)Σ_i(A_iY_i + Y_iA_iᵀ),
    Y_i = Σ_j (W⁺)_ij R_j. C_i = Y_i + Z."""
    S = lyapunov_S(sys)
    R = np.array([A @ S + S @ A.T + G for A, G in zip(sys.Ai, sys.Gi)])
    W = -sum(sys.jump(c) - np.eye(sys.N) for c in range(len(sys.clocks)))
    Y = np.einsum("ij,jab->iab", np.linalg.pinv(W), R)
    F = np.mean([A @ Yi + Yi @ A.T for A, Yi in zip(sys.Ai, Y)], axis=0)
    Z = scipy.linalg.solve_continuous_lyapunov(sys.Abar, -F)
    C = Y + Z
    return (C + np.swapaxes(C, 1, 2)) / 2


# -- second moments of the P-process over clock paths -------------------------------------------------

def vech_pairs(n: int) -> list[tuple[int, int]]:
    return [(a, b) for a in range(n) for b in range(a, n)]


def vech_weights(U: np.ndarray) -> np.ndarray:
    """w (k, n(n+1)/2) with uᵀPu = w·x for the directions U (k, n) and the coordinates x of a
    symmetric P: x_ab = P_ab (a ≤ b), so uᵀPu = Σ_a u_a²x_aa + 2Σ_{a<b} u_au_bx_ab."""
    pairs = vech_pairs(U.shape[1])
    return np.stack([U[:, a] * U[:, b] * (1.0 if a == b else 2.0) for a, b in pairs], axis=1)


def _vech_maps(n: int) -> tuple[np.ndarray, np.ndarray]:
    """(Dup (n², q), Elim (q, n²)): vec P = Dup x and x = Elim vec P (column-major vec)."""
    pairs = vech_pairs(n)
    Dup, Elim = np.zeros((n * n, len(pairs))), np.zeros((len(pairs), n * n))
    for k, (a, b) in enumerate(pairs):
        Dup[a + n * b, k] = Dup[b + n * a, k] = 1.0
        Elim[k, a + n * b] = 1.0
    return Dup, Elim


def sym_reduce(M: np.ndarray, D: int) -> np.ndarray:
    """Elim·M·Dup: an operator on vec of D×D matrices that maps symmetric matrices to symmetric
    ones, written on their symmetric coordinates (`vech_pairs` order): D(D+1)/2 instead of D²
    unknowns, with the same spectrum on that subspace."""
    pairs = np.array(vech_pairs(D))
    a, b = pairs[:, 0], pairs[:, 1]
    at, bt = a + D * b, b + D * a
    Mr = M[at]
    return Mr[:, at] + np.where(a != b, 1.0, 0.0) * Mr[:, bt]


def sym_coords(X: np.ndarray) -> np.ndarray:
    """The symmetric coordinates x_ab = X_ab (a ≤ b) of (…, D, D)."""
    pairs = np.array(vech_pairs(X.shape[-1]))
    return X[..., pairs[:, 0], pairs[:, 1]]


def from_sym_coords(x: np.ndarray, D: int) -> np.ndarray:
    pairs = np.array(vech_pairs(D))
    X = np.zeros(x.shape[:-1] + (D, D))
    X[..., pairs[:, 0], pairs[:, 1]] = x
    X[..., pairs[:, 1], pairs[:, 0]] = x
    return X


def bound_second_moments(sys: GossipSystem, rate: float, step: float, n_steps: int, weights: np.ndarray,
                         check: bool = False) -> tuple | None:
    """Exact mean and second moment over the clock paths of linear functionals c·p of the
    P-process (14), p = [x_1; …; x_N] the stacked symmetric coordinates of P_1..P_N.

    `weights` (K, N·q): the functionals (e.g. `vech_weights` of a direction, placed in node i's
    block). Returns (E[c·p], E[(c·p)²]) at the times k·step, arrays (n_steps + 1, K), or None
    when D = N·q exceeds MAX_SECOND_DIM; with `check`, also the relative difference from the same
    computation on twice the step (an estimate of its rounding error).

    Between rings p flows by ṗ = 𝔐p + g (𝔐 = blkdiag of the Lyapunov operators of the A_i on
    symmetric coordinates), and a ring of clock c maps p to 𝒦_cp with 𝒦_c = J_c ⊗ I_q. Hence
    (Dynkin's formula for this piecewise-deterministic Markov process) m = E[p] solves
    ṁ = (𝔐 + λΣ_c(𝒦_c − I))m + g (eq. 9) and W = E[ppᵀ] solves the closed linear equation
    Ẇ = 𝔐W + W𝔐ᵀ + gmᵀ + mgᵀ + λΣ_c(𝒦_cW𝒦_cᵀ − W), integrated exactly together with m on
    the symmetric coordinates of W (one matrix exponential of size D(D+1)/2 + D)."""
    n, N = sys.n, sys.N
    q = n * (n + 1) // 2
    D = N * q
    if D > MAX_SECOND_DIM:
        return None
    Dup, Elim = _vech_maps(n)
    Mf = scipy.linalg.block_diag(*[Elim @ lyapunov_generator(A) @ Dup for A in sys.Ai])
    g = np.concatenate([Elim @ vec(G) for G in sys.Gi])
    K = [np.kron(sys.jump(c), np.eye(q)) for c in range(len(sys.clocks))]
    I = np.eye(D)
    M1 = Mf + rate * sum(Kc - I for Kc in K)
    Op = np.kron(I, Mf) + np.kron(Mf, I) + rate * sum(np.kron(Kc, Kc) for Kc in K) - rate * len(K) * np.eye(D * D)
    Cm = np.kron(I, g[:, None]) + np.kron(g[:, None], I)                   # vec(gmᵀ + mgᵀ)
    D2, E2 = _vech_maps(D)                                                  # symmetric coordinates of W
    big = np.zeros((E2.shape[0] + D, E2.shape[0] + D))
    big[:E2.shape[0], :E2.shape[0]] = E2 @ Op @ D2
    big[:E2.shape[0], E2.shape[0]:] = E2 @ Cm
    big[E2.shape[0]:, E2.shape[0]:] = M1
    const = np.concatenate([np.zeros(E2.shape[0]), g])
    p0 = np.concatenate([Elim @ vec(P) for P in sys.P_init])
    y0 = np.concatenate([E2 @ vec(np.outer(p0, p0)), p0])
    y = affine_flow_grid(big, const, y0, step, n_steps)
    mean, second = _functionals(y, weights, E2.shape[0], D2, D)
    if not check:
        return mean, second
    # the same flow on twice the step: identical in exact arithmetic, so the difference measures
    # how much rounding the (possibly very non-normal) exponential has let through
    y2 = affine_flow_grid(big, const, y0, 2 * step, n_steps // 2)
    m2, s2 = _functionals(y2, weights, E2.shape[0], D2, D)
    with np.errstate(invalid="ignore", over="ignore"):
        rel = max(float(np.abs(m2 - mean[::2][:len(m2)]).max() / max(float(np.abs(mean).max()), 1e-300)),
                  float(np.abs(s2 - second[::2][:len(s2)]).max() / max(float(np.abs(second).max()), 1e-300)))
    return mean, second, rel


def _functionals(y: np.ndarray, weights: np.ndarray, q2: int, D2: np.ndarray, D: int) -> tuple[np.ndarray, np.ndarray]:
    Wt = unvec(y[:, :q2] @ D2.T, D)                                        # (T, D, D)
    return y[:, q2:] @ weights.T, np.einsum("kd,tde,ke->tk", weights, Wt, weights)


# -- exact mean joint covariance ----------------------------------------------------------------

def _joint_parts(sys: GossipSystem) -> tuple[np.ndarray, np.ndarray]:
    """(𝔄, W) with M_Σ(λ) = 𝔄 + λW on vec Σ̄: 𝔄 = I⊗𝒜 + 𝒜⊗I and W = Σ_c (𝒥_c⊗𝒥_c − I). With
    𝒥_c = I − αD_c (D_c = E_c ⊗ I_n, E_c = (u_i − u_j)(u_i − u_j)ᵀ for an edge clock, u_i(u_i − u_j)ᵀ for
    an ordered one, Σ_c E_c = 𝓛): W = −α(I⊗(𝓛⊗I_n) + (𝓛⊗I_n)⊗I) + α²Σ_c D_c⊗D_c, the last sum
    accumulated from the few nonzero entries of each D_c (no dense Kronecker product per clock)."""
    n, N = sys.n, sys.N
    D = N * n
    if D > MAX_JOINT_DIM:
        raise ValueError(f"N·n = {D} > {MAX_JOINT_DIM}: the dense generator of the joint covariance is too large")

    def build():
        I = np.eye(D)
        Ln = np.kron(sys.laplacian, np.eye(n))
        W = -sys.alpha * (np.kron(I, Ln) + np.kron(Ln, I))
        rows, cols, vals = [], [], []
        k = np.arange(n)
        for i, j in sys.clocks:
            entries = [(i, i, 1.0), (i, j, -1.0)] + ([(j, j, 1.0), (j, i, -1.0)] if sys.mode == "edge" else [])
            r = np.concatenate([a * n + k for a, _, _ in entries])
            c = np.concatenate([b * n + k for _, b, _ in entries])
            v = np.concatenate([np.full(n, x) for _, _, x in entries])
            rows.append((r[:, None] * D + r[None, :]).ravel())
            cols.append((c[:, None] * D + c[None, :]).ravel())
            vals.append((v[:, None] * v[None, :]).ravel())
        np.add.at(W, (np.concatenate(rows), np.concatenate(cols)), sys.alpha ** 2 * np.concatenate(vals))
        return lyapunov_generator(scipy.linalg.block_diag(*sys.Ai)), W

    return _memo(sys, "joint", build)


def joint_generator(sys: GossipSystem, rate: float) -> tuple[np.ndarray, np.ndarray]:
    """(M_Σ(λ), g_Σ) on vec Σ̄ (Nn × Nn, column-major)."""
    M0, W = _joint_parts(sys)
    return M0 + rate * W, vec(sys.joint_noise[sys.n:, sys.n:])


def joint_generator_sym(sys: GossipSystem, rate: float) -> tuple[np.ndarray, np.ndarray]:
    """`joint_generator` on the symmetric coordinates of Σ̄ (the flow and the jumps keep Σ̄
    symmetric; the spectral abscissa of the full operator is attained there, on the positive
    semidefinite cone the flow preserves)."""
    D = sys.N * sys.n
    M0, W = _memo(sys, "joint_sym", lambda: tuple(sym_reduce(X, D) for X in _joint_parts(sys)))
    return M0 + rate * W, sym_coords(sys.joint_noise[sys.n:, sys.n:])


def joint_initial(sys: GossipSystem) -> np.ndarray:
    return sys.joint_second_moment0()[sys.n:, sys.n:]


def joint_transient(sys: GossipSystem, rate: float, step: float, n_steps: int) -> np.ndarray:
    """Σ̄(k·step): (n_steps + 1, Nn, Nn)."""
    M, g = joint_generator_sym(sys, rate)
    D = sys.N * sys.n
    p = affine_flow_grid(M, g, sym_coords(joint_initial(sys)), step, n_steps)
    return from_sym_coords(p, D)


def joint_hurwitz(sys: GossipSystem, rate: float) -> bool:
    """Whether M_Σ(λ) is Hurwitz, by one linear solve instead of an eigenvalue problem.

    M_Σ(λ) is resolvent positive on the symmetric matrices (a Lyapunov operator plus the positive
    map λΣ_c𝒥_c·𝒥_cᵀ, shifted): such an operator is Hurwitz if and only if X = −M_Σ⁻¹(I) is positive
    definite (if it is Hurwitz, −M_Σ⁻¹ = ∫e^{M_Σt}dt maps I into the interior of the cone; if
    X ≻ 0 solves M_Σ(X) = −I ≺ 0, X is a Lyapunov certificate)."""
    M, _ = joint_generator_sym(sys, rate)
    D = sys.N * sys.n
    try:
        with np.errstate(all="ignore"):
            X = from_sym_coords(np.linalg.solve(M, -sym_coords(np.eye(D))), D)
    except np.linalg.LinAlgError:
        return False
    return bool(np.all(np.isfinite(X)) and np.linalg.eigvalsh(X)[0] > 0)


def joint_steady(sys: GossipSystem, rate: float) -> np.ndarray | None:
    if not joint_hurwitz(sys, rate):
        return None
    M, g = joint_generator_sym(sys, rate)
    return from_sym_coords(np.linalg.solve(M, -g), sys.N * sys.n)


def joint_abscissa(sys: GossipSystem, rate: float) -> tuple[float, float]:
    """(spectral abscissa of M_Σ(λ), its round-off level)."""
    M, _ = joint_generator_sym(sys, rate)
    return spectral_abscissa(M), abscissa_tolerance(M)


def critical_rate_joint(sys: GossipSystem, upper: float | None = None, *, rtol: float = 1e-10,
                        limit: float = 1e9) -> float:
    """λ_crit of the exact mean covariance: inf{λ : M_Σ(λ) Hurwitz}, by bisection on `joint_hurwitz`
    (0 when M_Σ(0) is Hurwitz, or only marginally stable at λ = 0 (abscissa zero to round-off) with
    every small λ > 0 stable; inf when no λ up to `limit` is stable). `upper` (e.g. λ_crit of (9),
    which is never smaller: 𝒫_i ⪰ E[e_ie_iᵀ]) narrows the bisection."""
    a0, t0 = joint_abscissa(sys, 0.0)
    return critical_parameter_by_test(lambda lam: joint_hurwitz(sys, lam), a0, t0, upper=limit, rtol=rtol,
                                      start=None if upper is None else upper * (1 + 1e-9))


def joint_steady_deviation(sys: GossipSystem, rate: float, S_lim: np.ndarray) -> np.ndarray | None:
    """Σ̄^∞(λ) − 11ᵀ⊗S_lim (Nn × Nn), solved for directly (None when M_Σ(λ) is not Hurwitz).

    As for `bound_steady_deviation`: 𝒥_c(11ᵀ⊗S)𝒥_cᵀ = 11ᵀ⊗S, so only the λ-free residual
    𝒜X + X𝒜ᵀ + 𝒢 of X = 11ᵀ⊗S_lim enters the right-hand side."""
    if not joint_hurwitz(sys, rate):
        return None
    M, _ = joint_generator_sym(sys, rate)
    X = np.kron(np.ones((sys.N, sys.N)), S_lim)
    Ablk = scipy.linalg.block_diag(*sys.Ai)
    R = Ablk @ X + X @ Ablk.T + sys.joint_noise[sys.n:, sys.n:]
    return from_sym_coords(np.linalg.solve(M, -sym_coords(R)), sys.N * sys.n)


def diagonal_blocks(S: np.ndarray, N: int, n: int) -> np.ndarray:
    """(…, Nn, Nn) → (…, N, n, n)."""
    return np.stack([S[..., i * n:(i + 1) * n, i * n:(i + 1) * n] for i in range(N)], axis=-3)


# -- (10), (11) and the large-rate limits -----------------------------------------------------------

def lyapunov_R(Abar: np.ndarray) -> np.ndarray:
    """R of (10) as the Lyapunov equality RĀ + ĀᵀR = −I (the Loewner-smallest R satisfying (10))."""
    R = scipy.linalg.solve_continuous_lyapunov(Abar.T, -np.eye(len(Abar)))
    return (R + R.T) / 2


def lyapunov_S(sys: GossipSystem) -> np.ndarray:
    """S of (11): ĀS + SĀᵀ + BBᵀ + (1/N) Σ L_iV_iL_iᵀ = 0."""
    S = scipy.linalg.solve_continuous_lyapunov(sys.Abar, -sys.Gbar)
    return (S + S.T) / 2


def lyapunov_S_true(sys: GossipSystem) -> np.ndarray:
    """lim_{λ→∞} of the true E[e_ie_iᵀ] (edge clocks): ĀS + SĀᵀ + BBᵀ + (1/N²) Σ L_iV_iL_iᵀ = 0."""
    N = sys.N
    G = sys.B @ sys.B.T + sum(L @ V @ L.T for L, V in zip(sys.L, sys.V)) / N ** 2
    S = scipy.linalg.solve_continuous_lyapunov(sys.Abar, -G)
    return (S + S.T) / 2


# -- explicit (12) ------------------------------------------------------------------------------------

@dataclass(frozen=True)
class ExplicitBound:
    """Constants of the explicit version of (12) (derived from the proof of Theorem III.1 item 2) for one variant."""

    variant: str
    C0: float
    C1: float
    C2: float
    C3: float
    a1: float
    a2: float
    sigma_G: float
    sigma1_R: float
    sigman_R: float
    kappa: float
    fiedler: float
    S_norm: float
    N: int
    alpha: float

    @property
    def threshold(self) -> float:
        """λ_thr: the explicit 'λ sufficiently large' (b > 0 beyond it; inf on a disconnected graph)."""
        coupling = self.alpha * self.fiedler
        return (self.C1 + self.a2 ** 2 / (2 * self.a1)) / coupling if coupling > 0 else math.inf

    def value(self, rate: float) -> float:
        """B_12(λ) ≥ limsup ‖𝒫_i(t) − S‖_F; inf below the threshold."""
        a3 = rate * self.alpha * self.fiedler - self.C1
        b = a3 - self.a2 ** 2 / (2 * self.a1)
        if b <= 0:
            return math.inf
        c = min(self.a1, b) / 2
        g = self.C3 * self.sigma_G + self.C2 * self.S_norm
        return math.sqrt(self.N) * self.kappa * g / math.sqrt(2 * b * c)


def explicit_bound(sys: GossipSystem, variant: str = "faithful") -> ExplicitBound:
    """Constants C_0..C_3 for the proof of Thm III.1 item 2 ('faithful': the paper's own
    estimates; 'tight': using Σ_i(Ũ_i⊗I)𝒬̃ = 0 and (Ũᵀ⊗I)(1⊗M) = 0)."""
    Abar, N = sys.Abar, sys.N
    R = lyapunov_R(Abar)
    eR = np.linalg.eigvalsh(R)
    s1, sn = float(eR[0]), float(eR[-1])
    norms = [np.linalg.norm(Ai, 2) for Ai in sys.Ai]
    mu = [np.linalg.eigvalsh((Ai + Ai.T) / 2).max() for Ai in sys.Ai]
    sigma_G = float(max(np.linalg.norm(G) for G in sys.Gi))
    C1 = max(0.0, 2 * max(mu))
    if variant == "faithful":
        C0, C2, C3 = 2 * sn ** 2 * max(norms), 2 * max(norms), 1.0
        a2 = math.sqrt(N) * C0 + C2
    elif variant == "tight":
        dA = max(np.linalg.norm(Ai - Abar, 2) for Ai in sys.Ai)
        C0, C2 = 2 * sn ** 2 * dA, 2 * dA
        C3 = max(np.linalg.norm(G - sys.Gbar) for G in sys.Gi) / sigma_G
        a2 = C0 + C2
    else:
        raise ValueError(f"unknown variant {variant!r}")
    fiedler = float(np.sort(np.linalg.eigvalsh(sys.laplacian))[1]) if N > 1 else 0.0
    kappa = math.sqrt(max(sn ** 2, 1.0) / min(s1 ** 2, 1.0))
    return ExplicitBound(variant, C0, C1, C2, C3, s1, a2, sigma_G, s1, sn, kappa, fiedler,
                         float(np.linalg.norm(lyapunov_S(sys))), N, sys.alpha)



# -- the steady states over a range of rates ----------------------------------------------------

def steady_state_sweep(s: GossipSystem, lams: np.ndarray, S: np.ndarray | None, S_true: np.ndarray | None,
                       eig_max: int) -> dict[str, np.ndarray]:
    """Steady states of (9) and of the exact mean covariance at every rate of `lams`, their deviations from S and
    S_true (solved for directly, with their round-off bounds; S None: Ā is not Hurwitz, no deviation) and the
    spectral abscissae of both generators (that of the exact covariance up to size `eig_max`)."""
    N, n = s.N, s.n
    hurwitz = S is not None
    L = len(lams)
    P_inf, J_inf = np.full((L, N, n, n), np.nan), np.full((L, N, n, n), np.nan)
    dev_P, dev_J = np.full((L, N, n, n), np.nan), np.full((L, N, n, n), np.nan)
    err_P, err_J, cond_J = np.full(L, np.nan), np.full(L, np.nan), np.full(L, np.nan)
    absc9, tol9 = np.zeros(L), np.zeros(L)
    abscS = np.full(L, np.nan)
    for k, lam in enumerate(lams):
        absc9[k], tol9[k] = bound_abscissa(s, lam), bound_abscissa_tolerance(s, lam)
        p = bound_steady(s, lam)
        if p is not None:
            P_inf[k] = p
        if hurwitz and (dv := bound_steady_deviation(s, lam, S)) is not None:
            dev_P[k] = dv
            err_P[k] = deviation_error(bound_generator(s, lam)[0], dv, s, S)
        if N * n <= MAX_JOINT_DIM:
            M, g = joint_generator_sym(s, lam)
            if len(M) <= eig_max:
                abscS[k] = float(np.max(np.linalg.eigvals(M).real))
            if joint_hurwitz(s, lam):
                lu = scipy.linalg.lu_factor(M)
                cond_J[k] = 1.0 / max(scipy.linalg.lapack.dgecon(lu[0], float(np.abs(M).sum(axis=0).max()), norm="1")[0], 1e-300)
                J_inf[k] = diagonal_blocks(from_sym_coords(scipy.linalg.lu_solve(lu, -g), N * n), N, n)
                if hurwitz and s.mode == "edge":
                    dj = joint_steady_deviation(s, lam, S_true)
                    dev_J[k] = diagonal_blocks(dj, N, n)
                    # as `deviation_error`: the residual's rounding is ~‖𝒜‖‖11ᵀ⊗S_true‖ ≤ ‖M‖‖S_true‖·N
                    err_J[k] = 10 * M.shape[0] * _EPS * cond_J[k] * (np.abs(dj).max() + N * np.abs(S_true).max())
    out = dict(sweep_bound=P_inf, sweep_joint=J_inf, sweep_dev_bound=dev_P, sweep_dev_joint=dev_J,
               sweep_dev_err=err_P, sweep_dev_joint_err=err_J, sweep_cond=cond_J,
               sweep_absc_bound=absc9, sweep_absc_tol=tol9, sweep_absc_joint=abscS)
    if hurwitz:
        for variant in ("faithful", "tight"):
            eb = explicit_bound(s, variant)
            out[f"sweep_explicit_{variant}"] = np.array([eb.value(x) for x in lams])
    return out


def deviation_error(M: np.ndarray, D: np.ndarray, s: GossipSystem, S: np.ndarray) -> float:
    """Round-off bound of the deviation D = 𝒫^∞ − S solved from M vec D = −r (`bound_steady_deviation`):
    10·dim·eps·κ(M)·(‖D‖ + ‖r‖/‖M‖) with the residual's own rounding ‖r‖ ~ 2‖A_i‖‖S‖ + ‖G_i‖
    and κ the 1-norm condition number (LAPACK estimate)."""
    lu = scipy.linalg.lu_factor(M)
    norm = float(np.abs(M).sum(axis=0).max())
    kappa = 1.0 / max(scipy.linalg.lapack.dgecon(lu[0], norm, norm="1")[0], 1e-300)
    r = max(2 * np.linalg.norm(A, 2) * np.linalg.norm(S, 2) + np.linalg.norm(G, 2) for A, G in zip(s.Ai, s.Gi))
    return 10 * M.shape[0] * _EPS * kappa * (float(np.abs(D).max()) + r / norm)


# -- per-path deterministic propagation (frozen clock path) ---------------------------------------

def path_bound_and_covariance(sys: GossipSystem, event_times: np.ndarray, event_clocks: np.ndarray,
                              times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For ONE fixed clock path: (P_i(t) of (14), Σ(t; τ) joint error covariance) at `times`,
    by Van Loan over every interval (slow reference, independent of the batched simulator)."""
    from .linear_flows import van_loan

    n, N = sys.n, sys.N
    Ablk = scipy.linalg.block_diag(*sys.Ai)
    Gblk = sys.joint_noise[n:, n:]
    Sig = joint_initial(sys).copy()
    P = np.array(sys.P_init, float)
    marks = sorted([(t, 0, int(c)) for t, c in zip(event_times, event_clocks) if t <= times[-1]] +
                   [(t, 1, k) for k, t in enumerate(times)])
    outP, outS = np.zeros((len(times), N, n, n)), np.zeros((len(times), N * n, N * n))
    t_cur = 0.0
    for t, kind, idx in marks:
        d = t - t_cur
        if d > 0:
            Phi, Q = van_loan(Ablk, Gblk, d)
            Sig = Phi @ Sig @ Phi.T + Q
            for i in range(N):
                s = slice(i * n, (i + 1) * n)
                P[i] = Phi[s, s] @ P[i] @ Phi[s, s].T + Q[s, s]
            t_cur = t
        if kind == 0:
            J = sys.jump(idx)
            Jz = np.kron(J, np.eye(n))
            Sig = Jz @ Sig @ Jz.T
            P = np.einsum("ij,jkl->ikl", J, P)
        else:
            outP[idx], outS[idx] = P, Sig
    return outP, outS


def gridded_scheme_covariance(sys: GossipSystem, rate: float, step: float, n_steps: int, every: int) -> np.ndarray:
    """The exact mean joint error covariance OF THE GRIDDED SIMULATOR (not of the model): flow
    over h/2, Poisson(λh) rings of every clock (J_c^count; forward clock order on odd steps,
    reversed on even steps), flow over h/2.
    Its distance to `joint_transient` is the simulator's discretisation bias. Returns Σ at
    steps 0, every, 2·every, …: (n_steps // every + 1, Nn, Nn)."""
    from .linear_flows import van_loan

    n, N = sys.n, sys.N
    D = N * n
    Ablk = scipy.linalg.block_diag(*sys.Ai)
    Phi, Q = van_loan(Ablk, sys.joint_noise[n:, n:], step / 2)
    mu = rate * step                               # Poisson(λh) ring counts, up to a tail below 1e-16
    probs = [math.exp(-mu)]
    while 1.0 - sum(probs) > 1e-16 and len(probs) < 200:
        probs.append(probs[-1] * mu / len(probs))
    probs = np.array(probs + [0.0]) / sum(probs)
    c_max = len(probs) - 1
    jumps = []
    for c in range(len(sys.clocks)):
        Jc = np.kron(sys.jump(c), np.eye(n))
        Ms, Jp = 0.0, np.eye(D)
        for k in range(c_max + 1):
            Ms = Ms + probs[k] * sym_reduce(np.kron(Jp, Jp), D)
            Jp = Jc @ Jp
        jumps.append(Ms)
    flow = sym_reduce(np.kron(Phi, Phi), D)
    q = sym_coords(Q)
    Q_dim = len(q)
    # every step as an affine map on the symmetric coordinates of Σ, written as an augmented
    # matrix [[F, c], [0, 1]]
    steps = []
    for seq in (jumps, jumps[::-1]):              # odd steps: forward clock order; even: reversed
        op = flow
        for Ms in seq:
            op = Ms @ op
        aug = np.eye(Q_dim + 1)
        aug[:-1, :-1] = flow @ op
        aug[:-1, -1] = flow @ _apply_all(seq, q) + q
        steps.append(aug)
    odd, even = steps
    # one output interval of `every` steps, starting on an odd or on an even step (products by squaring)
    half = every // 2
    from_odd = np.linalg.matrix_power(even @ odd, half)
    from_even = np.linalg.matrix_power(odd @ even, half)
    if every % 2:
        from_odd, from_even = odd @ from_odd, even @ from_even
    out = [joint_initial(sys)]
    v = np.append(sym_coords(out[0]), 1.0)
    start = 1
    for _ in range(n_steps // every):
        v = (from_odd if start % 2 else from_even) @ v
        start += every
        out.append(from_sym_coords(v[:-1], D))
    return np.array(out)


def _apply_all(mats, v):
    for M in mats:
        v = M @ v
    return v
