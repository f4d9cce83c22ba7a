"""Batched GIKF runs with on-line statistics: the filter kernel, and the accumulators beside it.

`gikf_units` simulates independent GIKF runs (eq (12) for the covariances, the error recursion of
`gikf_maps` for the estimates, and the centralized filter's error on the same noises) for units
of runs, each unit drawing from its own generator, and hands the state of every slot to its
accumulators. The kernel computes nothing a check needs: every statistic (features at the record
times, quantiles over runs, tail counts, Loewner margins with their round-off bounds, NEES, the
token chain, the sample runs, the moments of P̂(T)) is an accumulator the caller chooses. Every
accumulator keeps its statistics per unit, so that they depend only on that unit's draws; combine
the units with `fold_gikf` (in unit order) and `finish_gikf`.

An accumulator may implement any of these hooks (all optional, see `Accumulator`):

    start(run)        after the first draws (the random sensor q, the initial errors)
    matched(run, t)   after the matching A(t) is drawn, every slot (even after an overflow)
    stepped(run, t)   after P̂(t+1) = f(P̂_{->(n,t)}(t)) (`run.X_in`, `run.K`, `run.w` of the step)
    record(run, t)    the state at slot t (t = 0, then after every step that stayed finite)
    unit(run, u)      the statistics of unit u, a dict of arrays (at the end)
"""
from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from .gikf_maps import (EPS, FEATURES, GossipSystem, covariance_features, eigvalsh, error_norm, factor_psd,
                            gikf_error_step, propagate_error, riccati_roundoff, riccati_step, swap)
from .gossip_protocols import matching_at

QUANTILES = (0.05, 0.25, 0.5, 0.75, 0.95, 0.99)
#: at most this many slots carry the per-slot series of the sample runs, and at most STAT_SLOTS the
#: statistics over runs (quantiles, tail counts, Loewner margins): memory does not grow with the horizon
SERIES_SLOTS = 1000
STAT_SLOTS = 250
#: the matching of the sample runs is kept at every slot up to this one (the matching animation)
PARTNER_SLOTS = 1000


def decimated_slots(T: int, record_times: Sequence[int], stride: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """(series slots, statistic slots) of a run of T slots: every slot (series) and every `stride`-th slot
    (statistics) while they fit in SERIES_SLOTS and STAT_SLOTS, else evenly thinned; both always hold
    0, T − 1, T and the record times (statistics: from slot 1 on)."""
    times = {int(t) for t in record_times if 0 <= t <= T}
    k1 = max(1, -(-T // SERIES_SLOTS))
    series = set(range(0, T + 1, k1)) | times | {0, max(T - 1, 0), T}
    k2 = max(stride, -(-T // STAT_SLOTS))
    k2 = -(-k2 // k1) * k1                      # statistics on series slots
    stats = set(range(0, T + 1, k2)) | times | {T}
    return np.array(sorted(series)), np.array(sorted(stats))


def _units_draw(units, draw) -> np.ndarray:
    parts = [draw(g, m) for g, m in units]
    return parts[0] if len(parts) == 1 else np.concatenate(parts, axis=0)


class GikfRuns:
    """The state of a batch of B runs (units stacked on the leading axis) that accumulators read:
    `P` (B, N, M, M) the covariances P̂_n(t), `e` (B, N, M) the errors, `e_c` (B, M) the centralized
    filter's error, `q` (B,) each run's uniformly random sensor; during a step `partners` (B, N),
    `X_in` (the swapped covariances), `K` (the gains) and `w` (B, M) (the common process noise)."""

    def __init__(self, sys: GossipSystem, sizes: Sequence[int], T: int):
        self.sys, self.sizes, self.T = sys, list(sizes), T
        self.B, self.N, self.M = sum(self.sizes), sys.N, sys.M
        edges = np.cumsum([0, *self.sizes])
        self.slices = [slice(a, b) for a, b in zip(edges[:-1], edges[1:])]
        self.unit_of = np.repeat(np.arange(len(self.sizes)), self.sizes)
        self.rows = np.arange(self.B)
        self._lam_max: np.ndarray | None = None

    def per_unit(self, values: np.ndarray) -> np.ndarray:
        """Sums over the runs of each unit (in run order)."""
        return np.array([values[s_].sum(axis=0) for s_ in self.slices])

    def lam_max(self) -> np.ndarray:
        """λ_max(P̂_n(t)) of every run and sensor at the slot being recorded (computed once per slot)."""
        if self._lam_max is None:
            self._lam_max = eigvalsh(self.P)[..., -1]
        return self._lam_max


class Accumulator:
    """The hooks an accumulator may implement (see the module docstring); each does nothing here."""

    def start(self, run: GikfRuns) -> None:
        pass

    def matched(self, run: GikfRuns, t: int) -> None:
        pass

    def stepped(self, run: GikfRuns, t: int) -> None:
        pass

    def record(self, run: GikfRuns, t: int) -> None:
        pass

    def unit(self, run: GikfRuns, u: int) -> dict[str, np.ndarray]:
        return {}


def gikf_units(sys: GossipSystem, protocol, units: Sequence[tuple[np.random.Generator, int]], n_slots: int, *,
               K_central: np.ndarray, accumulators: Sequence[Accumulator]) -> list[dict[str, np.ndarray]]:
    """GIKF runs for units of runs (`units`: (generator, runs) pairs, simulated together): one dict per unit,
    the accumulators' statistics of that unit, its number of runs and `overflow`. K_central (T, M, N m): the
    centralized filter's update gains (its error runs on the same noises, the reference of the NEES).

    Per slot t the draws are, in this order: the matching A(t) (`matching_at`), the common w(t) ~ N(0, Q)
    and every sensor's v_n(t) ~ N(0, R_n); before the first slot, each run's random sensor q and its
    initial error e(0) ~ N(0, P0), shared by every sensor. When a covariance leaves float64 the covariance
    work stops for these units (the draws go on, so every unit's token counts stay its own); `overflow`
    is that slot (−1: none), and `finish_gikf` blanks what follows it."""
    N, M, m = sys.N, sys.M, sys.C.shape[1]
    run = GikfRuns(sys, [size for _, size in units], n_slots)
    B, T = run.B, n_slots
    run.q = _units_draw(units, lambda g, k: g.integers(0, N, k))
    run.P = np.broadcast_to(sys.P0, (B, N, M, M)).copy()
    run.e = np.broadcast_to(_units_draw(units, lambda g, k: g.standard_normal((k, 1, M))) @ factor_psd(sys.P0).T,
                            (B, N, M)).copy()
    run.e_c = run.e[:, 0].copy()
    Lr, Lq = sys.R_chol, np.linalg.cholesky(sys.Q)
    for a in accumulators:
        a.start(run)
    overflow = -1

    def record(t: int) -> None:
        run._lam_max = None
        for a in accumulators:
            a.record(run, t)

    with np.errstate(over="ignore", invalid="ignore"):
        record(0)
        for t in range(T):
            run.partners = _units_draw(units, lambda g, k: matching_at(protocol, t, k, g))
            for a in accumulators:
                a.matched(run, t)
            run.w = _units_draw(units, lambda g, k: g.standard_normal((k, M))) @ Lq.T
            v = np.einsum("nij,bnj->bni", Lr, _units_draw(units, lambda g, k: g.standard_normal((k, N, m))))
            if overflow >= 0:
                continue            # the draws go on (token counts), the covariances have left float64
            run.X_in = swap(run.P, run.partners)
            run.P, run.K = riccati_step(run.X_in, sys.C, sys.R, sys.F, sys.Q, return_gain=True)     # eq (12)
            for a in accumulators:
                a.stepped(run, t)
            run.e = gikf_error_step(run.e, run.partners, run.K, sys, run.w, v)
            run.e_c = (run.e_c - (np.einsum("bi,mi->bm", np.einsum("ij,bj->bi", sys.C_all, run.e_c)
                                            + v.reshape(B, -1), K_central[t]))) @ sys.F.T + run.w
            if not np.isfinite(run.P).all():
                overflow = t + 1
                continue
            record(t + 1)
    run.overflow = overflow
    out = []
    for u, s_ in enumerate(run.slices):
        part = {"overflow": np.array(overflow), "runs": np.array(s_.stop - s_.start)}
        for a in accumulators:
            part.update(a.unit(run, u))
        out.append(part)
    return out


# -- the accumulators ------------------------------------------------------------------------------------

class RecordTimes(Accumulator):
    """`covariance_features` of every sensor (`feat_n`, (times, features, B, N)) and of the run's random
    sensor q (`feat_q`) at the record times; `q` itself."""

    def __init__(self, record_times: Sequence[int], T: int):
        self.times = sorted(set(int(t) for t in record_times if 0 <= t <= T))

    def start(self, run):
        nf = len(FEATURES) + run.M
        self.feat_q = np.full((len(self.times), nf, run.B), np.nan)
        self.feat_n = np.full((len(self.times), nf, run.B, run.N), np.nan)

    def record(self, run, t):
        if t in self.times:
            i = self.times.index(t)
            self.feat_n[i] = covariance_features(run.P)
            self.feat_q[i] = self.feat_n[i][:, run.rows, run.q]

    def unit(self, run, u):
        s_ = run.slices[u]
        return {"times": np.array(self.times), "q": run.q[s_], "feat_q": self.feat_q[..., s_],
                "feat_n": self.feat_n[:, :, s_]}


class OverRuns(Accumulator):
    """At the statistic slots: log tr P̂_n(t) of every run (`log_trace`, for the quantiles over runs that
    `finish_gikf` takes) and the counts of ‖P̂_n(t)‖ ≥ J over `j_grid` (`exceed`)."""

    def __init__(self, stat_slots: np.ndarray, j_grid: np.ndarray):
        self.stat, self.j_grid = stat_slots, j_grid
        self.index = {int(t): i for i, t in enumerate(stat_slots)}

    def start(self, run):
        self.log_trace = np.full((len(self.stat), run.B, run.N), np.nan)
        self.exceed = np.zeros((len(run.sizes), len(self.stat), run.N, len(self.j_grid)), dtype=np.int64)

    def record(self, run, t):
        if t in self.index:
            i = self.index[t]
            self.log_trace[i] = np.log(np.maximum(np.trace(run.P, axis1=-2, axis2=-1), np.finfo(float).tiny))
            self.exceed[:, i] = run.per_unit(run.lam_max()[..., None] >= self.j_grid)

    def unit(self, run, u):
        return {"stat_slots": self.stat, "log_trace": self.log_trace[:, run.slices[u]], "exceed": self.exceed[u]}


class LoewnerMargins(Accumulator):
    """Relative Loewner margins on the runs of the first unit at the statistic slots, (S, 3, N): `margins`,
    min over those runs of λ_min(difference) / max(1, ‖P̂‖) per sensor, against a lower bound `P_floor` (a
    matrix per class, (T+1, C, M, M), sensor n in class floor_index[n]), against Q (t ≥ 1) and below the
    envelope f_0^t(P0) = exp(envelope_log[t]) · envelope[t]; `slack`, the same with the round-off allowance
    of both sides added before the minimum: the first-order bound of `riccati_roundoff` carried along every
    run (`propagate_error`), `floor_err` / `envelope_err` of the references, eps·‖Q‖. A margin is a
    counterexample only where its slack is < 0."""

    def __init__(self, stat_slots: np.ndarray, P_floor: np.ndarray, floor_index: np.ndarray, floor_err: np.ndarray,
                 envelope: np.ndarray, envelope_log: np.ndarray, envelope_err: np.ndarray):
        self.index = {int(t): i for i, t in enumerate(stat_slots)}
        self.S = len(stat_slots)
        self.P_floor, self.floor_index, self.floor_err = P_floor, floor_index, np.asarray(floor_err, float)
        self.envelope, self.envelope_log = envelope, np.asarray(envelope_log, float)
        self.envelope_err = np.asarray(envelope_err, float)

    def start(self, run):
        self.cr = run.sizes[0]
        self.err = np.zeros((self.cr, run.N, run.M, run.M))   # round-off bound of P̂_n(t) of the checked runs
        self.margins = np.full((self.S, 3, run.N), np.nan)
        self.slack = np.full((self.S, 3, run.N), np.nan)
        self.q_norm = EPS * float(np.linalg.norm(run.sys.Q, 2))

    def stepped(self, run, t):
        sys, cr = run.sys, self.cr
        delta, G = riccati_roundoff(run.X_in[:cr], run.K[:cr], sys.C, sys.R, sys.F, sys.Q)
        self.err = propagate_error(self.err[run.rows[:cr, None], run.partners[:cr]], G, delta)

    def record(self, run, t):
        if t not in self.index:
            return
        i, cr, P = self.index[t], self.cr, run.P
        scale = np.maximum(1.0, run.lam_max()[:cr])
        # the envelope is exp(envelope_log[t]) · envelope[t]: divide both sides by max(1, ‖envelope‖)
        env_log = self.envelope_log[t] + math.log(max(float(np.linalg.norm(self.envelope[t], 2)), np.finfo(float).tiny))
        shift = max(0.0, env_log)
        env_unit = math.exp(self.envelope_log[t] - shift) * self.envelope[t]
        e_P = error_norm(self.err)
        floor, f_err = self.P_floor[t][self.floor_index], self.floor_err[t][self.floor_index]
        lam_min = eigvalsh(np.stack([P[:cr] - floor, P[:cr] - run.sys.Q, env_unit - math.exp(-shift) * P[:cr]]))[..., 0]
        env_tol = math.exp(-shift) * e_P + math.exp(self.envelope_log[t] - shift) * self.envelope_err[t]
        for col, (tol, sc_) in enumerate(((e_P + f_err, scale), (e_P + self.q_norm, scale), (env_tol, 1.0))):
            if col == 1 and t == 0:
                continue
            self.margins[i, col] = (lam_min[col] / sc_).min(axis=0)
            self.slack[i, col] = ((lam_min[col] + tol) / sc_).min(axis=0)

    def unit(self, run, u):
        return {"margins": self.margins, "slack": self.slack} if u == 0 else {}


class Nees(Accumulator):
    """Normalised estimation errors squared. Per run, at `slots` (each exactly χ²_M given the gossip path, and
    independent across runs): of the random sensor q (`nees_q`) and of the centralized filter (`nees_c`, from
    its prior covariances P_central). Over the window [max(1, a), b): per unit, the sums and counts above the
    χ²_M `level` quantile of every sensor and of the centralized filter (`nees`), and the same per run
    (`nees_run`)."""

    def __init__(self, slots: Sequence[int], window: tuple[int, int], P_central: np.ndarray, T: int,
                 level: float = 0.99):
        from scipy.stats import chi2

        self.slots = [int(t) for t in slots if 1 <= t <= T]
        self.window, self.P_central = window, P_central
        self.threshold = chi2.ppf(level, P_central.shape[-1])

    def start(self, run):
        self.nees_q = np.full((len(self.slots), run.B), np.nan)
        self.nees_c = np.full((len(self.slots), run.B), np.nan)
        self.sums = np.zeros((len(run.sizes), 6))  # NEES sum, count above, n (sensors); the same (central)
        self.per_run = np.zeros((4, run.B))        # NEES sum and exceedances (sensors), the same (central)

    def record(self, run, t):
        e, e_c, P, rows = run.e, run.e_c, run.P, run.rows
        if t in self.slots:
            k = self.slots.index(t)
            eq = e[rows, run.q]
            self.nees_q[k] = np.einsum("bm,bm->b", eq, np.linalg.solve(P[rows, run.q], eq[..., None])[..., 0])
            self.nees_c[k] = np.einsum("bm,bm->b", e_c, np.linalg.solve(self.P_central[t], e_c.T).T)
        if max(1, self.window[0]) <= t < self.window[1]:
            z = np.einsum("bnm,bnm->bn", e, np.linalg.solve(P, e[..., None])[..., 0])
            zc = np.einsum("bm,bm->b", e_c, np.linalg.solve(self.P_central[t], e_c.T).T)
            thr, sums = self.threshold, self.sums
            sums[:, 0] += run.per_unit(z.sum(axis=1))
            sums[:, 1] += run.per_unit((z > thr).sum(axis=1))
            sums[:, 2] += np.array(run.sizes) * run.N
            sums[:, 3] += run.per_unit(zc)
            sums[:, 4] += run.per_unit(zc > thr)
            sums[:, 5] += run.sizes
            self.per_run[0] += z.sum(axis=1)
            self.per_run[1] += (z > thr).sum(axis=1)
            self.per_run[2] += zc
            self.per_run[3] += zc > thr

    def unit(self, run, u):
        s_ = run.slices[u]
        return {"nees_slots": np.array(self.slots, dtype=np.int64), "nees_threshold": np.array(self.threshold),
                "nees_q": self.nees_q[:, s_], "nees_c": self.nees_c[:, s_], "nees": self.sums[u],
                "nees_run": self.per_run[:, s_]}


class TokenChain(Accumulator):
    """Where the tokens go (Proposition 6): p_n(t) = ->(p_n(t−1), t). Per unit, the transition counts out of
    every node from slot 1 on (`trans`, (N, N)), the location of token 0 at slots 0..steps (`token0`) and
    after the last slot (`token0_final`)."""

    def __init__(self, steps: int = 20):
        self.steps = steps

    def start(self, run):
        n_units, N = len(run.sizes), run.N
        self.loc = np.tile(np.arange(N), (run.B, 1))
        self.trans = np.zeros((n_units, N, N), dtype=np.int64)
        self.tok0 = np.zeros((n_units, self.steps + 1, N), dtype=np.int64)
        for u, s_ in enumerate(run.slices):
            self.tok0[u, 0, 0] = s_.stop - s_.start

    def matched(self, run, t):
        N, n_units = run.N, len(run.sizes)
        new_loc = run.partners[run.rows[:, None], self.loc]
        if t > 0:
            flat = (run.unit_of[:, None] * N + self.loc) * N + new_loc
            self.trans += np.bincount(flat.ravel(), minlength=n_units * N * N).reshape(n_units, N, N)
        self.loc = new_loc
        if 1 <= t <= self.steps:
            self.tok0[:, t] = np.bincount(run.unit_of * N + self.loc[:, 0], minlength=n_units * N).reshape(n_units, N)

    def unit(self, run, u):
        return {"trans": self.trans[u], "token0": self.tok0[u],
                "token0_final": np.bincount(self.loc[run.slices[u], 0], minlength=run.N)}


class SamplePaths(Accumulator):
    """The first n_paths runs of the first unit, whole at the series slots: tr P̂_n(t) (`path_trace`), the
    errors of every sensor and of the centralized filter (`path_err`, `path_err_c`), the state x(t) from the
    prior mean x0 (`path_state`), and the matching of every slot up to PARTNER_SLOTS (`path_partners`)."""

    def __init__(self, series_slots: np.ndarray, n_paths: int, x0: np.ndarray | None = None):
        self.series, self.n_paths, self.x0 = series_slots, n_paths, x0
        self.index = {int(t): i for i, t in enumerate(series_slots)}

    def start(self, run):
        sp, S, N, M = min(self.n_paths, run.sizes[0]), len(self.series), run.N, run.M
        self.sp, self.n_part = sp, min(run.T, PARTNER_SLOTS) + 1
        self.trace = np.full((sp, S, N), np.nan)
        self.err = np.full((sp, S, N, M), np.nan)
        self.err_c = np.full((sp, S, M), np.nan)
        self.state = np.full((sp, S, M), np.nan)
        self.partners = np.tile(np.arange(N), (sp, self.n_part, 1))
        self.x = (np.zeros(M) if self.x0 is None else np.asarray(self.x0, float)) + run.e[:sp, 0]

    def matched(self, run, t):
        if t < self.n_part - 1:
            self.partners[:, t] = run.partners[:self.sp]

    def stepped(self, run, t):
        self.x = self.x @ run.sys.F.T + run.w[:self.sp]

    def record(self, run, t):
        if t in self.index:
            i, sp = self.index[t], self.sp
            self.trace[:, i] = np.trace(run.P[:sp], axis1=-2, axis2=-1)
            self.err[:, i] = run.e[:sp]
            self.err_c[:, i] = run.e_c[:sp]
            self.state[:, i] = self.x

    def unit(self, run, u):
        out = {"series_slots": self.series}
        if u == 0:
            out.update(path_trace=self.trace, path_err=self.err, path_err_c=self.err_c, path_state=self.state,
                       path_partners=self.partners)
        return out


class FinalMoments(Accumulator):
    """Per unit, Σ P̂_n(T) and Σ P̂_n(T)² entrywise over the runs (NaN after an overflow)."""

    def unit(self, run, u):
        final = run.P if run.overflow < 0 else np.full_like(run.P, np.nan)
        s_ = run.slices[u]
        return {"final_sum": final[s_].sum(axis=0), "final_sq": np.square(final[s_]).sum(axis=0)}


# -- combining units ----------------------------------------------------------------------------------------

#: how per-unit results combine: per-run arrays are concatenated along the given axis, counts and
#: float sums added (in unit order, so sums do not depend on how units are chunked), minima taken
RUN_AXIS = {"q": 0, "feat_q": 2, "feat_n": 2, "log_trace": 1, "nees_q": 1, "nees_c": 1, "nees_run": 1}
SUMS = ("exceed", "nees", "trans", "token0", "token0_final", "final_sum", "final_sq", "runs")
MINS = ("margins", "slack")


def fold_gikf(acc: dict | None, part: dict) -> dict:
    """Accumulate one unit's statistics (in unit order): see RUN_AXIS, SUMS, MINS."""
    if acc is None:
        acc = {k: ([v] if k in RUN_AXIS else v) for k, v in part.items()}
        acc["overflow"] = part["overflow"]
        return acc
    for k, v in part.items():
        if k in RUN_AXIS:
            acc[k].append(v)
        elif k in SUMS:
            acc[k] = acc[k] + v
        elif k in MINS:
            acc[k] = np.fmin(acc[k], v) if k in acc else v
        elif k == "overflow":
            a, b = int(acc[k]), int(v)
            acc[k] = np.array(min(a, b) if a >= 0 and b >= 0 else max(a, b))
        elif k not in acc:
            acc[k] = v
    return acc


def finish_gikf(acc: dict) -> dict[str, np.ndarray]:
    """The folded statistics as arrays: per-run arrays joined, quantiles over runs of log tr P̂_n(t) at the
    statistic slots (`quantiles`, (S, N, len(QUANTILES)); the per-run log traces are dropped), and, after an
    overflow at slot t₀, every statistic of a slot ≥ t₀ blanked (NaN; counts −1), so that nothing depends on
    which units were simulated together."""
    out = {k: (np.concatenate(v, axis=RUN_AXIS[k]) if k in RUN_AXIS else np.asarray(v)) for k, v in acc.items()}
    lt = out.pop("log_trace")
    with np.errstate(invalid="ignore"):
        out["quantiles"] = np.moveaxis(np.quantile(lt, QUANTILES, axis=1), 0, -1)
    t0 = int(out["overflow"])
    if t0 >= 0:
        late = out["stat_slots"] >= t0
        out["quantiles"][late] = np.nan
        out["exceed"][late] = -1
        for k in MINS:
            if k in out:
                out[k][late] = np.nan
        for k in ("feat_q", "feat_n"):
            out[k][out["times"] >= t0] = np.nan
        for k in ("nees_q", "nees_c"):
            out[k][out["nees_slots"] >= t0] = np.nan
        for k in ("path_trace", "path_err", "path_err_c", "path_state"):
            if k in out:
                out[k][:, out["series_slots"] >= t0] = np.nan
        out["nees"][:] = np.nan
        out["nees_run"][:] = np.nan
    return out


def standard_accumulators(sys: GossipSystem, T: int, *, record_times: Sequence[int], P_central: np.ndarray,
                          envelope: np.ndarray, j_grid: np.ndarray, envelope_log: np.ndarray | None = None,
                          n_paths: int = 3, check: bool = True, paths: bool = True,
                          nees_window: tuple[int, int] = (20, 60), nees_slots: Sequence[int] = (),
                          stat_stride: int = 1, P_floor: np.ndarray | None = None,
                          floor_index: np.ndarray | None = None, floor_err: np.ndarray | None = None,
                          envelope_err: np.ndarray | None = None, x0: np.ndarray | None = None) -> list[Accumulator]:
    """Every accumulator above: features at the record times, statistics over runs at the statistic slots
    (`decimated_slots` with `stat_stride`), NEES, the token chain, the moments of P̂(T); with `check`, the
    Loewner margins (floor: P_floor, default the centralized P_central for every sensor); with `paths`, the
    sample runs."""
    times = sorted(set(int(t) for t in record_times if 0 <= t <= T))
    series, stat = decimated_slots(T, times, stat_stride)
    out: list[Accumulator] = [RecordTimes(times, T), OverRuns(stat, j_grid)]
    if check:
        if P_floor is None:
            P_floor, floor_index = P_central[:, None], np.zeros(sys.N, dtype=np.int64)
        out.append(LoewnerMargins(stat, P_floor, floor_index,
                                  np.zeros(P_floor.shape[:2]) if floor_err is None else floor_err, envelope,
                                  np.zeros(T + 1) if envelope_log is None else envelope_log,
                                  np.zeros(T + 1) if envelope_err is None else envelope_err))
    out += [Nees(nees_slots, nees_window, P_central, T), TokenChain(), FinalMoments()]
    if paths:
        out.append(SamplePaths(series, n_paths, x0))
    return out


def simulate_gikf(sys: GossipSystem, protocol, n_runs: int, n_slots: int, rng: np.random.Generator, *,
                  K_central: np.ndarray, **kw) -> dict[str, np.ndarray]:
    """All runs as one unit drawn from `rng`, with `standard_accumulators(sys, n_slots, **kw)` (every run's
    Loewner margins checked)."""
    acc = standard_accumulators(sys, n_slots, **kw)
    return finish_gikf(fold_gikf(None, gikf_units(sys, protocol, [(rng, n_runs)], n_slots, K_central=K_central,
                                                  accumulators=acc)[0]))
