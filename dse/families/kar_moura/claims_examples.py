"""Claims about the paper's own example scenarios (E1, E7, E8: scope "paper-example", present in the
paper's reproduction only), fixed counterexamples (Remark 3, the textbook form (11)), and the structural
statements nothing numerical can check.
"""
from __future__ import annotations

import math

import numpy as np

import dse.estimators.switched_riccati as sr
import dse.estimators.walk_detectability as wd
from dse.contract.claims import ClaimSet, example
from dse.estimators.gikf_maps import FEATURES, GossipSystem, riccati_step, riccati_textbook
from dse.estimators.gikf_monte_carlo import QUANTILES
from dse.verify.rules import ERRATUM, FAIL, PASS, Verdict, claim_confidence, not_checkable, roundoff_tolerance

from . import stats as kst
from .bounds import envelope_matrix
from .checking import FEAT, error_level, feat, random_psd, tidx
from .results import Results, ScenarioResults

claims = ClaimSet()


@claims.claim("kar-moura.e7.periodic-orbit{.scenario}", "example E7 (ours)",
              "Covariances settle on a 2-periodic orbit with traces 1.8841 / 2.1634", "identity", when=example("e7"),
              scope="paper-example")
def check_periodic_orbit(r: ScenarioResults) -> Verdict:
    """E7: with A(t) = swap at every slot, both covariances settle on a 2-periodic orbit (traces 1.8841, 2.1634)."""
    sys_ = r.scenario.system
    X = [r.scenario.P0.copy() for _ in range(r.scenario.N)]
    for t in range(400):
        X = [riccati_step(X[1 - n] if t > 0 else X[n], sys_.C[n], sys_.R[n], sys_.F, sys_.Q) for n in range(2)]
    traces = sorted(float(np.trace(x)) for x in X)
    ok = bool(np.all(np.abs(np.array(traces) - [1.8841, 2.1634]) <= 5e-5))
    tr = r.gikf["path_trace"][0, -2:, 0]
    return Verdict(PASS if ok else FAIL, measured=traces, reference=[1.8841, 2.1634], tolerance=5e-5,
                   margin=float(5e-5 - np.abs(np.array(traces) - [1.8841, 2.1634]).max()),
                   detail=(f"reference traces to 4 decimals (half a unit of the last digit); GIKF sample path at sensor 0, last "
                           f"two slots: {np.round(tr, 4).tolist()}"))


@claims.claim("kar-moura.e7.token-domination-fails{.scenario}", "Theorem 10[ii]; example E7 (ours)",
              "PREDICTED: with periodic Ā the conclusion of (25) fails (P(P_n(t) ∈ S) = 1 > μ(S) every other slot)",
              "statistical", when=example("e7"), scope="paper-example")
def check_e7_token_domination_fails(r: ScenarioResults) -> Verdict:
    """E7 (periodic Ā, C.1 fails): Theorem 10[ii]'s conclusion fails, as predicted. The swap happens at
    every slot, so token 0 sits at sensor p_0(t−1) = (t−1) mod 2 and its covariance alternates between
    the two orbit points: P(P_0(t) ∈ S) is 1 at every other slot while μ_t(S) = 1/2, S = {tr X ≥ 2}."""
    ref, g = r.reference, r.gikf
    times = [int(t) for t in ref["times"]]
    level = error_level() / 2
    best, lines = -math.inf, []
    for t in times[-2:]:
        holder = (t - 1) % 2
        x = kst.finite(feat(g["feat_n"][tidx(r, t)][:, :, holder], "log_trace"))
        mu = kst.finite(feat(ref["features"][times.index(t)], "log_trace"))
        a = float(np.log(2.0))
        k1, k2 = int((x >= a).sum()), int((mu >= a).sum())
        lo, hi = kst.cp_lower(k1, len(x), level / 2), kst.cp_upper(k2, len(mu), level / 2)
        best = max(best, lo - hi)
        lines.append(f"t={t}: P(tr P_0(t) ≥ 2) = {k1 / len(x):.3f} (token 0 at sensor {holder}) vs μ̂_t = {k2 / len(mu):.3f}")
    return Verdict(PASS if best > 0 else FAIL, measured=float(best), reference=0.0, margin=float(best),
                   confidence=claim_confidence(), trials=r.runs,
                   detail=("predicted failure of (25) under periodic Ā: at one of the last two record times the lower "
                           "Clopper-Pearson bound for token 0 exceeds the upper bound for μ_t. " + "; ".join(lines)
                           + ". The mixture still converges."))


@claims.claim("kar-moura.e8.d1-not-necessary{.scenario}", "Remark 5; example E8 (ours)",
              "D.1 fails for singular F yet (F, C_all) is observable and P̂ stays bounded", "qualitative",
              when=example("e8"), scope="paper-example")
def check_d1_not_necessary(r: ScenarioResults) -> Verdict:
    """E8 (singular F): D.1 fails (certified), (F, C_all) is observable, and the covariances stay bounded
    (no drift of the median or q0.95 of log tr P̂_n over the second half): D.1 is sufficient, not necessary."""
    b, ref = r.bounds, r.reference
    lam = np.exp(feat(ref["features"][-1], "log_trace"))
    q = np.quantile(lam, [0.5, 0.99, 0.999])
    qq, slots = r.gikf["quantiles"], r.gikf["stat_slots"]
    late = slots >= r.slots // 2
    t = slots[late]
    drift = max(abs(np.polyfit(t, qq[late, n, k], 1)[0]) for n in range(r.scenario.N)
                for k in (QUANTILES.index(0.5), QUANTILES.index(0.95)))
    limit = 0.1 * 2 * np.log(max(np.abs(np.linalg.eigvals(r.scenario.F)).max(), 1.0 + 1e-9))
    ok = (r.assume.d1.holds is False) and bool(b["central_observable"]) and drift < limit
    return Verdict(PASS if ok else FAIL, measured=float(drift), reference=float(limit), margin=float(limit - drift),
                   detail=(f"observation on the example, not a paper claim: D.1 fails (max walk-Gramian rank "
                           f"{int(b['witness_max_rank'])} of {r.scenario.M}; {r.assume.d1.how}) while (F, C_all) is observable; "
                           f"the covariances are nevertheless bounded: the largest |slope| of the median and q0.95 of "
                           f"log tr P̂_n over the second half is {drift:.4f} per slot (limit: 10% of 2 log ρ(F) = {limit:.4f}); "
                           f"μ̂ trace quantiles 0.5/0.99/0.999 = {np.round(q, 2).tolist()} (reference 2.0 / 60 / 574). Remark 5's "
                           f"minimality is over all F."))


claims.unchecked("kar-moura.prop7-i.semi-markov", "Proposition 7[i], eq (16)", "(P_n(t), p_n(t)) is jointly Markov",
                 "qualitative", reason="structural (holds by construction); the bookkeeping is checked pathwise by prop7-ii")
claims.unchecked("kar-moura.lemma11-i.compactness", "Lemma 11[i]", "Conditional compactness of the RDS", "qualitative",
                 reason="topological statement in finite dimension; nothing numerical to check")
claims.unchecked("kar-moura.thm26.uniqueness", "Theorem 26 / Theorem 12 (uniqueness)", "The invariant measure is unique",
                 "qualitative", reason="uniqueness cannot be shown numerically; thm8.initial-law and lemma23.pullback "
                                       "support it")


@claims.claim("kar-moura.remark3.covering-walk", "Remark 3",
              "F invertible and Σ C_nᵀC_n full rank ⇒ every covering walk satisfies D.1", "qualitative",
              scope="paper-example")
def check_remark3(_res) -> Verdict:
    """Remark 3: 'F invertible and G = Σ C_nᵀC_n full rank ⇒ any covering walk works' is false."""
    F = np.array([[0.0, -1.0], [1.0, 0.0]])
    sys_ = GossipSystem.build(F, 0.1 * np.eye(2), [np.array([[1.0, 0.0]]), np.array([[0.0, 1.0]])],
                                 [np.eye(1), np.eye(1)], np.eye(2))
    cover = np.linalg.eigvalsh(wd.walk_gramian(sys_, (0, 1)))
    alt = np.linalg.eigvalsh(wd.walk_gramian(sys_, (0, 1, 0, 1, 0, 1)))
    found = wd.search_witness(sys_, np.array([[0.5, 0.5], [0.5, 0.5]]))
    eig = np.linalg.eigvalsh(found.gramian)
    return Verdict(ERRATUM, measured=float(cover[0]), reference=0.0, printed=float(cover[0]), corrected=float(eig[0]),
                   detail=(f"F = rotation by 90°, C_1 = [1 0], C_2 = [0 1] (G = I, F invertible): the covering walk (1,2) "
                           f"has Gramian eigenvalues {np.round(cover, 6).tolist()}, the alternating walk (1,2,1,2,1,2) "
                           f"{np.round(alt, 6).tolist()}: singular, contrary to Remark 3's justification. The conclusion "
                           f"(some walk works) survives: breadth-first search finds w0 = {tuple(x + 1 for x in found.witness)} "
                           f"(1-based) with eigenvalues {np.round(eig, 6).tolist()}. We therefore always search for and "
                           f"record w0."))


@claims.claim("kar-moura.eq11.joseph-form", "eq (11)",
              "The Riccati map is computed accurately for ‖X‖ up to 1e16 (Joseph form)", "identity",
              scope="paper-example")
def check_riccati_roundoff(_res) -> Verdict:
    """The textbook form (11) loses accuracy for huge ‖X‖; the Joseph form does not."""
    F, Q = np.diag([1.2, 1.1]), 0.1 * np.eye(2)
    C, R = np.array([[1.0, 0.0]]), np.eye(1)
    rng = np.random.default_rng(1)
    X = random_psd(rng, 200, 2, (12, 16))
    jos = riccati_step(X, C, R, F, Q)
    txt = riccati_textbook(X, C, R, F, Q)
    info = F @ np.linalg.inv(np.linalg.inv(X) + C.T @ C) @ F.T + Q  # information form (exact for X ≻ 0)
    ej = float(np.abs(jos - info)[:, 0, 0].max())
    et = float(np.abs(txt - info)[:, 0, 0].max())
    below_q = int((np.linalg.eigvalsh(txt - Q)[:, 0] < 0).sum())
    tol, how = roundoff_tolerance(scale=float(np.abs(info[:, 0, 0]).max()), operations=40, safety=1e3)
    return Verdict(PASS if ej < tol else FAIL, measured=ej, reference=0.0, tolerance=tol, margin=tol - ej,
                   detail=(f"‖X‖ ∈ [1e12, 1e16], C = [1 0]: error of the observed-direction entry f(X)_11 against the "
                           f"information form: Joseph {ej:.2e}, textbook (11) {et:.2e} ({how}, relative to the entry, not to "
                           f"‖X‖); textbook results violating f(X) ⪰ Q: {below_q} of 200. All simulations use the Joseph form."))


@claims.claim("kar-moura.r23.tail-exponent.e1", "derived heuristic (ours)",
              "Diagonal μ-entries have power tails with exponents κ_j, (1−ρ)a_j^{2κ_j} = 1", "statistical",
              when=example("e1"), scope="paper-example", args=("e1",))
def check_tail_exponent(res: Results, name: str) -> Verdict:
    """E1 heuristic: P(X_jj > x) ~ x^{−κ_j}, (1 − ρ) a_j^{2κ_j} = 1, ρ = rate of leaving a sensor type."""
    r = res.get(name)
    ref = r.reference
    if r.reference_runs < 10_000:
        return not_checkable(f"the tail fit needs ≥ 10,000 Theorem-8 runs (this run has {r.reference_runs}; quick mode)")
    M = r.scenario.M
    Abar = r.bounds["Abar"]
    rho = float(1 - Abar[0, 0])  # E1: every off-diagonal move changes the type
    a = np.abs(np.diag(r.scenario.F))
    kappa = -np.log(1 - rho) / (2 * np.log(a))
    est, lines = [], []
    for j in range(M):
        x = np.sort(ref["features"][-1][len(FEATURES) + j])[::-1]
        n = len(x)
        k = max(int(0.02 * n), 50)
        hill = 1.0 / np.mean(np.log(x[:k] / x[k]))
        est.append(hill)
        lines.append(f"X_{j + 1}{j + 1}: Hill estimate {hill:.3f} ± {hill / math.sqrt(k):.3f} (top {k} of {n}) vs κ = {kappa[j]:.3f}")
    rel = np.abs(np.array(est) - kappa) / kappa
    ok = bool(rel.max() < 0.15)
    return Verdict(PASS if ok else FAIL, measured=[float(e) for e in est], reference=kappa.tolist(), tolerance=0.15,
                   margin=float(0.15 - rel.max()), trials=len(ref["features"][-1][0]),
                   detail=("; ".join(lines) + ". A heuristic of ours (not the paper's), so a 15% tolerance rather than a "
                           "confidence level; κ_1 < 1 means E_μ[tr X] = ∞: the report uses quantiles, never means."))


#: μ and μ_n trace quantiles of E1 from an independent prototype (T = 300)
MU_QUANTILES_E1 = {0.10: 2.01, 0.25: 2.19, 0.50: 3.12, 0.75: 6.84, 0.90: 24.6, 0.99: 759.0}
MU_N_E1 = {0: {0.5: 2.43, 0.9: 8.7, 0.99: 65.0}, 1: {0.5: 4.29, 0.9: 53.0, 0.99: 2495.0}}


def quantile_ci(x: np.ndarray, q: float, level: float) -> tuple[float, float]:
    """Distribution-free confidence interval of the q-quantile from order statistics (binomial), level split in two."""
    from scipy import stats

    x = np.sort(x)
    n = len(x)
    lo = int(stats.binom.ppf(level / 2, n, q))
    hi = int(stats.binom.isf(level / 2, n, q))
    return float(x[max(lo - 1, 0)]), float(x[min(hi, n - 1)])


@claims.claim("kar-moura.e1.mu-quantiles", "reference numbers of an independent prototype (the paper has none)",
              "Quantiles of tr X under μ and under the per-type laws μ_n match the independent prototype",
              "statistical", when=example("e1"), scope="paper-example", args=("e1",))
def check_reference_quantiles(res: Results, name: str) -> Verdict:
    """μ and μ_n trace quantiles of E1 against an independent prototype's numbers (order-statistic CIs)."""
    r = res.get(name)
    if r.slots < 300 or r.reference_runs < 10_000:
        return not_checkable(f"the reference numbers are for T = 300 and ≥ 1e5 runs; this run has T = {r.slots}, "
                             f"{r.reference_runs} runs (quick mode)")
    ref = r.reference
    tr = np.exp(ref["features"][-1][FEAT["log_trace"]])
    last = ref["last"][-1]
    cells = [("μ", q, v, tr) for q, v in MU_QUANTILES_E1.items()]
    cells += [(f"μ_{n} (last switch at sensor type {n})", q, v, tr[(last % 2) == n]) for n, row in MU_N_E1.items()
              for q, v in row.items()]
    level = error_level() / len(cells)
    lines, worst, ok = [], math.inf, True
    for label, q, v, x in cells:
        lo, hi = quantile_ci(x, q, level)
        rounding = 0.005 * v  # the reference numbers carry 2-3 significant digits
        inside = lo - rounding <= v <= hi + rounding
        ok &= inside
        worst = min(worst, min(v - lo, hi - v) / v)
        lines.append(f"{label} q{q:g}: reference {v:g}, ours [{lo:.4g}, {hi:.4g}]{'' if inside else ' OUTSIDE'}")
    return Verdict(PASS if ok else FAIL, measured=float(np.quantile(tr, 0.5)), reference=MU_QUANTILES_E1[0.5],
                   margin=float(worst), confidence=claim_confidence(), trials=len(tr),
                   detail=(f"distribution-free order-statistic intervals (Bonferroni over {len(cells)} quantiles, widened by "
                           f"the reference's rounding of 0.5%): " + "; ".join(lines)
                           + ". Types by parity of the last switch (E1: even sensors see mode 1)."))


TV_S = (1, 2, 5, 10, 20, 40)  # the proof takes s > 0
TV_LEN = (1, 2, 3, 4, 6)


@claims.claim("kar-moura.eq82.tv-step", "eqs (78)-(84)",
              "d_v(P^s_n(t), Q^s(t)) ≤ N d_v(p_n(s), q(s)) (exact total variation over the finite supports)",
              "inequality", when=example("e1"), scope="paper-example", args=("e1",))
def check_tv_step(res: Results, name: str) -> Verdict:
    """(78)-(82) computed exactly: the laws of P^s_n(t) and Q^s(t) are finite (one atom per chain
    path (p(s), ..., p(t−1))); d_v = ½ Σ_atoms |P − Q| against N d_v(p_n(s), q(s)) (82)."""
    r = res.get(name)
    sc, b = r.scenario, r.bounds
    sys_ = sc.system
    Abar = b["Abar"]
    N = sc.N
    rows, worst_margin, ratio_max, path_identity, n_sum = [], math.inf, 0.0, 0.0, 1
    for s in TV_S:
        if s > r.slots:
            continue
        pi = np.linalg.matrix_power(Abar, s)
        dv = 0.5 * np.abs(pi - 1.0 / N).sum(axis=1)
        for L in TV_LEN:
            paths, w = sr.chain_paths(Abar, L)
            n_sum = max(n_sum, len(paths))
            X = np.broadcast_to(envelope_matrix(b, s), (len(paths), sc.M, sc.M)).copy()
            for k in range(L):
                X = sr.apply_maps(sys_, X, paths[:, k])
            _, atom = np.unique(X.reshape(len(X), -1), axis=0, return_inverse=True)
            atom = atom.ravel()
            lawP = pi[:, paths[:, 0]] * w
            lawQ = w / N
            diff = np.zeros((N, atom.max() + 1))
            np.add.at(diff.T, atom, (lawP - lawQ).T)
            tv = 0.5 * np.abs(diff).sum(axis=1)
            tv_paths = 0.5 * np.abs(lawP - lawQ).sum(axis=1)
            path_identity = max(path_identity, float(np.abs(tv_paths - dv).max()))
            worst_margin = min(worst_margin, float((N * dv - tv).min()))
            with np.errstate(invalid="ignore", divide="ignore"):
                ratio = np.where(dv > 1e-15, tv / np.maximum(dv, 1e-300), 0.0)
            ratio_max = max(ratio_max, float(ratio.max()))
            if L in (1, 4) or L == TV_LEN[-1]:
                n_star = int(np.argmax(tv))
                rows.append(f"s={s}, t−s={L}: {len(paths)} paths, max_n d_v(P^s_n, Q^s) = {tv[n_star]:.3e} (n={n_star}) "
                            f"vs d_v(p_n(s), U) = {dv[n_star]:.3e}")
    tol, how = roundoff_tolerance(scale=1.0, operations=n_sum + max(TV_S) * N)
    ok = worst_margin >= -tol and path_identity <= tol
    return Verdict(PASS if ok else FAIL, measured=ratio_max, reference=float(N), margin=worst_margin, tolerance=tol,
                   detail=(f"exact total variation over all atoms (no sampling), every token n = 0..{N - 1}, s ∈ {list(TV_S)}, "
                           f"t − s ∈ {list(TV_LEN)}; {how} (sums of probabilities ≤ 1). (82) holds everywhere: smallest slack "
                           f"N d_v − d_v(P^s_n, Q^s) = {worst_margin:.3e}. The constant N is crude: the largest ratio "
                           f"d_v(P^s_n(t), Q^s(t)) / d_v(p_n(s), q(s)) is {ratio_max:.4f} (≤ 1, data processing). On paths, "
                           f"before atoms merge, the distance equals d_v(p_n(s), U) (max deviation {path_identity:.1e}). "
                           + "; ".join(rows)))
