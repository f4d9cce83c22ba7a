"""The cost model of a hybrid-observer run (`dse check`, and the refusal of runs whose
non-streamable part does not fit the memory budget): seconds and peak memory from the
scenario's sizes, without simulating.

Time: the design (ρ's branch and bound, σ's enumeration, the local designs), the sampled
Lemma 5/6 checks, and per run the interval plan (A(s), B(s), G(s) once per distinct weight
sequence: q (mn)²(m + n) flops each) and the trials: every sample step propagates the state of
every trial (B D² flops plus a fixed overhead), every iteration multiplies every trial's
iterate (B (mn)²), every event index evaluates the bounds (B (mn)² plus an overhead per agent).
Memory: 200 MiB for the interpreter and libraries, the largest chunk of trials, and what is
kept whole: trial 0 at every event index and stored sample, statistics per event and sample,
trial 0's iterates and source sets of the first intervals, and the tables built from them.
Constants calibrated on this machine (benchmarks/bench_wang_liu_morse.py, `estimate` section):
the estimate is meant within a factor 2 for runs longer than a few seconds.
"""
from __future__ import annotations

import math
from typing import Any

from pipeline.errors import ScenarioError
from pipeline.reproduction import RunOptions

from . import bounds
from .scenario import SIGMA_MAX_AGENTS, HybridScenario

#: seconds per sample step (fixed), per flop of the batched propagation, per estimator iteration
#: (fixed), per flop of an iteration, per event index (fixed, per agent), per flop of dense algebra
STEP_S = 3.0e-5
PROPAGATION_FLOP_S = 1.2e-9
ITERATION_S = 4.0e-6
ITERATION_FLOP_S = 1.2e-9
EVENT_S = 1.5e-4
DENSE_FLOP_S = 4e-10
TABLE_ROW_S = 2.5e-6
DESIGN_S = 0.15
BASE_MIB = 200.0
TABLE_ROW_BYTES = 160.0


def _n_i(sc: HybridScenario) -> list[int]:
    import estimators.jointly_observable_design as jd

    return [jd.local_design(sc.A, C, rank_tol=sc.rank_tol, L=None if sc.L_given is None else sc.L_given[i]).n_i
            for i, C in enumerate(sc.C)]


def _design_seconds(sc: HybridScenario, extras: bool) -> float:
    import estimators.jointly_observable_design as jd

    m, n = sc.m, sc.n
    mn = m * n
    N = (m - 1) ** 2 + 1
    words = min(jd.count_complete_repeat_free_words(min(m, 8), min(N, 60)), 2_000_000)
    seconds = DESIGN_S + words * n ** 3 * 40 * DENSE_FLOP_S
    if m <= SIGMA_MAX_AGENTS:
        seconds += len(jd.connected_undirected_graphs(m)) * mn ** 3 * 30 * DENSE_FLOP_S
    from .design import LEMMA5_FLOPS, LEMMA6_FLOPS

    seconds += (2 * LEMMA5_FLOPS + LEMMA6_FLOPS) * DENSE_FLOP_S * 2
    if extras:
        seconds += 0.2 + m * words * n ** 3 * 40 * DENSE_FLOP_S
    return seconds


def run_cost(sc: HybridScenario, run, trials: int, n_i: list[int], budget_bytes: float) -> dict[str, float]:
    """Seconds and bytes of one run (see the module docstring)."""
    m, n, S, q = sc.m, sc.n, run.intervals, run.q
    mn = m * n
    nw = sum(n_i)
    D = n + nw + 2 + mn + n
    B = trials if run.mc else 1
    samples = S * sc.T / sc.sample_step + 1
    steps = samples + S * m
    distinct = min(S, 2 * max(1, len(sc.graphs)) if run.switching != "fixed" else 1) if not run.leave else min(S, 6)
    if run.timing == "offset" or run.switching == "alternate_iteration":
        distinct = min(S, 2 * max(1, len(sc.graphs)))
    per_trial = bounds.bytes_per_trial(sc, n_i)
    chunk = min(B, max(1, int(budget_bytes // max(per_trial * 1000, 1.0))) * 1000)
    chunks = math.ceil(B / chunk)
    plan = S * (q * m * m * 1e-7 + 2e-4) + distinct * q * mn * mn * (m + n) * DENSE_FLOP_S * 4
    recursion = chunks * distinct * q * mn * mn * (m + n) * DENSE_FLOP_S * 4
    propagate = chunks * steps * STEP_S + steps * B * D * D * PROPAGATION_FLOP_S
    iterate = chunks * S * q * ITERATION_S + S * q * B * mn * mn * ITERATION_FLOP_S
    events = chunks * S * (m * EVENT_S + 3e-4) + S * B * (3 * mn * mn + 60 * mn) * ITERATION_FLOP_S
    kf = samples * 6e-5 if run.noise else 0.0
    stored = min(samples, sc.stored_samples)
    keep = max(1, min(S, bounds.SOURCE_VALUES // max(q * m * m, 1), bounds.ITERATE_VALUES // max((q + 1) * mn, 1)))
    kept_bytes = 8 * ((S + 1) * (4 * mn + nw + 8 * m + 20) + stored * (n * (m + 2) + 3 * m + 8)
                      + keep * ((q + 1) * mn + q * m * m + m * (q + 1)) + 30 * B + 6 * S)
    table_rows = ((S + 1) * m * 2 + stored * (m + 1) + min(stored * n * (m + 2), 2_000_000) + keep * (q + 1) * m
                  + keep * q * m * 2 + S + B + 60)
    return {"seconds": plan + recursion + propagate + iterate + events + kf + table_rows * TABLE_ROW_S,
            "chunk_bytes": chunk * per_trial, "kept_bytes": kept_bytes, "table_bytes": table_rows * TABLE_ROW_BYTES,
            "trials": B, "chunks": chunks, "samples": samples}


def estimate(scenarios: dict[str, HybridScenario], opts: RunOptions, *, extras: bool = False) -> dict[str, Any]:
    from .compute import trial_count

    budget = opts.chunk_budget_bytes()
    seconds, kept, tables, chunk, parts = 0.0, 0.0, 0.0, 0.0, []
    for name, sc in scenarios.items():
        n_i = _n_i(sc)
        trials = trial_count(sc, opts)
        design_s = _design_seconds(sc, extras)
        costs = [run_cost(sc, run, trials, n_i, budget) for run in sc.runs]
        run_s = sum(c["seconds"] for c in costs) / max(1, min(opts.workers, len(costs)))
        seconds += design_s + run_s
        kept += sum(c["kept_bytes"] for c in costs)
        tables += sum(c["table_bytes"] for c in costs)
        chunk = max(chunk, max(c["chunk_bytes"] for c in costs) * max(1, min(opts.workers, len(costs))))
        parts.append(f"{name}: design ≈{design_s:.2g} s, {len(costs)} runs ≈{run_s:.3g} s "
                     f"({sum(c['samples'] for c in costs):,.0f} samples, {max(c['trials'] for c in costs):,} trials)")
    mib = BASE_MIB + (chunk + kept + 2.5 * tables) / 2**20
    return {"seconds": seconds, "peak_memory_mib": mib,
            "detail": "; ".join(parts) + f"; kept whole {kept / 2**20:.3g} MiB, tables {tables / 2**20:.3g} MiB, "
                      f"largest chunk {chunk / 2**20:.3g} MiB"}


def refuse_beyond_budget(scenarios: dict[str, HybridScenario], opts: RunOptions) -> None:
    """What cannot be streamed (trial 0 and the statistics at every event index and stored sample,
    and the tables made of them) must fit the memory budget: else one ScenarioError naming the run's
    `intervals` (or `sampling.stored`) and the estimate, before anything runs."""
    from .compute import trial_count

    budget_mib = opts.memory_budget_mib
    total, worst = BASE_MIB, None
    for name, sc in scenarios.items():
        n_i = _n_i(sc)
        for i, run in enumerate(sc.runs):
            c = run_cost(sc, run, trial_count(sc, opts), n_i, opts.chunk_budget_bytes())
            mib = (c["kept_bytes"] + 2.5 * c["table_bytes"]) / 2**20
            total += mib
            if worst is None or mib > worst[0]:
                worst = (mib, i, c)
    if worst is not None and total > budget_mib:
        mib, i, c = worst
        stored_share = min(c["samples"], next(iter(scenarios.values())).stored_samples)
        field = f"runs[{i}].intervals" if c["samples"] > 4 * stored_share or stored_share < 1000 else "sampling.stored"
        raise ScenarioError(field, f"the run keeps about {total:,.0f} MiB that cannot be streamed (trial 0 and the "
                                   f"statistics at every event index and stored sample, and their tables; the largest "
                                   f"run {mib:,.0f} MiB), more than the memory budget of {budget_mib:,.0f} MiB "
                                   "(--max-memory)")
