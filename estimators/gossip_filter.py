"""Constant-gain continuous-time filters at the nodes of a graph whose edges fuse estimates
at the rings of independent Poisson clocks (random pairwise gossip), simulated exactly.

Model (Itô): dx = A x dt + B dω, node i measures dy_i = H_i x dt + dv_i, E[dv_i dv_iᵀ] = V_i dt,
and runs the filter (flow, eq. (5))

    dx̂_i = (A − L_i H_i) x̂_i dt + L_i dy_i

between its communication instants. Each clock c has rate λ; when it rings the estimates
jump (eq. (6)) by x̂ ← (J_c ⊗ I_n) x̂ with

* ``mode="edge"`` (default): one clock per undirected edge {i, j}; both endpoints update
  with the pre-jump values, J = I − α (u_i − u_j)(u_i − u_j)ᵀ;
* ``mode="ordered"``: one clock per ordered pair (i ← j); only the receiver i updates,
  J = I − α u_i (u_i − u_j)ᵀ.

The errors e_i = x − x̂_i obey de_i = A_i e_i dt + B dω − L_i dv_i, A_i = A − L_i H_i, and jump
with the same J. Both simulators below propagate z = (x, e_1, …, e_N) with the exact Gaussian
transition of this linear SDE (Van Loan), batched over Monte Carlo trials on a leading axis:

* `simulate_event_driven`: every trial has its own exact Poisson event times; the state is
  propagated exactly from event to event (different δ per trial), so the law of the sampled
  paths is exact. Along every path it also propagates the exact conditional second moment
  Σ(t; τ) = E[z zᵀ | clocks] and the per-path bound P_i(t; τ) of eq. (14).
* `simulate_gridded`: a fixed step h, exact flow over h/2, then the Poisson number of rings
  of every clock in the step (applied as J_c^count, clocks in forward order on odd steps and
  reversed order on even steps), then h/2 more (Strang splitting; with the alternating order
  the bias of the mean second moments is O(h²), see `gossip_covariance.gridded_scheme_covariance`).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property
from typing import Sequence

import numpy as np
import scipy.linalg as sla

from .linear_flows import BlockDiagonalFlow, DenseFlow, van_loan

MODES = ("edge", "ordered")
#: eigenvector condition number κ above which the batched eigenbasis flows are not used: their noise
#: covariances carry a relative rounding error ~eps·κ² (entries of size κ²‖G‖ cancel), 2e-8 at κ = 1e4
EIGEN_COND_MAX = 1e4


@dataclass(frozen=True)
class GossipSystem:
    """Plant, sensors, gains and communication of the network of filters.

    A (n, n), B (n, m); H[i] (p_i, n), V[i] (p_i, p_i) ≻ 0, L[i] (n, p_i) per node;
    edges: undirected pairs (i, j), 0-based; alpha: fusion weight π_ij; mode: see module doc;
    P0 (n, n) and m0 (n,): x(0) ~ N(m0, P0), every x̂_i(0) = m0.
    """

    A: np.ndarray
    B: np.ndarray
    H: tuple
    V: tuple
    L: tuple
    edges: tuple
    alpha: float
    mode: str = "edge"
    P0: np.ndarray | None = None
    m0: np.ndarray | None = None

    def __post_init__(self):
        if self.mode not in MODES:
            raise ValueError(f"mode must be one of {MODES}, got {self.mode!r}")
        if self.P0 is None:
            object.__setattr__(self, "P0", np.eye(self.n))
        if self.m0 is None:
            object.__setattr__(self, "m0", np.zeros(self.n))

    # -- sizes and derived matrices ---------------------------------------------------------
    @property
    def n(self) -> int:
        return self.A.shape[0]

    @property
    def N(self) -> int:
        return len(self.H)

    @cached_property
    def Ai(self) -> np.ndarray:
        """A_i = A − L_i H_i, (N, n, n)."""
        return np.array([self.A - L @ H for L, H in zip(self.L, self.H)])

    @cached_property
    def Gi(self) -> np.ndarray:
        """G_i = BBᵀ + L_i V_i L_iᵀ, (N, n, n)."""
        Q = self.B @ self.B.T
        return np.array([Q + L @ V @ L.T for L, V in zip(self.L, self.V)])

    @property
    def Abar(self) -> np.ndarray:
        return self.Ai.mean(axis=0)

    @property
    def Gbar(self) -> np.ndarray:
        return self.Gi.mean(axis=0)

    @cached_property
    def laplacian(self) -> np.ndarray:
        Lap = np.zeros((self.N, self.N))
        for i, j in self.edges:
            Lap[i, j] -= 1
            Lap[j, i] -= 1
            Lap[i, i] += 1
            Lap[j, j] += 1
        return Lap

    @property
    def degrees(self) -> np.ndarray:
        return np.diag(self.laplacian).astype(int)

    @cached_property
    def clocks(self) -> tuple[tuple[int, int], ...]:
        """(i, j) per clock: an undirected edge ("edge") or receiver i ← sender j ("ordered")."""
        if self.mode == "edge":
            return tuple((int(i), int(j)) for i, j in self.edges)
        return tuple(c for i, j in self.edges for c in ((int(i), int(j)), (int(j), int(i))))

    def jump(self, c: int) -> np.ndarray:
        """J_c (N, N) of clock c."""
        i, j = self.clocks[c]
        d = np.zeros(self.N)
        d[i], d[j] = 1.0, -1.0
        if self.mode == "edge":
            return np.eye(self.N) - self.alpha * np.outer(d, d)
        u = np.zeros(self.N)
        u[i] = 1.0
        return np.eye(self.N) - self.alpha * np.outer(u, d)

    def jump_coefficients(self, counts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """For `counts` rings of one clock: (keep, take) with
        new_i = keep·e_i + take·e_j (and, in "edge" mode, new_j = keep·e_j + take·e_i)."""
        c = np.asarray(counts)
        if self.mode == "edge":
            take = (1.0 - (1.0 - 2.0 * self.alpha) ** c) / 2.0
        else:
            take = 1.0 - (1.0 - self.alpha) ** c
        return 1.0 - take, take

    # -- the joint linear SDE of z = (x, e_1, …, e_N) ---------------------------------------
    @cached_property
    def joint_noise(self) -> np.ndarray:
        """Noise intensity of z: ω drives x and every e_i; v_i drives e_i only."""
        n, N = self.n, self.N
        BB = self.B @ self.B.T
        G = np.kron(np.ones((N + 1, N + 1)), BB)
        for i, (L, V) in enumerate(zip(self.L, self.V)):
            s = slice((i + 1) * n, (i + 2) * n)
            G[s, s] += L @ V @ L.T
        return (G + G.T) / 2

    @property
    def joint_blocks(self) -> list[np.ndarray]:
        return [self.A] + list(self.Ai)

    @cached_property
    def joint_drift(self) -> np.ndarray:
        return sla.block_diag(*self.joint_blocks)

    def joint_second_moment0(self) -> np.ndarray:
        """E[z(0) z(0)ᵀ] with x(0) ~ N(m0, P0) and x̂_i(0) = m0: e_i(0) = x(0) − m0."""
        n, N = self.n, self.N
        S = np.kron(np.ones((N + 1, N + 1)), self.P0)
        mm = np.outer(self.m0, self.m0)
        S[:n, :n] += mm
        return S


def kalman_bucy_split_gains(A, B, H: Sequence[np.ndarray], V: Sequence[np.ndarray]) -> tuple[tuple, np.ndarray]:
    """The default gains: the centralized steady-state Kalman–Bucy gain K = P Hᵀ V⁻¹ (P from the
    filter CARE AP + PAᵀ + BBᵀ − PHᵀV⁻¹HP = 0), cut by columns K = [K_1 … K_N], L_i = N K_i, so
    that (1/N) Σ L_i H_i = K H. Returns (L tuple, P_KB)."""
    N = len(H)
    Hs = np.vstack(H)
    Vs = sla.block_diag(*V)
    P = sla.solve_continuous_are(A.T, Hs.T, B @ B.T, Vs)
    P = (P + P.T) / 2
    K = P @ Hs.T @ np.linalg.inv(Vs)
    cuts = np.cumsum([0] + [h.shape[0] for h in H])
    return tuple(N * K[:, cuts[i]:cuts[i + 1]] for i in range(N)), P


# -- Poisson clocks --------------------------------------------------------------------------

def sample_clock_events(n_clocks: int, rate: float, horizon: float, n_trials: int,
                        rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Exact event times of n_clocks independent Poisson clocks on [0, horizon], per trial.

    Returns (times (K, M), clock ids (K, M)), each row sorted by time and padded with
    (inf, −1); M is the largest number of events of any trial. Counts are Poisson, and given
    the count the times are i.i.d. uniform (order statistics), which is the Poisson law.
    """
    counts = rng.poisson(rate * horizon, size=(n_trials, n_clocks))
    per_trial = counts.sum(axis=1)
    M = int(per_trial.max()) if n_trials else 0
    times = np.full((n_trials, M), np.inf)
    ids = np.full((n_trials, M), -1, dtype=np.int64)
    if M == 0:
        return times, ids
    total = int(per_trial.sum())
    u = rng.random(total) * horizon
    clock_of = np.repeat(np.tile(np.arange(n_clocks), n_trials), counts.ravel())
    trial_of = np.repeat(np.arange(n_trials), per_trial)
    slot = np.arange(total) - np.repeat(np.cumsum(per_trial) - per_trial, per_trial)
    times[trial_of, slot] = u
    ids[trial_of, slot] = clock_of
    order = np.argsort(times, axis=1, kind="stable")
    return np.take_along_axis(times, order, 1), np.take_along_axis(ids, order, 1)


# -- exact event-driven simulator --------------------------------------------------------------

@dataclass
class EventDrivenRun:
    """Results of `simulate_event_driven` at the output times `times` (T,).

    z: (K, T, (N+1)n) sampled joint states (x, e_1..e_N) (None without noise sampling);
    sigma: (K, T, N, n, n) exact per-path E[e_i e_iᵀ | clocks] (diagonal blocks of Σ(t; τ));
    pbound: (K, T, N, n, n) per-path bound P_i(t; τ) of eq. (14);
    min_gap: (K, N) smallest eigenvalue of P_i − Σ_ii seen along the path at every event and
    output time; scale: (K, N) largest ‖P_i‖_F seen (for relative tolerances);
    event_times, event_clocks: (K, M) the clock paths (inf / −1 padded);
    condition: condition number of the eigenvector basis used for the exact flows (1 when the
    dense Van Loan fallback was used), which scales the rounding of every propagated quantity.
    """

    times: np.ndarray
    z: np.ndarray | None
    sigma: np.ndarray
    pbound: np.ndarray
    min_gap: np.ndarray
    scale: np.ndarray
    event_times: np.ndarray
    event_clocks: np.ndarray
    cross: np.ndarray | None = field(default=None)
    condition: float = 1.0


def _controllable_basis(A: np.ndarray, G: np.ndarray, tol: float = 1e-9) -> np.ndarray:
    """Orthonormal basis of the controllable subspace of (A, G^{1/2}) (block Arnoldi with
    re-orthogonalisation): every Van Loan noise Q(δ), δ > 0, has exactly this range."""
    w, U = np.linalg.eigh(G)
    keep = w > tol * max(w.max(), 1e-300)
    basis = U[:, keep]
    new = basis
    while new.shape[1] and basis.shape[1] < len(A):
        cand = A @ new
        for _ in range(2):
            cand = cand - basis @ (basis.T @ cand)
        Uc, s, _ = np.linalg.svd(cand, full_matrices=False)
        scale = np.linalg.norm(A, 2) + 1.0
        new = Uc[:, s > tol * scale]
        basis = np.hstack([basis, new])
    return basis


def _psd_factor(Q: np.ndarray, jitter: float = 1e-13) -> np.ndarray:
    """A batch of square roots F with F Fᵀ ≈ Q for (near-)PSD Q.

    Cholesky of Q + jitter·max(diag Q)·I first, a perturbation at the rounding level of Q itself
    (`jitter` ≥ 1e-13; larger when Q was formed through an ill-conditioned eigenvector basis),
    falling back to a clipped eigendecomposition for the rows that are numerically singular."""
    scale = np.max(np.diagonal(Q, axis1=-2, axis2=-1), axis=-1)
    Qr = Q + (jitter * scale)[..., None, None] * np.eye(Q.shape[-1])
    try:
        return np.linalg.cholesky(Qr)
    except np.linalg.LinAlgError:
        pass

    def clipped(X):
        w, U = np.linalg.eigh(X)
        return U * np.sqrt(np.clip(w, 0.0, None))[..., None, :]

    if Q.ndim == 2:
        return clipped(Q)
    bad = np.linalg.eigvalsh(Qr)[:, 0] <= 0
    out = np.empty_like(Q)
    out[bad] = clipped(Q[bad])
    try:
        out[~bad] = np.linalg.cholesky(Qr[~bad])
    except np.linalg.LinAlgError:
        out[~bad] = clipped(Q[~bad])
    return out


def simulate_event_driven(sys: GossipSystem, rate: float, times: np.ndarray, n_trials: int, rng: np.random.Generator,
                          *, sample: bool = True, clock_path: tuple[np.ndarray, np.ndarray] | None = None,
                          cross_pairs: Sequence[tuple[int, int]] = ()) -> EventDrivenRun:
    """Exact simulation (in law) on the output grid `times` (increasing, times[0] = 0).

    `clock_path`: optionally one fixed clock path (times (M,), clock ids (M,)) shared by all
    trials (Proposition III.2 "for fixed sampling times"); otherwise every trial draws its
    own exact Poisson clocks. `sample=False` propagates only Σ(t; τ) and P(t; τ).
    """
    times = np.asarray(times, float)
    T, K, n, N = len(times), n_trials, sys.n, sys.N
    d = (N + 1) * n
    horizon = float(times[-1])
    if clock_path is None:
        ev_t, ev_c = sample_clock_events(len(sys.clocks), rate, horizon, K, rng)
    else:
        t0, c0 = (np.asarray(a) for a in clock_path)
        keep = t0 <= horizon
        ev_t = np.broadcast_to(t0[keep], (K, int(keep.sum()))).copy()
        ev_c = np.broadcast_to(c0[keep].astype(np.int64), ev_t.shape).copy()
    M = ev_t.shape[1]
    ev_t = np.concatenate([ev_t, np.full((K, 1), np.inf)], axis=1)
    ev_c = np.concatenate([ev_c, np.full((K, 1), -1)], axis=1)

    flow = BlockDiagonalFlow.of(sys.joint_blocks, sys.joint_noise)
    if not flow.condition < EIGEN_COND_MAX:  # ill-conditioned eigenvectors: exact but slower dense Van Loan
        flow = DenseFlow.of(sys.joint_blocks, sys.joint_noise)
    basis = _controllable_basis(sys.joint_drift, sys.joint_noise)
    # the noise covariances are formed through the eigenvector basis: their rounding is ~eps·κ²
    jitter = max(1e-13, 10 * np.finfo(float).eps * min(flow.condition, 1e8) ** 2) if isinstance(flow, BlockDiagonalFlow) \
        else 1e-13
    clocks = np.array(sys.clocks, dtype=np.int64).reshape(-1, 2)
    # pieces of P_i's own flow: block (i+1, i+1) of the joint flow is A_i with noise G_i
    S0 = sys.joint_second_moment0()
    Sig = np.broadcast_to(S0, (K, d, d)).copy()
    P = np.broadcast_to(np.array([S0[(i + 1) * n:(i + 2) * n, (i + 1) * n:(i + 2) * n] for i in range(N)]),
                        (K, N, n, n)).copy()                 # P_i(0) = E[e_i(0) e_i(0)ᵀ]

    z = None
    if sample:
        z = np.zeros((K, d))
        x0 = sys.m0 + rng.standard_normal((K, n)) @ _psd_factor(sys.P0[None])[0].T
        z[:, :n] = x0
        z[:, n:] = np.tile(x0 - sys.m0, N)
        zs = np.zeros((K, T, d))
        zs[:, 0] = z
    sig_out = np.zeros((K, T, N, n, n))
    p_out = np.zeros((K, T, N, n, n))
    cross = np.zeros((K, T, len(cross_pairs), n, n)) if cross_pairs else None

    def diag_blocks(S):
        return np.stack([S[:, (i + 1) * n:(i + 2) * n, (i + 1) * n:(i + 2) * n] for i in range(N)], axis=1)

    def store(rows, gidx):
        sig_out[rows, gidx] = diag_blocks(Sig[rows])
        p_out[rows, gidx] = P[rows]
        if sample:
            zs[rows, gidx] = z[rows]
        if cross is not None:
            for q, (a, b) in enumerate(cross_pairs):
                cross[rows, gidx, q] = Sig[rows][:, (a + 1) * n:(a + 2) * n, (b + 1) * n:(b + 2) * n]

    store(np.arange(K), 0)
    min_gap = np.full((K, N), np.inf)
    scale = np.tile(np.linalg.norm(P[0], axis=(1, 2)), (K, 1))
    t_cur = np.zeros(K)
    eptr = np.zeros(K, dtype=np.int64)
    gptr = np.ones(K, dtype=np.int64)
    rows_all = np.arange(K)
    while True:
        active = gptr < T
        if not active.any():
            break
        r = rows_all[active]
        te = ev_t[r, eptr[r]]
        tg = times[gptr[r]]
        is_event = te < tg
        t_next = np.where(is_event, te, tg)
        delta = t_next - t_cur[r]
        if clock_path is not None:                        # one δ for every trial: factor once
            Phi = np.broadcast_to(flow.transition(delta[:1]), (len(r), N + 1, n, n))
            Q = np.broadcast_to(flow.noise(delta[:1]), (len(r), d, d))
        else:
            Phi = flow.transition(delta)                  # (k, N+1, n, n)
            Q = flow.noise(delta)                         # (k, d, d)
        # Σ ← Φ Σ Φᵀ + Q, Φ block diagonal
        Phd = np.zeros((len(r), d, d))
        for a in range(N + 1):
            Phd[:, a * n:(a + 1) * n, a * n:(a + 1) * n] = Phi[:, a]
        Sig[r] = Phd @ Sig[r] @ Phd.transpose(0, 2, 1) + Q
        # P_i ← e^{A_i δ} P_i e^{A_iᵀ δ} + ∫ e^{A_i s} G_i e^{A_iᵀ s} ds  (= block (i+1, i+1) of Q)
        Pi = Phi[:, 1:] @ P[r] @ Phi[:, 1:].transpose(0, 1, 3, 2)
        P[r] = Pi + diag_blocks(Q)
        if sample:
            zb = (Phd @ z[r][:, :, None])[:, :, 0]
            if clock_path is not None:
                Qc = basis.T @ Q[0] @ basis
                F = np.broadcast_to(_psd_factor(((Qc + Qc.T) / 2)[None], jitter)[0], (len(r),) + Qc.shape)
            else:
                Qc = basis.T @ Q @ basis
                F = _psd_factor((Qc + Qc.transpose(0, 2, 1)) / 2, jitter)
            xi = (F @ rng.standard_normal((len(r), basis.shape[1], 1)))[:, :, 0] @ basis.T
            z[r] = zb + xi
        t_cur[r] = t_next
        # jumps at events
        ev_rows = r[is_event]
        if len(ev_rows):
            cid = ev_c[ev_rows, eptr[ev_rows]]
            ci, cj = clocks[cid, 0], clocks[cid, 1]
            a = sys.alpha
            both = sys.mode == "edge"
            # errors
            if sample:
                zz = z[ev_rows].reshape(len(ev_rows), N + 1, n)
                ei, ej = zz[np.arange(len(ev_rows)), ci + 1].copy(), zz[np.arange(len(ev_rows)), cj + 1].copy()
                zz[np.arange(len(ev_rows)), ci + 1] = (1 - a) * ei + a * ej
                if both:
                    zz[np.arange(len(ev_rows)), cj + 1] = (1 - a) * ej + a * ei
                z[ev_rows] = zz.reshape(len(ev_rows), d)
            # Σ ← 𝒥 Σ 𝒥ᵀ with 𝒥 = blkdiag(I_n, J_c ⊗ I_n)
            Jz = np.broadcast_to(np.eye(N + 1), (len(ev_rows), N + 1, N + 1)).copy()
            k_ = np.arange(len(ev_rows))
            Jz[k_, ci + 1, ci + 1] = 1 - a
            Jz[k_, ci + 1, cj + 1] = a
            if both:
                Jz[k_, cj + 1, cj + 1] = 1 - a
                Jz[k_, cj + 1, ci + 1] = a
            Jd = np.kron(Jz, np.eye(n))                     # (k, d, d): blkdiag(I_n, J_c ⊗ I_n)
            Sig[ev_rows] = Jd @ Sig[ev_rows] @ Jd.transpose(0, 2, 1)
            # P (eq. 14b): convex combination with pre-jump values
            Pe = P[ev_rows]
            Pi_, Pj_ = Pe[k_, ci].copy(), Pe[k_, cj].copy()
            Pe[k_, ci] = (1 - a) * Pi_ + a * Pj_
            if both:
                Pe[k_, cj] = (1 - a) * Pj_ + a * Pi_
            P[ev_rows] = Pe
            eptr[ev_rows] += 1
        grid_rows = r[~is_event]
        if len(grid_rows):
            store(grid_rows, gptr[grid_rows])
            gptr[grid_rows] += 1
        # the per-path ordering P_i ≥ Σ_ii at this event or output time
        gap = P[r] - diag_blocks(Sig[r])
        mins = np.linalg.eigvalsh((gap + gap.transpose(0, 1, 3, 2)) / 2)[..., 0]
        min_gap[r] = np.minimum(min_gap[r], mins)
        scale[r] = np.maximum(scale[r], np.linalg.norm(P[r], axis=(2, 3)))
    cond = flow.condition if isinstance(flow, BlockDiagonalFlow) else 1.0
    return EventDrivenRun(times, zs if sample else None, sig_out, p_out, min_gap, scale, ev_t[:, :M], ev_c[:, :M], cross,
                          cond)


# -- gridded simulator -------------------------------------------------------------------------

@dataclass
class GriddedRun:
    """z at the output steps: (K, T, (N+1)n); events: (K, n_steps, n_clocks) ring counts per step
    (kept only for the first `keep_events` trials, else None)."""

    times: np.ndarray
    z: np.ndarray
    events: np.ndarray | None


def simulate_gridded(sys: GossipSystem, rate: float, step: float, n_steps: int, record_every: int, n_trials: int,
                     rng: np.random.Generator, *, keep_events: int = 0) -> GriddedRun:
    """Fixed-step simulation: exact Gaussian flow over h/2, Poisson(λh) rings of every clock
    (applied as J_c^count, forward clock order on odd steps, reversed on even), exact flow over h/2.

    Records z at steps 0, record_every, 2·record_every, … ≤ n_steps.
    """
    n, N, K = sys.n, sys.N, n_trials
    d = (N + 1) * n
    Phi, Q = van_loan(sys.joint_drift, sys.joint_noise, step / 2)
    w, U = np.linalg.eigh(Q)
    keep = w > 1e-14 * max(w.max(), 1e-300)
    F = U[:, keep] * np.sqrt(w[keep])                         # Q = F Fᵀ exactly up to rounding
    PhiT, FT = Phi.T.copy(), F.T.copy()
    z = np.zeros((K, d))
    x0 = sys.m0 + rng.standard_normal((K, n)) @ _psd_factor(sys.P0[None])[0].T
    z[:, :n] = x0
    z[:, n:] = np.tile(x0 - sys.m0, N)
    rec_steps = np.arange(0, n_steps + 1, record_every)
    out = np.zeros((K, len(rec_steps), d))
    out[:, 0] = z
    n_clocks = len(sys.clocks)
    events = np.zeros((min(keep_events, K), n_steps, n_clocks), dtype=np.int16) if keep_events else None
    zr = z.reshape(K, N + 1, n)
    r_out = 1
    for s in range(1, n_steps + 1):
        z = z @ PhiT + rng.standard_normal((K, F.shape[1])) @ FT
        zr = z.reshape(K, N + 1, n)
        counts = rng.poisson(rate * step, size=(K, n_clocks))
        if events is not None:
            events[:, s - 1] = counts[: events.shape[0]]
        # clocks in forward order on odd steps, reversed on even ones: the order error of two
        # rings in one step cancels between consecutive steps (global bias O(h²), not O(h))
        order = range(n_clocks) if s % 2 else range(n_clocks - 1, -1, -1)
        for c in order:
            i, j = sys.clocks[c]
            hit = np.flatnonzero(counts[:, c])
            if hit.size == 0:
                continue
            keep_c, take_c = sys.jump_coefficients(counts[hit, c])
            ei, ej = zr[hit, i + 1], zr[hit, j + 1]
            new_i = keep_c[:, None] * ei + take_c[:, None] * ej
            if sys.mode == "edge":
                zr[hit, j + 1] = keep_c[:, None] * ej + take_c[:, None] * ei
            zr[hit, i + 1] = new_i
        z = z @ PhiT + rng.standard_normal((K, F.shape[1])) @ FT
        if r_out < len(rec_steps) and s == rec_steps[r_out]:
            out[:, r_out] = z
            r_out += 1
    return GriddedRun(rec_steps * step, out, events)
