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

Trials (different initial conditions) run on a leading array axis. Time is streamed: the
simulator hands each sample, each completed event index and each interval's iterations to a
`Monitor` and keeps only what is still needed (the state, the open event indices), so memory
does not grow with the horizon; `FullRecord` (the default) keeps everything as a `HybridRun`.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import scipy  # scipy.linalg loads on first use (scipy imports submodules lazily): `dse list` skips it

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
    """T, q, Δ, β; offsets t_i0 (m,); jitter δ_is(k): None (synchronous), an array (S, m, q+1),
    or a callable s -> (m, q+1) for interval s = 1..S (drawn when needed; see `SequentialJitter`)."""

    T: float
    q: int
    Delta: float
    beta: float
    offsets: np.ndarray
    jitter: object = None

    def jitter_of(self, s: int, m: int) -> np.ndarray:
        """δ_is(k) of interval s (1-based), (m, q+1)."""
        if self.jitter is None:
            return np.zeros((m, self.q + 1))
        if callable(self.jitter):
            return self.jitter(s)
        return np.asarray(self.jitter)[s - 1]


class SequentialJitter:
    """δ_is(k) = ε_i u, u uniform on [-1, 1), drawn interval after interval from one generator
    (the same numbers as one draw of shape (S, m, q+1)), without keeping the whole array."""

    def __init__(self, make_generator, eps: np.ndarray, q: int):
        self.make_generator, self.eps, self.q = make_generator, np.asarray(eps, float), q
        self._gen, self._s, self._last = None, 0, None

    def __call__(self, s: int) -> np.ndarray:
        if self._last is not None and s == self._s:
            return self._last
        if self._gen is None or s < self._s:
            self._gen, self._s = self.make_generator(), 0
        while self._s < s:
            self._last = self._gen.uniform(-1.0, 1.0, size=(len(self.eps), self.q + 1)) * self.eps[:, None]
            self._s += 1
        return self._last


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


# -- what the simulator hands to a monitor ------------------------------------------------------------

@dataclass(frozen=True)
class RunLayout:
    """Static facts of a run: B trials, m agents, n states, S intervals, q iterations; event_ns
    (m, S+1) = t_is; participating (S, m); the sample grid g0 + k dt_ns, k = 0..samples-1."""

    B: int
    m: int
    n: int
    S: int
    q: int
    event_ns: np.ndarray
    participating: np.ndarray
    grid0_ns: int
    dt_ns: int
    samples: int
    w_slices: tuple


@dataclass(frozen=True)
class IntervalData:
    """The q iterations of interval s: W (q, m, m) weights, sources (q, m, m) S_is(k),
    nominal (q, m, m) N_i((s-1)T+(k-1)Δ+β), violations (messages outside the reception interval),
    tau (m, q+1) iteration times τ_is(k) in seconds, pi0_max / piq_max (B,) = max_i||π_is(0)||,
    max_i||π_is(q)|| over participating agents, traj0 (q+1, m, n) the iterates of the first trial."""

    s: int
    W: np.ndarray
    sources: np.ndarray
    nominal: np.ndarray
    violations: int
    tau: np.ndarray
    pi0_max: np.ndarray
    piq_max: np.ndarray
    traj0: np.ndarray


@dataclass(frozen=True)
class EventData:
    """Event index s, complete for every agent: e_pre / e_post (B, m, n) = e_i(t_is⁻), e_i(t_is);
    x_event (B, m, n) = x(t_is); ebar (B, Σn_i) = ē(s); x_nominal (B, n) = x(sT); central (B, m) =
    ||x_c(t_is) - x(t_is)|| of the centralized observer."""

    s: int
    e_pre: np.ndarray
    e_post: np.ndarray
    x_event: np.ndarray
    ebar: np.ndarray
    x_nominal: np.ndarray
    central: np.ndarray


class Monitor:
    """Receives a run as it is simulated. Event indices arrive in order s = 0..S; interval s's
    iterations arrive before event s (just before event s-1 when the last agent reaches event
    s-1, since they start there); samples arrive in time order, after the events at the same time.
    X is the state [x; w_1..w_m; c; s; x̂_1..x̂_m; x_c] of every trial (B, D), read-only."""

    def start(self, layout: RunLayout) -> None: ...

    def sample(self, k: int, t_ns: int, X: np.ndarray) -> None: ...

    def interval(self, data: IntervalData) -> None: ...

    def event(self, data: EventData) -> None: ...

    def finish(self):
        return None


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


class FullRecord(Monitor):
    """Keeps every sample, event and iteration of a run: a `HybridRun` (small runs and tests)."""

    def start(self, layout: RunLayout) -> None:
        B, m, n, S, q = layout.B, layout.m, layout.n, layout.S, layout.q
        nw = layout.w_slices[-1].stop
        self.layout = layout
        self.samples: list = []
        self.e_pre, self.e_post = np.full((S + 1, B, m, n), np.nan), np.full((S + 1, B, m, n), np.nan)
        self.ebar, self.x_event = np.full((S + 1, B, nw), np.nan), np.full((S + 1, B, m, n), np.nan)
        self.x_nominal = np.full((S + 1, B, layout.n), np.nan)
        self.W, self.z0 = np.zeros((S, q, m, m)), np.full((S, q + 1, m, n), np.nan)
        self.sources, self.nominal = np.zeros((S, q, m, m), bool), np.zeros((S, q, m, m), bool)
        self.pi0_max, self.piq_max = np.full((S, B), np.nan), np.full((S, B), np.nan)
        self.violations = 0

    def sample(self, k: int, t_ns: int, X: np.ndarray) -> None:
        L = self.layout
        m, n = L.m, L.n
        first = X.shape[1] - m * n - n                    # x̂_1..x̂_m sit just before x_c
        xh = X[:, first: first + m * n].reshape(-1, m, n)
        x, xc = X[:, :n], X[:, -n:]
        self.samples.append((t_ns, x[0].copy(), xh[0].copy(), xc[0].copy(), np.linalg.norm(xh - x[:, None], axis=-1),
                             np.linalg.norm(x, axis=-1), np.linalg.norm(xc - x, axis=-1)))

    def interval(self, d: IntervalData) -> None:
        i = d.s - 1
        self.W[i], self.sources[i], self.nominal[i], self.z0[i] = d.W, d.sources, d.nominal, d.traj0
        self.pi0_max[i], self.piq_max[i] = d.pi0_max, d.piq_max
        self.violations += d.violations

    def event(self, d: EventData) -> None:
        s = d.s
        self.e_pre[s], self.e_post[s], self.x_event[s] = d.e_pre, d.e_post, d.x_event
        self.ebar[s], self.x_nominal[s] = d.ebar, d.x_nominal

    def finish(self) -> HybridRun:
        cols = list(zip(*self.samples))
        return HybridRun(np.array(cols[0], dtype=np.int64), np.array(cols[1]), np.array(cols[2]), np.array(cols[3]),
                         np.array(cols[4]), np.array(cols[5]), np.array(cols[6]), self.layout.event_ns, self.e_pre,
                         self.e_post, self.ebar, self.x_event, self.x_nominal, self.W, self.sources, self.nominal,
                         self.z0, self.pi0_max, self.piq_max, self.layout.participating, self.violations)


def row_norms(v: np.ndarray) -> np.ndarray:
    """Euclidean norms along the last axis, each summed in a fixed order (a trial's value does not
    depend on the batch); cheaper than np.linalg.norm on the short axes of agents' states."""
    return np.sqrt(np.einsum("...i,...i->...", v, v))


def row_max(v: np.ndarray) -> np.ndarray:
    """The maximum along the last axis (NaN propagates), column by column for short axes (numpy's
    reduction over a short last axis goes one row at a time)."""
    if v.shape[-1] > 32:
        return v.max(axis=-1)
    out = v[..., 0].copy()
    for j in range(1, v.shape[-1]):
        np.maximum(out, v[..., j], out=out)
    return out


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


def state_dimension(d: ObserverDesign) -> int:
    """D = n + Σn_i + 2 + mn + n: plant, local observers, noise oscillator, estimates, centralized observer."""
    return d.n + sum(d.n_i) + 2 + d.m * d.n + d.n


def participation(event_ns: np.ndarray, membership: tuple[Membership, ...]) -> np.ndarray:
    """(S, m): agent i takes part in interval s unless its interval starts inside an absence."""
    m, S = event_ns.shape[0], event_ns.shape[1] - 1
    part = np.ones((S, m), dtype=bool)
    for mb in membership:
        starts = event_ns[mb.agent, :S]
        part[(to_ns(mb.leave) <= starts) & (starts < to_ns(mb.join)), mb.agent] = False
    return part


def interval_sources(schedule: GraphSchedule, timing: Timing, event_ns: np.ndarray, pp: np.ndarray, s: int,
                     rule: str = "mean", m_rule: int | None = None):
    """The communication of interval s (1-based) given who takes part (pp, (m,)):
    S_is(k) (11) from the graph at each sender's broadcast time τ_js(k-1) + β, the nominal
    N_i((s-1)T + (k-1)Δ + β), the weights of (13) or (25) (an absent agent keeps its iterate),
    the count of messages that land outside the receiver's reception interval [τ_is(k-1), τ_is(k)),
    and the iteration times τ_is(k) (m, q+1). Returns (W, sources, nominal, violations, tau)."""
    m, q = event_ns.shape[0], timing.q
    ar = np.arange(m)
    t0 = event_ns[:, s - 1] / NS
    ks = np.arange(q + 1)
    tau = t0[:, None] + ks[None, :] * timing.Delta + timing.jitter_of(s, m)         # τ_is(k), (m, q+1)
    bcast = (tau[:, :q] + timing.beta).T                                            # (q, m): j's k-th message
    N_send = schedule.at(bcast)                                                     # (q, m_sender, m, m)
    Sk = N_send[:, ar[None, :], ar[:, None], ar[None, :]]                           # [k, i, j] = j ∈ N_i(t_j)
    Sk &= pp[None, None, :] & pp[None, :, None]
    Sk |= np.eye(m, dtype=bool)[None]
    lo, hi = tau[:, :q].T[:, :, None], tau[:, 1:].T[:, :, None]                     # receiver i
    arrive = bcast[:, None, :]
    bad = Sk & ~np.eye(m, dtype=bool)[None] & ~((lo - 1e-12 <= arrive) & (arrive < hi - 1e-12))
    t_nom = (s - 1) * timing.T + ks[:q] * timing.Delta + timing.beta
    N_nom = schedule.at(t_nom) & pp[None, None, :] & pp[None, :, None]
    N_nom |= np.eye(m, dtype=bool)[None]
    if rule == "mean":
        Wk = Sk / Sk.sum(axis=2, keepdims=True)
    else:
        Wk = np.array([symmetric_weights(S_, m_rule) for S_ in Sk])
    Wk[:, ~pp] = 0.0
    Wk[:, ~pp, ~pp] = 1.0
    return Wk, Sk, N_nom, int(bad.sum()), tau


def step_matrix(P: np.ndarray, W: np.ndarray, pp: np.ndarray | None = None) -> np.ndarray:
    """M = P (W ⊗ I_n) (one iteration of (37)), with the rows of agents not taking part (pp False)
    replaced by identity rows (they keep their iterate); (mn, mn). Each entry is one product
    W_ij [P_i]_ab."""
    m, n, _ = P.shape
    M = np.einsum("ij,iab->iajb", W, P).reshape(m * n, m * n)
    if pp is not None and not pp.all():
        keep = np.repeat(~pp, n)
        M[keep, :] = 0.0
        M[keep, keep] = 1.0
    return M


def sample_grid(offsets_ns: np.ndarray, T_ns: int, intervals: int, dt: float) -> tuple[int, int, int, int, int]:
    """(start, end, first sample, sample step, number of samples) of a run, in ns: the run spans
    [min(0, min t_i0), max(S T, last event)] and is sampled at the multiples of the step in it."""
    start_ns = int(min(0, int(np.min(offsets_ns))))
    end_ns = int(max(intervals * T_ns, int(np.max(offsets_ns)) + intervals * T_ns))
    dt_ns = to_ns(dt)
    grid0 = -(-start_ns // dt_ns) * dt_ns                 # the first multiple of dt_ns at or after the start
    return start_ns, end_ns, grid0, dt_ns, (end_ns - grid0) // dt_ns + 1


def step_matrix_batch(P: np.ndarray, W: np.ndarray) -> np.ndarray:
    """`step_matrix` for a stack of weight matrices W (g, m, m): (g, mn, mn)."""
    m, n, _ = P.shape
    return np.einsum("gij,iab->giajb", W, P).reshape(len(W), m * n, m * n)


def simulate(d: ObserverDesign, timing: Timing, schedule: GraphSchedule, *, x0: np.ndarray, w0: np.ndarray,
             xhat0: np.ndarray, intervals: int, dt_plot: float = 0.01, rule: str = "mean", m_rule: int | None = None,
             noise_b: np.ndarray | None = None, noise_omega: float = 10.0, membership: tuple[Membership, ...] = (),
             central_gain: np.ndarray | None = None, xc0: np.ndarray | None = None, monitor: Monitor | None = None):
    """Run the hybrid observer for `intervals` event intervals per agent; returns
    `monitor.finish()` (a `HybridRun` with the default `FullRecord`).

    x0 (B, n) is x(0) (the plant starts at min(0, min t_i0) with x = e^{A t_start} x0 when that
    is negative and there is no noise input); w0 (B, Σn_i); xhat0 (B, m, n); agents start
    their dynamics at their own t_i0 (frozen before). Noise: x' = A x + b cos(ω t).
    """
    monitor = FullRecord() if monitor is None else monitor
    A, n, m, q, S = d.A, d.n, d.m, timing.q, intervals
    x0, w0, xhat0 = (np.atleast_2d(np.asarray(v, float)) for v in (x0, w0, xhat0))
    if xhat0.ndim == 2:
        xhat0 = xhat0[None]
    B = x0.shape[0]
    nw = sum(d.n_i)
    io = n + nw
    D = state_dimension(d)
    Cs = np.vstack(d.C)
    T_ns = to_ns(timing.T)
    off_ns = np.array([to_ns(t) for t in timing.offsets], dtype=np.int64)
    event_ns = off_ns[:, None] + T_ns * np.arange(S + 1)[None, :]
    start_ns, end_ns, grid0, dt_ns, samples = sample_grid(off_ns, T_ns, S, dt_plot)
    eAT = scipy.linalg.expm(A * (T_ns / NS))        # the event spacing as simulated (whole nanoseconds)
    W_slices = d.w_slices
    part = participation(event_ns, membership)
    monitor.start(RunLayout(B, m, n, S, q, event_ns, part, grid0, dt_ns, samples, tuple(W_slices)))

    def active_at(t_ns: int) -> np.ndarray:
        act = off_ns <= t_ns
        for mb in membership:
            if mb.policy != "open_loop" and to_ns(mb.leave) <= t_ns < to_ns(mb.join):
                act[mb.agent] = False
        return act

    # state
    X = np.zeros((B, D))
    x_start = rowwise_matmul(x0, scipy.linalg.expm(A * (start_ns / NS)).T) if (start_ns < 0 and noise_b is None) else x0.copy()
    X[:, :n] = x_start
    X[:, n:io] = w0
    X[:, io] = math.cos(noise_omega * start_ns / NS)
    X[:, io + 1] = math.sin(noise_omega * start_ns / NS)
    X[:, io + 2: io + 2 + m * n] = xhat0.reshape(B, m * n)
    X[:, D - n:] = x_start if xc0 is None else xc0

    gen_cache: dict = {}
    phi_cache: dict = {}
    step_cache: dict = {}

    def phi(act: np.ndarray, h_ns: int) -> np.ndarray:
        key = (act.tobytes(), h_ns)
        if key not in phi_cache:
            gk = act.tobytes()
            if gk not in gen_cache:
                gen_cache[gk] = _generator(d, act, noise_b, noise_omega, central_gain, Cs)
            if len(phi_cache) > 256:
                phi_cache.clear()
            phi_cache[key] = scipy.linalg.expm(gen_cache[gk] * (h_ns / NS)).T
        return phi_cache[key]

    def step_T(Wk: np.ndarray, pp: np.ndarray) -> np.ndarray:
        key = (Wk.tobytes(), pp.tobytes())
        if key not in step_cache:
            if len(step_cache) > 512:
                step_cache.clear()
            step_cache[key] = np.ascontiguousarray(step_matrix(d.P, Wk, pp).T)
        return step_cache[key]

    def xhat(Xv):
        return Xv[:, io + 2: io + 2 + m * n].reshape(-1, m, n)

    # open event indices s -> what is known of them; data captured for interval s+1; results of interval s
    events: dict[int, dict] = {}
    starts: dict[int, dict] = {}
    zq: dict[int, list] = {}
    next_emit = 0

    def event_buffer(s: int) -> dict:
        if s not in events:
            events[s] = {"e_pre": np.full((B, m, n), np.nan), "e_post": np.full((B, m, n), np.nan),
                         "x_event": np.full((B, m, n), np.nan), "ebar": np.full((B, nw), np.nan),
                         "central": np.full((B, m), np.nan), "x_nominal": None, "done": 0}
        return events[s]

    def run_iterations(s: int) -> None:
        """Interval s (1-based): q iterations of (12)-(13) from data captured at t_i(s-1)."""
        pp = part[s - 1]
        data = starts.pop(s)
        z = data["z"]
        Qw = np.zeros((B, m, n))
        for i in range(m):
            if pp[i]:
                Qw[:, i] = rowwise_matmul(data["w"][:, W_slices[i]], d.Q[i].T)
        xs = data["x"]                                     # x(t_i(s-1)) per agent, (B, m, n)
        pi0 = np.where(pp[None, :, None], z - xs, 0.0)
        Wk, Sk, N_nom, bad, tau = interval_sources(schedule, timing, event_ns, pp, s, rule, m_rule)
        c = np.where(pp[None, :, None], Qw, 0.0).reshape(B, m * n)
        zf = np.ascontiguousarray(z.reshape(B, m * n))
        traj = np.empty((q + 1, m * n))
        traj[0] = zf[0]
        # the step matrices of the interval (one when the weights do not change within it, as in
        # synchronous runs); each step is `rowwise_matmul` on contiguous operands
        steps = [step_T(Wk[0], pp)] * q if q and (Wk == Wk[:1]).all() else [step_T(w, pp) for w in Wk]
        for k, M in enumerate(steps, 1):
            zf = np.einsum("bk,kj->bj", zf, M) + c
            traj[k] = zf[0]
        z = zf.reshape(B, m, n)
        zq[s] = [z, 0]
        monitor.interval(IntervalData(s, Wk, Sk, N_nom, bad, tau, row_max(row_norms(pi0)),
                                      row_max(row_norms(np.where(pp[None, :, None], z - xs, 0.0))),
                                      traj.reshape(q + 1, m, n)))

    def capture(i: int, s: int, xt: np.ndarray) -> None:
        """Data of agent i for interval s+1 at t_is (after resets/re-initialisation)."""
        if s + 1 not in starts:
            starts[s + 1] = {"z": np.full((B, m, n), np.nan), "w": np.full((B, nw), np.nan),
                             "x": np.full((B, m, n), np.nan), "count": 0}
        st = starts[s + 1]
        st["z"][:, i] = xhat(X)[:, i]
        st["w"][:, W_slices[i]] = X[:, n + W_slices[i].start: n + W_slices[i].stop]
        st["x"][:, i] = xt
        st["count"] += 1
        if st["count"] == m:
            run_iterations(s + 1)

    def emit_ready() -> None:
        nonlocal next_emit
        while next_emit in events and events[next_emit]["done"] == m and events[next_emit]["x_nominal"] is not None:
            ev = events.pop(next_emit)
            monitor.event(EventData(next_emit, ev["e_pre"], ev["e_post"], ev["x_event"], ev["ebar"], ev["x_nominal"],
                                    ev["central"]))
            next_emit += 1

    all_events = np.unique(event_ns.ravel())
    nominal_ns = T_ns * np.arange(S + 1)
    next_s = np.zeros(m, dtype=int)      # next event index to process per agent
    t_prev = start_ns
    for seg_lo in range(start_ns, end_ns + 1, T_ns):
        seg_hi = min(seg_lo + T_ns, end_ns + 1)          # times in [seg_lo, seg_hi)
        k0 = -(-(seg_lo - grid0) // dt_ns)
        k1 = -(-(seg_hi - grid0) // dt_ns)
        grid = grid0 + dt_ns * np.arange(max(k0, 0), max(k1, 0), dtype=np.int64)
        evs = all_events[np.searchsorted(all_events, seg_lo):np.searchsorted(all_events, seg_hi)]
        noms = nominal_ns[np.searchsorted(nominal_ns, seg_lo):np.searchsorted(nominal_ns, seg_hi)]
        extra = [t for t in (start_ns, end_ns) if seg_lo <= t < seg_hi]
        for t in np.unique(np.concatenate([grid, evs, noms, np.array(extra, dtype=np.int64)])).tolist():
            if t > t_prev:
                X = rowwise_matmul(X, phi(active_at(t_prev), int(t - t_prev)))
                t_prev = t
            for i in range(m):
                s = next_s[i]
                if s <= S and event_ns[i, s] == t:
                    buf = event_buffer(s)
                    xt = X[:, :n].copy()
                    buf["e_pre"][:, i] = xhat(X)[:, i] - xt
                    if s >= 1 and part[s - 1, i]:
                        X[:, io + 2 + i * n: io + 2 + (i + 1) * n] = rowwise_matmul(zq[s][0][:, i], eAT.T)
                    if s >= 1:
                        zq[s][1] += 1
                        if zq[s][1] == m:
                            del zq[s]
                    for mb in membership:
                        if mb.agent == i and to_ns(mb.join) == t and mb.policy == "reinit":
                            if mb.x_reinit is not None:
                                X[:, io + 2 + i * n: io + 2 + (i + 1) * n] = mb.x_reinit
                            if mb.w_reinit is not None:
                                X[:, n + W_slices[i].start: n + W_slices[i].stop] = mb.w_reinit
                    buf["e_post"][:, i] = xhat(X)[:, i] - xt
                    buf["x_event"][:, i] = xt
                    wi = X[:, n + W_slices[i].start: n + W_slices[i].stop]
                    buf["ebar"][:, W_slices[i]] = wi - rowwise_matmul(xt, d.L[i].T)
                    buf["central"][:, i] = row_norms(X[:, D - n:] - xt)
                    buf["done"] += 1
                    next_s[i] += 1
                    if s < S:
                        capture(i, s, xt)
            if t % T_ns == 0 and 0 <= t // T_ns <= S:
                event_buffer(t // T_ns)["x_nominal"] = X[:, :n].copy()
            emit_ready()
            if t >= grid0 and (t - grid0) % dt_ns == 0:
                monitor.sample((t - grid0) // dt_ns, t, X)
    return monitor.finish()


# -- error recursion (37)-(43), (61') --------------------------------------------------------------

def step_matrices(P: np.ndarray, W: np.ndarray) -> np.ndarray:
    """M_k = P (W_k ⊗ I_n) for every k; W (q, m, m) -> (q, mn, mn)."""
    return step_matrix_batch(P, W)


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


def _times_step(Phi: np.ndarray, P: np.ndarray, W: np.ndarray) -> np.ndarray:
    """Φ P (W ⊗ I) by blocks, (mn)²(m + n) flops: columns of block j times P_j, then mix the
    column blocks with W (block (j, i) of W ⊗ I is W_ji I)."""
    m, n, _ = P.shape
    R = Phi.shape[0]
    Y = np.matmul(Phi.reshape(R, m, n).transpose(1, 0, 2), P)                      # (m, R, n): Φ_j P_j
    return np.matmul(Y.transpose(1, 2, 0), W).transpose(0, 2, 1).reshape(R, m * n)   # Σ_j Φ_j P_j W_ji


@dataclass(frozen=True)
class IntervalMatrices:
    """A(s) (42), B(s) (43), G(s) (61') of one interval, and the largest mixed norm |Φ_s(k)| over
    the k it was evaluated at (NaN when none was asked for)."""

    A: np.ndarray
    B: np.ndarray
    G: np.ndarray
    phi_max: float


def interval_matrices(d: ObserverDesign, W: np.ndarray, eAT: np.ndarray, E: np.ndarray | None = None,
                      phi_every: int = 0) -> IntervalMatrices:
    """A(s) = e^{ÃT} Φ(0), B(s) = e^{ÃT} Σ_{k=1}^q Φ(k) Q and, with event-time offsets (E (m, n, n)
    = e^{A t_i0}, None when every t_i0 = 0), G(s) = e^{ÃT} Σ_k Φ(k) P Γ(k), Γ_i(k) = Σ_j W_ij
    (e^{A t_i0} - e^{A t_j0}) (58): e(s) = A e(s-1) + B ē(s-1) - G x((s-1)T) (61, sign corrected).
    The products Φ(k) are formed backwards one at a time (memory (mn)², not q (mn)²); with
    `phi_every` = p > 0, |Φ(k)| is evaluated at every p-th k (and k = 0, q)."""
    from .jointly_observable_design import mixed_norm

    m, n = d.m, d.n
    q = W.shape[0]
    P = d.P
    Phi = np.eye(m * n)
    total = np.zeros((m * n, m * n))
    GX = np.zeros((m * n, n))
    phi_max = float("nan")
    if phi_every:
        phi_max = 1.0 if q else float("nan")                    # |Φ(q)| = |I| = 1
    offsets = E is not None
    pending: list = []                                  # Φ(k) whose mixed norms are due, evaluated in batches

    def flush():
        nonlocal phi_max
        if pending:
            phi_max = max(phi_max, float(np.max(mixed_norm(np.array(pending), [n] * m, [n] * m))))
            pending.clear()

    for k in range(q, 0, -1):
        total += Phi
        if offsets:
            Gam = E - np.einsum("ij,jab->iab", W[k - 1], E)                        # Γ(k), (m, n, n)
            GX += np.matmul(Phi.reshape(m * n, m, n).transpose(1, 0, 2), np.matmul(P, Gam)).sum(axis=0)   # Σ_j Φ_j P_j Γ_j
        Phi = _times_step(Phi, P, W[k - 1])
        if phi_every and ((k - 1) % phi_every == 0):
            pending.append(Phi)
            if len(pending) * Phi.size >= 2**22:
                flush()
    flush()
    big = np.kron(np.eye(m), eAT)
    As = big @ Phi
    Bs = big @ total @ scipy.linalg.block_diag(*d.Q)
    G = big @ GX
    return IntervalMatrices(As, Bs, G, phi_max)


def error_recursion(d: ObserverDesign, W: np.ndarray, T: float, offsets: np.ndarray | None = None,
                    Phi: np.ndarray | None = None, eAT: np.ndarray | None = None,
                    E: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A(s) = e^{ÃT} Φ(0) (42), B(s) = e^{ÃT} Σ_{k=1}^q Φ(k) Q (43), and for event-time offsets
    G(s) = e^{ÃT} Σ_k Φ(k) P Γ(k) with Γ_i(k) = Σ_j W_ij (e^{A t_i0} - e^{A t_j0}) (58), so that
    e(s) = A e(s-1) + B ē(s-1) - G x((s-1)T)  (61, with the sign corrected). `E`: the e^{A t_i0} if
    already computed; `Phi`: the products of (40) if already computed (else formed one at a time)."""
    m, n = d.m, d.n
    eAT = scipy.linalg.expm(d.A * T) if eAT is None else eAT
    if E is None and offsets is not None and np.any(np.asarray(offsets) != 0):
        E = np.array([scipy.linalg.expm(d.A * t) if t else np.eye(n) for t in offsets])
    if E is not None and not np.any(E - E[:1]):
        E = None                                                   # equal offsets: Γ = 0
    if Phi is None:
        r = interval_matrices(d, W, eAT, E)
        return r.A, r.B, r.G if E is not None else np.zeros((m * n, n))
    big = np.kron(np.eye(m), eAT)
    Qb = scipy.linalg.block_diag(*d.Q)
    As = big @ Phi[0]
    Bs = big @ Phi[1:].sum(axis=0) @ Qb
    G = np.zeros((m * n, n))
    if E is not None:
        Gam = E[None] - np.einsum("kij,jab->kiab", W, E)                   # (q, m, n, n), rows of W sum to 1
        Pb = scipy.linalg.block_diag(*d.P)
        G = big @ (Phi[1:] @ Pb[None] @ Gam.reshape(W.shape[0], m * n, n)).sum(axis=0)
    return As, Bs, G
