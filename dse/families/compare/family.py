"""The compare family: not a paper, an arena. One plant, one graph and one link model given to every
registered estimator that applies (`dse.estimators.network`), on common random numbers. Its modules:
scenario (the declared file), design (every estimator designed for the scenario, and the hypotheses'
numbers), stages (design, exact moments, Monte Carlo, token chain), statistics, claims (hypotheses and
claims on their checks), tables, views (figures and the recording), cost, generator, and this one.
"""
from __future__ import annotations

from dse.contract.family import Family
from dse.contract.options import RunOptions
from dse.estimators.network import registry

from . import generator
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
is reported as not applicable, with the reason. Exact second-moment recursions where they exist (linear filters
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

    def scenario_from_dict(self, data):
        from dse.scenario.declare import parse

        return parse(CompareFile, data)

    def generate(self, seed, edge=None):
        return generator.generate(seed, edge)

    def claims(self):
        return self.module("claims").claims

    def design(self, run, opts, ctx):
        return self.module("stages").design(run.scenario, opts.quick, ctx, tuple(registry().values()))

    def simulate(self, run, opts, ctx, design):
        return self.module("stages").simulate(run.scenario, design, opts.seed, self.trials(run, opts), opts.quick,
                                              opts.workers, opts.chunk_budget_bytes(), ctx)

    def trials(self, run, opts: RunOptions) -> int:
        s = run.scenario.simulation
        return opts.trials if opts.trials is not None else (s.quick_trials if opts.quick else s.trials)

    def cost(self, run, opts):
        return self.module("cost").cost(run.scenario, opts, self.trials(run, opts))

    def design_tables(self, run, design):
        return self.module("tables").design_tables(design)

    def tables(self, run, results):
        return self.module("tables").run_tables(results)

    def views(self, outputs):
        return self.module("views").views(outputs)
