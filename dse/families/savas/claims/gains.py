"""Claims on the optimal gains (§V-B) and the centralized references: the m = 0 optimum, the KKT
conditions of the tabulated optima, the centralized Kalman filter as a lower bound, the sandwich
of J* between the centralized and the no-communication costs, and filterpy's Kalman filter."""
from __future__ import annotations

import numpy as np

import dse.estimators.consensus_trace as ct
import dse.estimators.gain_tuning as gt
import dse.estimators.kalman as kal
from dse.verify.rules import EPS, FAIL, PASS, Verdict, below, within

from ..results import Results
from .common import DS, SYM, centralized, claims, formula_allowance, spectrum, steps_text, tol


@claims.claim("savas.tuning.m0", "§V-B", "for m = 0, J = (ℓ²r + q)N/(1−(1−ℓ)²); its minimiser is the single-sensor "
              "Kalman gain, J*₀ = N P₁⁻", "identity")
def check_m0(res: Results) -> Verdict:
    """m = 0: J = (ℓ²r + q)N/(1−(1−ℓ)²) (from (16) with Q† = I) is minimised by the single-sensor Kalman gain."""
    from scipy.optimize import minimize_scalar

    sc = res.scenario
    q, r, lam = sc.model.q, sc.model.r, spectrum(sc.Q)
    f = lambda ell: ct.asymptotic_trace_from_spectrum(lam, ell=ell, zeta=1.0, m=0, sigma_c=0.0, q=q, r=r)
    xatol = 1e-14
    num = minimize_scalar(f, bounds=(1e-12, 1.0), method="bounded", options={"xatol": xatol})
    ell0, J0 = gt.optimal_gain_no_communication(q, r, sc.n)
    P1, K1 = kal.scalar_random_walk_steady_state(q, r)
    NP1 = sc.n * P1
    cond = 1 / (1 - (1 - K1) ** 2)   # J is computed to relative precision eps·cond (1 − (1−ℓ)² loses digits)
    tol_ell = 10 * (np.sqrt(EPS * cond) * K1 + xatol)   # a minimiser found from values: √(eps·cond) relative
    tol_J = tol(scale=NP1, operations=sc.n + 10, condition=1 / (1 - (1 - K1) ** 2))
    measured = [num.x, f(num.x), ell0, J0, f(K1)]
    reference = [K1, NP1, K1, NP1, NP1]
    allow = [tol_ell, tol_J, tol_J * K1 / NP1, tol_J, tol_J]
    if "corrected_ell" in res.bounds:
        t_ell, t_J = res.bounds["corrected_ell"][:, 0], res.bounds["corrected_J"][:, 0]
        measured += list(t_ell) + list(t_J)
        reference += [K1] * len(t_ell) + [NP1] * len(t_J)
        allow += [tol_ell] * len(t_ell) + [tol_J] * len(t_J)
    return within(measured, reference, allow,
                  detail=(f"ℓ*₀ = K₁ = {K1:.7g} (single-sensor Kalman gain), J*₀ = N·P₁⁻ = {NP1:.7g}; numerical "
                          f"minimiser (bounded Brent on [1e-12, 1]) gives ℓ = {num.x:.7g}, J = {f(num.x):.7g}, located to "
                          f"10(√(eps/(1−(1−ℓ)²))·ℓ + xatol) = {tol_ell:.2g}: J is known to relative eps/(1−(1−ℓ)²), and a "
                          "minimum found from function values to the square root of that"))


@claims.claim("savas.tuning.kkt", "§V-B", "the optimised (ℓ*, ζ*) satisfy the KKT conditions of min J over [0, 1]²",
              "identity", hypotheses=(SYM,),
              requires=[(lambda res: res.scenario.rounds_max >= 1, "the gain tables have no m >= 1 (gains.rounds_max = 0)")])
def check_kkt(res: Results) -> Verdict:
    """KKT conditions of min J over [0, 1]² at the tabulated (ℓ*, ζ*), m >= 1, in units of the attainable precision."""
    b = res.bounds
    zeta, rel, ell = b["corrected_zeta"][:, 1:], b["corrected_kkt_scaled"][:, 1:], b["corrected_ell"][:, 1:]
    tols = 10 * np.sqrt(EPS / (1 - (1 - ell) ** 2))
    w = np.unravel_index(int(np.argmax(rel / tols)), rel.shape)
    t = float(tols[w])
    return Verdict(PASS if np.all(rel <= tols) else FAIL, measured=float(rel[w]), reference=0.0, tolerance=t,
                   margin=float(t - rel[w]),
                   detail=(f"projected gradient of J at (ℓ*, ζ*) over {rel.size} cells (m >= 1), each component divided by "
                           f"√(J·max(|J''|, J/s²)) (s = ℓ for ℓ, 1 for ζ): a minimum located from values of J is only "
                           f"known to √(eps'·J/J''), where the gradient is √(eps'·J·J''), with eps' = eps/(1−(1−ℓ)²) the "
                           f"relative precision of J; the allowance is 10√eps' ({t:.2g} in the worst cell); central "
                           f"differences (steps 1e-5·ℓ, 1e-5) add about 1e-10. Worst at σ_c = "
                           f"{res.scenario.sweep.sigma_c[w[0]]:g}, m = {w[1] + 1}; ζ* on the boundary 0 in "
                           f"{int((zeta <= 1e-9).sum())} cells"))


@claims.claim("savas.reference.kf_lower_bound", "§V (remark: not optimal)", "every agent's error variance is at least "
              "the centralized Kalman filter's, for every k, m, σ_c, gains", "inequality", hypotheses=(DS,))
def check_kf_lower_bound(res: Results) -> Verdict:
    n = res.scenario.n
    lo, up, t = [], [], []
    for c in res.cells:
        d = res.design.exact(c).diag
        lo.append(np.broadcast_to(res.design.kf_prior(res.design.steps_of(c))[:, None], d.shape)), up.append(d)
        t.append(np.full(d.shape, tol(scale=float(d.max()), operations=c.n_steps * (2 * n + 6) + 2 * (c.m + 1) * n)))
    return below(np.array(lo), np.array(up), np.array(t),
                 detail=(f"P_KF(k|k-1) <= [P(k|k-1)]_ii for every agent and cell, {steps_text(res)} (exact "
                         "recursions); allowance K(2N+6) + 2(m+1)N operations on the largest variance"))


@claims.claim("savas.reference.sandwich", "§V-B", "with optimal gains, N P_c⁻ <= J*(m) <= J*₀ (never worse than no "
              "communication)", "inequality", hypotheses=(SYM,))
def check_sandwich(res: Results) -> Verdict:
    J, ell = res.bounds["corrected_J"], res.bounds["corrected_ell"]
    _, NPc, NP1 = centralized(res)
    t = formula_allowance(J, ell) * res.scenario.n
    v1 = below(np.full(J.shape, NPc), J, t, detail="")
    v2 = below(J, np.full(J.shape, NP1), t, detail="")
    worst = v1 if v1.margin < v2.margin else v2
    ok = v1.status == PASS and v2.status == PASS
    return Verdict(PASS if ok else FAIL, measured=worst.measured, reference=worst.reference, tolerance=worst.tolerance,
                   margin=min(v1.margin, v2.margin),
                   detail=(f"N P_c⁻ = {NPc:.6f} <= J*(m, σ_c) <= N P₁⁻ = {NP1:.6f} over {J.size} cells; lower margin "
                           f"{v1.margin:.4g}, upper margin {v2.margin:.4g} (J*(0) = N P₁⁻ exactly; allowance: 200·N·eps·J "
                           "/(1−(1−ℓ)²), the round-off of (16))"))


def _filterpy_cell(res: Results):
    return next((c for c in res.cells if "filterpy_x" in res.mc[c.label]), None)


@claims.claim("savas.reference.filterpy", "reference", "the batched centralized Kalman filter equals filterpy's",
              "identity", requires=[(lambda res: _filterpy_cell(res) is not None, "no sample paths stored")])
def check_filterpy(res: Results) -> Verdict:
    """Our batched centralized KF equals filterpy's KalmanFilter on the sample-path measurements (run with the
    sample paths, `monte_carlo.filterpy_priors`), and the scalar recursion of the design equals its covariances."""
    sc, model = res.scenario, res.scenario.model
    a = res.mc[_filterpy_cell(res).label]
    y, fx, fP = a["path_y"], a["filterpy_x"], a["filterpy_P"]
    F, H_, Qw, R = np.eye(1), np.ones((sc.n, 1)), np.array([[model.q]]), model.r * np.eye(sc.n)
    run = kal.kalman_filter_batch(F, H_, Qw, R, np.array([model.x0_mean]), np.array([[model.sigma0]]), y)
    P_max = max(model.sigma0, float(run.cov.P_prior.max()))
    cond = (sc.n * P_max + model.r) / model.r   # condition of the innovation covariance P 11ᵀ + rI that filterpy inverts
    ops = y.shape[1] * (sc.n ** 2 + 10)
    t_x = tol(scale=max(np.abs(y).max(), abs(model.x0_mean), 1e-300), operations=ops, condition=cond)
    t_P = tol(scale=P_max, operations=ops, condition=cond)
    # the scalar recursion behind every P_KF of the design (bound checks, tables) on the same steps
    ours = list(res.design.kf_prior(np.arange(y.shape[1])))
    theirs = list(run.cov.P_prior[:, 0, 0])
    allow = [t_P] * y.shape[1]
    for p in range(y.shape[0]):
        for k in range(y.shape[1]):
            theirs += [fx[p, k], fP[p, k]]
            ours += [run.x_prior[p, k, 0], run.cov.P_prior[k, 0, 0]]
            allow += [t_x, t_P]
    return within(ours, theirs, allow,
                  detail=(f"priors x̂(k|k-1), P(k|k-1) on {y.shape[0]} sample trials × {y.shape[1]} steps, and the scalar "
                          "recursion of P_KF(k|k-1) used by the bounds on the same steps; allowance "
                          f"K(N²+10) operations × the condition {cond:.3g} of the innovation covariance"))
