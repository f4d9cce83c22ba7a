"""The ClaimSet of the random-comm-filter family and what its checks share: the tolerances of
propagated quantities, the tests of Monte Carlo means over random clock paths, and the preconditions
that say when a reference was not formed (a runtime finding: too large a system, a lost accuracy).

Per-scenario checks receive the scenario's `ScenarioResults` (hypotheses its `ScenarioDesign`);
run-level checks the run's `Results`.
"""
from __future__ import annotations

import numpy as np

import dse.estimators.gossip_covariance as gc
from dse.contract.claims import ClaimSet
from dse.verify.rules import EPS, Verdict, p_value_test, roundoff_tolerance

from .references import MAX_SCHEME_DIM
from .results import ScenarioResults

claims = ClaimSet(select=lambda res, name: res.scenarios[name], select_design=lambda design, name: design.scenarios[name],
                  modules=tuple(f"{__package__}.{m}" for m in ("hypotheses", "claims_propositions", "claims_theorem",
                                                                "claims_references")))  # report order

MIN_PATHS = 50          # below: a Monte Carlo mean over clock paths is not tested
MIN_TRIALS = 2          # exact-law tests keep their level at any sample size
SECOND_MOMENT_TRUST = 1e-6    # largest relative change of the second-moment solution under a doubled step


#: the id template of a scenario's hypotheses: `<paper>.hyp.<scenario>.<name>`, the scenario named only when the
#: run has several (a user's run `rcf_disc` has `rcf_disc.hyp.alpha`, not `rcf_disc.hyp.rcf_disc.alpha`)
HYP = "{paper}.hyp.{scenario.}"


def hyp(*names: str) -> tuple[str, ...]:
    """The ids of the scenario's hypotheses `names` (see `hypotheses`)."""
    return tuple(HYP + n for n in names)


def sps():
    """scipy.stats, imported when a claim first needs it (it takes a second to import; `dse check` does not)."""
    from scipy import stats

    return stats


def min_eig(X: np.ndarray) -> np.ndarray:
    return np.linalg.eigvalsh((X + np.swapaxes(X, -1, -2)) / 2)[..., 0]


def fmt(x) -> str:
    return "unbounded" if not np.isfinite(x) else f"{x:.6g}"


def rel_diff(a, b) -> float:
    return float(np.max(np.abs(a - b)) / max(float(np.max(np.abs(b))), 1e-300))


# -- what a claim requires of the scenario (`requires=` gates: the claim is not checkable without it) ------------

#: the exact joint covariance of the errors, formed up to N·n = MAX_JOINT_DIM
JOINT = (lambda r: r.joint(r.scenario.main_rate) is not None,
         lambda r: f"N·n = {r.sys.N * r.sys.n} > {gc.MAX_JOINT_DIM}: the exact joint covariance was not formed")
#: the exact second moments of the P-process over clock paths, formed and accurate
SECOND = ((lambda r: "cell_P_second" in r.bounds,
           lambda r: f"N·n(n+1)/2 = {r.sys.N * r.sys.n * (r.sys.n + 1) // 2} > {gc.MAX_SECOND_DIM}: the exact second "
                     "moments of the P-process over clock paths (needed for a test valid at any sample size) were not "
                     "formed"),
          (lambda r: float(r.bounds["cell_P_accuracy"]) <= SECOND_MOMENT_TRUST,
           lambda r: f"the second moments of the P-process lost their accuracy (strongly non-normal A_i: the same "
                     f"computation on a doubled step differs by {float(r.bounds['cell_P_accuracy']):.2g} relative, "
                     f"more than {SECOND_MOMENT_TRUST:g}), so no variance over the clock paths can be trusted"))


#: the gridded scheme's own exact mean covariance, formed up to N·n = MAX_SCHEME_DIM (`what` it is needed for)
def SCHEME(what: str) -> tuple:
    return (lambda r: "scheme_bias_h" in r.bounds), lambda r: f"N·n = {r.sys.N * r.sys.n} > {MAX_SCHEME_DIM}: {what}"


# -- round-off of propagated quantities ------------------------------------------------------------------

def flow_tolerance(values: np.ndarray, n_steps: int, dim: int, growth: float = 1.0) -> tuple[float, str]:
    """Round-off of a quantity propagated over `n_steps` exact steps (matrix exponential, then
    products of length `dim`): each step adds a relative error ~dim·eps of the values it acts
    on, which later steps carry along (amplified at most by `growth`)."""
    scale = float(np.nanmax(np.abs(values))) if np.size(values) else 0.0
    return roundoff_tolerance(scale=max(scale, 1e-300), operations=max(n_steps, 1) * dim, condition=max(growth, 1.0))


def transient_tolerance(r: ScenarioResults, *arrays) -> tuple[float, str]:
    """`flow_tolerance` of transients on the output grid, the growth measured from the initial values."""
    s, sc = r.sys, r.scenario
    vals = np.concatenate([np.ravel(a) for a in arrays])
    vals = vals[np.isfinite(vals)]
    start = max(float(np.abs(s.P0).max()), float(np.abs(s.P_init).max()), 1e-300)
    growth = float(np.max(np.abs(vals)) / start) if vals.size else 1.0
    return flow_tolerance(vals, sc.n_outputs, (s.N * s.n) ** 2, growth)


def path_tolerance(r: ScenarioResults, scale: float) -> tuple[float, str]:
    """Round-off of per-path quantities: each event or output time is one step of products of
    length (N+1)n through the eigenvector basis of the flows (condition number κ); an exact
    exponential over an interval δ ≤ the output step carries a relative error ~eps·‖A_i‖δ
    (scaling and squaring, in the simulator and in the Van Loan reference alike)."""
    ev, s = r.event, r.sys
    steps = int(ev["max_events"]) + r.scenario.n_outputs
    cond = float(ev["condition"]) if np.isfinite(ev["condition"]) else 1.0
    stiff = 1.0 + max(float(np.abs(A).sum(axis=0).max()) for A in s.Ai) * r.scenario.output_step
    return roundoff_tolerance(scale=max(scale, 1e-300), operations=steps * (s.N + 1) * s.n, condition=cond * stiff)


# -- tests for Monte Carlo means over random clock paths -------------------------------------------------

def path_mean_pvalues(s1, s2, n: int, mu, var, *, side: str = "two") -> np.ndarray:
    """p-values for the mean of n i.i.d. nonnegative per-path values X (sums s1 = ΣX, s2 = ΣX²)
    against `mu`, given an upper bound `var` ≥ Var(X) computed without the sample.

    * too low (x̄ < μ): Bernstein's inequality for Y = μ − X ≤ μ with Var Y ≤ v,
      P(x̄ ≤ μ − ε) ≤ exp(−nε²/(2v + 2με/3)), valid at every n and for every law of X ≥ 0;
    * too high (x̄ > μ): the larger of the one-sided p-values of the Student statistic
      (x̄ − μ)/(s/√n) (conservative when X is right-skewed: a large x̄ comes with a large s)
      and of the known-variance statistic (x̄ − μ)√n/√v (conservative when X is left-skewed
      or rare low values exist: v includes them). Rejecting only when both reject keeps the
      level whichever way X is skewed.

    `side`: "two" (equality, 2·min of the two sides) or "upper" (H0: E X ≤ μ)."""
    s1, s2, mu, var = (np.asarray(a, float) for a in (s1, s2, mu, var))
    xbar = s1 / n
    sample_var = np.maximum(s2 / n - xbar ** 2, 0.0) * n / (n - 1)
    v = np.maximum(var, 0.0) + var_floor(mu)
    eps = mu - xbar
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        p_lo = np.where(eps > 0, np.exp(-n * eps ** 2 / (2 * v + 2 * np.abs(mu) * eps / 3)), 1.0)
        t = np.where(sample_var > 0, (xbar - mu) / np.sqrt(sample_var / n),
                     np.where(xbar == mu, 0.0, np.sign(xbar - mu) * np.inf))
        p_t = sps().t.sf(t, n - 1)
        p_z = sps().norm.sf((xbar - mu) / np.sqrt(v / n))
    p_up = np.maximum(p_t, p_z)
    if side == "upper":
        return p_up
    return np.minimum(1.0, 2 * np.minimum(p_lo, p_up))


def var_floor(mu) -> np.ndarray:
    """Round-off level of a variance computed as E[X²] − (E X)² from exact moment equations:
    1e3·eps·μ² (the two terms agree to ~1e3·eps relative after the matrix exponentials)."""
    return 1e3 * EPS * np.square(np.asarray(mu, float)) + 1e-300


def path_test(p, *, n: int, measured, reference, detail: str, min_trials: int = MIN_PATHS) -> Verdict:
    return p_value_test(np.ravel(p), trials=n, min_trials=min_trials, measured=measured, reference=reference,
                        detail=detail)


def worst_cell(p, est, refv):
    k = int(np.argmin(np.ravel(p)))
    return float(np.ravel(est)[k]), float(np.ravel(refv)[k])


def chi2_lower_p(stat, dof) -> np.ndarray:
    return sps().chi2.cdf(np.asarray(stat, float), np.asarray(dof, float))


def chi2_upper_p(stat, dof) -> np.ndarray:
    return sps().chi2.sf(np.asarray(stat, float), np.asarray(dof, float))


def second_variance(b, var) -> np.ndarray:
    """A variance computed as E[X²] − (E X)² from the second-moment solution, plus its round-off:
    (1e3·eps + 10·δ)·3E[(uᵀP_iu)²] with δ the solution's change under a doubled step."""
    return var + (1e3 * EPS + 10 * float(b["cell_P_accuracy"])) * 3 * np.abs(b["cell_P_second"])


def cell_var_note(b) -> str:
    return ("variance over clock paths from the exact second-moment equation of the P-process (its mean agrees "
            f"with (9) to {rel_diff(b['cell_P_mean'], b['cell_bound']):.1e} relative; rounding estimate "
            f"{float(b['cell_P_accuracy']):.1e})")
