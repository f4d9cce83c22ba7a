"""The bounds of one hybrid-observer run, evaluated while it is simulated.

The simulator hands every sample, event index and interval of a chunk of trials to a
`ChunkMonitor`, which evaluates the bounds on the spot (the recursion (41), (51) and its
restarts, the continuous bound, (20), (54), (63), the decay-rate fits) and keeps per trial only
the worst case of each, plus statistics over trials per event index and per stored sample.
A chunk's monitor keeps what depends on the order of the units apart for each unit (`UnitPart`: its sums,
its moments, its worst cases and per-trial values) and the rest (maxima, counts, trial 0) in a
`RunAccumulator` of its own; the run's `RunAccumulator` absorbs the parts unit by unit in unit order, as if
one process had merged every unit in turn, so the result is the same bits whatever the memory chunk and
wherever the chunk ran (a chunk is a function of its units: it may run on a Dask worker). Trial 0 is kept
whole, at every event and at `sampling.stored` samples.
"""
from __future__ import annotations

import hashlib
import math

import numpy as np

import dse.estimators.hybrid_observer as ho

from .scenario import HybridFile, RunSection

#: the decay-rate fit starts at this event index (the first ones carry the initial transient)
FIT_SKIP = 2
rowmax, rownorm = ho.row_max, ho.row_norms


class Worst:
    """The worst case of an inequality lo <= up over many cases: the smallest slack up - lo with
    its (lo, up), the smallest relative slack, the number of cases and of non-finite ones. Kept
    per trial during a chunk, then merged unit by unit (ties keep the earlier trial and case)."""

    FIELDS = ("slack", "lo", "up", "rel", "count", "bad")

    def __init__(self, B: int = 1):
        self.slack, self.rel = np.full(B, np.inf), np.full(B, np.inf)
        self.lo, self.up = np.full(B, np.nan), np.full(B, np.nan)
        self.count, self.bad = np.zeros(B, dtype=np.int64), np.zeros(B, dtype=np.int64)

    def update(self, lo, up) -> None:
        lo, up = np.broadcast_arrays(np.asarray(lo, float), np.asarray(up, float))
        lo, up = lo.reshape(len(self.slack), -1), up.reshape(len(self.slack), -1)
        finite = np.isfinite(lo) & np.isfinite(up)
        self.bad += (~finite).sum(axis=1)
        self.count += lo.shape[1]
        slack = np.where(finite, up - lo, np.inf)
        j = np.argmin(slack, axis=1)
        ar = np.arange(len(j))
        s = slack[ar, j]
        better = s < self.slack
        self.slack = np.where(better, s, self.slack)
        self.lo, self.up = np.where(better, lo[ar, j], self.lo), np.where(better, up[ar, j], self.up)
        rel = np.where(finite, slack / np.maximum(np.abs(up), 1e-300), np.inf).min(axis=1)
        self.rel = np.minimum(self.rel, rel)

    def part(self, a: int, b: int) -> "Worst":
        """The worst case over trials a..b-1."""
        out = Worst(1)
        j = a + int(np.argmin(self.slack[a:b]))
        out.slack[0], out.lo[0], out.up[0] = self.slack[j], self.lo[j], self.up[j]
        out.rel[0] = self.rel[a:b].min()
        out.count[0], out.bad[0] = self.count[a:b].sum(), self.bad[a:b].sum()
        return out

    def merge(self, other: "Worst") -> None:
        if other.slack[0] < self.slack[0]:
            self.slack[0], self.lo[0], self.up[0] = other.slack[0], other.lo[0], other.up[0]
        self.rel[0] = min(self.rel[0], other.rel[0])
        self.count[0] += other.count[0]
        self.bad[0] += other.bad[0]

    def arrays(self, prefix: str) -> dict[str, np.ndarray]:
        return {f"{prefix}_{k}": np.array(getattr(self, k)[0]) for k in self.FIELDS}


#: the worst cases a run keeps: name -> what it is
WORST = {
    "eq51": "|e(s)| <= e^(-λsT)(|e(0)| + d|ē(0)|) + round-off (Theorem 1, (51))",
    "sym": "||e(s)||_2 <= e^(-λsT)(||e(0)||_2 + d'||ē(0)||_2) + round-off (symmetric case)",
    "c3": "max_i||π(q)|| and |e(s)| against the idealised attenuation (20) + round-off",
    "eq63": "|e(s)| <= (63) + round-off (event-time offsets)",
}
#: largest values over trials (and cases) a run keeps: name -> what it is
MAXIMA = {
    "ratio51": "max |e(s)| / (e^(-λsT)(|e(0)| + d|ē(0)|))",
    "ratio_sym": "max ||e(s)||_2 / (e^(-λsT)(||e(0)||_2 + d'||ē(0)||_2))",
    "ratio63": "max |e(s)| / (the right-hand side of (63))",
    "restart": "max over 1 <= s0 < s of |e(s)| / (the bound (51) restarted at s0, with round-off)",
    "cont_printed": "max over t of ||e_i(t)|| / (e^(||A||T - λt)(|e(0)| + d|ē(0)|) + round-off)",
    "cont_corrected": "max over t of ||e_i(t)|| / (e^((||A||+λ)T - λt)(|e(0)| + d|ē(0)|) + round-off)",
    "res_minus": "max |e(s) - A(s)e(s-1) - B(s)ē(s-1) + G(s)x((s-1)T)| / size of the states ((41), (61'))",
    "res_plus": "the same with +G(s)x((s-1)T) (the sign printed in (61))",
    "c3_piq1": "max over trials of max_i||π_i1(q)||",
    "c3_pi01": "max over trials of max_i||π_i1(0)||",
    "eb_max": "max over events and trials of |ē(s)|",
}
COUNTS = ("restart", "res", "cont")


class RunAccumulator:
    """What a run keeps (see the module docstring); filled unit by unit in unit order."""

    def __init__(self, sc: HybridFile, run: RunSection, layout_samples: int, grid0_ns: int, dt_ns: int, nw: int):
        m, n, S = sc.m, sc.n, run.intervals
        self.m, self.n, self.S = m, n, S
        self.stride = max(1, -(-layout_samples // sc.sampling.stored))
        stored = list(range(0, layout_samples, self.stride))
        if stored[-1] != layout_samples - 1:
            stored.append(layout_samples - 1)
        self.stored = {k: j for j, k in enumerate(stored)}
        G = len(stored)
        self.samples_total = layout_samples
        self.t_ns = grid0_ns + dt_ns * np.array(stored, dtype=np.int64)
        nan = np.nan
        self.trial0 = {"e_pre": np.full((S + 1, m, n), nan), "e_post": np.full((S + 1, m, n), nan),
                       "x_event": np.full((S + 1, m, n), nan), "ebar": np.full((S + 1, nw), nan),
                       "x_nominal": np.full((S + 1, n), nan), "central": np.full((S + 1, m), nan),
                       "floor": np.full(S + 1, nan), "carried": np.full(S + 1, nan), "carried_sym": np.full(S + 1, nan),
                       "bound41": np.full((S + 1, m), nan), "bound51": np.full(S + 1, nan),
                       "x": np.full((G, n), nan), "xhat": np.full((G, m, n), nan), "xc": np.full((G, n), nan),
                       "err": np.full((G, m), nan), "cerr": np.full(G, nan), "xnorm": np.full(G, nan),
                       "kf": np.full(G, nan)}
        self.z0 = None
        #: whether trial 0 (the scenario's initial conditions) is among this accumulator's trials
        self.has_trial0 = False
        #: the hash of trial 0's consensus iterates, every interval in turn (written by the chunk that holds trial 0)
        self.iterate_hash = hashlib.blake2b(digest_size=16).hexdigest()
        # per event index: count, mean, M2 of ||e_i(t_is)|| and of the centralized error; maxima
        self.ev_count = np.zeros(S + 1, dtype=np.int64)
        self.ev_mean, self.ev_m2 = np.zeros((S + 1, m)), np.zeros((S + 1, m))
        self.ev_max = np.full((S + 1, m), -np.inf)
        self.ce_mean, self.ce_m2 = np.zeros((S + 1, m)), np.zeros((S + 1, m))
        self.net_mean, self.net_m2 = np.zeros(S + 1), np.zeros(S + 1)
        self.net_max = np.full(S + 1, -np.inf)
        self.bound51_max, self.ratio51_s = np.full(S + 1, nan), np.full(S + 1, nan)
        # per stored sample: sums and maxima over trials
        self.g_count = 0
        self.g_sum, self.g_max = np.zeros((G, m)), np.full((G, m), -np.inf)
        self.g_csum = np.zeros(G)
        self.worst = {k: Worst(1) for k in WORST}
        self.maxima = {k: -np.inf for k in MAXIMA}
        self.counts = {k: 0 for k in COUNTS}
        self.per_trial: dict[str, list] = {k: [] for k in ("fit_rate", "fit_first", "fit_stop", "fingerprint",
                                                           "e0", "eb0")}

    def merge_moments(self, s: int, n_u: int, mean_u: np.ndarray, m2_u: np.ndarray, cmean_u, cm2_u, nmean_u,
                      nm2_u) -> None:
        """Chan's update of count, mean and M2 with one unit's (in unit order)."""
        n0 = self.ev_count[s]
        tot = n0 + n_u
        for mean, m2, mu, m2u in ((self.ev_mean, self.ev_m2, mean_u, m2_u), (self.ce_mean, self.ce_m2, cmean_u, cm2_u),
                                  (self.net_mean, self.net_m2, nmean_u, nm2_u)):
            delta = mu - mean[s]
            mean[s] = mean[s] + delta * n_u / tot
            m2[s] = m2[s] + m2u + delta ** 2 * n0 * n_u / tot
        self.ev_count[s] = tot

    def absorb(self, part: "UnitPart") -> "RunAccumulator":
        """Merge the next unit (in unit order), and with the first unit of a chunk, what the chunk kept as a whole:
        the same operations, in the same order for each statistic, as merging every unit in one process."""
        self.g_sum += part.g_sum            # a unit adds its sum at every stored sample (0.0 elsewhere: exact)
        self.g_csum += part.g_csum
        for moments in part.moments:
            self.merge_moments(*moments)
        for k, w in part.worst.items():
            self.worst[k].merge(w)
        for k, v in part.per_trial.items():
            self.per_trial[k].append(v)
        chunk = part.chunk
        if chunk is not None:
            if chunk.has_trial0:
                self.trial0, self.z0, self.iterate_hash = chunk.trial0, chunk.z0, chunk.iterate_hash
            self.g_max = np.maximum(self.g_max, chunk.g_max)
            self.ev_max = np.maximum(self.ev_max, chunk.ev_max)
            self.net_max = np.maximum(self.net_max, chunk.net_max)          # never NaN (see ChunkMonitor.event)
            self.bound51_max = np.fmax(self.bound51_max, chunk.bound51_max)
            self.ratio51_s = np.fmax(self.ratio51_s, chunk.ratio51_s)
            for k, v in chunk.maxima.items():
                self.maxima[k] = _nanmax(self.maxima[k], np.array(v))
            for k, v in chunk.counts.items():
                self.counts[k] += v
            self.g_count += chunk.g_count
        return self

    def arrays(self) -> dict[str, np.ndarray]:
        out = {f"t0_{k}": v for k, v in self.trial0.items()}
        if self.z0 is not None:
            out["t0_z"] = self.z0
        sd = np.sqrt(self.ev_m2 / np.maximum(self.ev_count - 1, 1)[:, None])
        out.update({"ev_count": self.ev_count, "ev_mean": self.ev_mean, "ev_sd": sd, "ev_max": self.ev_max,
                    "ev_central_mean": self.ce_mean,
                    "ev_central_sd": np.sqrt(self.ce_m2 / np.maximum(self.ev_count - 1, 1)[:, None]),
                    "net_mean": self.net_mean, "net_sd": np.sqrt(self.net_m2 / np.maximum(self.ev_count - 1, 1)),
                    "net_max": self.net_max, "bound51_max": self.bound51_max, "ratio51_s": self.ratio51_s,
                    "g_t_ns": self.t_ns, "g_mean": self.g_sum / max(self.g_count, 1), "g_max": self.g_max,
                    "g_central_mean": self.g_csum / max(self.g_count, 1), "g_stride": np.array(self.stride),
                    "g_total": np.array(self.samples_total), "iterate_hash": np.array(self.iterate_hash)})
        for k, w in self.worst.items():
            out.update(w.arrays(f"w_{k}"))
        out.update({f"max_{k}": np.array(v) for k, v in self.maxima.items()})
        out.update({f"count_{k}": np.array(v) for k, v in self.counts.items()})
        out.update({f"trial_{k}": np.concatenate(v) if v else np.empty(0) for k, v in self.per_trial.items()})
        return out


class UnitPart:
    """What one RNG unit of a chunk adds to the run, where the order of the units matters: its sums at the stored
    samples, its moments per event index (count, means, M2, for `RunAccumulator.merge_moments`), its worst cases
    and its per-trial values; the first unit of a chunk also carries the chunk's own `RunAccumulator` (`chunk`:
    maxima, counts, trial 0)."""

    def __init__(self, acc: RunAccumulator):
        self.g_sum, self.g_csum = np.zeros_like(acc.g_sum), np.zeros_like(acc.g_csum)
        self.moments: list[tuple] = []
        self.worst: dict[str, Worst] = {}
        self.per_trial: dict[str, np.ndarray] = {}
        self.chunk: RunAccumulator | None = None


class ChunkMonitor(ho.Monitor):
    """Evaluates the bounds of one chunk of trials as the simulator hands over its samples,
    intervals and events (see the module docstring). `acc` is the chunk's own accumulator (fresh); `finish`
    returns one `UnitPart` per unit, for the run's accumulator to absorb in unit order."""

    def __init__(self, ctx: dict, acc: RunAccumulator, sizes: list[int], first: int):
        self.ctx, self.acc = ctx, acc
        self.edges = np.cumsum([0, *sizes])
        self.has0 = first == 0
        acc.has_trial0 = self.has0
        self.parts = [UnitPart(acc) for _ in sizes]
        self.parts[0].chunk = acc
        self.iter_hash = hashlib.blake2b(digest_size=16)

    # -- set-up ----------------------------------------------------------------------------------
    def start(self, L: ho.RunLayout) -> None:
        c = self.ctx
        self.L = L
        B, m = L.B, L.m
        self.prev = None
        self.exact = None                          # e^(F_i sT) ē_i(0), per trial
        self.restart_min = np.full(B, np.inf)
        self.X_prev = None
        self.K0 = self.K0sym = None
        self.conv = np.zeros(B)
        self.intervals: dict[int, tuple] = {}
        self.cont = [np.full(B, -np.inf), np.full(B, -np.inf)]
        self.maxima = {k: np.full(B, -np.inf) for k in ("ratio51", "ratio_sym", "ratio63", "restart", "res_minus",
                                                        "res_plus", "eb_max")}
        self.worst = {k: Worst(B) for k in WORST}
        self.counts = {k: 0 for k in COUNTS}
        self.fit = {k: np.zeros(B) for k in ("n", "mt", "my", "stt", "sty")}
        self.fit_active = np.ones(B, dtype=bool)
        self.fit_stop = np.full(B, -1, dtype=np.int64)
        self.fp = np.zeros(B, dtype=np.uint64)
        self.fp_coef = np.random.default_rng(20_170_614).integers(1, 2**62, size=m * L.n, dtype=np.uint64) | np.uint64(1)
        self.c3_first = [np.full(B, np.nan), np.full(B, np.nan)]
        self.ef_now, self.efs_now = np.zeros(B), np.zeros(B)      # carried round-off at the current event index
        self.ef_next, self.efs_next, self.ef_prev = np.zeros(B), np.zeros(B), np.zeros(B)
        self.s_last = -1
        self.kf = c["make_kf"]() if (self.has0 and c["run"].noise) else None
        self.z_keep = c["iter_keep"]
        self.w_starts = np.array([w.start for w in L.w_slices])

    def units(self):
        return [(a, b) for a, b in zip(self.edges[:-1], self.edges[1:])]

    def unit_moments(self, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Per RNG unit: the mean and the sum of squared deviations from it of every column, (U, k)."""
        sizes = np.diff(self.edges)
        means = np.add.reduceat(values, self.edges[:-1], axis=0) / sizes[:, None]
        dev = values - np.repeat(means, sizes, axis=0)
        return means, np.add.reduceat(dev * dev, self.edges[:-1], axis=0)

    # -- samples ----------------------------------------------------------------------------------
    def sample(self, k: int, t_ns: int, X: np.ndarray) -> None:
        c, acc, L = self.ctx, self.acc, self.L
        m, n = L.m, L.n
        first = X.shape[1] - m * n - n
        x = X[:, :n]
        kf_err = None
        if self.kf is not None:
            if k:
                self.kf.predict()
            self.kf.update(c["Cs"] @ x[0])
            kf_err = float(np.linalg.norm(self.kf.x - x[0]))
        j = acc.stored.get(k)
        if j is None and not c["continuous"]:
            return                                          # nothing to evaluate or keep at this sample
        xh, xc = X[:, first:first + m * n].reshape(-1, m, n), X[:, -n:]
        diff = xh - x[:, None]
        err = np.sqrt(np.einsum("bij,bij->bi", diff, diff))                 # (B, m), ||x_i - x||
        xnorm = np.sqrt(np.einsum("bi,bi->b", x, x))
        if c["continuous"]:
            s_now = int(min(max(math.floor(t_ns / ho.NS / c["T"] + 1e-9), 0), L.S))
            emax = rowmax(err)
            floor = c["tol"] * np.maximum(1.0, xnorm + emax) + c["enAT"] * self.ef_at(s_now)
            t = t_ns / ho.NS
            for j_, extra in enumerate((0.0, c["lam"] * c["T"])):
                bound = math.exp(c["nA"] * c["T"] + extra - c["lam"] * t) * self.K0 + floor
                np.maximum(self.cont[j_], emax / bound, out=self.cont[j_])
            self.counts["cont"] += len(emax)
        if j is None:
            return
        if self.has0:
            t0 = acc.trial0
            t0["x"][j], t0["xhat"][j], t0["xc"][j] = x[0], xh[0], xc[0]
            t0["err"][j], t0["xnorm"][j] = err[0], xnorm[0]
            t0["cerr"][j] = np.linalg.norm(xc[0] - x[0])
            if kf_err is not None:
                t0["kf"][j] = kf_err
        cerr = rownorm(xc - x)
        for part, (a, b) in zip(self.parts, self.units()):
            part.g_sum[j] = err[a:b].sum(axis=0)
            part.g_csum[j] = cerr[a:b].sum()
        acc.g_max[j] = np.maximum(acc.g_max[j], err.max(axis=0))

    def ef_at(self, s: int) -> np.ndarray:
        """The carried round-off of the local observer errors at event index s (known once event
        s-1 is in)."""
        return self.ef_now if s <= self.s_last else self.ef_next

    # -- intervals ----------------------------------------------------------------------------------
    def interval(self, data: ho.IntervalData) -> None:
        # interval s's iterations run when every agent has reached event s-1, which the simulator
        # hands over just after: keep them by s until event s is in
        self.intervals[data.s] = (data.W, data.pi0_max, data.piq_max)
        if self.has0:
            acc = self.acc
            self.iter_hash.update(np.ascontiguousarray(data.traj0).tobytes())
            if data.s <= self.z_keep:
                if acc.z0 is None:
                    acc.z0 = np.full((self.z_keep, *data.traj0.shape), np.nan)
                acc.z0[data.s - 1] = data.traj0

    # -- events -------------------------------------------------------------------------------------
    def event(self, ev: ho.EventData) -> None:
        c, acc, L = self.ctx, self.acc, self.L
        s, m, n, B = ev.s, L.m, L.n, L.B
        sl = L.w_slices
        starts = self.w_starts
        e_i = rownorm(ev.e_post)                                                   # (B, m)
        pre_i = rownorm(ev.e_pre)
        eb_sq = np.add.reduceat(ev.ebar * ev.ebar, starts, axis=1)                 # (B, m): ||ē_i||²
        eb_i = np.sqrt(eb_sq)
        e_mix, eb_mix = rowmax(e_i), rowmax(eb_i)
        e2 = np.sqrt(np.einsum("bi,bi->b", e_i, e_i))
        eb2 = np.sqrt(eb_sq.sum(axis=1))
        xs = rowmax(rownorm(ev.x_event))
        xh = rowmax(rownorm(ev.e_post + ev.x_event))
        scale = np.nan_to_num(np.maximum.reduce([xs, xh, eb2, np.ones(B)]), nan=1.0)
        floor = c["tol"] * scale
        # δē(s) = ē(s) - e^(F_i sT) ē(0): the simulation's round-off in the local observer errors
        self.ef_prev = self.ef_now                                    # EF(s-1)
        if s == 0:
            self.exact = ev.ebar.copy()
            dev_i = np.zeros((B, m))
            self.ef_now, self.efs_now = np.zeros(B), np.zeros(B)
        else:
            self.exact = ho.rowwise_matmul(self.exact, c["steps_block"])        # e^(F_i sT) ē_i(0), every agent
            gap = ev.ebar - self.exact
            dev_i = np.sqrt(np.add.reduceat(gap * gap, starts, axis=1))
            self.ef_now, self.efs_now = self.ef_next, self.efs_next
        dev, dev2 = rowmax(dev_i), np.sqrt(np.einsum("bi,bi->b", dev_i, dev_i))
        lamT = c["lam"] * c["T"]
        # carried round-off of ē: EF(s+1) = e^(-λT) EF(s) + b δē(s)  (and its 2-norm analogue)
        self.ef_next = math.exp(-lamT) * self.ef_now + c["b"] * dev
        self.efs_next = math.exp(-lamT) * self.efs_now + c["b_sym"] * dev2
        self.s_last = s
        bound_floor = floor + self.ef_now
        self.maxima["eb_max"] = np.fmax(self.maxima["eb_max"], eb_mix)
        # statistics over trials, unit by unit in unit order
        cen = ev.central
        means, m2s = self.unit_moments(np.concatenate([e_i, cen, e_mix[:, None]], axis=1))
        for u, (a, b) in enumerate(self.units()):
            self.parts[u].moments.append((s, b - a, means[u, :m], m2s[u, :m], means[u, m:2 * m], m2s[u, m:2 * m],
                                          means[u, -1], m2s[u, -1]))
        acc.ev_max[s] = np.maximum(acc.ev_max[s], e_i.max(axis=0))
        acc.net_max[s] = max(acc.net_max[s], float(e_mix.max()))
        # per-trial fingerprint of e(s), for the bitwise comparison of Theorem 2
        bits = np.ascontiguousarray(ev.e_post.reshape(B, -1)).view(np.uint64)
        self.fp = self.fp * np.uint64(1_000_003) + (bits * self.fp_coef[None, :]).sum(axis=1, dtype=np.uint64)
        if self.has0:
            t0 = acc.trial0
            for key in ("e_pre", "e_post", "x_event", "ebar", "x_nominal", "central"):
                t0[key][s] = getattr(ev, key)[0]
            t0["floor"][s], t0["carried"][s], t0["carried_sym"][s] = floor[0], self.ef_now[0], self.efs_now[0]
        if s == 0:
            self.K0 = e_mix + c["d"] * eb_mix
            self.K0sym = e2 + c["d_sym"] * eb2
            self.per_trial_start = (e_mix, eb_mix)
        else:
            self.W, pi0, piq = self.intervals.pop(s)
            self.pi = (pi0, piq)
            self._recursion(ev, s, scale)
            self._bounds(s, e_mix, eb_mix, e2, pre_i, floor, bound_floor, dev, ev)
        self.prev = (ev, e_mix, eb_mix, floor)
        self.X_prev = e_mix + c["d"] * (eb_mix + dev) - self.ef_now        # X(s) of the restarted bound
        if s == L.S:
            self._finish_fit()

    def _recursion(self, ev: ho.EventData, s: int, scale: np.ndarray) -> None:
        """(41) / (61') on interval s, and the per-agent one-step bound of trial 0."""
        c, L = self.ctx, self.L
        if c["noise"] or not L.participating[s - 1].all():
            return
        B, m, n = L.B, L.m, L.n
        pev = self.prev[0]
        mats, (nA_, nB_, nG_), _ = c["matrices"].get(self.W, L.participating[s - 1])
        rm = ho.rowwise_matmul                               # per-trial sums: the same whatever the chunk
        base = rm(pev.e_post.reshape(B, m * n), mats.A.T) + rm(pev.ebar, mats.B.T)
        xg = rm(pev.x_nominal, mats.G.T)
        cur = ev.e_post.reshape(B, m * n)
        res_scale = np.maximum.reduce([rowmax(rownorm(ev.x_event)), rowmax(rownorm(pev.x_event)),
                                       rowmax(np.abs(pev.e_post).reshape(B, -1)), rownorm(pev.ebar), np.ones(B)])
        self.maxima["res_minus"] = np.maximum(self.maxima["res_minus"], rowmax(np.abs(cur - (base - xg))) / res_scale)
        self.maxima["res_plus"] = np.maximum(self.maxima["res_plus"], rowmax(np.abs(cur - (base + xg))) / res_scale)
        self.counts["res"] += B
        if self.has0:
            e_prev = np.linalg.norm(pev.e_post[0], axis=-1)
            eb_prev = np.array([np.linalg.norm(pev.ebar[0, w]) for w in L.w_slices])
            self.acc.trial0["bound41"][s] = nA_ @ e_prev + nB_ @ eb_prev + nG_[:, 0] * np.linalg.norm(pev.x_nominal[0])

    def _bounds(self, s, e_mix, eb_mix, e2, pre_i, floor, bound_floor, dev, ev) -> None:
        c = self.ctx
        lamT = c["lam"] * c["T"]
        decay = math.exp(-lamT * s)
        _, e_prev, eb_prev, floor_prev = self.prev
        if c["theorem"]:
            rhs = decay * self.K0
            self.worst["eq51"].update(e_mix, rhs + bound_floor)
            with np.errstate(divide="ignore", invalid="ignore"):
                ratio = e_mix / rhs
            self.maxima["ratio51"] = np.fmax(self.maxima["ratio51"], ratio)
            acc = self.acc
            acc.bound51_max[s] = np.fmax(acc.bound51_max[s], float(rhs.max()))
            acc.ratio51_s[s] = np.fmax(acc.ratio51_s[s], float(np.nanmax(ratio, initial=-np.inf)))
            if self.has0:
                acc.trial0["bound51"][s] = rhs[0]
        if c["restart"]:
            # min over 1 <= s0 < s of e^(-λ(s-s0)T) X(s0), X(s0) = e(s0) + d(ē(s0) + δē(s0)) - EF(s0)
            if s >= 2:
                self.restart_min = math.exp(-lamT) * np.minimum(self.restart_min, self.X_prev)
                bound = self.restart_min + self.ef_now + floor
                self.maxima["restart"] = np.maximum(self.maxima["restart"], e_mix / bound)
                self.counts["restart"] += len(e_mix) * (s - 1)
        if c["continuous"]:                    # the left limits e_i(t_is⁻) against the continuous bound
            pre = rowmax(pre_i)
            pre_floor = floor + c["enAT"] * self.ef_prev                      # tol·scale(s) + e^(||A||T) EF(s-1)
            for j, extra in enumerate((0.0, lamT)):
                bound = math.exp(c["nA"] * c["T"] + extra - lamT * s) * self.K0 + pre_floor
                self.cont[j] = np.maximum(self.cont[j], pre / bound)
        if c["fit"] and s >= FIT_SKIP:
            hit = self.fit_active & (e_mix <= floor)
            self.fit_stop = np.where(hit, s, self.fit_stop)
            self.fit_active &= ~hit
            a = self.fit_active
            if a.any():
                t = float(self.L.event_ns[0, s]) / ho.NS
                with np.errstate(divide="ignore"):
                    y = np.log(e_mix)
                f = self.fit
                f["n"] = np.where(a, f["n"] + 1, f["n"])
                dt = t - f["mt"]
                f["mt"] = np.where(a, f["mt"] + dt / np.maximum(f["n"], 1), f["mt"])
                dy = y - f["my"]
                f["my"] = np.where(a, f["my"] + dy / np.maximum(f["n"], 1), f["my"])
                f["stt"] = np.where(a, f["stt"] + dt * (t - f["mt"]), f["stt"])
                f["sty"] = np.where(a, f["sty"] + dt * (y - f["my"]), f["sty"])
        if c["ideal"]:
            pi0, piq = self.pi
            alpha_p, qQ = c["alpha_p"], c["qQ"]
            Bs = c["B_mixed"][s - 1]
            Bs = c["b"] if math.isnan(Bs) else Bs
            lhs = np.stack([piq, e_mix], axis=1)
            rhs = np.stack([alpha_p * pi0 + qQ * eb_prev + floor_prev,
                            c["enAT"] * alpha_p * e_prev + Bs * eb_prev + floor], axis=1)
            self.worst["c3"].update(lhs, rhs)
            if s == 1:
                self.c3_first = [pi0.copy(), piq.copy()]
        if c["symmetric"]:
            rhs = decay * self.K0sym
            self.worst["sym"].update(e2, rhs + floor * math.sqrt(self.L.m) + self.efs_now)
            with np.errstate(divide="ignore", invalid="ignore"):
                self.maxima["ratio_sym"] = np.fmax(self.maxima["ratio_sym"], e2 / rhs)
        if c["eq63"]:
            xn = rownorm(self.prev[0].x_nominal)
            self.conv = math.exp(-lamT) * self.conv + xn                   # Σ_{k=1}^{s} e^(-λ(s-k)T) ||x((k-1)T)||
            rhs = decay * self.K0 + c["eps"] * c["g"] * self.conv
            self.worst["eq63"].update(e_mix, rhs + bound_floor)
            with np.errstate(divide="ignore", invalid="ignore"):
                self.maxima["ratio63"] = np.fmax(self.maxima["ratio63"], e_mix / rhs)

    def _finish_fit(self) -> None:
        f = self.fit
        with np.errstate(divide="ignore", invalid="ignore"):
            rate = np.where(f["n"] >= 3, -f["sty"] / f["stt"], np.nan)
        self.fit_rate = rate
        self.fit_stop = np.where(self.fit_stop < 0, self.L.S + 1, self.fit_stop)

    # -- the end of the chunk -----------------------------------------------------------------------
    def finish(self) -> list[UnitPart]:
        acc = self.acc
        fit_rate = getattr(self, "fit_rate", np.full(self.L.B, np.nan))
        for part, (a, b) in zip(self.parts, self.units()):
            part.worst = {k: w.part(a, b) for k, w in self.worst.items()}
            part.per_trial = {"fit_rate": fit_rate[a:b], "fit_first": np.full(b - a, FIT_SKIP, dtype=np.int64),
                              "fit_stop": self.fit_stop[a:b], "fingerprint": self.fp[a:b],
                              "e0": self.per_trial_start[0][a:b], "eb0": self.per_trial_start[1][a:b]}
        if self.has0:
            acc.iterate_hash = self.iter_hash.hexdigest()
        for k, v in self.maxima.items():
            acc.maxima[k] = _nanmax(acc.maxima[k], v)
        acc.maxima["cont_printed"] = _nanmax(acc.maxima["cont_printed"], self.cont[0])
        acc.maxima["cont_corrected"] = _nanmax(acc.maxima["cont_corrected"], self.cont[1])
        acc.maxima["c3_pi01"] = _nanmax(acc.maxima["c3_pi01"], self.c3_first[0])
        acc.maxima["c3_piq1"] = _nanmax(acc.maxima["c3_piq1"], self.c3_first[1])
        for k, v in self.counts.items():
            acc.counts[k] += v
        acc.g_count += self.L.B
        return self.parts


def _nanmax(current: float, values: np.ndarray) -> float:
    """The running maximum of a check quantity; NaN (a comparison that could not be made) sticks."""
    if math.isnan(current) or np.isnan(values).any():
        return float("nan")
    return max(current, float(np.max(values)))
