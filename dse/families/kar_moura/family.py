"""The gossip-kalman family: Kar & Moura's GIKF paper (our scenarios E1-E9) and any user scenario of
the same kind. Its modules: scenario (the declared file), assumptions (C.1, D.1 and the blind modes,
decided without Monte Carlo), the stages bounds (the design), gikf (the GIKF Monte Carlo), theorem8
(the Theorem-8 process and the theorem's auxiliary samples) and eq74, results (what they give the
claims), hypotheses and the claims_* modules with their shared checking and stats (gathered in
claims), tables, views (figures and recordings), cost, generator, and this one, which ties them
together.
"""
from __future__ import annotations

from dse.contract.family import Computed, Declared, Family, Paper

from . import generator
from .scenario import PAPER_SCENARIOS, GossipKalmanFile

TITLE = "Kar & Moura: Gossip and distributed Kalman filtering — weak consensus under weak detectability (GIKF)"
#: in the paper's reproduction the structural checks (maps, tokens, indexing, constants) run on these scenarios
#: only; a user's scenario gets all of them
FULL_CHECKS = ("e1", "e2")
#: a run whose Monte Carlo is estimated at this many seconds or more loads the compiled kernels before it forks
#: (`gikf_maps.preload_compiled`): they repay their ~0.5 s in its first seconds
PRELOAD_COMPILED_S = 5.0

NOTES = """The paper has no numerical example; every scenario is ours: E1 (core, ring of 10, single-edge gossip), E2 (rotations,
actuators with C = 0, 3x4 grid, node-initiated gossip), E3 (Remark 9: two protocols with one Ā), negative controls E5 (D.1
violated), E6 (C.1 and D.1 violated), E6b (C.1 only), E7 (periodic Ā), E8 (singular F: D.1 fails, filter bounded) and E9
(scale-up: 30 nodes on a random geometric graph, M = 6, greedy maximal matching with link failures; Ā has no closed form, so
it is estimated by Monte Carlo for the report and the Theorem-8 chains are driven by an independent copy of the protocol;
the claims that need the exact Ā are not checkable there). Every theorem's conclusion names its hypotheses (C.1, D.1,
S.1, a recorded witness walk, the exact Ā, i.i.d. matchings): on the negative controls those conclusions are not
checkable, and what is predicted instead (divergence bounded below by a class's centralized filter, Theorem 26(a), E7's
failure of (25)) is checked. Implementation: covariances in Joseph form (symmetrised) batched over runs, with a
first-order round-off bound carried along every compared matrix; square-root (array) form where iterates can be huge
(starts at c·I, unseen modes); estimates through the error recursion (common w); token indexing corrected; the
Theorem-8 process with a stationary Ā-chain; the Lyapunov envelope f_0^t(P0) carried rescaled (finite over any
horizon). D.1 is read as "some Ā-walk has an invertible Gramian" and decided three ways (witness, certificate of
failure, undecided); the covering reading is reported. Statistical tests use one sample per independent run and are
exact or conservative at any sample size (exact KS p-values, binomial, χ², Clopper-Pearson, Hoeffding, DKW),
Bonferroni within each claim at its share of the report's family-wise confidence; quantiles, never means (E_μ tr X = ∞
in E1). GIKF runs are simulated in RNG units of 1,000; tail statistics, quantiles and Loewner margins are evaluated at
every 5th slot (at most 250 slots, plus every record time); Loewner margins on the first unit of 1,000 runs.
Reconstruction notes: docs/papers/kar-moura.md."""


class GossipKalman(Family):
    id = "gossip-kalman"
    #: the roles the claims' gates read (`roles` on the files: the structural checks, and E3's second protocol)
    paper = Paper("kar-moura", TITLE, PAPER_SCENARIOS, NOTES,
                  declared=(Declared("e1", roles={"full"}), Declared("e2", roles={"full"}),
                            Declared("e3", roles={"comparison"})))
    intro = """N sensors observe a linear Gaussian signal x(t+1) = F x(t) + w(t) through their own y_n = C_n x + v_n (none
need see the whole state; C_n = [] is a node that observes nothing). At every slot a random matching of the graph
decides which pairs swap their (estimate, covariance) pairs; each sensor then updates what it received with its own
observation and predicts (Kar & Moura's gossip interactive Kalman filter, GIKF). Protocols: one random edge per slot,
node-initiated gossip, a given law over matchings, random greedy maximal matchings with link failures, or a given
matching sequence replayed in every run (a protocol or a trace; the theorems, which assume i.i.d. matchings, are then
not checkable and the pathwise statements still are). A disconnected graph is accepted: C.1 (Ā irreducible and
aperiodic) then fails and is reported as a hypothesis that does not hold, like D.1 (a walk of Ā with an invertible
observability Gramian). At most 1,000 sensors (Ā is dense). Monte Carlo runs are streamed in units of 1,000 (the numbers do not depend on the memory
budget); per-slot statistics are kept at a bounded set of slots, so horizons up to 20,000 slots fit. Tables: design
(`design`, `f_eigenvalues`, `abar`, `abar_spectrum`, `sensors`, `classes`, `witness_walks`, `matrices`,
`tail_bounds`, `tv_decay`, `reference_series`; also from `dse check`) and run (`nodes`, `node_entries`,
`quantiles`, `laws`, `tails`, `margins`, `sample_paths`, `matchings`, `nees`, `tokens`, `metrics`). See
docs/papers/kar-moura.md."""
    scenario_model = GossipKalmanFile
    example = "scenarios/e1.toml"
    trials_key = "simulation.runs"
    edges = generator.EDGES

    # -- scenarios ---------------------------------------------------------------------------------------

    def scenario_from_dict(self, data):
        from .scenario import from_dict

        return from_dict(data)

    def paper_scenarios(self):
        from .scenario import load_scenario

        return [load_scenario(name) for name in PAPER_SCENARIOS]

    def roles(self, scenario, paper):
        """The role "full" (the structural checks of maps, tokens and constants) and "comparison" (a second
        protocol is given)."""
        roles = {"full"} if not paper or scenario.name in FULL_CHECKS else set()
        return frozenset(roles | ({"comparison"} if scenario.comparison_protocol is not None else set()))

    def generate(self, seed, edge=None):
        return generator.generate(seed, edge)

    # -- stages ------------------------------------------------------------------------------------------

    def claims(self):
        return self.module("claims").claims

    def design(self, run, opts, ctx):
        """The `bounds` stage of every scenario (`dse check`; `compute` runs the same stages under the same keys)."""
        from .assumptions import horizon
        from .bounds import bounds
        from .cost import scenario_cost
        from .results import Design, ScenarioDesign, sizes

        shapes = []
        for sc in run.scenarios:
            runs, ref_runs, slots = sizes(sc, opts)
            shapes.append((sc, horizon(sc, slots), runs, ref_runs))
        outs = ctx.run_many([(bounds, (sc, slots), {}) for sc, slots, _, _ in shapes], workers=opts.workers,
                            desc="gossip-kalman designs", seconds=True,
                            weights=[scenario_cost(sc, opts)["design_s"] for sc in run.scenarios])
        return Design(opts.quick, {sc.name: ScenarioDesign(sc, slots, runs, ref_runs, opts.quick, b)
                                   for (sc, slots, runs, ref_runs), b in zip(shapes, outs)})

    def compute(self, run, opts, ctx):
        """The designs with the claims' reference computations, then every Monte Carlo stage."""
        # imported once here and inherited by every forked worker (about 1 s each): the designs' filterpy reference,
        # the Wishart starts of the auxiliary stage and the claims' exact KS tests all need scipy.stats
        import filterpy.kalman  # noqa: F401
        import scipy.stats  # noqa: F401
        from dse.estimators import gikf_maps

        # the compiled kernels (numba, the same results) in the processes of this run where its budget has room for them
        workers, cost = max(1, min(opts.workers, len(run.scenarios))), self.cost(run, opts)
        gikf_maps.compiled_allowed = cost.peak_mib + gikf_maps.COMPILED_MIB * workers <= opts.memory_budget_mib
        if gikf_maps.compiled_allowed and cost.stages["monte_carlo"] >= PRELOAD_COMPILED_S:
            gikf_maps.preload_compiled()          # before the workers fork: they share numba instead of loading it
        design = self.design(run, opts, ctx)
        return Computed(design, self.simulate(run, opts, ctx, design))

    def simulate(self, run, opts, ctx, design):
        """Every Monte Carlo stage of every scenario, each a job of `opts.workers` forked processes, the heaviest
        first (by the cost model): the light ones fill in around them, and a scenario's stages run side by side.
        Among them the `bound_checks` of each scenario (the computations only claims use), whose arrays are added
        to the scenario's design (which keeps the key of `bounds`: no Monte Carlo stage reads them)."""
        from .results import Results, ScenarioResults

        jobs = [(d, *job) for d in design.scenarios.values()
                for job in self._stages(d, opts, "full" in self.roles(d.scenario, run.is_paper))]
        outs = ctx.run_many([call for *_, call in jobs], workers=opts.workers, desc="gossip-kalman Monte Carlo",
                            seconds=True, weights=[weight for _, _, weight, _ in jobs])
        done: dict[str, dict] = {name: {} for name in design.scenarios}
        for (d, name, _, _), out in zip(jobs, outs):
            done[d.name][name] = out
        results = {}
        for d in design.scenarios.values():
            out = done[d.name]
            d.bounds.update(out["checks"])
            results[d.name] = ScenarioResults(
                d.scenario, d.slots, d.runs, d.reference_runs, opts.quick, d.bounds, seed=opts.seed, gikf=out["gikf"],
                reference=out["reference"], aux={**out.get("aux", {}), **out.get("pullback_divergent", {})},
                comparison=out.get("comparison"), eq74=out.get("eq74"))
        return Results(opts.seed, opts.quick, results)

    @staticmethod
    def _stages(d, opts, structural: bool) -> list[tuple[str, float, tuple]]:
        """(name, estimated seconds, call) of the Monte Carlo stages of one scenario: independent of each other (each
        has its own random stream), run where a claim needs them: the auxiliary samples where C.1 and D.1 hold,
        Theorem 26(a)'s pull-backs where C.1 holds and a mode is unseen, the eq74 sequences with the structural checks."""
        from .bounds import bound_checks
        from .cost import gikf_bytes_per_run, scenario_cost
        from .eq74 import eq74
        from .gikf import gikf
        from .theorem8 import aux, pullback_divergent, theorem8

        sc, b, assume, cost = d.scenario, d.bounds, d.assume, scenario_cost(d.scenario, opts)
        budget = opts.chunk_budget_bytes()
        protocols = [("gikf", "protocol", sc.protocol)]
        if sc.comparison_protocol is not None:
            protocols.append(("comparison", "comparison", sc.comparison_protocol))
        out = [(name, cost["gikf_s"] / len(protocols),
                (gikf, (sc, b, opts.seed, d.runs, d.slots, which, budget, gikf_bytes_per_run(sc, d.slots, spec)), {}))
               for name, which, spec in protocols]
        out.append(("reference", cost["ref_s"], (theorem8, (sc, b, opts.seed, d.reference_runs, d.slots), {})))
        out.append(("checks", cost["checks_s"], (bound_checks, (sc, d.slots, b), {})))
        if assume.theorem:
            out.append(("aux", cost["aux_s"], (aux, (sc, b, opts.seed, d.reference_runs, d.slots), {})))
        if assume.c1 and assume.undetectable is True:
            out.append(("pullback_divergent", cost["pullback_s"], (pullback_divergent, (sc, b, opts.seed), {})))
        if structural:
            out.append(("eq74", cost["eq74_s"], (eq74, (sc, b, d.slots), {})))
        return out

    def trials(self, run, opts):
        from .results import sizes

        return sizes(run.scenarios[0], opts)[0]

    def cost(self, run, opts):
        from .cost import estimate

        return estimate(list(run.scenarios), opts)
