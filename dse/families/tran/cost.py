"""Time and memory of a coestimation run, estimated from the scenario before anything runs.

A cost model: each stage's work counted from the scenario's sizes (integration steps, trials,
recorded samples, the stacked dimension D = n + N(n + p), nodes, role vertices), times constants
measured on the development machine (CPU seconds; docs/papers/tran.md gives the measured ratios).
Memory: the interpreter and libraries, what the run keeps (the recorded samples of every
deterministic run and of the stored stochastic trials, the per-time Monte Carlo moments, the
claims' temporaries over the samples, the tables built from them) and one Monte Carlo chunk per
worker (streamed: bounded by the budget). The driver refuses, before it starts, a run whose kept
part and one chunk do not fit the budget, naming the key that sizes it (`simulation.record_dt`).
The same functions weigh the stages in the pool of workers (the heaviest first).
"""
from __future__ import annotations

import sys

from dse.contract.cost import MIB, Cost, human_seconds
from dse.contract.options import INTERPRETER_MIB, RunOptions
from dse.simulate.units import RNG_UNIT, units_per_chunk

from .design import QUICK_VERTEX_NODES, VERTEX_NODES, t_stochastic
from .runs import sde_bytes_per_trial
from .scenario import CoestimationFile

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
#: CPU seconds per step of the central Kalman filter (a Python loop)
KF_STEP_S = 5e-5
#: CPU seconds: figures, recording and report; per table row (building, Parquet, CSV, the figures' reading)
OUTPUTS_S = 2.0
ROW_S = 1.2e-6


def _dims(sc: CoestimationFile) -> tuple[int, float]:
    """(D, K): the simulated state's dimension and the number of noise factors."""
    return sc.n + sc.N * sc.q, FACTORS_PER_COLUMN * (1 + sc.N * sc.m)


def deterministic_seconds(sc: CoestimationFile, run: str) -> float:
    """CPU seconds of one deterministic run (`runs.DETERMINISTIC`): its φ-functions and its steps."""
    D, _ = _dims(sc)
    h = (sc.stochastic.step if "_sde" in run else sc.simulation.step) / (2 if run.endswith("_half") else 1)
    per_step = FIXED_STEP_S + FIXED_D2_S * D * D if run.startswith("fixed") else STEP_CALL_S + STEP_D2_S * D * D
    return sc.simulation.t_end / h * per_step + PREPARE_CUBE_S * D ** 3 / 2


def sde_seconds(sc: CoestimationFile, trials: int, steps: float, fixed: bool, budget_bytes: float) -> float:
    """CPU seconds of one Monte Carlo run of `trials` trials over `steps` steps, in chunks of RNG units that fit the
    budget."""
    D, K = _dims(sc)
    units = -(-trials // RNG_UNIT)
    chunks = -(-units // units_per_chunk(sde_bytes_per_trial(sc, int(K)), budget_bytes))
    if fixed:
        return steps * (chunks * FIXED_CHUNK_STEP_S + trials * (FIXED_TRIAL_D2_S * (D * D + K * D) + TRIAL_FIXED_S))
    return steps * (chunks * CHUNK_STEP_S + trials * (TRIAL_D2_S * (D * D + K * D) + TRIAL_FIXED_S))


def enumeration_seconds(sc: CoestimationFile, max_nodes: int) -> float:
    """CPU seconds of one vertex enumeration over {0,1}^N (none beyond `max_nodes` nodes)."""
    return 2 ** sc.N * VERTEX_CUBE_S * (sc.N * sc.q) ** 3 if sc.N <= max_nodes else 0.0


def estimate(sc: CoestimationFile, opts: RunOptions, trials: int, *, paper: bool = False) -> Cost:
    """The run's time and memory (see the module docstring); `paper`: with the paper's extra LMIs."""
    sim, st = sc.simulation, sc.stochastic
    N, n, p, m, q = sc.N, sc.n, sc.p, sc.m, sc.q
    Dz = N * q                      # the error system
    D = n + Dz                      # the simulated state
    n_rec = int(round(sim.t_end / sim.record_dt)) + 1
    t_sde = t_stochastic(sc, opts.quick)
    n_rec_sde = int(round(t_sde / sim.record_dt)) + 1
    vertex_nodes = QUICK_VERTEX_NODES if opts.quick else VERTEX_NODES
    # design: LMIs, per-node sweeps, spectra of S at 23 role vectors, the vertex enumerations
    t_design = DESIGN_S + len(sc.types) * (LMI_TYPE_S + (EXTRAS_TYPE_S if paper else 0.0)) + N * DESIGN_NODE_S \
        + 30 * EIG_CUBE_S * Dz ** 3 + 2 * enumeration_seconds(sc, vertex_nodes)
    # the exact law: tr(PΣ) at every sample, the step operators at h and h/2
    K = FACTORS_PER_COLUMN * (1 + N * m)
    t_law = n_rec_sde * LAW_CUBE_S * Dz ** 3 + 2 * PREPARE_CUBE_S * D ** 3
    # deterministic runs: coest, fixed and comparison at h; coest and fixed at h/2 (twice the steps); the fixed-role
    # runs at the stochastic step when it differs
    det_runs = ["coest", "coest_half", "fixed", "fixed_half", "comparison"]
    det_runs += ["fixed_sde", "fixed_sde_half"] if st.step != sim.step else []
    t_dets = [deterministic_seconds(sc, r) for r in det_runs]
    # Monte Carlo: three runs (time-varying and fixed roles at the stochastic step, fixed at half the step), in the
    # same pool of workers as the deterministic runs
    budget = opts.chunk_budget_bytes()
    t_runs = [sde_seconds(sc, trials, t_sde / st.step, False, budget), sde_seconds(sc, trials, t_sde / st.step, True, budget),
              sde_seconds(sc, trials, 2 * min(t_sde, st.quick_t_end) / st.step, True, budget)]
    workers = max(1, opts.workers)
    t_mc = max((sum(t_runs) + sum(t_dets)) / workers, max(t_runs + t_dets))
    kf_steps = (2 * n_rec + n_rec_sde) / max(1, round(sc.reference.dt / sim.record_dt))
    t_claims = 6 * n_rec * Dz * CLAIM_SAMPLE_S + kf_steps * KF_STEP_S
    rows = n_rec * N * (q + 2) * 3 + st.runs * n_rec_sde * N * (q + 1) + 4 * n_rec * N + 3 * Dz ** 2
    t_out = OUTPUTS_S + rows * ROW_S
    seconds = STARTUP_S + t_design + t_law + t_mc + t_claims + t_out
    # memory: the recorded runs, the kept trials, the moments, the claims' temporaries and the tables
    sample = 8.0 * (n + Dz + N + p)
    runs_bytes = n_rec * sample * 7 + st.runs * n_rec_sde * sample * 3
    moments = 8.0 * n_rec_sde * 12 * 3 + 8.0 * 3 * N * q * q
    design = 8.0 * Dz * Dz * (40 + 256 * (N <= vertex_nodes)) + 8.0 * D * D * 6 + 8.0 * 2 * K * D
    kept = OUTPUT_MIB + (runs_bytes + moments + 16 * 8.0 * n_rec * Dz + 150.0 * rows + design) / MIB
    per_trial = sde_bytes_per_trial(sc, int(K))
    chunk = min(units_per_chunk(per_trial, budget), -(-trials // RNG_UNIT)) * RNG_UNIT * per_trial / MIB
    detail = (f"{human_seconds(seconds)} in all: {sim.t_end / sim.step:,.0f} steps of h = {sim.step:g} over T = "
              f"{sim.t_end:g} s ({n_rec:,} recorded samples), stochastic {trials:,} trials x {t_sde / st.step:,.0f} steps, "
              f"D = {D}; design {t_design:.2g} s, exact law {t_law:.2g} s, deterministic runs {sum(t_dets):.3g} s and "
              f"Monte Carlo {sum(t_runs):.3g} s: {t_mc:.3g} s on {workers} worker(s), claims {t_claims:.2g} s, tables "
              f"and outputs {t_out:.2g} s; memory {BASE_MIB:.0f} MiB base + {kept:,.0f} MiB kept + {chunk:,.0f} MiB per "
              "Monte Carlo chunk")
    # refused when BASE_MIB + kept + chunk exceeds the budget: the libraries beyond the interpreter's share are kept
    return Cost(seconds, BASE_MIB + kept + chunk * workers, detail, kept_mib=BASE_MIB - INTERPRETER_MIB + kept,
                chunk_mib=chunk, unit_mib=chunk, sized_by="simulation.record_dt",
                kept_what=f"{n_rec:,} recorded samples of every trajectory (t_end / record_dt) with the stored trials, "
                          "moments, tables and the libraries beyond the interpreter",
                unit_what="Monte Carlo chunk",
                stages={"design": t_design, "law": t_law, "runs and Monte Carlo": t_mc, "claims": t_claims,
                        "outputs": t_out})


def announce(sc: CoestimationFile, cost: Cost) -> None:
    """A long run says so before it starts (with its estimated time and memory)."""
    if cost.seconds > LONG_RUN_S:
        print(f"{sc.name}: estimated {human_seconds(cost.seconds)} and {cost.peak_mib:,.0f} MiB peak memory "
              f"({cost.detail})", file=sys.stderr)
