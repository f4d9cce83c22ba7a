"""The Monte Carlo of both filters against the exact recursions (22) and (18), under exact laws.

Given the gains the errors are Gaussian with the exact covariance of the recursion (22), so
the per-agent sums of squares are exactly χ², the sums exactly normal and the trace a weighted
χ² with conservative Chernoff bounds (`exact_laws`). Their p-values keep the claim's confidence
at any number of trials.
"""
from __future__ import annotations

import numpy as np

from dse.verify.rules import Verdict, p_value_test

from ..exact_laws import chi2_sum_p, normal_sum_p, weighted_chi2_p
from ..results import Results
from .common import DS, MIN_TRIALS, claims, steps_text

_MC_TESTS = {
    "trace": "Σ_t ‖x̃‖² is a weighted sum Σ_j λ_j χ²_j(R) over the eigenvalues λ_j of P(k|k−1): conservative two-sided "
             "Chernoff p-values (exact χ² when one eigenvalue carries it all)",
    "agent": "Σ_t x̃_i² / P_ii(k|k−1) ~ χ²(R) exactly per agent and step",
    "filt": "Σ_t x̃_i(k|k)² / P_ii(k|k) ~ χ²(R) exactly per agent and step, P(k|k) = (1−ℓ)²P(k|k−1) + ℓ²rI (18)",
    "mean": "Σ_t x̃_i / √(R P_ii(k|k−1)) ~ N(0, 1) exactly per agent and step",
}


def check_mc_vs_exact(res: Results, stat: str) -> Verdict:
    """Every cell and step against the exact law of the simulated errors (see `exact_laws`)."""
    r = res.scenario.model.r
    sums, laws, est, refs = [], [], [], []
    R = res.moments(res.cells[0]).count   # every cell ran the same trials
    for c in res.cells:
        P = res.design.exact(c)
        diag = (1 - c.ell) ** 2 * P.diag + c.ell ** 2 * r if stat == "filt" else P.diag   # (18) for P(k|k)
        mom = res.moments(c, "filt" if stat == "filt" else "pred")
        if stat == "trace":
            sums.append(mom.s2.sum(axis=1)), laws.append(P.eigenvalues)
            est.append(sums[-1] / R), refs.append(P.trace)
        elif stat == "mean":
            sums.append(mom.s1), laws.append(diag), est.append(mom.s1 / R), refs.append(np.zeros_like(diag))
        else:
            sums.append(mom.s2), laws.append(diag), est.append(mom.s2 / R), refs.append(diag)
    # one call over every cell and step (each p-value is computed elementwise: the same numbers as cell by cell)
    total, law = np.concatenate(sums), np.concatenate(laws)
    p = (weighted_chi2_p(total, law, R) if stat == "trace" else
         normal_sum_p(total, law, R) if stat == "mean" else chi2_sum_p(total, law, R)).ravel()
    est, refs = (np.concatenate([a.ravel() for a in arrs]) for arrs in (est, refs))
    w = int(np.argmin(p))
    return p_value_test(p, trials=res.trials, min_trials=MIN_TRIALS, measured=float(est[w]), reference=float(refs[w]),
                        detail=(f"{_MC_TESTS[stat]}; exact at any number of trials. {len(res.cells)} cells (algorithm × m "
                                f"× σ_c), {steps_text(res)}; measured: the Monte Carlo "
                                f"{'mean' if stat == 'mean' else 'mean square'} of the cell with the smallest p-value"))


# in report order: one check, four claims
for _id, _source, _statement, _stat in (
        ("savas.mc.trace", "Figs. 1, 3 metric; eqs. (22), §III-B", "Monte Carlo tr P(k|k-1) agrees with the exact "
         "recursion for both filters, every k, m, σ_c", "trace"),
        ("savas.mc.per_agent", "eq. (22)", "Monte Carlo per-agent variances agree with diag P(k|k-1)", "agent"),
        ("savas.mc.filtered", "eq. (18)", "Monte Carlo posterior variances agree with P(k|k) = (1−ℓ)²P(k|k-1) + ℓ²rI",
         "filt"),
        ("savas.mc.unbiased", "eq. (14)", "the errors have zero mean", "mean")):
    claims.claim(_id, _source, _statement, "statistical", hypotheses=(DS,), args=(_stat,))(check_mc_vs_exact)
