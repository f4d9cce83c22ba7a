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
from dse.simulate.units import BLOCK_MEMORY_BYTES, block_generator, run_units

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
    samples = np.zeros((min(sc.simulation.sample_trials, trials), T, (N + 1) * n))
    pairs = np.zeros((min(pair, trials), len(cells), N, len(U)))
    start = [0]                                            # first trial of the chunk

    def chunk(streams):
        spans, first = _spans(streams), start[0]
        parts = [MatrixMoments.zeros(b - a, T, N, n) for a, b in spans]

        def record(k, z):
            e = _errors(z, N, n)
            for part, (a, b) in zip(parts, spans):
                part.add([k], e[a:b, None])
            rows = min(len(samples) - first, len(z))
            if rows > 0:
                samples[first:first + rows, k] = z[:rows]
            rows = min(len(pairs) - first, len(z))
            if rows > 0 and k in cell_at:
                pairs[first:first + rows, cell_at[k]] = np.square(e[:rows] @ U.T)

        gf.simulate_gridded(s, rate, sc.grid_step, sc.grid_steps, every, streams.n, streams, on_record=record)
        start[0] += streams.n
        return parts

    mom = run_units(chunk, _moments, trials, stream_seed(seed, "gridded", sc.name, rate),
                    bytes_per_trial=gridded_bytes_per_trial(sc), budget_bytes=budget_bytes)
    return {**mom.arrays("e_"), "sample_z": samples, **({"pair_values": pairs} if pair else {})}


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
        keep, shape = min(sc.simulation.sample_trials, trials), (len(cells), s.N, len(self.U))
        self.kept = {"z": np.zeros((keep, self.T, (s.N + 1) * s.n)), "sigma": np.zeros((keep, self.T, s.N, s.n, s.n)),
                     "pbound": np.zeros((keep, self.T, s.N, s.n, s.n)), "t": [[] for _ in range(keep)],
                     "c": [[] for _ in range(keep)]}
        self.pair_values = np.zeros((min(PAIR_MAX, trials), *shape))
        self.first, self.shape = 0, shape

    def chunk(self, streams) -> list[dict]:
        """`run_units`' chunk: simulate these units, one partial result per unit."""
        s, K = self.s, streams.n
        self.spans = _spans(streams)
        self.parts = [{"mom": MatrixMoments.zeros(b - a, self.T, s.N, s.n), **{k: np.zeros(self.shape) for k in
                       CELL_SUMS}} for a, b in self.spans]
        self.counts, self.events = np.zeros((K, s.N)), np.zeros(K, dtype=np.int64)
        self.last, self.spacing = np.full(K, -np.inf), np.full(K, np.inf)
        run = gf.simulate_event_driven(s, self.sc.main_rate, self.sc.output_times, K, streams,
                                       window=event_window(self.sc), on_window=self.on_window)
        self.first += K
        for part, (a, b) in zip(self.parts, self.spans):
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
        rows = min(len(self.pair_values) - self.first, len(e))
        if ci.size and rows > 0:
            self.pair_values[self.first:self.first + rows, ci] = np.square(e[:rows, wi] @ self.U.T)
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
        kept, first = self.kept, self.first
        rows = min(len(kept["t"]) - first, len(w.z))
        if rows > 0:
            g = slice(first, first + rows)
            kept["z"][g, w.index], kept["sigma"][g, w.index] = w.z[:rows], w.sigma[:rows]
            kept["pbound"][g, w.index] = w.pbound[:rows]
            for r in range(rows):
                ok = valid[r] if valid.size else np.zeros(0, bool)
                kept["t"][first + r].append(w.event_times[r][ok])
                kept["c"][first + r].append(w.event_clocks[r][ok])

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
        return out

    def arrays(self, total: dict) -> dict[str, np.ndarray]:
        """The stage's arrays: the folded sums, then the sample paths (rings inf / −1 padded) and paired values."""
        arrays = total.pop("mom").arrays("e_")
        arrays.update({k: np.asarray(v) for k, v in total.items()})
        keep = len(self.kept["t"])
        width = max([1] + [sum(len(x) for x in ts) for ts in self.kept["t"]])
        ev_t, ev_c = np.full((keep, width), np.inf), np.full((keep, width), -1, dtype=np.int64)
        for r in range(keep):
            t = np.concatenate(self.kept["t"][r] or [np.zeros(0)])
            c = np.concatenate(self.kept["c"][r] or [np.zeros(0, int)])
            ev_t[r, :len(t)], ev_c[r, :len(c)] = t, c
        arrays.update(sample_z=self.kept["z"], sample_sigma=self.kept["sigma"], sample_pbound=self.kept["pbound"],
                      sample_event_times=ev_t, sample_event_clocks=ev_c, pair_values=self.pair_values)
        return arrays


@stage(name="event", unkeyed=("budget_bytes",),
       allow_nonfinite=DIVERGING + ("sample_event_times", "spacing", "sample_sigma", "sample_pbound", "qP1", "qP2", "qS1",
                                    "qS2", "qE1", "qE2", "white", "min_gap", "min_rel_gap", "max_scale", "condition"))
def simulate_event_rate(sc: RandomCommFile, seed: int, trials: int,
                        budget_bytes: float = BLOCK_MEMORY_BYTES) -> dict[str, np.ndarray]:
    """The exact event-driven simulator at the main rate, with the statistics of `EventStatistics`."""
    stats = EventStatistics(sc, trials)
    total = run_units(stats.chunk, stats.fold, trials, stream_seed(seed, "event", sc.name, sc.main_rate),
                      bytes_per_trial=event_bytes_per_trial(sc), budget_bytes=budget_bytes)
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
    keep = {"path_sigma": np.zeros((T, N, n, n)), "path_pbound": np.zeros((T, N, n, n))}
    start = [0]

    def chunk(streams):
        spans, first = _spans(streams), start[0]
        parts = [MatrixMoments.zeros(b - a, T, N, n) for a, b in spans]

        def on_window(w: gf.EventWindow):
            e = _errors(w.z, N, n)
            for part, (a, b) in zip(parts, spans):
                part.add(w.index, e[a:b])
            if first == 0:
                keep["path_sigma"][w.index], keep["path_pbound"][w.index] = w.sigma[0], w.pbound[0]

        run = gf.simulate_event_driven(s, sc.main_rate, sc.output_times, streams.n, streams, clock_path=path,
                                       window=event_window(sc), on_window=on_window)
        if first == 0:
            keep["path_min_gap"] = run.min_gap.min(axis=0)
        start[0] += streams.n
        return parts

    mom = run_units(chunk, _moments, trials, stream_seed(seed, "frozen", sc.name),
                    bytes_per_trial=event_bytes_per_trial(sc), budget_bytes=budget_bytes)
    return {**mom.arrays("e_"), **keep, "path_times": path[0], "path_clocks": path[1]}
