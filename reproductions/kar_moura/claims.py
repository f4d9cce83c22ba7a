"""The claim catalogue of Kar & Moura's GIKF paper (spec §7, R1-R23, and the examples E1-E8).

Claims are built per scenario (id suffix = scenario name). Which claims a scenario gets
depends on its assumption checks: the theorem's conclusions are tested where C.1 and D.1
hold; where they fail and a class of Ā cannot detect an unstable mode, the predicted
divergence is tested instead (negative controls); the weak-consensus identity is tested
everywhere (it is a property of the swap structure, spec addendum).

Statistical tests: one sample per independent run, α = 1e-3 per family with Holm's correction;
a family passes when no test in it rejects (claims of agreement) or when every test rejects
(claims that two laws differ). Every verdict states the sample sizes and the smallest p-value.
"""
from __future__ import annotations

import math
from typing import Callable

import numpy as np
from scipy import stats

import estimators.gossip_kalman as gk
import estimators.switched_riccati as sr
import estimators.walk_detectability as wd
from pipeline.verify import ERRATUM, FAIL, NOT_CHECKABLE, PASS, Claim, Verdict, identity, inequality, not_checkable

from .compute import J_GRID, WITNESS_MAX_LEN, Results, ScenarioResults, chain_sampler

PAPER = "kar-moura"
ALPHA = 1e-3
LOEWNER_TOL = 1e-9
FEAT = {name: i for i, name in enumerate(gk.FEATURES)}
KS_FEATURES = ("log_trace", "log_lam_max", "log_lam_min", "log_det")


# -- statistics helpers ---------------------------------------------------------------------------------

def holm(pvalues: np.ndarray, alpha: float = ALPHA) -> np.ndarray:
    """Rejections under Holm's step-down procedure."""
    p = np.asarray(pvalues, float)
    order = np.argsort(p)
    reject = np.zeros(len(p), bool)
    for rank, i in enumerate(order):
        if p[i] <= alpha / (len(p) - rank):
            reject[i] = True
        else:
            break
    return reject


def _ks(a: np.ndarray, b: np.ndarray):
    """Two-sample KS with the asymptotic p-value (samples here are >= 100 per side; the exact
    method's failure with ties would otherwise be a warning)."""
    return stats.ks_2samp(a, b, method="asymp")


def _finite(a: np.ndarray) -> np.ndarray:
    a = np.asarray(a, float)
    return a[np.isfinite(a)]


#: the smallest sample (each side) a KS test is run on; smaller ones are reported, not tested
MIN_KS_SAMPLE = 20


def ks_agree(tests: list[tuple[str, np.ndarray, np.ndarray]], what: str) -> Verdict:
    """Pass iff no two-sample KS test of the family rejects at family-wise α (Holm). Tests with a
    sample under MIN_KS_SAMPLE are left out and named (e.g. a law conditioned on a rare event in a
    large network); with none left the claim is not checkable."""
    small = [(label, len(_finite(a)), len(_finite(b))) for label, a, b in tests
             if min(len(_finite(a)), len(_finite(b))) < MIN_KS_SAMPLE]
    tests = [t for t in tests if min(len(_finite(t[1])), len(_finite(t[2]))) >= MIN_KS_SAMPLE]
    skipped = ("" if not small else f" Left out (a sample under {MIN_KS_SAMPLE}): "
               + "; ".join(f"{label} (n = {na} vs {nb})" for label, na, nb in small) + ".")
    if not tests:
        return not_checkable(f"{what}: every sample is too small for a KS test.{skipped}")
    stat, pv, labels, sizes = [], [], [], []
    for label, a, b in tests:
        a, b = _finite(a), _finite(b)
        r = _ks(a, b)
        stat.append(r.statistic)
        pv.append(r.pvalue)
        labels.append(label)
        sizes.append((len(a), len(b)))
    rej = holm(np.array(pv))
    worst = int(np.argmin(pv))
    lines = "; ".join(f"{l}: D={d:.4f} p={p:.3g}{' REJECT' if r else ''}" for l, d, p, r in zip(labels, stat, pv, rej))
    return Verdict(FAIL if rej.any() else PASS, measured=float(pv[worst]), reference=ALPHA, tolerance=ALPHA,
                   margin=float(np.log10(pv[worst] / ALPHA)) if pv[worst] > 0 else -math.inf,
                   confidence=1 - ALPHA, trials=int(min(min(s) for s in sizes)),
                   detail=(f"{what}. {len(pv)} two-sample KS tests, Holm at family-wise α = {ALPHA}; smallest p = "
                           f"{pv[worst]:.3g} ({labels[worst]}, n = {sizes[worst][0]} vs {sizes[worst][1]}); "
                           f"{int(rej.sum())} rejected. {lines}.{skipped}"))


def ks_differ(tests: list[tuple[str, np.ndarray, np.ndarray]], what: str) -> Verdict:
    """Pass iff every test of the family rejects equality (Holm)."""
    pv, lines, sizes = [], [], []
    for label, a, b in tests:
        a, b = _finite(a), _finite(b)
        r = _ks(a, b)
        pv.append(r.pvalue)
        sizes.append(min(len(a), len(b)))
        lines.append(f"{label}: D={r.statistic:.4f} p={r.pvalue:.3g}")
    rej = holm(np.array(pv))
    return Verdict(PASS if rej.all() else FAIL, measured=float(max(pv)), reference=ALPHA, tolerance=ALPHA,
                   confidence=1 - ALPHA, trials=int(min(sizes)),
                   detail=f"{what}. Every test must reject at family-wise α = {ALPHA} (Holm); largest p = {max(pv):.3g}. "
                          + "; ".join(lines))


def wilson(k: float, n: int, z: float) -> tuple[float, float]:
    if n == 0:
        return 0.0, 1.0
    p = k / n
    den = 1 + z * z / n
    centre = (p + z * z / (2 * n)) / den
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / den
    return max(0.0, centre - half), min(1.0, centre + half)


def chi_square_gof(counts: np.ndarray, probs: np.ndarray) -> tuple[float, float, int]:
    """Pearson chi-square of counts against probs (cells with zero probability must have zero counts)."""
    counts, probs = np.asarray(counts, float), np.asarray(probs, float)
    if np.any(counts[probs <= 0] > 0):
        return math.inf, 0.0, 0
    keep = probs > 0
    c, e = counts[keep], probs[keep] * counts.sum()
    small = e < 5  # pool cells with expected count < 5 (the chi-square approximation needs it)
    if small.any():
        c = np.append(c[~small], c[small].sum())
        e = np.append(e[~small], e[small].sum())
        if e[-1] == 0:
            c, e = c[:-1], e[:-1]
    exp = e
    stat = float(((c - e) ** 2 / e).sum())
    dof = len(e) - 1
    return stat, float(stats.chi2.sf(stat, dof)) if dof > 0 else 1.0, dof


def feat(arr: np.ndarray, name: str) -> np.ndarray:
    return arr[FEAT[name]]


def _tidx(r: ScenarioResults, t: int, which: str = "gikf") -> int:
    times = list((r.gikf if which == "gikf" else r.reference)["times"])
    return times.index(t)


def _rel_loewner(lower: np.ndarray, upper: np.ndarray) -> np.ndarray:
    """λ_min(upper − lower) / max(1, ‖lower‖, ‖upper‖), batched."""
    scale = np.maximum(1.0, np.maximum(np.linalg.norm(lower, 2, axis=(-2, -1)), np.linalg.norm(upper, 2, axis=(-2, -1))))
    return np.linalg.eigvalsh(upper - lower)[..., 0] / scale


# -- assumption checks ----------------------------------------------------------------------------------

def check_c1(r: ScenarioResults) -> Verdict:
    b = r.bounds
    detail = (f"Ā: irreducible = {bool(b['irreducible'])} ({int(b['n_classes'])} class(es), eigenvalue 1 with multiplicity "
              f"{int(b['unit_multiplicity'])}), aperiodic = {bool(b['aperiodic'])} (λ_min(Ā) = {float(b['min_eig_Abar']):.4f}), "
              f"SLEM = {float(b['slem']):.6f}, relaxation time 1/(1−SLEM) = "
              f"{(1 / (1 - float(b['slem'])) if float(b['slem']) < 1 else math.inf):.1f} slots. Row sums 1 and symmetry "
              f"to {np.abs(b['Abar'].sum(1) - 1).max():.1e} / {np.abs(b['Abar'] - b['Abar'].T).max():.1e}.")
    if not bool(b.get("Abar_exact", True)):
        detail += (f" Ā is a Monte Carlo estimate ({int(b['Abar_draws']):,} matchings; largest standard error "
                   f"{float(b['Abar_se'].max()):.1e}): the SLEM is an estimate; irreducibility and aperiodicity come "
                   f"from the exact support (graph edges, and Ā_nn > 0 as links fail with probability 1 − p_link).")
    ok_struct = np.abs(b["Abar"].sum(1) - 1).max() < 1e-12 and np.abs(b["Abar"] - b["Abar"].T).max() < 1e-12
    expected = r.scenario.expect.get("c1")
    ok = ok_struct and (expected is None or expected == bool(b["c1"]))
    return Verdict(PASS if ok else FAIL, measured=bool(b["c1"]), reference=expected, margin=float(1 - b["slem"]),
                   detail=detail + (f" Expected C.1 = {expected}." if expected is not None else ""))


def check_s1(r: ScenarioResults) -> Verdict:
    sc = r.scenario
    M = sc.M
    Qh = np.linalg.cholesky(sc.Q)
    bad = []
    for lam in np.linalg.eigvals(sc.F):
        if abs(lam) >= 1 - 1e-12:
            rank = np.linalg.matrix_rank(np.hstack([sc.F - lam * np.eye(M), Qh]))
            if rank < M:
                bad.append(lam)
    lone = [n for n in range(sc.N) if r.bounds["sensor_detectable"][n]]
    return Verdict(PASS if not bad else FAIL, measured=float(np.linalg.eigvalsh(sc.Q)[0]), reference=0.0,
                   margin=float(np.linalg.eigvalsh(sc.Q)[0]),
                   detail=(f"Q ≻ 0 (λ_min = {np.linalg.eigvalsh(sc.Q)[0]:.4g}), so (F, Q^½) is stabilisable (PBH on every "
                           f"|λ| ≥ 1 eigenvalue: {len(bad)} failures). Sensors detectable on their own: {lone or 'none'}; "
                           f"(F, C_all) detectable: {bool(r.bounds['central_detectable'])}."))


def check_d1(r: ScenarioResults) -> Verdict:
    b = r.bounds
    w = r.witness()
    obs = bool(b["central_observable"])
    expected = r.scenario.expect.get("d1")
    if w is not None:
        eig = np.linalg.eigvalsh(b["gramian"])
        detail = (f"Witness walk w0 = {w} (ℓ = {len(w)}), found by breadth-first search over Ā-walks "
                  f"({int(b['walks_checked'])} walks checked); Gramian eigenvalues {np.round(eig, 4).tolist()}. "
                  f"Reading of D.1: 'some Ā-walk has an invertible Gramian' (spec §10.14); under the 'walk covering "
                  f"all N nodes' reading D.1 = {bool(b['d1_covering'])}.")
    else:
        detail = (f"No Ā-walk of length ≤ {WITNESS_MAX_LEN} has an invertible Gramian (max rank {int(b['witness_max_rank'])} of "
                  f"{r.scenario.M}; {int(b['walks_checked'])} walks checked).")
    consistent = (w is None) or obs  # (F, C_all) observable is necessary for D.1
    F_inv = abs(np.linalg.det(r.scenario.F)) > 1e-12
    if F_inv and bool(b["c1"]):
        # spec §6.3 [DERIVED]: for invertible F under C.1, D.1 ⟺ (F, C_all) observable
        agree = (w is not None) == obs
        detail += f" F invertible and C.1: D.1 ⟺ (F, C_all) observable (spec §6.3); search and observability agree: {agree}."
        if not agree and obs:
            detail += (f" (F, C_all) is observable, so a witness exists but is longer than the search depth "
                       f"{WITNESS_MAX_LEN}: D.1 holds, the tail bound is not computed.")
    ok = consistent and (expected is None or expected == (w is not None))
    detail += f" (F, C_all) observable: {obs} (necessary for D.1)."
    if expected is not None:
        detail += f" Expected D.1 = {expected}."
    return Verdict(PASS if ok else FAIL, measured=w is not None, reference=expected, detail=detail)


# -- Theorem 10[i]: weak consensus ------------------------------------------------------------------------

def check_weak_consensus(r: ScenarioResults) -> Verdict:
    g, ref = r.gikf, r.reference
    tests = []
    times = [int(t) for t in g["times"] if t >= 3]
    for t in times:
        i, j = _tidx(r, t), _tidx(r, t, "ref")
        for f in KS_FEATURES:
            tests.append((f"t={t} {f}", feat(g["feat_q"][i], f), feat(ref["features"][j], f)))
    v = ks_agree(tests, f"law of P̂ at a uniformly random sensor q ({r.runs} GIKF runs) vs the Theorem-8 process from P0 "
                       f"({r.reference_runs} runs) at t ∈ {times}")
    # exact small-t law by enumeration: chi-square of the GIKF atoms
    sys_ = r.scenario.system()
    extra, worst_p = [], 1.0
    for t in (1, 2):
        if t not in list(g["times"]) or r.scenario.N ** t > 400:
            continue
        if t > 1 and not bool(r.bounds.get("Abar_exact", True)):
            continue  # the t ≥ 2 law needs the exact Ā (t = 1 is uniform over the sensors whatever Ā is)
        atoms, probs = sr.exact_small_t_law(sys_, r.bounds["Abar"], t, r.scenario.P0, decimals=7)
        obs = np.round(feat(g["feat_q"][_tidx(r, t)], "log_trace"), 7)
        counts = np.array([(np.abs(obs - a) < 5e-7).sum() for a in atoms])
        unmatched = len(obs) - counts.sum()
        stat, p, dof = chi_square_gof(counts, probs)
        if unmatched:
            p = 0.0
        worst_p = min(worst_p, p)
        extra.append(f"t={t}: {len(atoms)} atoms, chi2 = {stat:.2f} (dof {dof}), p = {p:.3g}, unmatched samples {unmatched}")
    if extra:
        ok = v.status == PASS and worst_p > ALPHA / 2
        v = Verdict(PASS if ok else FAIL, measured=min(v.measured, worst_p), reference=ALPHA, tolerance=ALPHA,
                    margin=v.margin, confidence=v.confidence, trials=v.trials,
                    detail=v.detail + " Exact finite-t law by path enumeration (probabilities (1/N)ΠĀ): " + "; ".join(extra)
                    + ". The identity law(P̂_q(t)) = law(P̃(t)) holds at every t (spec R7, from (60)-(67)); it is a "
                      "property of the swap structure and holds whether or not C.1/D.1 do.")
    return v


def check_per_sensor(r: ScenarioResults) -> Verdict:
    """R7b: sensor n has the law of P̃(t) given p̃(t-1) = n; the per-sensor laws differ from each other and from μ."""
    g, ref = r.gikf, r.reference
    sys_ = r.scenario.system()
    agree, differ = [], []
    T = int(g["times"][-1])
    mid = [t for t in g["times"] if t >= 10]
    for t in sorted({mid[0], T} if mid else {T}):
        i, j = _tidx(r, t), _tidx(r, t, "ref")
        last = ref["last"][j]
        for n in sorted({0, min(1, r.scenario.N - 1)}):
            agree.append((f"t={t} sensor {n} vs μ_t | p̃(t−1)={n}", feat(g["feat_n"][i][:, :, n], "log_trace"),
                          feat(ref["features"][j], "log_trace")[last == n]))
    i, j = _tidx(r, T), _tidx(r, T, "ref")
    # the laws differ where the sensors' own maps differ: gate on the exact t = 1 atoms tr f_n(P0)
    atoms = np.array([np.trace(gk.riccati_step(r.scenario.P0, sys_.C[n], sys_.R[n], sys_.F, sys_.Q)) for n in range(r.scenario.N)])
    # the pair compared is the two sensors whose own maps differ most at t = 1 (a property of the
    # model: in E1 sensors 0 and 1; where two sensor types differ only slightly, e.g. E9's types 0
    # and 1, a fixed pair would test a tiny effect with little power)
    lo_n, hi_n = int(np.argmin(atoms)), int(np.argmax(atoms))
    if r.scenario.N > 1 and atoms[hi_n] - atoms[lo_n] > 1e-9 * atoms.max():
        a_, b_ = sorted((lo_n, hi_n))
        differ.append((f"t={T} sensor {a_} vs sensor {b_}", feat(g["feat_n"][i][:, :, a_], "log_trace"),
                       feat(g["feat_n"][i][:, :, b_], "log_trace")))
    for n in sorted({0, min(1, r.scenario.N - 1)}):
        if np.ptp(atoms) > 1e-9 * atoms.max():
            differ.append((f"t={T} sensor {n} vs unconditional μ_t", feat(g["feat_n"][i][:, :, n], "log_trace"),
                           feat(ref["features"][j], "log_trace")))
    va = ks_agree(agree, "each sensor's law equals the Theorem-8 law conditioned on the last switch (spec R7b, DERIVED)")
    if not differ:
        return va
    pv = np.array([_ks(_finite(a), _finite(b)).pvalue for _, a, b in differ])
    rej = holm(pv)
    pair = [i for i, (l, _, _) in enumerate(differ) if "unconditional" not in l]
    vs_mu = [i for i in range(len(differ)) if i not in pair]
    ok_d = (all(rej[i] for i in pair)) and (not vs_mu or any(rej[i] for i in vs_mu))
    vd = Verdict(PASS if ok_d else FAIL, detail=(
        "per-sensor laws differ (weak consensus is consensus of the mixture only): the two sensors whose own maps differ "
        "most (largest gap between tr f_n(P0)) must differ, and at least one sensor must differ from μ_t, Holm at α = 0.001: "
        + "; ".join(f"{l}: p={p:.3g}{' REJECT' if x else ''}" for (l, _, _), p, x in zip(differ, pv, rej))))
    if va.status == NOT_CHECKABLE:  # the conditional laws cannot be tested: neither can the claim as a whole
        return not_checkable(va.detail + " || " + vd.detail)
    ok = va.status == PASS and vd.status == PASS
    return Verdict(PASS if ok else FAIL, measured=va.measured, reference=ALPHA, confidence=1 - ALPHA, trials=va.trials,
                   detail=va.detail + " || " + vd.detail)


def check_eq29(r: ScenarioResults) -> Verdict:
    """(29) with equality for continuity sets: Σ_n P(P̂_n(t) ∈ S) = N μ_t(S), S = {log tr ≥ a}."""
    g, ref = r.gikf, r.reference
    T = int(g["times"][-1])
    i, j = _tidx(r, T), _tidx(r, T, "ref")
    mu = feat(ref["features"][j], "log_trace")
    sens = feat(g["feat_n"][i], "log_trace")  # (B, N)
    N = r.scenario.N
    zs, lines = [], []
    for qlev in (0.5, 0.9, 0.99):
        a = np.quantile(mu, qlev)
        pn = (sens >= a).mean(axis=0)
        lhs = pn.sum()
        m = (mu >= a).mean()
        # runs are independent; sensors within a run are not: use the per-run count's variance
        per_run = (sens >= a).sum(axis=1)
        se = math.sqrt(per_run.var(ddof=1) / len(per_run) + N * N * m * (1 - m) / len(mu))
        z = (lhs - N * m) / max(se, 1e-300)
        zs.append(z)
        lines.append(f"S = {{log tr ≥ μ q{qlev}}}: Σ_n p̂_n = {lhs:.4f} vs N μ̂(S) = {N * m:.4f} (z = {z:.2f})")
    zcrit = stats.norm.ppf(1 - ALPHA / (2 * len(zs)))
    worst = float(np.max(np.abs(zs)))
    return Verdict(PASS if worst <= zcrit else FAIL, measured=worst, reference=zcrit, tolerance=zcrit,
                   margin=float(zcrit - worst), confidence=1 - ALPHA, trials=r.runs,
                   detail=(f"(29) read as an equality for continuity sets at t = {T} (spec R10: the sum of limsups "
                           f"is not what §VI-B proves; equality follows from R7b). " + "; ".join(lines)))


# -- centralized reference --------------------------------------------------------------------------------

def check_filterpy(r: ScenarioResults) -> Verdict:
    b = r.bounds
    ours, fp = b["P_central"], b["P_central_filterpy"]
    scale = np.maximum(1.0, np.linalg.norm(fp, 2, axis=(-2, -1)))[:, None, None]
    v = identity(ours / scale, fp / scale, rtol=0, atol=1e-10,
                 detail=f"centralized prior covariance P_c(t), t = 0..{len(ours) - 1}: batched Joseph recursion vs "
                        f"filterpy.kalman.KalmanFilter (update then predict), relative to max(1, ‖P‖)")
    if "P_central_inf" in b and r.slots >= 100:
        dare = b["P_central_inf"]
        err = float(np.abs(ours[-1] - dare).max() / max(1.0, np.abs(dare).max()))
        ok = v.status == PASS and err < 1e-8
        return Verdict(PASS if ok else FAIL, measured=v.measured, reference=v.reference, tolerance=1e-10, margin=v.margin,
                       detail=v.detail + f"; P_c(T) vs scipy solve_discrete_are: relative error {err:.2e} (tol 1e-8); "
                                         f"P_c∞ diagonal {np.round(np.diag(dare), 5).tolist()}")
    return v


def check_domination(r: ScenarioResults) -> Verdict:
    """Every sensor's covariance dominates the centralized one: P̂_n(t) ⪰ P_c(t) pathwise (same P0)."""
    g, b = r.gikf, r.bounds
    m = float(np.nanmin(g["margins"][:, 0]))
    ref_final = r.reference.get("final")
    extra = ""
    if ref_final is not None:
        ref_m = float(_rel_loewner(b["P_central"][-1], ref_final).min())
        m_all = min(m, ref_m)
        extra = f"; Theorem-8 samples at T vs P_c(T): {ref_m:.3e}"
    else:
        m_all = m
    if "P_central_inf" in b:
        dom = float(_rel_loewner(b["P_central_inf"], ref_final).min()) if ref_final is not None else math.nan
        extra += f"; μ-sample vs steady state P_c∞: {dom:.3e} (P_c∞ is a valid lower bound only in the limit)"
    gap = np.nanmin(g["margins"][1:, 0]) if len(g["margins"]) > 1 else math.nan
    return Verdict(PASS if m_all >= -LOEWNER_TOL else FAIL, measured=m_all, reference=-LOEWNER_TOL, tolerance=LOEWNER_TOL,
                   margin=m_all + LOEWNER_TOL,
                   detail=(f"min over runs (first 1000), sensors and slots (every {5}th) of λ_min(P̂_n(t) − P_c(t)) / "
                           f"max(1, ‖P̂‖): {m:.3e} (t ≥ 1: {gap:.3e}){extra}. Each token uses a subset of the "
                           f"centralized observations and Riccati maps are monotone (spec §6.6, R21)."))


# -- stochastic boundedness, tails -------------------------------------------------------------------------

def _exceed_curve(r: ScenarioResults, t0: int) -> np.ndarray:
    """S_n(J) = max_{t0 ≤ t ≤ T} P̂(‖P̂_n(t)‖ ≥ J), shape (N, len(J_GRID))."""
    ex = r.gikf["exceed"].astype(float)
    rows = [t for t in range(t0, ex.shape[0]) if ex[t, 0, 0] >= 0]
    return ex[rows].max(axis=0) / r.runs


def check_bounded(r: ScenarioResults) -> Verdict:
    g, ref = r.gikf, r.reference
    if int(g["overflow"]) >= 0:
        return Verdict(FAIL, measured=int(g["overflow"]), detail=f"covariances overflowed float64 at slot {int(g['overflow'])}")
    N = r.scenario.N
    S = _exceed_curve(r, 1)
    mu_lam = np.exp(feat(ref["features"][-1], "log_lam_max"))
    J_star = N * np.quantile(mu_lam, 0.999)
    k = int(np.searchsorted(J_GRID, J_star))
    if k >= len(J_GRID):
        return not_checkable(f"N × μ̂ q0.999 = {J_star:.3g} is beyond the J grid")
    s_at = S[:, k]
    lo, hi = wilson(s_at.max() * r.runs, r.runs, stats.norm.ppf(1 - ALPHA))
    ok_level = lo <= 0.01
    # (27) exact form: P(P̂_n(T) ∈ S) ≤ N μ_T(S) for S = {‖X‖ ≥ J}
    lam_T = np.exp(feat(g["feat_n"][-1], "log_lam_max"))  # (B, N)
    zs = []
    for J in J_GRID[::4]:
        pn = (lam_T >= J).mean(axis=0)
        m = (mu_lam >= J).mean()
        se = np.sqrt(pn * (1 - pn) / r.runs + N * N * m * (1 - m) / len(mu_lam))
        zs.append(((pn - N * m) / np.maximum(se, 1e-12)).max())
    zcrit = stats.norm.ppf(1 - ALPHA / (len(zs) * N))
    ok27 = max(zs) <= zcrit
    mono = bool(np.all(np.diff(S, axis=1) <= 1e-12))
    ok = ok_level and ok27 and mono
    return Verdict(PASS if ok else FAIL, measured=float(s_at.max()), reference=0.01, margin=float(0.01 - lo),
                   confidence=1 - ALPHA, trials=r.runs,
                   detail=(f"(26): S_n(J) = max_{{1 ≤ t ≤ {r.slots}}} P̂(‖P̂_n(t)‖ ≥ J) (every {5}th slot) is non-increasing in J "
                           f"({mono}); at J = N·μ̂ q0.999(‖X‖) = {J_star:.4g} (grid J = {J_GRID[k]:.4g}) max_n S_n = "
                           f"{s_at.max():.4f} (Wilson {1 - ALPHA:.3f} interval [{lo:.4f}, {hi:.4f}], required ≤ 0.01). "
                           f"S_n(J) at J = 1e2, 1e4, 1e6: {[round(float(S[:, np.searchsorted(J_GRID, x)].max()), 4) for x in (1e2, 1e4, 1e6)]}. "
                           f"(27) exact form P(‖P̂_n(T)‖ ≥ J) ≤ N μ̂_T(‖X‖ ≥ J) on {len(zs)} thresholds × {N} sensors: "
                           f"max z = {max(zs):.2f} ≤ {zcrit:.2f}: {ok27}. Only finite horizons are checked; means are not "
                           f"claimed (they may be infinite)."))


def check_divergence(r: ScenarioResults) -> Verdict:
    """Negative control: sensors in a class of Ā that cannot detect an unstable mode diverge at
    the predicted rate 2 log|λ|; the others (if any) stay bounded."""
    g, b = r.gikf, r.bounds
    rate = b["divergence_rate"]
    q = g["quantiles"]  # (T+1, N, len(QUANTILES)), log tr
    T = q.shape[0] - 1
    if int(g["overflow"]) >= 0:
        return Verdict(PASS, measured=int(g["overflow"]), detail=f"diverged beyond float64 at slot {int(g['overflow'])}")
    t = np.arange(T // 2, T + 1)
    med = q[T // 2:, :, gk.QUANTILES.index(0.5)]
    slopes = np.array([np.polyfit(t, med[:, n], 1)[0] for n in range(r.scenario.N)])
    div = rate > 0
    rel = np.abs(slopes[div] - rate[div]) / rate[div]
    ok_div = bool(div.any() and rel.max() < 0.02)
    frac = (g["exceed"][T][:, np.searchsorted(J_GRID, 1e6)] / r.runs)
    detail = (f"predicted: log tr P̂_n grows like 2 log|λ_unobs| per slot at sensors whose Ā-class cannot detect λ. "
              f"Fitted slope of the median of log tr P̂_n(t) over t ∈ [{T // 2}, {T}] vs prediction: "
              + "; ".join(f"sensor {n}: {slopes[n]:.5f} vs {rate[n]:.5f}" for n in np.flatnonzero(div))
              + f" (max relative difference {rel.max() if div.any() else math.nan:.2e}, tolerance 0.02). "
              f"Fraction of runs with ‖P̂_n(T)‖ ≥ 1e6 at diverging sensors: min {frac[div].min() if div.any() else math.nan:.3f}.")
    ok_bnd = True
    if (~div).any() and div.any():
        q90 = q[T // 2:, :, gk.QUANTILES.index(0.95)]
        flat = np.array([max(abs(slopes[n]), abs(np.polyfit(t, q90[:, n], 1)[0])) for n in np.flatnonzero(~div)])
        limit = 0.1 * rate[div].min()
        ok_bnd = bool(flat.max() < limit)
        detail += (f" Sensors in detectable classes {np.flatnonzero(~div).tolist()} stay bounded: largest |slope| of the median "
                   f"and q0.95 of log tr over the second half {flat.max():.4f} per slot (must be < 10% of the smallest predicted "
                   f"rate, {limit:.4f}); fraction with ‖P̂‖ ≥ 1e6 at T: {frac[~div].max():.4f}.")
    return Verdict(PASS if ok_div and ok_bnd else FAIL, measured=float(slopes[div].max()) if div.any() else None,
                   reference=float(rate[div].max()) if div.any() else None, tolerance=0.02,
                   margin=float(0.02 - rel.max()) if div.any() else None, trials=r.runs, detail=detail)


def check_lemma15(r: ScenarioResults) -> Verdict:
    b, ref = r.bounds, r.reference
    lam = np.exp(feat(ref["features"][-1], "log_lam_max"))
    n = len(lam)
    z = stats.norm.ppf(1 - ALPHA / len(J_GRID))
    worst, lines, ratios = math.inf, [], []
    for J, bs, bm in zip(J_GRID, b["beta_single"], b["beta_multi"]):
        k = int((lam > J).sum())
        lo, _ = wilson(k, n, z)
        bound = min(bs, bm) if np.isfinite(bm) else bs
        worst = min(worst, bound - lo)
        if J in J_GRID[::8]:
            lines.append(f"J={J:.0e}: empirical {k / n:.2e}, single-walk β {bs:.3g}, all-walks β {bm:.3g}")
        if k:
            ratios.append(bm / (k / n) if np.isfinite(bm) else math.nan)
    return Verdict(PASS if worst >= 0 else FAIL, measured=float(worst), reference=0.0, margin=float(worst),
                   confidence=1 - ALPHA, trials=n,
                   detail=(f"P(‖P̃(T)‖ > J) ≤ β_T(J) (Lemma 15, off-by-one fixed (125)/(128); β = probability that the "
                           f"stationary chain window of k(J)+ℓ nodes misses the witness, killed-chain recursion) at "
                           f"T = {r.slots}, {n} Theorem-8 runs, Wilson lower bounds (Bonferroni over {len(J_GRID)} J). "
                           f"α0 = {float(b['alpha0']):.4f} (multi-walk {float(b['alpha0_multi']):.4f}), α = ‖F‖ = "
                           f"{float(b['alpha']):.4f}. Smallest slack β − lower bound = {worst:.3g}. "
                           + "; ".join(lines)
                           + (f". All-walks bound / empirical tail: median {np.nanmedian(ratios):.2f}"
                              if ratios and np.isfinite(ratios).any() else "")))


# -- Theorem 8 / 10[ii] --------------------------------------------------------------------------------

def check_initial_law(r: ScenarioResults) -> Verdict:
    ref, aux = r.reference, r.aux
    tests = []
    for label in ("zero", "huge", "wishart"):
        for f in KS_FEATURES:
            tests.append((f"ν={label} {f}", feat(aux[f"init_{label}"], f), feat(ref["features"][-1], f)))
    v = ks_agree(tests, f"Theorem 8: P̃(T) at T = {r.slots} from ν ∈ {{δ_0, δ_1e6·I, Wishart(M+2, I)}} vs from δ_P0")
    gap = aux["coupling"]
    q99 = np.quantile(gap, 0.99, axis=1)
    cpl = "; ".join(f"t={t}: median {np.median(gap[i]):.1e}, q99 {q99[i]:.1e}" for i, t in enumerate(aux["coupling_times"]))
    burn = next((int(t) for t, q in zip(aux["coupling_times"], q99) if q < 1e-8), None)
    detail = v.detail + f". Burn-in diagnostic (same switching from 0 and 1e6·I, relative gap): {cpl}; q99 < 1e-8 from t = {burn}."
    ok = v.status == PASS
    return Verdict(PASS if ok else FAIL, measured=v.measured, reference=ALPHA, tolerance=ALPHA, margin=v.margin,
                   confidence=v.confidence, trials=v.trials, detail=detail)


def check_token_domination(r: ScenarioResults) -> Verdict:
    """(23)-(25): limsup_t P(P_n(t) ∈ S) ≤ μ(S) for upward-closed S. Under periodicity (E7) the
    spec predicts failure: the token alternates and limsup = 1 > μ(S) = 1/2."""
    ref, aux = r.reference, r.aux
    times = list(ref["times"])
    mu_t = feat(ref["features"][-1], "log_trace")
    T = times[-1]
    zs, lines = [], []
    for n in sorted({0, min(1, r.scenario.N - 1)}):
        tok = aux[f"token{n}"]
        for t in (times[-2], T):
            x = feat(tok[times.index(t)], "log_trace")
            mu = feat(ref["features"][times.index(t)], "log_trace")
            for qlev in (0.5, 0.9, 0.99):
                a = np.quantile(mu_t, qlev)
                p, m = (x >= a).mean(), (mu >= a).mean()
                se = math.sqrt(p * (1 - p) / len(x) + m * (1 - m) / len(mu))
                zs.append((p - m) / max(se, 1e-12))
                lines.append(f"token {n} t={t} S=log tr ≥ μ q{qlev}: {p:.4f} vs μ̂ {m:.4f}")
    zcrit = stats.norm.ppf(1 - ALPHA / len(zs))
    worst = float(max(zs))
    held = worst <= zcrit
    periodic = not bool(r.bounds["aperiodic"])
    if periodic:
        status = PASS if not held else FAIL
        statement = (f"PREDICTED FAILURE (Ā periodic): the token's probability exceeds μ(S) significantly (max z = {worst:.1f} "
                     f"> {zcrit:.2f}) as the spec predicts for E7: {not held}. ")
    else:
        status = PASS if held else FAIL
        statement = f"one-sided z-tests (Bonferroni over {len(zs)}): max z = {worst:.2f} ≤ {zcrit:.2f}. "
    return Verdict(status, measured=worst, reference=zcrit, tolerance=zcrit, margin=float(zcrit - worst) if not periodic else float(worst - zcrit),
                   confidence=1 - ALPHA, trials=len(feat(aux['token0'][0], 'log_trace')),
                   detail=statement + "; ".join(lines) + ". Observed (not claimed by the paper): the token laws approach μ "
                                                        "(equality), spec R8.")


def check_periodic_orbit(r: ScenarioResults) -> Verdict:
    """E7: with A(t) = swap at every slot, both covariances settle on a 2-periodic orbit (spec: traces 1.8841, 2.1634)."""
    sys_ = r.scenario.system()
    X = [r.scenario.P0.copy() for _ in range(r.scenario.N)]
    for t in range(400):
        X = [gk.riccati_step(X[1 - n] if t > 0 else X[n], sys_.C[n], sys_.R[n], sys_.F, sys_.Q) for n in range(2)]
    traces = sorted(float(np.trace(x)) for x in X)
    v = identity(traces, [1.8841, 2.1634], rtol=0, atol=6e-5, detail="spec §12 values (4 decimals)")
    g = r.gikf
    tr = g["path_trace"][0, -2:, 0]
    return Verdict(v.status, measured=traces, reference=[1.8841, 2.1634], tolerance=6e-5, margin=v.margin,
                   detail=v.detail + f"; GIKF sample path at sensor 0, last two slots: {np.round(tr, 4).tolist()}")


# -- Riccati-map lemmas ----------------------------------------------------------------------------------

def _random_psd(rng, size, M, log_scale=(-2, 8)):
    Z = rng.standard_normal((size, M, M + 2))
    X = Z @ np.swapaxes(Z, -1, -2) / (M + 2)
    return X * (10.0 ** rng.uniform(*log_scale, size))[:, None, None]


def _compose(sys_, X, seq):
    for n in seq:
        X = gk.riccati_step(X, sys_.C[n], sys_.R[n], sys_.F, sys_.Q)
    return X


def check_lemma11(r: ScenarioResults) -> Verdict:
    """Lemma 11 [ii] order preserving, [iii] strong sublinearity with margin (1−λ)Q, and concavity of each f_n."""
    sys_ = r.scenario.system()
    rng = np.random.default_rng(11)
    M, N = sys_.M, sys_.N
    worst = {"monotone": math.inf, "sublinear": math.inf, "concave": math.inf, "f_n ⪯ f_0": math.inf}
    for length in (1, 2, 5, 20):
        seq = rng.integers(0, N, length)
        X = _random_psd(rng, 300, M)
        D = np.diag([0.0] + [1.0] * (M - 1))
        X[:50] = D @ X[:50] @ D  # rank-deficient
        Z = _random_psd(rng, 300, M)
        # round-off accumulates over the composition: the spec's per-comparison tolerance is applied per map
        worst["monotone"] = min(worst["monotone"], _rel_loewner(_compose(sys_, X, seq), _compose(sys_, X + Z, seq)).min() / length)
        Xp = X[50:] + 1e-3 * np.eye(M)
        lam = rng.uniform(0.05, 0.95, len(Xp))[:, None, None]
        lhs = _compose(sys_, lam * Xp, seq) - lam * _compose(sys_, Xp, seq) - (1 - lam) * sys_.Q
        scale = np.maximum(1.0, np.linalg.norm(_compose(sys_, Xp, seq), 2, axis=(-2, -1)))
        worst["sublinear"] = min(worst["sublinear"], (np.linalg.eigvalsh(lhs)[:, 0] / scale).min() / length)
    for n in range(N):
        X, Y = _random_psd(rng, 300, M), _random_psd(rng, 300, M)
        lam = rng.uniform(0, 1, 300)[:, None, None]
        f = lambda A: gk.riccati_step(A, sys_.C[n], sys_.R[n], sys_.F, sys_.Q)
        worst["concave"] = min(worst["concave"], _rel_loewner(lam * f(X) + (1 - lam) * f(Y), f(lam * X + (1 - lam) * Y)).min())
        worst["f_n ⪯ f_0"] = min(worst["f_n ⪯ f_0"], _rel_loewner(f(X), gk.lyapunov_step(X, sys_.F, sys_.Q)).min())
    m = min(worst.values())
    return Verdict(PASS if m >= -LOEWNER_TOL else FAIL, measured=float(m), reference=-LOEWNER_TOL, tolerance=LOEWNER_TOL,
                   margin=float(m + LOEWNER_TOL),
                   detail=("relative Loewner margins (λ_min of the difference / max(1, ‖·‖), divided by the composition "
                           "length for compositions, as round-off accumulates per map) over random PSD X with scales "
                           "10^U(−2, 8), rank-deficient cases and random compositions of length 1-20: "
                           + ", ".join(f"{k} {v:.2e}" for k, v in worst.items())
                           + ". Strong sublinearity is checked with its explicit margin φ(λX) − λφ(X) ⪰ (1−λ)Q (spec R11)."))


def check_lemma14(r: ScenarioResults) -> Verdict:
    b = r.bounds
    w = r.witness()
    sys_ = r.scenario.system()
    rng = np.random.default_rng(14)
    X = _random_psd(rng, 2000, sys_.M)
    X = np.concatenate([X, np.array([c * np.eye(sys_.M) for c in (1e2, 1e4, 1e6, 1e8)])])
    m = float(_rel_loewner(wd.compose_walk(sys_, w, X), b["sigma_sub"]).min())
    lam = np.linalg.eigvalsh(b["g_of_cI"])[:, -1]
    mono = bool(np.all(np.diff(lam) >= -1e-9 * lam[-1]))
    return Verdict(PASS if m >= -LOEWNER_TOL and mono else FAIL, measured=m, reference=-LOEWNER_TOL, tolerance=LOEWNER_TOL,
                   margin=m + LOEWNER_TOL,
                   detail=(f"g_w0(X) ⪯ Σ_sub for 2004 X (Wishart scaled 10^U(−2, 8) and c·I up to 1e8), w0 = {w}: smallest "
                           f"relative margin {m:.3e}. Σ_sub = {np.round(b['sigma_sub'], 4).tolist()}, α0 = λ_max(Σ_sub) = "
                           f"{float(b['alpha0']):.4f}; λ_max g_w0(c·I) for c = 1e2..1e8: {np.round(lam, 5).tolist()} "
                           f"(non-decreasing: {mono}); tightness α0 / λ_max g(1e8 I) = {float(b['alpha0']) / lam[-1]:.5f}."))


def check_lemma14_printed(r: ScenarioResults) -> Verdict:
    """(118)/(120) as printed drop Σ_s F^{ℓ−s} w_s: the printed covariance F^ℓ G̃⁻¹ F^ℓᵀ is not a bound."""
    b = r.bounds
    sup = float(np.linalg.eigvalsh(b["g_of_cI"][-1])[-1])
    printed = float(np.linalg.eigvalsh(b["sigma_sub_printed"])[-1])
    corrected = float(b["alpha0"])
    p_margin = float(_rel_loewner(b["g_of_cI"][-1], b["sigma_sub_printed"]))
    c_margin = float(_rel_loewner(b["g_of_cI"][-1], b["sigma_sub"]))
    if p_margin >= -LOEWNER_TOL:
        status = PASS
    elif c_margin >= -LOEWNER_TOL:
        status = ERRATUM
    else:
        status = FAIL
    return Verdict(status, measured=sup, reference=corrected, printed=printed, corrected=corrected, margin=c_margin,
                   tolerance=LOEWNER_TOL,
                   detail=(f"sup_X λ_max g_w0(X) ≈ λ_max g_w0(1e8 I) = {sup:.5f}. Printed (120) covariance F^ℓ G̃⁻¹ F^ℓᵀ: "
                           f"λ_max {printed:.5f}, Loewner margin {p_margin:.3e} (not a bound); corrected Σ_sub with the "
                           f"process-noise term (spec §6.4): λ_max {corrected:.5f}, margin {c_margin:.3e}. Also (118) "
                           f"needs C_{{n_t}}ᵀ."))


def check_support(r: ScenarioResults) -> Verdict:
    """Lemma 16 / eq (43): every P̂_n(t) (t ≥ 1) and every Theorem-8 sample is ⪰ Q; envelope (73) P̂ ⪯ f_0^t(P0)."""
    g = r.gikf
    mQ = float(np.nanmin(g["margins"][1:, 1]))
    mE = float(np.nanmin(g["margins"][:, 2]))
    mR = float(_rel_loewner(r.scenario.Q, r.reference["final"]).min())
    m = min(mQ, mE, mR)
    return Verdict(PASS if m >= -LOEWNER_TOL else FAIL, measured=m, reference=-LOEWNER_TOL, tolerance=LOEWNER_TOL,
                   margin=m + LOEWNER_TOL,
                   detail=(f"relative Loewner margins: P̂_n(t) − Q (t ≥ 1, GIKF) {mQ:.3e}; P̃(T) − Q (Theorem-8 samples) "
                           f"{mR:.3e}; f_0^t(P0) − P̂_n(t) (Lyapunov envelope (73)) {mE:.3e}."))


def check_pathwise(r: ScenarioResults) -> Verdict:
    """Prop 7[ii], (19): with a common matching sequence, the token recursion reproduces the sensors'
    covariances pathwise. Corrected indexing p_n(t) = ->(p_n(t−1), t) vs the printed (13)/(17)."""
    sc = r.scenario
    sys_ = sc.system()
    protocol = sc.protocol.build(sc.graph)
    rng = np.random.default_rng(7)
    B, T, N = 64, 40, sc.N
    partners = np.array([np.tile(np.arange(N), (B, 1))] + [protocol.sample(B, rng) for _ in range(1, T)])
    P = np.broadcast_to(sc.P0, (B, N, sc.M, sc.M)).copy()
    sensors = [P]
    for t in range(T):
        P = gk.gikf_covariance_step(P, partners[t], sys_)
        sensors.append(P)
    rows = np.arange(B)[:, None]
    errs = {}
    for variant in ("corrected", "printed"):
        loc = np.tile(np.arange(N), (B, 1))
        tok = np.broadcast_to(sc.P0, (B, N, sc.M, sc.M)).copy()
        worst = 0.0
        for t in range(T):
            if variant == "corrected":
                loc = partners[t][rows, loc]          # p_n(t) = ->(p_n(t−1), t): move with slot t's matching
                node = loc
            else:
                node = loc                            # (17): π_t uses matchings 0..t−1 (one slot early)
            tok = gk.riccati_step(tok, sys_.C[node], sys_.R[node], sys_.F, sys_.Q)
            held = sensors[t + 1][rows, node]
            worst = max(worst, float((np.abs(tok - held).max(axis=(-2, -1)) /
                                      np.maximum(1, np.abs(held).max(axis=(-2, -1)))).max()))
            if variant == "printed":
                loc = partners[t][rows, loc]          # π_{t+1}(n) = ->(π_t(n), t)
        errs[variant] = worst
    if errs["corrected"] > 1e-12:
        status = FAIL
    elif errs["printed"] <= 1e-12:
        status = PASS
    else:
        status = ERRATUM
    return Verdict(status, measured=errs["printed"], reference=0.0, tolerance=1e-12, printed=errs["printed"],
                   corrected=errs["corrected"], margin=1e-12 - errs["corrected"],
                   detail=(f"{B} runs × {T} slots, N = {N}: max relative |P_n(t+1) − P̂_{{p_n(t)}}(t+1)| is "
                           f"{errs['corrected']:.1e} with p_n(t) = ->(p_n(t−1), t) (spec §4 fix) and {errs['printed']:.3g} "
                           f"with the printed (13)/(17), which index the matching one slot early. Laws are unaffected "
                           f"(A(t) i.i.d.)."))


# -- comparison lemmas (71)-(74) and the total-variation step (78)-(84) -------------------------------------

EQ74_S = (1, 2, 5, 10, 20, 50)


def check_eq74(r: ScenarioResults) -> Verdict:
    """(72)-(74): P_n(t) ⪯ P^s_n(t) for t ≥ s, pathwise, where P^s_n follows token n's own switching
    p_n(s), p_n(s+1), ... but restarts at slot s from the Lyapunov iterate f_0^s(P0) (72)."""
    sc, b = r.scenario, r.bounds
    sys_ = sc.system()
    T = min(r.slots, 120)
    s_list = [s for s in EQ74_S if s < T]
    chain = chain_sampler(sc, b)
    rng = np.random.default_rng(74)
    B = 1000
    worst = {s: math.inf for s in s_list}
    gap_5: dict[int, list[float]] = {}
    gap_T: dict[int, list[float]] = {}
    tokens = sorted({0, min(1, sc.N - 1)})
    with np.errstate(over="ignore", invalid="ignore"):
        for n in tokens:
            path = chain(B, T, rng, start=n)           # path[:, t] = p_n(t), p_n(0) = n
            P = np.broadcast_to(sc.P0, (B, sc.M, sc.M)).copy()
            Ps: dict[int, np.ndarray] = {}
            for t in range(T + 1):
                if t in s_list:
                    Ps[t] = np.broadcast_to(b["envelope"][t], (B, sc.M, sc.M)).copy()   # P^s_n(s) = f_0^s(P0)
                for s_, X in Ps.items():
                    worst[s_] = min(worst[s_], float(_rel_loewner(P, X).min()))
                    if t == min(s_ + 5, T):
                        gap_5.setdefault(s_, []).append(_median_rel_gap(X, P))
                if t == T:
                    break
                nodes = path[:, t]
                P = sr.apply_maps(sys_, P, nodes)                                        # (69)
                for s_ in Ps:
                    Ps[s_] = sr.apply_maps(sys_, Ps[s_], nodes)                           # (72)
            for s_, X in Ps.items():
                gap_T.setdefault(s_, []).append(_median_rel_gap(X, P))
    m = min(worst.values())
    ok = m >= -LOEWNER_TOL
    return Verdict(PASS if ok else FAIL, measured=m, reference=-LOEWNER_TOL, tolerance=LOEWNER_TOL, margin=m + LOEWNER_TOL,
                   trials=B,
                   detail=(f"tokens {tokens}, {B} paths each ({'Ā-chain' if bool(b.get('Abar_exact', True)) else 'protocol-driven chain (S3)'}), "
                           f"t = s..{T}: smallest relative Loewner margin λ_min(P^s_n(t) − P_n(t)) / max(1, ‖·‖) per s: "
                           + ", ".join(f"s={s_}: {worst[s_]:.2e}" for s_ in s_list)
                           + ". The comparison is not vacuous: median relative gap ‖P^s_n(t) − P_n(t)‖/‖P_n(t)‖ five slots after "
                             "the restart: " + ", ".join(f"s={s_}: {max(gap_5[s_]):.2e}" for s_ in s_list)
                           + f"; at T = {T}: " + ", ".join(f"s={s_}: {max(gap_T[s_]):.1e}" for s_ in s_list)
                           + " (the restarted process forgets f_0^s(P0) as the token collects observations). "
                             "(73) (P̂ ⪯ f_0^t(P0)) is checked in lemma16.support, (71) in lemma11.riccati-maps."))


def _median_rel_gap(X: np.ndarray, P: np.ndarray) -> float:
    return float(np.median(np.linalg.norm(X - P, 2, axis=(-2, -1)) / np.linalg.norm(P, 2, axis=(-2, -1))))


def _kernel_paths(Abar: np.ndarray, length: int) -> tuple[np.ndarray, np.ndarray]:
    """All Ā-paths (i_1, ..., i_L) with positive kernel weight Π_r Ā[i_r, i_(r+1)] (any i_1), and the weights."""
    N = len(Abar)
    paths = np.arange(N)[:, None]
    w = np.ones(N)
    for _ in range(length - 1):
        parent, child = np.nonzero(Abar[paths[:, -1]] > 0)
        w = w[parent] * Abar[paths[parent, -1], child]
        paths = np.hstack([paths[parent], child[:, None]])
    return paths, w


TV_S = (1, 2, 5, 10, 20, 40)  # the proof takes s > 0
TV_LEN = (1, 2, 3, 4, 6)


def check_tv_step(r: ScenarioResults) -> Verdict:
    """(78)-(82) computed exactly: the laws of P^s_n(t) and Q^s(t) are finite (one atom per chain
    path (p(s), ..., p(t−1))); d_v = ½ Σ_atoms |P − Q| against N d_v(p_n(s), q(s)) (82)."""
    sc, b = r.scenario, r.bounds
    sys_ = sc.system()
    Abar = b["Abar"]
    N = sc.N
    rows, worst_margin, ratio_max, path_identity = [], math.inf, 0.0, 0.0
    for s in TV_S:
        if s > r.slots:
            continue
        pi = np.linalg.matrix_power(Abar, s)                    # row n: law of p_n(s) = e_nᵀ Āˢ
        dv = 0.5 * np.abs(pi - 1.0 / N).sum(axis=1)             # d_v(p_n(s), q(s)), q(s) uniform
        for L in TV_LEN:
            paths, w = _kernel_paths(Abar, L)
            X = np.broadcast_to(b["envelope"][s], (len(paths), sc.M, sc.M)).copy()   # f_0^s(P0), (76)
            for k in range(L):
                X = sr.apply_maps(sys_, X, paths[:, k])           # f_(i_L) ∘ … ∘ f_(i_1)(f_0^s(P0)), (79)
            # atoms = distinct matrices: paths through sensors of the same types apply the same maps
            # in the same order and give bitwise-equal results, so exact equality identifies atoms
            _, atom = np.unique(X.reshape(len(X), -1), axis=0, return_inverse=True)
            atom = atom.ravel()
            lawP = pi[:, paths[:, 0]] * w                        # (N, paths): P(path) for token n, (80)
            lawQ = w / N                                         # stationary q, (81)
            n_atoms = atom.max() + 1
            diff = np.zeros((N, n_atoms))
            np.add.at(diff.T, atom, (lawP - lawQ).T)
            tv = 0.5 * np.abs(diff).sum(axis=1)                  # exact d_v(P^s_n(t), Q^s(t)), (78)
            tv_paths = 0.5 * np.abs(lawP - lawQ).sum(axis=1)     # the same on paths (no merging of atoms)
            path_identity = max(path_identity, float(np.abs(tv_paths - dv).max()))
            worst_margin = min(worst_margin, float((N * dv - tv).min()))
            with np.errstate(invalid="ignore", divide="ignore"):
                ratio = np.where(dv > 1e-15, tv / np.maximum(dv, 1e-300), 0.0)
            ratio_max = max(ratio_max, float(ratio.max()))
            n_star = int(np.argmax(tv))
            if L in (1, 4) or L == TV_LEN[-1]:
                rows.append(f"s={s}, t−s={L}: {len(paths)} paths, {n_atoms} atoms, max_n d_v(P^s_n, Q^s) = {tv[n_star]:.3e} "
                            f"(n={n_star}) vs d_v(p_n(s), U) = {dv[n_star]:.3e}, N d_v = {N * dv[n_star]:.3e}")
    ok = worst_margin >= -1e-12 and path_identity < 1e-12
    return Verdict(PASS if ok else FAIL, measured=ratio_max, reference=float(N), margin=worst_margin, tolerance=1e-12,
                   detail=(f"E1, exact total variation over all atoms (no sampling), every token n = 0..{N - 1}, s ∈ {list(TV_S)}, "
                           f"t − s ∈ {list(TV_LEN)}. (82) d_v(P^s_n(t), Q^s(t)) ≤ N d_v(p_n(s), q(s)) holds everywhere: "
                           f"smallest slack N d_v − d_v(P^s_n, Q^s) = {worst_margin:.3e}. The constant N is crude: the largest "
                           f"ratio d_v(P^s_n(t), Q^s(t)) / d_v(p_n(s), q(s)) is {ratio_max:.4f} (≤ 1, the data-processing "
                           f"inequality; the proof's own sum over i_1 gives 2, spec R17). On paths, before atoms merge, the "
                           f"distance equals d_v(p_n(s), U) exactly (max deviation {path_identity:.1e}); atoms with equal "
                           f"matrices (same sensor types along the path, compared bitwise) merge and lower it. " + "; ".join(rows)))


# -- token chain ---------------------------------------------------------------------------------------

def check_token_chain(r: ScenarioResults) -> Verdict:
    g, Abar = r.gikf, r.bounds["Abar"]
    N = r.scenario.N
    pv, lines = [], []
    for k in range(N):
        stat, p, dof = chi_square_gof(g["trans"][k], Abar[k])
        pv.append(p)
    lines.append(f"transition rows vs Ā: min p = {min(pv):.3g} over {N} rows ({int(g['trans'].sum())} transitions)")
    Pk = np.eye(N)[0]
    tok_p = []
    for t in range(1, len(g["token0"])):
        Pk = Pk @ Abar
        stat, p, dof = chi_square_gof(g["token0"][t], Pk)
        tok_p.append(p)
    lines.append(f"law of p_0(t) vs e_0ᵀ Āᵗ for t = 1..{len(tok_p)}: min p = {min(tok_p):.3g}")
    pv += tok_p
    if bool(r.bounds["c1"]):
        stat, p, dof = chi_square_gof(g["token0_final"], np.full(N, 1.0 / N))
        pv.append(p)
        lines.append(f"occupancy of token 0 at T = {r.slots} vs uniform (Prop 6[ii]): p = {p:.3g}")
    rej = holm(np.array(pv))
    return Verdict(FAIL if rej.any() else PASS, measured=float(min(pv)), reference=ALPHA, tolerance=ALPHA,
                   confidence=1 - ALPHA, trials=r.runs,
                   detail=f"Prop 6: chi-square goodness of fit, {len(pv)} tests, Holm at α = {ALPHA}, {int(rej.sum())} rejected. "
                          + "; ".join(lines) + ". Correlation between tokens of one run is irrelevant here: each test "
                                               "uses token 0 only or one transition per token and slot.")


def check_tv_decay(r: ScenarioResults) -> Verdict:
    b = r.bounds
    tv = b["tv"]
    N = r.scenario.N
    s = np.arange(len(tv))
    bound = np.minimum(1.0, 0.5 * math.sqrt(N) * float(b["slem"]) ** s)
    v = inequality(tv, bound + 1e-12, detail=f"eq (83): d_v(p_n(s), U) ≤ (√N/2) SLEM^s, s < {len(tv)}; d_v(s=50) = {tv[min(50, len(tv) - 1)]:.3e}")
    return v


def check_pullback(r: ScenarioResults) -> Verdict:
    """Lemma 23 / (108): forward and pull-back iterates have the same law; the pull-back converges pathwise (Thm 26(b))."""
    aux, ref = r.aux, r.reference
    times = list(ref["times"])
    tests = []
    for i, t in enumerate(aux["pullback_law_T"]):
        if int(t) in times:
            for f in ("log_trace", "log_lam_min"):
                tests.append((f"t={int(t)} {f}", feat(aux["pullback_law"][i], f), feat(ref["features"][times.index(int(t))], f)))
    v = ks_agree(tests, "pull-back f_ω₋₁∘…∘f_ω₋t(P0) vs forward P̃(t) from P0")
    gap = np.median(aux["pullback_gap"], axis=1)
    step = np.median(aux["pullback_step"], axis=1)
    Ts = aux["pullback_path_T"].tolist()
    ok = v.status == PASS and gap[-1] < 1e-6
    return Verdict(PASS if ok else FAIL, measured=v.measured, reference=ALPHA, tolerance=ALPHA, confidence=v.confidence,
                   trials=v.trials, margin=v.margin,
                   detail=v.detail + (f". Pathwise (Theorem 26(b), random equilibrium u(ω)): along 500 backward paths, median "
                                      f"relative gap between pull-backs from 0 and 1e6·I at T = {Ts}: "
                                      f"{[f'{x:.1e}' for x in gap]} (required < 1e-6 at the largest T); median relative change "
                                      f"between consecutive horizons: {[f'{x:.1e}' for x in step]}."))


def check_dichotomy_divergent(r: ScenarioResults) -> Verdict:
    """Theorem 26 alternative (a) for a negative control: ‖pull-back‖ → ∞ at the predicted rate."""
    aux, b = r.aux, r.bounds
    Ts = aux["pullback_path_T"].astype(float)
    lg = np.log(np.median(aux["pullback_lo_norm"], axis=1))
    slope = float(np.polyfit(Ts[-3:], lg[-3:], 1)[0])
    rate = float(b["divergence_rate"].max())
    rel = abs(slope - rate) / rate
    return Verdict(PASS if rel < 0.02 else FAIL, measured=slope, reference=rate, tolerance=0.02, margin=0.02 - rel,
                   detail=(f"alternative (a): log median ‖f_ω₋₁∘…∘f_ω₋T(0)‖ at T = {Ts.astype(int).tolist()}: "
                           f"{np.round(lg, 3).tolist()}; slope over the last three horizons {slope:.5f} vs 2 log|λ_unobs| = "
                           f"{rate:.5f} (relative difference {rel:.2e})."))


def check_lifted_chain(r: ScenarioResults) -> Verdict:
    b = r.bounds
    if "lifted_pi" not in b:
        return not_checkable("the lifted chain has more than 5000 admissible windows (dense eigen-solve skipped)")
    pi, corr, printed = b["lifted_pi"], b["lifted_corrected"], b["lifted_printed"]
    status_p = np.allclose(printed, pi, atol=1e-12, rtol=0)
    status_c = np.allclose(corr, pi, atol=1e-12, rtol=0)
    i = int(np.argmax(np.abs(printed - pi)))
    status = PASS if status_p else (ERRATUM if status_c else FAIL)
    return Verdict(status, measured=float(pi[i]), reference=float(pi[i]), printed=float(printed[i]), corrected=float(corr[i]),
                   tolerance=1e-12, margin=float(1e-12 - np.abs(corr - pi).max()),
                   detail=(f"stationary law of z(t) = (p̃(t−ℓ+1..t)) over {len(pi)} admissible windows (ℓ = {len(r.witness())}): "
                           f"left unit eigenvector of the lifted transition matrix vs (134) as printed, (1/N)Π_j Ā[j, j+1] "
                           f"(max error {np.abs(printed - pi).max():.3g}) and corrected (1/N)Π_j Ā[i_j, i_(j+1)] "
                           f"(max error {np.abs(corr - pi).max():.1e})."))


def check_nees(r: ScenarioResults) -> Verdict:
    """NEES ~ χ²_M: errors are exactly N(0, P̂_n) given the gossip path. Runs are independent (sensors
    and slots within a run are not), so the tests use one value per run: its average NEES and its
    fraction of values above the χ² 99% quantile."""
    g = r.gikf
    s, above, n, sc_sum, above_c, n_c = g["nees"]
    M, N = r.scenario.M, r.scenario.N
    per_run = g["nees_run"]
    k_s, k_c = n / r.runs, n_c / r.runs  # values per run (sensors × slots, slots)
    cells = [("sensors: mean NEES", per_run[0] / k_s, M), ("sensors: fraction > χ² q0.99", per_run[1] / k_s, 0.01),
             ("centralized: mean NEES", per_run[2] / k_c, M), ("centralized: fraction > χ² q0.99", per_run[3] / k_c, 0.01)]
    zcrit = stats.norm.ppf(1 - ALPHA / (2 * len(cells)))
    zs, lines = [], []
    for label, x, ref in cells:
        se = x.std(ddof=1) / math.sqrt(len(x))
        z = (x.mean() - ref) / max(se, 1e-300)
        zs.append(z)
        lines.append(f"{label} {x.mean():.4f} (reference {ref:g}, z = {z:.2f})")
    worst = float(np.max(np.abs(zs)))
    return Verdict(PASS if worst <= zcrit else FAIL, measured=float(s / n), reference=float(M), tolerance=zcrit,
                   margin=float(zcrit - worst), confidence=1 - ALPHA, trials=r.runs,
                   detail=(f"NEES e_nᵀ P̂_n⁻¹ e_n ~ χ²_M (M = {M}) from the error recursion (common w, per-sensor v), "
                           f"{int(n)} (run, sensor, slot) values over {r.runs} independent runs; z-tests on per-run "
                           f"averages (Bonferroni over {len(cells)}, |z| ≤ {zcrit:.2f}): " + "; ".join(lines) + "."))


def check_remark9(r: ScenarioResults) -> Verdict:
    a, b = r.gikf, r.comparison
    tests = []
    for t in a["times"]:
        if t < 2:
            continue
        i = list(a["times"]).index(t)
        tests.append((f"t={t} random sensor", feat(a["feat_q"][i], "log_trace"), feat(b["feat_q"][i], "log_trace")))
        for n in (0, 1):
            tests.append((f"t={t} sensor {n}", feat(a["feat_n"][i][:, :, n], "log_trace"), feat(b["feat_n"][i][:, :, n], "log_trace")))
    def _mean(spec):
        prot = spec.build(r.scenario.graph)
        try:
            return prot.mean_matrix()
        except ValueError:  # greedy matching on a large graph: Monte Carlo estimate
            return prot.estimate_mean_matrix(200_000, np.random.default_rng(9))[0]

    Aa, Ab = _mean(r.scenario.protocol), _mean(r.scenario.comparison)
    v = ks_agree(tests, f"Remark 9: GIKF laws under '{r.scenario.protocol.kind}' vs '{r.scenario.comparison.kind}' "
                        f"(same Ā up to {np.abs(Aa - Ab).max():.1e}), {r.runs} runs each")
    return v


def check_d1_not_necessary(r: ScenarioResults) -> Verdict:
    b, ref = r.bounds, r.reference
    lam = np.exp(feat(ref["features"][-1], "log_trace"))
    q = np.quantile(lam, [0.5, 0.99, 0.999])
    qq = r.gikf["quantiles"]
    T = qq.shape[0] - 1
    t = np.arange(T // 2, T + 1)
    drift = max(abs(np.polyfit(t, qq[T // 2:, n, k], 1)[0]) for n in range(r.scenario.N)
                for k in (gk.QUANTILES.index(0.5), gk.QUANTILES.index(0.95)))
    limit = 0.1 * 2 * np.log(max(np.abs(np.linalg.eigvals(r.scenario.F)).max(), 1.0 + 1e-9))
    ok = (not bool(b["d1"])) and bool(b["central_observable"]) and drift < limit
    return Verdict(PASS if ok else FAIL, measured=float(drift), reference=float(limit), margin=float(limit - drift),
                   detail=(f"observation, not a paper claim (spec E8): D.1 fails (max walk-Gramian rank "
                           f"{int(b['witness_max_rank'])} of {r.scenario.M}) while (F, C_all) is observable "
                           f"({bool(b['central_observable'])}); the covariances are nevertheless bounded: the largest |slope| of the "
                           f"median and q0.95 of log tr P̂_n over the second half is {drift:.4f} per slot (limit: 10% of "
                           f"2 log ρ(F) = {limit:.4f}); μ̂ trace quantiles 0.5/0.99/0.999 = "
                           f"{np.round(q, 2).tolist()} (spec: 2.0 / 60 / 574). Remark 5's minimality is over all F."))


# -- paper-only claims (E1 specifics) --------------------------------------------------------------------

def check_remark3(_res) -> Verdict:
    """Remark 3: 'F invertible and G = Σ C_nᵀC_n full rank ⇒ any covering walk works' is false."""
    F = np.array([[0.0, -1.0], [1.0, 0.0]])
    sys_ = gk.GossipSystem.build(F, 0.1 * np.eye(2), [np.array([[1.0, 0.0]]), np.array([[0.0, 1.0]])],
                                 [np.eye(1), np.eye(1)], np.eye(2))
    cover = np.linalg.eigvalsh(wd.walk_gramian(sys_, (0, 1)))
    alt = np.linalg.eigvalsh(wd.walk_gramian(sys_, (0, 1, 0, 1, 0, 1)))
    Abar = np.array([[0.5, 0.5], [0.5, 0.5]])
    found = wd.search_witness(sys_, Abar)
    eig = np.linalg.eigvalsh(found.gramian)
    return Verdict(ERRATUM, measured=float(cover[0]), reference=0.0, printed=float(cover[0]), corrected=float(eig[0]),
                   detail=(f"F = rotation by 90°, C_1 = [1 0], C_2 = [0 1] (G = I, F invertible): the covering walk (1,2) "
                           f"has Gramian eigenvalues {np.round(cover, 6).tolist()}, the alternating walk (1,2,1,2,1,2) "
                           f"{np.round(alt, 6).tolist()}: singular, contrary to Remark 3's justification. The conclusion "
                           f"(some walk works) survives: breadth-first search finds w0 = {tuple(x + 1 for x in found.witness)} "
                           f"(1-based) with eigenvalues {np.round(eig, 6).tolist()}. We therefore always search for and "
                           f"record w0 (spec §6.3)."))


def check_riccati_roundoff(_res) -> Verdict:
    """Spec §11 P1: the textbook form (11) loses accuracy for huge ‖X‖; the Joseph form does not."""
    F, Q = np.diag([1.2, 1.1]), 0.1 * np.eye(2)
    C, R = np.array([[1.0, 0.0]]), np.eye(1)
    rng = np.random.default_rng(1)
    X = _random_psd(rng, 200, 2, (12, 16))
    jos = gk.riccati_step(X, C, R, F, Q)
    txt = gk.riccati_textbook(X, C, R, F, Q)
    info = F @ np.linalg.inv(np.linalg.inv(X) + C.T @ C) @ F.T + Q  # information form (exact for X ≻ 0)
    ej = float(np.abs(jos - info)[:, 0, 0].max())
    et = float(np.abs(txt - info)[:, 0, 0].max())
    below_q = int((np.linalg.eigvalsh(txt - Q)[:, 0] < 0).sum())
    return Verdict(PASS if ej < 1e-9 else FAIL, measured=ej, reference=0.0, tolerance=1e-9, margin=1e-9 - ej,
                   detail=(f"‖X‖ ∈ [1e12, 1e16], C = [1 0]: error of the observed-direction entry f(X)_11 against the "
                           f"information form: Joseph {ej:.2e}, textbook (11) {et:.2e}; textbook results violating "
                           f"f(X) ⪰ Q: {below_q} of 200. All simulations use the Joseph form."))


def check_tail_exponent(r: ScenarioResults) -> Verdict:
    """R23 (E1 heuristic): P(X_jj > x) ~ x^{−κ_j}, (1 − ρ) a_j^{2κ_j} = 1, ρ = rate of leaving a sensor type."""
    ref = r.reference
    if r.reference_runs < 10_000:
        return not_checkable(f"the tail fit needs >= 10,000 Theorem-8 runs (this run has {r.reference_runs}; quick mode)")
    M = r.scenario.M
    Abar = r.bounds["Abar"]
    rho = float(1 - Abar[0, 0])  # E1: every off-diagonal move changes the type
    a = np.abs(np.diag(r.scenario.F))
    kappa = -np.log(1 - rho) / (2 * np.log(a))
    est, lines = [], []
    for j in range(M):
        x = np.sort(ref["features"][-1][len(gk.FEATURES) + j])[::-1]
        n = len(x)
        k = max(int(0.02 * n), 50)
        hill = 1.0 / np.mean(np.log(x[:k] / x[k]))
        se = hill / math.sqrt(k)
        est.append(hill)
        lines.append(f"X_{j + 1}{j + 1}: Hill estimate {hill:.3f} ± {se:.3f} (top {k} of {n}) vs predicted κ = {kappa[j]:.3f}")
    rel = np.abs(np.array(est) - kappa) / kappa
    ok = bool(rel.max() < 0.15)
    return Verdict(PASS if ok else FAIL, measured=[float(e) for e in est], reference=kappa.tolist(), tolerance=0.15,
                   margin=float(0.15 - rel.max()), trials=len(ref["features"][-1][0]),
                   detail=("; ".join(lines) + f". Heuristic (spec R23, DERIVED), so a 15% tolerance rather than a "
                           f"confidence level; κ_1 < 1 means E_μ[tr X] = ∞: the report uses quantiles, never means."))


def _quantile_ci(x: np.ndarray, q: float, confidence: float) -> tuple[float, float]:
    """Distribution-free confidence interval of the q-quantile from order statistics (binomial)."""
    x = np.sort(x)
    n = len(x)
    a = (1 - confidence) / 2
    lo = int(stats.binom.ppf(a, n, q))
    hi = int(stats.binom.isf(a, n, q))
    return float(x[max(lo - 1, 0)]), float(x[min(hi, n - 1)])


MU_QUANTILES_E1 = {0.10: 2.01, 0.25: 2.19, 0.50: 3.12, 0.75: 6.84, 0.90: 24.6, 0.99: 759.0}  # spec §12, T = 300, 1e5 runs
MU_N_E1 = {0: {0.5: 2.43, 0.9: 8.7, 0.99: 65.0}, 1: {0.5: 4.29, 0.9: 53.0, 0.99: 2495.0}}     # spec §8 E4 table


def check_reference_quantiles(r: ScenarioResults) -> Verdict:
    """μ and μ_n trace quantiles of E1 against the spec's reference numbers (order-statistic CIs)."""
    if r.slots < 300 or r.reference_runs < 10_000:
        return not_checkable(f"the spec's numbers are for T = 300 and >= 1e5 runs; this run has T = {r.slots}, "
                             f"{r.reference_runs} runs (quick mode)")
    ref = r.reference
    tr = np.exp(ref["features"][-1][FEAT["log_trace"]])
    last = ref["last"][-1]
    cells = [("μ", q, v, tr) for q, v in MU_QUANTILES_E1.items()]
    cells += [(f"μ_{n} (last switch at sensor type {n})", q, v, tr[(last % 2) == n]) for n, row in MU_N_E1.items()
              for q, v in row.items()]
    conf = 1 - ALPHA / len(cells)
    lines, worst, ok = [], math.inf, True
    for label, q, v, x in cells:
        lo, hi = _quantile_ci(x, q, conf)
        rounding = 0.005 * v  # the spec's numbers carry 2-3 significant digits
        inside = lo - rounding <= v <= hi + rounding
        ok &= inside
        rel = min(v - lo, hi - v) / v
        worst = min(worst, rel)
        lines.append(f"{label} q{q:g}: spec {v:g}, ours [{lo:.4g}, {hi:.4g}]{'' if inside else ' OUTSIDE'}")
    return Verdict(PASS if ok else FAIL, measured=float(np.quantile(tr, 0.5)), reference=MU_QUANTILES_E1[0.5],
                   margin=float(worst), confidence=1 - ALPHA, trials=len(tr),
                   detail=(f"distribution-free order-statistic intervals at family-wise confidence {1 - ALPHA} (Bonferroni "
                           f"over {len(cells)} quantiles, widened by the spec's rounding of 0.5%): " + "; ".join(lines)
                           + ". Types by parity of the last switch (E1: even sensors see mode 1)."))


# -- catalogue ------------------------------------------------------------------------------------------

def _on(name: str, fn: Callable[[ScenarioResults], Verdict]) -> Callable[[Results], Verdict]:
    def check(res: Results) -> Verdict:
        r = res.get(name)
        if r is None:
            return not_checkable(f"scenario {name} was not computed")
        return fn(r)
    return check


def _needs_exact_abar(fn):
    def check(r: ScenarioResults) -> Verdict:
        if not bool(r.bounds.get("Abar_exact", True)):
            return not_checkable(f"Ā is only a Monte Carlo estimate here ({int(r.bounds['Abar_draws']):,} matchings of the "
                                 f"greedy protocol; no exact form for {r.scenario.N} nodes): this check needs the exact Ā "
                                 f"(spec §11 P9); the Theorem-8 samples are drawn with the protocol-driven chain (S3)")
        return fn(r)
    return check


def _needs_theorem(fn):
    def check(r: ScenarioResults) -> Verdict:
        if not r.theorem_applies:
            return not_checkable(f"hypotheses fail (C.1 = {r.c1}, D.1 = {r.d1}): the theorem makes no claim here")
        return fn(r)
    return check


def scenario_claims(name: str, roles: dict) -> list[Claim]:
    """Claims for one scenario; roles: flags from the scenario's expectations (c1, d1, diverges, periodic...)."""
    c = []

    def add(where, what, source, statement, kind, fn):
        c.append(Claim(f"{PAPER}.{where}.{what}.{name}", source, statement, kind, _on(name, fn)))

    add("assumption", "c1", "§II-A, C.1, eq (6)", "Ā = E[A(t)] is symmetric, doubly stochastic; C.1 (irreducible, aperiodic) as expected",
        "qualitative", check_c1)
    add("assumption", "s1", "§II-A, S.1", "(F, Q^½) stabilisable (Q ≻ 0)", "qualitative", check_s1)
    add("assumption", "d1", "§II-A, D.1, Remark 2, footnote 6", "D.1: a witness Ā-walk with invertible Gramian exists (searched, recorded) as expected",
        "qualitative", check_d1)
    add("thm10-i", "weak-consensus", "Theorem 10[i], eq (22); exact form eqs (60)-(67)",
        "A uniformly random sensor's P̂_q(t) has the law of the Theorem-8 process P̃(t) (exactly, at every t)", "statistical",
        check_weak_consensus)
    add("thm10-i", "per-sensor-laws", "spec R7b (derived from (60)-(67))",
        "Sensor n's law is μ_t conditioned on the last switch = n; per-sensor laws differ from each other and from μ_t",
        "statistical", check_per_sensor)
    add("centralized", "filterpy", "spec §6.6 (reference)", "Centralized P_c(t): batched recursion = filterpy KalmanFilter; limit = DARE",
        "identity", check_filterpy)
    add("centralized", "domination", "spec §6.6, R21", "P̂_n(t) ⪰ P_c(t) for every sensor, slot and run (pathwise)",
        "inequality", check_domination)
    add("lemma16", "support", "Lemma 16, eqs (43), (45), (73)", "P̂_n(t) ⪰ Q (t ≥ 1) and P̂_n(t) ⪯ f_0^t(P0); μ(X ⪰ Q) = 1",
        "inequality", check_support)
    add("nees", "consistency", "spec R22 (derived)", "Errors are N(0, P̂_n): NEES ~ χ²_M at every sensor and for the centralized filter",
        "statistical", check_nees)
    if roles.get("full", True):
        add("lemma11", "riccati-maps", "Lemma 11[ii], [iii]; (71)", "Compositions of f_n are order preserving, strongly sublinear; f_n concave, f_n ⪯ f_0",
            "inequality", check_lemma11)
        add("prop6", "token-chain", "Proposition 6[i], [ii]", "Token locations form a Ā-Markov chain with uniform limit", "statistical",
            _needs_exact_abar(check_token_chain))
        add("prop7-ii", "pathwise", "Proposition 7[ii], eq (19), with (13)/(17)", "Token recursion equals the sensor covariances pathwise",
            "identity", check_pathwise)
        add("eq74", "comparison", "eqs (71)-(74), spec R16",
            "P_n(t) ⪯ P^s_n(t) for t ≥ s: the token's covariance is dominated by the same switching restarted at s from f_0^s(P0)",
            "inequality", check_eq74)
    if roles.get("tv", True) and roles.get("full", True):
        add("eq83", "tv-decay", "eq (83), Proposition 6[ii]", "d_v(p_n(s), U) decays geometrically with the SLEM", "inequality", _needs_exact_abar(check_tv_decay))
    if roles.get("diverges"):
        add("negative-control", "divergence", "spec E5/E6 (hypotheses violated)",
            "PREDICTED DIVERGENCE: sensors in an Ā-class that cannot detect an unstable mode λ diverge at rate 2 log|λ|; others stay bounded",
            "qualitative", check_divergence)
        if roles.get("c1"):
            add("thm26", "alternative-a", "Theorem 26 (a), spec R19", "PREDICTED: the pull-back norm grows at rate 2 log|λ_unobs| (alternative (a))",
                "qualitative", check_dichotomy_divergent)
    elif roles.get("periodic"):
        add("thm10-ii", "token-domination", "Theorem 10[ii], (23)-(25); spec E7",
            "PREDICTED FAILURE under periodic Ā: a token's law is not dominated by μ (limsup P(P_n(t) ∈ S) = 1 > μ(S))",
            "statistical", check_token_domination)
        add("e7", "periodic-orbit", "spec E7", "Covariances settle on a 2-periodic orbit with traces 1.8841 / 2.1634", "identity",
            check_periodic_orbit)
    elif roles.get("d1") is False:
        add("e8", "d1-not-necessary", "Remark 5; spec E8", "D.1 fails for singular F yet (F, C_all) is observable and P̂ stays bounded",
            "qualitative", check_d1_not_necessary)
    else:
        add("thm10-iii", "bounded", "Theorem 10[iii], eqs (26), (27)", "Every sensor's P̂_n(t) is stochastically bounded; P(P̂_n ∈ S) ≤ N μ(S)",
            "statistical", _needs_theorem(check_bounded))
        add("thm10-ii", "token-domination", "Theorem 10[ii], eqs (23)-(25)", "limsup_t P(P_n(t) ∈ S) ≤ μ(S) for upward-closed S",
            "statistical", _needs_theorem(check_token_domination))
        add("eq29", "sensor-sum", "eq (29) (spec R10)", "Σ_n P(P̂_n(t) ∈ S) = N μ(S) for continuity sets S (the unproven (29) holds with equality)",
            "statistical", _needs_theorem(check_eq29))
        add("thm8", "initial-law", "Theorem 8 / Theorem 12", "P̃(t) ⇒ μ from any initial law (same limit from δ0, δ_1e6I, Wishart)",
            "statistical", _needs_theorem(check_initial_law))
        add("lemma23", "pullback", "Lemma 23, eq (108); Theorem 26(b)", "Forward and pull-back iterates agree in law; the pull-back converges pathwise",
            "statistical", _needs_theorem(check_pullback))
        if roles.get("full", True):
            add("lemma14", "bound", "Lemma 14, eqs (39)-(41)", "g_w0(X) ⪯ α0 I for all X ⪰ 0 (α0 from the corrected Σ_sub)", "inequality",
                _needs_theorem(check_lemma14))
        if roles.get("full", True):
            add("lemma14", "eq120", "eqs (118)-(120)", "The sub-optimal estimator's covariance bounds g_w0 (printed form vs corrected)",
                "inequality", _needs_theorem(check_lemma14_printed))
        add("lemma15", "tail-bound", "Lemma 15, eqs (122)-(142)", "P(‖P̃(t)‖ > J) ≤ β_t(J) → 0 (tightness)", "statistical",
            _needs_theorem(_needs_exact_abar(check_lemma15)))
        if roles.get("full", True):
            add("eq134", "lifted-chain", "eqs (132)-(134)", "Stationary law of the lifted window chain", "identity",
                _needs_theorem(_needs_exact_abar(check_lifted_chain)))
    return c


def catalogue(names_roles: list[tuple[str, dict]], paper: bool) -> list[Claim]:
    claims: list[Claim] = []
    for name, roles in names_roles:
        claims += scenario_claims(name, roles)
    if paper:
        claims += [
            Claim(f"{PAPER}.rem9.protocol-invariance.e3", "Remark 9", "μ and the per-sensor laws depend on the protocol only through Ā",
                  "statistical", _on("e3", lambda r: check_remark9(r))),
            Claim(f"{PAPER}.r23.tail-exponent.e1", "spec R23 (derived heuristic)", "Diagonal μ-entries have power tails with exponents κ_j, (1−ρ)a_j^{2κ_j} = 1",
                  "statistical", _on("e1", check_tail_exponent)),
            Claim(f"{PAPER}.e1.mu-quantiles", "spec §12 and §8 E4 (reference numbers; the paper has none)",
                  "Quantiles of tr X under μ and under the per-type laws μ_n match the spec's independent prototype",
                  "statistical", _on("e1", check_reference_quantiles)),
            Claim(f"{PAPER}.remark3.covering-walk", "Remark 3", "F invertible and Σ C_nᵀC_n full rank ⇒ every covering walk satisfies D.1",
                  "qualitative", check_remark3),
            Claim(f"{PAPER}.eq11.joseph-form", "eq (11), spec §11 P1", "The Riccati map is computed accurately for ‖X‖ up to 1e16 (Joseph form)",
                  "identity", check_riccati_roundoff),
            Claim(f"{PAPER}.prop7-i.semi-markov", "Proposition 7[i], eq (16)", "(P_n(t), p_n(t)) is jointly Markov", "qualitative",
                  lambda _r: not_checkable("structural (holds by construction); the bookkeeping is checked pathwise by prop7-ii")),
            Claim(f"{PAPER}.lemma11-i.compactness", "Lemma 11[i]", "Conditional compactness of the RDS", "qualitative",
                  lambda _r: not_checkable("topological statement in finite dimension; nothing numerical to check")),
            Claim(f"{PAPER}.eq82.tv-step", "eqs (78)-(84), spec R17", "d_v(P^s_n(t), Q^s(t)) ≤ N d_v(p_n(s), q(s)) (exact total variation over the finite supports)",
                  "inequality", _on("e1", check_tv_step)),
            Claim(f"{PAPER}.thm26.uniqueness", "Theorem 26 / Theorem 12 (uniqueness)", "The invariant measure is unique", "qualitative",
                  lambda _r: not_checkable("uniqueness cannot be shown numerically; thm8.initial-law and lemma23.pullback support it")),
        ]
    return claims
