"""Time and memory of a random-comm-filter run, estimated from the scenario before anything runs
(`dse check`, the order in which the stages are run, and the driver's refusal of runs whose
non-streamable part does not fit the memory budget).

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

from dse.contract.cost import MIB, Cost, human_seconds
from dse.contract.options import INTERPRETER_MIB, RunOptions
from dse.simulate.units import RNG_UNIT, units_per_chunk

from .design import NUMERICS_PATHS, QUICK_SWEEP_POINTS, SWEEP_EIG_MAX, joint_ok, numerics_times
from .monte_carlo import PAIR_MAX, event_bytes_per_trial, event_window, gridded_bytes_per_trial
from .references import FILTERPY_FRACTIONS, FILTERPY_MAX_STEPS, MAX_SCHEME_DIM
from .scenario import RandomCommFile

#: resident memory before any array: Python, numpy, scipy, pandas, pyarrow, matplotlib, rerun
BASE_MIB = 300.0
#: resident memory of the figures and recordings being written
OUTPUT_MIB = 60.0
#: bytes of one table row in memory (frames, Arrow copies)
ROW_BYTES = 200.0
#: CPU seconds per unit of each feature (see `features`), fitted on measured stages (the claims' oracles, 0.12 s
#: on small scenarios, moved from "claims" to "refs" since: python-control and Radau run in the references stage)
COEF = {
    "design": {"base": 0.0372, "eig": 1.23e-09, "solve": 0.0, "build": 0.0, "steps": 1.3e-08, "outputs": 4.98e-05, "intervals": 3.08e-06},
    "refs": {"base": 0.573, "kron": 2.4e-09, "second": 3.65e-10, "scheme": 4.3e-09, "steps": 9.08e-10, "filterpy": 3.96e-06},
    "grid": {"trial_steps": 6.22e-12, "trial_steps_c": 1.87e-08, "unit_steps": 7.31e-06, "chunk_steps": 3.95e-06, "unit_outputs": 5.14e-05},
    "event": {"d3": 0.0, "d2": 6.54e-08, "marks": 9.14e-07, "chunk_marks": 0.000614},
    "frozen": {"d3": 0.0, "d2": 2.11e-08, "marks": 3.92e-07, "chunk_marks": 0.000351},
    "claims": {"base": 0.451, "intervals": 1e-06, "outputs": 9.39e-06},
    "out": {"base": 0.95, "rows": 0.0, "nodes": 0.037},      # issue 16: fixed margins, no tight_layout
}
#: CPU seconds: interpreter start and imports; the paper's topology sweep
STARTUP_S = 2.5
TOPOLOGY_S = 3.0


class Sizes:
    """The sizes the cost of one scenario's run is counted in."""

    def __init__(self, sc: RandomCommFile, opts: RunOptions):
        s = sc.gossip
        self.N, self.n, self.R, self.C = s.N, s.n, len(sc.rates), len(s.clocks)
        self.d, self.Nn, self.T = (s.N + 1) * s.n, s.N * s.n, sc.n_outputs + 1
        self.D9, self.DS = s.N * s.n * s.n, s.N * s.n * (s.N * s.n + 1) // 2
        self.q = s.n * (s.n + 1) // 2
        self.joint = joint_ok(s)
        self.trials, self.ev_trials = sc.trial_counts(opts.trials, opts.quick)
        self.S = min(sc.simulation.sample_trials, self.ev_trials)
        self.pts = (min(sc.sweep[2], QUICK_SWEEP_POINTS) if opts.quick else sc.sweep[2]) + 5
        self.events = sc.main_rate * self.C * sc.horizon
        budget = opts.chunk_budget_bytes()
        self.g_bytes, self.e_bytes = gridded_bytes_per_trial(sc), event_bytes_per_trial(sc)
        self.g_units, self.e_units = -(-self.trials // RNG_UNIT), -(-self.ev_trials // RNG_UNIT)
        self.g_chunk = min(units_per_chunk(self.g_bytes, budget), self.g_units)
        self.e_chunk = min(units_per_chunk(self.e_bytes, budget), self.e_units)


def features(sc: RandomCommFile, z: Sizes) -> dict[str, dict[str, float]]:
    """The work of every stage, in the units of COEF."""
    N, n, d, Nn, C, T, D9, DS, R, joint = z.N, z.n, z.d, z.Nn, z.C, z.T, z.D9, z.DS, z.R, z.joint
    bisect = 45
    eig = (z.pts + 2 + R) * D9 ** 3 + ((z.pts if DS <= SWEEP_EIG_MAX else 0) + R + 1) * DS ** 3 * joint
    solve = (4 * z.pts + bisect + 3 * R) * D9 ** 3 + (4 * z.pts + bisect + 2 * R) * DS ** 3 * joint
    nt = numerics_times(sc)
    path_intervals = NUMERICS_PATHS * (sc.main_rate * C * nt[-1] + len(nt))
    design = {"base": 1.0, "eig": eig, "solve": solve, "build": (C + 4) * Nn ** 4 * joint,
              "steps": R * T * (D9 ** 2 + (DS ** 2 if joint else 0)), "outputs": (R + 1) * T,
              "intervals": path_intervals * (1 + (2 * Nn) ** 3 / 1000.0)}
    Dq = N * z.q
    big = Dq * (Dq + 1) // 2 + Dq
    second, scheme = Dq <= 40, Nn <= MAX_SCHEME_DIM
    every = max(1, int(round(sc.output_step / sc.grid_step)))
    refs = {"base": 1.0, "kron": second * C * Dq ** 4, "second": second * (2 * big ** 3 + 1.5 * T * big ** 2),
            "scheme": scheme * (C * 10 * Nn ** 4 + 2 * (C + math.log2(2 * every + 1)) * DS ** 3 + 2 * T * DS ** 2),
            "steps": 2.0 * T * (D9 ** 2 + (DS ** 2 if joint else 0)), "filterpy": _filterpy_steps(sc)}
    steps, g_chunks = sc.grid_steps, -(-z.g_units // z.g_chunk)
    grid = {"trial_steps": R * z.trials * steps * 4 * d * d, "trial_steps_c": R * z.trials * steps * (C + d),
            "unit_steps": R * z.g_units * steps, "chunk_steps": R * g_chunks * steps * (C + 4),
            "unit_outputs": R * z.g_units * T}
    e_chunks, windows = -(-z.e_units // z.e_chunk), math.ceil((T - 1) / event_window(sc))
    marks = z.events + T + windows * 3.0 * math.sqrt(max(z.events / windows, 1.0))
    per_path = {"d3": z.ev_trials * (z.events + T) * d ** 3, "d2": z.ev_trials * (z.events + T) * d * d,
                "marks": z.ev_trials * (z.events + T)}
    claims = {"base": 1.0, "intervals": z.S * (z.events + T) * (1 + (2 * Nn) ** 3 / 1000.0), "outputs": T * (1 + n ** 3)}
    rows = (R * T * N * 2 + 2 * z.S * T * N * n + z.S * T * N + 2 * T * N + (z.pts + 5) * N + 12 * Nn * Nn
            + (z.S + 1) * z.events + 10 * N * z.q * 10)
    return {"design": design, "refs": refs, "grid": grid, "event": {**per_path, "chunk_marks": e_chunks * marks},
            "frozen": {**per_path, "chunk_marks": e_chunks * (z.events + T)}, "claims": claims,
            "out": {"base": 1.0, "rows": rows, "nodes": N * (1 + R)}}


def _filterpy_steps(sc: RandomCommFile) -> float:
    """Steps of filterpy's sampled filter until its covariance settles, at the four sampling steps of
    `references.filterpy_reference`: about 14 time constants of the slowest Kalman–Bucy mode (the Riccati
    difference contracts at twice its rate), at most 6,000."""
    import numpy as np
    import scipy.linalg as sla

    s = sc.gossip
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


def scenario_cost(sc: RandomCommFile, opts: RunOptions) -> dict:
    """One scenario's stage seconds (`stages`: design, references, event, frozen, then gridded per rate) and
    memory (MiB): what it keeps, one chunk, one RNG unit."""
    z = Sizes(sc, opts)
    feat = features(sc, z)
    sec = {stage: sum(COEF[stage][k] * v for k, v in f.items()) for stage, f in feat.items()}
    N, n, d, T, R, q = z.N, z.n, z.d, z.T, z.R, z.q
    mom = 8.0 * T * N * (2 * n * n + 1)
    kept = ((R + 2) * mom * 2 + 8.0 * z.S * T * (2 * d + 4 * N * n * n) + 16.0 * (z.S + 1) * z.events
            + 8.0 * min(PAIR_MAX, z.ev_trials, z.trials) * 10 * N * q * 2)
    design = (8.0 * R * T * ((z.Nn * z.Nn if z.joint else 0) + 2 * z.D9) + 8.0 * z.pts * N * n * n * 8
              + (8.0 * 5 * z.Nn ** 4 if z.joint else 0) + 8.0 * 4 * z.D9 ** 2)
    if N * q <= 40:
        big = N * q * (N * q + 1) // 2 + N * q
        design += 8.0 * 3 * big ** 2 + 8.0 * T * big
    tables = ROW_BYTES * feat["out"]["rows"]
    return {**{f"{k}_s": v for k, v in sec.items()},
            "stages": [sec["design"], sec["refs"], sec["event"], sec["frozen"]] + [sec["grid"] / R] * R,
            "kept_mib": (kept + design + tables) / MIB,
            "chunk_mib": max(z.g_chunk * RNG_UNIT * z.g_bytes, z.e_chunk * RNG_UNIT * z.e_bytes) / MIB,
            "unit_mib": RNG_UNIT * max(z.g_bytes, z.e_bytes) / MIB, "trials": z.trials, "ev_trials": z.ev_trials,
            "steps": sc.grid_steps, "events": z.events}


def estimate(scenarios, opts: RunOptions, *, paper: bool = False) -> Cost:
    """The run's cost. The driver refuses it when what it keeps (beside the libraries' BASE_MIB) and one RNG
    unit of trials do not fit the memory budget, naming the key that sizes what it keeps: the rates (the
    stored rings of the sample paths) or the output step (the moments per output time)."""
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
    sc = max(scenarios, key=lambda s: costs[s.name]["kept_mib"])
    paths_mib = (16.0 + ROW_BYTES) * (sc.simulation.sample_trials + 1) * costs[sc.name]["events"] / MIB
    return Cost(seconds, peak, detail, kept_mib=kept + BASE_MIB - INTERPRETER_MIB, chunk_mib=chunk, unit_mib=unit,
                sized_by="communication.rates" if paths_mib > 0.5 * costs[sc.name]["kept_mib"] else "simulation.output_step",
                kept_what=f"moments at {sc.n_outputs + 1:,} output times, {sc.simulation.sample_trials} sample trials with "
                          f"about {costs[sc.name]['events']:,.0f} rings each, the frozen clock path, the design arrays and "
                          f"the tables of '{sc.name}' (and {BASE_MIB - INTERPRETER_MIB:.0f} MiB of libraries)",
                unit_what=f"unit of {RNG_UNIT:,} trials",
                stages={"design": sum(c["design_s"] for c in costs.values()),
                        "references": sum(c["refs_s"] for c in costs.values()),
                        "gridded": sum(c["grid_s"] for c in costs.values()),
                        "event": sum(c["event_s"] for c in costs.values()),
                        "frozen": sum(c["frozen_s"] for c in costs.values()), "topology": TOPOLOGY_S if paper else 0.0})
