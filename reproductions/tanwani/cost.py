"""Time and memory of a random-comm-filter run, estimated from the scenario before anything runs
(`dse check`, and the refusal of runs whose non-streamable part does not fit the memory budget).

Time (CPU seconds, constants fitted on the development machine; docs/papers/tanwani.md gives the
measured ratios): the design (eigenvalue problems of the generators of (9), of size D9 = N·n², and
of the exact mean covariance, of size DS = Nn(Nn+1)/2, at every sweep rate and along the two
critical-rate bisections; the transients), the references (the second moments of the P-process, the
gridded scheme's bias, filterpy), the gridded Monte Carlo (per trial and step: two flows of the
(N+1)n state; per step and clock: the rings), the event-driven and frozen-path Monte Carlo (per
trial and event or output time: the exact flow of the joint covariance, dense products of size
(N+1)n), the claims (per-interval Van Loan along the stored paths) and the tables and outputs.

Memory: the interpreter and libraries, what the run keeps (moments per output time of every
Monte Carlo stage, the sample trials and their clock paths, the paired trials, the frozen path, the
design arrays and the dense generators, the tables) and one Monte Carlo chunk per worker
(streamed: bounded by the budget, at least one RNG unit of 1,000 trials).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from pipeline.errors import ScenarioError
from pipeline.reproduction import RunOptions
from pipeline.simulate import RNG_UNIT, units_per_chunk

from .scenario import FilterNetworkScenario

MIB = 2.0**20
#: resident memory before any array: Python, numpy, scipy, pandas, pyarrow, matplotlib, rerun
BASE_MIB = 300.0
#: resident memory of the figures and recordings being written
OUTPUT_MIB = 60.0
#: CPU seconds: interpreter start and imports; the claims' fixed part; figures, recordings, report per scenario
STARTUP_S = 2.5
CLAIMS_S = 0.6
OUTPUTS_S = 2.5
#: CPU seconds per cubed dimension of a dense eigenvalue problem or solve (the design's generators)
EIG_CUBE_S = 2.5e-9
#: CPU seconds per design call (Python overhead of building a generator and its abscissa)
DESIGN_CALL_S = 4e-4
#: CPU seconds per squared dimension of building a dense generator (kron products per clock)
BUILD_SQ_S = 2e-9
#: CPU seconds per output step and squared dimension of a transient (matrix-vector products)
STEP_SQ_S = 2e-9
#: gridded: per trial, step and squared state dimension (two flows); per step (Python, per unit); per step and clock
GRID_TRIAL_S = 1.5e-9
GRID_STEP_S = 6e-5
GRID_CLOCK_S = 4e-6
GRID_RECORD_S = 6e-5
#: event-driven: per trial, mark (event or output) and cubed joint dimension; per trial and mark (fixed); per mark
EVENT_CUBE_S = 1.2e-9
EVENT_TRIAL_S = 6e-6
EVENT_MARK_S = 1.5e-3
#: claims: per-interval Van Loan along the stored paths, per interval and cubed doubled dimension
PATH_CUBE_S = 3e-9
PATH_INTERVAL_S = 1.5e-4
#: CPU seconds per table row (building, Parquet, CSV, the figures' reading)
ROW_S = 3e-6
#: topology sweep of the paper
TOPOLOGY_S = 3.0
#: bytes of one table row in memory (frames, Arrow copies)
ROW_BYTES = 200.0
#: a run estimated longer than this says so when it starts
LONG_RUN_S = 60.0


@dataclass(frozen=True)
class Cost:
    seconds: float
    peak_mib: float
    kept_mib: float       # what cannot be streamed (moments, samples, paths, design arrays, tables)
    chunk_mib: float      # one Monte Carlo chunk, per worker
    unit_mib: float       # one RNG unit of the largest stage
    detail: str
    parts: dict


def human_seconds(s: float) -> str:
    for unit, size in (("days", 86400.0), ("hours", 3600.0), ("minutes", 60.0)):
        if s >= 2 * size:
            return f"{s / size:.3g} {unit}"
    return f"{s:.3g} s"


def _sizes(sc: FilterNetworkScenario) -> dict:
    s = sc.system
    N, n = s.N, s.n
    return {"N": N, "n": n, "d": (N + 1) * n, "D9": N * n * n, "DS": N * n * (N * n + 1) // 2, "Nn": N * n,
            "C": len(s.clocks), "T": sc.n_outputs + 1}


def scenario_cost(sc: FilterNetworkScenario, opts: RunOptions, *, paper: bool = False) -> dict:
    from .compute import (MAX_SCHEME_DIM, PAIR_MAX, event_bytes_per_trial, event_window, gridded_bytes_per_trial,
                          trial_counts)
    from .design import QUICK_SWEEP_POINTS, joint_ok, numerics_times

    z = _sizes(sc)
    N, n, d, D9, DS, Nn, C, T = (z[k] for k in ("N", "n", "d", "D9", "DS", "Nn", "C", "T"))
    trials, ev_trials = trial_counts(sc, opts)
    joint = joint_ok(sc.system)
    R = len(sc.rates)
    # design: sweep points and bisections, each an eigenvalue problem (and a solve) of each generator
    pts = sc.sweep[2] if not opts.quick else min(sc.sweep[2], QUICK_SWEEP_POINTS)
    pts += 5
    evals9 = 4 * pts + 90 + 3 * R
    evalsS = (3 * pts + 90 + 2 * R) if joint else 0
    t_design = (evals9 * (DESIGN_CALL_S + EIG_CUBE_S * D9 ** 3 + BUILD_SQ_S * C * D9 ** 2)
                + evalsS * (DESIGN_CALL_S + EIG_CUBE_S * DS ** 3 + BUILD_SQ_S * (C + 2) * Nn ** 4)
                + R * T * STEP_SQ_S * (D9 ** 2 + (DS ** 2 if joint else 0)))
    nt = numerics_times(sc)
    path_marks = sc.main_rate * C * nt[-1] + len(nt)
    t_design += 3 * path_marks * (PATH_INTERVAL_S + PATH_CUBE_S * (2 * Nn) ** 3)
    # references: second moments of the P-process, the gridded scheme's bias, filterpy
    q = n * (n + 1) // 2
    Dq = N * q
    big = Dq * (Dq + 1) // 2 + Dq
    t_refs = 0.5
    if Dq <= 40:
        t_refs += 2 * EIG_CUBE_S * 6 * big ** 3 + 1.5 * T * STEP_SQ_S * big ** 2
    if Nn <= MAX_SCHEME_DIM:
        t_refs += 3 * C * EIG_CUBE_S * 4 * DS ** 3 + 2 * T * STEP_SQ_S * DS ** 2
    # gridded Monte Carlo, every rate
    budget = opts.chunk_budget_bytes()
    g_bytes = gridded_bytes_per_trial(sc)
    g_units = -(-trials // RNG_UNIT)
    g_chunks = -(-g_units // units_per_chunk(g_bytes, budget))
    steps = sc.grid_steps
    t_grid = R * (steps * (trials * GRID_TRIAL_S * (d * d + 4 * d) + g_units * GRID_STEP_S
                           + g_chunks * C * GRID_CLOCK_S * 2) + T * g_units * GRID_RECORD_S)
    # event-driven and frozen path: every trial visits every ring and output time
    e_bytes = event_bytes_per_trial(sc)
    e_units = -(-ev_trials // RNG_UNIT)
    e_chunks = -(-e_units // units_per_chunk(e_bytes, budget))
    events = sc.main_rate * C * sc.horizon
    L = event_window(sc)
    windows = math.ceil((T - 1) / L)
    spread = 3.0 * math.sqrt(max(events / windows, 1.0))
    marks = events + T + windows * spread                  # lock-step marks of a chunk (the slowest trial per window)
    per_mark = EVENT_CUBE_S * d ** 3 + EVENT_TRIAL_S
    t_event = ev_trials * marks * per_mark + e_chunks * marks * EVENT_MARK_S
    t_frozen = ev_trials * (events + T) * (EVENT_CUBE_S * d ** 3 * 0.6 + EVENT_TRIAL_S) + e_chunks * (events + T) * \
        EVENT_MARK_S
    # claims: per-interval Van Loan along the stored sample paths
    S = min(sc.sample_trials, ev_trials)
    t_claims = CLAIMS_S + S * (events + T) * (PATH_INTERVAL_S + PATH_CUBE_S * (2 * Nn) ** 3)
    rows = (R * T * N * 3 + S * T * N * (2 * n + 1) + 2 * S * T * N * n + pts * N + 10 * (N * n) ** 2
            + min(PAIR_MAX, ev_trials) * 0 + S * events)
    t_out = OUTPUTS_S + rows * ROW_S
    workers = max(1, opts.workers)
    stages = [t_design, t_refs, t_event, t_frozen] + [t_grid / R] * R
    wall_mc = max(sum(stages) / workers, max(stages))
    seconds = wall_mc + t_claims + t_out
    # memory kept: moments, samples and paths, design arrays and generators, tables
    mom = 8.0 * T * N * (2 * n * n + 1)
    kept = ((R + 2) * mom * 2 + 8.0 * S * T * (2 * d + 4 * N * n * n) + 16.0 * (S + 1) * events
            + 8.0 * min(PAIR_MAX, ev_trials, trials) * 10 * N * q * 2)
    design = (8.0 * R * T * ((Nn * Nn if joint else 0) + 2 * D9) + 8.0 * pts * N * n * n * 8
              + (8.0 * 4 * Nn ** 4 if joint else 0) + 8.0 * 4 * D9 ** 2)
    if Dq <= 40:
        design += 8.0 * 3 * big ** 2 + 8.0 * T * big
    tables = ROW_BYTES * rows
    kept_mib = OUTPUT_MIB + (kept + design + tables) / MIB
    unit_mib = RNG_UNIT * max(g_bytes, e_bytes) / MIB
    chunk_mib = max(min(units_per_chunk(g_bytes, budget), g_units) * RNG_UNIT * g_bytes,
                    min(units_per_chunk(e_bytes, budget), e_units) * RNG_UNIT * e_bytes) / MIB
    return {"seconds": seconds, "design_s": t_design, "refs_s": t_refs, "grid_s": t_grid, "event_s": t_event,
            "frozen_s": t_frozen, "claims_s": t_claims, "out_s": t_out, "kept_mib": kept_mib, "chunk_mib": chunk_mib,
            "unit_mib": unit_mib, "trials": trials, "ev_trials": ev_trials, "steps": steps, "events": events,
            "rows": rows}


def estimate(scenarios: list[FilterNetworkScenario], opts: RunOptions, *, paper: bool = False) -> Cost:
    costs = {sc.name: scenario_cost(sc, opts, paper=paper) for sc in scenarios}
    workers = max(1, opts.workers)
    seconds = STARTUP_S + sum(c["seconds"] for c in costs.values()) + (TOPOLOGY_S if paper else 0.0)
    kept = sum(c["kept_mib"] for c in costs.values())
    chunk = max(c["chunk_mib"] for c in costs.values())
    unit = max(c["unit_mib"] for c in costs.values())
    peak = BASE_MIB + kept + chunk * min(workers, 2)
    parts = [f"{name}: design {c['design_s']:.2g} s, gridded {c['trials']:,} trials × {c['steps']:,} steps per rate "
             f"{c['grid_s']:.3g} s, event-driven {c['ev_trials']:,} paths × {c['events']:,.0f} expected rings "
             f"{c['event_s']:.3g} s, frozen path {c['frozen_s']:.2g} s, claims {c['claims_s']:.2g} s, tables and "
             f"outputs {c['out_s']:.2g} s; kept {c['kept_mib']:,.0f} MiB" for name, c in costs.items()]
    detail = (f"{human_seconds(seconds)} in all on {workers} worker(s); memory {BASE_MIB:.0f} MiB base + {kept:,.0f} MiB "
              f"kept + {chunk:,.0f} MiB per Monte Carlo chunk. " + "; ".join(parts))
    return Cost(seconds, peak, kept, chunk, unit, detail, costs)


def refuse_if_too_large(scenarios: list[FilterNetworkScenario], opts: RunOptions, *, paper: bool = False) -> None:
    """What cannot be streamed must fit the memory budget, and so must one RNG unit of trials: else one
    ScenarioError naming the field and the estimate, before anything runs."""
    budget = opts.memory_budget_mib
    c = estimate(scenarios, opts, paper=paper)
    if BASE_MIB + c.kept_mib + c.unit_mib > budget:
        worst = max(c.parts.items(), key=lambda kv: kv[1]["kept_mib"])
        name, p = worst
        sc = next(s for s in scenarios if s.name == name)
        field = "simulation.horizon" if p["events"] * (sc.sample_trials + 1) * 16 > 0.5 * p["kept_mib"] * MIB \
            else "simulation.output_step"
        raise ScenarioError(field, f"'{name}' keeps about {c.kept_mib:,.0f} MiB that cannot be streamed (moments at "
                                   f"{sc.n_outputs + 1:,} output times, {sc.sample_trials} sample trials with about "
                                   f"{p['events']:,.0f} rings each, the frozen clock path, the design arrays and the "
                                   f"tables), besides {BASE_MIB:.0f} MiB of libraries and a {c.unit_mib:,.0f} MiB unit of "
                                   f"trials: more than the memory budget of {budget:,.0f} MiB (--max-memory); a shorter "
                                   "horizon, a larger output_step or fewer rings fit")
