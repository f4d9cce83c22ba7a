"""Closed forms of the steady-state trace of the consensus filters, from the spectrum of Q.

The model and the error recursion are those of `dse.estimators.consensus_covariance`. For a
normal ``Q`` with eigenvalues ``lam_h`` (``lam_0 = 1``) the steady-state covariance decouples
mode by mode, which gives the trace formula (16) of Theorem 1(ii), as printed and corrected,
the closed-form asymptotic trace ``J_C`` of the plain two-stage filter (7)+(9) with its lower
bounds, and the round-noise quantities behind the heuristics of §IV (the consensus mode's
variance, the Cesàro average of the iterates). Equation numbers refer to Savas, Srivastava &
Leonard, "On distributed linear filtering with noisy communication".
"""

from __future__ import annotations

import numbers

import numpy as np

from .consensus_covariance import (
    _as_consensus_matrix,
    _check_ell,
    _check_nonneg,
    _check_rounds,
    _check_symmetric,
    _check_zeta,
    _power_sum,
    geometric_gram_sum,
    predictive_covariance_at_steps,
    reinjection_matrix,
    round_noise_gram,
)

__all__ = [
    "asymptotic_trace_from_spectrum",
    "trace_formula_printed",
    "trace_formula_corrected",
    "carli_asymptotic_trace",
    "carli_trace_lower_bound_asymptotic",
    "carli_trace_lower_bound",
    "carli_noise_thresholds",
    "consensus_mode_variance",
    "averaged_iterates_deviation_norm",
    "averaged_iterates_deviation_norm_modal",
    "averaged_round_noise_covariance",
]


# --------------------------------------------------------------------------------------
# trace formulas (16)
# --------------------------------------------------------------------------------------


def _split_unit_eigenvalue(eigenvalues) -> np.ndarray:
    """Drop the eigenvalue nearest 1 (``lam_0 = 1``, handled in closed form); return the rest."""
    lam = np.asarray(eigenvalues)
    if lam.ndim != 1 or lam.size == 0:
        raise ValueError(f"eigenvalues must be a non-empty 1-D array, got shape {lam.shape}")
    i0 = int(np.argmin(np.abs(lam - 1.0)))
    if abs(lam[i0] - 1.0) > 1e-8:
        raise ValueError(f"eigenvalues must contain lambda_0 = 1 (closest is {lam[i0]!r})")
    return np.delete(lam, i0)


def _spectral_trace_values(lam_bar, s, zeta, beta, a, lr, pref, head_ell, head_zeta, one_minus_a):
    """Value-only fast path of :func:`_spectral_trace` for real spectra: in-place passes over
    preallocated arrays (an optimiser grid is 400 x 401; fresh temporaries cost page faults)."""
    shape = np.broadcast_shapes(np.shape(head_ell), np.shape(head_zeta), np.shape(a), np.shape(zeta))
    J = np.empty(shape)
    np.add(head_ell, head_zeta, out=J)
    J /= one_minus_a
    den = np.empty(shape)
    num = np.empty(shape)
    for h in range(lam_bar.shape[0]):
        mu = beta * lam_bar[h] + zeta
        mu2 = mu * mu
        np.multiply(a, mu2, out=den)
        np.subtract(1.0, den, out=den)
        np.multiply(lr, mu2, out=num)
        num += pref * s[h]
        num /= den
        J += num
    return J


def _spectral_trace(lam_rest, n, ell, zeta, m, sigma_c, q, r, printed, with_gradient=False):
    """Eq. (16) from the non-unit eigenvalues, broadcasting over ``ell`` and ``zeta``.

    No validation (the optimiser probes slightly outside [0, 1] for finite differences).
    With ``with_gradient`` also returns ``(dJ/dell, dJ/dzeta)`` analytically.  The loop runs
    over modes so that a (n_ell, n_zeta) grid costs a few passes over 2-D arrays.
    """
    ell = np.asarray(ell, dtype=np.float64)
    zeta = np.asarray(zeta, dtype=np.float64)
    inv = 1.0 / (m + 1)
    beta = (1.0 - zeta) * inv
    lam_bar = _power_sum(lam_rest, m)
    s = geometric_gram_sum(lam_rest, m - 1 if printed else m)
    a = (1.0 - ell) ** 2
    one_minus_a = 1.0 - a
    lr = ell**2 * r
    pref = beta**2 * sigma_c**2
    if not with_gradient and np.isrealobj(lam_bar) and np.all(np.isfinite(s)):
        return _spectral_trace_values(lam_bar, s, zeta, beta, a, lr, pref, lr + q * n, pref * m, one_minus_a)
    head_num = lr + q * n + pref * m
    J = head_num / one_minus_a
    if with_gradient:
        da = -2.0 * (1.0 - ell)
        dpref = -2.0 * beta * inv * sigma_c**2
        dJ_dell = 2.0 * ell * r / one_minus_a + head_num * da / one_minus_a**2
        dJ_dzeta = dpref * m / one_minus_a
    for h in range(lam_rest.shape[0]):
        mu = beta * lam_bar[h] + zeta
        mu2 = np.abs(mu) ** 2 if np.iscomplexobj(mu) else mu * mu
        den = 1.0 - a * mu2
        if np.isfinite(s[h]):
            noise = pref * s[h]
        else:  # printed (16) at m = 0, lam_h = 0: a vanishing prefactor drops the infinite term
            with np.errstate(invalid="ignore"):
                noise = np.where(pref == 0.0, 0.0, pref * s[h])
        J = J + (lr * mu2 + noise) / den
        if with_gradient:
            dmu2 = 2.0 * np.real(np.conj(mu) * (1.0 - lam_bar[h] * inv))
            num = lr * mu2 + noise
            dJ_dell = dJ_dell + (2.0 * ell * r * mu2) / den + num * mu2 * da / den**2
            dJ_dzeta = dJ_dzeta + (lr * dmu2 + dpref * s[h]) / den + num * a * dmu2 / den**2
    if not with_gradient:
        return J
    return J, dJ_dell, dJ_dzeta


def _as_result(x):
    x = np.asarray(x)
    return float(x) if x.ndim == 0 else x


def _trace_common(ell, zeta, m, sigma_c, q, r):
    return (
        _check_ell(ell),
        _check_zeta(zeta),
        _check_rounds(m),
        _check_nonneg(sigma_c, "sigma_c"),
        _check_nonneg(q, "q"),
        _check_nonneg(r, "r"),
    )


def asymptotic_trace_from_spectrum(eigenvalues, *, ell, zeta, m, sigma_c, q, r, printed=False):
    """Theorem 1(ii), eq. (16), evaluated from the spectrum ``{1, lam_1, ..., lam_{N-1}}`` of ``Q``.

    ``J = (ell^2 r + qN + (1-zeta)^2 sigma_c^2 m/(m+1)^2)/(1-a)
    + ell^2 r sum_{h>=1} |mu_h|^2/(1 - a|mu_h|^2) + beta^2 sigma_c^2 sum_{h>=1} s_h/(1 - a|mu_h|^2)``
    with ``a = (1-ell)^2``, ``beta = (1-zeta)/(m+1)``, ``mu_h = beta lam_bar_h + zeta`` and
    ``lam_bar_h = sum_{n=0}^m lam_h^n``.  ``printed=False``: ``s_h = (1-|lam_h|^{2m})/(1-|lam_h|^2)``
    (corrected).  ``printed=True``: the paper's ``(1-|lam_h|^{2(m-1)})/(1-|lam_h|^2)``, verbatim.
    A vanishing prefactor ``beta^2 sigma_c^2`` (``zeta = 1`` or ``sigma_c = 0``) drops the last term
    even where the printed bracket is infinite.  Eigenvalues may be complex (the paper's
    absolute values); the formula is exact only for normal ``Q``.  Broadcasts over
    ``ell`` and ``zeta``.
    """
    ell, zeta, m, sigma_c, q, r = _trace_common(ell, zeta, m, sigma_c, q, r)
    lam = np.asarray(eigenvalues)
    rest = _split_unit_eigenvalue(lam)
    return _as_result(_spectral_trace(rest, lam.size, ell, zeta, m, sigma_c, q, r, bool(printed)))


def trace_formula_printed(Q, *, ell, zeta, m, sigma_c, q, r):
    """Eq. (16) exactly as printed (last-term exponent ``2(m-1)``), symmetric ``Q``.

    Not the trace of the steady state for ``m >= 1`` (too small) and pathological at
    ``m = 0`` (negative bracket ``-1/lam_h^2``, ``-inf`` at ``lam_h = 0``) unless ``zeta = 1``
    or ``sigma_c = 0``.  Kept verbatim for figure fidelity; see :func:`trace_formula_corrected`.
    """
    Q = _as_consensus_matrix(Q)
    _check_symmetric(Q)
    return asymptotic_trace_from_spectrum(
        np.linalg.eigvalsh(Q), ell=ell, zeta=zeta, m=m, sigma_c=sigma_c, q=q, r=r, printed=True
    )


def trace_formula_corrected(Q, *, ell, zeta, m, sigma_c, q, r):
    """Eq. (16) with the last bracket ``(1 - lam_h^{2m})/(1 - lam_h^2)`` (geometric sum of ``S_m``).

    Equals ``tr lim P(k|k-1)`` of the re-injection filter for symmetric doubly stochastic ``Q``.
    Broadcasts over ``ell`` and ``zeta``.
    """
    Q = _as_consensus_matrix(Q)
    _check_symmetric(Q)
    return asymptotic_trace_from_spectrum(
        np.linalg.eigvalsh(Q), ell=ell, zeta=zeta, m=m, sigma_c=sigma_c, q=q, r=r, printed=False
    )


def _carli_spectral_trace(lam_rest, n, ell, m, sigma_c, q, r, with_gradient=False):
    ell = np.asarray(ell, dtype=np.float64)[..., None]
    mu2 = np.abs(lam_rest) ** (2 * m)
    s = geometric_gram_sum(lam_rest, m)
    a = (1.0 - ell) ** 2
    head_num = ell**2 * r + q * n + sigma_c**2 * m
    den = 1.0 - a * mu2
    J = head_num / (1.0 - a) + np.sum((ell**2 * r * mu2 + sigma_c**2 * s) / den, axis=-1, keepdims=True)
    if not with_gradient:
        return J[..., 0]
    da = -2.0 * (1.0 - ell)
    num = ell**2 * r * mu2 + sigma_c**2 * s
    dJ = (
        2.0 * ell * r / (1.0 - a)
        + head_num * da / (1.0 - a) ** 2
        + np.sum(2.0 * ell * r * mu2 / den + num * mu2 * da / den**2, axis=-1, keepdims=True)
    )
    return J[..., 0], dJ[..., 0]


def carli_asymptotic_trace(Q, *, ell, m, sigma_c, q, r):
    """Closed-form ``tr lim P(k|k-1)`` of the plain noisy two-stage filter (7)+(9), symmetric ``Q``.

    ``J_C = (ell^2 r + qN + sigma_c^2 m)/(1-(1-ell)^2)
    + sum_{h>=1} [ell^2 r lam_h^{2m} + sigma_c^2 (1-lam_h^{2m})/(1-lam_h^2)] / (1 - (1-ell)^2 lam_h^{2m})``
    (the paper gives no formula; this is (16) with ``Qdag -> Q^m`` and ``beta -> 1``).
    ``sigma_c = 0`` is the noise-free filter (7)+(8).  Broadcasts over ``ell``.
    """
    Q = _as_consensus_matrix(Q)
    _check_symmetric(Q)
    ell = _check_ell(ell)
    m = _check_rounds(m)
    sigma_c = _check_nonneg(sigma_c, "sigma_c")
    lam = np.linalg.eigvalsh(Q)
    rest = _split_unit_eigenvalue(lam)
    return _as_result(
        _carli_spectral_trace(rest, lam.size, ell, m, sigma_c, _check_nonneg(q, "q"), _check_nonneg(r, "r"))
    )


def carli_trace_lower_bound_asymptotic(*, ell, m, sigma_c) -> float:
    """``J_C >= sigma_c^2 m / (ell (2 - ell))``: the consensus mode integrates ``m sigma_c^2`` per step.

    Quantifies §III-B ("not stabilizing"): for fixed ``ell`` the plain filter is bounded in
    ``k`` but its steady-state trace grows at least linearly in the number of rounds ``m``.
    """
    ell = float(_check_ell(ell))
    m = _check_rounds(m)
    sigma_c = _check_nonneg(sigma_c, "sigma_c")
    return sigma_c**2 * m / (ell * (2.0 - ell))


def carli_trace_lower_bound(*, ell, m, sigma_c, k: int) -> float:
    """``tr P_C(k|k-1) >= sigma_c^2 m sum_{i=0}^{k-1} (1-ell)^{2i}`` (finite-``k`` version of the above)."""
    ell = float(_check_ell(ell))
    m = _check_rounds(m)
    sigma_c = _check_nonneg(sigma_c, "sigma_c")
    if isinstance(k, bool) or not isinstance(k, numbers.Integral) or k < 0:
        raise ValueError(f"k must be a non-negative integer, got {k!r}")
    rho = (1.0 - ell) ** 2
    return sigma_c**2 * m * float(sum(rho**i for i in range(int(k))))


def carli_noise_thresholds(Q, *, ell, ms, k: int, q, r, sigma0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(thresholds, b, a)``: ``tr P(k|k-1)`` of the plain filter (7)+(9) is ``a_m + b_m sigma_c^2`` (the
    recursion is affine in ``sigma_c^2``), with ``a_m`` the noise-free trace and ``b_m`` the trace of
    the communication noise alone; for consecutive ``m -> m'`` in ``ms``, the ``sigma_c`` above which
    the trace is larger at ``m'`` (0 if it always is, inf if never)."""
    def trace(m, noise_only):
        kw = dict(q=0.0, r=0.0, sigma0=0.0, sigma_c=1.0) if noise_only else dict(q=q, r=r, sigma0=sigma0, sigma_c=0.0)
        return float(predictive_covariance_at_steps(Q, ell=ell, m=m, steps=[k], reinjection=False, **kw).trace[0])

    a = np.array([trace(m, False) for m in ms])
    b = np.array([trace(m, True) for m in ms])
    da, db = -np.diff(a), np.diff(b)   # the trace rises from m to m' iff b' sigma_c^2 + a' > b sigma_c^2 + a
    with np.errstate(divide="ignore", invalid="ignore"):
        thr = np.where(db > 0, np.sqrt(np.maximum(da, 0.0) / db), np.where(da < 0, 0.0, np.inf))
    return thr, b, a


# --------------------------------------------------------------------------------------
# round-noise heuristics of §IV
# --------------------------------------------------------------------------------------


def consensus_mode_variance(Q, m: int) -> float:
    """``v_0^T S_m v_0`` with ``v_0 = 1/sqrt(N)``: the consensus-mode variance (per ``sigma_c^2``) of ``m``
    noisy rounds from a deterministic start (§IV, "the dominating component ... is m sigma_c^2").

    Equals ``m`` exactly for doubly stochastic ``Q`` (``Q^T 1 = 1``).
    """
    Q = _as_consensus_matrix(Q)
    S = round_noise_gram(Q, m)
    v0 = np.ones(Q.shape[0]) / np.sqrt(Q.shape[0])
    return float(v0 @ S @ v0)


def averaged_iterates_deviation_norm(Q, m: int) -> float:
    """``|| (1/(m+1)) sum_{i=0}^m Q^i - (1/N) 1 1^T ||_2``: how far the mean of ``z(k+1|k)/(m+1)`` (eq. (19))
    is from the network average of ``xhat(k|k)`` (§IV heuristic)."""
    Q = _as_consensus_matrix(Q)
    m = _check_rounds(m)
    n = Q.shape[0]
    avg = reinjection_matrix(Q, m, 0.0)
    return float(np.linalg.norm(avg - np.ones((n, n)) / n, ord=2))


def averaged_iterates_deviation_norm_modal(Q, m: int) -> float:
    """Closed form of :func:`averaged_iterates_deviation_norm` for symmetric ``Q`` with a simple unit
    eigenvalue: ``max_{h>=1} |1 - lam_h^{m+1}| / ((m+1)(1 - lam_h))`` (``= |lam_bar_h|/(m+1)``), O(1/m)."""
    Q = _as_consensus_matrix(Q)
    _check_symmetric(Q)
    m = _check_rounds(m)
    rest = _split_unit_eigenvalue(np.linalg.eigvalsh(Q))
    if rest.size == 0:
        return 0.0
    return float(np.max(np.abs(_power_sum(rest, m))) / (m + 1))


def averaged_round_noise_covariance(Q, m: int, sigma_c: float) -> np.ndarray:
    """Covariance ``sigma_c^2 S_m / (m+1)^2`` of the noise part of ``z(k+1|k)/(m+1)`` (eq. (19)).

    Its consensus-mode component is ``m sigma_c^2/(m+1)^2`` (§IV) and its trace
    ``sigma_c^2 sum_h s_h/(m+1)^2``; both are O(1/m).
    """
    sigma_c = _check_nonneg(sigma_c, "sigma_c")
    m = _check_rounds(m)
    return sigma_c**2 * round_noise_gram(Q, m) / (m + 1) ** 2
