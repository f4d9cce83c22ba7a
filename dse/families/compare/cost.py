"""The cost model of a compare run (`dse check`): seconds and peak memory from the scenario's sizes and the
registered estimators' declarations.

Per step, every estimator costs a fixed overhead plus a term per trial and node that grows with the work
per node: n² for the filters that keep a covariance per trial (`trialwise_covariance`), n for the others;
Poisson exchanges add a term per exchange for the filters that work at each one (`per_exchange`). The exact
recursions cost (N n)³ per step; the gain tuning a number of steady states, each a Lyapunov solve ((N n)³)
or an iterative solve on random links. Constants calibrated on this machine (benchmarks/bench_compare.py):
the estimate is meant within a factor 2.
"""
from __future__ import annotations

from dse.contract.cost import MIB, Cost
from dse.contract.options import RunOptions
from dse.estimators.network import registry
from dse.estimators.network_comparison import PER_TRIAL_SUMS, STATS
from dse.simulate.units import RNG_UNIT

from .scenario import CompareFile

#: CPU seconds per step and estimator (overhead), per trial·node·state·round, per trial·node·state² (trial-wise
#: covariances), per trial·node for drawing the step and its statistics, per Poisson exchange, per flop of the
#: exact recursions; measured with benchmarks/bench_compare.py (50 nodes, 4 states, 1,000 trials)
OVERHEAD_S = 4e-4
PER_STATE_S = 2e-8
PER_COV_S = 4e-8
PER_TRIAL_NODE_S = 3e-7
PER_EVENT_S = 2e-5
PER_FLOP_S = 1.5e-9
BASE_MIB = 200


def cost(sc: CompareFile, opts: RunOptions, trials: int) -> Cost:
    B, N, n, K = trials, sc.N, sc.n, sc.simulation.steps
    links = sc.link_model
    specs = [registry()[name] for name in sc.estimator_names]
    cov_trialwise = sum(1 for e in specs if e.trialwise_covariance(links))
    plain = len(specs) - cov_trialwise
    rounds = sc.links.rounds if links.synchronous else 1
    per_step = len(specs) * OVERHEAD_S + B * N * (plain * n * PER_STATE_S * rounds + cov_trialwise * n * n * PER_COV_S
                                                  + PER_TRIAL_NODE_S)
    if not links.synchronous:
        per_step += sc.links.rate * links.topology.E * PER_EVENT_S * sum(1 for e in specs if e.per_exchange)
    mc = K * per_step / max(1, min(opts.workers, 3 if cov_trialwise else 1))
    Nn = N * n
    exact_runs = Nn <= sc.simulation.exact_max_dimension
    exact = K * (Nn ** 3) * PER_FLOP_S * sum(1 for e in specs if e.exact is not None) if exact_runs else 0.0
    g = sc.gains
    solves = 60 if "optimal" in (g.carli_scale, g.reinjection_scale, g.reinjection_zeta) else 3
    tuning = solves * (Nn ** 3) * PER_FLOP_S * (30 if links.random else 10)
    per_trial = 8 * N * (len(specs) * n * 8 + cov_trialwise * n * n * 3)
    exact_mib = 8 * K * Nn * n * len(specs) / MIB
    units, recorded = -(-B // RNG_UNIT), min(K, 101)
    sums_mib = 8 * units * recorded * N * (len(STATS) + len(PER_TRIAL_SUMS)) * len(specs) / MIB
    return Cost(mc + exact + tuning, BASE_MIB + B * per_trial / MIB + exact_mib,
                f"Monte Carlo ≈{mc:.3g} s ({B:,} trials × {K} steps × {len(specs)} estimators, {cov_trialwise} with "
                f"per-trial covariances), exact recursions ≈{exact:.3g} s, gain tuning ≈{tuning:.3g} s",
                kept_mib=(2 * exact_mib if exact_runs else 0.0) + sums_mib, unit_mib=RNG_UNIT * per_trial / MIB,
                sized_by="simulation.steps", kept_what="exact moments and per-step Monte Carlo sums",
                stages={"monte_carlo": mc, "exact_moments": exact, "design": tuning})
