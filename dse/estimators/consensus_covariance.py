"""Exact error covariances of constant-gain consensus filters for a scalar random walk.

Model (a = 1): ``x(k+1) = x(k) + w(k)``, ``w ~ N(0, q)``; agent measurements
``y(k) = x(k) 1_N + n(k)``, ``n ~ N(0, r I_N)``; ``X_0 ~ N(x_0, sigma0)`` and
``xhat(0|-1) = x_0 1_N``, so ``P(0|-1) = sigma0 1 1^T``.  Every agent applies the
constant-gain update ``xhat(k|k) = (1-ell) xhat(k|k-1) + ell y(k)`` and then ``m`` rounds
of noisy consensus ``z <- Q z + sigma_c u (+ xhat(k|k))``, ``u ~ N(0, I_N)``.

Two filters share one error recursion
``xtilde(k+1|k) = A xtilde(k|k) + w(k) 1 - g sigma_c sum_{h=1}^m Q^{m-h} u(k+h/m)``:

* plain consensus (``reinjection=False``; two-stage filter, eqs (7)+(9)):
  ``A = Q^m`` and ``g = 1``;
* consensus with re-injection of ``xhat(k|k)`` (eqs (11)-(13), (20)):
  ``A = Qdag = zeta I + (1-zeta)/(m+1) sum_{i=0}^m Q^i`` and ``g = (1-zeta)/(m+1)``.

Hence the one-step predictive recursion (eq. (22) for re-injection)::

    P(k+1|k) = (1-ell)^2 A P(k|k-1) A^T + ell^2 r A A^T + q 1 1^T + g^2 sigma_c^2 S_m,
    S_m = sum_{j=0}^{m-1} Q^j Q^{jT}.

This module computes that recursion, its unrolled form (23), the steady state (15) three
ways (Lyapunov solver, truncated series, modal decomposition), the trace formula (16) as
printed and corrected, (the trace formula (16), the closed-form asymptotic trace of the plain filter and its lower
bounds, and the round-noise quantities behind the heuristics of the re-injection design are in
`dse.estimators.consensus_trace`).
All functions are deterministic; equation numbers refer to Savas, Srivastava & Leonard,
"On distributed linear filtering with noisy communication".
"""

from __future__ import annotations

import functools
import numbers
from dataclasses import dataclass

import numpy as np
import scipy  # scipy.linalg loads on first use (scipy imports submodules lazily): `dse list` skips it

__all__ = [
    "reinjection_matrix",
    "round_noise_gram",
    "error_transition_matrix",
    "communication_noise_gain",
    "predictive_covariance_sequence",
    "filtered_covariance",
    "predictive_covariance_unrolled",
    "CovarianceAtSteps",
    "predictive_covariance_at_steps",
    "centralized_prior_variances",
    "SteadyStateSummary",
    "asymptotic_covariance_summary",
    "asymptotic_covariance_lyapunov",
    "asymptotic_covariance_series",
    "asymptotic_covariance_modal",
    "geometric_gram_sum",
]

_ROW_SUM_TOL = 1e-10
_SYMMETRY_TOL = 1e-12


# --------------------------------------------------------------------------------------
# input validation (shared with the simulator and the gain tuning)
# --------------------------------------------------------------------------------------


def _as_consensus_matrix(Q, name: str = "Q") -> np.ndarray:
    """Return ``Q`` as a float64 square matrix whose rows sum to 1, or raise ValueError."""
    A = np.asarray(Q, dtype=np.float64)
    if A.ndim != 2 or A.shape[0] != A.shape[1] or A.shape[0] == 0:
        raise ValueError(f"{name} must be a non-empty square matrix, got shape {A.shape}")
    if not np.all(np.isfinite(A)):
        raise ValueError(f"{name} must have finite entries")
    dev = np.max(np.abs(A.sum(axis=1) - 1.0))
    if dev > _ROW_SUM_TOL:
        raise ValueError(f"{name} must be row stochastic (rows summing to 1); max |row sum - 1| = {dev:.3g}")
    return A


def _check_symmetric(Q: np.ndarray, name: str = "Q") -> None:
    dev = np.max(np.abs(Q - Q.T))
    if dev > _SYMMETRY_TOL:
        raise ValueError(
            f"{name} must be symmetric for the modal/trace formulas (eq. (16) needs a normal Q); "
            f"max |Q - Q^T| = {dev:.3g}"
        )


def _check_rounds(m, name: str = "m") -> int:
    if isinstance(m, bool) or not isinstance(m, numbers.Integral):
        raise ValueError(f"{name} must be an integer number of consensus rounds, got {m!r}")
    if m < 0:
        raise ValueError(f"{name} must be >= 0, got {m}")
    return int(m)


def _check_nonneg(value, name: str) -> float:
    v = float(value)
    if not np.isfinite(v) or v < 0.0:
        raise ValueError(f"{name} must be finite and >= 0, got {value!r}")
    return v


def _check_ell(ell, name: str = "ell"):
    """``ell`` in (0, 1] (scalar or array); ``ell = 0`` has no steady state (q 11^T diverges)."""
    if isinstance(ell, (float, int)) and not isinstance(ell, bool) and 0.0 < ell <= 1.0:
        return float(ell)   # the common case without numpy's overhead (the claims validate thousands)
    a = np.asarray(ell, dtype=np.float64)
    if not np.all(np.isfinite(a)) or np.any(a <= 0.0) or np.any(a > 1.0):
        raise ValueError(f"{name} must lie in (0, 1], got {ell!r}")
    return float(a) if a.ndim == 0 else a


def _check_zeta(zeta, name: str = "zeta"):
    if isinstance(zeta, (float, int)) and not isinstance(zeta, bool) and 0.0 <= zeta <= 1.0:
        return float(zeta)
    a = np.asarray(zeta, dtype=np.float64)
    if not np.all(np.isfinite(a)) or np.any(a < 0.0) or np.any(a > 1.0):
        raise ValueError(f"{name} must lie in [0, 1], got {zeta!r}")
    return float(a) if a.ndim == 0 else a


def _check_steps(n, name: str) -> int:
    if isinstance(n, bool) or not isinstance(n, numbers.Integral) or n < 1:
        raise ValueError(f"{name} must be a positive integer, got {n!r}")
    return int(n)


# --------------------------------------------------------------------------------------
# building blocks
# --------------------------------------------------------------------------------------


def reinjection_matrix(Q, m: int, zeta: float) -> np.ndarray:
    """``Qdag = zeta I + (1-zeta)/(m+1) sum_{i=0}^m Q^i`` (Theorem 1, below eq. (15); eq. (20)).

    ``m = 0`` gives ``Qdag = I`` for every ``zeta`` (no rounds: ``z(k+1|k) = xhat(k|k)``).
    ``Qdag 1 = 1`` whenever ``Q 1 = 1``.
    """
    Q = _as_consensus_matrix(Q)
    m = _check_rounds(m)
    zeta = float(_check_zeta(zeta))
    n = Q.shape[0]
    acc = np.eye(n)
    power = np.eye(n)
    for _ in range(m):
        power = power @ Q
        acc = acc + power
    return zeta * np.eye(n) + ((1.0 - zeta) / (m + 1)) * acc


def round_noise_gram(Q, m: int) -> np.ndarray:
    """``S_m = sum_{j=0}^{m-1} Q^j Q^{jT}`` (the sum in eqs (15), (21)-(23)); ``S_0 = 0``.

    ``sigma_c^2 S_m`` is the covariance of the noise accumulated over ``m`` rounds of (6)/(9)/(12):
    ``sigma_c sum_{h=1}^m Q^{m-h} u(k+h/m)``.
    """
    Q = _as_consensus_matrix(Q)
    m = _check_rounds(m)
    n = Q.shape[0]
    S = np.zeros((n, n))
    power = np.eye(n)
    for _ in range(m):
        S += power @ power.T
        power = power @ Q
    return S


def error_transition_matrix(Q, m: int, zeta: float, *, reinjection: bool) -> np.ndarray:
    """``A`` in ``xtilde(k+1|k) = A xtilde(k|k) + ...``: ``Qdag`` (eq. (20)) or ``Q^m`` (eq. (9))."""
    Q = _as_consensus_matrix(Q)
    m = _check_rounds(m)
    if reinjection:
        return reinjection_matrix(Q, m, zeta)
    return np.linalg.matrix_power(Q, m)


def communication_noise_gain(m: int, zeta: float, *, reinjection: bool) -> float:
    """``g``: the round noise enters the error as ``-g sigma_c sum Q^{m-h} u``; ``(1-zeta)/(m+1)`` in (20), 1 in (9)."""
    m = _check_rounds(m)
    zeta = float(_check_zeta(zeta))
    return (1.0 - zeta) / (m + 1) if reinjection else 1.0


def _recursion_terms(Q, ell, m, sigma_c, q, r, zeta, reinjection):
    """``A`` and ``B`` with ``P(k+1|k) = (1-ell)^2 A P A^T + B`` (eq. (22) / its plain analogue)."""
    Q = _as_consensus_matrix(Q)
    m = _check_rounds(m)
    ell = float(_check_ell(ell))
    zeta = float(_check_zeta(zeta))
    sigma_c = _check_nonneg(sigma_c, "sigma_c")
    q = _check_nonneg(q, "q")
    r = _check_nonneg(r, "r")
    n = Q.shape[0]
    A = error_transition_matrix(Q, m, zeta, reinjection=reinjection)
    g = communication_noise_gain(m, zeta, reinjection=reinjection)
    S = round_noise_gram(Q, m)
    B = ell**2 * r * (A @ A.T) + q * np.ones((n, n)) + (g * sigma_c) ** 2 * S
    return Q, A, B, S, g, ell


# --------------------------------------------------------------------------------------
# finite-horizon covariances
# --------------------------------------------------------------------------------------


def predictive_covariance_sequence(
    Q, *, ell, m, sigma_c, q, r, sigma0, n_steps, reinjection, zeta=1.0
) -> np.ndarray:
    """``P(k|k-1)`` for ``k = 0..n_steps-1`` by the one-step recursion (22), shape ``(K, N, N)``.

    ``P(k+1|k) = (1-ell)^2 A P(k|k-1) A^T + ell^2 r A A^T + q 1 1^T + g^2 sigma_c^2 S_m`` with
    ``P(0|-1) = sigma0 1 1^T``.  With ``reinjection=True``, ``A = Qdag`` and ``g = (1-zeta)/(m+1)``
    (eq. (22)); with ``reinjection=False``, ``A = Q^m`` and ``g = 1`` (plain noisy consensus,
    eqs (7)+(9); ``sigma_c = 0`` is the noise-free filter (7)+(8)).  Each step is symmetrised.
    Entry ``k`` matches ``err_pred[:, k, :]`` of the Monte Carlo simulator.
    """
    _, A, B, _, _, ell = _recursion_terms(Q, ell, m, sigma_c, q, r, zeta, reinjection)
    sigma0 = _check_nonneg(sigma0, "sigma0")
    K = _check_steps(n_steps, "n_steps")
    n = A.shape[0]
    out = np.empty((K, n, n))
    P = sigma0 * np.ones((n, n))
    out[0] = P
    a2 = (1.0 - ell) ** 2
    for k in range(1, K):
        P = a2 * (A @ P @ A.T) + B
        P = 0.5 * (P + P.T)
        out[k] = P
    return out


def filtered_covariance(P_pred, ell, r) -> np.ndarray:
    """``P(k|k) = (1-ell)^2 P(k|k-1) + ell^2 r I_N`` (eq. (18)); works on ``(..., N, N)``."""
    P_pred = np.asarray(P_pred, dtype=np.float64)
    if P_pred.ndim < 2 or P_pred.shape[-1] != P_pred.shape[-2]:
        raise ValueError(f"P_pred must have shape (..., N, N), got {P_pred.shape}")
    ell = float(_check_ell(ell))
    r = _check_nonneg(r, "r")
    n = P_pred.shape[-1]
    return (1.0 - ell) ** 2 * P_pred + ell**2 * r * np.eye(n)


def predictive_covariance_unrolled(
    Q, *, ell, m, sigma_c, q, r, sigma0, n_steps, reinjection, zeta=1.0
) -> np.ndarray:
    """``P(k|k-1)``, ``k = 0..n_steps-1``, from the finite-k closed form (23), shape ``(K, N, N)``.

    ``P(k|k-1) = (1-ell)^{2k} A^k P(0|-1) A^{kT} + ell^2 r sum_{i<k} (1-ell)^{2i} A^{i+1} A^{(i+1)T}
    + q sum_{i<k} (1-ell)^{2i} 1 1^T + g^2 sigma_c^2 sum_{i<k} (1-ell)^{2i} A^i S_m A^{iT}``.

    An independent code path for the recursion (22): it sums explicit matrix powers instead of
    iterating.  ``A``/``g`` as in :func:`predictive_covariance_sequence`.
    """
    Q, A, _, S, g, ell = _recursion_terms(Q, ell, m, sigma_c, q, r, zeta, reinjection)
    sigma_c = float(sigma_c)
    r = float(r)
    q = float(q)
    sigma0 = _check_nonneg(sigma0, "sigma0")
    K = _check_steps(n_steps, "n_steps")
    n = A.shape[0]
    ones = np.ones((n, n))
    P0 = sigma0 * ones
    powers = [np.eye(n)]
    for _ in range(K):
        powers.append(powers[-1] @ A)
    rho = (1.0 - ell) ** 2
    terms = np.empty((K, n, n))
    for i in range(K):
        Ai, Ai1 = powers[i], powers[i + 1]
        terms[i] = rho**i * (
            ell**2 * r * (Ai1 @ Ai1.T) + q * ones + (g * sigma_c) ** 2 * (Ai @ S @ Ai.T)
        )
    partial = np.concatenate([np.zeros((1, n, n)), np.cumsum(terms, axis=0)[:-1]], axis=0)
    out = np.empty((K, n, n))
    for k in range(K):
        out[k] = rho**k * (powers[k] @ P0 @ powers[k].T) + partial[k]
    return 0.5 * (out + np.swapaxes(out, -1, -2))


@dataclass(frozen=True, eq=False)
class CovarianceAtSteps:
    """``P(k|k-1)`` at chosen steps, summarised: ``diag`` (K, N) (the agents' error variances),
    ``trace`` (K,) and ``eigenvalues`` (K, N) in ascending order (the weights of the trace's law)."""

    steps: np.ndarray
    diag: np.ndarray
    trace: np.ndarray
    eigenvalues: np.ndarray


def _check_step_list(steps) -> np.ndarray:
    k = np.asarray(steps)
    if k.ndim != 1 or k.size == 0 or not np.issubdtype(k.dtype, np.integer) or k.min() < 0 or np.any(np.diff(k) <= 0):
        raise ValueError(f"steps must be a non-empty strictly increasing sequence of integers >= 0, got {steps!r}")
    return k.astype(np.int64)


@functools.lru_cache(maxsize=4)
def _eigh_of(shape: tuple[int, int], data: bytes):
    Q = np.frombuffer(data, dtype=np.float64).reshape(shape)
    lam, V = np.linalg.eigh(Q)
    lam.flags.writeable = V.flags.writeable = False
    return lam, V


def _modal_terms(Q, ell, m, sigma_c, q, r, zeta, reinjection):
    """The recursion (22) mode by mode, when ``Q`` is symmetric and ``1`` lies in one of its eigenvectors
    (a simple unit eigenvalue): ``(V, V^T 1, b, alpha, ell)`` with ``p_h(k+1) = alpha_h p_h(k) + b_h``; else
    None. Needs no N x N product (the eigendecomposition of ``Q`` is computed once and kept)."""
    Q = _as_consensus_matrix(Q)
    if not np.array_equal(Q, Q.T):
        return None
    m, ell, zeta = _check_rounds(m), float(_check_ell(ell)), float(_check_zeta(zeta))
    sigma_c, q, r = _check_nonneg(sigma_c, "sigma_c"), _check_nonneg(q, "q"), _check_nonneg(r, "r")
    lam, V = _eigh_of(Q.shape, np.ascontiguousarray(Q).tobytes())
    ones = V.T @ np.ones(Q.shape[0])
    spread = np.sort(np.abs(ones))[:-1]
    if spread.size and spread.max() > 1e-10 * np.sqrt(Q.shape[0]):
        return None
    g = communication_noise_gain(m, zeta, reinjection=reinjection)
    mu = zeta + (1.0 - zeta) / (m + 1) * _power_sum(lam, m) if reinjection else lam**m
    b = ell**2 * r * mu**2 + (g * sigma_c) ** 2 * geometric_gram_sum(lam, m) + q * ones**2
    return V, ones, b, (1.0 - ell) ** 2 * mu**2, ell


@dataclass(frozen=True, eq=False)
class SteadyStateSummary:
    """``P_inf = lim P(k|k-1)`` summarised: ``diag`` (N,), ``trace``, ``eigenvalues`` (N,) ascending,
    ``loewner_gap`` = the smallest eigenvalue of ``P_inf - p_ref 1 1^T`` (>= 0 when every agent's
    error is at least a reference variance ``p_ref`` in every direction of the consensus mode), and
    ``matrix`` (N, N) when asked for."""

    diag: np.ndarray
    trace: float
    eigenvalues: np.ndarray
    loewner_gap: float
    matrix: np.ndarray | None


def asymptotic_covariance_summary(
    Q, *, ell, m, sigma_c, q, r, reinjection, zeta=1.0, reference=0.0, with_matrix=True
) -> SteadyStateSummary:
    """The steady state of (22) (Theorem 1(i)) without forming N x N matrices when ``Q`` is symmetric
    with a simple unit eigenvalue (modes ``p_h = b_h/(1 - alpha_h)``, O(N) after the eigendecomposition;
    then ``P_inf - reference 1 1^T`` has eigenvalues ``p_h`` off the consensus mode and
    ``p_0 - N reference`` on it); otherwise from :func:`asymptotic_covariance_lyapunov`."""
    reference = float(reference)
    modes = _modal_terms(Q, ell, m, sigma_c, q, r, zeta, reinjection)
    if modes is not None:
        V, ones, b, alpha, _ = modes
        # as in `_check_stable`: the unit mode's eigenvalue may come out as 1 - 1e-16 (the LAPACK build decides),
        # so a gain that rounds away is caught by itself, not by alpha
        if alpha.max() >= 1.0 or 1.0 - float(np.min(ell)) == 1.0:
            raise _no_steady_state(np.sqrt(alpha.max()), ell)
        p = b / (1.0 - alpha)
        shifted = p - reference * ones**2
        P = (V * p) @ V.T if with_matrix else None
        return SteadyStateSummary((V * V) @ p, float(p.sum()), np.sort(p), float(shifted.min()),
                                  None if P is None else 0.5 * (P + P.T))
    P = asymptotic_covariance_lyapunov(Q, ell=ell, m=m, sigma_c=sigma_c, q=q, r=r, reinjection=reinjection, zeta=zeta)
    n = P.shape[0]
    gap = float(np.linalg.eigvalsh(P - reference * np.ones((n, n))).min())
    return SteadyStateSummary(np.diag(P).copy(), float(np.trace(P)), np.linalg.eigvalsh(P), gap,
                              P if with_matrix else None)


def predictive_covariance_at_steps(
    Q, *, ell, m, sigma_c, q, r, sigma0, steps, reinjection, zeta=1.0
) -> CovarianceAtSteps:
    """``P(k|k-1)`` of the recursion (22) (or its plain analogue) at the given steps ``k``, for any horizon.

    For a symmetric ``Q`` with a simple unit eigenvalue every matrix of (22) is diagonal in the
    eigenbasis ``Q = V diag(lam) V^T``, and each mode follows the scalar recursion
    ``p_h(k+1) = alpha_h p_h(k) + b_h``, ``alpha_h = (1-ell)^2 mu_h^2``, in closed form
    ``p_h(k) = alpha_h^k p_h(0) + b_h (1 - alpha_h^k)/(1 - alpha_h)`` with ``p_h(0) = sigma0 (v_h^T 1)^2`` and
    ``b_h = ell^2 r mu_h^2 + g^2 sigma_c^2 s_h + q (v_h^T 1)^2`` (``mu_h``, ``s_h`` as in
    :func:`asymptotic_covariance_modal`): O(N) per step whatever ``k``. Otherwise the affine map
    ``P -> Ã P Ã^T + B`` (``Ã = (1-ell) A``) is applied in jumps between consecutive steps, each jump
    ``j`` composed by repeated squaring from ``(Ã, B)``: ``log2(j)`` matrix products instead of ``j``.
    """
    sigma0 = _check_nonneg(sigma0, "sigma0")
    k = _check_step_list(steps)
    modes = _modal_terms(Q, ell, m, sigma_c, q, r, zeta, reinjection)
    if modes is not None:
        V, ones, b, alpha, ell = modes
        n = V.shape[0]
        kk = k[:, None].astype(float)
        with np.errstate(divide="ignore"):
            log_alpha = np.log(np.where(alpha > 0, alpha, 1.0))
            decay = np.where(alpha > 0, np.exp(kk * log_alpha), (kk == 0).astype(float))
            rise = np.where(alpha > 0, -np.expm1(kk * log_alpha), (kk > 0).astype(float))
            # sum_{j<k} alpha^j = (1 - alpha^k)/(1 - alpha), and k where alpha rounds to 1 (a gain below
            # the rounding unit of 1): the same limit, without 0 * inf
            accumulated = np.where(alpha < 1.0, rise / np.where(alpha < 1.0, 1.0 - alpha, 1.0), kk)
        p = decay * (sigma0 * ones**2) + accumulated * b
        out = CovarianceAtSteps(k, p @ (V * V).T, p.sum(axis=1), np.sort(p, axis=1))
        if k[0] == 0:   # P(0|-1) = sigma0 1 1^T exactly
            out.diag[0], out.trace[0], out.eigenvalues[0] = sigma0, n * sigma0, 0.0
            out.eigenvalues[0, -1] = n * sigma0
        return out
    _, A, B, _, _, ell = _recursion_terms(Q, ell, m, sigma_c, q, r, zeta, reinjection)
    n = A.shape[0]
    At = (1.0 - ell) * A
    jumps: dict[int, tuple[np.ndarray, np.ndarray]] = {}
    for gap in set(np.diff(np.concatenate([[0], k])).tolist()) - {0}:
        power, gram = np.eye(n), np.zeros((n, n))   # the map applied `done` times: P -> power P power^T + gram
        sq_power, sq_gram, left = At, B, gap          # the map applied 2^i times
        while left:
            if left & 1:
                power, gram = sq_power @ power, sq_power @ gram @ sq_power.T + sq_gram
            left >>= 1
            if left:
                sq_power, sq_gram = sq_power @ sq_power, sq_power @ sq_gram @ sq_power.T + sq_gram
        jumps[gap] = (power, 0.5 * (gram + gram.T))
    P = sigma0 * np.ones((n, n))
    diag, trace, eig = np.empty((k.size, n)), np.empty(k.size), np.empty((k.size, n))
    done = 0
    for i, step in enumerate(k):
        if step > done:
            power, gram = jumps[int(step - done)]
            P = power @ P @ power.T + gram
            P = 0.5 * (P + P.T)
            done = int(step)
        diag[i], trace[i], eig[i] = np.diag(P), np.trace(P), np.linalg.eigvalsh(P)
    return CovarianceAtSteps(k, diag, trace, eig)


def centralized_prior_variances(q, r, n_agents, sigma0, n_steps) -> np.ndarray:
    """``P_KF(k|k-1)``, ``k = 0..n_steps-1``, of the centralized Kalman filter on all ``N`` measurements:
    a scalar filter on their mean (noise variance ``r/N``), ``P(k+1) = P(k) r/(r + N P(k)) + q``,
    ``P(0) = sigma0``. Every agent's error variance of any linear filter here is at least this."""
    q, r, sigma0 = _check_nonneg(q, "q"), _check_nonneg(r, "r"), _check_nonneg(sigma0, "sigma0")
    K = _check_steps(n_steps, "n_steps")
    out = np.empty(K)
    P = sigma0
    for k in range(K):
        out[k] = P
        P = P * r / (r + n_agents * P) + q
    return out


# --------------------------------------------------------------------------------------
# steady state
# --------------------------------------------------------------------------------------


def _no_steady_state(rho: float, ell) -> Exception:
    """The error for a steady state that does not exist at working precision. With 0 < ell <= 1 and
    a stochastic A it exists in exact arithmetic; when ell is below the rounding unit of 1, 1 - ell
    rounds to 1 and the recursion is marginally stable in float64 (a NumericalLimit, not an input
    error). Any other case is a caller's error (ValueError)."""
    from dse.errors import NumericalLimit

    ell_min = float(np.min(ell))
    if 0.0 < ell_min and 1.0 - ell_min == 1.0:
        return NumericalLimit(f"no steady-state covariance: the gain ell = {ell_min:.3g} is below the rounding unit "
                              f"of 1, so 1 - ell rounds to 1 and the spectral radius of (1-ell) A to {rho:.6g} "
                              "(the measurement noise is too large against the process noise to compute with)")
    return ValueError(f"no steady state: spectral radius of (1-ell) A is {rho:.6g} >= 1 "
                      "(Q must be nonnegative so that rho(Qdag) = 1)")


def _check_stable(A: np.ndarray, ell: float) -> None:
    rho = float(np.max(np.abs(np.linalg.eigvals((1.0 - ell) * A))))
    if rho >= 1.0 or 1.0 - float(np.min(ell)) == 1.0:   # a stochastic A has radius 1 (eigvals may say 1 - 1e-16)
        raise _no_steady_state(rho, ell)


def asymptotic_covariance_lyapunov(
    Q, *, ell, m, sigma_c, q, r, reinjection, zeta=1.0
) -> np.ndarray:
    """``lim P(k|k-1)`` as the solution of ``P = (1-ell)^2 A P A^T + B`` (Theorem 1(i), eq. (15)).

    Solved with :func:`scipy.linalg.solve_discrete_lyapunov` on ``((1-ell) A, B)``; ``A``, ``B`` as
    in (22) (``A = Qdag`` with re-injection, ``A = Q^m``, ``g = 1`` without).  Requires
    ``rho((1-ell) A) < 1`` (true for nonnegative stochastic ``Q`` and ``ell`` in (0, 1]).
    """
    _, A, B, _, _, ell = _recursion_terms(Q, ell, m, sigma_c, q, r, zeta, reinjection)
    _check_stable(A, ell)
    P = scipy.linalg.solve_discrete_lyapunov((1.0 - ell) * A, B)
    return 0.5 * (P + P.T)


def asymptotic_covariance_series(
    Q, *, ell, m, sigma_c, q, r, reinjection, zeta=1.0, tol=1e-16
) -> np.ndarray:
    """Theorem 1(i), eq. (15), as a truncated series.

    ``ell^2 r sum_i (1-ell)^{2i} A^{i+1} A^{(i+1)T} + q/(1-(1-ell)^2) 1 1^T
    + g^2 sigma_c^2 sum_i (1-ell)^{2i} A^i S_m A^{iT}``, truncated after the first ``T = 2^j`` terms
    with ``(1-ell)^{2T} < tol`` (every ``A^i`` has 2-norm at most 1 for a nonnegative doubly
    stochastic ``Q``, so the tail is below ``tol`` times the first term).  The partial sums are
    formed by doubling, ``X_{2T} = X_T + Ã^T X_T Ã^{T T}`` with ``Ã = (1-ell) A``: ``j ≈ log2(18.4/ell)``
    matrix steps instead of ``T`` (``T`` is about 1.8e7 at ``ell = 1e-6``).  An independent code
    path for the Lyapunov solution of :func:`asymptotic_covariance_lyapunov`.
    """
    Q, A, _, S, g, ell = _recursion_terms(Q, ell, m, sigma_c, q, r, zeta, reinjection)
    _check_stable(A, ell)
    if not (0.0 < tol < 1.0):
        raise ValueError(f"tol must lie in (0, 1), got {tol!r}")
    n = A.shape[0]
    rho = (1.0 - ell) ** 2
    total = ell**2 * float(r) * (A @ A.T) + (g * float(sigma_c)) ** 2 * S  # the i = 0 term
    step = (1.0 - ell) * A  # Ã^T for the current number of terms T
    weight = rho  # (1-ell)^{2T}
    while weight >= tol:
        total = total + step @ total @ step.T
        step = step @ step
        weight = weight * weight
    total += float(q) / (1.0 - rho) * np.ones((n, n))
    return 0.5 * (total + total.T)


def _power_sum(lam, m: int):
    """``lam_bar = sum_{n=0}^m lam^n`` by Horner (exact at ``lam = 1``, fine for complex ``lam``)."""
    lam = np.asarray(lam)
    acc = np.ones_like(lam)
    for _ in range(m):
        acc = 1.0 + lam * acc
    return acc


def geometric_gram_sum(lam, p: int) -> np.ndarray:
    """``(1 - |lam|^{2p}) / (1 - |lam|^2)``, the limit ``p`` at ``|lam| = 1``; elementwise.

    For ``p >= 0`` this is ``s = sum_{j=0}^{p-1} |lam|^{2j}``, the modal value of ``S_p``
    (the modal ``s_h``; eq. (16) corrected).  Negative ``p`` is allowed so that the printed (16),
    which has ``p = m - 1``, can be evaluated verbatim at ``m = 0`` (giving ``-1/lam^2``, and
    ``-inf`` at ``lam = 0``).  Evaluated as ``expm1(p x)/expm1(x)`` with ``x = 2 ln|lam|``,
    which is accurate also for ``|lam|`` within rounding of 1.
    """
    p = int(p)
    mag = np.abs(np.asarray(lam))
    if p == 0:
        return np.zeros(mag.shape)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        x = 2.0 * np.log(mag)
        out = np.expm1(p * x) / np.expm1(x)
    return np.where(x == 0.0, float(p), out)


def _symmetric_spectrum(Q: np.ndarray):
    _check_symmetric(Q)
    lam, V = np.linalg.eigh(0.5 * (Q + Q.T))
    return lam, V


def asymptotic_covariance_modal(
    Q, *, ell, m, sigma_c, q, r, reinjection, zeta=1.0
) -> np.ndarray:
    """Steady state of (22) by modal decomposition of a symmetric ``Q = V diag(lam) V^T``.

    Per mode ``h``: ``mu_h = zeta + (1-zeta)/(m+1) lam_bar_h`` (re-injection; ``lam_h^m`` without),
    ``s_h = (1 - lam_h^{2m})/(1 - lam_h^2)`` (``m`` at ``lam_h^2 = 1``),
    ``b_h = ell^2 r mu_h^2 + g^2 sigma_c^2 s_h + q N [h = 0]`` and ``p_h = b_h/(1 - (1-ell)^2 mu_h^2)``
    (the per-mode form of Theorem 1(i); eq. (24) corrected).  The ``q 1 1^T`` term is kept
    as ``q (V^T 1)(V^T 1)^T`` and the Stein equation is solved entrywise in the eigenbasis,
    which reduces to ``P = V diag(p_h) V^T`` when the unit eigenvalue is simple and stays
    exact when it is not (disconnected graph).
    """
    Q, A, _, _, g, ell = _recursion_terms(Q, ell, m, sigma_c, q, r, zeta, reinjection)
    _check_stable(A, ell)
    lam, V = _symmetric_spectrum(Q)
    m = int(m)
    zeta = float(zeta)
    if reinjection:
        mu = zeta + (1.0 - zeta) / (m + 1) * _power_sum(lam, m)
    else:
        mu = lam**m
    s = geometric_gram_sum(lam, m)
    ones_modal = V.T @ np.ones(Q.shape[0])
    Bm = np.diag(ell**2 * float(r) * mu**2 + (g * float(sigma_c)) ** 2 * s) + float(q) * np.outer(
        ones_modal, ones_modal
    )
    Pm = Bm / (1.0 - (1.0 - ell) ** 2 * np.outer(mu, mu))
    P = V @ Pm @ V.T
    return 0.5 * (P + P.T)
