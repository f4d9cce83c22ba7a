"""The hypotheses of the random-comm-filter family, one set per scenario
(`<paper>.hyp.<scenario>.<name>`, the scenario named only in a run of several), decided on the design stage alone (`dse check`): each check
receives the scenario's `ScenarioDesign`."""
from __future__ import annotations

import numpy as np

import dse.estimators.gossip_covariance as gc
from dse.verify.rules import EPS, Holds

from .claims_common import HYP as H, claims, fmt, min_eig
from .design import CARE_COND_MAX, ScenarioDesign
from .scenario import GRID_ASYMPTOTIC, MAX_SWEEP_RATE

NUMERICS_RTOL = 1e-6     # two independent computations of the per-path covariances must agree to this


@claims.hypothesis(H + "alpha", "0 < α ≤ 1/d_max (eq. 3): the fusion weights Π = I − α𝓛 are nonnegative and doubly "
                                "stochastic")
def alpha(d: ScenarioDesign) -> Holds:
    s = d.sys
    dmax = int(s.degrees.max())
    return Holds(bool(0 < s.alpha <= 1.0 / dmax * (1 + 4 * EPS)), s.alpha, 1.0 / dmax,
                 f"α = {s.alpha:.6g}, 1/d_max = {1 / dmax:.6g}")


@claims.hypothesis(H + "connected", "the communication graph is connected (σ₂(𝓛) > 0)")
def connected(d: ScenarioDesign) -> Holds:
    s = d.sys
    lam = np.linalg.eigvalsh(s.laplacian)
    tol = 10 * s.N * EPS * float(np.abs(s.laplacian).sum(axis=0).max())
    fied = float(lam[1]) if s.N > 1 else 0.0
    return Holds(bool(fied > tol), fied, tol, f"σ₂(𝓛) = {fied:.6g} (round-off level {tol:.2g})")


@claims.hypothesis(H + "initial", "P_i(0) ⪰ E[e_i(0)e_i(0)ᵀ] for every node (Prop. III.2, Thm. III.1)")
def initial(d: ScenarioDesign) -> Holds:
    s = d.sys
    E0 = gc.diagonal_blocks(s.joint_second_moment0()[s.n:, s.n:], s.N, s.n)
    gaps = min_eig(np.asarray(s.P_init) - E0)
    gap, worst = float(gaps.min()), int(np.argmin(gaps))
    tol = 10 * s.n * EPS * max(1.0, float(np.abs(s.P_init).max()), float(np.abs(E0).max()))
    given = not np.array_equal(np.asarray(s.P_init), np.broadcast_to(s.P0, np.shape(s.P_init)))
    how = "P_i(0) as given per node" if given else "P_i(0) = 𝒫_i(0) = P0"
    return Holds(bool(gap >= -tol), gap, -tol, f"{how}, E[e_i(0)e_i(0)ᵀ] = P0 (x̂_i(0) = m0): smallest eigenvalue of "
                                               f"P_i(0) − E[e_i(0)e_i(0)ᵀ] {gap:.3g} (node {worst}; round-off level "
                                               f"{tol:.2g})")


@claims.hypothesis(H + "abar_hurwitz", "Ā = (1/N)Σ_i(A − L_iH_i) is Hurwitz (Thm. III.1 item 2)")
def abar_hurwitz(d: ScenarioDesign) -> Holds:
    a, tol = float(d.bounds["abar_abscissa"]), float(d.bounds["abar_tolerance"])
    if abs(a) <= tol:
        return Holds(None, a, 0.0, f"spectral abscissa of Ā = {a:.3g} cannot be told from 0 (round-off level {tol:.2g})")
    return Holds(bool(a < 0), a, 0.0, f"spectral abscissa of Ā = (1/N)Σ(A − L_iH_i): {a:.6g}")


@claims.hypothesis(H + "rate_sufficient", "'λ sufficiently large' in (12): the λ sweep reaches a decade above the "
                                          "explicit threshold λ_thr (derived constants, tight variant)")
def rate_sufficient(d: ScenarioDesign) -> Holds:
    b = d.bounds
    if "explicit_tight" not in b:
        return Holds(None, None, None, "Ā is not Hurwitz: no explicit threshold")
    thr = float(b["explicit_tight"][-1])
    lams = b["sweep"][np.all(np.isfinite(b["sweep_dev_bound"]), axis=(1, 2, 3))]
    top = float(lams.max()) if lams.size else 0.0
    return Holds(bool(top / 10 >= thr), top / 10, thr,
                 f"the λ sweep (with points added at multiples of λ_thr, up to {MAX_SWEEP_RATE:g}) reaches λ = {top:.4g}; "
                 f"its top decade starts at {top / 10:.4g}, λ_thr of the explicit (12) (tight constants) is {thr:.4g}")


@claims.hypothesis(H + "rate_above_critical", "the simulated λ exceeds λ_crit of (9), so that 𝒫_i(t) has a finite "
                                              "limit")
def rate_above_critical(d: ScenarioDesign) -> Holds:
    c, lam = float(d.bounds["crit_bound"]), d.scenario.main_rate
    return Holds(bool(lam > c), lam, c, f"simulated λ = {lam:g}, λ_crit of (9) = {fmt(c)}")


@claims.hypothesis(H + "kalman_bucy", "the filter Riccati equation has a stabilising, well-conditioned solution "
                                      "(centralized Kalman–Bucy reference)")
def kalman_bucy(d: ScenarioDesign) -> Holds:
    b = d.bounds
    if "P_kb" not in b:
        return Holds(False, None, None, "no stabilising solution of the filter CARE ((A, H) not detectable or (A, B) "
                                        "not stabilisable)")
    kappa = float(b["kb_condition"])
    if not kappa <= CARE_COND_MAX:
        return Holds(None, kappa, CARE_COND_MAX, f"the filter CARE is too ill-conditioned for double precision "
                                                  f"(relative condition number {kappa:.3g})")
    return Holds(True, kappa, CARE_COND_MAX, f"tr P_KB = {np.trace(b['P_kb']):.6g}, relative condition number of the "
                                              f"CARE {kappa:.3g}")


@claims.hypothesis(H + "numerics", "the per-path computations are accurate in double precision (two independent "
                                   f"computations agree to {NUMERICS_RTOL:g} relative)")
def numerics(d: ScenarioDesign) -> Holds:
    b = d.bounds
    m = np.concatenate([b["numerics_pbound"].ravel(), b["numerics_sigma"].ravel()])
    ref_ = np.concatenate([b["numerics_ref_pbound"].ravel(), b["numerics_ref_sigma"].ravel()])
    with np.errstate(invalid="ignore", over="ignore"):
        rel = float(np.abs(m - ref_).max() / max(float(np.abs(ref_).max()), 1e-300))
    paths, t_end = b["numerics_pbound"].shape[0], float(b["numerics_times"][-1])
    if not np.isfinite(rel):
        return Holds(False, rel, NUMERICS_RTOL, "the per-path covariances overflow")
    return Holds(bool(rel <= NUMERICS_RTOL), rel, NUMERICS_RTOL,
                 f"the batched per-path covariances and an independent per-interval Van Loan computation agree to "
                 f"{rel:.2g} relative on {paths} clock paths drawn from the seed over [0, {t_end:g}] (a model too "
                 "ill-conditioned for double precision, e.g. strongly non-normal A_i, makes them disagree)")


@claims.hypothesis(H + "grid_asymptotic", "the gridded simulator's step is in its asymptotic regime, "
                                          f"h·(max‖A_i‖₂ + λ d_max) ≤ {GRID_ASYMPTOTIC:g}")
def grid_asymptotic(d: ScenarioDesign) -> Holds:
    sc, rho = d.scenario, float(d.bounds["grid_regime_0"])
    return Holds(bool(rho <= GRID_ASYMPTOTIC), rho, GRID_ASYMPTOTIC,
                 f"h·(max‖A_i‖₂ + λ d_max) = {rho:.3g} with h = {sc.grid_step:.6g} ({sc.grid_rule})")
