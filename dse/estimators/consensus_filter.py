"""Monte Carlo simulation of constant-gain consensus filters for a scalar random walk.

Process and sensors (a = 1): ``x(k+1) = x(k) + w(k)`` (eq. (3)), ``y(k) = x(k) 1_N + n(k)``
(eqs (4)-(5)), ``X_0 ~ N(x0_mean, sigma0)``, ``w ~ N(0, q)``, ``n ~ N(0, r I_N)``.  Each step:

1. record the predictive error ``xtilde(k|k-1) = x(k) 1 - xhat(k|k-1)`` (eq. (10)/(14));
2. measure ``y(k)`` at the current ``x(k)``;
3. update ``xhat(k|k) = (1-ell) xhat(k|k-1) + ell y(k)`` (eq. (7) = (11));
4. run ``m`` rounds of noisy consensus from ``z(k|k) = xhat(k|k)``:
   ``z <- Q z + sigma_c u`` (eq. (9); plain filter) or
   ``z <- Q z + sigma_c u + xhat(k|k)`` (eq. (12); re-injection), ``u ~ N(0, I_N)``;
   then ``xhat(k+1|k) = z`` (plain) or ``zeta xhat(k|k) + (1-zeta) z/(m+1)`` (eq. (13));
5. propagate ``x(k+1) = x(k) + w(k)``.

Trials live on an array axis; the only Python loops are over time steps and consensus
rounds (the rounds in closed form, ``z(m) = A xhat(k|k) + sigma_c b(m)``, see `_simulate`).
Products with ``Q`` and ``A`` are sums over each row's nonzero entries in a fixed order, made of
elementwise operations only: a trial's numbers never depend on how many trials are simulated
together (a matrix product's kernel may change with the array's width).

Random numbers come from ``rng``: one generator, or a sequence of ``(generator, size)`` streams
that cover consecutive groups of trials, each group drawing from its own generator. Draw order
per group (fixed, so a seed reproduces a run): ``X_0`` (size,), then per step ``n(k)`` (N, size),
``u(k + h/m)`` for ``h = 1..m`` (N, size) each, ``w(k)`` (size,). The ``u`` draws are made even when
``sigma_c = 0`` so that runs differing only in ``sigma_c`` share their process and measurement noise.

Two ways to consume a run: `simulate_consensus_filter(_configs)` keeps every error (trials x
steps x agents; for tests and small runs), `consensus_filter_moments` keeps only per-stream
sums of the errors' powers at chosen steps, so that memory does not grow with the horizon.
"""

from __future__ import annotations

import numbers
from dataclasses import dataclass
from typing import Callable

import numpy as np

from .consensus_covariance import (
    _as_consensus_matrix,
    _check_ell,
    _check_nonneg,
    _check_rounds,
    _check_steps,
    _check_zeta,
)

__all__ = ["ConsensusFilterRun", "ConsensusFilterMoments", "StreamMoments", "simulate_consensus_filter",
           "simulate_consensus_filter_configs", "consensus_filter_moments"]


@dataclass(frozen=True, eq=False)
class ConsensusFilterRun:
    """Result of :func:`simulate_consensus_filter`; ``K = n_steps``, ``N`` agents, ``P = n_paths``.

    Attributes
    ----------
    err_pred : (trials, K, N)
        Predictive errors ``xtilde(k|k-1) = x(k) 1 - xhat(k|k-1)``, ``k = 0..K-1`` (eq. (10)/(14)).
    err_filt : (trials, K, N)
        Posterior errors ``xtilde(k|k) = x(k) 1 - xhat(k|k)`` (eq. (14)).
    x : (P, K)
        True state ``x(k)`` of the first ``P`` trials.
    y : (P, K, N)
        Measurements ``y(k) = x(k) 1 + n(k)`` (eq. (5)).
    xhat_pred, xhat_filt : (P, K, N)
        ``xhat(k|k-1)`` and ``xhat(k|k)``.
    z_rounds : (P, K, m+1, N)
        Consensus iterates ``z(k + h/m | k)`` for ``h = 0..m`` (``h = 0`` is ``xhat(k|k)``); for the
        plain filter these are the iterates ``xhat(k + h/m | k)`` of eq. (9).
    u : (P, K, m, N)
        Standard normal communication draws ``u(k + h/m)``, ``h = 1..m`` (unscaled by ``sigma_c``).
    w : (P, K)
        Process noise ``w(k)`` (variance ``q``; ``x(k+1) = x(k) + w(k)``).
    n : (P, K, N)
        Measurement noise ``n(k)`` (variance ``r``).

    With several configurations (:func:`simulate_consensus_filter_configs`, :func:`consensus_filter_moments`)
    ``err_pred``, ``err_filt``, ``xhat_pred``, ``xhat_filt`` and ``z_rounds`` carry an extra axis 1 of
    length ``C``; in :func:`consensus_filter_moments` the paths cover the first ``path_steps`` steps only
    and ``err_pred``, ``err_filt`` are those of the ``P`` path trials.
    """

    err_pred: np.ndarray
    err_filt: np.ndarray
    x: np.ndarray
    y: np.ndarray
    xhat_pred: np.ndarray
    xhat_filt: np.ndarray
    z_rounds: np.ndarray
    u: np.ndarray
    w: np.ndarray
    n: np.ndarray


@dataclass(frozen=True, eq=False)
class StreamMoments:
    """Sums over the trials of each random stream, at the recorded steps (``U`` streams, ``C``
    configurations, ``S`` recorded steps, ``N`` agents): ``count`` (U,) trials; ``s1``, ``s2``, ``s4``
    (U, C, S, N) sums of ``e``, ``e^2``, ``e^4`` per agent; ``t1``, ``t2`` (U, C, S) sums of
    ``t = sum_i e_i^2`` and ``t^2``. Summed over streams in stream order they are the moments of
    the whole run, the same whatever groups of streams were simulated together."""

    count: np.ndarray
    s1: np.ndarray
    s2: np.ndarray
    s4: np.ndarray
    t1: np.ndarray
    t2: np.ndarray


@dataclass(frozen=True, eq=False)
class ConsensusFilterMoments:
    """Result of :func:`consensus_filter_moments`: the recorded ``steps``, the moments of the
    predictive and posterior errors (:class:`StreamMoments`), and the sample paths of the first
    ``P`` trials over the first ``path_steps`` steps (a :class:`ConsensusFilterRun`; ``P = 0`` when
    none were asked for)."""

    steps: np.ndarray
    pred: StreamMoments
    filt: StreamMoments
    paths: ConsensusFilterRun


def simulate_consensus_filter(
    Q,
    *,
    ell,
    m,
    sigma_c,
    q,
    r,
    sigma0,
    x0_mean,
    n_steps,
    n_trials,
    rng,
    reinjection,
    zeta=1.0,
    n_paths=0,
) -> ConsensusFilterRun:
    """Simulate ``n_trials`` independent runs of a two-stage consensus filter for ``n_steps`` steps.

    Parameters
    ----------
    Q : (N, N) row-stochastic consensus matrix (the paper assumes doubly stochastic).
    ell : constant measurement gain in (0, 1] (eq. (7)/(11)).
    m : number of consensus rounds per step, integer >= 0 (``m = 0``: no communication).
    sigma_c : communication noise standard deviation (eq. (6)).
    q, r, sigma0 : variances of ``w``, of each ``n_i`` and of ``X_0``.
    x0_mean : mean of ``X_0``; ``xhat(0|-1) = x0_mean 1``.
    n_steps : ``K``, number of steps ``k = 0..K-1`` recorded.
    n_trials : number of Monte Carlo trials (leading axis).
    rng : ``numpy.random.Generator``, or ``(generator, size)`` streams (see the module docstring).
    reinjection : False for the Carli et al. filter (7)+(9) (``sigma_c = 0`` gives (7)+(8));
        True for the re-injection filter (11)-(13).
    zeta : convex weight of eq. (13), in [0, 1] (ignored when ``reinjection`` is False).
    n_paths : number of leading trials whose full sample paths are kept.
    """
    run = simulate_consensus_filter_configs(
        Q, ell=[ell], m=m, sigma_c=[sigma_c], q=q, r=r, sigma0=sigma0, x0_mean=x0_mean, n_steps=n_steps,
        n_trials=n_trials, rng=rng, reinjection=reinjection, zeta=[zeta], n_paths=n_paths,
    )
    return ConsensusFilterRun(
        err_pred=run.err_pred[:, 0], err_filt=run.err_filt[:, 0], x=run.x, y=run.y,
        xhat_pred=run.xhat_pred[:, 0], xhat_filt=run.xhat_filt[:, 0], z_rounds=run.z_rounds[:, 0],
        u=run.u, w=run.w, n=run.n,
    )


def simulate_consensus_filter_configs(
    Q, *, ell, m, sigma_c, q, r, sigma0, x0_mean, n_steps, n_trials, rng, reinjection, zeta=1.0, n_paths=0,
) -> ConsensusFilterRun:
    """Several gain / noise configurations of the same filter driven by the same random draws.

    ``ell``, ``sigma_c`` and ``zeta`` are scalars or 1-D sequences broadcast to a common length
    ``C``. Every configuration sees the same ``X_0``, ``w``, ``n`` and standard-normal ``u`` (the
    latter scaled by its own ``sigma_c``): common random numbers, so the configurations are
    each an exact simulation of their filter, and the draws are paid for once. The draw order is
    the one of :func:`simulate_consensus_filter` (which is this function with ``C = 1``).

    Returns a :class:`ConsensusFilterRun` whose per-configuration fields carry an extra axis 1 of
    length ``C``: ``err_pred``, ``err_filt`` (trials, C, K, N); ``xhat_pred``, ``xhat_filt``
    (P, C, K, N); ``z_rounds`` (P, C, K, m+1, N). ``x``, ``y``, ``u``, ``w``, ``n`` are shared.
    Memory grows with trials x steps: :func:`consensus_filter_moments` is the streaming variant.
    """
    setup = _Setup(Q, ell, m, sigma_c, q, r, sigma0, x0_mean, n_steps, n_trials, rng, reinjection, zeta, n_paths)
    C, K, N, R = setup.C, setup.K, setup.N, setup.R
    e_pred = np.empty((C, K, N, R))
    e_filt = np.empty((C, K, N, R))

    def keep(k, ep, ef):
        e_pred[:, k] = ep
        e_filt[:, k] = ef

    paths = _simulate(setup, keep, path_steps=K)
    paths["err_pred"] = np.moveaxis(e_pred, 3, 0)  # (R, C, K, N) views of the trials-last arrays
    paths["err_filt"] = np.moveaxis(e_filt, 3, 0)
    return ConsensusFilterRun(**paths)


def consensus_filter_moments(
    Q, *, ell, m, sigma_c, q, r, sigma0, x0_mean, n_steps, rng, reinjection, record_steps, zeta=1.0, n_paths=0,
    path_steps=None,
) -> ConsensusFilterMoments:
    """The configurations of :func:`simulate_consensus_filter_configs`, keeping only the moments of the
    errors at ``record_steps`` (sums per random stream, :class:`StreamMoments`) and the sample paths
    of the first ``n_paths`` trials over the first ``path_steps`` steps (default: all). Memory is that
    of one step of the trials plus the recorded sums: it does not grow with ``n_steps``.

    ``rng``: ``(generator, size)`` streams (a single generator is one stream); the number of trials
    is their total size.
    """
    streams = _streams(rng)
    n_trials = sum(size for _, size in streams)
    setup = _Setup(Q, ell, m, sigma_c, q, r, sigma0, x0_mean, n_steps, n_trials, rng, reinjection, zeta, n_paths)
    steps = np.asarray(record_steps)
    if (steps.ndim != 1 or steps.size == 0 or not np.issubdtype(steps.dtype, np.integer) or steps.min() < 0
            or steps.max() >= setup.K or np.any(np.diff(steps) <= 0)):
        raise ValueError(f"record_steps must be strictly increasing integers in [0, n_steps), got {record_steps!r}")
    P_steps = setup.K if path_steps is None else _check_steps(path_steps, "path_steps")
    if P_steps > setup.K:
        raise ValueError(f"path_steps must be at most n_steps = {setup.K}, got {path_steps!r}")
    sizes = np.array([size for _, size in streams])
    U, C, S, N = sizes.size, setup.C, steps.size, setup.N
    where = np.full(setup.K, -1)
    where[steps] = np.arange(S)
    # per kind (pred, filt): sums of e, e², e⁴ per agent (C, S, N, U) and of t = Σ_i e_i², t² (C, S, U), streams last
    # while accumulating (one reduction per statistic group and step), moved first at the end
    node_sums = np.zeros((2, 3, C, S, N, U))
    trace_sums = np.zeros((2, 2, C, S, U))
    powers = np.empty((2, C, N, setup.R))   # e², e⁴ of one kind (reused)
    traces = np.empty((2, C, setup.R))      # t, t²
    per_stream = _stream_reducer(sizes)

    def accumulate(k, ep, ef):
        j = where[k]
        if j < 0:
            return
        for kind, e in enumerate((ep, ef)):
            np.multiply(e, e, out=powers[0])
            np.sum(powers[0], axis=1, out=traces[0])
            np.multiply(powers[0], powers[0], out=powers[1])
            np.multiply(traces[0], traces[0], out=traces[1])
            node_sums[kind, 0, :, j] = per_stream(e)
            node_sums[kind, 1:, :, j] = per_stream(powers)
            trace_sums[kind, :, :, j] = per_stream(traces)

    paths = _simulate(setup, accumulate, path_steps=P_steps)
    counts = sizes.astype(np.int64)

    def moments(kind: int) -> StreamMoments:
        first = lambda a: np.ascontiguousarray(np.moveaxis(a, -1, 0))   # noqa: E731 - streams on the leading axis
        return StreamMoments(counts, *(first(node_sums[kind, i]) for i in range(3)),
                             *(first(trace_sums[kind, i]) for i in range(2)))

    return ConsensusFilterMoments(steps.astype(np.int64), moments(0), moments(1), ConsensusFilterRun(**paths))


def _stream_reducer(sizes: np.ndarray) -> Callable[[np.ndarray], np.ndarray]:
    """The sums over the trials (last axis) of each stream: (..., R) -> (..., U). Each stream's sum is the
    same pairwise sum over its own trials wherever it sits in the array (streams of one size are summed
    as rows of a reshaped view, the others one by one)."""
    full = int(np.argmin(np.append(sizes, -1) == sizes[0]))   # the leading streams of the first stream's size
    size = int(sizes[0])
    if full == sizes.size:
        return lambda a: a.reshape(a.shape[:-1] + (full, size)).sum(axis=-1)
    edges = np.concatenate([[0], np.cumsum(sizes)])

    def reduce(a: np.ndarray) -> np.ndarray:
        head = a[..., : edges[full]].reshape(a.shape[:-1] + (full, size)).sum(axis=-1) if full else None
        rest = [a[..., edges[u]:edges[u + 1]].sum(axis=-1)[..., None] for u in range(full, sizes.size)]
        return np.concatenate(([head] if head is not None else []) + rest, axis=-1)

    return reduce


# --------------------------------------------------------------------------------------
# the common engine
# --------------------------------------------------------------------------------------


def _config_vector(value, name: str, check) -> np.ndarray:
    arr = np.atleast_1d(np.asarray(value, dtype=np.float64))
    if arr.ndim != 1 or arr.size == 0:
        raise ValueError(f"{name} must be a scalar or a non-empty 1-D sequence, got shape {arr.shape}")
    for v in arr:
        check(float(v), name)
    return arr


def _streams(rng) -> list[tuple[np.random.Generator, int]]:
    if isinstance(rng, np.random.Generator):
        raise TypeError("rng: the streaming simulator needs (generator, size) streams")
    try:
        streams = [(g, int(size)) for g, size in rng]
    except (TypeError, ValueError):
        raise TypeError(f"rng must be a numpy.random.Generator or a sequence of (generator, size), got "
                        f"{type(rng).__name__}") from None
    if not streams or any(not isinstance(g, np.random.Generator) or size < 1 for g, size in streams):
        raise TypeError("rng: every stream must be a (numpy.random.Generator, positive size) pair")
    return streams


class _Draws:
    """Standard normal draws for all trials, stream by stream along the last (trial) axis."""

    def __init__(self, rng, n_trials: int):
        self.streams = [(rng, n_trials)] if isinstance(rng, np.random.Generator) else _streams(rng)
        if sum(size for _, size in self.streams) != n_trials:
            raise ValueError("rng: the streams' sizes must add up to n_trials")

    def normal(self, out: np.ndarray) -> np.ndarray:
        if len(self.streams) == 1:
            self.streams[0][0].standard_normal(out=out)
            return out
        start = 0
        for g, size in self.streams:
            out[..., start:start + size] = g.standard_normal(out.shape[:-1] + (size,))
            start += size
        return out


class _RowSparse:
    """``M @ v`` for v of shape (..., N, R) as a sum over each row's nonzero entries of M, in a fixed
    order, with elementwise operations only (exact IEEE per element: independent of R)."""

    def __init__(self, M: np.ndarray):
        n = M.shape[0]
        nz = [np.flatnonzero(M[i]) for i in range(n)]
        width = max(1, max(len(c) for c in nz))
        self.cols = np.zeros((width, n), dtype=np.intp)
        self.weights = np.zeros((width, n, 1))
        for i, c in enumerate(nz):
            self.cols[: len(c), i] = c
            self.cols[len(c):, i] = c[0] if len(c) else 0
            self.weights[: len(c), i, 0] = M[i, c]

    def apply(self, v: np.ndarray, out: np.ndarray, tmp: np.ndarray) -> np.ndarray:
        np.take(v, self.cols[0], axis=-2, out=out, mode="clip")
        out *= self.weights[0]
        for cols, w in zip(self.cols[1:], self.weights[1:]):
            np.take(v, cols, axis=-2, out=tmp, mode="clip")
            tmp *= w
            out += tmp
        return out


class _Setup:
    """Validated inputs of a run."""

    def __init__(self, Q, ell, m, sigma_c, q, r, sigma0, x0_mean, n_steps, n_trials, rng, reinjection, zeta, n_paths):
        self.Q = _as_consensus_matrix(Q)
        ell_v = _config_vector(ell, "ell", lambda v, n: _check_ell(v, n))
        sigma_v = _config_vector(sigma_c, "sigma_c", _check_nonneg)
        zeta_v = _config_vector(zeta, "zeta", lambda v, n: _check_zeta(v, n))
        try:
            self.ell, self.sigma_c, self.zeta = np.broadcast_arrays(ell_v, sigma_v, zeta_v)
        except ValueError:
            raise ValueError(f"ell, sigma_c and zeta must have a common length, got {ell_v.size}, {sigma_v.size}, "
                             f"{zeta_v.size}") from None
        self.m = _check_rounds(m)
        self.q = _check_nonneg(q, "q")
        self.r = _check_nonneg(r, "r")
        self.sigma0 = _check_nonneg(sigma0, "sigma0")
        self.x0_mean = float(x0_mean)
        if not np.isfinite(self.x0_mean):
            raise ValueError(f"x0_mean must be finite, got {x0_mean!r}")
        self.K = _check_steps(n_steps, "n_steps")
        self.R = _check_steps(n_trials, "n_trials")
        if isinstance(n_paths, bool) or not isinstance(n_paths, numbers.Integral) or not 0 <= n_paths <= self.R:
            raise ValueError(f"n_paths must be an integer in [0, n_trials], got {n_paths!r}")
        self.P = int(n_paths)
        if not isinstance(rng, np.random.Generator) and isinstance(rng, (np.random.RandomState, str, bytes)):
            raise TypeError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")
        self.draws = _Draws(rng, self.R)
        self.reinjection = bool(reinjection)
        self.N = self.Q.shape[0]
        self.C = self.ell.size


def _simulate(s: _Setup, visit: Callable[[int, np.ndarray, np.ndarray], None], *, path_steps: int) -> dict:
    """Run the filters; ``visit(k, e_pred, e_filt)`` sees each step's errors (C, N, R) (valid during the call).
    Returns the sample paths of the first P trials over the first ``path_steps`` steps."""
    C, K, N, R, P, m = s.C, s.K, s.N, s.R, s.P, s.m
    Kp = path_steps
    sq, sr = np.sqrt(s.q), np.sqrt(s.r)
    # Internal layout: trials on the LAST axis, (C, N, R). With N tiny, every broadcast then
    # runs over long contiguous inner loops (measured several times faster than (R, C, N)).
    gain = s.ell[:, None, None]
    retain = (1.0 - s.ell)[:, None, None]
    keep = ((1.0 - s.zeta) / (m + 1))[:, None, None]
    zeta_b = s.zeta[:, None, None]
    sigma_b = s.sigma_c[:, None, None]
    noisy = bool(np.any(s.sigma_c != 0.0))

    paths = dict(
        err_pred=np.empty((P, C, Kp, N)), err_filt=np.empty((P, C, Kp, N)), x=np.empty((P, Kp)),
        y=np.empty((P, Kp, N)), xhat_pred=np.empty((P, C, Kp, N)), xhat_filt=np.empty((P, C, Kp, N)),
        z_rounds=np.empty((P, C, Kp, m + 1, N)), u=np.empty((P, Kp, m, N)), w=np.empty((P, Kp)), n=np.empty((P, Kp, N)),
    )

    e_pred = np.empty((C, N, R))
    e_filt = np.empty((C, N, R))
    x = np.empty(R)
    s.draws.normal(x)
    x *= np.sqrt(s.sigma0)
    x += s.x0_mean
    xp = np.full((C, N, R), s.x0_mean)
    xf = np.empty((C, N, R))
    noise = np.empty((N, R))
    scaled = np.empty((C, N, R))
    spare = np.empty((C, N, R))
    z = np.empty((C, N, R))
    w = np.empty(R)
    # The m consensus rounds in closed form. z(h) = Q z(h-1) + sigma_c u(h) (+ xhat(k|k) with
    # re-injection, eq. (12)) from z(0) = xhat(k|k) is linear, so z(m) = A xhat(k|k) + sigma_c b(m)
    # with A = Q^m (eq. (9)) or sum_{j<=m} Q^j (eq. (12)) precomputed, and b(h) = Q b(h-1) + u(h),
    # b(0) = 0, the noise part, which every configuration shares: the rounds cost one (N, R)
    # product per round instead of one (C, N, R) product, scaling and sum (same draws, same
    # results up to rounding). The rounds of the first P trials are also run one by one, for the
    # kept paths.
    A = np.eye(N)
    power = np.eye(N)
    for _ in range(m):
        power = s.Q @ power
        A = A + power if s.reinjection else power
    Q_op, A_op = _RowSparse(s.Q), _RowSparse(A)
    b = np.zeros((N, R))
    bnext = np.empty((N, R))
    btmp = np.empty((N, R))

    def paths_of(a):  # (C, N, R) -> (P, C, N) for the first P trials
        return a[:, :, :P].transpose(2, 0, 1)

    for k in range(K):
        np.subtract(x, xp, out=e_pred)
        s.draws.normal(noise)  # n(k) / sqrt(r)
        noise *= sr
        on_path = P > 0 and k < Kp
        if on_path:
            paths["x"][:, k] = x[:P]
            paths["n"][:, k] = noise[:, :P].T
            paths["y"][:, k] = x[:P, None] + noise[:, :P].T
            paths["xhat_pred"][:, :, k] = paths_of(xp)
            paths["err_pred"][:, :, k] = paths_of(e_pred)
        # (7)/(11): xf = (1-ell) xp + ell (x 1 + n)
        noise += x
        np.multiply(noise, gain, out=xf)
        xp *= retain
        xf += xp
        np.subtract(x, xf, out=e_filt)
        visit(k, e_pred, e_filt)
        if on_path:
            paths["err_filt"][:, :, k] = paths_of(e_filt)
            paths["xhat_filt"][:, :, k] = paths_of(xf)
            paths["z_rounds"][:, :, k, 0] = paths_of(xf)
            zp = xf[:, :, :P].copy()
        b[...] = 0.0
        for h in range(m):
            s.draws.normal(noise)  # u(k + (h+1)/m), shared by the configurations
            Q_op.apply(b, bnext, btmp)
            bnext += noise
            b, bnext = bnext, b
            if on_path:
                paths["u"][:, k, h] = noise[:, :P].T
                zp = np.einsum("ij,cjp->cip", s.Q, zp) + sigma_b * noise[:, :P] + (xf[:, :, :P] if s.reinjection else 0.0)
                paths["z_rounds"][:, :, k, h + 1] = zp.transpose(2, 0, 1)
        if m:
            A_op.apply(xf, z, spare)
            if noisy:
                np.multiply(b, sigma_b, out=scaled)
                z += scaled
        else:
            z[...] = xf
        if s.reinjection:
            # (13): xhat(k+1|k) = zeta xhat(k|k) + (1-zeta) z(k+1|k)/(m+1)
            np.multiply(z, keep, out=xp)
            np.multiply(xf, zeta_b, out=scaled)
            xp += scaled
        else:
            xp[...] = z
        s.draws.normal(w)
        w *= sq
        if on_path:
            paths["w"][:, k] = w[:P]
        x += w
    return paths
