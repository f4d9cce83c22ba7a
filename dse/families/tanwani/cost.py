"""Time and memory of a random-comm-filter run, estimated from the scenario before anything runs
(`dse check`, and the refusal of runs whose non-streamable part does not fit the memory budget).

Time: each stage's work is counted from the scenario's sizes (`features`) and multiplied by CPU
seconds per unit (`COEF`, fitted on the development machine by least squares over the stages of
measured runs; docs/papers/tanwani.md gives the scenarios and the ratios):

* design: dense eigenvalue problems and solves of the generators of (9) (size D9 = N·n²) and of
  the exact mean covariance (DS = Nn(Nn+1)/2) along the two critical-rate bisections and at every
  sweep rate, the transients (matrix-vector products per output step), the clock paths of the
  `numerics` hypothesis (a matrix exponential per ring);
* references: the second moments of the P-process (a dense exponential of size ~(N·q)²/2), the
  gridded scheme's bias, filterpy's sampled filter;
* gridded Monte Carlo: per trial and step two flows of the (N+1)n state; per unit and step the
  draws; per chunk, step and clock the rings; per unit and output the moments;
* event-driven and frozen-path Monte Carlo: per trial and mark (ring or output time) the exact
  flow of the joint covariance (dense products of size (N+1)n); per chunk and mark the Python loop;
* claims (per-interval Van Loan along the stored paths, the Kalman–Bucy references), tables and outputs.

Memory: the interpreter and libraries, what the run keeps (moments per output time of every Monte
Carlo stage, the sample trials and their clock paths, the paired trials, the frozen path, the design
arrays and dense generators, the tables) and one Monte Carlo chunk per worker (streamed: bounded by
the budget, at least one RNG unit of 1,000 trials).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from dse.errors import ScenarioError
from dse.engine.driver import RunOptions
from dse.simulate.units import RNG_UNIT, units_per_chunk

from .scenario import FilterNetworkScenario

MIB = 2.0**20
#: resident memory before any array: Python, numpy, scipy, pandas, pyarrow, matplotlib, rerun
BASE_MIB = 300.0
#: resident memory of the figures and recordings being written
OUTPUT_MIB = 60.0
#: bytes of one table row in memory (frames, Arrow copies)
ROW_BYTES = 200.0
#: CPU seconds per unit of each feature (see `features`), fitted on measured stages
COEF = {
    "design": {"base": 0.0372, "eig": 1.23e-09, "solve": 0.0, "build": 0.0, "steps": 1.3e-08, "outputs": 4.98e-05, "intervals": 3.08e-06},
    "refs": {"base": 0.453, "kron": 2.4e-09, "second": 3.65e-10, "scheme": 4.3e-09, "steps": 9.08e-10, "filterpy": 3.96e-06},
    "grid": {"trial_steps": 6.22e-12, "trial_steps_c": 1.87e-08, "unit_steps": 7.31e-06, "chunk_steps": 3.95e-06, "unit_outputs": 5.14e-05},
    "event": {"d3": 0.0, "d2": 6.54e-08, "marks": 9.14e-07, "chunk_marks": 0.000614},
    "frozen": {"d3": 0.0, "d2": 2.11e-08, "marks": 3.92e-07, "chunk_marks": 0.000351},
    "claims": {"base": 0.571, "intervals": 1e-06, "outputs": 9.39e-06},
    "out": {"base": 0.95, "rows": 0.0, "nodes": 0.037},      # issue 16: fixed margins, no tight_layout
}
#: CPU seconds: interpreter start and imports; the paper's topology sweep
STARTUP_S = 2.5
TOPOLOGY_S = 3.0
#: a run estimated longer than this says so when it starts
LONG_RUN_S = 60.0
#: flops of a dense nonsymmetric eigenvalue problem and of an LU solve, per cubed dimension
EIG_FLOPS, SOLVE_FLOPS = 25.0, 0.7


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


def features(sc: FilterNetworkScenario, opts: RunOptions) -> dict[str, dict[str, float]]:
    """The work of every stage, in the units of COEF."""
    from .compute import MAX_SCHEME_DIM, event_bytes_per_trial, event_window, gridded_bytes_per_trial, trial_counts
    from .design import NUMERICS_PATHS, QUICK_SWEEP_POINTS, SWEEP_EIG_MAX, joint_ok, numerics_times

    s = sc.system
    N, n = s.N, s.n
    d, Nn, C, T = (N + 1) * n, N * n, len(s.clocks), sc.n_outputs + 1
    D9, DS = N * n * n, N * n * (N * n + 1) // 2
    joint = joint_ok(s)
    trials, ev_trials = trial_counts(sc, opts)
    R = len(sc.rates)
    pts = (min(sc.sweep[2], QUICK_SWEEP_POINTS) if opts.quick else sc.sweep[2]) + 5
    bisect = 45
    eig = (pts + 2 + R) * D9 ** 3 + ((pts if DS <= SWEEP_EIG_MAX else 0) + R + 1) * DS ** 3 * joint
    solve = (4 * pts + bisect + 3 * R) * D9 ** 3 + (4 * pts + bisect + 2 * R) * DS ** 3 * joint
    nt = numerics_times(sc)
    path_intervals = NUMERICS_PATHS * (sc.main_rate * C * nt[-1] + len(nt))
    design = {"base": 1.0, "eig": eig, "solve": solve, "build": (C + 4) * Nn ** 4 * joint,
              "steps": R * T * (D9 ** 2 + (DS ** 2 if joint else 0)), "outputs": (R + 1) * T,
              "intervals": path_intervals * (1 + (2 * Nn) ** 3 / 1000.0)}
    q = n * (n + 1) // 2
    Dq = N * q
    big = Dq * (Dq + 1) // 2 + Dq
    second = Dq <= 40
    scheme = Nn <= MAX_SCHEME_DIM
    every = max(1, int(round(sc.output_step / sc.grid_step)))
    refs = {"base": 1.0, "kron": second * C * Dq ** 4, "second": second * (2 * big ** 3 + 1.5 * T * big ** 2),
            "scheme": scheme * (C * 10 * Nn ** 4 + 2 * (C + math.log2(2 * every + 1)) * DS ** 3 + 2 * T * DS ** 2),
            "steps": 2.0 * T * (D9 ** 2 + (DS ** 2 if joint else 0)), "filterpy": _filterpy_steps(sc)}
    budget = opts.chunk_budget_bytes()
    g_units = -(-trials // RNG_UNIT)
    g_chunks = -(-g_units // units_per_chunk(gridded_bytes_per_trial(sc), budget))
    steps = sc.grid_steps
    grid = {"trial_steps": R * trials * steps * 4 * d * d, "trial_steps_c": R * trials * steps * (C + d),
            "unit_steps": R * g_units * steps,
            "chunk_steps": R * g_chunks * steps * (C + 4), "unit_outputs": R * g_units * T}
    e_units = -(-ev_trials // RNG_UNIT)
    e_chunks = -(-e_units // units_per_chunk(event_bytes_per_trial(sc), budget))
    events = sc.main_rate * C * sc.horizon
    L = event_window(sc)
    windows = math.ceil((T - 1) / L)
    marks = events + T + windows * 3.0 * math.sqrt(max(events / windows, 1.0))
    event = {"d3": ev_trials * (events + T) * d ** 3, "d2": ev_trials * (events + T) * d * d,
             "marks": ev_trials * (events + T), "chunk_marks": e_chunks * marks}
    frozen = {"d3": ev_trials * (events + T) * d ** 3, "d2": ev_trials * (events + T) * d * d,
              "marks": ev_trials * (events + T), "chunk_marks": e_chunks * (events + T)}
    S = min(sc.sample_trials, ev_trials)
    claims = {"base": 1.0, "intervals": S * (events + T) * (1 + (2 * Nn) ** 3 / 1000.0), "outputs": T * (1 + n ** 3)}
    rows = (R * T * N * 2 + 2 * S * T * N * n + S * T * N + 2 * T * N + (pts + 5) * N + 12 * Nn * Nn
            + (S + 1) * events + 10 * N * q * 10)
    out = {"base": 1.0, "rows": rows, "nodes": N * (1 + R)}
    return {"design": design, "refs": refs, "grid": grid, "event": event, "frozen": frozen, "claims": claims, "out": out}


def _filterpy_steps(sc: FilterNetworkScenario) -> float:
    """Steps of filterpy's sampled filter until its covariance settles, at the four sampling steps of
    `compute.filterpy_reference`: about 14 time constants of the slowest Kalman–Bucy mode (the Riccati difference contracts at twice its rate), at most 6,000."""
    import numpy as np
    import scipy.linalg as sla

    from .compute import FILTERPY_FRACTIONS, FILTERPY_MAX_STEPS

    s = sc.system
    Hs, Vs = np.vstack(s.H), sla.block_diag(*s.V)
    try:
        P = sla.solve_continuous_are(s.A.T, Hs.T, s.B @ s.B.T, Vs)
        eig = np.linalg.eigvals(s.A - P @ Hs.T @ np.linalg.solve(Vs, Hs))
    except (np.linalg.LinAlgError, ValueError):
        return 0.0
    if not np.all(np.isfinite(eig)) or eig.real.max() >= 0:
        return 0.0
    nu, mu = float(np.abs(eig).max()), float(-eig.real.max())
    hs = min(0.1, 0.5 / max(nu, 1e-12)) * np.array(FILTERPY_FRACTIONS)
    return float(sum(min(FILTERPY_MAX_STEPS, 14.0 / (h * mu)) for h in hs))


def stage_seconds(feat: dict[str, dict[str, float]]) -> dict[str, float]:
    return {stage: sum(COEF[stage][k] * v for k, v in f.items()) for stage, f in feat.items()}


def scenario_cost(sc: FilterNetworkScenario, opts: RunOptions) -> dict:
    from .compute import PAIR_MAX, event_bytes_per_trial, gridded_bytes_per_trial, trial_counts
    from .design import QUICK_SWEEP_POINTS, joint_ok

    feat = features(sc, opts)
    sec = stage_seconds(feat)
    s = sc.system
    N, n = s.N, s.n
    d, Nn, T = (N + 1) * n, N * n, sc.n_outputs + 1
    D9 = N * n * n
    trials, ev_trials = trial_counts(sc, opts)
    joint = joint_ok(s)
    R = len(sc.rates)
    S = min(sc.sample_trials, ev_trials)
    q = n * (n + 1) // 2
    events = sc.main_rate * len(s.clocks) * sc.horizon
    pts = (min(sc.sweep[2], QUICK_SWEEP_POINTS) if opts.quick else sc.sweep[2]) + 5
    mom = 8.0 * T * N * (2 * n * n + 1)
    kept = ((R + 2) * mom * 2 + 8.0 * S * T * (2 * d + 4 * N * n * n) + 16.0 * (S + 1) * events
            + 8.0 * min(PAIR_MAX, ev_trials, trials) * 10 * N * q * 2)
    design = (8.0 * R * T * ((Nn * Nn if joint else 0) + 2 * D9) + 8.0 * pts * N * n * n * 8
              + (8.0 * 5 * Nn ** 4 if joint else 0) + 8.0 * 4 * D9 ** 2)
    Dq = N * q
    if Dq <= 40:
        big = Dq * (Dq + 1) // 2 + Dq
        design += 8.0 * 3 * big ** 2 + 8.0 * T * big
    tables = ROW_BYTES * feat["out"]["rows"]
    budget = opts.chunk_budget_bytes()
    g_bytes, e_bytes = gridded_bytes_per_trial(sc), event_bytes_per_trial(sc)
    g_units, e_units = -(-trials // RNG_UNIT), -(-ev_trials // RNG_UNIT)
    chunk_mib = max(min(units_per_chunk(g_bytes, budget), g_units) * RNG_UNIT * g_bytes,
                    min(units_per_chunk(e_bytes, budget), e_units) * RNG_UNIT * e_bytes) / MIB
    return {**{f"{k}_s": v for k, v in sec.items()}, "stages": [sec["design"], sec["refs"], sec["event"],
                                                                sec["frozen"]] + [sec["grid"] / R] * R,
            "kept_mib": (kept + design + tables) / MIB, "chunk_mib": chunk_mib,
            "unit_mib": RNG_UNIT * max(g_bytes, e_bytes) / MIB, "trials": trials, "ev_trials": ev_trials,
            "steps": sc.grid_steps, "events": events}


def estimate(scenarios: list[FilterNetworkScenario], opts: RunOptions, *, paper: bool = False) -> Cost:
    costs = {sc.name: scenario_cost(sc, opts) for sc in scenarios}
    workers = max(1, opts.workers)
    stages = [t for c in costs.values() for t in c["stages"]] + ([TOPOLOGY_S] if paper else [])
    compute = max(sum(stages) / workers, max(stages))         # the stages run in `workers` processes
    # claims in the main process; figures and recordings in `workers` forked processes
    serial = sum(c["claims_s"] for c in costs.values()) + sum(c["out_s"] for c in costs.values()) / workers
    seconds = STARTUP_S + compute + serial
    kept = OUTPUT_MIB + sum(c["kept_mib"] for c in costs.values())
    chunk = max(c["chunk_mib"] for c in costs.values())
    unit = max(c["unit_mib"] for c in costs.values())
    # one worker simulates beside what the run keeps; several are forked processes, each with its own chunk
    peak = BASE_MIB + (kept + chunk if workers == 1 else max(kept, chunk))
    parts = [f"{name}: design {c['design_s']:.2g} s, references {c['refs_s']:.2g} s, gridded {c['trials']:,} trials × "
             f"{c['steps']:,} steps per rate {c['grid_s']:.3g} s, event-driven {c['ev_trials']:,} paths × "
             f"{c['events']:,.0f} expected rings {c['event_s']:.3g} s, frozen path {c['frozen_s']:.2g} s, claims "
             f"{c['claims_s']:.2g} s, tables and outputs {c['out_s']:.2g} s; kept {c['kept_mib']:,.0f} MiB"
             for name, c in costs.items()]
    detail = (f"{human_seconds(seconds)} in all on {workers} worker(s); memory {BASE_MIB:.0f} MiB base + {kept:,.0f} MiB "
              f"kept + {chunk:,.0f} MiB per Monte Carlo chunk. " + "; ".join(parts))
    return Cost(seconds, peak, kept, chunk, unit, detail, costs)


def refuse_if_too_large(scenarios: list[FilterNetworkScenario], opts: RunOptions, *, paper: bool = False) -> None:
    """What cannot be streamed must fit the memory budget, and so must one RNG unit of trials: else one
    ScenarioError naming the field and the estimate, before anything runs. A long run says so when it starts."""
    budget = opts.memory_budget_mib
    c = estimate(scenarios, opts, paper=paper)
    if BASE_MIB + c.kept_mib + c.unit_mib <= budget:
        if c.seconds > LONG_RUN_S and not paper:
            import sys

            print(f"{scenarios[0].name}: estimated {human_seconds(c.seconds)} and {c.peak_mib:,.0f} MiB peak memory "
                  f"({c.detail})", file=sys.stderr)
        return
    name, p = max(c.parts.items(), key=lambda kv: kv[1]["kept_mib"])
    sc = next(s for s in scenarios if s.name == name)
    paths_mib = (16.0 + ROW_BYTES) * (sc.sample_trials + 1) * p["events"] / MIB      # the stored rings and their rows
    field = "communication.rates" if paths_mib > 0.5 * p["kept_mib"] else "simulation.output_step"
    raise ScenarioError(field, f"'{name}' keeps about {c.kept_mib:,.0f} MiB that cannot be streamed (moments at "
                               f"{sc.n_outputs + 1:,} output times, {sc.sample_trials} sample trials with about "
                               f"{p['events']:,.0f} rings each, the frozen clock path, the design arrays and the tables), "
                               f"besides {BASE_MIB:.0f} MiB of libraries and a {c.unit_mib:,.0f} MiB unit of trials: more "
                               f"than the memory budget of {budget:,.0f} MiB (--max-memory); fewer rings (a lower rate or "
                               "a shorter horizon) or fewer output times fit")
