"""Stages of the noisy-consensus-filter family: design (deterministic, cached) and Monte Carlo.

The design holds every quantity the theorems are made of and that needs no simulation: Q and
its spectrum, the optimal gains per (m, σ_c) under the printed and the corrected (16), the
cells and their gains, the exact covariances of (22) at the recorded steps and in the steady
state, the centralized Kalman reference and the σ_c thresholds of Fig. 1.

Monte Carlo cells (algorithm, m, σ_c) are simulated in groups that share (algorithm, m): one
run drives every σ_c with the same random draws (common random numbers), and each group is one
cache entry, so an interrupted run resumes group by group. Within a group the trials stream in
units of 1,000 with their own random streams (`dse.simulate.units.run_units`), as many units at a
time as the memory budget allows, and time streams step by step: only the sums of the errors'
powers at the recorded steps are kept. Results do not depend on the budget.
"""
from __future__ import annotations

import functools
from dataclasses import dataclass, field
from typing import Any

import numpy as np

import dse.estimators.consensus_covariance as cc
import dse.estimators.consensus_filter as cf
import dse.estimators.gain_tuning as gt
from dse.engine.cache import StageCache, code_fingerprint
from dse.engine.driver import RunOptions
from dse.simulate.seeding import stream_seed
from dse.simulate.units import RNG_UNIT, parallel_map, run_units
from dse.simulate.stats import ErrorMoments

from .scenario import NoisyConsensusScenario

ALGORITHMS = ("carli", "reinjection")
LARGE_M = (5, 10, 20, 50, 100, 200)
LONG_RUN_STEPS = 60
#: grid of (ℓ, ζ) in quick runs
QUICK_GRID = (100, 101)
#: steady-state covariance matrices are tabulated entry by entry up to this many agents
MATRIX_TABLE_AGENTS = 50
#: the arrays of a cell's steady state in the design (see `compute_design`)
STEADY_ARRAYS = ("diag", "trace", "gap", "matrix")
#: a chunk holds at most this many trials and bytes (measured fastest here: larger arrays leave the
#: processor's caches); the memory budget may make it smaller, never larger
CHUNK_TRIALS = 10_000
CHUNK_BYTES = 32 * 2**20
CODE_MODULES = ("dse.estimators.consensus_covariance", "dse.estimators.consensus_filter", "dse.estimators.gain_tuning",
                "dse.simulate.stats", "dse.simulate.units", "dse.simulate.seeding", "dse.families.savas.compute")


@dataclass(frozen=True)
class Cell:
    """One Monte Carlo cell: algorithm, rounds m, communication noise σ_c, its gains and horizon."""

    alg: str
    m: int
    sigma_c: float
    ell: float
    zeta: float
    n_steps: int

    @property
    def label(self) -> str:
        return f"{self.alg}_m{self.m}_sc{self.sigma_c:g}_K{self.n_steps}"

    @property
    def reinjection(self) -> bool:
        return self.alg == "reinjection"


def trial_count(sc: NoisyConsensusScenario, opts: RunOptions) -> int:
    return opts.trials if opts.trials is not None else (sc.quick_trials if opts.quick else sc.trials)


def gain_grid(sc: NoisyConsensusScenario, quick: bool) -> tuple[int, int]:
    return QUICK_GRID if quick else sc.grid


def recorded_steps(n_steps: int, budget: int, eval_step: int) -> np.ndarray:
    """The steps whose statistics are kept: all when n_steps <= budget, else the first budget/2 steps,
    then evenly spaced up to the last step, and eval_step."""
    if n_steps <= budget:
        return np.arange(n_steps)
    head = budget // 2
    tail = np.rint(np.linspace(head, n_steps - 1, budget - head)).astype(np.int64)
    return np.unique(np.concatenate([np.arange(head), tail, [eval_step]]))


def filter_kwargs(sc: NoisyConsensusScenario, cell: Cell) -> dict[str, Any]:
    return dict(ell=cell.ell, m=cell.m, sigma_c=cell.sigma_c, q=sc.q, r=sc.r, sigma0=sc.sigma0,
                n_steps=cell.n_steps, reinjection=cell.reinjection, zeta=cell.zeta)


def steady_kwargs(sc: NoisyConsensusScenario, cell: Cell) -> dict[str, Any]:
    return dict(ell=cell.ell, m=cell.m, sigma_c=cell.sigma_c, q=sc.q, r=sc.r, reinjection=cell.reinjection,
                zeta=cell.zeta)


# -- design ---------------------------------------------------------------------------------------

@dataclass
class Design:
    """The deterministic stage: named arrays (cached) and the cells derived from them."""

    scenario: NoisyConsensusScenario
    arrays: dict[str, np.ndarray]
    cells: list[Cell] = field(default_factory=list)
    long_cell: Cell | None = None

    @property
    def steps(self) -> np.ndarray:
        return self.arrays["steps"]

    def steps_of(self, cell: Cell) -> np.ndarray:
        return self.arrays["steps"] if cell.n_steps == self.scenario.n_steps else np.arange(cell.n_steps)

    def exact(self, cell: Cell) -> cc.CovarianceAtSteps:
        """P(k|k-1) of (22) at the cell's recorded steps: diag, trace and eigenvalues."""
        a = self.arrays
        return cc.CovarianceAtSteps(self.steps_of(cell), a[f"exact:{cell.label}:diag"], a[f"exact:{cell.label}:trace"],
                                    a[f"exact:{cell.label}:eig"])

    def steady(self, cell: Cell) -> dict[str, np.ndarray]:
        """The exact steady state of the cell: diag, trace, gap (and matrix up to MATRIX_TABLE_AGENTS agents)."""
        a, label = self.arrays, cell.label
        return {name: a[key] for name in STEADY_ARRAYS if (key := f"steady:{label}:{name}") in a}

    def cell(self, alg: str, m: int, sigma_c: float) -> Cell:
        return next(c for c in self.cells if c.alg == alg and c.m == m and c.sigma_c == sigma_c)

    def kf_prior(self, steps) -> np.ndarray:
        return self.arrays["kf_prior"][np.asarray(steps)]


def gain_tables(sc: NoisyConsensusScenario, quick: bool) -> dict[str, np.ndarray]:
    """The optimal gains of (16), printed and corrected, m = 0..rounds_max (Fig. 2); the corrected
    ones at LARGE_M (§IV); the re-optimised gain of Carli's filter. Symmetric Q only."""
    out: dict[str, np.ndarray] = {}
    if not sc.symmetric:
        return out
    grid = gain_grid(sc, quick)
    common = dict(sigma_c=sc.sigma_c, q=sc.q, r=sc.r)
    tables = gt.reinjection_gain_tables(sc.Q, ms=range(sc.rounds_max + 1), formulas=("corrected", "printed"),
                                        grid=grid, **common)
    tables["large_m"] = gt.reinjection_gain_tables(sc.Q, ms=LARGE_M, formulas=("corrected",), grid=grid,
                                                   **common)["corrected"]
    tables["carli_opt"] = gt.carli_gain_table(sc.Q, ms=range(sc.rounds_max + 1), **common)
    for name, t in tables.items():
        for attr in ("ell", "zeta", "J", "dJ_dell", "dJ_dzeta", "d2J_dell2", "d2J_dzeta2", "kkt_residual",
                     "kkt_scaled", "grid_min"):
            out[f"{name}_{attr}"] = getattr(t, attr)
    out["large_m"] = np.array(LARGE_M)
    return out


def reinjection_gains(sc: NoisyConsensusScenario, arrays: dict[str, np.ndarray], m: int, sigma_c: float,
                      variant: str | None = None) -> tuple[float, float]:
    """The (ℓ, ζ) the re-injection filter uses in a cell, by the scenario's gain rule."""
    variant = variant or sc.reinjection_gains
    if variant == "fixed":
        return sc.fixed_ell, sc.fixed_zeta
    s = sc.sigma_c.index(sigma_c)
    formula = variant.removeprefix("optimal-")
    return float(arrays[f"{formula}_ell"][s, m]), float(arrays[f"{formula}_zeta"][s, m])


def make_cells(sc: NoisyConsensusScenario, arrays: dict[str, np.ndarray]) -> list[Cell]:
    cells = []
    for alg in ALGORITHMS:
        for m in sc.rounds:
            for sigma_c in sc.sigma_c:
                ell, zeta = (sc.carli_ell, 1.0) if alg == "carli" else reinjection_gains(sc, arrays, m, sigma_c)
                cells.append(Cell(alg, m, sigma_c, ell, zeta, sc.n_steps))
    return cells


def long_run_cell(sc: NoisyConsensusScenario, arrays: dict[str, np.ndarray]) -> Cell:
    """Theorem 1(i) check in the asymptotic regime: re-injection filter, m = 1 (or the smallest
    m > 0), the largest σ_c, its gains, over max(n_steps, LONG_RUN_STEPS) steps (the grid's own
    cell when the horizon is long enough)."""
    m = next((m for m in sc.rounds if m > 0), sc.rounds[-1])
    sigma_c = sc.sigma_c[-1]
    ell, zeta = reinjection_gains(sc, arrays, m, sigma_c)
    return Cell("reinjection", m, sigma_c, ell, zeta, max(sc.n_steps, LONG_RUN_STEPS))


def carli_thresholds(sc: NoisyConsensusScenario, rounds) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For consecutive m → m' in `rounds`: the σ_c above which tr P(k_eval) of Carli's filter increases
    (0 if it always does, inf if never), the σ_c² coefficients b_m and the noise-free traces a_m
    (tr = a_m + b_m σ_c², the recursion being affine in σ_c²)."""
    def trace(m, noise_only):
        kw = dict(q=0.0, r=0.0, sigma0=0.0, sigma_c=1.0) if noise_only else dict(q=sc.q, r=sc.r, sigma0=sc.sigma0,
                                                                                sigma_c=0.0)
        P = cc.predictive_covariance_at_steps(sc.Q, ell=sc.carli_ell, m=m, steps=[sc.eval_step], reinjection=False, **kw)
        return float(P.trace[0])

    a = np.array([trace(m, False) for m in rounds])
    b = np.array([trace(m, True) for m in rounds])
    da, db = -np.diff(a), np.diff(b)   # the trace rises from m to m' iff b' σ² + a' > b σ² + a
    with np.errstate(divide="ignore", invalid="ignore"):
        thr = np.where(db > 0, np.sqrt(np.maximum(da, 0.0) / db), np.where(da < 0, 0.0, np.inf))
    return thr, b, a


def compute_design(sc: NoisyConsensusScenario, quick: bool) -> dict[str, np.ndarray]:
    """Every deterministic quantity of a scenario, as named arrays (see `Design`)."""
    out = gain_tables(sc, quick)
    out["Q"] = sc.Q
    lam = np.linalg.eigvalsh(sc.Q) if sc.symmetric else np.linalg.eigvals(sc.Q)
    lam = lam[np.lexsort((np.imag(lam), np.real(lam)))]
    out["eig_real"], out["eig_imag"] = np.real(lam).astype(float), np.imag(lam).astype(float)
    out["steps"] = recorded_steps(sc.n_steps, sc.recorded_steps, sc.eval_step)
    Kc, NPc = gt.optimal_gain_no_communication(sc.q, sc.r / sc.n, sc.n)
    K1, NP1 = gt.optimal_gain_no_communication(sc.q, sc.r, sc.n)
    out["centralized"] = np.array([Kc, NPc / sc.n, K1, NP1 / sc.n])   # K_c, P_c⁻, K_1, P_1⁻
    out["kf_prior"] = cc.centralized_prior_variances(sc.q, sc.r, sc.n, sc.sigma0, max(sc.n_steps, LONG_RUN_STEPS))
    cells = make_cells(sc, out)
    long_cell = long_run_cell(sc, out)
    design = Design(sc, out)
    full = sc.n <= MATRIX_TABLE_AGENTS
    for c in dict.fromkeys(cells + [long_cell]):
        P = cc.predictive_covariance_at_steps(sc.Q, steps=design.steps_of(c), **{k: v for k, v in filter_kwargs(sc, c).items()
                                                                                   if k != "n_steps"})
        out[f"exact:{c.label}:diag"], out[f"exact:{c.label}:trace"], out[f"exact:{c.label}:eig"] = \
            P.diag, P.trace, P.eigenvalues
        S = cc.asymptotic_covariance_summary(sc.Q, reference=NPc / sc.n, with_matrix=full, **steady_kwargs(sc, c))
        out[f"steady:{c.label}:diag"], out[f"steady:{c.label}:trace"] = S.diag, np.array(S.trace)
        out[f"steady:{c.label}:gap"] = np.array(S.loewner_gap)
        if full:
            out[f"steady:{c.label}:matrix"] = S.matrix
    if len(sc.rounds) >= 2:
        out["carli_thresholds"], out["carli_noise_coef"], out["carli_noise_free"] = carli_thresholds(sc, sc.rounds)
    return out


def design_from(sc: NoisyConsensusScenario, arrays: dict[str, np.ndarray]) -> Design:
    return Design(sc, arrays, make_cells(sc, arrays), long_run_cell(sc, arrays))


def design_key(sc: NoisyConsensusScenario, quick: bool) -> dict[str, Any]:
    return {"scenario": sc.key(), "grid": gain_grid(sc, quick), "code": code_fingerprint(CODE_MODULES)}


def design(sc: NoisyConsensusScenario, quick: bool, cache: StageCache | None = None) -> Design:
    if cache is None:
        return design_from(sc, compute_design(sc, quick))
    arrays = cache.get_or_compute("design", design_key(sc, quick), lambda: compute_design(sc, quick), scenario=sc.name,
                                  allow_nonfinite=("carli_thresholds",))
    return design_from(sc, arrays)


# -- Monte Carlo ----------------------------------------------------------------------------------

STATS = ("s1", "s2", "s4", "t1", "t2")


def bytes_per_trial(n_configs: int, n_agents: int, n_recorded: int) -> float:
    """Memory of one trial in a chunk: the filters' state, one step's errors and their powers
    (about 13 arrays of C x N, 8 of N), and its share of its stream's recorded sums."""
    C, N, S = n_configs, n_agents, n_recorded
    return 8.0 * (13 * C * N + 8 * N + 6) + 2 * 8.0 * C * S * (3 * N + 2) / RNG_UNIT


def group_streams(seed: int, cells: tuple[Cell, ...]) -> np.random.SeedSequence:
    # named by (m, horizon) only: both filters at the same m see the same x, n, u and w, so sample
    # trials compare them on one truth (each cell stays an exact simulation)
    return stream_seed(seed, "mc", cells[0].m, cells[0].n_steps)


def simulate_group(sc: NoisyConsensusScenario, seed: int, trials: int, steps: np.ndarray, budget_bytes: float,
                   cells: tuple[Cell, ...], desc: str = "", reference: bool = False) -> dict[str, np.ndarray]:
    """All trials of cells that differ only in (σ_c, ℓ, ζ), streamed over trials (units of 1,000) and
    time (moments at `steps` only). Returns moment sums per cell (keys ``<label>__pred_s1``, ...)
    and the sample paths of the first trials over the first steps; with `reference`, also filterpy's
    Kalman filter on the first cell's sample measurements (`filterpy_priors`)."""
    first = cells[0]
    assert all((c.alg, c.m, c.n_steps) == (first.alg, first.m, first.n_steps) for c in cells)
    C = len(cells)
    path_steps = min(first.n_steps, sc.sample_steps)

    def chunk(streams):
        paths = sc.sample_paths if streams is not None and chunk.first else 0
        chunk.first = False
        run = cf.consensus_filter_moments(
            sc.Q, ell=[c.ell for c in cells], sigma_c=[c.sigma_c for c in cells], zeta=[c.zeta for c in cells],
            m=first.m, q=sc.q, r=sc.r, sigma0=sc.sigma0, x0_mean=sc.x0_mean, n_steps=first.n_steps,
            rng=list(zip(streams.generators, streams.sizes)), reinjection=first.reinjection, record_steps=steps,
            n_paths=paths, path_steps=path_steps)
        parts = [{f"{kind}_{name}": getattr(getattr(run, kind), name)[u] for kind in ("pred", "filt") for name in STATS}
                 | {"count": run.pred.count[u]} for u in range(len(streams.sizes))]
        if paths:
            parts[0]["paths"] = run.paths
        return parts

    chunk.first = True

    def fold(acc, part):
        if acc is None:
            return dict(part)
        for k, v in part.items():
            if k != "paths":
                acc[k] = acc[k] + v
        return acc

    per_trial = bytes_per_trial(C, sc.n, len(steps))
    total = run_units(chunk, fold, trials, group_streams(seed, cells), bytes_per_trial=per_trial,
                      budget_bytes=min(budget_bytes, CHUNK_BYTES, CHUNK_TRIALS * per_trial), desc=desc)
    arrays: dict[str, np.ndarray] = {}
    paths = total.pop("paths", None)
    for j, c in enumerate(cells):
        arrays[f"{c.label}__pred_count"] = arrays[f"{c.label}__filt_count"] = np.array(total["count"])
        for kind in ("pred", "filt"):
            for name in STATS:
                arrays[f"{c.label}__{kind}_{name}"] = total[f"{kind}_{name}"][j]
        if paths is not None:
            for name in ("x", "y", "u", "w", "n"):
                arrays[f"{c.label}__path_{name}"] = np.asarray(getattr(paths, name))
            for name in ("xhat_pred", "xhat_filt", "z_rounds"):
                arrays[f"{c.label}__path_{name}"] = np.asarray(getattr(paths, name)[:, j])
    if reference and paths is not None:
        arrays[f"{first.label}__filterpy_x"], arrays[f"{first.label}__filterpy_P"] = filterpy_priors(sc, paths.y)
    return arrays


def filterpy_priors(sc: NoisyConsensusScenario, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """x̂(k|k-1) and P(k|k-1) (P, K) of filterpy's KalmanFilter (update, then predict) on the stacked
    measurements y (P, K, N) of each sample trial: the independent reference of the claim
    savas.reference.filterpy, computed with the sample paths (in a Monte Carlo worker, where importing
    filterpy, and with it scipy.stats, overlaps the other workers' trials)."""
    from filterpy.kalman import KalmanFilter

    F, H_, Qw, R = np.eye(1), np.ones((sc.n, 1)), np.array([[sc.q]]), sc.r * np.eye(sc.n)
    xs, Ps = np.empty(y.shape[:2]), np.empty(y.shape[:2])
    for p in range(y.shape[0]):
        kf = KalmanFilter(dim_x=1, dim_z=sc.n)
        kf.F, kf.H, kf.Q, kf.R = F.copy(), H_.copy(), Qw.copy(), R.copy()
        kf.x, kf.P = np.array([[sc.x0_mean]]), np.array([[sc.sigma0]])
        for k in range(y.shape[1]):
            xs[p, k], Ps[p, k] = kf.x[0, 0], kf.P[0, 0]
            kf.update(y[p, k])
            kf.predict()
    return xs, Ps


def cell_groups(cells: list[Cell]) -> list[tuple[Cell, ...]]:
    """Cells grouped by (algorithm, m, horizon), in first-seen order (a cell listed twice once)."""
    groups: dict[tuple, list[Cell]] = {}
    for c in dict.fromkeys(cells):
        groups.setdefault((c.alg, c.m, c.n_steps), []).append(c)
    return [tuple(g) for g in groups.values()]


@dataclass
class Results:
    scenario: NoisyConsensusScenario
    seed: int
    trials: int
    quick: bool
    design: Design
    mc: dict[str, dict[str, np.ndarray]] = field(default_factory=dict)

    @property
    def bounds(self) -> dict[str, np.ndarray]:
        return self.design.arrays

    @property
    def cells(self) -> list[Cell]:
        return self.design.cells

    @property
    def long_cell(self) -> Cell | None:
        return self.design.long_cell

    def cell(self, alg: str, m: int, sigma_c: float) -> Cell:
        return self.design.cell(alg, m, sigma_c)

    def steps_of(self, cell: Cell) -> np.ndarray:
        return self.design.steps_of(cell)

    def exact(self, cell: Cell) -> cc.CovarianceAtSteps:
        return self.design.exact(cell)

    def moments(self, cell: Cell, which: str = "pred") -> ErrorMoments:
        """Monte Carlo sums of the cell's errors at its recorded steps (axis 0 of every array)."""
        a = self.mc[cell.label]
        return ErrorMoments.from_arrays({k.removeprefix(which + "_"): v for k, v in a.items() if k.startswith(which + "_")})

    def paths(self, cell: Cell) -> dict[str, np.ndarray]:
        return {k.removeprefix("path_"): v for k, v in self.mc[cell.label].items() if k.startswith("path_")}


def _cached_group(cache: StageCache, key: dict[str, Any], sc, seed, trials, steps, budget, desc, reference, cells
                  ) -> dict[str, np.ndarray]:
    return cache.get_or_compute("mc", {**key, "cells": [c.__dict__ for c in cells], "steps": steps, "reference": reference},
                                functools.partial(simulate_group, sc, seed, trials, steps, budget, cells, desc, reference),
                                scenario=sc.name)


def compute(sc: NoisyConsensusScenario, opts: RunOptions, cache: StageCache) -> Results:
    from .cost import refuse_if_too_large

    trials = trial_count(sc, opts)
    refuse_if_too_large(sc, opts)
    d = design(sc, opts.quick, cache)
    base = {"scenario": sc.key(), "code": code_fingerprint(CODE_MODULES), "seed": opts.seed, "trials": trials}
    budget = opts.chunk_budget_bytes()
    # the group of the first cell also runs filterpy's reference filter on its sample paths: first, so that
    # importing filterpy overlaps the other groups; then the longest first
    groups = sorted(cell_groups(d.cells + [d.long_cell]), key=lambda g: (g[0] != d.cells[0], -(g[0].m + 2) * g[0].n_steps))
    # in one process, each group shows its chunks (with the time left); with workers, the groups are counted
    desc = (lambda g: f"{sc.name}: {g[0].alg} m = {g[0].m}, {trials:,} trials") if opts.workers <= 1 else (lambda g: "")
    work = [functools.partial(_cached_group, cache, base, sc, opts.seed, trials, d.steps_of(g[0]), budget, desc(g),
                              g[0] == d.cells[0], g) for g in groups]
    outputs = parallel_map(_call, work, workers=opts.workers, desc=f"{sc.name}: Monte Carlo (algorithm, m) groups")
    mc: dict[str, dict[str, np.ndarray]] = {}
    for out in outputs:
        for k, value in out.items():
            label, name = k.split("__", 1)
            mc.setdefault(label, {})[name] = value
    return Results(sc, opts.seed, trials, opts.quick, d, mc)


def _call(f):
    return f()
