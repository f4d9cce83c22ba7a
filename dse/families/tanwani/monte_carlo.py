"""The Monte Carlo stages of the random-comm-filter family: the gridded simulator per (scenario, λ),
the exact event-driven simulator at the main rate, and one frozen clock path shared by every trial.

Monte Carlo is streamed: trials in RNG units of 1,000 (`dse.simulate.units.run_units`, as many
units per chunk as the memory budget allows; every reduction is made per unit and folded in unit
order, so the numbers do not depend on the budget), and time output by output (gridded) or window
by window (event-driven). The statistics the claims test are accumulated beside the simulators, in
their output callbacks: second moments per output time, the test-cell sums, the node event counts,
the few sample trials and the paired trials; nothing else is kept.
"""
from __future__ import annotations

import math

import numpy as np

import dse.estimators.gossip_covariance as gc
import dse.estimators.gossip_filter as gf
from dse.contract.stages import stage
from dse.simulate.matrix_moments import MatrixMoments
from dse.simulate.seeding import stream_seed
from dse.simulate.units import (BLOCK_MEMORY_BYTES, block_generator, kept_rows, rows_by_unit, run_units,
                                stack_rows)

from .references import directions, quadratic_forms, test_times
from .scenario import RandomCommFile

PAIR_MAX = 5000            # trials kept one by one for the paired comparison of the two simulators
WHITEN_RTOL = 1e-9         # eigenvalues of Σ_ii(t; τ) below this fraction of the largest are not whitened
#: arrays where inf/NaN is a result, not a failure: Monte Carlo states that overflow on a strongly unstable
#: scenario over a long horizon (the claims then say that nothing finite was compared), the inf padding of events
DIVERGING = ("e_s2", "e_s4_trace", "e_s4_entry", "sample_z", "pair_values")
CELL_SUMS = ("qP1", "qP2", "qS1", "qS2", "qE1", "qE2", "white", "white_n")


def _spans(streams) -> list[tuple[int, int]]:
    edges = np.cumsum([0, *streams.sizes])
    return [(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:])]


def _errors(z: np.ndarray, N: int, n: int) -> np.ndarray:
    """The errors e_i of sampled states z (…, (N+1)n) as (…, N, n)."""
    return z[..., n:].reshape(*z.shape[:-1], N, n)


def _moments(acc, part):
    return part if acc is None else MatrixMoments.combine([acc, part])


def _fold_kept(acc: dict | None, part: dict) -> dict:
    """Moments folded in unit order, beside the rows of the trials kept whole (`kept`, a list per unit)."""
    if acc is None:
        return part
    return {"mom": MatrixMoments.combine([acc["mom"], part["mom"]]), "kept": acc["kept"] + part["kept"]}


def gridded_bytes_per_trial(sc: RandomCommFile) -> float:
    """Memory of one gridded trial in a chunk: the state and its copies, the noise draws, the ring counts."""
    s = sc.gossip
    d = (s.N + 1) * s.n
    return 8.0 * (8 * d + 2 * d + 2 * len(s.clocks)) + 64.0


@stage(name="gridded", unkeyed=("budget_bytes",), allow_nonfinite=DIVERGING)
def simulate_gridded_rate(sc: RandomCommFile, seed: int, trials: int, rate: float, pair: int = 0,
                          budget_bytes: float = BLOCK_MEMORY_BYTES) -> dict[str, np.ndarray]:
    """The gridded simulator at one rate: second-moment sums of the errors at every output time
    (MatrixMoments), the first sample trials whole, and (`pair` > 0, main rate) the test-cell values
    (uᵀe_i)² of the first `pair` trials one by one, for the paired comparison with the event-driven
    simulator."""
    s = sc.gossip
    n, N, T = s.n, s.N, sc.n_outputs + 1
    every = int(round(sc.output_step / sc.grid_step))
    U, cells = directions(n), test_times(sc)
    cell_at = {int(k): c for c, k in enumerate(cells)}
    n_samples, n_pairs, D = min(sc.simulation.sample_trials, trials), min(pair, trials), (N + 1) * n

    def chunk(streams):
        spans = _spans(streams)
        parts = [MatrixMoments.zeros(b - a, T, N, n) for a, b in spans]
        samples = np.zeros((kept_rows(streams, n_samples), T, D))
        pairs = np.zeros((kept_rows(streams, n_pairs), len(cells), N, len(U)))

        def record(k, z):
            e = _errors(z, N, n)
            for part, (a, b) in zip(parts, spans):
                part.add([k], e[a:b, None])
            samples[:, k] = z[:len(samples)]
            if len(pairs) and k in cell_at:
                pairs[:, cell_at[k]] = np.square(e[:len(pairs)] @ U.T)

        gf.simulate_gridded(s, rate, sc.grid_step, sc.grid_steps, every, streams.n, streams, on_record=record)
        return [{"mom": m, "kept": [rows] if rows else []} for m, rows in
                zip(parts, rows_by_unit(streams, sample_z=samples, pair_values=pairs))]

    total = run_units(chunk, _fold_kept, trials, stream_seed(seed, "gridded", sc.name, rate),
                      bytes_per_trial=gridded_bytes_per_trial(sc), budget_bytes=budget_bytes, portable=True)
    kept = {"sample_z": stack_rows(total["kept"], "sample_z", np.zeros((0, T, D)))}
    if pair:
        kept["pair_values"] = stack_rows(total["kept"], "pair_values", np.zeros((0, len(cells), N, len(U))))
    return {**total["mom"].arrays("e_"), **kept}


def event_bytes_per_trial(sc: RandomCommFile, *, sample: bool = True) -> float:
    """Memory of one event-driven trial in a chunk: its window of outputs (and the copies the reductions
    make), the window's events, the joint covariance and the per-event temporaries (flows, noise
    covariances, jump matrices)."""
    s = sc.gossip
    N, n = s.N, s.n
    d = (N + 1) * n
    per_output = ((d if sample else 0) + 2 * N * n * n) * 8.0
    events = 3 * (gf.EVENTS_PER_WINDOW + 8 * math.sqrt(gf.EVENTS_PER_WINDOW)) * 16.0
    return 1.5 * event_window(sc) * per_output + events + 8.0 * (9 * d * d + 6 * N * n * n + 4 * d) + 256.0


def event_window(sc: RandomCommFile) -> int:
    return gf.default_window(sc.gossip, sc.main_rate, sc.output_step, sc.n_outputs)


def whitened_squares(sigma: np.ndarray, e: np.ndarray, pairs) -> tuple[np.ndarray, np.ndarray]:
    """Errors whitened by their own path's covariance: with Σ_ii(t; τ) = V diag(w) Vᵀ, the
    coordinates y = diag(w)^(-1/2) Vᵀ e_i are independent N(0, 1) given the clock path when the
    sampler is exact. Returns, per (time, node, cell), the sum over trials of y_a² (cells (a, a))
    and of (y_a + y_b)²/2 (cells (a, b), a < b; also N(0, 1)), and the number of terms (the
    coordinates with w ≤ WHITEN_RTOL·max w are left out: the errors there are rounding)."""
    w, V = np.linalg.eigh((sigma + np.swapaxes(sigma, -1, -2)) / 2)
    ok = w > WHITEN_RTOL * np.maximum(w[..., -1:], 1e-300)
    y = np.einsum("...ab,...a->...b", V, e) / np.sqrt(np.where(ok, w, 1.0))
    sq = np.stack([np.where(ok[..., a], y[..., a] ** 2, 0.0) if a == b
                   else np.where(ok[..., a] & ok[..., b], (y[..., a] + y[..., b]) ** 2 / 2, 0.0) for a, b in pairs], -1)
    cnt = np.stack([ok[..., a] if a == b else ok[..., a] & ok[..., b] for a, b in pairs], -1)
    return sq.sum(0), cnt.sum(0)


class EventStatistics:
    """What the event-driven stage accumulates beside the simulator (its window callback), chunk by
    chunk of RNG units. Per unit: the second-moment sums of the sampled errors and, per test cell
    (`test_times` × node × `directions`), sums of uᵀP_i(t; τ)u, uᵀΣ_ii(t; τ)u, (uᵀe_i)² and their
    squares, and the errors whitened by their own path's exact covariance (`whitened_squares`); node
    event counts (sums and number of paths without event) and the smallest spacing between events.
    Across the run: the first sample paths whole (states, covariances, bounds and rings) and the
    first PAIR_MAX values of (uᵀe_i)²."""

    def __init__(self, sc: RandomCommFile, trials: int):
        s = self.s = sc.gossip
        self.sc, self.T = sc, sc.n_outputs + 1
        self.U, cells = directions(s.n), test_times(sc)
        self.pairs = gc.vech_pairs(s.n)
        self.cell_of = np.full(self.T, -1)
        self.cell_of[cells] = np.arange(len(cells))
        self.n_keep, self.n_pairs = min(sc.simulation.sample_trials, trials), min(PAIR_MAX, trials)
        self.shape = (len(cells), s.N, len(self.U))

    def _start(self, streams) -> None:
        """This chunk's rows of the trials kept whole and of the paired values (the stream's first ones)."""
        s, keep = self.s, kept_rows(streams, self.n_keep)
        self.kept = {"z": np.zeros((keep, self.T, (s.N + 1) * s.n)), "sigma": np.zeros((keep, self.T, s.N, s.n, s.n)),
                     "pbound": np.zeros((keep, self.T, s.N, s.n, s.n)), "t": [[] for _ in range(keep)],
                     "c": [[] for _ in range(keep)]}
        self.pair_values = np.zeros((kept_rows(streams, self.n_pairs), *self.shape))

    def chunk(self, streams) -> list[dict]:
        """`run_units`' chunk: simulate these units, one partial result per unit (a function of the units alone:
        every attribute it sets is set again by the next chunk)."""
        s, K = self.s, streams.n
        self._start(streams)
        self.spans = _spans(streams)
        self.parts = [{"mom": MatrixMoments.zeros(b - a, self.T, s.N, s.n), **{k: np.zeros(self.shape) for k in
                       CELL_SUMS}} for a, b in self.spans]
        self.counts, self.events = np.zeros((K, s.N)), np.zeros(K, dtype=np.int64)
        self.last, self.spacing = np.full(K, -np.inf), np.full(K, np.inf)
        run = gf.simulate_event_driven(s, self.sc.main_rate, self.sc.output_times, K, streams,
                                       window=event_window(self.sc), on_window=self.on_window)
        kept = rows_by_unit(streams, pair_values=self.pair_values, **self.kept)
        for part, (a, b), rows in zip(self.parts, self.spans, kept):
            part["kept"] = [rows] if rows else []
            part.update(c1=self.counts[a:b].sum(0), c0=(self.counts[a:b] == 0).sum(0),
                        spacing=float(self.spacing[a:b].min()), min_gap=float(run.min_gap[a:b].min()),
                        min_rel_gap=float((run.min_gap[a:b] / np.maximum(1.0, run.scale[a:b])).min()),
                        max_scale=float(run.scale[a:b].max()), max_events=int(self.events[a:b].max(initial=0)),
                        condition=float(run.condition), n=b - a)
        return self.parts

    def on_window(self, w: gf.EventWindow) -> None:
        e = _errors(w.z, self.s.N, self.s.n)
        sel = self.cell_of[w.index] >= 0
        ci, wi = self.cell_of[w.index][sel], np.flatnonzero(sel)
        for part, (a, b) in zip(self.parts, self.spans):
            part["mom"].add(w.index, e[a:b])
            if ci.size:
                self._cells(part, ci, w.pbound[a:b, wi], w.sigma[a:b, wi], e[a:b, wi])
        rows = len(self.pair_values)
        if ci.size and rows > 0:
            self.pair_values[:, ci] = np.square(e[:rows, wi] @ self.U.T)
        valid = w.event_clocks >= 0
        if valid.size:
            self._count(w, valid)
        self._keep(w, valid)

    def _cells(self, part: dict, ci, pbound, sigma, e) -> None:
        qP, qS, qE = quadratic_forms(self.U, pbound), quadratic_forms(self.U, sigma), np.square(e @ self.U.T)
        for key, v in (("qP", qP), ("qS", qS), ("qE", qE)):
            part[f"{key}1"][ci] = v.sum(0)
            part[f"{key}2"][ci] = np.square(v).sum(0)
        part["white"][ci], part["white_n"][ci] = whitened_squares(sigma, e, self.pairs)

    def _count(self, w: gf.EventWindow, valid: np.ndarray) -> None:
        for c, (i, j) in enumerate(self.s.clocks):
            hits = ((w.event_clocks == c) & valid).sum(axis=1)
            self.counts[:, i] += hits
            if self.s.mode == "edge":
                self.counts[:, j] += hits
        self.events[:] += valid.sum(axis=1)
        t_all = np.concatenate([self.last[:, None], np.where(valid, w.event_times, np.inf)], axis=1)
        with np.errstate(invalid="ignore"):
            gaps = np.diff(t_all, axis=1)
        self.spacing[:] = np.minimum(self.spacing, np.min(np.where(np.isfinite(gaps), gaps, np.inf), axis=1))
        has = valid.any(axis=1)
        self.last[has] = np.max(np.where(valid, w.event_times, -np.inf), axis=1)[has]

    def _keep(self, w: gf.EventWindow, valid: np.ndarray) -> None:
        kept = self.kept
        rows = len(kept["t"])
        if rows > 0:
            kept["z"][:, w.index], kept["sigma"][:, w.index] = w.z[:rows], w.sigma[:rows]
            kept["pbound"][:, w.index] = w.pbound[:rows]
            for r in range(rows):
                ok = valid[r] if valid.size else np.zeros(0, bool)
                kept["t"][r].append(w.event_times[r][ok])
                kept["c"][r].append(w.event_clocks[r][ok])

    @staticmethod
    def fold(acc: dict | None, part: dict) -> dict:
        if acc is None:
            return part
        out = {"mom": MatrixMoments.combine([acc["mom"], part["mom"]])}
        for key in (*CELL_SUMS, "c1", "c0", "n"):
            out[key] = acc[key] + part[key]
        for key in ("spacing", "min_gap", "min_rel_gap"):
            out[key] = min(acc[key], part[key])
        for key in ("max_scale", "max_events", "condition"):
            out[key] = max(acc[key], part[key])
        out["kept"] = acc["kept"] + part["kept"]
        return out

    def arrays(self, total: dict) -> dict[str, np.ndarray]:
        """The stage's arrays: the folded sums, then the sample paths (rings inf / −1 padded) and paired values."""
        arrays, units = total.pop("mom").arrays("e_"), total.pop("kept")
        arrays.update({k: np.asarray(v) for k, v in total.items()})
        s, T = self.s, self.T
        times = [ts for u in units for ts in u.get("t", [])]
        clocks = [cs for u in units for cs in u.get("c", [])]
        width = max([1] + [sum(len(x) for x in ts) for ts in times])
        ev_t, ev_c = np.full((len(times), width), np.inf), np.full((len(times), width), -1, dtype=np.int64)
        for r in range(len(times)):
            t = np.concatenate(times[r] or [np.zeros(0)])
            c = np.concatenate(clocks[r] or [np.zeros(0, int)])
            ev_t[r, :len(t)], ev_c[r, :len(c)] = t, c
        matrices = np.zeros((0, T, s.N, s.n, s.n))
        arrays.update(sample_z=stack_rows(units, "z", np.zeros((0, T, (s.N + 1) * s.n))),
                      sample_sigma=stack_rows(units, "sigma", matrices), sample_pbound=stack_rows(units, "pbound", matrices),
                      sample_event_times=ev_t, sample_event_clocks=ev_c,
                      pair_values=stack_rows(units, "pair_values", np.zeros((0, *self.shape))))
        return arrays


@stage(name="event", unkeyed=("budget_bytes",),
       allow_nonfinite=DIVERGING + ("sample_event_times", "spacing", "sample_sigma", "sample_pbound", "qP1", "qP2", "qS1",
                                    "qS2", "qE1", "qE2", "white", "min_gap", "min_rel_gap", "max_scale", "condition"))
def simulate_event_rate(sc: RandomCommFile, seed: int, trials: int,
                        budget_bytes: float = BLOCK_MEMORY_BYTES) -> dict[str, np.ndarray]:
    """The exact event-driven simulator at the main rate, with the statistics of `EventStatistics`."""
    stats = EventStatistics(sc, trials)
    total = run_units(stats.chunk, stats.fold, trials, stream_seed(seed, "event", sc.name, sc.main_rate),
                      bytes_per_trial=event_bytes_per_trial(sc), budget_bytes=budget_bytes, portable=True)
    return stats.arrays(total)


def frozen_path(sc: RandomCommFile, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """The one clock path of the frozen-path Monte Carlo (main rate, whole horizon), drawn from the seed."""
    rng = block_generator(stream_seed(seed, "frozen-path", sc.name))
    t, c = gf.sample_clock_events(len(sc.gossip.clocks), sc.main_rate, sc.horizon, 1, rng)
    return t[0][np.isfinite(t[0])], c[0][c[0] >= 0]


@stage(name="frozen", unkeyed=("budget_bytes",), allow_nonfinite=DIVERGING + ("path_sigma", "path_pbound", "path_min_gap"))
def simulate_frozen(sc: RandomCommFile, seed: int, trials: int,
                    budget_bytes: float = BLOCK_MEMORY_BYTES) -> dict[str, np.ndarray]:
    """One clock path, drawn once, shared by every trial: Monte Carlo over (x0, ω, v) only."""
    s = sc.gossip
    n, N, T = s.n, s.N, sc.n_outputs + 1
    path = frozen_path(sc, seed)

    def chunk(streams):
        spans, first = _spans(streams), streams.first_unit == 0
        parts = [MatrixMoments.zeros(b - a, T, N, n) for a, b in spans]
        keep = {"path_sigma": np.zeros((T, N, n, n)), "path_pbound": np.zeros((T, N, n, n))}

        def on_window(w: gf.EventWindow):
            e = _errors(w.z, N, n)
            for part, (a, b) in zip(parts, spans):
                part.add(w.index, e[a:b])
            if first:
                keep["path_sigma"][w.index], keep["path_pbound"][w.index] = w.sigma[0], w.pbound[0]

        run = gf.simulate_event_driven(s, sc.main_rate, sc.output_times, streams.n, streams, clock_path=path,
                                       window=event_window(sc), on_window=on_window)
        keep["path_min_gap"] = run.min_gap.min(axis=0)
        # the path's covariances are those of the first chunk (trial 0's; the same for every trial)
        return [{"mom": m, "kept": [keep] if first and u == 0 else []} for u, m in enumerate(parts)]

    total = run_units(chunk, _fold_kept, trials, stream_seed(seed, "frozen", sc.name),
                      bytes_per_trial=event_bytes_per_trial(sc), budget_bytes=budget_bytes, portable=True)
    return {**total["mom"].arrays("e_"), **total["kept"][0], "path_times": path[0], "path_clocks": path[1]}
