"""The random-comm-filter family: Tanwani's distributed filter with random communication, for the
paper's reproduction and for users' own scenario files (`family = "random-comm-filter"`).

Its modules: scenario (the declared file), design, references, monte_carlo and topology (the
stages), results (what the claims read), hypotheses and claims* (registered on their checks),
tables, views, figures and recording (the outputs), cost (the estimate) and generator (random
valid scenarios). Compute, claims, tables and outputs (scipy, matplotlib, rerun) are imported
when first needed, so that validating a scenario file and reporting its errors stays fast.
"""
from __future__ import annotations

from dse.contract.family import Family, Paper

from . import generator
from .scenario import RandomCommFile, load_scenario

#: the paper's main scenario (role "main"): the errata, Fig. 1 and the topology sweep S4 are computed on it
MAIN = "s2"


class RandomCommFilter(Family):
    id = "random-comm-filter"
    paper = Paper("tanwani", "Tanwani: Suboptimal filtering over sensor networks with random communication (IEEE TAC "
                             "2022)", ("s1a", "s1b", "s1c", "s2", "s3"),
                  notes="""The paper has no numerical example, no simulation and no table (its Fig. 1 is a schematic): the scenarios
here (S1a-c, S2, S3 and the topology sweep S4) were designed for this reproduction, and their reference numbers
were computed independently.""")
    intro = """A continuous-time plant dx = Ax dt + B dω observed by N sensor nodes, dy_i = H_i x dt + dv_i; every node
runs a constant-gain filter (5) and, at the rings of independent Poisson clocks of rate λ on the edges of a graph,
moves its estimate towards a neighbour's (6) (Tanwani's distributed filter with random communication). Computed
exactly: the mean bound (9) and the exact mean joint error covariance (transients and steady states per node), the
critical rates of both, Ā, R of (10), S of (11), the true large-rate limit S_true, the explicit constants of (12),
the centralized Kalman–Bucy reference. Simulated: an exact event-driven Monte Carlo (per-path covariances and the
bound (14) along every clock path), a gridded one at every simulated rate, and one frozen clock path. A disconnected
graph is accepted (item 1 of Theorem III.1 holds on any graph; item 2 then rests on the hypothesis `connected`,
reported as failing); each node may start its bound at its own P_i(0) (`sensors[].P_init`, the hypothesis `initial`
says whether it dominates the initial error). The gridded step is chosen from the rates when not given. Monte Carlo
is streamed over trials (units of 1,000) and time (moments per output time only), so horizons up to 1,000 s and
10⁷ gridded trials fit the memory budget. Tables: design (`design`, `spectra`, `matrices`, `rates`, `steady_states`,
`sweep`, `sweep_nodes`, `series`, `graph_nodes`, `graph_edges`, `node_entries`; also from `dse check`) and run
(`nodes`, `mc_series`, `sample_paths`, `path_series`, `path_events`, `cells`, `frozen`, `poisson`, `references`,
`scheme_bias`, `metrics`, and for the paper `topology`, `topology_rates`, `topology_graphs`). See
docs/papers/tanwani.md."""
    notes = """Model choices: x(0) ~ N(m0, P0), x̂_i(0) = m0, one Poisson clock per undirected edge with both endpoints
updating from pre-jump values (per ordered pair with `communication.mode = "ordered"`), α = min(1/2, 1/d_max) unless
given, gains = the centralized Kalman–Bucy gain split by columns (L_i = N K_i) unless given, P_i(0) = P0 unless given
per node. E[e eᵀ] is the second moment. Derived here, not in the paper: the exact mean joint covariance ODE, the
per-path quantities, the second moments of the P-process over clock paths, the critical rates, the limit S_true, the
first-order rate of (9) and explicit constants for (12). Monte Carlo: an exact event-driven simulator (exact Poisson
events, exact Gaussian transitions between events, exact per-path covariances) and a gridded one (exact flow over h/2,
Poisson(λh) rings per clock per step in alternating clock order, flow over h/2; its own exact mean covariance gives
its O(h²) bias). Statistical verdicts use exact laws (χ² of whitened Gaussian errors given the clocks, Poisson and
binomial counts, Efron's bound for paired symmetric differences) or, for means over random clock paths, Bernstein's
inequality with the exact variance for low means and a Student plus known-variance test for high means. Typos that
numbers cannot show (no claim): (13a) reads '(A − L_iH_i) de_i' (the corrected form is used and checked by
`prop3_2.flow_equality`); the interval in (5); lost minus signs in the problem statement; 'v_i standard' with
covariance V_i; Lemma III.3's garbled text; Ũ† = Ũ. Reconstruction notes: docs/papers/tanwani.md."""
    scenario_model = RandomCommFile
    example = "example.toml"
    trials_key = "simulation.trials"
    edges = generator.EDGES
    #: scipy.stats for the laws of the claims' tests (0.3 s; python-control and scipy.integrate, the claims' oracles,
    #: are imported by the references stage's worker, which computes them), and the claims and tables modules
    idle_imports = ("scipy.stats", ".claims", ".tables")

    # -- scenarios -----------------------------------------------------------------------------------------

    def paper_scenarios(self):
        return [load_scenario(name) for name in self.paper.scenario_ids]

    def roles(self, scenario, paper):
        """"main": the paper's S2, or the one scenario of a user's run."""
        return frozenset({"main"}) if not paper or scenario.name == MAIN else frozenset()

    def main(self, run) -> RandomCommFile:
        return next(sc for sc in run.scenarios if "main" in self.roles(sc, run.is_paper))

    def generate(self, seed, edge=None):
        return generator.generate(seed, edge)

    # -- stages ---------------------------------------------------------------------------------------------

    def claims(self):
        return self.module("claims").claims

    def design(self, run, opts, ctx):
        """Every scenario's design stage (the hypotheses are decided on it)."""
        calls, weights = self._design_calls(run, opts)
        return self._design(run, ctx.run_many(calls, workers=opts.workers, weights=weights,
                                              seconds=True, desc="random-comm-filter design"))

    def simulate(self, run, opts, ctx, design):
        """The references and the Monte Carlo of every scenario, and (paper) the topology sweep on the main one;
        the heaviest stages first (by the cost model), in `opts.workers` processes."""
        calls, weights = self._simulate_calls(run, opts)
        return self._results(run, opts, design, ctx.run_many(calls, workers=opts.workers, weights=weights,
                                                             seconds=True, desc="random-comm-filter stages"))

    def compute(self, run, opts, ctx):
        """The design and every other stage in one pool of workers, heaviest first (no stage of the simulation
        reads the design, so none waits for it)."""
        from dse.contract.family import Computed

        (dc, dw), (sc, sw) = self._design_calls(run, opts), self._simulate_calls(run, opts)
        out = ctx.run_many(dc + sc, workers=opts.workers, weights=dw + sw, seconds=True,
                           desc="random-comm-filter stages")
        design = self._design(run, out[:len(dc)])
        return Computed(design, self._results(run, opts, design, out[len(dc):]))

    def _design_calls(self, run, opts):
        design, cost = self.module("design"), self.module("cost")
        return ([(design.scenario_design, (sc, opts.quick, opts.seed), {}) for sc in run.scenarios],
                [cost.scenario_cost(sc, opts)["design_s"] for sc in run.scenarios])

    def _design(self, run, out):
        design = self.module("design")
        return design.Design({sc.name: design.ScenarioDesign(sc, dict(r)) for sc, r in zip(run.scenarios, out)})

    def _simulate_calls(self, run, opts):
        mc, refs, cost = (self.module(m) for m in ("monte_carlo", "references", "cost"))
        budget, calls, weights = opts.chunk_budget_bytes(), [], []
        for sc in run.scenarios:
            trials, ev = sc.trial_counts(opts.trials, opts.quick)
            calls += [(refs.compute_references, (sc,), {})]
            calls += [(mc.simulate_gridded_rate, (sc, opts.seed, trials, rate, min(ev, trials, mc.PAIR_MAX)
                                                  if rate == sc.main_rate else 0, budget), {}) for rate in sc.rates]
            calls += [(mc.simulate_event_rate, (sc, opts.seed, ev, budget), {}),
                      (mc.simulate_frozen, (sc, opts.seed, ev, budget), {})]
            refs_s, event_s, frozen_s, *grid_s = cost.scenario_cost(sc, opts)["stages"][1:]
            weights += [refs_s, *grid_s, event_s, frozen_s]
        if run.is_paper:
            calls.append((self.module("topology").compute_topology, (self.main(run), opts.quick), {}))
            weights.append(cost.TOPOLOGY_S)
        return calls, weights

    def _results(self, run, opts, design, out):
        results, out = self.module("results"), iter(out)
        scenarios = {}
        for sc in run.scenarios:
            reference, gridded = next(out), {rate: next(out) for rate in sc.rates}
            scenarios[sc.name] = results.ScenarioResults(sc, design.scenarios[sc.name], reference, gridded, next(out),
                                                         next(out), *sc.trial_counts(opts.trials, opts.quick))
        return results.Results(scenarios, self.main(run).name, next(out) if run.is_paper else None)

    def trials(self, run, opts):
        return max(sc.trial_counts(opts.trials, opts.quick)[0] for sc in run.scenarios)

    def cost(self, run, opts):
        return self.module("cost").estimate(run.scenarios, opts, paper=run.is_paper)

