"""The template family: the smallest complete implementation of the contract, to copy when adding
a paper (docs/design.md, "Adding a paper"). Its modules: scenario (the declared file), stages
(design and Monte Carlo), claims (hypotheses and claims on their checks), outputs (tables, figure,
recording), generator (random valid scenarios) and this one, which ties them together.
"""
from __future__ import annotations

from dse.contract.cost import MIB, Cost
from dse.contract.family import Declared, Family
from dse.contract.options import RunOptions
from dse.simulate.units import RNG_UNIT

from . import generator
from .scenario import ConsensusFile

#: CPU seconds per trial, round and node² (the product e W ᵀ), measured with `dse run --quick`
TRIAL_ROUND_S = 1.5e-9
#: CPU seconds of everything else: interpreter start, imports, the figure, the recording and the tables (`dse run
#: --quick example.toml` takes 1.9-2.6 s of CPU, `make bench` section `estimates`)
STARTUP_S = 2.0


class Template(Family):
    id = "template"
    intro = """The template family (the example to copy when adding a paper): N nodes measure a constant θ once,
y_i = θ + v_i with v_i ~ N(0, r), then run average consensus x(t+1) = W x(t) with Metropolis weights W. The
exact mean-square error of node i after t rounds is r (W^{2t})_ii; a Monte Carlo checks it (exact χ² law) and
the geometric approach to the centralized r/N is checked where the graph is connected. Tables: `spectrum`
(design; also from `dse check`) and `mse`."""
    notes = "Statistical verdicts use the exact χ² law of the errors, valid at any number of trials."
    scenario_model = ConsensusFile
    example = "example.toml"
    example_declared = Declared("ring8")   # the example's name: its claims' gates read nothing else
    trials_key = "monte_carlo.trials"
    edges = generator.EDGES

    def generate(self, seed, edge=None):
        return generator.generate(seed, edge)

    def claims(self):
        return self.module("claims").claims

    def design(self, run, opts, ctx):
        return self.module("stages").design(run.scenario)

    def simulate(self, run, opts, ctx, design):
        stages = self.module("stages")
        trials = self.trials(run, opts)
        mc = ctx.run(stages.monte_carlo, run.scenario, opts.seed, trials, opts.chunk_budget_bytes())
        return stages.Results(design, trials, mc["sq"])

    def trials(self, run, opts: RunOptions) -> int:
        mc = run.scenario.monte_carlo
        return opts.trials if opts.trials is not None else (mc.quick_trials if opts.quick else mc.trials)

    def cost(self, run, opts):
        sc, trials = run.scenario, self.trials(run, opts)
        seconds = STARTUP_S + trials * (sc.model.rounds + 1) * sc.n ** 2 * TRIAL_ROUND_S
        kept = 8.0 * 4 * (sc.model.rounds + 1) * sc.n / MIB
        unit = 8.0 * 3 * RNG_UNIT * (sc.model.rounds + 2) * sc.n / MIB
        return Cost(seconds, 300.0 + kept + unit, f"{trials:,} trials x {sc.model.rounds} rounds x {sc.n} nodes",
                    kept_mib=kept, unit_mib=unit, sized_by="model.rounds", kept_what="per-round statistics")

    def design_tables(self, run, design):
        return self.module("outputs").design_tables(design)

    def tables(self, run, results):
        return self.module("outputs").run_tables(results)

    def views(self, outputs):
        return self.module("outputs").views(outputs)
