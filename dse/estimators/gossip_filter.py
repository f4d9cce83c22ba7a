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

Both stream over time (the event-driven one window of output times at a time, the gridded one
output by output, each handing its outputs to a callback), and draw their random numbers unit
by unit (`TrialDraws`), so that a trial's path does not depend on how many trials are
simulated together.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property
from typing import Callable, Sequence

import numpy as np
import scipy  # scipy.linalg loads on first use (scipy imports submodules lazily): `dse list` skips it

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
    P0 (n, n) and m0 (n,): x(0) ~ N(m0, P0), every x̂_i(0) = m0, so E[e_i(0)e_i(0)ᵀ] = P0;
    P_init (N, n, n): the initial values P_i(0) of the per-path bound (14) and of its mean (9)
    (default P0 at every node; Prop. III.2 needs P_i(0) ⪰ E[e_i(0)e_i(0)ᵀ]).
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
    P_init: np.ndarray | None = None

    def __post_init__(self):
        if self.mode not in MODES:
            raise ValueError(f"mode must be one of {MODES}, got {self.mode!r}")
        if self.P0 is None:
            object.__setattr__(self, "P0", np.eye(self.n))
        if self.m0 is None:
            object.__setattr__(self, "m0", np.zeros(self.n))
        if self.P_init is None:
            object.__setattr__(self, "P_init", np.broadcast_to(self.P0, (self.N, self.n, self.n)).copy())

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
        return scipy.linalg.block_diag(*self.joint_blocks)

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
    Vs = scipy.linalg.block_diag(*V)
    P = scipy.linalg.solve_continuous_are(A.T, Hs.T, B @ B.T, Vs)
    P = (P + P.T) / 2
    K = P @ Hs.T @ np.linalg.inv(Vs)
    cuts = np.cumsum([0] + [h.shape[0] for h in H])
    return tuple(N * K[:, cuts[i]:cuts[i + 1]] for i in range(N)), P


# -- random draws, trial by trial ----------------------------------------------------------------

class TrialDraws:
    """The random numbers of a batch of trials, drawn unit by unit.

    `rng` is a numpy Generator (one unit: the whole batch) or an object with `generators` and
    `sizes` (e.g. `dse.simulate.units.UnitStreams`): consecutive units of trials, each with its own
    generator. Every draw is made per unit, for that unit's trials only (`rows`: the sorted
    indices of the trials that draw now), so a trial's numbers depend only on its unit's
    generator and on its own history, never on which other units share the batch."""

    def __init__(self, rng, n_trials: int):
        if hasattr(rng, "generators"):
            self.generators, self.sizes = list(rng.generators), [int(m) for m in rng.sizes]
            if sum(self.sizes) != n_trials:
                raise ValueError(f"the unit sizes sum to {sum(self.sizes)}, not {n_trials} trials")
        else:
            self.generators, self.sizes = [rng], [int(n_trials)]
        self.edges = np.cumsum([0, *self.sizes])

    def _counts(self, rows) -> list[int]:
        if rows is None:
            return self.sizes
        return np.diff(np.searchsorted(rows, self.edges)).tolist()

    def _stack(self, draw, rows, tail) -> np.ndarray:
        parts = [draw(g, m) for g, m in zip(self.generators, self._counts(rows)) if m]
        if not parts:
            return np.zeros((0, *tail))
        return parts[0] if len(parts) == 1 else np.concatenate(parts, axis=0)

    def normal(self, tail: tuple[int, ...], rows=None) -> np.ndarray:
        return self._stack(lambda g, m: g.standard_normal((m, *tail)), rows, tail)

    def poisson(self, lam: float, tail: tuple[int, ...]) -> np.ndarray:
        return self._stack(lambda g, m: g.poisson(lam, size=(m, *tail)), None, tail)

    def clock_events(self, n_clocks: int, rate: float, start: float, end: float) -> tuple[np.ndarray, np.ndarray]:
        """`sample_clock_events` on [start, end) for every trial, unit by unit, padded to a common width."""
        parts = [sample_clock_events(n_clocks, rate, end, m, g, start=start) for g, m in zip(self.generators, self.sizes)]
        width = max(p[0].shape[1] for p in parts)
        times = np.concatenate([np.pad(t, ((0, 0), (0, width - t.shape[1])), constant_values=np.inf) for t, _ in parts])
        ids = np.concatenate([np.pad(c, ((0, 0), (0, width - c.shape[1])), constant_values=-1) for _, c in parts])
        return times, ids


# -- Poisson clocks --------------------------------------------------------------------------

def sample_clock_events(n_clocks: int, rate: float, horizon: float, n_trials: int,
                        rng: np.random.Generator, *, start: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Exact event times of n_clocks independent Poisson clocks on [start, horizon), per trial.

    Returns (times (K, M), clock ids (K, M)), each row sorted by time and padded with
    (inf, −1); M is the largest number of events of any trial. Counts are Poisson, and given
    the count the times are i.i.d. uniform (order statistics), which is the Poisson law.
    Disjoint intervals are independent, so a path may be drawn window by window.
    """
    counts = rng.poisson(rate * (horizon - start), size=(n_trials, n_clocks))
    per_trial = counts.sum(axis=1)
    M = int(per_trial.max()) if n_trials else 0
    times = np.full((n_trials, M), np.inf)
    ids = np.full((n_trials, M), -1, dtype=np.int64)
    if M == 0:
        return times, ids
    total = int(per_trial.sum())
    # a uniform draw can round up to `horizon` itself: keep every time strictly inside the window
    u = np.minimum(start + rng.random(total) * (horizon - start), np.nextafter(horizon, -np.inf))
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
    event_times, event_clocks: (K, M) the clock paths (inf / −1 padded);
    (these four are None when the outputs were handed to a window callback instead);
    min_gap: (K, N) smallest eigenvalue of P_i − Σ_ii seen along the path at every event and
    output time; scale: (K, N) largest ‖P_i‖_F seen (for relative tolerances);
    condition: condition number of the eigenvector basis used for the exact flows (1 when the
    dense Van Loan fallback was used), which scales the rounding of every propagated quantity.
    """

    times: np.ndarray
    z: np.ndarray | None
    sigma: np.ndarray | None
    pbound: np.ndarray | None
    min_gap: np.ndarray
    scale: np.ndarray
    event_times: np.ndarray | None
    event_clocks: np.ndarray | None
    condition: float = 1.0


@dataclass
class EventWindow:
    """What `simulate_event_driven` hands its callback for one window of output times: the
    output indices `index` (L,), the sampled states z (K, L, (N+1)n) (None without sampling), the
    per-path covariances sigma and bounds pbound (K, L, N, n, n), and the window's clock events
    (K, M) (inf / −1 padded; none for the initial output)."""

    index: np.ndarray
    z: np.ndarray | None
    sigma: np.ndarray
    pbound: np.ndarray
    event_times: np.ndarray
    event_clocks: np.ndarray


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
    and a clipped eigendecomposition for the matrices whose Cholesky factorisation fails (decided
    matrix by matrix, so that a matrix gets the same factor in any batch)."""
    scale = np.max(np.diagonal(Q, axis1=-2, axis2=-1), axis=-1)
    Qr = Q + (jitter * scale)[..., None, None] * np.eye(Q.shape[-1])
    try:
        return np.linalg.cholesky(Qr)
    except np.linalg.LinAlgError:
        pass

    def one(X, Xr):
        try:
            return np.linalg.cholesky(Xr)
        except np.linalg.LinAlgError:
            w, U = np.linalg.eigh(X)
            return U * np.sqrt(np.clip(w, 0.0, None))[..., None, :]

    if Q.ndim == 2:
        return one(Q, Qr)
    return np.stack([one(X, Xr) for X, Xr in zip(Q, Qr)])


def _initial_states(sys: GossipSystem, draws: TrialDraws) -> np.ndarray:
    """z(0) = (x(0), e_1(0), …, e_N(0)) with x(0) ~ N(m0, P0) and e_i(0) = x(0) − m0: (K, (N+1)n)."""
    n = sys.n
    x0 = sys.m0 + rowwise(draws.normal((n,)), _psd_factor(sys.P0[None])[0].T)
    return np.concatenate([x0, np.tile(x0 - sys.m0, sys.N)], axis=1)


def rowwise(X: np.ndarray, M: np.ndarray) -> np.ndarray:
    """X @ M row by row (a batch of (1, a) @ (a, b) products): unlike one (K, a) @ (a, b) product,
    whose rows BLAS may round differently for different K, each row's result does not depend on
    the others."""
    return (X[:, None, :] @ M)[:, 0]


def default_window(sys: GossipSystem, rate: float, output_step: float, n_outputs: int, *, sample: bool = True) -> int:
    """Output intervals per window of `simulate_event_driven`: about EVENTS_PER_WINDOW expected
    events per trial, and at most OUTPUT_BYTES_PER_WINDOW of stored outputs per trial (a function
    of the model only: the window decides the order of the draws, so it must not depend on memory)."""
    expected = max(rate * len(sys.clocks) * output_step, 1e-300)
    per_output = 8 * (((sys.N + 1) * sys.n if sample else 0) + 2 * sys.N * sys.n * sys.n)
    w = min(math.ceil(EVENTS_PER_WINDOW / expected), OUTPUT_BYTES_PER_WINDOW // per_output)
    return int(max(1, min(w, n_outputs)))


#: expected events per trial in one window of the event-driven simulator
EVENTS_PER_WINDOW = 64
#: stored outputs per trial in one window (bytes)
OUTPUT_BYTES_PER_WINDOW = 64 * 1024


def simulate_event_driven(sys: GossipSystem, rate: float, times: np.ndarray, n_trials: int, rng, *,
                          sample: bool = True, clock_path: tuple[np.ndarray, np.ndarray] | None = None,
                          window: int | None = None,
                          on_window: Callable[[EventWindow], None] | None = None) -> EventDrivenRun:
    """Exact simulation (in law) on the output grid `times` (increasing, times[0] = 0).

    `clock_path`: optionally one fixed clock path (times (M,), clock ids (M,)) shared by all
    trials (Proposition III.2 "for fixed sampling times"); otherwise every trial draws its
    own exact Poisson clocks. `sample=False` propagates only Σ(t; τ) and P(t; τ).

    Time is streamed in windows of `window` output intervals (default: the whole horizon): the
    clock events of a window are drawn when it starts, and its outputs are handed to
    `on_window` (an `EventWindow`; the initial output first) when it ends. Without a callback
    the outputs and events are gathered into the returned run. `rng`: see `TrialDraws`.
    """
    times = np.asarray(times, float)
    T, K, n, N = len(times), n_trials, sys.n, sys.N
    d = (N + 1) * n
    draws = TrialDraws(rng, K)
    window = (T - 1) if window is None else max(1, int(window))
    gathered: list[EventWindow] = []
    emit = on_window if on_window is not None else gathered.append

    flow = BlockDiagonalFlow.of(sys.joint_blocks, sys.joint_noise)
    if not flow.condition < EIGEN_COND_MAX:  # ill-conditioned eigenvectors: exact but slower dense Van Loan
        flow = DenseFlow.of(sys.joint_blocks, sys.joint_noise)
    basis = _controllable_basis(sys.joint_drift, sys.joint_noise)
    # the noise covariances are formed through the eigenvector basis: their rounding is ~eps·κ²
    jitter = max(1e-13, 10 * np.finfo(float).eps * min(flow.condition, 1e8) ** 2) if isinstance(flow, BlockDiagonalFlow) \
        else 1e-13
    clocks = np.array(sys.clocks, dtype=np.int64).reshape(-1, 2)
    S0 = sys.joint_second_moment0()
    Sig = np.broadcast_to(S0, (K, d, d)).copy()
    P = np.broadcast_to(np.asarray(sys.P_init, float), (K, N, n, n)).copy()     # P_i(0)
    z = _initial_states(sys, draws) if sample else None
    if clock_path is not None:
        path_t, path_c = (np.asarray(a) for a in clock_path)

    def diag_blocks(S):
        return np.stack([S[:, (i + 1) * n:(i + 2) * n, (i + 1) * n:(i + 2) * n] for i in range(N)], axis=1)

    none = (np.zeros((K, 0)), np.zeros((K, 0), dtype=np.int64))
    emit(EventWindow(np.array([0]), None if z is None else z[:, None].copy(), diag_blocks(Sig)[:, None], P[:, None].copy(),
                     *none))
    min_gap = np.full((K, N), np.inf)
    scale = np.tile(np.linalg.norm(P[0], axis=(1, 2)), (K, 1))
    rows_all = np.arange(K)
    a = 0
    while a < T - 1:
        b = min(a + window, T - 1)
        ta, tb = times[a], times[b]
        if clock_path is None:
            ev_t, ev_c = draws.clock_events(len(sys.clocks), rate, ta, tb)
        else:
            keep = (path_t >= ta) & (path_t < tb)
            ev_t = np.broadcast_to(path_t[keep], (K, int(keep.sum()))).copy()
            ev_c = np.broadcast_to(path_c[keep].astype(np.int64), ev_t.shape).copy()
        win_t, win_c = ev_t, ev_c
        ev_t = np.concatenate([ev_t, np.full((K, 1), np.inf)], axis=1)
        ev_c = np.concatenate([ev_c, np.full((K, 1), -1)], axis=1)
        L = b - a
        zs = np.zeros((K, L, d)) if sample else None
        sig_out = np.zeros((K, L, N, n, n))
        p_out = np.zeros((K, L, N, n, n))
        t_cur = np.full(K, ta)
        eptr = np.zeros(K, dtype=np.int64)
        gptr = np.full(K, a + 1, dtype=np.int64)
        while True:
            active = gptr <= b
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
            for blk in range(N + 1):
                Phd[:, blk * n:(blk + 1) * n, blk * n:(blk + 1) * n] = Phi[:, blk]
            Sig[r] = Phd @ Sig[r] @ Phd.transpose(0, 2, 1) + Q
            # P_i ← e^{A_i δ} P_i e^{A_iᵀ δ} + ∫ e^{A_i s} G_i e^{A_iᵀ s} ds  (= block (i+1, i+1) of Q)
            P[r] = Phi[:, 1:] @ P[r] @ Phi[:, 1:].transpose(0, 1, 3, 2) + diag_blocks(Q)
            if sample:
                zb = (Phd @ z[r][:, :, None])[:, :, 0]
                if clock_path is not None:
                    Qc = basis.T @ Q[0] @ basis
                    F = np.broadcast_to(_psd_factor(((Qc + Qc.T) / 2)[None], jitter)[0], (len(r),) + Qc.shape)
                else:
                    Qc = basis.T @ Q @ basis
                    F = _psd_factor((Qc + Qc.transpose(0, 2, 1)) / 2, jitter)
                xi = rowwise((F @ draws.normal((basis.shape[1], 1), rows=r))[:, :, 0], basis.T)
                z[r] = zb + xi
            t_cur[r] = t_next
            ev_rows = r[is_event]
            if len(ev_rows):
                _jump(sys, clocks, ev_c[ev_rows, eptr[ev_rows]], ev_rows, z, Sig, P, n)
                eptr[ev_rows] += 1
            grid_rows = r[~is_event]
            if len(grid_rows):
                k = gptr[grid_rows] - a - 1
                sig_out[grid_rows, k] = diag_blocks(Sig[grid_rows])
                p_out[grid_rows, k] = P[grid_rows]
                if sample:
                    zs[grid_rows, k] = z[grid_rows]
                gptr[grid_rows] += 1
            # the per-path ordering P_i ≥ Σ_ii at this event or output time
            gap = P[r] - diag_blocks(Sig[r])
            mins = np.linalg.eigvalsh((gap + gap.transpose(0, 1, 3, 2)) / 2)[..., 0]
            min_gap[r] = np.minimum(min_gap[r], mins)
            scale[r] = np.maximum(scale[r], np.linalg.norm(P[r], axis=(2, 3)))
        emit(EventWindow(np.arange(a + 1, b + 1), zs, sig_out, p_out, win_t, win_c))
        a = b
    cond = flow.condition if isinstance(flow, BlockDiagonalFlow) else 1.0
    if on_window is not None:
        return EventDrivenRun(times, None, None, None, min_gap, scale, None, None, cond)
    ev_t = np.concatenate([w.event_times for w in gathered], axis=1)
    ev_c = np.concatenate([w.event_clocks for w in gathered], axis=1)
    order = np.argsort(ev_t, axis=1, kind="stable")                  # the inf padding of every window to the end
    width = int((ev_c >= 0).sum(axis=1).max(initial=0))
    return EventDrivenRun(times, np.concatenate([w.z for w in gathered], axis=1) if sample else None,
                          np.concatenate([w.sigma for w in gathered], axis=1),
                          np.concatenate([w.pbound for w in gathered], axis=1), min_gap, scale,
                          np.take_along_axis(ev_t, order, 1)[:, :width], np.take_along_axis(ev_c, order, 1)[:, :width], cond)


def _jump(sys: GossipSystem, clocks: np.ndarray, cid: np.ndarray, rows: np.ndarray, z, Sig, P, n: int) -> None:
    """The rings `cid` of the trials `rows`, in place: errors (13b), Σ ← 𝒥Σ𝒥ᵀ with 𝒥 = blkdiag(I_n, J_c ⊗ I_n),
    and P (14b), each a convex combination of pre-jump values."""
    N = sys.N
    ci, cj = clocks[cid, 0], clocks[cid, 1]
    a = sys.alpha
    both = sys.mode == "edge"
    k_ = np.arange(len(rows))
    if z is not None:
        zz = z[rows].reshape(len(rows), N + 1, n)
        ei, ej = zz[k_, ci + 1].copy(), zz[k_, cj + 1].copy()
        zz[k_, ci + 1] = (1 - a) * ei + a * ej
        if both:
            zz[k_, cj + 1] = (1 - a) * ej + a * ei
        z[rows] = zz.reshape(len(rows), -1)
    Jz = np.broadcast_to(np.eye(N + 1), (len(rows), N + 1, N + 1)).copy()
    Jz[k_, ci + 1, ci + 1] = 1 - a
    Jz[k_, ci + 1, cj + 1] = a
    if both:
        Jz[k_, cj + 1, cj + 1] = 1 - a
        Jz[k_, cj + 1, ci + 1] = a
    Jd = np.kron(Jz, np.eye(n))
    Sig[rows] = Jd @ Sig[rows] @ Jd.transpose(0, 2, 1)
    Pe = P[rows]
    Pi_, Pj_ = Pe[k_, ci].copy(), Pe[k_, cj].copy()
    Pe[k_, ci] = (1 - a) * Pi_ + a * Pj_
    if both:
        Pe[k_, cj] = (1 - a) * Pj_ + a * Pi_
    P[rows] = Pe


# -- gridded simulator -------------------------------------------------------------------------

@dataclass
class GriddedRun:
    """z at the recorded steps: (K, T, (N+1)n) (None when a record callback took them)."""

    times: np.ndarray
    z: np.ndarray | None


def simulate_gridded(sys: GossipSystem, rate: float, step: float, n_steps: int, record_every: int, n_trials: int,
                     rng, *, on_record: Callable[[int, np.ndarray], None] | None = None) -> GriddedRun:
    """Fixed-step simulation: exact Gaussian flow over h/2, Poisson(λh) rings of every clock
    (applied as J_c^count, forward clock order on odd steps, reversed on even), exact flow over h/2.

    Records z at steps 0, record_every, 2·record_every, … ≤ n_steps: `on_record(k, z)` with the
    record index k and z (K, (N+1)n) at each of them (streaming: memory does not grow with the
    horizon), or, without a callback, gathered into the returned run. `rng`: see `TrialDraws`.
    """
    n, N, K = sys.n, sys.N, n_trials
    draws = TrialDraws(rng, K)
    Phi, Q = van_loan(sys.joint_drift, sys.joint_noise, step / 2)
    w, U = np.linalg.eigh(Q)
    keep = w > 1e-14 * max(w.max(), 1e-300)
    F = U[:, keep] * np.sqrt(w[keep])                         # Q = F Fᵀ exactly up to rounding
    PhiT, FT = Phi.T.copy(), F.T.copy()
    z = _initial_states(sys, draws)
    rec_steps = np.arange(0, n_steps + 1, record_every)
    out = np.zeros((K, len(rec_steps), z.shape[1])) if on_record is None else None
    record = on_record if on_record is not None else (lambda k, zk: out.__setitem__((slice(None), k), zk))
    record(0, z)
    n_clocks = len(sys.clocks)
    spans = list(zip(draws.edges[:-1], draws.edges[1:]))

    def half_flow(z):
        # one product per unit of trials: a unit's rows then round the same in any batch
        xi = draws.normal((F.shape[1],))
        out = np.empty_like(z)
        for a, b in spans:
            out[a:b] = z[a:b] @ PhiT + xi[a:b] @ FT
        return out

    r_out = 1
    for s in range(1, n_steps + 1):
        z = half_flow(z)
        zr = z.reshape(K, N + 1, n)
        counts = draws.poisson(rate * step, (n_clocks,))
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
        z = half_flow(z)
        if r_out < len(rec_steps) and s == rec_steps[r_out]:
            record(r_out, z)
            r_out += 1
    return GriddedRun(rec_steps * step, out)
