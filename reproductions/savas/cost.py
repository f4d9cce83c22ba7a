"""Time and memory of a noisy-consensus-filter run, estimated from the scenario before anything runs.

A cost model: each stage's work counted from the scenario's sizes (cells, trials, steps, agents,
rounds, recorded steps, gain-grid points), times constants measured on the development machine
(2 cores, `make bench`-like conditions; see docs/papers/savas.md for the measured ratios). Memory:
the interpreter and libraries, one Monte Carlo chunk per worker (streamed: bounded by the budget),
and what cannot be streamed (the recorded statistics of every cell, the exact covariances, the
tables built from them). A run whose unstreamable part exceeds the budget is refused before it
starts, naming the key that sizes it.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline.errors import ScenarioError
from pipeline.reproduction import RunOptions
from pipeline.simulate import RNG_UNIT

from .scenario import NoisyConsensusScenario

MIB = 2.0**20
#: resident memory of a run before any array: Python, numpy, scipy, pandas, pyarrow, matplotlib, rerun
BASE_MIB = 300.0
#: seconds: interpreter start and imports, report, figures and recordings of a small scenario
FIXED_S = 6.0

# seconds per unit of work (measured, see docs/papers/savas.md)
GRID_POINT_MODE_S = 4.0e-9       # one grid point of (16), one mode, one m
GRID_POINT_S = 2.5e-9            # one grid point per (σ_c, formula): J, its minimum and local minima
TRIAL_STEP_S = 9.0e-9            # one trial-step: draws of x and w, bookkeeping
TRIAL_NODE_S = 1.2e-9            # one trial-step-agent: a measurement draw and the update, per configuration
TRIAL_DRAW_S = 4.5e-9            # one standard normal draw (per agent, per round)
TRIAL_TERM_S = 1.0e-9            # one term of a row-sparse product, per agent (Q per round, A per configuration)
TRIAL_RECORD_S = 3.0e-9          # one recorded step, per configuration and agent: the powers and their sums
STEP_CALL_S = 2.0e-6             # Python overhead per numpy call, per step of a chunk
RECORD_ROW_S = 4.0e-6            # one row of the per-step tables (claims, tables, Parquet)
CELL_S = 0.02                    # per cell: exact covariances, steady state, claims' solves


@dataclass(frozen=True)
class Cost:
    seconds: float
    peak_mib: float
    fixed_mib: float      # what cannot be streamed
    chunk_mib: float      # one Monte Carlo chunk, per worker
    detail: str


def _nnz_rows(M: np.ndarray) -> int:
    return int(max(1, (M != 0).sum(axis=1).max()))


def _a_nnz(sc: NoisyConsensusScenario, m: int) -> int:
    """Widest row of A = Σ_{j<=m} Q^j (or Q^m): the terms of its row-sparse product."""
    support = (sc.Q != 0).astype(float)
    A = np.eye(sc.n)
    P = np.eye(sc.n)
    for _ in range(min(m, sc.n)):
        P = np.minimum(support @ P, 1.0)
        A = np.maximum(A, P)
    return int(A.sum(axis=1).max())


def estimate(sc: NoisyConsensusScenario, opts: RunOptions) -> Cost:
    from .compute import CHUNK_UNITS, LARGE_M, LONG_RUN_STEPS, bytes_per_trial, gain_grid, recorded_steps, trial_count

    trials = trial_count(sc, opts)
    N, S_c, M = sc.n, len(sc.sigma_c), len(sc.rounds)
    S = len(recorded_steps(sc.n_steps, sc.recorded_steps, sc.eval_step))
    n_cells = 2 * M * S_c + 1
    # design: gain grids (symmetric Q only), then per-cell covariances
    t_design = n_cells * CELL_S
    if sc.symmetric:
        n_ell, n_zeta = gain_grid(sc, opts.quick)
        tables = sc.rounds_max + 1 + len(LARGE_M)
        t_design += tables * n_ell * n_zeta * ((N - 1) * GRID_POINT_MODE_S + 2 * S_c * GRID_POINT_S)
    # Monte Carlo: per group (algorithm, m) of S_c configurations over the horizon
    qnnz = _nnz_rows(sc.Q)
    groups = [(alg, m, sc.n_steps, S_c, S) for alg in ("carli", "reinjection") for m in sc.rounds]
    if sc.n_steps < LONG_RUN_STEPS:
        m_long = next((m for m in sc.rounds if m > 0), sc.rounds[-1])
        groups.append(("reinjection", m_long, LONG_RUN_STEPS, 1, LONG_RUN_STEPS))
    t_mc = 0.0
    chunk_trials = min(trials, CHUNK_UNITS * RNG_UNIT)
    for _, m, K, C, S_g in groups:
        per_trial_step = (TRIAL_STEP_S + C * N * TRIAL_NODE_S * 6 + (1 + m) * N * TRIAL_DRAW_S
                          + m * N * qnnz * TRIAL_TERM_S + (C * N * _a_nnz(sc, m) * TRIAL_TERM_S if m else 0.0))
        calls = 30 + m * (3 + 3 * qnnz) + (3 * _a_nnz(sc, m) if m else 0)
        t_mc += trials * K * per_trial_step + (trials / chunk_trials) * K * calls * STEP_CALL_S
        t_mc += trials * S_g * C * N * 10 * TRIAL_RECORD_S
    t_mc /= max(1, min(opts.workers, len(groups)))
    rows = n_cells * S * (N + 1)
    t_out = rows * RECORD_ROW_S + n_cells * CELL_S
    seconds = FIXED_S + t_design + t_mc + t_out
    # memory: what stays (recorded sums, exact series, paths, tables) and one chunk per worker
    per_cell = 8.0 * S * (2 * (3 * N + 2) + 2 * N + 1) * 3   # sums, exact diag/eig/trace; x3 for the tables built
    paths = 8.0 * sc.sample_paths * min(sc.n_steps, sc.sample_steps) * N * (max(sc.rounds) + 8) * n_cells
    steady = 8.0 * N * N * n_cells if N <= 50 else 0.0
    fixed = (n_cells * per_cell + paths + steady + 8.0 * max(sc.n_steps, LONG_RUN_STEPS)) / MIB
    per_trial = max(bytes_per_trial(S_c, N, S), bytes_per_trial(1, N, LONG_RUN_STEPS))
    budget_bytes = opts.chunk_budget_bytes()
    chunk_units = max(1, min(CHUNK_UNITS, int(budget_bytes // (per_trial * RNG_UNIT)), -(-trials // RNG_UNIT)))
    chunk = chunk_units * RNG_UNIT * per_trial * 1.5 / MIB   # temporaries of the moment sums
    if sc.symmetric:
        n_ell, n_zeta = gain_grid(sc, opts.quick)
        fixed += 8.0 * n_ell * n_zeta * (2 * 2 + 4) / MIB
    peak = BASE_MIB + fixed + chunk * max(1, min(opts.workers, len(groups)))
    detail = (f"{n_cells} cells x {trials:,} trials x {sc.n_steps:,} steps x {N} agents, {S} recorded steps; design "
              f"{t_design:.2g} s, Monte Carlo {t_mc:.3g} s on {opts.workers} worker(s), tables and outputs "
              f"{FIXED_S + t_out:.2g} s; memory {BASE_MIB:.0f} MiB base + {fixed:.0f} MiB kept + {chunk:.0f} MiB "
              "per Monte Carlo chunk")
    return Cost(seconds, peak, fixed, chunk, detail)


def refuse_if_too_large(sc: NoisyConsensusScenario, opts: RunOptions) -> None:
    """Refuse, before anything runs, a run whose unstreamable part does not fit the memory budget."""
    c = estimate(sc, opts)
    budget = opts.memory_budget_mib
    if BASE_MIB + c.fixed_mib + c.chunk_mib > budget:
        raise ScenarioError("sweep.recorded_steps", f"the run keeps about {c.fixed_mib:,.0f} MiB of per-step statistics "
                            f"and tables ({len(sc.sigma_c) * len(sc.rounds) * 2 + 1} cells x {sc.n} agents x the "
                            f"recorded steps) besides {BASE_MIB:.0f} MiB of libraries and a {c.chunk_mib:.0f} MiB "
                            f"chunk: more than the memory budget of {budget:,.0f} MiB; record fewer steps, or raise "
                            "--max-memory")
