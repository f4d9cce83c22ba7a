"""Exact simulation of a hybrid distributed observer: continuous-time local observers,
open-loop estimate propagation between event times, and a q-step distributed parameter
estimator per event interval whose result resets the estimate at the next event time.

Construction of Wang, Liu and Morse: local observers (3), propagation (5), reset (6),
initialisation (7), iteration times (8)-(9), source sets (11), averaging (13) or the
convex rule (25), update (12). Error objects: (14), (28)-(43); event-time offsets (56)-(61).

Exactness: between consecutive sample or event instants the plant, the local observers, a
harmonic noise oscillator, the agents' estimates and a centralized observer form one linear
time-invariant system, stepped with its matrix exponential (no ODE solver, no step-size
error). The q iterations of an interval are algebraic (they need no time integration);
their timing only decides which graph each message sees. Times are integer nanoseconds.

Trials (different initial conditions) run on a leading array axis.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import scipy.linalg as sla

from .jointly_observable_design import symmetric_weights

NS = 1_000_000_000


def to_ns(t: float) -> int:
    return int(round(t * NS))


@dataclass(frozen=True)
class ObserverDesign:
    """A (n x n); C, L, Abar, Cbar, K, Q: per-agent lists; P (m, n, n)."""

    A: np.ndarray
    C: tuple
    L: tuple
    Abar: tuple
    Cbar: tuple
    K: tuple
    Q: tuple
    P: np.ndarray

    @property
    def m(self) -> int:
        return len(self.C)

    @property
    def n(self) -> int:
        return self.A.shape[0]

    @property
    def n_i(self) -> list[int]:
        return [L.shape[0] for L in self.L]

    @property
    def w_slices(self) -> list[slice]:
        off = np.concatenate([[0], np.cumsum(self.n_i)])
        return [slice(int(off[i]), int(off[i + 1])) for i in range(self.m)]

    def F(self, i: int) -> np.ndarray:
        return self.Abar[i] + self.K[i] @ self.Cbar[i]


@dataclass(frozen=True)
class GraphSchedule:
    """Piecewise-constant neighbour graph N(t), right-continuous.

    kind: 'fixed' (graph `fixed`), 'alternate_interval' (graphs cycle once per period T,
    starting at t = 0), 'alternate_iteration' (graphs cycle once per iteration, switching at
    (s-1)T + (k-1)Δ + β + Δ/2: the fastest switching Theorem 2 allows), 'sequence' (switch
    at `times[j]` to graph `indices[j]`; before times[0] graph indices[0]).
    """

    graphs: np.ndarray          # (G, m, m) boolean masks, N[i, j] = j ∈ N_i
    kind: str = "fixed"
    fixed: int = 0
    T: float = 1.0
    Delta: float = 0.0
    beta: float = 0.0
    q: int = 1
    times: tuple = ()
    indices: tuple = ()

    def index_at(self, t) -> np.ndarray:
        t = np.asarray(t, float)
        G = len(self.graphs)
        if self.kind == "fixed":
            return np.full(t.shape, self.fixed, dtype=int)
        if self.kind == "alternate_interval":
            return (np.floor(t / self.T + 1e-12).astype(int)) % G
        if self.kind == "alternate_iteration":
            s = np.floor(t / self.T + 1e-12)
            u = t - s * self.T
            j = np.clip(np.floor((u - self.beta + self.Delta / 2) / self.Delta + 1e-12), 0, self.q - 1).astype(int)
            return (s.astype(int) * self.q + j) % G
        if self.kind == "sequence":
            pos = np.searchsorted(np.asarray(self.times, float), t + 1e-12, side="right") - 1
            return np.asarray(self.indices, int)[np.clip(pos, 0, None)]
        raise ValueError(f"unknown schedule kind {self.kind!r}")

    def at(self, t) -> np.ndarray:
        return self.graphs[self.index_at(t)]

    def switch_times(self, t_end: float) -> np.ndarray:
        """The instants in (0, t_end] at which N(t) changes (right-continuous: the new graph
        holds from the instant on), sorted."""
        if self.kind == "fixed" or len(self.graphs) < 2:
            return np.empty(0)
        S = int(math.floor(t_end / self.T + 1e-12))
        starts = self.T * np.arange(1, S + 1)
        if self.kind == "alternate_interval":
            return starts
        if self.kind == "alternate_iteration":
            j = np.arange(1, self.q)
            inner = (self.T * np.arange(S + 1))[:, None] + (self.beta - self.Delta / 2 + j * self.Delta)[None, :]
            inner = inner[(inner > 0) & (inner <= t_end)]
            return np.unique(np.concatenate([starts, inner.ravel()]))
        if self.kind == "sequence":
            idx = np.asarray(self.indices, int)
            t = np.asarray(self.times, float)
            change = np.nonzero(idx[1:] != idx[:-1])[0] + 1
            return t[change][(t[change] > 0) & (t[change] <= t_end)]
        raise ValueError(f"unknown schedule kind {self.kind!r}")


@dataclass(frozen=True)
class Timing:
    """T, q, Δ, β; offsets t_i0 (m,); jitter δ_is(k) (S, m, q+1) or None (synchronous)."""

    T: float
    q: int
    Delta: float
    beta: float
    offsets: np.ndarray
    jitter: np.ndarray | None = None


@dataclass(frozen=True)
class Membership:
    """Agent `agent` is absent from the intervals that start in [leave, join) (own clock);
    at `join` it is re-initialised ('reinit'), resumes its frozen state ('resume') or keeps
    the state its open-loop dynamics reached ('open_loop', its observer and propagation keep
    running while it is out)."""

    agent: int
    leave: float
    join: float
    policy: str = "reinit"
    x_reinit: np.ndarray | None = None
    w_reinit: np.ndarray | None = None


@dataclass
class HybridRun:
    """Results. Shapes: B trials, m agents, n states, S intervals, Gt sample times.

    t_ns (Gt,); x0 (Gt, n) and xhat0 (Gt, m, n): trial 0 states; err (Gt, B, m) ||e_i(t)||
    (right-continuous, post-reset); xnorm (Gt, B); central_err (Gt, B).
    event_ns (m, S+1): t_is. e_pre/e_post (S+1, B, m, n): e_i(t_is^-), e_i(t_is) (index 0: initial).
    ebar (S+1, B, Σn_i): ē(s) = column ē_i(t_is). x_event (S+1, B, m, n): x(t_is).
    x_nominal (S+1, B, n): x(sT). W (S, q, m, m): averaging weights used at iteration k of
    interval s; sources (S, q, m, m) and nominal (S, q, m, m): S_is(k) and N_i((s-1)T+(k-1)Δ+β).
    z0 (S, q+1, m, n): iterates of trial 0. pi0_max/piq_max (S, B): max_i ||π_is(0)||, ||π_is(q)||.
    participating (S, m). reception_violations: messages that arrive outside the receiver's
    reception interval [τ_is(k-1), τ_is(k)).
    """

    t_ns: np.ndarray
    x0: np.ndarray
    xhat0: np.ndarray
    xc0: np.ndarray
    err: np.ndarray
    xnorm: np.ndarray
    central_err: np.ndarray
    event_ns: np.ndarray
    e_pre: np.ndarray
    e_post: np.ndarray
    ebar: np.ndarray
    x_event: np.ndarray
    x_nominal: np.ndarray
    W: np.ndarray
    sources: np.ndarray
    nominal: np.ndarray
    z0: np.ndarray
    pi0_max: np.ndarray
    piq_max: np.ndarray
    participating: np.ndarray
    reception_violations: int
    extra: dict = field(default_factory=dict)

    def arrays(self) -> dict[str, np.ndarray]:
        out = {k: np.asarray(v) for k, v in self.__dict__.items() if k != "extra"}
        out.update({f"extra_{k}": np.asarray(v) for k, v in self.extra.items()})
        return out

    @classmethod
    def from_arrays(cls, a: dict[str, np.ndarray]) -> "HybridRun":
        names = [f for f in cls.__dataclass_fields__ if f != "extra"]
        kw = {k: a[k] for k in names}
        kw["reception_violations"] = int(a["reception_violations"])
        return cls(**kw, extra={k.removeprefix("extra_"): v for k, v in a.items() if k.startswith("extra_")})


def rowwise_matmul(X: np.ndarray, M: np.ndarray) -> np.ndarray:
    """X @ M with a fixed summation order per row: a trial's numbers do not depend on how many
    trials run beside it (BLAS blocks differently for different batch sizes), so a run of one
    trial reproduces trial 0 of a batch bit for bit.

    numpy's own einsum loop (no BLAS, no optimize) on contiguous operands: checked row by row
    against batches of other sizes over 3,360 shapes (B ≤ 1024, K, J ≤ 80, strided views) with
    no difference, and 5-12x faster than the broadcast product + sum it replaces (which built a
    (B, K, J) temporary; profiled as ~40% of `dse reproduce wang-liu-morse`)."""
    return np.einsum("bk,kj->bj", np.ascontiguousarray(X), np.ascontiguousarray(M))


def _generator(d: ObserverDesign, active: np.ndarray, b: np.ndarray | None, omega: float, Kc: np.ndarray | None,
               Cs: np.ndarray) -> np.ndarray:
    """Generator of [x; w_1..w_m; c; s; x_1..x_m; x_c]; inactive agents are frozen."""
    n, m = d.n, d.m
    nw = sum(d.n_i)
    D = n + nw + 2 + m * n + n
    G = np.zeros((D, D))
    G[:n, :n] = d.A
    io = n + nw
    if b is not None:
        G[:n, io] = b
    G[io, io + 1] = -omega
    G[io + 1, io] = omega
    for i, sl in enumerate(d.w_slices):
        if not active[i]:
            continue
        rows = slice(n + sl.start, n + sl.stop)
        G[rows, rows] = d.F(i)
        G[rows, :n] = -d.K[i] @ d.C[i]
        xi = slice(io + 2 + i * n, io + 2 + (i + 1) * n)
        G[xi, xi] = d.A
    xc = slice(D - n, D)
    if Kc is not None:
        G[xc, xc] = d.A + Kc @ Cs
        G[xc, :n] = -Kc @ Cs
    else:
        G[xc, xc] = d.A
    return G


def simulate(d: ObserverDesign, timing: Timing, schedule: GraphSchedule, *, x0: np.ndarray, w0: np.ndarray,
             xhat0: np.ndarray, intervals: int, dt_plot: float = 0.01, rule: str = "mean", m_rule: int | None = None,
             noise_b: np.ndarray | None = None, noise_omega: float = 10.0, membership: tuple[Membership, ...] = (),
             central_gain: np.ndarray | None = None, xc0: np.ndarray | None = None) -> HybridRun:
    """Run the hybrid observer for `intervals` event intervals per agent.

    x0 (B, n) is x(0) (the plant starts at min(0, min t_i0) with x = e^{A t_start} x0 when that
    is negative and there is no noise input); w0 (B, Σn_i); xhat0 (B, m, n); agents start
    their dynamics at their own t_i0 (frozen before). Noise: x' = A x + b cos(ω t).
    """
    A, n, m, q, S = d.A, d.n, d.m, timing.q, intervals
    x0, w0, xhat0 = (np.atleast_2d(np.asarray(v, float)) for v in (x0, w0, xhat0))
    if xhat0.ndim == 2:
        xhat0 = xhat0[None]
    B = x0.shape[0]
    nw = sum(d.n_i)
    io = n + nw
    D = io + 2 + m * n + n
    Cs = np.vstack(d.C)
    T_ns = to_ns(timing.T)
    off_ns = np.array([to_ns(t) for t in timing.offsets], dtype=np.int64)
    event_ns = off_ns[:, None] + T_ns * np.arange(S + 1)[None, :]
    start_ns = int(min(0, off_ns.min()))
    end_ns = int(max(S * T_ns, event_ns.max()))
    dt_ns = to_ns(dt_plot)
    grid = np.arange(start_ns - (start_ns % dt_ns if start_ns % dt_ns else 0), end_ns + 1, dt_ns)
    grid = grid[(grid >= start_ns) & (grid <= end_ns)]
    times = np.unique(np.concatenate([grid, event_ns.ravel(), T_ns * np.arange(S + 1), [start_ns, end_ns]]))
    eAT = sla.expm(A * (T_ns / NS))        # the event spacing as simulated (whole nanoseconds)
    W_slices = d.w_slices

    # interval participation and agent activity
    part = np.ones((S, m), dtype=bool)
    for mb in membership:
        for s in range(1, S + 1):
            t_start_int = event_ns[mb.agent, s - 1]
            if to_ns(mb.leave) <= t_start_int < to_ns(mb.join):
                part[s - 1, mb.agent] = False

    def active_at(t_ns: int) -> np.ndarray:
        act = off_ns <= t_ns
        for mb in membership:
            if mb.policy != "open_loop" and to_ns(mb.leave) <= t_ns < to_ns(mb.join):
                act[mb.agent] = False
        return act

    # state
    X = np.zeros((B, D))
    x_start = rowwise_matmul(x0, sla.expm(A * (start_ns / NS)).T) if (start_ns < 0 and noise_b is None) else x0.copy()
    X[:, :n] = x_start
    X[:, n:io] = w0
    X[:, io] = math.cos(noise_omega * start_ns / NS)
    X[:, io + 1] = math.sin(noise_omega * start_ns / NS)
    X[:, io + 2: io + 2 + m * n] = xhat0.reshape(B, m * n)
    X[:, D - n:] = x_start if xc0 is None else xc0
    noise = noise_b if noise_b is not None else None

    gen_cache: dict = {}
    phi_cache: dict = {}

    def phi(act: np.ndarray, h_ns: int) -> np.ndarray:
        key = (act.tobytes(), h_ns)
        if key not in phi_cache:
            gk = act.tobytes()
            if gk not in gen_cache:
                gen_cache[gk] = _generator(d, act, noise, noise_omega, central_gain, Cs)
            phi_cache[key] = sla.expm(gen_cache[gk] * (h_ns / NS)).T
        return phi_cache[key]

    def xhat(Xv):
        return Xv[:, io + 2: io + 2 + m * n].reshape(-1, m, n)

    grid_set = set(grid.tolist())
    rec_t, rec_x, rec_xh, rec_xc, rec_err, rec_xn, rec_ce = [], [], [], [], [], [], []
    e_pre = np.full((S + 1, B, m, n), np.nan)
    e_post = np.full((S + 1, B, m, n), np.nan)
    ebar = np.full((S + 1, B, nw), np.nan)
    x_event = np.full((S + 1, B, m, n), np.nan)
    x_nominal = np.full((S + 1, B, n), np.nan)
    z_start = np.full((S + 1, B, m, n), np.nan)   # z_is(0) for interval s (index s-1 data at t_i(s-1))
    w_start = np.full((S + 1, B, nw), np.nan)
    captured = np.zeros((S + 1, m), dtype=bool)
    Wall = np.zeros((S, q, m, m))
    src = np.zeros((S, q, m, m), dtype=bool)
    nom = np.zeros((S, q, m, m), dtype=bool)
    z0 = np.full((S, q + 1, m, n), np.nan)
    pi0_max = np.full((S, B), np.nan)
    piq_max = np.full((S, B), np.nan)
    zq = {}
    violations = 0
    jitter = timing.jitter
    P = d.P

    Pbig = sla.block_diag(*P)
    eye_n = np.eye(n)
    ar = np.arange(m)

    def run_iterations(s: int) -> None:
        """Interval s (1-based): q iterations of (12)-(13) from data captured at t_i(s-1)."""
        nonlocal violations
        pp = part[s - 1]
        z = z_start[s].copy()
        Qw = np.zeros((B, m, n))
        for i in range(m):
            if pp[i]:
                Qw[:, i] = rowwise_matmul(w_start[s][:, W_slices[i]], d.Q[i].T)
        xs = x_event[s - 1]                               # x(t_i(s-1)) per agent
        pi0 = np.where(pp[None, :, None], z - xs, 0.0)
        pi0_max[s - 1] = np.linalg.norm(pi0, axis=-1).max(axis=-1)
        t0 = event_ns[:, s - 1] / NS
        ks = np.arange(q + 1)
        delta = jitter[s - 1] if jitter is not None else np.zeros((m, q + 1))      # (m, q+1)
        tau = t0[:, None] + ks[None, :] * timing.Delta + delta                       # τ_is(k), (m, q+1)
        bcast = (tau[:, :q] + timing.beta).T                                         # (q, m): j's k-th message
        N_send = schedule.at(bcast)                                                  # (q, m_sender, m, m)
        Sk = N_send[:, ar[None, :], ar[:, None], ar[None, :]]                        # [k, i, j] = j ∈ N_i(t_j)
        Sk &= pp[None, None, :] & pp[None, :, None]
        Sk |= np.eye(m, dtype=bool)[None]
        # physical check: j's message lands in i's reception interval [τ_is(k-1), τ_is(k))
        lo, hi = tau[:, :q].T[:, :, None], tau[:, 1:].T[:, :, None]                 # receiver i
        arrive = bcast[:, None, :]
        bad = Sk & ~np.eye(m, dtype=bool)[None] & ~((lo - 1e-12 <= arrive) & (arrive < hi - 1e-12))
        violations += int(bad.sum())
        t_nom = (s - 1) * timing.T + (ks[:q]) * timing.Delta + timing.beta
        N_nom = schedule.at(t_nom) & pp[None, None, :] & pp[None, :, None]
        N_nom |= np.eye(m, dtype=bool)[None]
        src[s - 1], nom[s - 1] = Sk, N_nom
        if rule == "mean":
            Wk = Sk / Sk.sum(axis=2, keepdims=True)
        else:
            Wk = np.array([symmetric_weights(S_, m_rule) for S_ in Sk])
        Wk[:, ~pp] = 0.0
        Wk[:, ~pp, ~pp] = 1.0
        Wall[s - 1] = Wk
        M = Pbig[None] @ np.einsum("kij,ab->kiajb", Wk, eye_n).reshape(q, m * n, m * n)
        keep = np.repeat(~pp, n)
        M[:, keep, :] = 0.0
        M[:, keep, keep] = 1.0
        c = np.where(pp[None, :, None], Qw, 0.0).reshape(B, m * n)
        zf = z.reshape(B, m * n)
        MT = np.ascontiguousarray(np.swapaxes(M, 1, 2))
        traj = np.empty((q + 1, m * n))
        traj[0] = zf[0]
        for k in range(q):
            zf = rowwise_matmul(zf, MT[k]) + c
            traj[k + 1] = zf[0]
        z = zf.reshape(B, m, n)
        z0[s - 1] = traj.reshape(q + 1, m, n)
        piq_max[s - 1] = np.linalg.norm(np.where(pp[None, :, None], z - xs, 0.0), axis=-1).max(axis=-1)
        zq[s] = z

    def capture(i: int, s: int) -> None:
        """Data of agent i for interval s+1 at t_is (after resets/re-initialisation)."""
        z_start[s + 1][:, i] = xhat(X)[:, i]
        w_start[s + 1][:, W_slices[i]] = X[:, n + W_slices[i].start: n + W_slices[i].stop]
        captured[s, i] = True
        if s + 1 <= S and captured[s].all():
            run_iterations(s + 1)

    # initial captures for agents whose t_i0 == start
    next_s = np.zeros(m, dtype=int)      # next event index to process per agent
    t_prev = start_ns
    for t in times:
        if t > t_prev:
            X = rowwise_matmul(X, phi(active_at(t_prev), int(t - t_prev)))
            t_prev = t
        for i in range(m):
            s = next_s[i]
            if s <= S and event_ns[i, s] == t:
                xi = xhat(X)[:, i]
                xt = X[:, :n]
                e_pre[s][:, i] = xi - xt
                if s >= 1 and part[s - 1, i]:
                    X[:, io + 2 + i * n: io + 2 + (i + 1) * n] = rowwise_matmul(zq[s][:, i], eAT.T)
                for mb in membership:
                    if mb.agent == i and to_ns(mb.join) == t and mb.policy == "reinit":
                        if mb.x_reinit is not None:
                            X[:, io + 2 + i * n: io + 2 + (i + 1) * n] = mb.x_reinit
                        if mb.w_reinit is not None:
                            X[:, n + W_slices[i].start: n + W_slices[i].stop] = mb.w_reinit
                e_post[s][:, i] = xhat(X)[:, i] - xt
                x_event[s][:, i] = xt
                wi = X[:, n + W_slices[i].start: n + W_slices[i].stop]
                ebar[s][:, W_slices[i]] = wi - rowwise_matmul(xt, d.L[i].T)
                next_s[i] += 1
                if s < S:
                    capture(i, s)
        if t % T_ns == 0 and 0 <= t // T_ns <= S:
            x_nominal[t // T_ns] = X[:, :n]
        if t in grid_set:
            rec_t.append(t)
            rec_x.append(X[0, :n].copy())
            rec_xh.append(xhat(X)[0].copy())
            rec_xc.append(X[0, D - n:].copy())
            e = xhat(X) - X[:, None, :n]
            rec_err.append(np.linalg.norm(e, axis=-1))
            rec_xn.append(np.linalg.norm(X[:, :n], axis=-1))
            rec_ce.append(np.linalg.norm(X[:, D - n:] - X[:, :n], axis=-1))
    return HybridRun(np.array(rec_t, dtype=np.int64), np.array(rec_x), np.array(rec_xh), np.array(rec_xc),
                     np.array(rec_err), np.array(rec_xn), np.array(rec_ce), event_ns, e_pre, e_post, ebar, x_event,
                     x_nominal, Wall, src, nom, z0, pi0_max, piq_max, part, violations)


# -- error recursion (37)-(43), (61') --------------------------------------------------------------

def step_matrices(P: np.ndarray, W: np.ndarray) -> np.ndarray:
    """M_k = P (W_k ⊗ I_n) for every k; W (q, m, m) -> (q, mn, mn)."""
    m, n, _ = P.shape
    q = W.shape[0]
    Pb = sla.block_diag(*P)
    return Pb[None] @ np.einsum("kij,ab->kiajb", W, np.eye(n)).reshape(q, m * n, m * n)


def transition_products(P: np.ndarray, W: np.ndarray) -> np.ndarray:
    """Φ(k) = P(W_q ⊗ I) ··· P(W_{k+1} ⊗ I) for k = 0..q (40), Φ(q) = I; W (q, m, m). Returns (q+1, mn, mn)."""
    m, n, _ = P.shape
    q = W.shape[0]
    M = step_matrices(P, W)
    Phi = np.empty((q + 1, m * n, m * n))
    Phi[q] = np.eye(m * n)
    for k in range(q, 0, -1):
        Phi[k - 1] = Phi[k] @ M[k - 1]
    return Phi


def error_recursion(d: ObserverDesign, W: np.ndarray, T: float, offsets: np.ndarray | None = None,
                    Phi: np.ndarray | None = None, eAT: np.ndarray | None = None,
                    E: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A(s) = e^{ÃT} Φ(0) (42), B(s) = e^{ÃT} Σ_{k=1}^q Φ(k) Q (43), and for event-time offsets
    G(s) = e^{ÃT} Σ_k Φ(k) P Γ(k) with Γ_i(k) = Σ_j W_ij(k) (e^{A t_i0} - e^{A t_j0}) (58), so that
    e(s) = A e(s-1) + B ē(s-1) - G x((s-1)T)  (61, with the sign corrected). `E`: the e^{A t_i0} if
    already computed."""
    m, n = d.m, d.n
    Phi = transition_products(d.P, W) if Phi is None else Phi
    eAT = np.kron(np.eye(m), sla.expm(d.A * T) if eAT is None else eAT)
    Qb = sla.block_diag(*d.Q)
    As = eAT @ Phi[0]
    Bs = eAT @ Phi[1:].sum(axis=0) @ Qb
    G = np.zeros((m * n, n))
    if offsets is not None and np.any(offsets != 0):
        if E is None:                                                       # e^{A t_i0}, (m, n, n)
            E = np.array([sla.expm(d.A * t) if t else np.eye(n) for t in offsets])
        Gam = E[None] - np.einsum("kij,jab->kiab", W, E)                   # (q, m, n, n), rows of W sum to 1
        Pb = sla.block_diag(*d.P)
        G = eAT @ (Phi[1:] @ Pb[None] @ Gam.reshape(W.shape[0], m * n, n)).sum(axis=0)
    return As, Bs, G
