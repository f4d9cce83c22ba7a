"""Gains minimising the asymptotic trace of consensus filters for a scalar random walk.

* No communication (``m = 0``): ``J_0(ell) = N (ell^2 r + q) / (1 - (1-ell)^2)`` (§V-B), minimised in
  closed form by the single-sensor steady-state Kalman gain.
* Re-injection filter (11)-(13): minimise ``J(ell, zeta)`` of eq. (16) (corrected, or as printed)
  over ``[1e-6, 1] x [0, 1]``: ``J`` on a dense grid, the lowest discrete local minima of the grid
  refined on two finer local grids, then a box-constrained Newton method with the analytic
  gradient from each of them (the paper used fmincon with unstated settings; (16) need not be
  convex, and the printed (16) can have two local minima). The best point is kept, never worse
  than the grid.
* Plain noisy consensus filter (7)+(9): the same for the closed-form ``J_C(ell)`` over ``ell``.

Whole tables (every ``m`` and ``sigma_c`` of a scenario) are optimised at once: ``J`` is affine in
``sigma_c^2`` with coefficients that depend on ``m`` only, so a grid is built once per ``m`` and
shared by every ``sigma_c`` and both formulas, and the Newton iterations run on all cells
together. Optimality is reported as KKT residuals from central finite differences,
independent of the analytic gradient used by the optimiser.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .consensus_covariance import (
    _as_consensus_matrix,
    _check_nonneg,
    _check_rounds,
    _check_symmetric,
    _power_sum,
    geometric_gram_sum,
)
from .consensus_trace import _split_unit_eigenvalue

__all__ = [
    "KKTResiduals",
    "GainOptimum",
    "CarliGainOptimum",
    "GainTable",
    "optimal_gain_no_communication",
    "optimal_reinjection_gains",
    "optimal_carli_gain",
    "reinjection_gain_tables",
    "carli_gain_table",
]

ELL_BOUNDS = (1e-6, 1.0)
ZETA_BOUNDS = (0.0, 1.0)
#: the grid of ell starts here (J grows like 1/ell below it)
GRID_ELL_MIN = 1e-3
#: central-difference steps: relative to ell (its scale; the cost grows like 1/ell as ell -> 0), absolute in zeta
_FD_STEP = 1e-5
_BOUND_TOL = 1e-9
_NEWTON_ITERATIONS = 60
_LINE_SEARCH_HALVINGS = 45


@dataclass(frozen=True)
class KKTResiduals:
    """First-order optimality of a box-constrained minimum, by central finite differences.

    Attributes
    ----------
    dJ_dell, dJ_dzeta : partial derivatives at the optimum (``dJ_dzeta`` is 0 for one-parameter problems).
    projected_gradient : the gradient with each component at an active bound replaced by its
        infeasible part (``min(g, 0)`` at a lower bound, ``max(g, 0)`` at an upper bound); its
        infinity norm is the KKT residual, 0 at an exact KKT point.
    d2J_dell2, d2J_dzeta2 : second differences (curvatures) at the optimum, for scaling the residual.
    """

    dJ_dell: float
    dJ_dzeta: float
    projected_gradient: tuple[float, float]
    d2J_dell2: float = 0.0
    d2J_dzeta2: float = 0.0

    @property
    def residual(self) -> float:
        return float(max(abs(g) for g in self.projected_gradient))

    def scaled_residual(self, J: float, ell: float) -> float:
        """The projected gradient in units of what a minimum located from values of ``J`` can resolve.

        Such a minimiser is within ``sqrt(eps J / J'')`` of the true one, where the gradient is
        ``sqrt(eps J J'')``; so each component is divided by ``sqrt(J max(|J''|, J/s^2))`` with the
        coordinate's scale ``s`` (``ell`` for ``ell``, 1 for ``zeta``, whose range is [0, 1]). The result is
        at most about ``sqrt(eps)`` at a computed minimum (less after the Newton steps).
        """
        return float(_scaled_residual(np.array(self.projected_gradient), np.array([self.d2J_dell2, self.d2J_dzeta2]),
                                      float(J), float(ell)))


def _scaled_residual(proj, curv, J, ell):
    """Vectorised `KKTResiduals.scaled_residual`: ``proj``, ``curv`` (..., 2); ``J``, ``ell`` (...)."""
    J = np.abs(np.asarray(J, float))[..., None]
    scale = np.stack([np.asarray(ell, float), np.ones(np.shape(ell))], axis=-1)
    return np.max(np.abs(proj) / np.sqrt(J * np.maximum(np.abs(curv), J / scale**2)), axis=-1)


@dataclass(frozen=True, eq=False)
class GainOptimum:
    """Minimiser of ``J(ell, zeta)`` (eq. (16)) for the re-injection filter.

    Attributes
    ----------
    ell, zeta, J : the optimum and its cost under the chosen formula.
    grid_ell : (n_ell,) grid of ``ell`` in [1e-3, 1]; grid_zeta : (n_zeta,) grid of ``zeta`` in [0, 1].
    grid_J : (n_ell, n_zeta) cost on the grid (at ``m = 0`` the no-communication cost ``J_0(ell)``,
        constant in ``zeta``).
    kkt : :class:`KKTResiduals` at the optimum.
    """

    ell: float
    zeta: float
    J: float
    grid_ell: np.ndarray = field(repr=False)
    grid_zeta: np.ndarray = field(repr=False)
    grid_J: np.ndarray = field(repr=False)
    kkt: KKTResiduals


@dataclass(frozen=True, eq=False)
class CarliGainOptimum:
    """Minimiser of the plain filter's ``J_C(ell)``; ``grid_J`` is ``J_C`` on ``grid_ell``."""

    ell: float
    J: float
    grid_ell: np.ndarray = field(repr=False)
    grid_J: np.ndarray = field(repr=False)
    kkt: KKTResiduals


@dataclass(frozen=True, eq=False)
class GainTable:
    """Optimal gains of every cell (``sigma_c`` rows x ``m`` columns), arrays of shape (S, M).

    ``zeta`` is 1 for the plain filter (no such parameter) and at ``m = 0`` (no rounds).
    ``dJ_dell``, ``dJ_dzeta``, ``d2J_dell2``, ``d2J_dzeta2``: central differences at the optimum;
    ``kkt_residual``: infinity norm of the projected gradient; ``kkt_scaled``: the same in units of
    the attainable precision (:meth:`KKTResiduals.scaled_residual`); ``grid_min``: the smallest
    cost on the grid. ``grids`` (only when asked for): the grid of each cell.
    """

    ms: np.ndarray
    sigma_c: np.ndarray
    ell: np.ndarray
    zeta: np.ndarray
    J: np.ndarray
    dJ_dell: np.ndarray
    dJ_dzeta: np.ndarray
    d2J_dell2: np.ndarray
    d2J_dzeta2: np.ndarray
    kkt_residual: np.ndarray
    kkt_scaled: np.ndarray
    grid_min: np.ndarray
    grid_ell: np.ndarray = field(repr=False)
    grid_zeta: np.ndarray = field(repr=False)
    grids: np.ndarray | None = field(default=None, repr=False)

    def kkt(self, s: int, j: int) -> KKTResiduals:
        e, z = float(self.ell[s, j]), float(self.zeta[s, j])
        g = np.array([self.dJ_dell[s, j], self.dJ_dzeta[s, j]])
        proj = _project(g, np.array([e, z]), np.array([ELL_BOUNDS[0], ZETA_BOUNDS[0]]),
                        np.array([ELL_BOUNDS[1], ZETA_BOUNDS[1]]))
        return KKTResiduals(float(g[0]), float(g[1]), (float(proj[0]), float(proj[1])),
                            float(self.d2J_dell2[s, j]), float(self.d2J_dzeta2[s, j]))

    def optimum(self, s: int, j: int) -> GainOptimum:
        """The optimum of one cell with its grid (of a table made with ``keep_grids``); the same as
        :func:`optimal_reinjection_gains` of that cell alone (the cells are optimised independently)."""
        return GainOptimum(float(self.ell[s, j]), float(self.zeta[s, j]), float(self.J[s, j]), self.grid_ell,
                           self.grid_zeta, self.grids[s, j], self.kkt(s, j))


def optimal_gain_no_communication(q, r, n_agents) -> tuple[float, float]:
    """``(ell*_0, J*_0)`` minimising ``J_0(ell) = N (ell^2 r + q)/(1-(1-ell)^2)`` (§V-B, ``m = 0``, ``zeta := 1``).

    ``ell*_0 = (-q + sqrt(q^2 + 4 q r)) / (2 r)``, the single-sensor steady-state Kalman gain, and
    ``J*_0 = N q / ell*_0 = N (q + sqrt(q^2 + 4 q r))/2`` (``N`` times the steady-state prior variance).
    With ``r -> r/N`` this gives the centralised Kalman gain ``K_c`` and ``N P_c^- = N q / K_c``.
    """
    q = _check_nonneg(q, "q")
    r = _check_nonneg(r, "r")
    if q <= 0.0:
        raise ValueError(f"q must be > 0, got {q!r}")
    if r <= 0.0:
        raise ValueError(f"r must be > 0, got {r!r}")
    if isinstance(n_agents, bool) or int(n_agents) != n_agents or n_agents < 1:
        raise ValueError(f"n_agents must be a positive integer, got {n_agents!r}")
    # 2q / (q + sqrt(q^2 + 4qr)) is the same number without cancellation for small q/r.
    ell = 2.0 * q / (q + np.sqrt(q * q + 4.0 * q * r))
    return float(ell), float(n_agents * q / ell)


def _no_communication_cost(ell, n, q, r):
    ell = np.asarray(ell, dtype=np.float64)
    return n * (ell**2 * r + q) / (ell * (2.0 - ell))    # 1 - (1-ell)^2 without cancellation


# --------------------------------------------------------------------------------------
# the costs, per cell: values on grids, values and gradients at points
# --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class _Cells:
    """Per-cell constants of ``J``: ``mu_h = beta lam_bar_h + zeta`` (re-injection; ``beta = (1-zeta)/(m+1)``)
    or ``mu_h = lam_h^m`` (plain filter); ``s`` the noise bracket of each mode; arrays (C,) and (C, H)."""

    m: np.ndarray
    sigma2: np.ndarray
    lam_bar: np.ndarray
    s: np.ndarray
    n: int
    q: float
    r: float
    reinjection: bool

    def take(self, idx):
        return _Cells(self.m[idx], self.sigma2[idx], self.lam_bar[idx], self.s[idx], self.n, self.q, self.r,
                      self.reinjection)


def _cost_and_gradient(cells: _Cells, ell, zeta, gradient: bool = True):
    """``J``, ``dJ/dell``, ``dJ/dzeta`` at points (P,) of cells (P,) (analytic; eq. (16) or J_C); ``(J,)``
    without the gradient."""
    ell, zeta = np.asarray(ell, float), np.asarray(zeta, float)
    a = (1.0 - ell) ** 2
    one_minus_a = 1.0 - a
    lr = ell**2 * cells.r
    if cells.reinjection:
        inv = 1.0 / (cells.m + 1.0)
        beta = (1.0 - zeta) * inv
        mu = beta[:, None] * cells.lam_bar + zeta[:, None]
        dmu = 1.0 - cells.lam_bar * inv[:, None]
        pref = beta**2 * cells.sigma2
        dpref = -2.0 * beta * inv * cells.sigma2
    else:
        mu = cells.lam_bar
        dmu = np.zeros_like(mu)
        pref = cells.sigma2
        dpref = np.zeros_like(pref)
    mu2 = mu * mu
    head_num = lr + cells.q * cells.n + pref * cells.m
    den = 1.0 - a[:, None] * mu2
    num = lr[:, None] * mu2 + pref[:, None] * cells.s
    J = head_num / one_minus_a + np.sum(num / den, axis=1)
    if not gradient:
        return (J,)
    da = -2.0 * (1.0 - ell)
    dJ_dell = (2.0 * ell * cells.r / one_minus_a + head_num * da / one_minus_a**2
               + np.sum(2.0 * ell[:, None] * cells.r * mu2 / den + num * mu2 * da[:, None] / den**2, axis=1))
    dmu2 = 2.0 * mu * dmu
    dJ_dzeta = (dpref * cells.m / one_minus_a
                + np.sum((lr[:, None] * dmu2 + dpref[:, None] * cells.s) / den + num * a[:, None] * dmu2 / den**2, axis=1))
    return J, dJ_dell, dJ_dzeta


def _cost(cells: _Cells, ell, zeta):
    """``J`` at points (P,) of cells (P,): +inf where ``1 - (1-ell)^2`` rounds to 0 (a gain below the
    rounding unit of 1 has no steady state in float64; the design then raises NumericalLimit)."""
    with np.errstate(divide="ignore"):
        return _cost_and_gradient(cells, ell, zeta, gradient=False)[0]


#: points per block of `_at`: a block's per-mode arrays stay near 2 MB whatever the number of modes
_BLOCK_ELEMENTS = 2**18


def _at(cells: _Cells, rows, ell, zeta, gradient: bool = True):
    """``J`` and its gradient (``[J]`` without it) at points (P,) of the cells ``rows`` (P,), in blocks of
    bounded memory."""
    rows, ell, zeta = np.asarray(rows), np.asarray(ell, float), np.asarray(zeta, float)
    step = max(1, _BLOCK_ELEMENTS // max(1, cells.lam_bar.shape[1]))
    out = [np.empty(rows.size) for _ in range(3 if gradient else 1)]
    for a in range(0, rows.size, step):
        sl = slice(a, a + step)
        for o, v in zip(out, _cost_and_gradient(cells.take(rows[sl]), ell[sl], zeta[sl], gradient)):
            o[sl] = v
    return out


def _grid_parts(lam_bar, s_variants, m, n, q, r, grid_ell, grid_zeta, reinjection):
    """For one ``m``: ``J = base + sigma_c^2 noise_v`` on the grid, for each noise bracket ``s_v`` (V, H).

    Returns ``base`` (n_ell, n_zeta) and ``noise`` (V, n_ell, n_zeta). The loop runs over modes so
    that a grid costs a few passes over 2-D arrays."""
    a = (1.0 - grid_ell) ** 2
    lr = grid_ell**2 * r
    inv_head = 1.0 / (1.0 - a)
    shape = (grid_ell.size, grid_zeta.size)
    beta2 = ((1.0 - grid_zeta) / (m + 1)) ** 2 if reinjection else np.ones(grid_zeta.size)
    base = np.empty(shape)
    np.multiply(((lr + q * n) * inv_head)[:, None], np.ones(grid_zeta.size)[None, :], out=base)
    noise = np.empty((len(s_variants),) + shape)
    noise[...] = (m * inv_head)[:, None]
    den = np.empty(shape)
    term = np.empty(shape)
    for h in range(lam_bar.shape[0]):
        mu = (1.0 - grid_zeta) / (m + 1) * lam_bar[h] + grid_zeta if reinjection else np.full(grid_zeta.size, lam_bar[h])
        mu2 = mu * mu
        np.multiply(a[:, None], mu2[None, :], out=den)
        np.subtract(1.0, den, out=den)
        np.reciprocal(den, out=den)
        np.multiply(lr[:, None], mu2[None, :], out=term)
        term *= den
        base += term
        for v, s in enumerate(s_variants):
            if s[h] != 0.0:
                np.multiply(den, s[h], out=term)
                noise[v] += term
    noise *= beta2[None, None, :]
    return base, noise


def _grid_local_minima(G: np.ndarray, n_best: int) -> np.ndarray:
    """Flat indices (B, n_best) of the lowest discrete local minima (3x3 neighbourhood, ties
    included) of each grid G[b] (lowest first, so the grid minimum comes first); a grid with
    fewer local minima repeats its minimum. The minima along rows are found first (two
    comparisons over the grid); only they are compared with the rows above and below."""
    B, n0, n1 = G.shape
    row_min = np.empty(G.shape, bool)   # not above either neighbour in its row (a missing neighbour is +inf)
    np.less_equal(G[:, :, 1:-1], G[:, :, :-2], out=row_min[:, :, 1:-1])
    row_min[:, :, 1:-1] &= G[:, :, 1:-1] <= G[:, :, 2:]
    row_min[:, :, 0] = G[:, :, 0] <= G[:, :, 1]
    row_min[:, :, -1] = G[:, :, -1] <= G[:, :, -2]
    b, i, j = np.unravel_index(np.flatnonzero(row_min), G.shape)
    v = G[b, i, j]
    ok = np.ones(b.size, bool)
    for di in (-1, 1):
        ii = i + di
        inside = (ii >= 0) & (ii < n0)
        iic = np.clip(ii, 0, n0 - 1)
        for dj in (-1, 0, 1):
            jj = np.clip(j + dj, 0, n1 - 1)
            ok &= ~inside | (j + dj < 0) | (j + dj >= n1) | (v <= G[b, iic, jj])
    b, flat, v = b[ok], i[ok] * n1 + j[ok], v[ok]
    order = np.lexsort((flat, v, b))
    b, flat = b[order], flat[order]
    rank = np.arange(b.size) - np.searchsorted(b, b)
    out = np.empty((B, n_best), dtype=np.int64)
    keep = rank < n_best
    out[b[keep], rank[keep]] = flat[keep]
    count = np.bincount(b[keep], minlength=B)
    for r in range(1, n_best):   # fewer minima than starts: repeat the grid minimum
        out[count <= r, r] = out[count <= r, 0]
    return out


def _project(g, x, lo, hi):
    """The projected gradient of a box-constrained problem (KKT residual components)."""
    at_lo, at_hi = x <= lo + _BOUND_TOL, x >= hi - _BOUND_TOL
    return np.where(at_lo, np.minimum(g, 0.0), np.where(at_hi, np.maximum(g, 0.0), g))


def _line_search(fun_grad, rows, xa, Ja, ga, step, lo, hi, sa, pd, factors):
    """The first of ``x + t step`` (t in ``factors``, projected on the box) that passes the Armijo test, or
    (for the full step) keeps J within rounding while shrinking the projected gradient; NaN where none."""
    A, d = xa.shape
    T = factors.size
    trial = np.clip(xa[:, None, :] + factors[None, :, None] * step[:, None, :], lo, hi)   # (A, T, d)
    Jt, gt = fun_grad(trial.reshape(-1, d), np.repeat(rows, T))
    Jt, gt = Jt.reshape(A, T), gt.reshape(A, T, d)
    decrease = np.sum(ga[:, None, :] * (trial - xa[:, None, :]), axis=2)
    ok = (Jt <= Ja[:, None] + 1e-4 * decrease) & (Jt < Ja[:, None]) & np.isfinite(Jt)
    if factors[0] == 1.0:
        # Close to the minimum J no longer resolves a decrease (its changes are rounding); a full
        # Newton step is still taken if J stays within rounding and the projected gradient shrinks,
        # which locates the minimum to the precision of the gradient rather than of J.
        shrinks = (np.max(np.abs(_project(gt[:, 0], trial[:, 0], lo, hi)) * sa, axis=1)
                   < np.max(np.abs(_project(ga, xa, lo, hi)) * sa, axis=1))
        ok[:, 0] |= (Jt[:, 0] <= Ja + 1e-13 * np.abs(Ja)) & shrinks & pd
    found = ok.any(axis=1)
    first = np.argmax(ok, axis=1)
    pick = np.arange(A)
    Jn = np.where(found, Jt[pick, first], np.nan)
    return Jn, gt[pick, first], trial[pick, first]


def _minimise_box(fun_grad, x, lo, hi, scale):
    """Box-constrained Newton method on many independent problems at once.

    ``fun_grad(x) -> (J, g)`` for points ``x`` (P, d); the Hessian is the central difference of the
    analytic gradient (steps ``1e-5 * scale``). A coordinate at a bound whose gradient points out of
    the box is held; the Newton step on the others (a scaled gradient step where the Hessian is not
    positive definite) is followed along the projected path with Armijo backtracking. Each problem
    stops when no step is accepted, after _NEWTON_ITERATIONS iterations, or when it returns to a point
    it visited before (rounding can make the last steps cycle): then with the point the remaining
    iterations of the cycle would have left it at, the same as iterating them."""
    x = np.clip(np.array(x, float), lo, hi)
    P, d = x.shape
    active_rows = np.arange(P)
    J, g = fun_grad(x)
    halvings = 0.5 ** np.arange(_LINE_SEARCH_HALVINGS)
    seen_x = np.full((_NEWTON_ITERATIONS + 1, P, d), np.nan)   # the point of every problem after each iteration
    seen_J = np.full((_NEWTON_ITERATIONS + 1, P), np.nan)
    seen_x[0], seen_J[0], t = x, J, 0
    for _ in range(_NEWTON_ITERATIONS):
        if active_rows.size == 0:
            break
        xa, Ja, ga = x[active_rows], J[active_rows], g[active_rows]
        sa = scale[active_rows]
        h = _FD_STEP * sa
        # the 2d shifted points of every problem in one evaluation (each point's gradient is computed on its own)
        shifted = np.repeat(xa[None], 2 * d, axis=0)                       # (2d, A, d): +h_i, -h_i per coordinate
        for i in range(d):
            shifted[2 * i, :, i] += h[:, i]
            shifted[2 * i + 1, :, i] -= h[:, i]
        g_shifted = fun_grad(shifted.reshape(-1, d), np.tile(active_rows, 2 * d))[1].reshape(2 * d, -1, d)
        H = np.empty((active_rows.size, d, d))
        for i in range(d):
            H[:, :, i] = (g_shifted[2 * i] - g_shifted[2 * i + 1]) / (2 * h[:, i:i + 1])
        H = 0.5 * (H + np.swapaxes(H, 1, 2))
        held = ((xa <= lo + _BOUND_TOL) & (ga > 0)) | ((xa >= hi - _BOUND_TOL) & (ga < 0)) | (lo >= hi)
        free = ~held
        Hf = np.where(free[:, :, None] & free[:, None, :], H, 0.0) + np.eye(d) * held[:, :, None]
        gf = np.where(free, ga, 0.0)
        pd = np.all(np.linalg.eigvalsh(Hf) > 0, axis=1)
        step = np.zeros_like(xa)
        if pd.any():
            step[pd] = -np.linalg.solve(Hf[pd], gf[pd][:, :, None])[:, :, 0]
        if (~pd).any():  # a gradient step scaled by the curvature J/s^2 of the coordinate's range
            step[~pd] = -gf[~pd] * sa[~pd] ** 2 / np.maximum(np.abs(Ja[~pd]), 1e-300)[:, None]
        # line search along the projected path: the full step first, halvings only where it fails
        Jn, gn, xn = _line_search(fun_grad, active_rows, xa, Ja, ga, step, lo, hi, sa, pd, halvings[:1])
        retry = np.isnan(Jn)
        if retry.any():
            Jn[retry], gn[retry], xn[retry] = _line_search(fun_grad, active_rows[retry], xa[retry], Ja[retry], ga[retry],
                                                           step[retry], lo, hi, sa[retry], pd[retry], halvings[1:])
        moved = ~np.isnan(Jn) & np.any(xn != xa, axis=1)
        upd = active_rows[moved]
        x[upd], J[upd], g[upd] = xn[moved], Jn[moved], gn[moved]
        t += 1
        seen_x[t, upd], seen_J[t, upd] = x[upd], J[upd]
        # A problem back at a point it visited before cycles from there on (an iteration depends on the
        # point only: J and the gradient are functions of it, and every problem is computed on its own),
        # so where the last iteration leaves it is known now; it stops here with that point.
        again = _revisits(seen_x[:t, upd], x[upd])
        cycling = again.any(axis=0)
        if cycling.any():
            rows, first = upd[cycling], np.argmax(again[:, cycling], axis=0)
            last = first + (_NEWTON_ITERATIONS - first) % (t - first)
            x[rows], J[rows] = seen_x[last, rows], seen_J[last, rows]
        active_rows = upd[~cycling]
    return x, J


def _revisits(seen: np.ndarray, x: np.ndarray) -> np.ndarray:
    """(t, P): where the points x (P, d) of the problems were before (their points `seen` (t, P, d))."""
    return np.all(seen == x[None], axis=2)


def _fd_kkt(cost, x, lo, hi, scale, n_free):
    """Central first and second differences of ``cost`` at ``x`` (P, 2) with steps ``1e-5 * scale``: the
    first differences' error relative to the gradient's scale ``J/ell`` is about ``(1e-5)^2`` (truncation)
    plus ``eps/1e-5`` (rounding), near 1e-10. Only the first ``n_free`` coordinates are differenced."""
    J0 = cost(x)
    g = np.zeros(x.shape)
    c = np.zeros(x.shape)
    for i in range(n_free):
        e = np.zeros(x.shape)
        e[:, i] = _FD_STEP * scale[:, i]
        up, down = cost(x + e), cost(x - e)
        g[:, i] = (up - down) / (2.0 * e[:, i])
        c[:, i] = (up - 2.0 * J0 + down) / e[:, i] ** 2
    proj = _project(g, x, lo, hi)
    proj[:, n_free:] = 0.0
    return g, c, proj


def _optimise_cells(cells: _Cells, starts, lo, hi, n_free):
    """Polish starting points (C, K, 2) of cells (C,) and keep each cell's best: (x (C, 2), J (C,))."""
    C, K, _ = starts.shape
    rows = np.repeat(np.arange(C), K)

    def fun_grad(x, idx=None):
        J, de, dz = _at(cells, rows if idx is None else rows[idx], x[:, 0], x[:, 1])
        g = np.stack([de, dz if n_free == 2 else np.zeros_like(dz)], axis=1)
        return J, g

    x0 = starts.reshape(-1, 2)
    scale = np.stack([np.maximum(x0[:, 0], ELL_BOUNDS[0]), np.ones(len(x0))], axis=1)
    x, J = _minimise_box(fun_grad, x0, lo, hi, scale)
    J = J.reshape(C, K)
    best = np.argmin(J, axis=1)
    return x.reshape(C, K, 2)[np.arange(C), best], J[np.arange(C), best]


def _zoom(cells: _Cells, rows0, ell0, zeta0, d_ell, d_zeta, reinjection, n=11, levels=2):
    """Refine grid points (P,) of the cells ``rows0`` (P,) on successively finer local grids (vectorised)."""
    P = ell0.size
    off = np.linspace(-1.0, 1.0, n)
    for _ in range(levels):
        le = np.clip(ell0[:, None] + d_ell * off[None, :], *ELL_BOUNDS)                     # (P, n)
        ze = np.clip(zeta0[:, None] + d_zeta * off[None, :], *ZETA_BOUNDS) if reinjection else zeta0[:, None] * np.ones(n)
        E = np.broadcast_to(le[:, :, None], (P, n, n)).reshape(P, -1)
        Z = np.broadcast_to(ze[:, None, :], (P, n, n)).reshape(P, -1)
        G = _at(cells, np.repeat(rows0, n * n), E.ravel(), Z.ravel(), gradient=False)[0].reshape(P, -1)
        best = np.argmin(G, axis=1)
        ell0, zeta0 = E[np.arange(P), best], Z[np.arange(P), best]
        d_ell, d_zeta = 2.0 * d_ell / (n - 1), 2.0 * d_zeta / (n - 1)
    return ell0, zeta0


def _check_grid(grid) -> tuple[int, int]:
    try:
        n_ell, n_zeta = (int(v) for v in grid)
    except (TypeError, ValueError):
        raise ValueError(f"grid must be a pair of integers (n_ell, n_zeta), got {grid!r}") from None
    if n_ell < 3 or n_zeta < 3:
        raise ValueError(f"grid must have at least 3 points per axis, got {grid!r}")
    return n_ell, n_zeta


def _spectrum_of(Q) -> tuple[np.ndarray, int]:
    Q = _as_consensus_matrix(Q)
    _check_symmetric(Q)
    lam = np.linalg.eigvalsh(Q)
    return _split_unit_eigenvalue(lam), lam.size


def _check_table_args(ms, sigma_c, q, r):
    ms = np.array([_check_rounds(m.item() if isinstance(m, np.generic) else m) for m in np.atleast_1d(ms).tolist()],
                  dtype=int)
    sig = np.array([_check_nonneg(s, "sigma_c") for s in np.atleast_1d(sigma_c)], float)
    if ms.size == 0 or sig.size == 0:
        raise ValueError("ms and sigma_c must be non-empty")
    return ms, sig, _check_nonneg(q, "q"), _check_nonneg(r, "r")


def reinjection_gain_tables(Q, *, ms, sigma_c, q, r, formulas=("corrected",), grid=(400, 401), n_starts=4,
                            keep_grids=False) -> dict[str, GainTable]:
    """``(ell*, zeta*) = argmin J(ell, zeta)`` over ``[1e-6, 1] x [0, 1]`` for every ``sigma_c`` x ``m`` cell,
    with ``J`` from eq. (16): ``formula = "corrected"`` (the exact asymptotic trace for symmetric
    ``Q``) or ``"printed"`` (verbatim, as the paper's Fig. 2 most likely used). Returns one
    :class:`GainTable` per formula.

    Method: ``J`` on a grid ``ell`` in ``[1e-3, 1]`` x ``zeta`` in ``[0, 1]`` (``grid = (n_ell, n_zeta)``);
    from each of the lowest ``n_starts`` discrete local minima two finer 11 x 11 local grids, then
    a box-constrained Newton method with the analytic gradient; the best point, never worse than
    the grid.

    ``m = 0``: no rounds, ``Qdag = I``; ``zeta := 1`` (the paper's convention; the corrected ``J`` does
    not depend on ``zeta`` there, the printed one is undefined) and ``ell`` is the closed form of
    :func:`optimal_gain_no_communication`.
    """
    rest, n = _spectrum_of(Q)
    ms, sig, q, r = _check_table_args(ms, sigma_c, q, r)
    for f in formulas:
        if f not in ("corrected", "printed"):
            raise ValueError(f"formula must be 'corrected' or 'printed', got {f!r}")
    n_ell, n_zeta = _check_grid(grid)
    if isinstance(n_starts, bool) or int(n_starts) != n_starts or n_starts < 1:
        raise ValueError(f"n_starts must be a positive integer, got {n_starts!r}")
    grid_ell = np.linspace(GRID_ELL_MIN, 1.0, n_ell)
    grid_zeta = np.linspace(0.0, 1.0, n_zeta)
    S, M, F = sig.size, ms.size, len(formulas)
    ell = np.empty((F, S, M))
    zeta = np.empty((F, S, M))
    Jopt = np.empty((F, S, M))
    grid_min = np.empty((F, S, M))
    grids = np.empty((F, S, M, n_ell, n_zeta)) if keep_grids else None
    starts, start_rows = [], []   # (F, S, M) cells with m >= 1 and their starting points
    lam_bars, s_all = {}, {}
    for j, m in enumerate(ms):
        lam_bars[m] = _power_sum(rest, int(m))
        s_all[m] = {f: geometric_gram_sum(rest, int(m) - 1 if f == "printed" else int(m)) for f in formulas}
        if m == 0:
            ell0, J0 = optimal_gain_no_communication(q, r, n)
            ell[:, :, j], zeta[:, :, j], Jopt[:, :, j] = ell0, 1.0, J0
            G0 = _no_communication_cost(grid_ell, n, q, r)
            grid_min[:, :, j] = G0.min()
            if keep_grids:
                grids[:, :, j] = G0[:, None]
            continue
        base, noise = _grid_parts(lam_bars[m], [s_all[m][f] for f in formulas], int(m), n, q, r, grid_ell, grid_zeta,
                                  True)
        G = np.empty((n_ell, n_zeta))
        for f in range(F):   # one grid at a time: it stays in the processor's cache
            for s in range(S):
                np.multiply(noise[f], sig[s] ** 2, out=G)
                G += base
                if keep_grids:
                    grids[f, s, j] = G
                grid_min[f, s, j] = G.min()
                bi, bj = np.unravel_index(_grid_local_minima(G[None], int(n_starts))[0], (n_ell, n_zeta))
                starts.append(np.stack([grid_ell[bi], grid_zeta[bj]], axis=1))
                start_rows.append((f, s, j))
    if start_rows:
        f_idx, s_idx, j_idx = (np.array(v) for v in zip(*start_rows))
        m_of = ms[j_idx]
        H = rest.size
        cells = _Cells(m_of.astype(float), sig[s_idx] ** 2, np.array([lam_bars[m] for m in m_of]).reshape(-1, H),
                       np.array([s_all[m][formulas[f]] for m, f in zip(m_of, f_idx)]).reshape(-1, H), n, q, r, True)
        x0 = np.array(starts)                                                          # (C, K, 2)
        C, K = x0.shape[:2]
        rows = np.repeat(np.arange(C), K)
        ze, zz = _zoom(cells, rows, x0[:, :, 0].ravel(), x0[:, :, 1].ravel(), grid_ell[1] - grid_ell[0],
                       grid_zeta[1] - grid_zeta[0], True)
        lo, hi = np.array([ELL_BOUNDS[0], ZETA_BOUNDS[0]]), np.array([ELL_BOUNDS[1], ZETA_BOUNDS[1]])
        x, J = _optimise_cells(cells, np.stack([ze, zz], axis=1).reshape(C, K, 2), lo, hi, 2)
        gmin = grid_min[f_idx, s_idx, j_idx]
        worse = ~(J <= gmin)   # never return worse than the grid (the grid minimum is the first start)
        x[worse] = x0[worse, 0]
        J[worse] = _at(cells, np.flatnonzero(worse), x[worse, 0], x[worse, 1], gradient=False)[0]
        ell[f_idx, s_idx, j_idx], zeta[f_idx, s_idx, j_idx], Jopt[f_idx, s_idx, j_idx] = x[:, 0], x[:, 1], J
    out = {}
    for f_i, formula in enumerate(formulas):
        kkt = _table_kkt(rest, n, ms, sig, q, r, formula, ell[f_i], zeta[f_i])
        out[formula] = GainTable(ms, sig, ell[f_i], zeta[f_i], Jopt[f_i], *kkt, grid_min[f_i], grid_ell, grid_zeta,
                                 None if grids is None else grids[f_i])
    return out


def _table_kkt(rest, n, ms, sig, q, r, formula, ell, zeta):
    """Finite-difference KKT quantities of a table (S, M): m >= 1 cells in (ell, zeta), m = 0 in ell only
    (the no-communication cost)."""
    S, M = ell.shape
    H = rest.size
    m_grid = np.broadcast_to(ms[None, :], (S, M)).ravel()
    s_grid = np.broadcast_to(sig[:, None], (S, M)).ravel()
    cells = _Cells(m_grid.astype(float), s_grid**2,
                   np.array([_power_sum(rest, int(m)) for m in m_grid]).reshape(-1, H),
                   np.array([geometric_gram_sum(rest, int(m) - 1 if formula == "printed" else int(m)) for m in m_grid]
                            ).reshape(-1, H), n, q, r, True)
    x = np.stack([ell.ravel(), zeta.ravel()], axis=1)
    zero = m_grid == 0

    def cost(pts):
        out = _cost(cells, pts[:, 0], pts[:, 1])
        # m = 0: the no-communication cost (the printed (16) is undefined there)
        return np.where(zero, _no_communication_cost(pts[:, 0], n, q, r), out)

    lo, hi = np.array([ELL_BOUNDS[0], ZETA_BOUNDS[0]]), np.array([ELL_BOUNDS[1], ZETA_BOUNDS[1]])
    scale = np.stack([x[:, 0], np.ones(len(x))], axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        g, c, proj = _fd_kkt(cost, x, lo, hi, scale, 2)
    g[zero, 1], c[zero, 1], proj[zero, 1] = 0.0, 0.0, 0.0
    J = cost(x)
    scaled = _scaled_residual(proj, c, J, x[:, 0])
    shape = (S, M)
    return (g[:, 0].reshape(shape), g[:, 1].reshape(shape), c[:, 0].reshape(shape), c[:, 1].reshape(shape),
            np.max(np.abs(proj), axis=1).reshape(shape), scaled.reshape(shape))


def carli_gain_table(Q, *, ms, sigma_c, q, r, n_grid=2000, keep_grids=False) -> GainTable:
    """``ell* = argmin_ell J_C(ell)`` over ``[1e-6, 1]`` for the plain noisy two-stage filter (7)+(9), every
    ``sigma_c`` x ``m`` cell. ``J_C`` is the closed-form asymptotic trace (see
    :func:`dse.estimators.consensus_trace.carli_asymptotic_trace`). Grid on ``[1e-3, 1]``, two finer
    local grids around the grid minimum, then the box-constrained Newton method."""
    rest, n = _spectrum_of(Q)
    ms, sig, q, r = _check_table_args(ms, sigma_c, q, r)
    if isinstance(n_grid, bool) or int(n_grid) != n_grid or n_grid < 3:
        raise ValueError(f"n_grid must be an integer >= 3, got {n_grid!r}")
    grid_ell = np.linspace(GRID_ELL_MIN, 1.0, int(n_grid))
    S, M, H = sig.size, ms.size, rest.size
    mus = {int(m): np.abs(rest) ** int(m) for m in ms}
    ss = {int(m): geometric_gram_sum(rest, int(m)) for m in ms}
    G = np.empty((S, M, grid_ell.size))
    for j, m in enumerate(ms):
        base, noise = _grid_parts(mus[int(m)], [ss[int(m)]], int(m), n, q, r, grid_ell, np.zeros(1), False)
        G[:, j] = base[None, :, 0] + sig[:, None] ** 2 * noise[0][None, :, 0]
    m_grid = np.broadcast_to(ms[None, :], (S, M)).ravel()
    s_grid = np.broadcast_to(sig[:, None], (S, M)).ravel()
    cells = _Cells(m_grid.astype(float), s_grid**2, np.array([mus[int(m)] for m in m_grid]).reshape(-1, H),
                   np.array([ss[int(m)] for m in m_grid]).reshape(-1, H), n, q, r, False)
    flatG = G.reshape(S * M, -1)
    i0 = np.argmin(flatG, axis=1)
    ones = np.ones(S * M)
    e0, _ = _zoom(cells, np.arange(S * M), grid_ell[i0], ones, grid_ell[1] - grid_ell[0], 0.0, False)
    lo, hi = np.array([ELL_BOUNDS[0], 1.0]), np.array([ELL_BOUNDS[1], 1.0])
    x, J = _optimise_cells(cells, np.stack([e0, ones], axis=1)[:, None, :], lo, hi, 1)
    grid_best = flatG[np.arange(S * M), i0]
    worse = ~(J <= grid_best)
    x[worse, 0], J[worse] = grid_ell[i0[worse]], grid_best[worse]
    scale = np.stack([x[:, 0], np.ones(len(x))], axis=1)
    g, c, proj = _fd_kkt(lambda p: _cost(cells, p[:, 0], p[:, 1]), x, lo, hi, scale, 1)
    scaled = _scaled_residual(proj, c, J, x[:, 0])
    shape = (S, M)
    return GainTable(ms, sig, x[:, 0].reshape(shape), np.ones(shape), J.reshape(shape), g[:, 0].reshape(shape),
                     np.zeros(shape), c[:, 0].reshape(shape), np.zeros(shape), np.abs(proj[:, 0]).reshape(shape),
                     scaled.reshape(shape), flatG.min(axis=1).reshape(shape), grid_ell, np.ones(1),
                     G if keep_grids else None)


def optimal_reinjection_gains(
    Q, *, m, sigma_c, q, r, formula="corrected", grid=(400, 401), n_starts=4
) -> GainOptimum:
    """The optimum of one cell (see :func:`reinjection_gain_tables`), with its grid."""
    return reinjection_gain_tables(Q, ms=[m], sigma_c=[sigma_c], q=q, r=r, formulas=(formula,), grid=grid,
                                   n_starts=n_starts, keep_grids=True)[formula].optimum(0, 0)


def optimal_carli_gain(Q, *, m, sigma_c, q, r, n_grid=2000) -> CarliGainOptimum:
    """The optimum of one cell (see :func:`carli_gain_table`), with its grid."""
    t = carli_gain_table(Q, ms=[m], sigma_c=[sigma_c], q=q, r=r, n_grid=n_grid, keep_grids=True)
    k = t.kkt(0, 0)
    kkt = KKTResiduals(k.dJ_dell, 0.0, (k.projected_gradient[0], 0.0), k.d2J_dell2, 0.0)
    return CarliGainOptimum(float(t.ell[0, 0]), float(t.J[0, 0]), t.grid_ell, t.grids[0, 0], kkt)
