"""Time and memory of a compare run, estimated from the scenario before anything runs (`dse check`, and the
driver's refusals: memory beyond the budget, time beyond --max-time; `dse check` also refuses to compute a
design estimated beyond its own budget).

Time, in CPU seconds (every constant below was measured on the development machine, 2 cores, one process,
OPENBLAS_NUM_THREADS=1; `make bench`, section `estimates`, reports estimate / measured for every shipped
and generated scenario):

* start-up and outputs: the interpreter and imports, the figures, recordings and tables (fitted on
  `dse run --quick` of the shipped scenarios: about 3 s beyond the stages, whatever their size);
* the design (`stages.tune`): the gain searches of Carli's and the re-injection filter. Each searched gain
  costs one steady state of the mean recursion per candidate (`tuning_solves`). On reliable synchronous links
  a steady state is a Stein doubling and an eigenvalue problem on N n x N n; on random links it is the sum
  of about TERMS_PER_SOLVE terms of the mean step, each node mixes (N x N by N x N n², which dominate) and
  edge patterns (N² x E by E x n²) (`SOLVE_TERM_S`; with more rounds a term costs more and fewer terms are
  needed: 1.5x and 0.67x at two rounds, the same in all). Fitted on random geometric graphs of 10 to 50
  nodes (2 states, failures and reliable links, 1 and 2 rounds, quick and not), measured by the CPU time
  of the design stage alone and the number of terms it summed (105-117 per steady state at one round);
* the Monte Carlo: per step a fixed overhead per estimator and a term per trial and node that grows with
  its work per node (n² for the filters that keep a covariance per trial, n for the others); Poisson
  exchanges add a term per exchange (calibrated with benchmarks/bench_compare.py: 50 nodes, 4 states,
  1,000 trials);
* the exact recursions, (N n)³ per step.
"""
from __future__ import annotations

from dse.contract.cost import MIB, Cost
from dse.contract.options import RunOptions

from .scenario import CompareFile

#: CPU seconds: interpreter start and imports; figures, recordings and tables (whole `dse run --quick` runs of
#: the shipped scenarios minus their stages)
STARTUP_S = 1.4
OUTPUTS_S = 1.6
#: CPU seconds per step and estimator (overhead), per trial·node·state·round, per trial·node·state² (trial-wise
#: covariances), per trial·node for drawing the step and its statistics, per Poisson exchange, per flop of the
#: exact recursions
OVERHEAD_S = 4e-4
PER_STATE_S = 2e-8
PER_COV_S = 4e-8
PER_TRIAL_NODE_S = 3e-7
PER_EVENT_S = 2e-5
PER_FLOP_S = 1.5e-9
BASE_MIB = 200
#: the design: a fixed part; per steady state on reliable links, per (N n)³; on random links, terms of the
#: mean step per steady state and the CPU seconds of one term: a + b·N³·n² (node mixes) + c·N²·E·n² (edge patterns)
DESIGN_BASE_S = 0.15
RELIABLE_SOLVE_S = 4e-9
TERMS_PER_SOLVE = 110
SOLVE_TERM_S = (4e-5, 3.2e-9, 2e-11)
#: steady states computed beside the searches: each constant-gain filter's own (with its radius), Carli's
#: gains without fusion
FINISH_SOLVES = 4


def _scale_search(quick: bool) -> int:
    """Steady states of one search of a gain scale: a log grid, then golden section (`search_grid`)."""
    grid, iters = (7, 6) if quick else (17, 18)
    return grid + iters + 2


def tuning_solves(sc: CompareFile, quick: bool, running: set[str]) -> int:
    """Steady states the design computes: the searches `gains` asks for (`optimal`) of the running
    constant-gain filters, and their own steady states."""
    g = sc.gains
    solves = FINISH_SOLVES if running & {"carli", "reinjection", "pairwise"} else 0
    if "carli" in running and g.carli_scale == "optimal":
        solves += _scale_search(quick)
    if "reinjection" in running:
        iters = _scale_search(quick) - (7 if quick else 17)
        if g.reinjection_scale == "optimal" and g.reinjection_zeta == "optimal":
            sweeps, zeta_grid = (1, 5) if quick else (2, 11)
            solves += 1 + sweeps * (zeta_grid + 2 * iters)
        elif g.reinjection_zeta == "optimal":
            solves += 11 * 3           # a finer tolerance: about three searches' worth of terms
        elif g.reinjection_scale == "optimal":
            solves += _scale_search(quick)
    return solves


def design_seconds(sc: CompareFile, quick: bool) -> float:
    """CPU seconds of the design stage (what `dse check` computes)."""
    links = sc.link_model
    running = {name for name in sc.estimator_names if not sc.estimator_specs[name].applies(links)}
    solves = tuning_solves(sc, quick, running)
    N, n, E = sc.N, sc.n, links.topology.E
    if not links.random and links.synchronous:
        per_solve = RELIABLE_SOLVE_S * (N * n) ** 3
    else:
        a, b, c = SOLVE_TERM_S
        per_solve = TERMS_PER_SOLVE * (a + b * N ** 3 * n * n + c * N * N * E * n * n)
    return DESIGN_BASE_S + solves * per_solve


def design_mib(sc: CompareFile) -> float:
    """MiB the design holds on random links: the edge patterns (N² x E) and the blocks they act on, with
    their temporaries (`joint_moments.apply_edge_pattern`)."""
    links = sc.link_model
    if not links.random:
        return 0.0
    N, n, E = sc.N, sc.n, links.topology.E
    return 8.0 * (N * N * E + 6 * E * n * n + 8 * (N * n) ** 2) / MIB


#: CPU seconds per step, trial, node and unit of a plug-in filter's declared `cost_weight` (a local Kalman filter
#: on every node, weight 1, measured with benchmarks/bench_plugin.py)
PLUGIN_UNIT_S = 1.5e-7


def plugin_step_seconds(sc: CompareFile, trials: int, spec) -> float:
    """CPU seconds of one step of a plug-in filter beside the built-ins' terms: its declared weight (relative
    to a local Kalman filter on every node), and delivering its messages (N · max degree · n numbers per
    exchange and trial, up to two messages of n numbers per exchange)."""
    links = sc.link_model
    rounds = sc.links.rounds if links.synchronous else max(1, int(sc.links.rate * links.topology.E))
    D = int(links.topology.degrees.max(initial=1))
    return trials * sc.N * (spec.cost_weight * PLUGIN_UNIT_S + 2 * rounds * D * sc.n * PER_STATE_S)


def time_limits(sc: CompareFile, trials: int) -> dict[str, float]:
    """name -> the CPU seconds a plug-in filter may take by default (`dse.plugin.declare.LIMIT_FACTOR` times
    its share of the estimate, at least `MIN_LIMIT_S`)."""
    from dse.plugin.declare import LIMIT_FACTOR, MIN_LIMIT_S

    K = sc.simulation.steps
    return {name: max(MIN_LIMIT_S, LIMIT_FACTOR * K * (OVERHEAD_S + plugin_step_seconds(sc, trials, spec)))
            for name, spec in sc.estimator_specs.items() if spec.plugin}


def estimate(sc: CompareFile, opts: RunOptions, trials: int) -> Cost:
    """The cost model (module doc); `design_s` is the design stage alone, sized by `graph.n`."""
    from dse.estimators.network_comparison import PER_TRIAL_SUMS, STATS
    from dse.simulate.units import RNG_UNIT

    B, N, n, K = trials, sc.N, sc.n, sc.simulation.steps
    links = sc.link_model
    specs = [sc.estimator_specs[name] for name in sc.estimator_names]
    cov_trialwise = sum(1 for e in specs if e.trialwise_covariance(links))
    plain = len(specs) - cov_trialwise
    rounds = sc.links.rounds if links.synchronous else 1
    per_step = len(specs) * OVERHEAD_S + B * N * (plain * n * PER_STATE_S * rounds + cov_trialwise * n * n * PER_COV_S
                                                  + PER_TRIAL_NODE_S)
    per_step += sum(plugin_step_seconds(sc, B, e) for e in specs if e.plugin)
    if not links.synchronous:
        per_step += sc.links.rate * links.topology.E * PER_EVENT_S * sum(1 for e in specs if e.per_exchange)
    mc = K * per_step / max(1, min(opts.workers, 3 if cov_trialwise else 1))
    Nn = N * n
    exact_runs = Nn <= sc.simulation.exact_max_dimension
    exact = K * (Nn ** 3) * PER_FLOP_S * sum(1 for e in specs if e.exact is not None) if exact_runs else 0.0
    design = design_seconds(sc, opts.quick)
    per_trial = 8 * N * (len(specs) * n * 8 + cov_trialwise * n * n * 3)
    exact_mib = 8 * K * Nn * n * len(specs) / MIB
    units, recorded = -(-B // RNG_UNIT), min(K, 101)
    sums_mib = 8 * units * recorded * N * (len(STATS) + len(PER_TRIAL_SUMS)) * len(specs) / MIB
    seconds = STARTUP_S + design + mc + exact + OUTPUTS_S
    peak = BASE_MIB + max(B * per_trial / MIB + exact_mib, design_mib(sc))
    return Cost(seconds, peak,
                f"start-up and outputs ≈{STARTUP_S + OUTPUTS_S:.2g} s, design (gain searches) ≈{design:.3g} s, "
                f"Monte Carlo ≈{mc:.3g} s ({B:,} trials × {K} steps × {len(specs)} estimators, {cov_trialwise} with "
                f"per-trial covariances), exact recursions ≈{exact:.3g} s",
                design_s=design, design_sized_by="graph.n",
                kept_mib=(2 * exact_mib if exact_runs else 0.0) + sums_mib, unit_mib=RNG_UNIT * per_trial / MIB,
                sized_by="simulation.steps", kept_what="exact moments and per-step Monte Carlo sums",
                stages={"design": design, "monte_carlo": mc, "exact_moments": exact})
