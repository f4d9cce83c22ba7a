"""Time and memory of a coestimation run, estimated from the scenario before anything runs.

A cost model: each stage's work counted from the scenario's sizes (integration steps, trials,
recorded samples, the stacked dimension D = n + N(n + p), nodes, role vertices), times constants
measured on the development machine (CPU seconds; docs/papers/tran.md gives the measured ratios).
Memory: the interpreter and libraries, what the run keeps (the recorded samples of every
deterministic run and of the stored stochastic trials, the per-time Monte Carlo moments, the
claims' temporaries over the samples, the tables built from them) and one Monte Carlo chunk per
worker (streamed: bounded by the budget). A run whose kept part exceeds the budget is refused
before it starts, naming the key that sizes it.
"""
from __future__ import annotations

from dataclasses import dataclass

from dse.errors import ScenarioError
from dse.engine.driver import RunOptions
from dse.simulate.units import RNG_UNIT, units_per_chunk

from .scenario import CoestimationScenario

MIB = 2.0**20
#: a run estimated longer than this says so when it starts
LONG_RUN_S = 60.0
#: resident memory before any array: Python, numpy, scipy, clarabel, pandas, pyarrow, matplotlib, rerun
BASE_MIB = 330.0
#: resident memory of the figures and the recording being written (matplotlib canvases, the Rerun buffer)
OUTPUT_MIB = 90.0
#: CPU seconds: interpreter start and imports (numpy, scipy, pandas, pydantic, clarabel, rerun; matplotlib in one process)
STARTUP_S = 1.3
#: CPU seconds: the design's fixed part, the LMIs of one node type (feasibility, margin, the comparison LMIs),
#: the paper's extra LMIs per type (smallest feasible σ by bisection, the J sweep), the sweeps per node
DESIGN_S = 0.1
LMI_TYPE_S = 0.02
EXTRAS_TYPE_S = 0.1
DESIGN_NODE_S = 0.012
#: CPU seconds per cubed stacked dimension: one dense eigen-decomposition of S (30 of them)
EIG_CUBE_S = 1.0e-9
#: CPU seconds per role vertex and cubed stacked dimension (batched symmetric eigenvalues), two enumerations
VERTEX_CUBE_S = 3.6e-10
#: CPU seconds per cubed dimension of the simulated state: the φ-functions and exact noise factors of one step
PREPARE_CUBE_S = 5.0e-8
#: CPU seconds per recorded sample of the stochastic horizon and cubed error dimension (tr(PΣ) of the exact law)
LAW_CUBE_S = 2.0e-10
#: CPU seconds per integration step of a deterministic run with time-varying roles: calls, and per squared
#: dimension; with fixed roles (one composed step operator)
STEP_CALL_S = 30e-6
STEP_D2_S = 3.6e-9
FIXED_STEP_S = 4e-6
FIXED_D2_S = 0.5e-9
#: CPU seconds per step of a Monte Carlo chunk (calls), and per trial-step: per squared dimension plus per noise
#: factor and dimension (matrix products), and a fixed part (draws, reduction); with fixed roles the step is
#: one product by the composed operator and one by the noise map
CHUNK_STEP_S = 0.9e-4
TRIAL_D2_S = 2.0e-10
TRIAL_FIXED_S = 1.8e-7
FIXED_CHUNK_STEP_S = 0.3e-4
FIXED_TRIAL_D2_S = 0.6e-10
#: noise factors per noise column (the numerical rank of each column's one-step covariance, measured)
FACTORS_PER_COLUMN = 4.0
#: CPU seconds per recorded sample and error dimension: the claims' checks along the deterministic runs
CLAIM_SAMPLE_S = 2.0e-7
#: CPU seconds per step of the central Kalman filter (filterpy, Python loop)
KF_STEP_S = 5e-5
#: CPU seconds: figures, recording and report; per table row (building, Parquet, CSV, the figures' reading)
OUTPUTS_S = 2.0
ROW_S = 1.2e-6


@dataclass(frozen=True)
class Cost:
    seconds: float
    peak_mib: float
    kept_mib: float       # what cannot be streamed (recorded samples, moments, tables)
    chunk_mib: float      # one Monte Carlo chunk, per worker
    detail: str


def human_seconds(s: float) -> str:
    for unit, size in (("days", 86400.0), ("hours", 3600.0), ("minutes", 60.0)):
        if s >= 2 * size:
            return f"{s / size:.3g} {unit}"
    return f"{s:.3g} s"


def _dims(sc: CoestimationScenario) -> tuple[int, float]:
    """(D, K): the simulated state's dimension and the number of noise factors."""
    return sc.n + sc.N * sc.q, FACTORS_PER_COLUMN * (1 + sc.N * sc.m)


def deterministic_seconds(sc: CoestimationScenario, run: str) -> float:
    """CPU seconds of one deterministic run (`compute.deterministic_jobs`): its φ-functions and its steps."""
    D, _ = _dims(sc)
    h = (sc.sde_step if "_sde" in run else sc.step) / (2 if run.endswith("_half") else 1)
    per_step = FIXED_STEP_S + FIXED_D2_S * D * D if run.startswith("fixed") else STEP_CALL_S + STEP_D2_S * D * D
    return sc.t_end / h * per_step + PREPARE_CUBE_S * D ** 3 / 2


def sde_seconds(sc: CoestimationScenario, trials: int, steps: float, fixed: bool, budget_bytes: float) -> float:
    """CPU seconds of one Monte Carlo run of `trials` trials over `steps` steps, in chunks of RNG units that fit the
    budget."""
    from .compute import sde_bytes_per_trial

    D, K = _dims(sc)
    units = -(-trials // RNG_UNIT)
    chunks = -(-units // units_per_chunk(sde_bytes_per_trial(sc, int(K)), budget_bytes))
    if fixed:
        return steps * (chunks * FIXED_CHUNK_STEP_S + trials * (FIXED_TRIAL_D2_S * (D * D + K * D) + TRIAL_FIXED_S))
    return steps * (chunks * CHUNK_STEP_S + trials * (TRIAL_D2_S * (D * D + K * D) + TRIAL_FIXED_S))


def estimate(sc: CoestimationScenario, opts: RunOptions, *, paper: bool = False) -> Cost:
    from .compute import trial_count, sde_bytes_per_trial
    from .design import QUICK_VERTEX_NODES, VERTEX_NODES, t_stochastic

    trials = trial_count(sc, opts)
    N, n, p, m, q = sc.N, sc.n, sc.p, sc.m, sc.q
    Dz = N * q                      # the error system
    D = n + Dz                      # the simulated state
    T = len(sc.types)
    n_rec = int(round(sc.t_end / sc.record_dt)) + 1
    t_sde = t_stochastic(sc, opts.quick)
    n_rec_sde = int(round(t_sde / sc.record_dt)) + 1
    vertex_nodes = QUICK_VERTEX_NODES if opts.quick else VERTEX_NODES
    # design: LMIs, per-node sweeps, spectra of S at 23 role vectors, the vertex enumerations
    t_design = DESIGN_S + T * (LMI_TYPE_S + (EXTRAS_TYPE_S if paper else 0.0)) + N * DESIGN_NODE_S + 30 * EIG_CUBE_S * Dz ** 3
    if N <= vertex_nodes:
        t_design += 2 * 2 ** N * VERTEX_CUBE_S * Dz ** 3
    # the exact law: tr(PΣ) at every sample, the step operators at h and h/2
    n_noise = 1 + N * m
    K = FACTORS_PER_COLUMN * n_noise
    t_law = n_rec_sde * LAW_CUBE_S * Dz ** 3 + 2 * PREPARE_CUBE_S * D ** 3
    # deterministic runs: coest, fixed and comparison at h; coest and fixed at h/2 (twice the steps); the fixed-role
    # runs at the stochastic step when it differs
    steps = sc.t_end / sc.step
    det_runs = ["coest", "coest_half", "fixed", "fixed_half", "comparison"]
    det_runs += ["fixed_sde", "fixed_sde_half"] if sc.sde_step != sc.step else []
    t_dets = [deterministic_seconds(sc, r) for r in det_runs]
    t_det = sum(t_dets)
    # Monte Carlo: three runs (time-varying and fixed roles at the stochastic step, fixed at half the step), in the
    # same pool of workers as the deterministic runs
    budget = opts.chunk_budget_bytes()
    per_trial = sde_bytes_per_trial(sc, int(K))
    units = -(-trials // RNG_UNIT)
    t_runs = [sde_seconds(sc, trials, t_sde / sc.sde_step, False, budget),
              sde_seconds(sc, trials, t_sde / sc.sde_step, True, budget),
              sde_seconds(sc, trials, 2 * min(t_sde, sc.quick_t_end) / sc.sde_step, True, budget)]
    workers = max(1, opts.workers)
    t_mc = max((sum(t_runs) + t_det) / workers, max(t_runs + t_dets))
    kf_steps = (2 * n_rec + n_rec_sde) / max(1, round(sc.kf_dt / sc.record_dt))
    t_claims = 6 * n_rec * Dz * CLAIM_SAMPLE_S + kf_steps * KF_STEP_S
    rows = n_rec * N * (q + 2) * 3 + sc.runs * n_rec_sde * N * (q + 1) + 4 * n_rec * N + 3 * Dz ** 2
    t_out = OUTPUTS_S + rows * ROW_S
    seconds = STARTUP_S + t_design + t_law + t_mc + t_claims + t_out
    # memory: the recorded runs, the kept trials, the moments, the claims' temporaries and the tables
    sample = 8.0 * (n + Dz + N + p)
    runs_bytes = n_rec * sample * 7 + sc.runs * n_rec_sde * sample * 3
    moments = 8.0 * n_rec_sde * 12 * 3 + 8.0 * 3 * N * q * q
    claims = 16 * 8.0 * n_rec * Dz
    tables = 150.0 * rows
    design = 8.0 * Dz * Dz * (40 + 256 * (N <= vertex_nodes)) + 8.0 * D * D * 6 + 8.0 * 2 * K * D
    kept = OUTPUT_MIB + (runs_bytes + moments + claims + tables + design) / MIB
    chunk_units = min(units_per_chunk(per_trial, budget), units)
    chunk = chunk_units * RNG_UNIT * per_trial / MIB
    peak = BASE_MIB + kept + chunk * workers
    detail = (f"{human_seconds(seconds)} in all: {steps:,.0f} steps of h = {sc.step:g} over T = {sc.t_end:g} s ({n_rec:,} recorded samples), stochastic "
              f"{trials:,} trials x {t_sde / sc.sde_step:,.0f} steps, D = {D}; design {t_design:.2g} s, exact law "
              f"{t_law:.2g} s, deterministic runs {t_det:.3g} s and Monte Carlo {sum(t_runs):.3g} s: {t_mc:.3g} s on {workers} "
              f"worker(s), claims "
              f"{t_claims:.2g} s, tables and outputs {t_out:.2g} s; memory {BASE_MIB:.0f} MiB base + {kept:,.0f} MiB "
              f"kept + {chunk:,.0f} MiB per Monte Carlo chunk")
    return Cost(seconds, peak, kept, chunk, detail)


def refuse_if_too_large(sc: CoestimationScenario, opts: RunOptions) -> None:
    """Refuse, before anything runs, a run whose kept part does not fit the memory budget."""
    c = estimate(sc, opts)
    budget = opts.memory_budget_mib
    if BASE_MIB + c.kept_mib + c.chunk_mib > budget:
        n_rec = int(round(sc.t_end / sc.record_dt)) + 1
        raise ScenarioError("simulation.record_dt", f"the run keeps {n_rec:,} recorded samples of every trajectory "
                            f"(t_end / record_dt), about {c.kept_mib:,.0f} MiB with the stored trials, moments and "
                            f"tables, besides {BASE_MIB:.0f} MiB of libraries and a {c.chunk_mib:.0f} MiB chunk: more "
                            f"than the memory budget of {budget:,.0f} MiB; use a larger record_dt (or leave it to its "
                            "default), or raise --max-memory")
