"""Deterministic second-moment theory of the gossiping constant-gain filters
(see `estimators.gossip_filter` for the model).

* eq. (9), the mean of the per-path bound P_i of eq. (14): 𝒫̇_i = A_i𝒫_i + 𝒫_iA_iᵀ + G_i
  + λ Σ_c [(J_c ⊗ I)𝒫 − 𝒫]_i, which is λα Σ_{j∈N_i}(𝒫_j − 𝒫_i) in both clock modes; its
  generator M_9(λ) on p = [vec 𝒫_1; …; vec 𝒫_N] (column-major vec), transient, steady state
  and critical rate;
* the exact mean joint error covariance Σ̄(t) = E[e eᵀ] (expectation over noise and clocks):
  Σ̄' = 𝒜Σ̄ + Σ̄𝒜ᵀ + 𝒢 + λ Σ_c (𝒥_cΣ̄𝒥_cᵀ − Σ̄), 𝒜 = blkdiag(A_i), 𝒥_c = J_c ⊗ I_n;
* the Lyapunov solutions R of (10) and S of (11), the large-rate limit S_true of the true
  covariance, and an explicit version of the bound (12) with computable constants.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy.linalg as sla

from .gossip_filter import GossipSystem
from .linear_flows import affine_flow_grid, affine_steady_state, critical_parameter, spectral_abscissa

MAX_JOINT_DIM = 40     # N·n above which the dense (Nn)²×(Nn)² generator of Σ̄ is not formed


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

def bound_generator(sys: GossipSystem, rate: float) -> tuple[np.ndarray, np.ndarray]:
    """(M_9(λ), g) with ṗ = M_9 p + g."""
    n, N = sys.n, sys.N
    M = sla.block_diag(*[lyapunov_generator(Ai) for Ai in sys.Ai])
    jump = sum(sys.jump(c) - np.eye(N) for c in range(len(sys.clocks)))
    M = M + rate * np.kron(jump, np.eye(n * n))
    return M, np.concatenate([vec(G) for G in sys.Gi])


def bound_transient(sys: GossipSystem, rate: float, step: float, n_steps: int, P_init=None) -> np.ndarray:
    """𝒫_i(k·step), (n_steps + 1, N, n, n), 𝒫_i(0) = P_init[i] (default E[e_i(0)e_i(0)ᵀ] = P0)."""
    M, g = bound_generator(sys, rate)
    if P_init is None:
        P_init = np.broadcast_to(sys.P0, (sys.N, sys.n, sys.n))
    p = affine_flow_grid(M, g, np.concatenate([vec(P) for P in P_init]), step, n_steps)
    return unvec(p.reshape(n_steps + 1, sys.N, -1), sys.n)


def bound_steady(sys: GossipSystem, rate: float) -> np.ndarray | None:
    """𝒫_i^∞(λ) (N, n, n), or None when M_9(λ) is not Hurwitz (the bound diverges)."""
    M, g = bound_generator(sys, rate)
    p = affine_steady_state(M, g)
    return None if p is None else unvec(p.reshape(sys.N, -1), sys.n)


def bound_abscissa(sys: GossipSystem, rate: float) -> float:
    return spectral_abscissa(bound_generator(sys, rate)[0])


def critical_rate_bound(sys: GossipSystem) -> float:
    """λ_crit of (9): inf{λ : M_9(λ) Hurwitz} (0 if every A_i is Hurwitz, inf if never)."""
    return critical_parameter(lambda lam: bound_abscissa(sys, lam))


# -- exact mean joint covariance ----------------------------------------------------------------

def joint_generator(sys: GossipSystem, rate: float) -> tuple[np.ndarray, np.ndarray]:
    """(M_Σ(λ), g_Σ) on vec Σ̄ (Nn × Nn, column-major)."""
    n, N = sys.n, sys.N
    D = N * n
    if D > MAX_JOINT_DIM:
        raise ValueError(f"N·n = {D} > {MAX_JOINT_DIM}: the dense generator of the joint covariance is too large")
    Ablk = sla.block_diag(*sys.Ai)
    M = lyapunov_generator(Ablk)
    I = np.eye(D * D)
    for c in range(len(sys.clocks)):
        Jz = np.kron(sys.jump(c), np.eye(n))
        M += rate * (np.kron(Jz, Jz) - I)
    G = sys.joint_noise[n:, n:]
    return M, vec(G)


def joint_initial(sys: GossipSystem) -> np.ndarray:
    return sys.joint_second_moment0()[sys.n:, sys.n:]


def joint_transient(sys: GossipSystem, rate: float, step: float, n_steps: int) -> np.ndarray:
    """Σ̄(k·step): (n_steps + 1, Nn, Nn)."""
    M, g = joint_generator(sys, rate)
    D = sys.N * sys.n
    p = affine_flow_grid(M, g, vec(joint_initial(sys)), step, n_steps)
    return unvec(p, D)


def joint_steady(sys: GossipSystem, rate: float) -> np.ndarray | None:
    M, g = joint_generator(sys, rate)
    p = affine_steady_state(M, g)
    return None if p is None else unvec(p, sys.N * sys.n)


def critical_rate_joint(sys: GossipSystem, upper: float | None = None) -> float:
    """λ_crit of the exact mean covariance; `upper` (e.g. λ_crit of (9), which is never smaller:
    𝒫_i ⪰ E[e_ie_iᵀ]) narrows the bisection."""
    f = lambda lam: spectral_abscissa(joint_generator(sys, lam)[0])
    if upper is not None and math.isfinite(upper) and upper > 0 and f(upper * (1 + 1e-9)) < 0:
        return critical_parameter(f, start=upper * (1 + 1e-9))
    return critical_parameter(f)


def diagonal_blocks(S: np.ndarray, N: int, n: int) -> np.ndarray:
    """(…, Nn, Nn) → (…, N, n, n)."""
    return np.stack([S[..., i * n:(i + 1) * n, i * n:(i + 1) * n] for i in range(N)], axis=-3)


# -- (10), (11) and the large-rate limits -----------------------------------------------------------

def lyapunov_R(Abar: np.ndarray) -> np.ndarray:
    """R of (10) as the Lyapunov equality RĀ + ĀᵀR = −I (the Loewner-smallest R satisfying (10))."""
    R = sla.solve_continuous_lyapunov(Abar.T, -np.eye(len(Abar)))
    return (R + R.T) / 2


def lyapunov_S(sys: GossipSystem) -> np.ndarray:
    """S of (11): ĀS + SĀᵀ + BBᵀ + (1/N) Σ L_iV_iL_iᵀ = 0."""
    S = sla.solve_continuous_lyapunov(sys.Abar, -sys.Gbar)
    return (S + S.T) / 2


def lyapunov_S_true(sys: GossipSystem) -> np.ndarray:
    """lim_{λ→∞} of the true E[e_ie_iᵀ] (edge clocks): ĀS + SĀᵀ + BBᵀ + (1/N²) Σ L_iV_iL_iᵀ = 0."""
    N = sys.N
    G = sys.B @ sys.B.T + sum(L @ V @ L.T for L, V in zip(sys.L, sys.V)) / N ** 2
    S = sla.solve_continuous_lyapunov(sys.Abar, -G)
    return (S + S.T) / 2


# -- explicit (12) ------------------------------------------------------------------------------------

@dataclass(frozen=True)
class ExplicitBound:
    """Constants of the explicit version of (12) (DERIVED in the spec, §4.5) for one variant."""

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
        """λ_thr: the explicit 'λ sufficiently large' (b > 0 beyond it)."""
        return (self.C1 + self.a2 ** 2 / (2 * self.a1)) / (self.alpha * self.fiedler)

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


# -- per-path deterministic propagation (frozen clock path) ---------------------------------------

def path_bound_and_covariance(sys: GossipSystem, event_times: np.ndarray, event_clocks: np.ndarray,
                              times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For ONE fixed clock path: (P_i(t) of (14), Σ(t; τ) joint error covariance) at `times`,
    by Van Loan over every interval (slow reference, independent of the batched simulator)."""
    from .linear_flows import van_loan

    n, N = sys.n, sys.N
    Ablk = sla.block_diag(*sys.Ai)
    Gblk = sys.joint_noise[n:, n:]
    Sig = joint_initial(sys).copy()
    P = diagonal_blocks(Sig, N, n).copy()
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
    from scipy.stats import poisson

    from .linear_flows import van_loan

    n, N = sys.n, sys.N
    D = N * n
    Ablk = sla.block_diag(*sys.Ai)
    Phi, Q = van_loan(Ablk, sys.joint_noise[n:, n:], step / 2)
    c_max = int(poisson.ppf(1 - 1e-16, rate * step)) + 2
    probs = poisson.pmf(np.arange(c_max + 1), rate * step)
    probs = probs / probs.sum()
    jumps = []
    for c in range(len(sys.clocks)):
        Jc = np.kron(sys.jump(c), np.eye(n))
        Ms, Jp = np.zeros((D * D, D * D)), np.eye(D)
        for k in range(c_max + 1):
            Ms += probs[k] * np.kron(Jp, Jp)
            Jp = Jc @ Jp
        jumps.append(Ms)
    flow = np.kron(Phi, Phi)
    q = vec(Q)
    ops = []
    for seq in (jumps, jumps[::-1]):              # odd steps: forward clock order; even: reversed
        op = flow
        for Ms in seq:
            op = Ms @ op
        ops.append((flow @ op, flow @ _apply_all(seq, q) + q))
    out = [joint_initial(sys)]
    v = vec(out[0])
    for s in range(1, n_steps + 1):
        op, const = ops[0] if s % 2 else ops[1]
        v = op @ v + const
        if s % every == 0:
            out.append(unvec(v, D))
    return np.array(out)


def _apply_all(mats, v):
    for M in mats:
        v = M @ v
    return v
