"""Time and memory of a noisy-consensus-filter run, estimated from the scenario before anything runs.

A cost model: each stage's work counted from the scenario's sizes (cells, trials, steps, agents,
rounds, recorded steps, gain-grid points), times constants measured on the development machine
(2 cores, `make bench`-like conditions; see docs/papers/savas.md for the measured ratios). Memory:
the interpreter and libraries, one Monte Carlo chunk per worker (streamed: bounded by the budget),
and what cannot be streamed (the recorded statistics of every cell, the exact covariances, the
tables built from them). The driver refuses, before it starts, a run whose unstreamable part exceeds
the budget, naming the key that sizes it (`sweep.recorded_steps`).
"""
from __future__ import annotations

import numpy as np

from dse.contract.cost import MIB, Cost
from dse.contract.options import RunOptions
from dse.simulate.units import RNG_UNIT

from .cells import LARGE_M, LONG_RUN_STEPS, gain_grid, scenario_steps
from .monte_carlo import CHUNK_BYTES, CHUNK_TRIALS, bytes_per_trial
from .scenario import NoisyConsensusFile

#: resident memory of a run before any array: Python, numpy, scipy, pandas, pyarrow, matplotlib, rerun
BASE_MIB = 300.0
#: seconds of CPU: interpreter start and imports
STARTUP_S = 0.6
#: seconds of CPU: the claims' fixed part (scipy.stats, filterpy, the large-m and optimiser checks)
CLAIMS_S = 0.5
#: seconds of CPU: figures, recordings and report of a small scenario
OUTPUTS_S = 1.5

# seconds of CPU per unit of work, measured on this machine (docs/papers/savas.md gives the ratios)
GRID_POINT_MODE_S = 5.0e-9       # one grid point of (16), one mode, one m
GRID_POINT_S = 6.0e-9            # one grid point per (σ_c, formula): J, its minimum and local minima
CELL_DESIGN_S = 0.003            # per cell and (1 + N/10): exact covariances at the recorded steps, steady state
TRIAL_CONFIG_S = 6.0e-9          # per trial, step, configuration and agent: the update and the errors
TRIAL_DRAW_S = 9.6e-9            # per trial, step and agent, per draw (measurement and each round)
TRIAL_Q_TERM_S = 0.3e-9          # one term of the row-sparse product with Q, per trial, round and agent
TRIAL_A_TERM_S = 2.1e-9          # one term of the product with A, per trial, step, configuration and agent
TRIAL_RECORD_S = 8.9e-9          # per trial, recorded step, configuration and agent: powers and their sums
RECORD_CALL_S = 3.6e-6           # Python overhead per numpy call of a recorded step, per chunk (12 calls)
CELL_CLAIMS_S = 0.005            # per cell: the claims' solves and exact laws
CELL_CLAIMS_N3_S = 3.2e-8        # per cell and N³: the claims' dense N x N solves (Lyapunov, series, (23))
NODE_OUTPUT_S = 6.0e-3           # per agent: the recordings' series
FILTERPY_N3_S = 2.0e-9           # per sample trial, sample step and N³: filterpy's reference filter (N x N inverse)
CELL_TABLES_S = 0.006            # per cell: its rows of the tables (pandas)
ROW_S = 2.0e-6                   # one row of the per-step tables: the exact laws, pandas, Parquet


def _nnz_rows(M: np.ndarray) -> int:
    return int(max(1, (M != 0).sum(axis=1).max()))


#: up to this many agents the hop distances come from boolean matrix products (no scipy.sparse import)
DENSE_HOPS_AGENTS = 64


def _hops(adjacency: np.ndarray) -> np.ndarray:
    """Hop distances along the directed edges i → j of `adjacency` (n where j cannot be reached from i)."""
    n = len(adjacency)
    if n > DENSE_HOPS_AGENTS:   # one breadth-first search per agent
        from scipy.sparse import csr_matrix
        from scipy.sparse.csgraph import shortest_path

        hops = shortest_path(csr_matrix(adjacency), unweighted=True)
        return np.where(np.isfinite(hops), hops, n).astype(np.int64)
    hops = np.full((n, n), n, dtype=np.int64)
    reach = np.eye(n, dtype=bool)
    step = adjacency.astype(float)
    for d in range(n):
        hops[reach & (hops == n)] = d
        grown = reach | (reach.astype(float) @ step > 0)
        if np.array_equal(grown, reach):
            break
        reach = grown
    return hops


def _a_widths(sc: NoisyConsensusFile, ms) -> dict[int, int]:
    """Widest row of A = Σ_{j<=m} Q^j (or Q^m) for each m: the agents within m hops, the terms of the
    row-sparse product with A, from the graph's hop distances."""
    hops = _hops(sc.Q != 0)
    counts = np.zeros((sc.n, int(hops.max()) + 1))
    np.add.at(counts, (np.repeat(np.arange(sc.n), sc.n), hops.ravel()), 1.0)
    within = np.cumsum(counts, axis=1).max(axis=0)          # the most agents within d hops of one agent
    return {m: int(within[min(m, within.size - 1)]) for m in ms}


def _groups(sc: NoisyConsensusFile) -> list[tuple[int, int, int, int]]:
    """(m, horizon, configurations, recorded steps) of every Monte Carlo group (algorithm, m)."""
    sw = sc.sweep
    S_c, S = len(sw.sigma_c), len(scenario_steps(sc))
    groups = [(m, sw.n_steps, S_c, S) for m in sw.rounds for _filter in ("carli", "reinjection")]
    if sw.n_steps < LONG_RUN_STEPS:
        groups.append((next((m for m in sw.rounds if m > 0), sw.rounds[-1]), LONG_RUN_STEPS, 1, LONG_RUN_STEPS))
    return groups


def _chunks(sc: NoisyConsensusFile, opts: RunOptions, groups, trials: int) -> list[tuple[int, float, float]]:
    """Per group: RNG units per chunk, bytes of one chunk and of one unit (within the chunk budget)."""
    budget_bytes = min(opts.chunk_budget_bytes(), CHUNK_BYTES)
    out = []
    for _m, _K, C, S_g in groups:
        per_trial = bytes_per_trial(C, sc.n, S_g)
        units = max(1, min(int(budget_bytes // (per_trial * RNG_UNIT)), CHUNK_TRIALS // RNG_UNIT,
                           -(-trials // RNG_UNIT)))
        out.append((units, units * RNG_UNIT * per_trial, min(trials, RNG_UNIT) * per_trial))
    return out


def _kept_mib(sc: NoisyConsensusFile, opts: RunOptions, n_cells: int, S: int) -> float:
    """What a run keeps whatever the chunking: recorded sums, exact series, paths, steady states, tables."""
    N, sw, mc = sc.n, sc.sweep, sc.monte_carlo
    per_cell = 8.0 * S * (2 * (3 * N + 2) + 2 * N + 1) * 3   # sums, exact diag/eig/trace; x3 for the tables built
    paths = 8.0 * mc.sample_paths * min(sw.n_steps, mc.sample_steps) * N * (max(sw.rounds) + 8) * n_cells
    steady = 8.0 * N * N * n_cells if N <= 50 else 0.0
    fixed = (n_cells * per_cell + paths + steady + 8.0 * max(sw.n_steps, LONG_RUN_STEPS)) / MIB
    if sc.symmetric:
        n_ell, n_zeta = gain_grid(sc, opts.quick)
        fixed += 8.0 * n_ell * n_zeta * (2 * 2 + 4) / MIB
    return fixed


def _monte_carlo_seconds(sc: NoisyConsensusFile, groups, chunks, trials: int) -> list[float]:
    """CPU seconds of each Monte Carlo group (algorithm, m) of configurations over the horizon."""
    N, qnnz, a_width = sc.n, _nnz_rows(sc.Q), _a_widths(sc, sc.sweep.rounds)
    group_s = []
    for (m, K, C, S_g), (units, _, _) in zip(groups, chunks):
        a_nnz = a_width[m] if m else 0
        per_trial_step = (C * N * TRIAL_CONFIG_S + (1 + m) * N * TRIAL_DRAW_S + m * N * qnnz * TRIAL_Q_TERM_S
                          + C * N * a_nnz * TRIAL_A_TERM_S)
        n_chunks = -(-trials // (units * RNG_UNIT))
        group_s.append(trials * K * per_trial_step + n_chunks * S_g * 12 * RECORD_CALL_S
                       + trials * S_g * C * N * TRIAL_RECORD_S)
    return group_s


def estimate(sc: NoisyConsensusFile, opts: RunOptions, trials: int) -> Cost:
    """The run's time and memory; `kept_mib` and `unit_mib` are what the driver's refusal reads."""
    sw, mc = sc.sweep, sc.monte_carlo
    N, S_c, M = sc.n, len(sw.sigma_c), len(sw.rounds)
    S = len(scenario_steps(sc))
    n_cells = 2 * M * S_c + (1 if sw.n_steps < LONG_RUN_STEPS else 0)
    # design: gain grids (symmetric Q only), then per-cell covariances
    t_design = n_cells * CELL_DESIGN_S * (1.0 + N / 10.0)
    if sc.symmetric:
        n_ell, n_zeta = gain_grid(sc, opts.quick)
        tables = sc.rounds_max + 1 + len(LARGE_M)
        t_design += tables * n_ell * n_zeta * ((N - 1) * GRID_POINT_MODE_S + 2 * S_c * GRID_POINT_S)
    groups = _groups(sc)
    chunks = _chunks(sc, opts, groups, trials)
    group_s = _monte_carlo_seconds(sc, groups, chunks, trials)
    workers = max(1, min(opts.workers, len(groups)))
    t_mc = max(sum(group_s) / workers, max(group_s))
    rows = n_cells * S * (N + 1)
    t_claims = (CLAIMS_S + n_cells * (CELL_CLAIMS_S + CELL_CLAIMS_N3_S * N**3) + rows * ROW_S
                + mc.sample_paths * min(sw.n_steps, mc.sample_steps) * FILTERPY_N3_S * N**3)
    t_out = OUTPUTS_S + n_cells * CELL_TABLES_S + rows * ROW_S + N * NODE_OUTPUT_S
    seconds = STARTUP_S + t_design + t_mc + t_claims + t_out
    # memory: what stays (recorded sums, exact series, paths, tables) and one chunk per worker
    fixed = _kept_mib(sc, opts, n_cells, S)
    chunk = max(c[1] for c in chunks) * 1.5 / MIB   # with the temporaries of the moment sums
    peak = BASE_MIB + fixed + chunk   # the largest process (what getrusage reports); each worker holds one chunk
    detail = (f"{n_cells} cells x {trials:,} trials x {sw.n_steps:,} steps x {N} agents, {S} recorded steps; design "
              f"{t_design:.2g} s, Monte Carlo {t_mc:.3g} s on {workers} worker(s), claims {t_claims:.2g} s, tables and "
              f"outputs {t_out:.2g} s; memory of the largest process: {BASE_MIB:.0f} MiB base + {fixed:.0f} MiB kept + "
              f"{chunk:.0f} MiB per Monte Carlo chunk (one per worker)")
    return Cost(seconds, peak, detail, kept_mib=fixed, chunk_mib=chunk, unit_mib=max(c[2] for c in chunks) * 1.5 / MIB,
                sized_by="sweep.recorded_steps", unit_what="1,000 trials",
                kept_what=f"per-step statistics and tables (cells x {N} agents x the recorded steps)",
                stages={"design": t_design, "monte_carlo": t_mc, "claims": t_claims, "outputs": t_out})
