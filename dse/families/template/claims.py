"""The template family's hypothesis and claims, each declared on its check.

Claim and hypothesis ids are templates: `{paper}` is the run's id (the scenario's name in a
user's run). The verdict helpers of `dse.verify.rules` give every claim the same fields
(measured, reference, tolerance, margin, confidence); tolerances come from the arithmetic.
"""
from __future__ import annotations

import numpy as np

from dse.contract.claims import ClaimSet
from dse.verify.rules import Holds, inequality, p_value_test, roundoff_tolerance

from .stages import Design, Results

claims = ClaimSet()

CONNECTED = "{paper}.hyp.connected"


@claims.hypothesis(CONNECTED, "the graph is connected: every eigenvalue of W but one is inside the unit disk")
def connected(design: Design) -> Holds:
    lam = design.second_modulus
    tol, how = roundoff_tolerance(scale=1.0, operations=design.scenario.n ** 2)
    return Holds(lam < 1.0 - tol, value=lam, threshold=1.0,
                 detail=f"second largest |λ(W)| = {lam:.12g}, below 1 by more than the eigensolver's {how}")


@claims.claim("{paper}.consensus.monte_carlo", "exact law of the errors", "the Monte Carlo mean-square error of "
              "every node after t rounds is r (W^{2t})_ii", "statistical")
def check_monte_carlo(res: Results) -> object:
    """Given the weights, e_i(t) = (Wᵗv)_i is exactly N(0, P_ii(t)), so the sum of e_i(t)² over n
    independent trials divided by P_ii(t) is exactly χ²_n: a two-sided p-value per (t, node),
    Bonferroni over the cells (valid whatever their dependence)."""
    # χ²_n's cdf and survival function are scipy.special's chdtr and chdtrc (what scipy.stats.chi2 evaluates, to
    # the bit): scipy.stats itself takes about a second to import
    from scipy.special import chdtr, chdtrc

    stat = res.sq / res.design.mse
    p = 2.0 * np.minimum(chdtr(res.trials, stat), chdtrc(res.trials, stat))
    return p_value_test(np.minimum(p, 1.0), trials=res.trials, detail=f"exact χ²_{res.trials} law of Σ e_i(t)² / P_ii(t) "
                        f"over {stat.size} (round, node) cells")


@claims.claim("{paper}.consensus.rate", "spectral decomposition of W^{2t}", "every node's mean-square error "
              "approaches the centralized r/N geometrically: |P_ii(t) − r/N| ≤ r (1 − 1/N) λ*^{2t}", "inequality",
              hypotheses=(CONNECTED,))
def check_rate(res: Results) -> object:
    """P(t) = r(J + Σ_{k<N} λ_k^{2t} v_k v_kᵀ) with J = 11ᵀ/N, so P_ii(t) − r/N = r Σ_{k<N} λ_k^{2t} v_ik²
    ≤ r λ*^{2t} (1 − 1/N). P(t) comes from the recursion, λ* from the eigensolver: two computations."""
    d = res.design
    sc = d.scenario
    t = np.arange(d.mse.shape[0])[:, None]
    lower = np.abs(d.mse - sc.model.r / sc.n)
    upper = np.broadcast_to(sc.model.r * (1 - 1 / sc.n) * d.second_modulus ** (2 * t), lower.shape)
    tol, how = roundoff_tolerance(scale=sc.model.r, operations=2 * sc.n * (sc.model.rounds + 1) + sc.n ** 2)
    return inequality(lower, upper, tolerance=tol, detail=f"every node and round t = 0..{sc.model.rounds}; {how}")
