"""The compare family: not a paper, an arena where every registered estimator (`dse.estimators.network`)
runs on one scenario. Its modules: scenario, design (every estimator designed, the hypotheses' numbers),
stages, results (what the claims read, and the run of the stages), claims, tables, views, generator, and
cost (the cost model) and this one.
"""
from __future__ import annotations

from dse.contract.family import Declared, Family
from dse.contract.options import RunOptions

from . import generator
from .cost import estimate
from .scenario import CompareFile



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
    example_declared = Declared("tracking", plugin_names=())   # the example has no plug-in filter
    trials_key = "simulation.trials"
    edges = generator.EDGES
    #: filterpy (0.4 s with scipy.stats), for the centralized filter's reference stage after the Monte Carlo (whether
    #: or not the scenario runs it: on a core the workers leave idle)
    idle_imports = ("filterpy.kalman",)
    run_title = "one network, every estimator"

    def generate(self, seed, edge=None):
        return generator.generate(seed, edge)

    def claims(self):
        return self.module("claims").claims

    def design(self, run, opts, ctx):
        return self.module("results").design(run.scenario, opts.quick, ctx, tuple(run.scenario.estimator_specs.values()))

    def simulate(self, run, opts, ctx, design):
        return self.module("results").simulate(run.scenario, design, opts.seed, self.trials(run, opts),
                                              opts.quick, opts.workers, opts.chunk_budget_bytes(), ctx)

    def external_code(self, scenario) -> str:
        """The plug-in filters' code (`dse.plugin.declare.code_of`)."""
        return "".join(spec.code for spec in scenario.estimator_specs.values() if spec.plugin)

    def trials(self, run, opts: RunOptions) -> int:
        s = run.scenario.simulation
        return opts.trials if opts.trials is not None else (s.quick_trials if opts.quick else s.trials)

    def cost(self, run, opts):
        return estimate(run.scenario, opts, self.trials(run, opts))
