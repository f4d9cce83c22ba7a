"""One hybrid-observer run, simulated in two passes, streamed over trials and time:

1. the interval plan (no trials): for every event interval s the communication of its q
   iterations (weights, source sets, the nominal graph, messages outside their reception
   interval) and the norms of A(s), B(s), G(s) of (42), (43), (61') and |Φ_s(k)| of (49),
   computed once per distinct weight sequence;
2. the trials, in fixed RNG units of 1,000 (dse.simulate.units.run_units), each chunk's bounds
   evaluated while it is simulated (`monitor.ChunkMonitor`): memory grows with neither the
   horizon nor the trial count. A chunk is a function of its units (portable: it goes to the run's
   unit executor, a Dask cluster with `--scheduler local`), and the run's accumulator absorbs its
   units' parts in unit order.
"""
from __future__ import annotations

import hashlib
import math
from collections import OrderedDict

import numpy as np
import scipy  # scipy.linalg loads on first use (scipy imports submodules lazily): `dse list` skips it

import dse.estimators.hybrid_observer as ho
import dse.estimators.jointly_observable_design as jd
from dse.simulate.seeding import stream_seed
from dse.simulate.units import RNG_UNIT, block_generator, run_units
from dse.verify.rules import roundoff_tolerance

from .design import alpha_power, constants
from .monitor import ChunkMonitor, RunAccumulator
from .scenario import HybridFile, RunSection

#: intervals on which |Φ_s(k)| of (49) is evaluated (at most PHI_EVALUATIONS k each)
PHI_INTERVALS = 4
PHI_EVALUATIONS = 2_000
#: trial 0's iterates and the source sets are kept for the first intervals, up to this many numbers
ITERATE_VALUES = 200_000
SOURCE_VALUES = 200_000
#: A(s), B(s), G(s) of recent weight sequences kept for the trial pass
MATRIX_CACHE_BYTES = 64 * 2**20


def is_theorem_run(run: RunSection) -> bool:
    """The runs Theorems 1 and 2 are about: x' = Ax (no input), every agent present, rule (13)."""
    return not run.noise and run.leave is None and run.rule == "mean"


def schedule_for(sc: HybridFile, run: RunSection) -> ho.GraphSchedule:
    return ho.GraphSchedule(sc.graph_masks, kind=run.switching, fixed=run.graph_index, T=sc.T, Delta=run.Delta,
                            beta=run.beta, q=run.q)


def timing_for(sc: HybridFile, run: RunSection, seed: int) -> ho.Timing:
    """Iteration times; an asynchronous run's jitter δ_is(k) ∈ [-ε_i, ε_i] is drawn interval by interval."""
    jitter = None
    if run.timing == "async":
        jitter = ho.SequentialJitter(lambda: block_generator(stream_seed(seed, "jitter", run.name)), run.epsilon, run.q)
    return ho.Timing(sc.T, run.q, run.Delta, run.beta, np.asarray(run.offsets, float), jitter)


def event_times(sc: HybridFile, run: RunSection) -> np.ndarray:
    """t_is = t_i0 + sT in integer nanoseconds, (m, S+1), as the simulator uses them."""
    off = np.array([ho.to_ns(t) for t in run.offsets], dtype=np.int64)
    return off[:, None] + ho.to_ns(sc.T) * np.arange(run.intervals + 1)[None, :]


def memberships(run: RunSection, x_reinit=None, w_reinit=None) -> tuple:
    if run.leave is None:
        return ()
    lv = run.leave
    return (ho.Membership(lv.index, lv.at, lv.rejoin, lv.policy, x_reinit, w_reinit),)


def offset_exponentials(sc: HybridFile, event_ns: np.ndarray) -> np.ndarray | None:
    """e^{A t_i0} for the offsets as simulated (whole nanoseconds), None when every t_i0 = 0."""
    offsets = event_ns[:, 0] / ho.NS
    if not np.any(offsets):
        return None
    return np.array([scipy.linalg.expm(sc.A * t) if t else np.eye(sc.n) for t in offsets])


def digest(W: np.ndarray, pp: np.ndarray) -> bytes:
    return hashlib.blake2b(W.tobytes() + pp.tobytes(), digest_size=16).digest()


def block_norms(M: np.ndarray, rows, cols) -> np.ndarray:
    """The matrix of blockwise spectral norms (its max row sum is the mixed norm |M|)."""
    r = np.concatenate([[0], np.cumsum(rows)])
    c = np.concatenate([[0], np.cumsum(cols)])
    return np.array([[np.linalg.norm(M[r[a]:r[a + 1], c[b]:c[b + 1]], 2) for b in range(len(cols))]
                     for a in range(len(rows))])


class MatrixCache:
    """A(s), B(s), G(s) and their block norms by weight sequence (least recently used dropped)."""

    def __init__(self, sc: HybridFile, d: ho.ObserverDesign, eAT: np.ndarray, E: np.ndarray | None):
        self.sc, self.d, self.eAT, self.E = sc, d, eAT, E
        self.items: OrderedDict = OrderedDict()
        mn = d.m * d.n
        self.capacity = max(2, MATRIX_CACHE_BYTES // (8 * (2 * mn * mn + mn * sum(d.n_i) + mn * d.n)))

    def get(self, W: np.ndarray, pp: np.ndarray, key: bytes | None = None, phi_every: int = 0):
        key = digest(W, pp) if key is None else key
        if key in self.items and not (phi_every and math.isnan(self.items[key][0].phi_max)):
            self.items.move_to_end(key)
            return self.items[key]
        mats = ho.interval_matrices(self.d, W, self.eAT, self.E, phi_every=phi_every)
        m, n = self.d.m, self.d.n
        blocks = (block_norms(mats.A, [n] * m, [n] * m), block_norms(mats.B, [n] * m, self.d.n_i),
                  block_norms(mats.G, [n] * m, [n]))
        norms = {"A_mixed": float(jd.mixed_norm(mats.A, [n] * m, [n] * m)),
                 "B_mixed": float(jd.mixed_norm(mats.B, [n] * m, self.d.n_i)),
                 "G_mixed": float(jd.mixed_norm(mats.G, [n] * m, [n])),
                 "A_2": float(np.linalg.norm(mats.A, 2)), "B_2": float(np.linalg.norm(mats.B, 2)),
                 "Phi_max": mats.phi_max}
        self.items[key] = (mats, blocks, norms)
        while len(self.items) > self.capacity:
            self.items.popitem(last=False)
        return self.items[key]


# -- pass 1: the interval plan ------------------------------------------------------------------------

def interval_plan(sc: HybridFile, run: RunSection, seed: int) -> dict[str, np.ndarray]:
    """Per interval s = 1..S (trial independent): |A(s)|, |B(s)|, |G(s)| (mixed norms), ||A(s)||_2,
    ||B(s)||_2 (NaN when an agent sits the interval out), max_k |Φ_s(k)| on the first PHI_INTERVALS
    intervals, source-set entries that differ from the nominal graph, messages outside their
    reception interval, the nominal graph at the first iteration; the source sets, nominal graphs
    and iteration times of the first intervals (for the recordings)."""
    d = sc.observer
    m, n, S, q = sc.m, sc.n, run.intervals, run.q
    timing, schedule = timing_for(sc, run, seed), schedule_for(sc, run)
    ev = event_times(sc, run)
    part = ho.participation(ev, memberships(run))
    eAT = scipy.linalg.expm(sc.A * (ho.to_ns(sc.T) / ho.NS))
    cache = MatrixCache(sc, d, eAT, offset_exponentials(sc, ev))
    out = {k: np.full(S, np.nan) for k in ("A_mixed", "B_mixed", "G_mixed", "A_2", "B_2", "Phi_max")}
    mism, entries = np.zeros(S, dtype=np.int64), np.zeros(S, dtype=np.int64)
    nominal_graph = schedule.index_at((np.arange(S) * sc.T) + run.beta)
    keep = int(max(1, min(S, SOURCE_VALUES // max(q * m * m, 1), ITERATE_VALUES // max((q + 1) * m * n, 1))))
    src0, nom0 = np.zeros((keep, q, m, m), bool), np.zeros((keep, q, m, m), bool)
    tau0 = np.zeros((keep, m, q + 1))
    violations, seen = 0, set()
    phi_every = max(1, -(-q // PHI_EVALUATIONS))
    for s in range(1, S + 1):
        pp = part[s - 1]
        W, Sk, Nn, bad, tau = ho.interval_sources(schedule, timing, ev, pp, s, run.rule)
        violations += bad
        mism[s - 1], entries[s - 1] = int((Sk != Nn).sum()), Sk.size
        if s <= keep:
            src0[s - 1], nom0[s - 1], tau0[s - 1] = Sk, Nn, tau
        if not pp.all():
            continue
        key = digest(W, pp)
        seen.add(key)
        _, _, norms = cache.get(W, pp, key, phi_every if s <= PHI_INTERVALS else 0)
        for name in ("A_mixed", "B_mixed", "G_mixed", "A_2", "B_2") + (("Phi_max",) if s <= PHI_INTERVALS else ()):
            out[name][s - 1] = norms[name]
    out.update({"source_mismatch": mism, "source_entries": entries, "reception_violations": np.array(violations),
                "participating": part, "nominal_graph": nominal_graph, "distinct_intervals": np.array(len(seen)),
                "event_ns": ev, "sources0": src0, "nominal0": nom0, "tau0": tau0,
                "phi_k_checked": np.array(len(range(0, q, phi_every)) + 1)})
    return out


def simulation_tolerance(sc: HybridFile, design: dict, run: RunSection, plan: dict) -> tuple[float, str]:
    """Round-off allowance, relative to the size of the states, of any quantity built from a
    simulated run (errors e = x̂ - x, the identities (41)/(61')).

    Longest chains of floating-point operations per interval: the q estimator iterations, each
    a sum over mn terms, and the exact propagation over the interval, T/step + m + 1 steps of a
    D-dimensional matrix exponential (D = n + Σn_i + 2 + mn + n states); their results are
    multiplied by e^(AT) and by B(s) (so the condition is ||e^(AT)||_2 (1 + max_s ||B(s)||_2)).
    """
    m, n = sc.m, sc.n
    D = n + int(np.sum(design["n_i"])) + 2 + m * n + n
    steps = math.ceil(sc.T / sc.sampling.step) + m + 1
    ops = run.q * m * n + steps * D
    b2 = plan["B_2"]
    bmax = float(np.nanmax(b2)) if np.isfinite(b2).any() else float(design["Q_2"]) * run.q * math.exp(
        float(design["norm_A"]) * sc.T)
    cond = max(1.0, float(design["norm_eAT"])) * (1.0 + bmax)
    tol, text = roundoff_tolerance(scale=1.0, operations=ops, condition=cond)
    return tol, (f"{text} (relative to the size of the states: q·mn = {run.q * m * n:,} iteration terms + {steps} "
                 f"propagation steps × D = {D}; condition ||e^(AT)||(1 + max ||B(s)||) = {cond:.3g})")


# -- pass 2: the trials ---------------------------------------------------------------------------------

#: arrays of a run's result that must be finite (a NaN or inf there is a numerical failure); the
#: others hold NaN where a quantity does not apply (intervals an agent sat out, checks a run skips)
MUST_BE_FINITE = ("t0_e_post", "t0_x_event", "ev_mean", "ev_max", "net_max")


def run_epsilon(run: RunSection) -> float:
    """ε of (24): the largest jitter bound (asynchronous runs) or event-time offset (Section 4)."""
    if run.timing == "offset":
        return max(abs(x) for x in run.offsets)
    return max(run.epsilon) if run.timing == "async" else 0.0


def bytes_per_trial(sc: HybridFile, n_i) -> float:
    """Memory one trial needs while its chunk is simulated: the state (D numbers) and the
    propagated copy, up to three open event indices and two intervals' captured data, the
    iteration, the monitor's per-trial worst cases, and numpy's temporaries (measured 6.3 kB for
    m = 8, n = 4, D = 58; this model gives 9.7 kB there)."""
    m, n = sc.m, sc.n
    nw = int(np.sum(n_i))
    D = n + nw + 2 + m * n + n
    return 8.0 * (6 * D + 20 * m * n + 6 * nw + 8 * m + 60)


def simulate_run(sc: HybridFile, design: dict, run: RunSection, trials: int, seed: int,
                 budget_bytes: float) -> dict[str, np.ndarray]:
    """The interval plan, then every trial in RNG units within `budget_bytes` per chunk."""
    plan = interval_plan(sc, run, seed)
    d = sc.observer
    m, n = sc.m, sc.n
    nw = sum(d.n_i)
    B_total = trials if run.monte_carlo else 1
    tol, _ = simulation_tolerance(sc, design, run, plan)
    k = constants(design, sc, run)
    N = (m - 1) ** 2 + 1
    ev = plan["event_ns"]
    eAT = scipy.linalg.expm(sc.A * (ho.to_ns(sc.T) / ho.NS))
    Cs = np.vstack(sc.C)

    def make_kf():
        """A centralized Kalman filter (filterpy) on the stacked outputs sampled every sampling
        step, trial 0; the harmonic input is modelled as white process noise of the same power. filterpy
        is imported here, by the runs with an input only: its import (scipy.stats, about 0.4 s) is most of
        a small run's stage otherwise."""
        from filterpy.kalman import KalmanFilter

        kf = KalmanFilter(dim_x=n, dim_z=Cs.shape[0])
        kf.F, kf.H = scipy.linalg.expm(sc.A * sc.sampling.step), Cs
        b = sc.noise_b if sc.noise_b is not None else np.zeros(n)
        kf.Q = 0.5 * np.outer(b, b) * sc.sampling.step + 1e-12 * np.eye(n)
        kf.R = 1e-6 * np.eye(Cs.shape[0])
        kf.x, kf.P = np.zeros(n), 100.0 * np.eye(n)
        return kf

    theorem = is_theorem_run(run)
    ctx = {"run": run, "tol": tol, "lam": sc.lam, "T": sc.T, "nA": k["norm_A"], "enAT": math.exp(k["norm_A"] * sc.T),
           "b": k["b"], "b_sym": k["b_sym"], "d": k["d"], "d_sym": k["d_sym"], "g": k["g"], "eps": run_epsilon(run),
           "noise": run.noise, "theorem": theorem, "restart": theorem and run.timing == "sync",
           "continuous": theorem and run.timing == "sync", "fit": theorem and run.timing == "sync",
           "ideal": run.ideal and run.rule == "mean" and run.leave is None and not run.noise,
           "alpha_p": alpha_power(design, run.q // N),
           "qQ": run.q * float(design["Q_mixed"]), "B_mixed": plan["B_mixed"],
           "symmetric": run.rule == "symmetric" and run.leave is None and not run.noise,
           "eq63": run.timing == "offset" and theorem,
           "steps_block": scipy.linalg.block_diag(*[scipy.linalg.expm(d.F(i) * (ho.to_ns(sc.T) / ho.NS))
                                                    for i in range(m)]).T,
           "Cs": Cs, "make_kf": make_kf,
           "matrices": MatrixCache(sc, d, eAT, offset_exponentials(sc, ev)), "iter_keep": plan["sources0"].shape[0]}
    _, _, grid0, dt_ns, samples = ho.sample_grid(ev[:, 0], ho.to_ns(sc.T), run.intervals, sc.sampling.step)
    Kc = sc.central_gain

    def chunk(streams):
        """The units of `streams`, a function of them alone (portable): one `UnitPart` per unit."""
        x0 = sc.monte_carlo.scale * streams.standard_normal((n,))
        w0 = sc.monte_carlo.scale * streams.standard_normal((nw,))
        xh = sc.monte_carlo.scale * streams.standard_normal((m, n))
        if streams.first_unit == 0:                        # trial 0: the scenario's initial conditions
            x0[0], xh[0] = sc.x0, sc.xhat0
            w0[0] = sc.w0 if sc.w0 is not None else 0.0
        if run.ideal:
            w0 = np.concatenate([ho.rowwise_matmul(x0, L.T) for L in d.L], axis=1)
        members = ()
        if run.leave is not None:
            ag = run.leave.index
            members = memberships(run, xh[:, ag], w0[:, d.w_slices[ag]])
        monitor = ChunkMonitor(ctx, RunAccumulator(sc, run, samples, grid0, dt_ns, nw), streams.sizes,
                               streams.first_unit * RNG_UNIT)
        return ho.simulate(d, timing_for(sc, run, seed), schedule_for(sc, run), x0=x0, w0=w0, xhat0=xh,
                           intervals=run.intervals, dt_plot=sc.sampling.step, rule=run.rule,
                           noise_b=sc.noise_b if run.noise else None, noise_omega=sc.noise.omega, membership=members,
                           central_gain=Kc, xc0=xh.mean(axis=1), monitor=monitor)

    acc = RunAccumulator(sc, run, samples, grid0, dt_ns, nw)
    run_units(chunk, lambda _, part: acc.absorb(part), B_total, stream_seed(seed, "initial-conditions"),
              bytes_per_trial=bytes_per_trial(sc, d.n_i), budget_bytes=budget_bytes, portable=True)
    out = dict(plan)
    out.update(acc.arrays())
    out["trials"] = np.array(B_total)
    return out
