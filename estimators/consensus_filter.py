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

Trials live on the leading array axis; the only Python loops are over time steps and
consensus rounds (the rounds in closed form, z(m) = A xhat(k|k) + sigma_c b(m), see the loop).  Draw order from ``rng`` (fixed, so a seed reproduces a run): ``X_0``
(trials,), then per step ``n(k)`` (trials, N), ``u(k + h/m)`` for ``h = 1..m`` (trials, N)
each, ``w(k)`` (trials,).  The ``u`` draws are made even when ``sigma_c = 0`` so that runs
differing only in ``sigma_c`` share their process and measurement noise.
"""

from __future__ import annotations

import numbers
from dataclasses import dataclass

import numpy as np

from .consensus_covariance import (
    _as_consensus_matrix,
    _check_ell,
    _check_nonneg,
    _check_rounds,
    _check_steps,
    _check_zeta,
)

__all__ = ["ConsensusFilterRun", "simulate_consensus_filter", "simulate_consensus_filter_configs"]

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
    rng : ``numpy.random.Generator``.
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


def _config_vector(value, name: str, check) -> np.ndarray:
    arr = np.atleast_1d(np.asarray(value, dtype=np.float64))
    if arr.ndim != 1 or arr.size == 0:
        raise ValueError(f"{name} must be a scalar or a non-empty 1-D sequence, got shape {arr.shape}")
    for v in arr:
        check(float(v), name)
    return arr


def simulate_consensus_filter_configs(
    Q, *, ell, m, sigma_c, q, r, sigma0, x0_mean, n_steps, n_trials, rng, reinjection, zeta=1.0, n_paths=0,
    buffers: dict | None = None,
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

    ``buffers``: an optional dict kept by a caller that simulates block after block and is done
    with a block's ``err_pred`` / ``err_filt`` before it asks for the next one. Those two arrays
    (the bulk of the memory) are then reused between calls of the same shape instead of being
    allocated anew: a fresh allocation of that size is mapped from the OS and pays a page fault
    on first touch, measured ~2 ns per element here, as much as the normal draws of the step.
    """
    Q = _as_consensus_matrix(Q)
    ell_v = _config_vector(ell, "ell", lambda v, n: _check_ell(v, n))
    sigma_v = _config_vector(sigma_c, "sigma_c", _check_nonneg)
    zeta_v = _config_vector(zeta, "zeta", lambda v, n: _check_zeta(v, n))
    try:
        ell_v, sigma_v, zeta_v = np.broadcast_arrays(ell_v, sigma_v, zeta_v)
    except ValueError:
        raise ValueError(f"ell, sigma_c and zeta must have a common length, got {ell_v.size}, {sigma_v.size}, "
                         f"{zeta_v.size}") from None
    m = _check_rounds(m)
    q = _check_nonneg(q, "q")
    r = _check_nonneg(r, "r")
    sigma0 = _check_nonneg(sigma0, "sigma0")
    x0_mean = float(x0_mean)
    if not np.isfinite(x0_mean):
        raise ValueError(f"x0_mean must be finite, got {x0_mean!r}")
    K = _check_steps(n_steps, "n_steps")
    R = _check_steps(n_trials, "n_trials")
    if isinstance(n_paths, bool) or not isinstance(n_paths, numbers.Integral) or not 0 <= n_paths <= R:
        raise ValueError(f"n_paths must be an integer in [0, n_trials], got {n_paths!r}")
    P = int(n_paths)
    if not isinstance(rng, np.random.Generator):
        raise TypeError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")
    reinjection = bool(reinjection)

    N = Q.shape[0]
    C = ell_v.size
    sq, sr = np.sqrt(q), np.sqrt(r)
    # Internal layout: trials on the LAST axis, (C, N, R). With N tiny, every broadcast then
    # runs over long contiguous inner loops (measured several times faster than (R, C, N));
    # the results are exposed with trials leading, as views.
    gain = ell_v[:, None, None]
    retain = (1.0 - ell_v)[:, None, None]
    keep = ((1.0 - zeta_v) / (m + 1))[:, None, None]
    zeta_b = zeta_v[:, None, None]
    sigma_b = sigma_v[:, None, None]
    noisy = bool(np.any(sigma_v != 0.0))

    if buffers is not None and buffers.get("shape") == (C, K, N, R):
        e_pred, e_filt = buffers["e_pred"], buffers["e_filt"]
    else:
        e_pred = np.empty((C, K, N, R))
        e_filt = np.empty((C, K, N, R))
        if buffers is not None:
            buffers.update(shape=(C, K, N, R), e_pred=e_pred, e_filt=e_filt)
    p_x = np.empty((P, K))
    p_y = np.empty((P, K, N))
    p_xp = np.empty((P, C, K, N))
    p_xf = np.empty((P, C, K, N))
    p_z = np.empty((P, C, K, m + 1, N))
    p_u = np.empty((P, K, m, N))
    p_w = np.empty((P, K))
    p_n = np.empty((P, K, N))

    x = np.empty(R)
    rng.standard_normal(out=x)
    x *= np.sqrt(sigma0)
    x += x0_mean
    xp = np.full((C, N, R), x0_mean)
    xf = np.empty((C, N, R))
    noise = np.empty((N, R))
    scaled = np.empty((C, N, R))
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
        power = Q @ power
        A = A + power if reinjection else power
    b = np.zeros((N, R))
    bnext = np.empty((N, R))

    def paths_of(a):  # (C, N, R) -> (P, C, N) for the first P trials
        return np.moveaxis(a[:, :, :P], 2, 0)

    for k in range(K):
        np.subtract(x, xp, out=e_pred[:, k])
        rng.standard_normal(out=noise)  # n(k) / sqrt(r)
        noise *= sr
        if P:
            p_x[:, k] = x[:P]
            p_n[:, k] = noise[:, :P].T
            p_y[:, k] = x[:P, None] + noise[:, :P].T
            p_xp[:, :, k] = paths_of(xp)
        # (7)/(11): xf = (1-ell) xp + ell (x 1 + n)
        noise += x
        np.multiply(noise, gain, out=xf)
        xp *= retain
        xf += xp
        np.subtract(x, xf, out=e_filt[:, k])
        if P:
            p_xf[:, :, k] = paths_of(xf)
            p_z[:, :, k, 0] = paths_of(xf)
            zp = xf[:, :, :P].copy()
        b[...] = 0.0
        for h in range(m):
            rng.standard_normal(out=noise)  # u(k + (h+1)/m), shared by the configurations
            np.matmul(Q, b, out=bnext)
            bnext += noise
            b, bnext = bnext, b
            if P:
                p_u[:, k, h] = noise[:, :P].T
                zp = Q @ zp + sigma_b * noise[:, :P] + (xf[:, :, :P] if reinjection else 0.0)
                p_z[:, :, k, h + 1] = np.moveaxis(zp, 2, 0)
        if m:
            np.matmul(A, xf, out=z)
            if noisy:
                np.multiply(b, sigma_b, out=scaled)
                z += scaled
        else:
            z[...] = xf
        if reinjection:
            # (13): xhat(k+1|k) = zeta xhat(k|k) + (1-zeta) z(k+1|k)/(m+1)
            np.multiply(z, keep, out=xp)
            np.multiply(xf, zeta_b, out=scaled)
            xp += scaled
        else:
            xp[...] = z
        rng.standard_normal(out=w)
        w *= sq
        if P:
            p_w[:, k] = w[:P]
        x += w

    err_pred = np.moveaxis(e_pred, 3, 0)  # (R, C, K, N) views of the trials-last arrays
    err_filt = np.moveaxis(e_filt, 3, 0)
    return ConsensusFilterRun(
        err_pred=err_pred,
        err_filt=err_filt,
        x=p_x,
        y=p_y,
        xhat_pred=p_xp,
        xhat_filt=p_xf,
        z_rounds=p_z,
        u=p_u,
        w=p_w,
        n=p_n,
    )
