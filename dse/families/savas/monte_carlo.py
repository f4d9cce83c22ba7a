"""The Monte Carlo stage of the noisy-consensus-filter family.

Cells (algorithm, m, σ_c) are simulated in groups that share (algorithm, m, horizon): one run
drives every σ_c with the same random draws (common random numbers), and each group is one
stage result (one cache entry), so an interrupted run resumes group by group. Within a group
the trials stream in units of 1,000 with their own random streams (`dse.simulate.units.run_units`,
portable: on the run's unit executor, a Dask cluster with `--scheduler local`), as many units at a time
as the memory budget allows, and time streams step by step: only the
sums of the errors' powers at the recorded steps are kept. Results do not depend on the budget.
"""
from __future__ import annotations

import numpy as np

import dse.estimators.consensus_filter as cf
from dse.contract.stages import stage
from dse.simulate.seeding import stream_seed
from dse.simulate.units import RNG_UNIT, run_units

from .cells import Cell
from .scenario import NoisyConsensusFile

STATS = ("s1", "s2", "s4", "t1", "t2")
#: parts of the first unit's result that are not sums over trials: the sample paths and filterpy's reference on them
FIRST_UNIT_ONLY = ("paths", "filterpy")
#: a chunk holds at most this many trials and bytes (measured fastest here: larger arrays leave the
#: processor's caches); the memory budget may make it smaller, never larger
CHUNK_TRIALS = 10_000
CHUNK_BYTES = 32 * 2**20


def bytes_per_trial(n_configs: int, n_agents: int, n_recorded: int) -> float:
    """Memory of one trial in a chunk: the filters' state, one step's errors and their powers
    (about 13 arrays of C x N, 8 of N), and its share of its stream's recorded sums."""
    C, N, S = n_configs, n_agents, n_recorded
    return 8.0 * (13 * C * N + 8 * N + 6) + 2 * 8.0 * C * S * (3 * N + 2) / RNG_UNIT


def group_streams(seed: int, cells: tuple[Cell, ...]) -> np.random.SeedSequence:
    # named by (m, horizon) only: both filters at the same m see the same x, n, u and w, so sample
    # trials compare them on one truth (each cell stays an exact simulation)
    return stream_seed(seed, "mc", cells[0].m, cells[0].n_steps)


def cell_groups(cells: list[Cell]) -> list[tuple[Cell, ...]]:
    """Cells grouped by (algorithm, m, horizon), in first-seen order (a cell listed twice once)."""
    groups: dict[tuple, list[Cell]] = {}
    for c in dict.fromkeys(cells):
        groups.setdefault((c.alg, c.m, c.n_steps), []).append(c)
    return [tuple(g) for g in groups.values()]


def _group_arrays(sc: NoisyConsensusFile, cells: tuple[Cell, ...], total: dict, reference: bool) -> dict[str, np.ndarray]:
    """The folded sums of a group as named arrays per cell (``<label>__pred_s1``, ..., ``<label>__path_x``)."""
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
        arrays[f"{cells[0].label}__filterpy_x"], arrays[f"{cells[0].label}__filterpy_P"] = total.pop("filterpy")
    return arrays


@stage(name="monte_carlo", unkeyed=("budget_bytes", "desc"))
def simulate_group(sc: NoisyConsensusFile, seed: int, trials: int, steps: np.ndarray, budget_bytes: float,
                   cells: tuple[Cell, ...], desc: str = "", reference: bool = False) -> dict[str, np.ndarray]:
    """All trials of cells that differ only in (σ_c, ℓ, ζ), streamed over trials (units of 1,000) and
    time (moments at `steps` only). Returns moment sums per cell (keys ``<label>__pred_s1``, ...)
    and the sample paths of the first trials over the first steps; with `reference`, also filterpy's
    Kalman filter on the first cell's sample measurements (`filterpy_priors`)."""
    first, model, mc = cells[0], sc.model, sc.monte_carlo
    assert all((c.alg, c.m, c.n_steps) == (first.alg, first.m, first.n_steps) for c in cells)
    path_steps = min(first.n_steps, mc.sample_steps)

    def chunk(streams):
        paths = mc.sample_paths if streams.first_unit == 0 else 0      # the sample paths are the first trials'
        run = cf.consensus_filter_moments(
            sc.Q, ell=[c.ell for c in cells], sigma_c=[c.sigma_c for c in cells], zeta=[c.zeta for c in cells],
            m=first.m, q=model.q, r=model.r, sigma0=model.sigma0, x0_mean=model.x0_mean, n_steps=first.n_steps,
            rng=list(zip(streams.generators, streams.sizes)), reinjection=first.reinjection, record_steps=steps,
            n_paths=paths, path_steps=path_steps)
        parts = [{f"{kind}_{name}": getattr(getattr(run, kind), name)[u] for kind in ("pred", "filt") for name in STATS}
                 | {"count": run.pred.count[u]} for u in range(len(streams.sizes))]
        if paths:
            parts[0]["paths"] = run.paths
            if reference:
                parts[0]["filterpy"] = filterpy_priors(sc, run.paths.y)
        return parts

    def fold(acc, part):
        if acc is None:
            return dict(part)
        for k, v in part.items():
            if k not in FIRST_UNIT_ONLY:
                acc[k] = acc[k] + v
        return acc

    per_trial = bytes_per_trial(len(cells), sc.n, len(steps))
    total = run_units(chunk, fold, trials, group_streams(seed, cells), bytes_per_trial=per_trial,
                      budget_bytes=min(budget_bytes, CHUNK_BYTES, CHUNK_TRIALS * per_trial), desc=desc, portable=True)
    return _group_arrays(sc, cells, total, reference)


def filterpy_priors(sc: NoisyConsensusFile, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """x̂(k|k-1) and P(k|k-1) (P, K) of filterpy's KalmanFilter (update, then predict) on the stacked
    measurements y (P, K, N) of each sample trial: the independent reference of the claim
    savas.reference.filterpy, computed by the chunk that draws the sample paths: in a Monte Carlo worker
    (a forked process, or a Dask worker on a cluster), where importing filterpy, and with it scipy.stats,
    overlaps the other workers' trials instead of following them all."""
    from filterpy.kalman import KalmanFilter

    model = sc.model
    F, H_, Qw, R = np.eye(1), np.ones((sc.n, 1)), np.array([[model.q]]), model.r * np.eye(sc.n)
    xs, Ps = np.empty(y.shape[:2]), np.empty(y.shape[:2])
    for p in range(y.shape[0]):
        kf = KalmanFilter(dim_x=1, dim_z=sc.n)
        kf.F, kf.H, kf.Q, kf.R = F.copy(), H_.copy(), Qw.copy(), R.copy()
        kf.x, kf.P = np.array([[model.x0_mean]]), np.array([[model.sigma0]])
        for k in range(y.shape[1]):
            xs[p, k], Ps[p, k] = kf.x[0, 0], kf.P[0, 0]
            kf.update(y[p, k])
            kf.predict()
    return xs, Ps
