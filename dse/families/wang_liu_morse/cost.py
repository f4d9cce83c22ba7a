"""The cost model of a hybrid-observer run (`dse check`, and the refusal of runs whose
non-streamable part does not fit the memory budget): seconds and peak memory from the
scenario's sizes, without simulating.

Time: the design (ρ's search within its budget, σ's enumeration), the sampled Lemma 5/6 checks, and
per run the interval plan (A(s), B(s), G(s) once per distinct weight sequence) and the trials:
every time instant (sample or event) costs a fixed overhead per chunk of trials and B D² for
the propagation of the B trials' states, every estimator iteration a fixed overhead and
B (mn)², and every sample at which the continuous bound is checked or stored B·mn; then the
tables, figures and recordings. Memory: the interpreter and libraries, the largest chunk of
trials, and what is kept whole: trial 0 at every event index and stored sample, statistics per
event and sample, trial 0's iterates and source sets of the first intervals, and the tables
built from them. The constants are fitted to the CPU time of measured runs on this machine (2 to
32 agents, 15 to 2,000 intervals, q 5 to 2,000, 8 to 20,000 trials: every fitted time within
0.9-1.1 of the measurement; `benchmarks/bench_wang_liu_morse.py --estimate` compares whole runs):
the estimate is meant within a factor 2 of an unloaded machine's wall time.
"""
from __future__ import annotations

import math

from dse.contract.cost import MIB, Cost
from dse.contract.options import RunOptions

from . import simulation
from .scenario import HybridFile

#: fitted CPU seconds (this machine, one BLAS thread): per time instant and chunk, per trial·D² of the
#: propagation, per iteration and chunk, per trial·(mn)² of an iteration, per event index and chunk, per
#: trial·((mn)² + 20 mn) of an event's bounds, per trial·mn of a checked or stored sample
INSTANT_S = 2.2e-5
PROPAGATION_S = 7.3e-11
ITERATION_S = 9.5e-6
ITERATION_FLOP_S = 5e-11
EVENT_S = 3.8e-4
EVENT_FLOP_S = 9.1e-11
SAMPLE_CHECK_S = 4.2e-8
#: design: fixed; ρ's search: per prefix examined (times 1 + n³/40, its products and norms), per subset of
#: letters and letter of the tail bounds (times 1 + n³/8,000); then per flop of σ and of the Lemma 5/6 samples
DESIGN_S = 0.1
RHO_PREFIX_S = 6e-7
#: per multiply-add of the integer matrix products that test the strong connectivity of the sampled graphs
#: (numpy's integer matmul, no BLAS): 4,059 graphs of 64 agents take 4.1 s (`design.lemma_samples`)
SCC_OP_S = 5.5e-10
RHO_TAIL_S = 2.5e-5
#: Section 4's model-mismatch demonstration (two filterpy Kalman filters over 2,000 steps; the paper's extras)
MISMATCH_S = 0.4
#: outputs: per figure, per recording, per table row (build and write)
FIGURE_S = 0.15
RECORDING_S = 0.08
#: importing the numeric, table, plotting and recording libraries
IMPORT_S = 1.2
ROW_S = 2e-6
BASE_MIB = 330.0
TABLE_ROW_BYTES = 160.0
#: the tables' frames and their Parquet and CSV encodings alive at once, at the peak
TABLE_COPIES = 1.5


def _flop_s(mn: int) -> float:
    """Seconds per flop of the dense products of the design checks (BLAS is faster on larger blocks)."""
    return 6e-11 + 1.5e-7 / mn ** 2


def design_seconds(sc: HybridFile, extras: bool) -> float:
    from .design import connected_graph_count, sigma_skip_reason

    m, n = sc.m, sc.n
    mn = m * n
    N = (m - 1) ** 2 + 1
    seconds = DESIGN_S + rho_seconds(m, n, N) * (1 + extras * m)
    if sigma_skip_reason(m, n) is None:                  # σ is enumerated (design.sigma_skip_reason)
        seconds += connected_graph_count(m) * mn ** 3 * _flop_s(mn)
    return seconds + sample_seconds(sc) + (0.25 if extras else 0.0)


def rho_seconds(m: int, n: int, N: int) -> float:
    """An upper estimate of ρ's search (dse/estimators/projection_products.py): the prefixes it may
    examine (its budget, or every repeat-free word when fewer) and the tail bounds over the subsets
    of at most TAIL_MAX_LETTERS letters (m distinct letters at most)."""
    import dse.estimators.projection_products as pp

    # up to 4 agents the search examines about a hundred prefixes (96 at most over 160 random cases): 10^4 bounds it
    prefixes = min(jd_words(m, N), pp.prefix_budget(n)) if m > 4 else 10 ** 4
    tails = (2 ** m * m if m <= pp.TAIL_MAX_LETTERS else 0) * RHO_TAIL_S * (1 + n ** 3 / 8000)
    return prefixes * RHO_PREFIX_S * (1 + n ** 3 / 40) + tails


def jd_words(m: int, N: int) -> int:
    """Complete repeat-free words of length <= N over m letters (a bound of the search's prefixes; capped
    at 10^9 beyond m = 6)."""
    import dse.estimators.projection_products as pp

    return pp.count_complete_repeat_free_words(m, N) if m <= 6 else 10 ** 9


def sample_seconds(sc: HybridFile) -> float:
    """The sampled checks of Lemmas 5 and 6 (`design.lemma_samples`)."""
    from .design import LEMMA5_FLOPS, LEMMA5_SAMPLES, LEMMA6_FLOPS, LEMMA6_SAMPLES

    m, mn = sc.m, sc.m * sc.n
    per_product = ((m - 1) ** 2 + 1) * mn ** 3
    pool = 1606 if m == 4 else (4000 if m > 4 else 50)
    samples = min(LEMMA5_SAMPLES, max(min(pool, LEMMA5_SAMPLES), LEMMA5_FLOPS // per_product))
    if per_product * min(samples, pool) > 20 * LEMMA5_FLOPS:
        samples = max(1, 20 * LEMMA5_FLOPS // per_product)
    count6 = max(1, min(LEMMA6_SAMPLES, LEMMA6_FLOPS // mn ** 3))
    lemma6 = count6 * mn ** 3
    tested = (4000 if m > 4 else 0) + count6         # strong connectivity of the candidate graphs
    scc = tested * m ** 3 * (math.ceil(math.log2(max(m, 2))) + 1) * SCC_OP_S
    return (samples * per_product + lemma6) * _flop_s(mn) + scc


def run_cost(sc: HybridFile, run, trials: int, n_i: list[int], budget_bytes: float) -> dict[str, float]:
    """Seconds and bytes of one run (see the module docstring)."""
    m, n, S, q = sc.m, sc.n, run.intervals, run.q
    mn = m * n
    nw = sum(n_i)
    D = n + nw + 2 + mn + n
    B = trials if run.monte_carlo else 1
    samples = S * sc.T / sc.sampling.step + 1
    instants = samples + S * m
    per_trial = simulation.bytes_per_trial(sc, n_i)
    chunk = min(B, max(1, int(budget_bytes // max(per_trial * 1000, 1.0))) * 1000)
    chunks = math.ceil(B / chunk)
    distinct = min(S, 2 * max(1, len(sc.graph_masks))) + (6 if run.leave else 0)
    matrices = distinct * (1 + chunks) * q * mn * mn * (m + n) * _flop_s(mn)
    checked = samples if (simulation.is_theorem_run(run) and run.timing == "sync") else min(samples, sc.sampling.stored)
    trials_s = (instants * chunks * INSTANT_S + instants * B * D * D * PROPAGATION_S + S * q * chunks * ITERATION_S
                + S * q * B * mn * mn * ITERATION_FLOP_S + S * chunks * EVENT_S + S * B * (mn * mn + 20 * mn) * EVENT_FLOP_S
                + checked * B * mn * SAMPLE_CHECK_S)
    kf = samples * 6e-5 if run.noise else 0.0
    stored = min(samples, sc.sampling.stored)
    keep = max(1, min(S, simulation.SOURCE_VALUES // max(q * m * m, 1), simulation.ITERATE_VALUES // max((q + 1) * mn, 1)))
    kept_bytes = 8 * ((S + 1) * (4 * mn + nw + 8 * m + 20) + stored * (n * (m + 2) + 3 * m + 8)
                      + keep * ((q + 1) * mn + q * m * m + m * (q + 1)) + 30 * B + 6 * S)
    table_rows = ((S + 1) * m * 3 + stored * (m + 1) + min(stored * n * (m + 2), 2_000_000) + keep * (q + 1) * m
                  + keep * q * m * 2 + S + B + 60)
    return {"seconds": S * 2e-4 + matrices + trials_s + kf + table_rows * ROW_S + RECORDING_S,
            "chunk_bytes": chunk * per_trial, "kept_bytes": kept_bytes, "table_bytes": table_rows * TABLE_ROW_BYTES,
            "trials": B, "chunks": chunks, "samples": samples}


def estimate(scenarios, opts: RunOptions, *, extras: bool = False) -> Cost:
    """The run's cost (see the module docstring). The driver refuses it when what cannot be streamed
    (trial 0 and the statistics at every event index and stored sample, and their tables) does not
    fit the memory budget beside the interpreter, naming the largest run's `intervals` (or
    `sampling.stored` when its stored samples dominate)."""
    budget = opts.chunk_budget_bytes()
    runs = sum(len(sc.runs) for sc in scenarios)
    figures = 9 if extras else 4 + runs                  # the paper's figures; a user's: 4 and one per run
    seconds, kept, tables, chunk, parts = IMPORT_S + figures * FIGURE_S, 0.0, 0.0, 0.0, []
    kept_mib, worst = 0.0, None
    for sc in scenarios:
        n_i = [loc.n_i for loc in sc.locs]
        trials = sc.trials_for(opts)
        design_s = design_seconds(sc, extras)
        costs = [run_cost(sc, run, trials, n_i, budget) for run in sc.runs]
        run_s = sum(c["seconds"] for c in costs) / max(1, min(opts.workers, len(costs)))
        seconds += design_s + run_s
        kept += sum(c["kept_bytes"] for c in costs)
        tables += sum(c["table_bytes"] for c in costs)
        chunk = max(chunk, max(c["chunk_bytes"] for c in costs) * max(1, min(opts.workers, len(costs))))
        parts.append(f"{sc.name if extras else 'scenario'}: design ≈{design_s:.2g} s, {len(costs)} runs ≈{run_s:.3g} s "
                     f"({sum(c['samples'] for c in costs):,.0f} samples, {max(c['trials'] for c in costs):,} trials, "
                     f"{max(c['chunks'] for c in costs)} chunk(s))")
        for i, c in enumerate(costs):
            mib = (c["kept_bytes"] + TABLE_COPIES * c["table_bytes"]) / MIB
            kept_mib += mib
            if worst is None or mib > worst[0]:
                worst = (mib, i, c, sc)
    mib = BASE_MIB + (chunk + kept + TABLE_COPIES * tables) / MIB
    return Cost(seconds, mib, "; ".join(parts) + f"; kept whole {kept / MIB:.3g} MiB, tables {tables / MIB:.3g} MiB, "
                f"largest chunk {chunk / MIB:.3g} MiB", kept_mib=kept_mib, unit_mib=0.0, sized_by=_sized_by(worst),
                kept_what="trial 0 and the statistics at every event index and stored sample, and their tables",
                unit_what="chunk of trials (chunks are sized to the budget)")


def _sized_by(worst) -> str:
    """The key that sizes what the run keeps: the largest run's intervals, or the stored samples."""
    if worst is None:
        return "runs"
    _, i, c, sc = worst
    by_samples = min(c["samples"], sc.sampling.stored) * sc.n * (sc.m + 2) > (sc.runs[i].intervals + 1) * sc.m * 3
    return "sampling.stored" if by_samples else f"runs[{i}].intervals"
