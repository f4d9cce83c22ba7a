"""Claims on the model of the random-communication filtering paper: Lemma III.3 (Jensen's
inequality for convex combinations), the fusion weights (3) and (6), and the Poisson clocks (P1)-(P2)
of the simulated paths."""
from __future__ import annotations

import numpy as np

from dse.verify.rules import FAIL, PASS, Verdict, p_value_test, roundoff_tolerance

from .claims_common import MIN_TRIALS, claims, hyp, min_eig, sps
from .results import ScenarioResults


@claims.claim("{paper}.lemma3_3.jensen", "Lemma III.3, eq. (16)", "zzᵀ ≤ Σγ_j x_jx_jᵀ for a convex combination "
              "z = Σγ_j x_j", "inequality")
def check_jensen(_res) -> Verdict:
    """Lemma III.3 on random vectors and Dirichlet weights, and its exact gap."""
    rng = np.random.default_rng(20210930)
    worst, ident, tol_rel = np.inf, 0.0, 0.0
    for _ in range(2000):
        m, n = rng.integers(1, 6), rng.integers(1, 6)
        X = rng.standard_normal((m, n)) * rng.exponential(1.0, (m, 1))
        g = rng.dirichlet(np.ones(m))
        z = g @ X
        gap = np.einsum("j,ja,jb->ab", g, X, X) - np.outer(z, z)
        scale = float(np.abs(X).max() ** 2)
        worst = min(worst, float(min_eig(gap)) / scale)
        exact = np.einsum("j,ja,jb->ab", g, X - z, X - z)
        ident = max(ident, float(np.abs(gap - exact).max()) / scale)
        tol_rel = max(tol_rel, roundoff_tolerance(scale=1.0, operations=2 * m + 2 * n)[0])
    ok = worst >= -tol_rel and ident <= tol_rel
    return Verdict(PASS if ok else FAIL, measured=worst, reference=0.0, tolerance=tol_rel, margin=worst + tol_rel,
                   detail=f"2000 random cases (m, n ≤ 5): smallest eigenvalue of Σγ_j x_jx_jᵀ − zzᵀ relative to max|x|² "
                          f"{worst:.3e}; the gap equals Σγ_j(x_j − z)(x_j − z)ᵀ to {ident:.1e}; round-off allowance "
                          f"{tol_rel:.2g} = 10·(2m + 2n) operations·eps (sums of m outer products and the eigenvalue solve)")


@claims.claim("{paper}.model.fusion_weights.{scenario}", "eq. (3), (6)", "Π = I − α𝓛 is symmetric, doubly stochastic "
              "and nonnegative for 0 < α ≤ 1/d_max, and the mean jump of the edge clocks is λ(Π − I)", "identity",
              hypotheses=hyp("alpha"))
def check_fusion(r: ScenarioResults) -> Verdict:
    s = r.sys
    Pi = np.eye(s.N) - s.alpha * s.laplacian
    jump_sum = sum(s.jump(c) - np.eye(s.N) for c in range(len(s.clocks)))
    err = max(np.abs(Pi.sum(0) - 1).max(), np.abs(Pi.sum(1) - 1).max(), np.abs(jump_sum + s.alpha * s.laplacian).max(),
              np.abs(Pi - Pi.T).max())
    tol, how = roundoff_tolerance(scale=1.0, operations=2 * s.N + len(s.clocks))
    ok = err <= tol and Pi.min() >= -tol
    return Verdict(PASS if ok else FAIL, measured=float(Pi.min()), reference=0.0, tolerance=tol, margin=float(Pi.min()),
                   detail=f"Π = I − α𝓛 with α = {s.alpha:.6g}: symmetric, row/column sums 1 and Σ_c (J_c − I) = −α𝓛 "
                          f"hold to {err:.1e} ({how}); smallest entry {Pi.min():.4g} ≥ 0")


def _two_sided_discrete(cdf_k, sf_k) -> np.ndarray:
    return np.minimum(1.0, 2 * np.minimum(cdf_k, sf_k))


@claims.claim("{paper}.model.poisson_clocks.{scenario}", "§II, (P1)-(P2)", "node counters are Poisson of rate d_iλ; "
              "rings are never simultaneous, so every activation set is a singleton", "statistical")
def check_poisson(r: ScenarioResults) -> Verdict:
    """Node counters against their exact laws: the total count over n paths is Poisson(n·d_iλT)
    and the number of paths without any event is Binomial(n, e^{−d_iλT}) (exact tests)."""
    ev, sc, s = r.event, r.scenario, r.sys
    n = int(ev["n"])
    mu = s.degrees * sc.main_rate * sc.horizon
    total, zeros = np.asarray(ev["c1"], float), np.asarray(ev["c0"], float)
    p_sum = _two_sided_discrete(sps().poisson.cdf(total, n * mu), sps().poisson.sf(total - 1, n * mu))
    p0 = np.exp(-mu)
    p_zero = _two_sided_discrete(sps().binom.cdf(zeros, n, p0), sps().binom.sf(zeros - 1, n, p0))
    spacing = float(ev["spacing"])
    v = p_value_test(np.concatenate([p_sum, p_zero]), trials=n, min_trials=MIN_TRIALS,
                     measured=float((total / n)[np.argmin(p_sum)]), reference=float(mu[np.argmin(p_sum)]),
                     detail=f"exact tests of the node event counts on [0, {sc.horizon:g}] at λ = {sc.main_rate:g}: total "
                            f"over {n} paths ~ Poisson(n·d_iλT) (means {np.round(total / n, 3).tolist()} vs "
                            f"{np.round(mu, 3).tolist()}), paths without event ~ Binomial(n, e^(−d_iλT)) "
                            f"({zeros.astype(int).tolist()} vs expected {np.round(n * p0, 2).tolist()}); smallest spacing "
                            f"between events {spacing:.3g} > 0 (no simultaneous rings)")
    if v.status == PASS and not spacing > 0:
        return Verdict(FAIL, detail="two events at the same instant. " + v.detail)
    return v
