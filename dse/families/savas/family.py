"""The noisy-consensus-filter family: Savas, Srivastava & Leonard's paper and users' scenario files of
the same kind (`family = "noisy-consensus-filter"`). Its modules: scenario (the declared file);
cells, design and monte_carlo (the stages) and results (what they give the claims); claims (the
hypotheses and claims on their checks, with exact_laws and reference_values); tables, figures and
recordings (the views); cost and generators; this one ties them together. Everything but the
scenario and the generator's edge cases is imported on first use, so that validating a file and
reporting its errors stays fast.
"""
from __future__ import annotations

from dse.contract.family import Family, Paper
from dse.contract.options import RunOptions

from .generators import EDGES
from .scenario import NoisyConsensusFile


class NoisyConsensusFilter(Family):
    id = "noisy-consensus-filter"
    paper = Paper("savas", "Savas, Srivastava & Leonard: On distributed linear filtering with noisy communication",
                  ("paper",), notes="""Reconstructions (values the paper does not give; our choices): σ_c grid {0, 0.25,
0.5, 1, 1.5, 2, 3}, X₀ variance σ = 1, Fig. 2 range m = 0..20, optimiser = dense grid, finer local grids and a
box-constrained Newton method from the lowest local minima. Fig. 3 uses the gains that are optimal for the corrected
(16); the gains from the printed (16) are in Fig. 2 (dashed). Monte Carlo: independent seeded streams per unit of 1,000
trials and per (m, horizon); the metric is the ddof = 1 sample variance summed over agents. See docs/papers/savas.md.""")
    intro = """A scalar random walk x(k+1) = x(k) + w(k) measured by N agents, y_i(k) = x(k) + n_i(k), who
average their estimates over a doubly stochastic consensus matrix Q for m rounds between two measurements,
each round adding independent N(0, σ_c²) noise at every agent. Two filters are simulated and checked in
every cell (m, σ_c): Carli et al.'s two-stage filter (7)+(9) with a fixed gain, and the paper's filter
with re-injection (11)-(13) with optimal or fixed gains (ℓ, ζ); the exact covariances of (22), the
steady state of Theorem 1 and the centralized Kalman filter are the references. Tables: `consensus_matrix`,
`spectrum`, `references`, `gains`, `carli_thresholds`, `cells`, `steady_covariance` (design; also from
`dse check`), `nodes`, `trace_series`, `node_series`, `sample_paths`, `consensus_rounds` and `metrics`.
Networks are connected, of 2 to 1,000 agents; horizons up to 100,000 steps (the Monte Carlo streams
over trials and time; statistics are kept at `sweep.recorded_steps` steps)."""
    notes = """Statistical verdicts use exact laws of the simulated errors given the gains (χ² for per-agent mean squares,
normal for sums, conservative Chernoff bounds for the trace), valid at any number of trials, under the report's
family-wise confidence."""
    scenario_model = NoisyConsensusFile
    example = "paper.toml"
    trials_key = "monte_carlo.trials"
    edges = EDGES
    #: the scipy modules the claims import (linalg, special, optimize: about 0.4 s)
    idle_imports = ("scipy.linalg", "scipy.optimize", "scipy.special")

    def paper_scenarios(self):
        from dse.scenario.fields import load_toml

        data = load_toml(self.directory() / "paper.toml")
        data.pop("family")
        return (self.scenario_from_dict(data),)

    def generate(self, seed, edge=None):
        return self.module("generators").generate(seed, edge)

    def claims(self):
        return self.module("claims").claims

    def design(self, run, opts, ctx):
        design, sc = self.module("design"), run.scenario
        return design.Design.of(sc, ctx.run(design.design_arrays, sc, self.module("cells").gain_grid(sc, opts.quick)))

    def simulate(self, run, opts, ctx, design):
        return self.module("results").simulate(ctx, run.scenario, design, opts.seed, self.trials(run, opts),
                                               workers=opts.workers, budget_bytes=opts.chunk_budget_bytes())

    def trials(self, run, opts: RunOptions) -> int:
        mc = run.scenario.monte_carlo
        return opts.trials if opts.trials is not None else (mc.quick_trials if opts.quick else mc.trials)

    def cost(self, run, opts):
        return self.module("cost").estimate(run.scenario, opts, self.trials(run, opts))

    def views(self, outputs):
        return self.module("figures").views(outputs) + self.module("recordings").views(outputs)
