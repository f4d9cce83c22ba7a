"""The hypotheses and claims checked on a compare scenario, each registered on its check: the references
and exact recursions against the simulation, the optimality of the centralized filter, the consistency
properties the papers prove for their covariances, and the orderings the papers claim (Savas et al.:
re-injection against Carli's filter under noisy links; Kar & Moura: weak consensus of the GIKF).

Hypotheses are decided on the design alone (`dse check`); `requires=` declares what the run must contain
for a claim to be checked at all (the estimators it is about). Statistical tests keep their level at the sample
size: exact χ² laws where the error is Gaussian with a known covariance (given the link draws), the
two-sample Kolmogorov-Smirnov test for the token law, normal z-tests of means of many independent trials
only with an effective-sample-size gate; every claim's cells share its confidence (Bonferroni).
"""
from __future__ import annotations

import numpy as np

from dse.contract.claims import ClaimSet
from dse.estimators.network_comparison import effective_sample_size, ks_test, mean_and_se
from dse.simulate.stats import chi2_two_sided_p, normal_two_sided_p
from dse.verify.rules import Holds, Verdict, inequality, not_checkable, p_value_test, roundoff_tolerance

from .stages import token_times

claims = ClaimSet()

#: z-tests of Monte Carlo means need at least this many trials and this effective sample size
MIN_TRIALS_Z = 500
MIN_ESS = 200
#: the Kolmogorov-Smirnov comparison needs this many trials in each sample
MIN_TRIALS_KS = 50

NOISY = "compare.hyp.noisy_links"
NOISELESS = "compare.hyp.noiseless_links"
CARLI_NOISE = "compare.hyp.carli_noise_dominated"
STABLE = "compare.hyp.mean_square_stable"
C1 = "compare.hyp.kar_moura.C1"
D1 = "compare.hyp.kar_moura.D1"
S1 = "compare.hyp.kar_moura.S1"


# -- hypotheses --------------------------------------------------------------------------------------------

@claims.hypothesis(NOISELESS, "the links add no communication noise (σ_c = 0)", args=(False,))
@claims.hypothesis(NOISY, "the links add communication noise (σ_c > 0)", args=(True,))     # registered first
def communication_noise(d, noisy: bool) -> Holds:
    s = d.scenario.links.noise_std
    return Holds((s > 0) if noisy else (s == 0), s, 0.0, f"communication noise σ_c = {s:g}")


@claims.hypothesis(CARLI_NOISE, "communication noise dominates Carli's filter: its steady mean-square error exceeds "
                   "that of the same local filters without fusion")
def carli_noise(d) -> Holds:
    t = d.network.tuned
    if "carli" not in d.running or "carli_local_steady" not in t:
        return Holds(None, detail="Carli's filter does not run on this scenario: " + d.estimators["carli"].reason)
    if d.links.kind == "matchings":
        return Holds(None, detail="under random matchings the steady state has no closed form here (the gains were "
                                  "tuned on independent links of the same mean activity)")
    carli, local = t["carli_steady"], t["carli_local_steady"]
    if not (np.isfinite(carli) or np.isfinite(local)):
        return Holds(None, detail="neither steady state exists (mean-square unstable)")
    return Holds(bool(carli > local), carli, local,
                 f"exact steady network MSE of Carli's filter with its tuned gain {carli:.6g} against the same local "
                 f"filters without fusion {local:.6g}: communication "
                 + ("hurts (the noise it integrates outweighs the averaging; the regime of Savas et al.'s Fig. 1)"
                    if carli > local else "helps"))


@claims.hypothesis(STABLE, "Carli's and the re-injection filter's mean-square error recursions are stable (ρ < 1)")
def stable(d) -> Holds:
    # designed gains, running or not: a filter whose recursion is unstable is not applicable, and this says why
    rows = {e: d.estimators[e].tuning["rho"] for e in ("carli", "reinjection")
            if e in d.estimators and d.estimators[e].tuning}
    if len(rows) < 2:
        return Holds(None, detail="Carli's or the re-injection filter does not run on this scenario")
    if d.links.kind == "matchings":
        return Holds(None, detail="under random matchings the mean second-moment recursion has no closed form here")
    worst = max(rows.values())
    return Holds(bool(worst < 1), worst, 1.0, "spectral radius of the exact mean second-moment step: " +
                 ", ".join(f"{e} {r:.6g}" for e, r in rows.items()))


@claims.hypothesis(C1, "C.1: the GIKF's mean communication matrix is irreducible and aperiodic")
def c1(d) -> Holds:
    return Holds(d.numbers["c1"], None, None,
                 "mean of the GIKF's swap permutation irreducible and aperiodic: " + d.numbers["c1_detail"])


@claims.hypothesis(D1, "D.1: weak detectability (a covering walk with an invertible observability Gramian)")
def d1(d) -> Holds:
    v, r = d.numbers["d1"], d.numbers["d1_ratio"]
    text = (f"Gramian Σ (F^i)ᵀ H_{{w_i}}ᵀ H_{{w_i}} F^i along a covering walk of length {d.numbers['d1_walk_length']}: "
            f"λ_min/λ_max = {r:.3g}")
    if v is None:
        text += "; (F, H) is observable but this walk's Gramian is singular: undecided"
    elif not v:
        text += "; (F, H) of all sensors together is not observable, so no walk's Gramian is invertible"
    return Holds(v, r, 1e-10, text)


@claims.hypothesis(S1, "S.1: (F, Q^½) stabilizable")
def s1(d) -> Holds:
    return Holds(bool(d.numbers["stabilizable"]), None, None, "(F, Q^½) stabilizable (PBH test on the modes |λ| ≥ 1)")


@claims.hypothesis("compare.hyp.collective_detectability", "collective detectability of (F, H)")
def collective(d) -> Holds:
    return Holds(bool(d.numbers["collective_detectable"]), None, None,
                 "(F, H) of all sensors together detectable: the centralized filter's error is bounded")


@claims.hypothesis("compare.hyp.local_detectability", "local detectability at every node")
def local(d) -> Holds:
    loc = np.asarray(d.numbers["local_detectable"])
    return Holds(bool(loc.all()), int(loc.sum()), len(loc),
                 f"{int(loc.sum())} of {len(loc)} nodes can detect the state alone (what filters without communication "
                 "need; weak detectability asks only for the network)")


# -- claims ------------------------------------------------------------------------------------------------

def _finite(*arrays) -> bool:
    return all(np.all(np.isfinite(np.asarray(a, float))) for a in arrays if a is not None)


@claims.claim("compare.central.filterpy", "reference (filterpy)", "the centralized Kalman filter agrees with "
              "filterpy's KalmanFilter on the stacked model to round-off", "identity",
              requires=[(lambda res: bool(res.reference), "the centralized filter does not run")])
def filterpy_reference(res) -> Verdict:
    r = res.reference
    m = res.design.model
    ops = float(r["steps"]) * (m.N * m.m + m.n) * 10
    tol_x, how = roundoff_tolerance(scale=float(max(r["sx"], 1.0)), operations=ops, condition=float(r["cond"]))
    tol_P, _ = roundoff_tolerance(scale=float(max(r["sP"], 1.0)), operations=ops, condition=float(r["cond"]))
    return inequality([float(r["dx"]), float(r["dP"])], [tol_x, tol_P],
                      detail=f"largest differences from filterpy's KalmanFilter over {int(r['steps'])} steps of 3 "
                             f"simulated trials: estimates {float(r['dx']):.3g}, covariances {float(r['dP']):.3g}; "
                             f"{how} (condition of the innovation covariance).")


def _resolved_by_float64(res, est: str, idx: list[int]) -> np.ndarray:
    """(C, W) whether the exact covariance Σ_ii of a cell is known well enough for the χ² test: Σ_ii is built by
    k + 1 steps of (rounds + 2) sums over N n terms, so its smallest eigenvalue carries a relative round-off up to
    δ = 10·ops·eps·cond(Σ_ii) (`roundoff_tolerance`); that moves the summed NEES by δ·trials·n, to be kept below a
    tenth of its standard deviation √(2·trials·n). A filter whose errors grow without bound reaches condition
    numbers beyond 1/eps, where Σ_ii⁻¹ is round-off."""
    m, B = res.design.model, res.trials
    steps = np.asarray(res.steps)[idx]
    blocks = res.exact[est]["blocks"][steps]                                  # (C, W, n, n)
    finite = np.isfinite(blocks).all(axis=(-2, -1))
    cond = np.full(finite.shape, np.inf)
    cond[finite] = np.linalg.cond(blocks[finite])
    ops = (steps[:, None] + 1.0) * (res.scenario.links.rounds + 2) * m.N * m.n
    delta = roundoff_tolerance(scale=1.0, operations=1.0)[0] * ops * cond        # linear in both
    with np.errstate(invalid="ignore"):
        return np.isfinite(cond) & (delta * B * m.n <= 0.1 * np.sqrt(2.0 * B * m.n))


def _exact_pvalues(res, est: str) -> tuple[np.ndarray | None, str, str, tuple]:
    """(p-values, law, why cells were left out, (Monte Carlo, exact) of the worst cell) of one estimator's
    exact moments against the simulation (None: not compared, with the reason in the third entry)."""
    B, n = res.trials, res.design.model.n
    idx = res.check_indices()
    s = res.mc[est]
    ex = res.exact[est]["mse"][res.steps[idx]]                   # (C, N)
    skipped = ""
    if not (res.design.links.random or not res.design.links.synchronous):
        p = chi2_two_sided_p(np.asarray(s["xnees"][idx], float), B * n)
        law = "χ²"
        resolved = _resolved_by_float64(res, est, idx)
        if not resolved.all():
            skipped = (f"{est} at {int((~resolved).sum())} of {resolved.size} cells, whose exact covariance float64 "
                       "does not resolve")
            if not resolved.any():
                return None, law, skipped, ()
            p = np.where(resolved, p, 1.0)          # left out: a p-value of 1 rejects nothing
    else:
        st = res.stats(est)
        mse, se = st.mse[idx], st.mse_se[idx]
        ess = effective_sample_size(s["sq"][idx], s["sq2"][idx])
        if B < MIN_TRIALS_Z or np.min(ess) < MIN_ESS:
            return None, "normal", f"{est} (effective sample size {np.min(ess):.0f})", ()
        p = normal_two_sided_p((mse - ex) / np.maximum(se, 1e-300))
        law = "normal"
    if not _finite(p):
        return None, law, f"{est} (not finite)", ()
    k = int(np.argmin(p))
    return np.ravel(p), law, skipped, (float(np.ravel(s["sq"][idx] / B)[k]), float(np.ravel(ex)[k]))


EXACT_LAW = ("With every link working the error is Gaussian with the exact covariance, so the sum over trials of "
             "e_iᵀ Σ_ii⁻¹ e_i is χ²(trials·n) exactly (cells whose Σ_ii float64 does not resolve are left out: a "
             "round-off of 10·operations·eps·cond(Σ_ii) relative must move the sum by less than a tenth of its "
             "standard deviation); with random links the mean squared error of independent trials is compared with "
             f"the exact mean over link patterns (normal, effective sample size ≥ {MIN_ESS}).")


def _exact_claim(res, names: list[str]) -> Verdict:
    """The exact moments of `names` against the simulation, every cell under one confidence."""
    ps, cells, skipped = [], [], []
    worst = (None, None)
    for est in names:
        p, law, why, cell = _exact_pvalues(res, est)
        if why:
            skipped.append(why)
        if p is None:
            continue
        ps.append(p)
        cells.append(f"{est} ({law}, {np.size(p)} cells)")
        if worst[0] is None or p.min() < worst[0]:
            worst = (p.min(), cell)
    if not ps:
        return not_checkable("no estimator with exact moments runs on this scenario" +
                             (f" (left out: {', '.join(skipped)})" if skipped else ""))
    idx = res.check_indices()
    detail = ("Monte Carlo against the exact moments at steps " + ", ".join(str(int(res.steps[i])) for i in idx) +
              ": " + "; ".join(cells) + ". " + EXACT_LAW + (f" Left out: {', '.join(skipped)}." if skipped else ""))
    return p_value_test(np.concatenate(ps), trials=res.trials, measured=worst[1][0], reference=worst[1][1],
                        detail=detail)


def _builtins(res, names) -> list[str]:
    """The built-in estimators among `names` (a plug-in filter has claims of its own)."""
    return [e for e in names if not res.design.estimators[e].spec.plugin]


@claims.claim("compare.exact.monte_carlo", "exact moment recursions", "the exact second moments of the linear "
              "network filters (Carli, re-injection, pairwise averaging; Kalman-consensus, diffusion and CI on "
              "reliable links) agree with the simulation", "statistical")
def exact_vs_monte_carlo(res) -> Verdict:
    return _exact_claim(res, [e for e in _builtins(res, res.design.estimators) if res.design.estimators[e].spec.joint_moments
                              and e in res.exact and e in res.mc])


@claims.claim("compare.central.orthogonality", "orthogonality principle", "the centralized filter's error is "
              "orthogonal to every other estimate's distance from it, so the excess mean-square error over the "
              "centralized filter is the mean-square distance to it", "statistical",
              requires=[(lambda res: "central" in res.mc, "the centralized filter does not run"),
                        (lambda res: res.trials >= MIN_TRIALS_Z,
                         lambda res: f"needs ≥ {MIN_TRIALS_Z} trials for the normal z-test; ran {res.trials}")])
def orthogonality(res) -> Verdict:
    """E[(x − x̂_c)ᵀ(x̂_c − x̂_i)] = 0 for every built-in estimator (`_orthogonality`)."""
    return _orthogonality(res, [e for e in _builtins(res, res.mc) if e != "central"])


def _roundoff_allowance(res, idx: list[int]) -> np.ndarray:
    """(C, 1) the round-off allowance of a mean of (x − x̂_c)ᵀ(x̂_c − x̂_i) (`_orthogonality`)."""
    m = res.design.model
    steps = np.asarray(res.steps)[idx]
    err_rms = np.sqrt(np.maximum(res.stats("central").mse[idx], 0.0)).reshape(len(idx), -1)[:, :1]
    ops = (steps + 1.0) * (res.scenario.links.rounds + 1) * (m.n + m.N * m.m)
    state_rms = m.state_rms(res.scenario.simulation.steps)[steps]
    return np.array([roundoff_tolerance(scale=float(e * x), operations=float(o))[0]
                     for e, x, o in zip(err_rms[:, 0], state_rms, ops)])[:, None]


def _orthogonality(res, names: list[str]) -> Verdict:
    """E[(x − x̂_c)ᵀ(x̂_c − x̂_i)] = 0, tested cell by cell (node, step) by a normal z-test of the mean over
    trials, beyond a round-off allowance: an estimator that equals the centralized filter up to rounding
    (the Kalman-consensus and diffusion filters with enough rounds on a small network) has a difference
    x̂_c − x̂_i made of rounding errors, which are not independent of x − x̂_c; by Cauchy–Schwarz they move
    the mean by at most RMS(x − x̂_c) · RMS(rounding of x̂), bounded by `roundoff_tolerance` with the input
    scale RMS(x − x̂_c) · RMS(x) and the operations of k steps of (rounds + 1) updates of n + N·m terms.
    The z statistic is (|mean| − allowance)⁺ / standard error."""
    B = res.trials
    idx = res.check_indices()
    steps = np.asarray(res.steps)[idx]
    allowance = _roundoff_allowance(res, idx)
    ps, names_in, skipped, worst = [], [], [], (None, 0.0)
    for est in names:
        st = res.stats(est)
        excess = np.maximum(np.abs(st.cross[idx]) - allowance, 0.0)
        z = excess / np.maximum(st.cross_se[idx], 1e-300)
        if not _finite(z):
            skipped.append(est)
            continue
        ps.append(np.ravel(normal_two_sided_p(z)))
        names_in.append(est)
        k = int(np.argmax(np.abs(st.cross[idx])))
        if worst[0] is None or np.ravel(np.abs(st.cross[idx]))[k] > abs(worst[1]):
            worst = (est, float(np.ravel(st.cross[idx])[k]))
    if not ps:
        return not_checkable("no estimator with finite errors besides the centralized filter")
    return p_value_test(np.concatenate(ps), trials=B, measured=worst[1], reference=0.0, detail=(
        "E[(x − x̂_c)ᵀ(x̂_c − x̂_i)] = 0 for every node i of " + ", ".join(names_in) + " at steps " +
        ", ".join(str(int(k)) for k in steps) + " (normal z-test of the mean over independent trials, beyond a "
        "round-off allowance of " + ", ".join(f"{a:.2g}" for a in allowance[:, 0]) + " = 10·operations·eps·RMS(x − "
        "x̂_c)·RMS(x): estimators equal to the centralized filter up to rounding differ from it by rounding errors "
        "only). The centralized estimate is E[x | all measurements] and every other estimate is a function of the "
        "measurements and of independent link and noise draws, so its error is orthogonal to them: MSE_i = MSE_c + "
        "E‖x̂_i − x̂_c‖², the excess over the centralized filter is exactly the mean-square distance to it. Largest "
        f"mean: {worst[1]:.4g} ({worst[0]})." + (f" Left out (errors not finite): {', '.join(skipped)}." if skipped else "")))


@claims.claim("compare.central.lower_bound", "optimality of the centralized filter", "no estimator has a smaller "
              "exact mean-square error than the centralized Kalman filter, at any node and step", "inequality",
              requires=[(lambda res: "central" in res.exact, "the centralized filter does not run")])
def lower_bound(res) -> Verdict:
    central = res.exact["central"]["mse"][:, 0]
    lows, ups, names = [], [], []
    for est, ex in res.exact.items():
        if est == "central" or not _finite(ex["mse"]) or res.design.estimators[est].spec.plugin:
            continue
        lows.append(np.broadcast_to(central[:, None], ex["mse"].shape).ravel())
        ups.append(ex["mse"].ravel())
        names.append(est)
    if not lows:
        return not_checkable("no other estimator has exact moments on this scenario")
    m = res.design.model
    scale = float(max(np.max(central), 1e-300))
    ops = float(res.scenario.simulation.steps) * (2 * m.N * m.n + m.n ** 3)
    tol, how = roundoff_tolerance(scale=scale, operations=ops, condition=_recursion_condition(res, names))
    return inequality(np.concatenate(lows), np.concatenate(ups), tolerance=tol,
                      detail=f"exact MSE of every node of {', '.join(names)} at every step against the centralized "
                             f"filter's (the conditional mean given every measurement); {how} (operations: per step "
                             "2 N n terms of the joint products and an n x n inverse; condition: the largest of the "
                             "centralized filter's covariances times the largest of the estimators' own covariances, "
                             "the matrices the recursions invert). An estimator equal to the centralized filter in "
                             "exact arithmetic (the Kalman-consensus filter on two nodes) differs from it by this "
                             "round-off only.")


def _recursion_condition(res, names: list[str]) -> float:
    """cond of the centralized filter's covariances times the largest cond of the estimators' own covariances
    (the inverses their exact recursions take), over every step."""
    def worst(covs) -> float:
        covs = np.asarray(covs, float).reshape(-1, *np.shape(covs)[-2:])
        ok = np.isfinite(covs).all(axis=(1, 2))
        return float(np.max(np.linalg.cond(covs[ok]), initial=1.0)) if ok.any() else 1.0

    own = [worst(res.exact[e]["own_cov"]) for e in names if "own_cov" in res.exact[e]]
    return worst(res.exact["central"]["blocks"]) * max(own, default=1.0)


@claims.claim("compare.kalman.conditional_covariance", "Kar & Moura (8)-(10); Kalman (1960)", "the covariances "
              "of the centralized, local and GIKF filters are their errors' conditional covariances (GIKF: given the "
              "swap path)", "statistical")
def conditional_covariances(res) -> Verdict:
    B, n = res.trials, res.design.model.n
    idx = res.check_indices()
    ps, names = [], []
    for est in _builtins(res, res.mc):
        if res.design.estimators[est].spec.covariance_law != "conditional":
            continue
        total = res.mc[est]["nees"][idx]
        if not _finite(total):
            continue
        ps.append(np.ravel(chi2_two_sided_p(np.asarray(total, float), B * n)))
        names.append(est)
    if not ps:
        return not_checkable("none of the centralized, local and GIKF filters runs")
    mean = float(np.concatenate([np.ravel(res.mc[e]["nees"][idx]) for e in names]).mean() / B)
    return p_value_test(np.concatenate(ps), trials=B, measured=mean, reference=float(n), detail=(
        f"the sum over trials of e_iᵀ P_i⁻¹ e_i is χ²(trials·n) exactly when P_i is the conditional error covariance "
        f"(Kalman filters; for the GIKF given the swap path, Kar & Moura (8)-(10), with the communication noise added to "
        f"the covariance received): {', '.join(names)}, every node, steps " +
        ", ".join(str(int(res.steps[i])) for i in idx) + "."))


@claims.claim("compare.ci.conservative.exact", "Battistelli & Chisci (2014), consistency of CI", "with noiseless "
              "links the CI filter's covariance bounds its error covariance: E[e_i e_iᵀ] ⪯ Ω_i⁻¹ (exact, reliable "
              "links)", "inequality", hypotheses=(NOISELESS,),
              requires=[(lambda res: "ci" in res.exact, "the CI filter has no exact moments on this scenario (random "
                                                        "links or too large): see compare.ci.conservative.monte_carlo")])
def ci_conservative_exact(res) -> Verdict:
    ex = res.exact["ci"]
    diff = ex["own_cov"] - ex["blocks"]
    low = np.linalg.eigvalsh(0.5 * (diff + np.swapaxes(diff, -1, -2)))[..., 0]
    m = res.design.model
    scale = float(np.abs(ex["own_cov"]).max())
    tol, how = roundoff_tolerance(scale=scale, operations=float(res.scenario.simulation.steps) * m.N * m.n ** 2,
                                  condition=float(np.max(np.linalg.cond(ex["own_cov"]))))
    return inequality(np.zeros_like(low).ravel(), low.ravel(), tolerance=tol,
                      detail="smallest eigenvalue of Ω_i⁻¹ − E[e_i e_iᵀ] (the filter's covariance minus the exact "
                             f"error covariance) at every node and step; {how}.")


@claims.claim("compare.ci.conservative.monte_carlo", "Battistelli & Chisci (2014), consistency of CI", "with "
              "noiseless links the CI filter's covariance bounds its error covariance (random links: one-sided χ² "
              "test)", "statistical", hypotheses=(NOISELESS,),
              requires=[(lambda res: "ci" in res.mc, "the CI filter does not run"),
                        (lambda res: "ci" not in res.exact, "checked exactly: see compare.ci.conservative.exact")])
def ci_conservative_mc(res) -> Verdict:
    from scipy.stats import chi2

    B, n = res.trials, res.design.model.n
    idx = res.check_indices()
    total = res.mc["ci"]["nees"][idx]
    p = chi2.sf(total, B * n)
    return p_value_test(np.ravel(p), trials=B, measured=float(np.max(total) / B), reference=float(n), detail=(
        "given the link draws, E[e_i e_iᵀ] ⪯ Ω_i⁻¹ makes e_iᵀ Ω_i e_i stochastically smaller than χ²(n), so the sum "
        "over independent trials is stochastically smaller than χ²(trials·n): one-sided test, exact at any number of "
        "trials (every node, steps " + ", ".join(str(int(res.steps[i])) for i in idx) + ")."))


@claims.claim("compare.savas.reinjection_beats_carli", "Savas et al. §III-B, §IV, Figs. 1 and 3", "under noisy "
              "links, in the regime where communication noise dominates Carli's filter, the re-injection filter with "
              "gains tuned for its steady state has a smaller steady-state mean-square error than Carli's filter with "
              "its tuned gain, on the same links and rounds", "inequality", hypotheses=(NOISY, CARLI_NOISE, STABLE),
              requires=[(lambda res: {"carli", "reinjection"} <= set(res.design.gains),
                         "Carli's or the re-injection filter does not run on this scenario")])
def reinjection_beats_carli(res) -> Verdict:
    g = res.design.gains
    rein, carli = g["reinjection"]["steady_mse"], g["carli"]["steady_mse"]
    m = res.design.model
    tol, how = roundoff_tolerance(scale=carli, operations=float((m.N * m.n) ** 2), condition=1.0 / max(
        1e-300, 1 - max(g["reinjection"]["rho"], g["carli"]["rho"])))
    extra = ""
    k = res.scenario.simulation.eval_step
    if "carli" in res.mc and "reinjection" in res.mc:
        sr, sc_ = res.stats("reinjection"), res.stats("carli")
        i = res.eval_index
        extra = (f" At step {k}: Monte Carlo network MSE {sr.mse[i].mean():.6g} (re-injection) and "
                 f"{sc_.mse[i].mean():.6g} (Carli)")
        if "reinjection" in res.exact and "carli" in res.exact:
            extra += (f", exact {res.exact['reinjection']['mse'][k].mean():.6g} and "
                      f"{res.exact['carli']['mse'][k].mean():.6g}")
        extra += "."
    return inequality(rein, carli, tolerance=tol, detail=(
        f"exact steady-state network MSE of the re-injection filter (ℓ = {g['reinjection']['scale']:.4g}, ζ = "
        f"{g['reinjection']['zeta']:.4g}) against Carli's (ℓ = {g['carli']['scale']:.4g}), same rounds and links; "
        f"{how}.{extra}"))


@claims.claim("compare.kar_moura.random_sensor_law", "Kar & Moura Thm 10(i) and its proof", "weak consensus: "
              "the conditional covariance at a uniformly random sensor has, at every step, the law of Riccati iterates "
              "along a stationary token walk with the mean communication kernel (20), which converges to one "
              "invariant law under weak detectability", "statistical", hypotheses=(C1, D1, S1),
              requires=[(lambda res: {"gikf", "chain"} <= set(res.token), "the GIKF does not run"),
                        (lambda res: res.token["gikf"].shape[1] >= MIN_TRIALS_KS,
                         lambda res: f"needs ≥ {MIN_TRIALS_KS} trials per sample; ran {res.token['gikf'].shape[1]}")])
def random_sensor_law(res) -> Verdict:
    a, b = res.token["gikf"], res.token["chain"]
    ps, stats_, parts = [], [], []
    for t, (x, y) in enumerate(zip(a, b)):
        if not (_finite(x) and _finite(y)):
            return not_checkable("covariance traces not finite")
        r = ks_test(x, y)
        ps.append(r.pvalue)
        stats_.append(r.statistic)
        parts.append(f"k = {token_times(res.scenario)[t]}: D = {r.statistic:.4f}, medians {np.median(x):.5g} / "
                     f"{np.median(y):.5g}")
    k = int(np.argmin(ps))
    return p_value_test(ps, trials=a.shape[1], measured=float(stats_[k]), reference=0.0, detail=(
        "two-sample Kolmogorov-Smirnov test of tr P̂_q(k) (GIKF, q a uniformly random sensor independent of the "
        "communication) against tr P̃(k) of the token chain (20) driven by an independent copy of the communication "
        "(conservative where the laws have atoms): " + "; ".join(parts) + "."))




# -- a plug-in filter's claims (dse.plugin): the built-ins' checks, one claim each, for every plug-in ------------

def plugins_of(where) -> list[tuple[str, str]]:
    """(label, name) of the plug-in filters of the run's scenario."""
    return [(name, name) for sc in where.run.scenarios for name in sc.plugin_names]


def _ran(res, name: str) -> bool:
    return name in res.mc


def _failed(res, name: str) -> str:
    return f"it failed: {res.faults[name]}" if name in res.faults else "it does not apply to this scenario"


_RAN = (_ran, _failed)
_CENTRAL = (lambda res, name: "central" in res.mc, "the centralized filter does not run")
_Z_TRIALS = (lambda res, name: res.trials >= MIN_TRIALS_Z,
             lambda res, name: f"needs ≥ {MIN_TRIALS_Z} trials for the normal z-test; ran {res.trials}")


@claims.claim("compare.plugin.{item}.orthogonality", "orthogonality principle", "the centralized filter's error is "
              "orthogonal to the plug-in filter {item}'s distance from it (its estimates use only the measurements and "
              "the links), so its excess mean-square error over the centralized filter is its mean-square distance to "
              "it", "statistical", each=plugins_of, confidence_group="plugin:{item}",
              requires=[_RAN, _CENTRAL, _Z_TRIALS])
def plugin_orthogonality(res, name: str) -> Verdict:
    return _orthogonality(res, [name])


@claims.claim("compare.plugin.{item}.lower_bound", "optimality of the centralized filter", "the plug-in filter "
              "{item} has no smaller mean-square error than the centralized Kalman filter, at any node and step",
              "statistical", each=plugins_of, confidence_group="plugin:{item}",
              requires=[_RAN, _CENTRAL, _Z_TRIALS])
def plugin_lower_bound(res, name: str) -> Verdict:
    """One-sided z-test, cell by cell, of the mean over trials of the paired gap ‖x − x̂_i‖² − ‖x − x̂_c‖² (≥ 0
    by the optimality of the centralized filter), beyond twice the orthogonality's round-off allowance (the
    gap is ‖x̂_i − x̂_c‖² + 2 (x − x̂_c)ᵀ(x̂_c − x̂_i))."""
    from scipy.stats import norm

    idx = res.check_indices()
    mean, se = mean_and_se(res.mc[name]["gap"][idx], res.mc[name]["gap2"][idx], res.trials)
    allowance = 2 * _roundoff_allowance(res, idx)
    z = (mean + allowance) / np.maximum(se, 1e-300)           # p = P(a gap this low | true gap 0)
    if not _finite(z):
        return not_checkable("its errors are not finite")
    k = int(np.argmin(np.ravel(mean)))
    central = res.stats("central").mse[idx]
    return p_value_test(np.ravel(norm.cdf(z)), trials=res.trials, measured=float(np.ravel(mean)[k]), reference=0.0,
                        detail=f"mean over trials of ‖x − x̂_i‖² − ‖x − x̂_c‖² at every node, steps "
                               f"{', '.join(str(int(res.steps[i])) for i in idx)} (one-sided normal z-test of the "
                               f"mean of independent paired trials, beyond a round-off allowance of twice the "
                               f"orthogonality's); smallest mean gap {np.ravel(mean)[k]:.4g} against a centralized "
                               f"MSE of {float(np.ravel(np.broadcast_to(central, mean.shape))[k]):.4g}.")


@claims.claim("compare.plugin.{item}.nees", "consistency of the filter's covariance", "the covariance the plug-in "
              "filter {item} reports is what it declares: its error's covariance given the link draws (two-sided χ² "
              "test of the NEES), or an upper bound of it (one-sided)", "statistical", each=plugins_of,
              confidence_group="plugin:{item}",
              requires=[_RAN, (lambda res, name: res.design.estimators[name].spec.covariance_law is not None,
                               "it declares no covariance (covariance_law = None)")])
def plugin_nees(res, name: str) -> Verdict:
    from scipy.stats import chi2

    B, n = res.trials, res.design.model.n
    idx = res.check_indices()
    total = np.asarray(res.mc[name]["nees"][idx], float)
    if not _finite(total):
        return not_checkable("its NEES is not finite")
    law = res.design.estimators[name].spec.covariance_law
    p = chi2_two_sided_p(total, B * n) if law == "conditional" else chi2.sf(total, B * n)
    return p_value_test(np.ravel(p), trials=B, measured=float(np.max(total) / B if law == "bound" else
                                                              total.mean() / B), reference=float(n), detail=(
        f"declared covariance_law = {law!r}: the sum over independent trials of e_iᵀ P_i⁻¹ e_i is χ²(trials·n) "
        "when P_i is the error's conditional covariance (two-sided test) and stochastically smaller when it bounds "
        "it (one-sided); every node, steps " + ", ".join(str(int(res.steps[i])) for i in idx) + "."))


@claims.claim("compare.plugin.{item}.exact_moments", "exact moment recursion", "the exact second moments of the "
              "plug-in filter {item}, from the matrices it declares (linear filters, reliable links), agree with the "
              "simulation", "statistical", each=plugins_of, confidence_group="plugin:{item}",
              requires=[_RAN, (lambda res, name: name in res.exact,
                               lambda res, name: res.faults.get(name) or res.design.estimators[name].exact_reason
                               or "no exact moments")])
def plugin_exact(res, name: str) -> Verdict:
    return _exact_claim(res, [name])
