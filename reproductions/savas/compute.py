"""Stages of the noisy-consensus-filter family: bounds (exact, cached) and Monte Carlo.

Monte Carlo cells (algorithm, m, σ_c) are simulated in groups that share (algorithm, m):
one run drives every σ_c with the same random draws (common random numbers), and each
group is one cache entry, so an interrupted run resumes group by group."""
from __future__ import annotations

import functools
from dataclasses import dataclass, field
from typing import Any

import numpy as np

import estimators.consensus_covariance as cc
import estimators.consensus_filter as cf
import estimators.gain_tuning as gt
import estimators.kalman as kal
from pipeline.cache import StageCache, code_fingerprint
from pipeline.reproduction import RunOptions
from pipeline.progress import progress
from pipeline.seeding import stream_seed
from pipeline.simulate import block_size, parallel_map, run_blocks
from pipeline.stats import ErrorMoments

from .scenario import NoisyConsensusScenario

ALGORITHMS = ("carli", "reinjection")
LARGE_M = (5, 10, 20, 50, 100, 200)
LONG_RUN_STEPS = 60
CODE_MODULES = ("estimators.consensus_covariance", "estimators.consensus_filter", "estimators.gain_tuning",
                "estimators.kalman", "pipeline.stats", "pipeline.simulate", "pipeline.seeding",
                "reproductions.savas.compute")


@dataclass(frozen=True)
class Cell:
    """One Monte Carlo cell: algorithm, rounds m, communication noise σ_c and its gains."""

    alg: str
    m: int
    sigma_c: float
    ell: float
    zeta: float
    n_steps: int

    @property
    def label(self) -> str:
        return f"{self.alg}_m{self.m}_sc{self.sigma_c:g}_K{self.n_steps}"


@dataclass
class Results:
    scenario: NoisyConsensusScenario
    seed: int
    trials: int
    quick: bool
    bounds: dict[str, np.ndarray]
    cells: list[Cell]
    mc: dict[str, dict[str, np.ndarray]] = field(default_factory=dict)
    long_cell: Cell | None = None

    def moments(self, cell: Cell, which: str = "pred") -> ErrorMoments:
        a = self.mc[cell.label]
        return ErrorMoments.from_arrays({k.removeprefix(which + "_"): v for k, v in a.items() if k.startswith(which + "_")})

    def exact_pred(self, cell: Cell) -> np.ndarray:
        """P(k|k-1), k < cell.n_steps, from the one-step recursion (22) (memoised)."""
        cache = self.__dict__.setdefault("_exact", {})
        if cell.label not in cache:
            cache[cell.label] = cc.predictive_covariance_sequence(self.scenario.Q, **filter_kwargs(self.scenario, cell))
        return cache[cell.label]

    def cell(self, alg: str, m: int, sigma_c: float) -> Cell:
        return next(c for c in self.cells if c.alg == alg and c.m == m and c.sigma_c == sigma_c)


def trial_count(sc: NoisyConsensusScenario, opts: RunOptions) -> int:
    return opts.trials if opts.trials is not None else (sc.quick_trials if opts.quick else sc.trials)


def gain_grid(sc: NoisyConsensusScenario, quick: bool) -> tuple[int, int]:
    return (100, 101) if quick else sc.grid


def filter_kwargs(sc: NoisyConsensusScenario, cell: Cell) -> dict[str, Any]:
    return dict(ell=cell.ell, m=cell.m, sigma_c=cell.sigma_c, q=sc.q, r=sc.r, sigma0=sc.sigma0,
                n_steps=cell.n_steps, reinjection=cell.alg == "reinjection", zeta=cell.zeta)


# -- bounds ---------------------------------------------------------------------------------------

def compute_bounds(sc: NoisyConsensusScenario, quick: bool) -> dict[str, np.ndarray]:
    """Gain optimisation tables (Fig. 2), large-m limits, Carli's optimum and the KF reference."""
    S, M = len(sc.sigma_c), sc.rounds_max
    out: dict[str, np.ndarray] = {}
    grid = gain_grid(sc, quick)
    if sc.symmetric:
        for formula in ("corrected", "printed"):
            ell, zeta, J, kkt, kkt_zeta, grid_min, scaled = (np.zeros((S, M + 1)) for _ in range(7))
            for s, sigma_c in enumerate(progress(sc.sigma_c, desc=f"{sc.name}: optimal gains, {formula} (16)")):
                for m in range(M + 1):
                    opt = gt.optimal_reinjection_gains(sc.Q, m=m, sigma_c=sigma_c, q=sc.q, r=sc.r,
                                                       formula=formula, grid=grid)
                    ell[s, m], zeta[s, m], J[s, m] = opt.ell, opt.zeta, opt.J
                    kkt[s, m], kkt_zeta[s, m] = opt.kkt.dJ_dell, opt.kkt.dJ_dzeta
                    scaled[s, m] = opt.kkt.scaled_residual(opt.J, opt.ell)
                    grid_min[s, m] = np.min(opt.grid_J)
            out.update({f"{formula}_ell": ell, f"{formula}_zeta": zeta, f"{formula}_J": J,
                        f"{formula}_dJ_dell": kkt, f"{formula}_dJ_dzeta": kkt_zeta, f"{formula}_grid_min": grid_min,
                        f"{formula}_kkt_scaled": scaled})
        big = [[gt.optimal_reinjection_gains(sc.Q, m=m, sigma_c=s_c, q=sc.q, r=sc.r, formula="corrected", grid=grid)
                for m in LARGE_M] for s_c in sc.sigma_c]
        out["large_m"] = np.array(LARGE_M)
        out["large_m_ell"] = np.array([[o.ell for o in row] for row in big])
        out["large_m_zeta"] = np.array([[o.zeta for o in row] for row in big])
        out["large_m_J"] = np.array([[o.J for o in row] for row in big])
        carli = [[gt.optimal_carli_gain(sc.Q, m=m, sigma_c=s_c, q=sc.q, r=sc.r) for m in range(M + 1)]
                 for s_c in sc.sigma_c]
        out["carli_opt_ell"] = np.array([[o.ell for o in row] for row in carli])
        out["carli_opt_J"] = np.array([[o.J for o in row] for row in carli])
    # centralized Kalman filter on all N measurements: the lower bound of every agent
    F, H, Qw, R = np.eye(1), np.ones((sc.n, 1)), np.array([[sc.q]]), sc.r * np.eye(sc.n)
    kf = kal.kalman_covariances(F, H, Qw, R, np.array([[sc.sigma0]]), max(sc.n_steps, LONG_RUN_STEPS))
    out["kf_prior"] = kf.P_prior[:, 0, 0]
    out["kf_steady_prior"] = np.array(kal.steady_state_prior_covariance(F, H, Qw, R)[0, 0])
    out["single_sensor_steady_prior"] = np.array(kal.scalar_random_walk_steady_state(sc.q, sc.r)[0])
    return out


def reinjection_gains(sc: NoisyConsensusScenario, bounds: dict[str, np.ndarray], m: int, sigma_c: float,
                      variant: str | None = None) -> tuple[float, float]:
    """The (ℓ, ζ) the re-injection filter uses in a cell, by the scenario's gain rule."""
    variant = variant or sc.reinjection_gains
    if variant == "fixed":
        return sc.fixed_ell, sc.fixed_zeta
    s = sc.sigma_c.index(sigma_c)
    formula = variant.removeprefix("optimal-")
    return float(bounds[f"{formula}_ell"][s, m]), float(bounds[f"{formula}_zeta"][s, m])


def make_cells(sc: NoisyConsensusScenario, bounds: dict[str, np.ndarray]) -> list[Cell]:
    cells = []
    for alg in ALGORITHMS:
        for m in sc.rounds:
            for sigma_c in sc.sigma_c:
                ell, zeta = (sc.carli_ell, 1.0) if alg == "carli" else reinjection_gains(sc, bounds, m, sigma_c)
                cells.append(Cell(alg, m, sigma_c, ell, zeta, sc.n_steps))
    return cells


def long_run_cell(sc: NoisyConsensusScenario, bounds: dict[str, np.ndarray]) -> Cell:
    """Theorem 1(i) check in the asymptotic regime: re-injection filter, m = 1 (or the smallest
    m > 0), the largest σ_c, its gains, run for LONG_RUN_STEPS steps."""
    m = next((m for m in sc.rounds if m > 0), sc.rounds[-1])
    sigma_c = sc.sigma_c[-1]
    ell, zeta = reinjection_gains(sc, bounds, m, sigma_c)
    return Cell("reinjection", m, sigma_c, ell, zeta, LONG_RUN_STEPS)


# -- Monte Carlo ----------------------------------------------------------------------------------

def simulate_group(sc: NoisyConsensusScenario, seed: int, trials: int, cells: tuple[Cell, ...]) -> dict[str, np.ndarray]:
    """All trials of cells that differ only in (σ_c, ℓ, ζ): one run with common random numbers
    (estimators.consensus_filter.simulate_consensus_filter_configs), in seeded blocks.

    Returns moment sums per cell (keys ``<label>__pred_s1``, ...) and a few sample paths."""
    first = cells[0]
    assert all((c.alg, c.m, c.n_steps) == (first.alg, first.m, first.n_steps) for c in cells)
    C = len(cells)
    paths: dict[str, np.ndarray] = {}
    buffers: dict = {}   # error arrays reused block to block (each block's moments are taken before the next)

    def block(size: int, rng: np.random.Generator):
        want_paths = sc.sample_paths if not paths else 0
        run = cf.simulate_consensus_filter_configs(
            sc.Q, ell=[c.ell for c in cells], sigma_c=[c.sigma_c for c in cells], zeta=[c.zeta for c in cells],
            m=first.m, q=sc.q, r=sc.r, sigma0=sc.sigma0, x0_mean=sc.x0_mean, n_steps=first.n_steps, n_trials=size,
            rng=rng, reinjection=first.alg == "reinjection", n_paths=want_paths, buffers=buffers)
        if want_paths:
            for j, c in enumerate(cells):
                for name in ("x", "y", "u", "w", "n"):
                    paths[f"{c.label}__path_{name}"] = np.asarray(getattr(run, name))
                for name in ("xhat_pred", "xhat_filt", "z_rounds"):
                    paths[f"{c.label}__path_{name}"] = np.asarray(getattr(run, name)[:, j])
        return [(ErrorMoments.of(run.err_pred[:, j]), ErrorMoments.of(run.err_filt[:, j])) for j in range(C)]

    def combine(parts):
        return [(ErrorMoments.combine([p[j][0] for p in parts]), ErrorMoments.combine([p[j][1] for p in parts]))
                for j in range(C)]

    per_trial = 8 * C * first.n_steps * sc.n * 2 + 8 * 8 * C * sc.n
    # the stream is named by (m, horizon) only: both filters at the same m see the same x, n, u
    # and w, so sample trials compare them on one truth (each cell stays an exact simulation)
    moments = run_blocks(block, combine, trials, stream_seed(seed, "mc", first.m, first.n_steps),
                         block=block_size(per_trial))
    arrays = dict(paths)
    for c, (pred, filt) in zip(cells, moments):
        arrays.update({f"{c.label}__pred_{k}": v for k, v in pred.arrays().items()})
        arrays.update({f"{c.label}__filt_{k}": v for k, v in filt.arrays().items()})
    return arrays


def cell_groups(cells: list[Cell]) -> list[tuple[Cell, ...]]:
    """Cells grouped by (algorithm, m, horizon), in first-seen order."""
    groups: dict[tuple, list[Cell]] = {}
    for c in cells:
        groups.setdefault((c.alg, c.m, c.n_steps), []).append(c)
    return [tuple(g) for g in groups.values()]


def _cached_group(cache: StageCache, key: dict[str, Any], sc, seed, trials, cells) -> dict[str, np.ndarray]:
    return cache.get_or_compute("mc", {**key, "cells": [c.__dict__ for c in cells]},
                                functools.partial(simulate_group, sc, seed, trials, cells), scenario=sc.name)


def compute(sc: NoisyConsensusScenario, opts: RunOptions, cache: StageCache) -> Results:
    trials = trial_count(sc, opts)
    code = code_fingerprint(CODE_MODULES)
    base = {"scenario": sc.key(), "code": code}
    bounds = cache.get_or_compute("bounds", {**base, "grid": gain_grid(sc, opts.quick)},
                                  lambda: compute_bounds(sc, opts.quick), scenario=sc.name)
    cells = make_cells(sc, bounds)
    long_cell = long_run_cell(sc, bounds)
    mc_key = {**base, "seed": opts.seed, "trials": trials}
    work = functools.partial(_cached_group, cache, mc_key, sc, opts.seed, trials)
    groups = sorted(cell_groups(cells + [long_cell]), key=lambda g: -g[0].m * g[0].n_steps)  # longest first
    outputs = parallel_map(work, groups, workers=opts.workers, desc=f"{sc.name}: Monte Carlo (algorithm, m) groups")
    mc: dict[str, dict[str, np.ndarray]] = {}
    for out in outputs:
        for key, value in out.items():
            label, name = key.split("__", 1)
            mc.setdefault(label, {})[name] = value
    return Results(sc, opts.seed, trials, opts.quick, bounds, cells, mc, long_cell)
