"""Gains minimising the asymptotic trace of consensus filters for a scalar random walk.

* No communication (``m = 0``): ``J_0(ell) = N (ell^2 r + q) / (1 - (1-ell)^2)`` (§V-B), minimised in
  closed form by the single-sensor steady-state Kalman gain.
* Re-injection filter (11)-(13): minimise ``J(ell, zeta)`` of eq. (16) (corrected, or as printed)
  over ``[0, 1]^2`` by a dense grid followed by multi-start bounded L-BFGS-B polishing with the
  analytic gradient (the paper used fmincon with unstated settings; (16) need not be convex,
  and the printed (16) can have two local minima).
* Plain noisy consensus filter (7)+(9): minimise the closed-form ``J_C(ell)`` over ``ell``.

Optimality is reported as KKT residuals from central finite differences, independent of the
analytic gradient used by the optimiser.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.ndimage
import scipy.optimize

from .consensus_covariance import (
    _as_consensus_matrix,
    _carli_spectral_trace,
    _check_nonneg,
    _check_rounds,
    _check_symmetric,
    _spectral_trace,
    _split_unit_eigenvalue,
)

__all__ = [
    "KKTResiduals",
    "GainOptimum",
    "CarliGainOptimum",
    "optimal_gain_no_communication",
    "optimal_reinjection_gains",
    "optimal_carli_gain",
]

ELL_BOUNDS = (1e-6, 1.0)
ZETA_BOUNDS = (0.0, 1.0)
#: central-difference steps: relative to ell (its scale; the cost grows like 1/ell as ell -> 0), absolute in zeta
_FD_STEP = 1e-5
_BOUND_TOL = 1e-9


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
        at most about ``sqrt(eps)`` at a computed minimum (less after the Newton polish).
        """
        J = abs(float(J))
        out = 0.0
        for g, h, s in zip(self.projected_gradient, (self.d2J_dell2, self.d2J_dzeta2), (ell, 1.0)):
            out = max(out, abs(g) / np.sqrt(J * max(abs(h), J / s**2)))
        return float(out)


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
    return n * (ell**2 * r + q) / (1.0 - (1.0 - ell) ** 2)


def _projected(g: float, x: float, lo: float, hi: float) -> float:
    if x <= lo + _BOUND_TOL:
        return min(g, 0.0)
    if x >= hi - _BOUND_TOL:
        return max(g, 0.0)
    return g


def _kkt(fun, ell: float, zeta: float | None) -> KKTResiduals:
    """Central first and second differences with steps ``1e-5 ell`` and ``1e-5``: the first differences'
    error relative to the gradient's scale ``J/ell`` is about ``(1e-5)^2`` (truncation) plus
    ``eps/1e-5`` (rounding), near 1e-10."""
    h = _FD_STEP * ell
    J0 = float(fun(ell, zeta))
    up, down = float(fun(ell + h, zeta)), float(fun(ell - h, zeta))
    d_ell, dd_ell = (up - down) / (2.0 * h), (up - 2.0 * J0 + down) / h**2
    if zeta is None:
        return KKTResiduals(d_ell, 0.0, (_projected(d_ell, ell, *ELL_BOUNDS), 0.0), dd_ell, 0.0)
    h = _FD_STEP
    up, down = float(fun(ell, zeta + h)), float(fun(ell, zeta - h))
    d_zeta, dd_zeta = (up - down) / (2.0 * h), (up - 2.0 * J0 + down) / h**2
    return KKTResiduals(
        d_ell,
        d_zeta,
        (_projected(d_ell, ell, *ELL_BOUNDS), _projected(d_zeta, zeta, *ZETA_BOUNDS)),
        dd_ell,
        dd_zeta,
    )


def _grid_local_minima(G: np.ndarray, n_best: int) -> list[tuple[int, int]]:
    """Indices of up to ``n_best`` discrete local minima of ``G`` (3x3 neighbourhood), lowest first."""
    is_min = G <= scipy.ndimage.minimum_filter(G, size=3, mode="constant", cval=np.inf)
    idx = np.flatnonzero(is_min)
    idx = idx[np.argsort(G.ravel()[idx], kind="stable")][:n_best]
    starts = [tuple(int(v) for v in np.unravel_index(i, G.shape)) for i in idx]
    best = tuple(int(v) for v in np.unravel_index(int(np.argmin(G)), G.shape))
    if best not in starts:
        starts.insert(0, best)
    return starts


def _zoom(cost, ell0, zeta0, d_ell, d_zeta, n=11, levels=2):
    """Refine a grid point on successively finer local grids (cheap, vectorised); shortens the
    L-BFGS-B runs that follow."""
    for _ in range(levels):
        le = np.clip(ell0 + d_ell * np.linspace(-1.0, 1.0, n), *ELL_BOUNDS)
        ze = np.clip(zeta0 + d_zeta * np.linspace(-1.0, 1.0, n), *ZETA_BOUNDS)
        G = cost(le[:, None], ze[None, :])
        i, j = np.unravel_index(int(np.argmin(G)), G.shape)
        ell0, zeta0 = float(le[i]), float(ze[j])
        d_ell, d_zeta = 2.0 * d_ell / (n - 1), 2.0 * d_zeta / (n - 1)
    return ell0, zeta0


def _newton_polish(fun_and_grad, x, bounds, n_iter=3):
    """Newton steps on the free coordinates (those not at a bound) using the analytic gradient.

    L-BFGS-B stops on relative decrease of ``J``, which leaves gradients of order
    ``sqrt(eps |J| |H|)`` ~ 1e-6; solving ``grad J = 0`` directly reaches ~1e-12.  A step is kept
    only if it stays feasible, does not raise ``J`` beyond rounding and shrinks the gradient.
    """
    x = np.array(x, dtype=np.float64)
    lo = np.array([b[0] for b in bounds])
    hi = np.array([b[1] for b in bounds])
    free = (x > lo + _BOUND_TOL) & (x < hi - _BOUND_TOL)
    if not free.any():
        return x
    J, g = fun_and_grad(x)
    h = 1e-5
    for _ in range(n_iter):
        idx = np.flatnonzero(free)
        H = np.empty((idx.size, idx.size))
        for c, i in enumerate(idx):
            e = np.zeros_like(x)
            e[i] = h
            H[:, c] = (fun_and_grad(x + e)[1][idx] - fun_and_grad(x - e)[1][idx]) / (2.0 * h)
        H = 0.5 * (H + H.T)
        try:
            if np.min(np.linalg.eigvalsh(H)) <= 0.0:
                break
            step = np.linalg.solve(H, -g[idx])
        except np.linalg.LinAlgError:
            break
        x_new = x.copy()
        x_new[idx] += step
        if np.any(x_new < lo) or np.any(x_new > hi):
            break
        J_new, g_new = fun_and_grad(x_new)
        if J_new > J + 1e-13 * abs(J) or np.max(np.abs(g_new[idx])) >= np.max(np.abs(g[idx])):
            break
        x, J, g = x_new, J_new, g_new
    return x


def _check_grid(grid) -> tuple[int, int]:
    try:
        n_ell, n_zeta = (int(v) for v in grid)
    except (TypeError, ValueError):
        raise ValueError(f"grid must be a pair of integers (n_ell, n_zeta), got {grid!r}") from None
    if n_ell < 3 or n_zeta < 3:
        raise ValueError(f"grid must have at least 3 points per axis, got {grid!r}")
    return n_ell, n_zeta


def optimal_reinjection_gains(
    Q, *, m, sigma_c, q, r, formula="corrected", grid=(400, 401), n_starts=4
) -> GainOptimum:
    """``(ell*, zeta*) = argmin J(ell, zeta)`` over ``[1e-6, 1] x [0, 1]`` with ``J`` from eq. (16).

    ``formula="corrected"`` uses the corrected (16) (exact asymptotic trace for symmetric ``Q``);
    ``"printed"`` uses (16) verbatim, as the paper's Fig. 2 most likely did.  Method: ``J`` on
    a dense grid ``ell`` in ``[1e-3, 1]`` x ``zeta`` in ``[0, 1]`` (``grid = (n_ell, n_zeta)``), then
    L-BFGS-B with the analytic gradient from the lowest ``n_starts`` discrete local minima of
    the grid (and the grid minimum); the best polished point is kept.

    ``m = 0``: no rounds, ``Qdag = I``; ``zeta := 1`` (the paper's convention; the corrected ``J`` does
    not depend on ``zeta`` there, the printed one is undefined) and ``ell`` is the closed form of
    :func:`optimal_gain_no_communication`.
    """
    Q = _as_consensus_matrix(Q)
    _check_symmetric(Q)
    m = _check_rounds(m)
    sigma_c = _check_nonneg(sigma_c, "sigma_c")
    q = _check_nonneg(q, "q")
    r = _check_nonneg(r, "r")
    if formula not in ("corrected", "printed"):
        raise ValueError(f"formula must be 'corrected' or 'printed', got {formula!r}")
    n_ell, n_zeta = _check_grid(grid)
    if isinstance(n_starts, bool) or int(n_starts) != n_starts or n_starts < 1:
        raise ValueError(f"n_starts must be a positive integer, got {n_starts!r}")
    printed = formula == "printed"
    lam = np.linalg.eigvalsh(Q)
    rest = _split_unit_eigenvalue(lam)
    n = lam.size
    grid_ell = np.linspace(1e-3, 1.0, n_ell)
    grid_zeta = np.linspace(0.0, 1.0, n_zeta)

    if m == 0:
        ell, J = optimal_gain_no_communication(q, r, n)
        grid_J = np.broadcast_to(_no_communication_cost(grid_ell, n, q, r)[:, None], (n_ell, n_zeta)).copy()
        kkt = _kkt(lambda l, _z: _no_communication_cost(l, n, q, r), ell, None)
        return GainOptimum(ell, 1.0, J, grid_ell, grid_zeta, grid_J, kkt)

    def cost(ell, zeta):
        return _spectral_trace(rest, n, ell, zeta, m, sigma_c, q, r, printed)

    def fun_and_grad(x):
        J, dl, dz = _spectral_trace(rest, n, x[0], x[1], m, sigma_c, q, r, printed, with_gradient=True)
        return float(J), np.array([float(dl), float(dz)])

    grid_J = cost(grid_ell[:, None], grid_zeta[None, :])
    d_ell, d_zeta = grid_ell[1] - grid_ell[0], grid_zeta[1] - grid_zeta[0]
    best_x, best_J = None, np.inf
    for i, j in _grid_local_minima(grid_J, int(n_starts)):
        x0 = np.array(_zoom(cost, grid_ell[i], grid_zeta[j], d_ell, d_zeta))
        res = scipy.optimize.minimize(
            fun_and_grad,
            x0,
            jac=True,
            method="L-BFGS-B",
            bounds=[ELL_BOUNDS, ZETA_BOUNDS],
            options={"ftol": 1e-15, "gtol": 1e-12, "maxiter": 1000},
        )
        x = _newton_polish(fun_and_grad, res.x, [ELL_BOUNDS, ZETA_BOUNDS])
        J = float(cost(x[0], x[1]))
        if J < best_J:
            best_x, best_J = x, J
        if grid_J[i, j] < best_J:  # never return worse than the grid
            best_x, best_J = np.array([grid_ell[i], grid_zeta[j]]), float(grid_J[i, j])
    ell, zeta = float(best_x[0]), float(best_x[1])
    kkt = _kkt(lambda l, z: cost(l, z), ell, zeta)
    return GainOptimum(ell, zeta, best_J, grid_ell, grid_zeta, grid_J, kkt)


def optimal_carli_gain(Q, *, m, sigma_c, q, r, n_grid=2000) -> CarliGainOptimum:
    """``ell* = argmin_ell J_C(ell)`` for the plain noisy two-stage filter (7)+(9) over ``[1e-6, 1]``.

    ``J_C`` is the closed-form asymptotic trace (see
    :func:`estimators.consensus_covariance.carli_asymptotic_trace`).  Grid on ``[1e-3, 1]``,
    then bounded L-BFGS-B with the analytic derivative from the grid minimum.
    """
    Q = _as_consensus_matrix(Q)
    _check_symmetric(Q)
    m = _check_rounds(m)
    sigma_c = _check_nonneg(sigma_c, "sigma_c")
    q = _check_nonneg(q, "q")
    r = _check_nonneg(r, "r")
    if isinstance(n_grid, bool) or int(n_grid) != n_grid or n_grid < 3:
        raise ValueError(f"n_grid must be an integer >= 3, got {n_grid!r}")
    lam = np.linalg.eigvalsh(Q)
    rest = _split_unit_eigenvalue(lam)
    n = lam.size
    grid_ell = np.linspace(1e-3, 1.0, int(n_grid))
    grid_J = _carli_spectral_trace(rest, n, grid_ell, m, sigma_c, q, r)
    i = int(np.argmin(grid_J))

    def fun_and_grad(x):
        J, dJ = _carli_spectral_trace(rest, n, x[0], m, sigma_c, q, r, with_gradient=True)
        return float(J), np.array([float(dJ)])

    res = scipy.optimize.minimize(
        fun_and_grad,
        np.array([grid_ell[i]]),
        jac=True,
        method="L-BFGS-B",
        bounds=[ELL_BOUNDS],
        options={"ftol": 1e-15, "gtol": 1e-12, "maxiter": 1000},
    )
    x = _newton_polish(fun_and_grad, res.x, [ELL_BOUNDS])
    ell, J = float(x[0]), float(fun_and_grad(x)[0])
    if grid_J[i] < J:
        ell, J = float(grid_ell[i]), float(grid_J[i])
    kkt = _kkt(lambda l, _z: _carli_spectral_trace(rest, n, l, m, sigma_c, q, r), ell, None)
    return CarliGainOptimum(ell, J, grid_ell, grid_J, kkt)
