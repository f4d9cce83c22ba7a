"""The cost model of a compare run (`dse check`): seconds and peak memory from the scenario's sizes.

Per step, every estimator costs a fixed overhead plus a term per trial and node that grows with
the work per node: n² for the filters whose covariances depend on the trial (the GIKF; the
Kalman-consensus, diffusion and CI filters on random links), n for the others; Poisson exchanges
add a term per exchange. The exact recursions cost (N n)³ per step; the gain tuning a number of
steady states, each a Lyapunov solve ((N n)³) or an iterative solve on random links. Constants
calibrated on this machine (benchmarks/bench_compare.py): the estimate is meant within a factor 2.
"""
from __future__ import annotations

from typing import Any

from dse.engine.driver import RunOptions

from .scenario import CompareScenario

#: CPU seconds per step and estimator (overhead), per trial·node·state·round, per trial·node·state² (trial-wise
#: covariances), per trial·node for drawing the step and its statistics, per Poisson exchange, per flop of the
#: exact recursions; measured with benchmarks/bench_compare.py (50 nodes, 4 states, 1,000 trials)
OVERHEAD_S = 4e-4
PER_STATE_S = 2e-8
PER_COV_S = 4e-8
PER_TRIAL_NODE_S = 3e-7
PER_EVENT_S = 2e-5
PER_FLOP_S = 1.5e-9


def estimate(sc: CompareScenario, opts: RunOptions) -> dict[str, Any]:
    from .compute import trial_count

    B = trial_count(sc, opts)
    N, n, K = sc.N, sc.n, sc.steps
    random_links = sc.link_model != "reliable" and not (sc.link_model == "failures" and sc.p_fail == 0)
    E = len(list(sc.graph.build().edges()))
    ests = list(sc.include)
    cov_trialwise = sum(1 for e in ests if e == "gikf" or (random_links and e in ("kcf", "diffusion", "ci")))
    plain = len(ests) - cov_trialwise
    rounds = sc.rounds if sc.link_model != "poisson" else 1
    per_step = len(ests) * OVERHEAD_S + B * N * (plain * n * PER_STATE_S * rounds + cov_trialwise * n * n * PER_COV_S
                                                 + PER_TRIAL_NODE_S)
    if sc.link_model == "poisson":
        per_step += sc.rate * E * PER_EVENT_S * sum(1 for e in ests if e in ("gikf", "pairwise", "ci"))
    mc = K * per_step / max(1, min(opts.workers, 3 if cov_trialwise else 1))
    Nn = N * n
    exact = K * (Nn ** 3) * PER_FLOP_S * sum(1 for e in ests if e not in ("gikf",)) if Nn <= sc.exact_max_dimension else 0.0
    solves = 60 if "optimal" in (sc.carli_scale, sc.reinjection_scale, sc.reinjection_zeta) else 3
    tuning = solves * (Nn ** 3) * PER_FLOP_S * (30 if random_links else 10)
    mib = 200 + 8 * B * N * (len(ests) * n * 8 + cov_trialwise * n * n * 3) / 2 ** 20 + 8 * K * Nn * n * len(ests) / 2 ** 20
    return {"seconds": mc + exact + tuning, "peak_memory_mib": mib,
            "detail": f"Monte Carlo ≈{mc:.3g} s ({B:,} trials × {K} steps × {len(ests)} estimators, {cov_trialwise} with "
                      f"per-trial covariances), exact recursions ≈{exact:.3g} s, gain tuning ≈{tuning:.3g} s"}
