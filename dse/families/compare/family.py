"""The compare family: not a paper, an arena where every registered estimator (`dse.estimators.network`)
runs on one scenario. Its modules: scenario, design (every estimator designed, the hypotheses' numbers),
stages, results (what the claims read, and the run of the stages), claims, tables, views, generator, and
this one (with the cost model).
"""
from __future__ import annotations

from dse.contract.cost import MIB, Cost
from dse.contract.family import Family
from dse.contract.options import RunOptions
from dse.estimators.network import registry

from . import generator
from .scenario import CompareFile

#: CPU seconds per step and estimator (overhead), per trial·node·state·round, per trial·node·state² (trial-wise
#: covariances), per trial·node for drawing the step and its statistics, per Poisson exchange, per flop of the
#: exact recursions; calibrated with benchmarks/bench_compare.py (50 nodes, 4 states, 1,000 trials)
OVERHEAD_S = 4e-4
PER_STATE_S = 2e-8
PER_COV_S = 4e-8
PER_TRIAL_NODE_S = 3e-7
PER_EVENT_S = 2e-5
PER_FLOP_S = 1.5e-9
BASE_MIB = 200


class Compare(Family):
    id = "compare"
    intro = """One discrete-time linear-Gaussian plant x(k+1) = F x(k) + w(k) seen by sensors y_i(k) = H_i x(k) +
v_i(k) at the nodes of a graph, one link model (reliable links, independent link failures, random matchings or
Poisson-clocked pairwise exchanges, each with optional additive communication noise), and every estimator that
applies, on common random numbers: the centralized Kalman filter (the reference), local Kalman filters without
communication (the floor), the GIKF (Kar & Moura), Carli et al.'s two-stage consensus filter and Savas et al.'s
re-injection filter in vector form, Tanwani's constant-gain filters with pairwise averaging in discrete time, the
Kalman-consensus filter (Olfati-Saber), the diffusion Kalman filter in adapt-then-combine form (Cattivelli & Sayed)
and the consensus-on-information filter (Battistelli & Chisci). An estimator that does not apply to the link model
is reported as not applicable, with the reason; so is a constant-gain filter (Carli's, re-injection, pairwise)
whose mean-square error recursion has no steady state with the gains it would run with (computed; one rule
for the three, tuned or given gains alike). Exact second-moment recursions where they exist (linear filters
with gains that do not depend on the data; the mean over link patterns where it is exact), Monte Carlo with
confidence intervals otherwise. Tables: `applicability`, `gains`, `edge_weights`, `detectability` (design; also
from `dse check`), `estimators` (error against communication), `nodes`, `series`, `token_law` and `metrics`.
See docs/papers/compare.md."""
    notes = """Not a paper: a comparison on one scenario. Statistical verdicts use exact χ² laws where an error is Gaussian
with a known covariance given the link draws (every filter on reliable links against its exact recursion; the
centralized, local and GIKF filters against their own covariances), a one-sided χ² bound for the consistency of
CI, the two-sample Kolmogorov-Smirnov test for the GIKF's token law, and normal z-tests of means of independent
trials only above an effective-sample-size gate, under the report's family-wise confidence. Constant gains are
tuned on the exact steady state of their mean recursion. See docs/papers/compare.md for what each estimator is,
its generalisation to this setting and what it sends."""
    scenario_model = CompareFile
    example = "scenarios/tracking.toml"
    edges = generator.EDGES
    run_title = "one network, every estimator"

    def generate(self, seed, edge=None):
        return generator.generate(seed, edge)

    def claims(self):
        return self.module("claims").claims

    def design(self, run, opts, ctx):
        return self.module("results").design(run.scenario, opts.quick, ctx, tuple(registry().values()))

    def simulate(self, run, opts, ctx, design):
        return self.module("results").simulate(run.scenario, design, opts.seed, self.trials(run, opts), opts.quick,
                                              opts.workers, opts.chunk_budget_bytes(), ctx)

    def trials(self, run, opts: RunOptions) -> int:
        s = run.scenario.simulation
        return opts.trials if opts.trials is not None else (s.quick_trials if opts.quick else s.trials)

    def cost(self, run, opts):
        return estimate(run.scenario, opts, self.trials(run, opts))

    def design_tables(self, run, design):
        return self.module("tables").design_tables(design)

    def tables(self, run, results):
        return self.module("tables").run_tables(results)

    def views(self, outputs):
        return self.module("views").views(outputs)


def estimate(sc: CompareFile, opts: RunOptions, trials: int) -> Cost:
    """The cost model: per step, every estimator costs a fixed overhead plus a term per trial and node that grows
    with its work per node, n² for the filters that keep a covariance per trial (`trialwise_covariance`), n for
    the others; Poisson exchanges add a term per exchange for the filters that work at each one
    (`per_exchange`). The exact recursions cost (N n)³ per step, the gain tuning a number of steady states, each
    a Lyapunov solve ((N n)³) or an iterative solve on random links. Meant within a factor 2."""
    from dse.estimators.network_comparison import PER_TRIAL_SUMS, STATS
    from dse.simulate.units import RNG_UNIT

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
