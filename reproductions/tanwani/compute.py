"""Stages of the random-comm-filter family, each cached: deterministic bounds per scenario,
the gridded Monte Carlo per (scenario, λ), the exact event-driven Monte Carlo and the
frozen-clock-path Monte Carlo per scenario, and (paper only) the topology sweep S4."""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field

import numpy as np
import scipy.linalg as sla

import estimators.gossip_covariance as gc
import estimators.gossip_filter as gf
import estimators.kalman_bucy as kb
from estimators.linear_flows import van_loan
from pipeline.cache import StageCache, code_fingerprint
from pipeline.graphs import GraphSpec
from pipeline.matrix_moments import MatrixMoments
from pipeline.reproduction import RunOptions
from pipeline.seeding import stream_seed
from pipeline.simulate import parallel_map, run_blocks

from .scenario import FilterNetworkScenario, with_graph

CODE_MODULES = ("estimators.gossip_covariance", "estimators.gossip_filter", "estimators.kalman_bucy",
                "estimators.linear_flows", "pipeline.matrix_moments", "pipeline.simulate", "pipeline.seeding",
                "reproductions.tanwani.compute")
FILTERPY_STEPS = (0.1, 0.05, 0.02, 0.01, 0.005)
GRID_BLOCK = 2_500
EVENT_BLOCK = 1000
TOPOLOGIES = {"path": {"kind": "line", "n": 4}, "ring": {"kind": "ring", "n": 4},
              "star": {"kind": "edges", "n": 4, "edges": [[0, 1], [0, 2], [0, 3]]}, "complete": {"kind": "complete", "n": 4}}


@dataclass
class ScenarioResults:
    scenario: FilterNetworkScenario
    bounds: dict[str, np.ndarray]
    gridded: dict[float, dict[str, np.ndarray]]
    event: dict[str, np.ndarray]
    frozen: dict[str, np.ndarray]
    trials: int
    event_trials: int

    @property
    def sys(self) -> gf.GossipSystem:
        return self.scenario.system

    def grid_moments(self, rate: float) -> MatrixMoments:
        return MatrixMoments.from_arrays(self.gridded[rate], "e_")

    def event_moments(self) -> MatrixMoments:
        return MatrixMoments.from_arrays(self.event, "e_")

    def frozen_moments(self) -> MatrixMoments:
        return MatrixMoments.from_arrays(self.frozen, "e_")

    def bound(self, rate: float) -> np.ndarray:
        return self.bounds[f"bound_t_{self.scenario.rates.index(rate)}"]

    def joint(self, rate: float) -> np.ndarray | None:
        key = f"joint_t_{self.scenario.rates.index(rate)}"
        return self.bounds.get(key)


@dataclass
class Results:
    seed: int
    quick: bool
    is_paper: bool
    scenarios: dict[str, ScenarioResults]
    topology: dict[str, np.ndarray] | None = field(default=None)


def trial_counts(sc: FilterNetworkScenario, opts: RunOptions) -> tuple[int, int]:
    if opts.trials is not None:
        return opts.trials, max(50, opts.trials // 5)
    return (sc.quick_trials, sc.quick_event_trials) if opts.quick else (sc.trials, sc.event_trials)


def joint_ok(sys: gf.GossipSystem) -> bool:
    return sys.N * sys.n <= gc.MAX_JOINT_DIM


# -- bounds ----------------------------------------------------------------------------------------

QUICK_SWEEP_POINTS = 15
QUICK_TOPOLOGY_POINTS = 8


def compute_bounds(sc: FilterNetworkScenario, quick: bool = False) -> dict[str, np.ndarray]:
    """Everything deterministic of one scenario (quick: a coarser λ sweep)."""
    s = sc.system
    N, n = s.N, s.n
    out: dict[str, np.ndarray] = {}
    Hs, Vs = np.vstack(s.H), sla.block_diag(*s.V)
    T = sc.n_outputs
    try:
        P_kb, K_kb = kb.kalman_bucy_steady(s.A, s.B, Hs, Vs)
        out["P_kb"], out["K_kb"] = P_kb, K_kb
    except (np.linalg.LinAlgError, ValueError):
        pass
    out["P_kb_t"] = kb.kalman_bucy_riccati(s.A, s.B, Hs, Vs, s.P0, sc.output_step, T)
    for r, lam in enumerate(sc.rates):
        out[f"bound_t_{r}"] = gc.bound_transient(s, lam, sc.output_step, T)
        if joint_ok(s):
            out[f"joint_t_{r}"] = gc.joint_transient(s, lam, sc.output_step, T)
    out["crit_bound"] = np.array(gc.critical_rate_bound(s))
    if joint_ok(s):
        out["crit_joint"] = np.array(gc.critical_rate_joint(s, upper=float(out["crit_bound"])))
    abar = float(np.max(np.linalg.eigvals(s.Abar).real))
    out["abar_abscissa"] = np.array(abar)
    if abar < 0:
        out["S"], out["R"] = gc.lyapunov_S(s), gc.lyapunov_R(s.Abar)
        out["S_true"] = gc.lyapunov_S_true(s)
    lo, hi, pts = sc.sweep
    pts = min(pts, QUICK_SWEEP_POINTS) if quick else pts
    lams = np.geomspace(lo, hi, pts)
    extra = []
    if abar < 0:
        for variant in ("faithful", "tight"):
            c = eb = gc.explicit_bound(s, variant)
            out[f"explicit_{variant}"] = np.array([c.C0, c.C1, c.C2, c.C3, c.a1, c.a2, c.sigma_G, c.sigma1_R, c.sigman_R,
                                                   c.kappa, c.fiedler, c.S_norm, c.threshold])
            if math.isfinite(eb.threshold) and eb.threshold > 0:
                extra += [eb.threshold * f for f in (1.5, 3.0, 10.0, 100.0)]
    lams = np.unique(np.concatenate([lams, extra]))
    out["sweep"] = lams
    P_inf = np.full((len(lams), N, n, n), np.nan)
    J_inf = np.full((len(lams), N, n, n), np.nan)
    absc9, abscS = np.zeros(len(lams)), np.full(len(lams), np.nan)
    for k, lam in enumerate(lams):
        absc9[k] = gc.bound_abscissa(s, lam)
        p = gc.bound_steady(s, lam)
        if p is not None:
            P_inf[k] = p
        if joint_ok(s):
            M, g = gc.joint_generator(s, lam)
            abscS[k] = float(np.max(np.linalg.eigvals(M).real))
            if abscS[k] < 0:
                J_inf[k] = gc.diagonal_blocks(gc.unvec(np.linalg.solve(M, -g), N * n), N, n)
    out["sweep_bound"], out["sweep_joint"], out["sweep_absc_bound"], out["sweep_absc_joint"] = P_inf, J_inf, absc9, abscS
    if abar < 0:
        for variant in ("faithful", "tight"):
            eb = gc.explicit_bound(s, variant)
            out[f"sweep_explicit_{variant}"] = np.array([eb.value(l) for l in lams])
    # filterpy on the sampled model, several sampling steps, run to steady state
    pri, post, dare = [], [], []
    for h in FILTERPY_STEPS:
        steps = int(round(min(30.0, 40.0 / max(1e-3, -min(abar, -1e-3))) / h))
        prior, posterior = kb.discretised_kalman_covariances(s.A, s.B, Hs, Vs, s.P0, h, min(steps, 6000))
        pri.append(prior[-1]), post.append(posterior[-1])
        F, Qd = van_loan(s.A, s.B @ s.B.T, h)
        dare.append(sla.solve_discrete_are(F.T, Hs.T, Qd, Vs / h))
    out["filterpy_h"], out["filterpy_prior"], out["filterpy_post"], out["dare_prior"] = (
        np.array(FILTERPY_STEPS), np.array(pri), np.array(post), np.array(dare))
    return out


# -- Monte Carlo ------------------------------------------------------------------------------------

def simulate_gridded_rate(sc: FilterNetworkScenario, seed: int, trials: int, rate: float) -> dict[str, np.ndarray]:
    s = sc.system
    n, N = s.n, s.N
    n_steps = int(round(sc.horizon / sc.grid_step))
    every = int(round(sc.output_step / sc.grid_step))
    samples: dict[str, np.ndarray] = {}

    def block(size, rng):
        keep = 0 if samples else min(sc.sample_trials, size)
        run = gf.simulate_gridded(s, rate, sc.grid_step, n_steps, every, size, rng, keep_events=keep)
        if keep:
            samples["sample_z"] = run.z[:keep]
            samples["sample_events"] = run.events
        e = run.z[:, :, n:].reshape(size, -1, N, n)
        return MatrixMoments.of(e)

    mom = run_blocks(block, MatrixMoments.combine, trials, stream_seed(seed, "gridded", sc.name, rate), GRID_BLOCK)
    return {**mom.arrays("e_"), **samples}


def simulate_event_rate(sc: FilterNetworkScenario, seed: int, trials: int) -> dict[str, np.ndarray]:
    s = sc.system
    n, N = s.n, s.N
    rate = sc.main_rate
    times = sc.output_times
    samples: dict[str, np.ndarray] = {}
    # the silent clock path (no ring): a deterministic shift for the power sums of the per-path
    # Σ(t; τ) and P(t; τ) below, so that their skewness is formed without cancellation
    silent = gf.simulate_event_driven(s, rate, times, 1, np.random.default_rng(0), sample=False,
                                      clock_path=(np.zeros(0), np.zeros(0, dtype=np.int64)))
    sig_c, p_c = silent.sigma[0], silent.pbound[0]

    def block(size, rng):
        run = gf.simulate_event_driven(s, rate, times, size, rng)
        if not samples:
            k = min(sc.sample_trials, size)
            samples.update(sample_z=run.z[:k], sample_sigma=run.sigma[:k], sample_pbound=run.pbound[:k],
                           sample_event_times=run.event_times[:k], sample_event_clocks=run.event_clocks[:k])
        e = run.z[:, :, n:].reshape(size, -1, N, n)
        counts = np.zeros((size, N))
        valid = run.event_clocks >= 0
        for c, (i, j) in enumerate(s.clocks):
            hits = ((run.event_clocks == c) & valid).sum(axis=1)
            counts[:, i] += hits
            if s.mode == "edge":
                counts[:, j] += hits
        with np.errstate(invalid="ignore"):
            gaps = np.diff(run.event_times, axis=1)
        min_spacing = float(np.min(np.where(np.isfinite(gaps), gaps, np.inf))) if gaps.size else math.inf
        rel = run.min_gap / np.maximum(1.0, run.scale)
        # given the clocks, e(t) ~ N(0, Σ(t; τ)) exactly: E[e_ae_b − Σ_ab | τ] = 0 with conditional
        # variance Σ_ab² + Σ_aaΣ_bb (Gaussian fourth moments)
        dg = np.diagonal(run.sigma, axis1=-2, axis2=-1)
        cond_var = run.sigma ** 2 + dg[..., :, None] * dg[..., None, :]
        resid = e[..., :, None] * e[..., None, :] - run.sigma
        ds, dp = run.sigma - sig_c, run.pbound - p_c
        return {"mom": MatrixMoments.of(e), "sig1": run.sigma.sum(0), "sig2": (run.sigma ** 2).sum(0),
                "p1": run.pbound.sum(0), "p2": (run.pbound ** 2).sum(0),
                "sigd1": ds.sum(0), "sigd2": (ds ** 2).sum(0), "sigd3": (ds ** 3).sum(0),
                "pd1": dp.sum(0), "pd2": (dp ** 2).sum(0), "pd3": (dp ** 3).sum(0), "min_gap": run.min_gap.min(),
                "min_rel_gap": rel.min(), "c1": counts.sum(0), "c2": (counts ** 2).sum(0), "spacing": min_spacing,
                "resid": resid.sum(0), "cond_var": cond_var.sum(0), "n": size}

    def combine(parts):
        out = {"mom": MatrixMoments.combine([p["mom"] for p in parts])}
        for key in ("sig1", "sig2", "p1", "p2", "sigd1", "sigd2", "sigd3", "pd1", "pd2", "pd3", "c1", "c2", "resid",
                    "cond_var", "n"):
            out[key] = sum(p[key] for p in parts)
        out["min_gap"] = min(p["min_gap"] for p in parts)
        out["min_rel_gap"] = min(p["min_rel_gap"] for p in parts)
        out["spacing"] = min(p["spacing"] for p in parts)
        return out

    res = run_blocks(block, combine, trials, stream_seed(seed, "event", sc.name, rate), EVENT_BLOCK)
    arrays = res.pop("mom").arrays("e_")
    arrays.update({k: np.asarray(v) for k, v in res.items()})
    arrays.update(samples, sig_c=sig_c, p_c=p_c)
    return arrays


def simulate_frozen(sc: FilterNetworkScenario, seed: int, trials: int) -> dict[str, np.ndarray]:
    """One clock path, drawn once, shared by every trial: MC over (x0, ω, v) only."""
    s = sc.system
    n, N = s.n, s.N
    rng = np.random.Generator(np.random.SFC64(stream_seed(seed, "frozen-path", sc.name)))
    t, c = gf.sample_clock_events(len(s.clocks), sc.main_rate, sc.horizon, 1, rng)
    path = (t[0][np.isfinite(t[0])], c[0][c[0] >= 0])
    keep: dict[str, np.ndarray] = {}

    def block(size, rng):
        run = gf.simulate_event_driven(s, sc.main_rate, sc.output_times, size, rng, clock_path=path)
        if not keep:
            keep.update(path_sigma=run.sigma[0], path_pbound=run.pbound[0], path_min_gap=run.min_gap.min(axis=0))
        return MatrixMoments.of(run.z[:, :, n:].reshape(size, -1, N, n))

    mom = run_blocks(block, MatrixMoments.combine, trials, stream_seed(seed, "frozen", sc.name), 4 * EVENT_BLOCK)
    return {**mom.arrays("e_"), **keep, "path_times": path[0], "path_clocks": path[1]}


def compute_topology(sc: FilterNetworkScenario, quick: bool = False) -> dict[str, np.ndarray]:
    """S4: S2's plant and sensors on the path, ring, star and complete graphs of 4 nodes."""
    lams = np.geomspace(0.3, 1e4, QUICK_TOPOLOGY_POINTS if quick else 20)
    out: dict[str, np.ndarray] = {"lams": lams}
    for name, g in TOPOLOGIES.items():
        s = with_graph(sc, GraphSpec.from_dict(g), name)
        fied = float(np.sort(np.linalg.eigvalsh(s.laplacian))[1])
        out[f"{name}_alpha_fiedler"] = np.array(s.alpha * fied)
        S = gc.lyapunov_S(s)
        d, tr = np.full((len(lams), s.N), np.nan), np.full((len(lams), s.N), np.nan)
        gap = np.full(len(lams), np.nan)
        for k, lam in enumerate(lams):
            P = gc.bound_steady(s, lam)
            if P is not None:
                d[k] = np.linalg.norm(P - S, axis=(1, 2))
            Jm = gc.joint_steady(s, lam)
            if Jm is not None:
                Jd = gc.diagonal_blocks(Jm, s.N, s.n)
                tr[k] = np.trace(Jd, axis1=1, axis2=2)
                if P is not None:
                    gap[k] = np.linalg.eigvalsh(P - Jd)[:, 0].min()
        out[f"{name}_d"], out[f"{name}_trace_joint"], out[f"{name}_gap"] = d, tr, gap
        out[f"{name}_crit_bound"] = np.array(gc.critical_rate_bound(s))
    return out


# -- the driver --------------------------------------------------------------------------------------

def _nonfinite_allowed(stage: str, sc: FilterNetworkScenario) -> tuple[str, ...]:
    """Arrays where inf/NaN is a result, not a failure: a bound that diverges below the critical
    rate, an explicit bound below its threshold, the inf padding of event lists."""
    if stage == "bounds":
        return (("sweep_bound", "sweep_joint", "sweep_absc_joint", "sweep_explicit_faithful", "sweep_explicit_tight",
                 "crit_bound", "crit_joint", "explicit_faithful", "explicit_tight")
                + tuple(f"bound_t_{k}" for k in range(len(sc.rates))) + tuple(f"joint_t_{k}" for k in range(len(sc.rates))))
    if stage == "event":
        return ("sample_event_times", "spacing")
    if stage == "topology":
        return tuple(f"{g}_{k}" for g in TOPOLOGIES for k in ("d", "trace_joint", "crit_bound", "gap"))
    return ()


def _work(item):
    cache, stage, params, fn, sc = item
    return cache.get_or_compute(stage, params, fn, scenario=sc.name, allow_nonfinite=_nonfinite_allowed(stage, sc))


def compute(scenarios: list[FilterNetworkScenario], opts: RunOptions, cache: StageCache, *, is_paper: bool) -> Results:
    code = code_fingerprint(CODE_MODULES)
    items, index = [], []
    for sc in scenarios:
        trials, ev_trials = trial_counts(sc, opts)
        base = {"scenario": sc.key(), "code": code}
        mc = {**base, "seed": opts.seed}
        items.append((cache, "bounds", {**base, "quick": opts.quick}, functools.partial(compute_bounds, sc, opts.quick),
                      sc))
        index.append((sc.name, "bounds", None))
        for rate in sc.rates:
            items.append((cache, "gridded", {**mc, "trials": trials, "rate": rate, "samples": sc.sample_trials},
                          functools.partial(simulate_gridded_rate, sc, opts.seed, trials, rate), sc))
            index.append((sc.name, "gridded", rate))
        items.append((cache, "event", {**mc, "trials": ev_trials, "samples": sc.sample_trials},
                      functools.partial(simulate_event_rate, sc, opts.seed, ev_trials), sc))
        index.append((sc.name, "event", None))
        items.append((cache, "frozen", {**mc, "trials": ev_trials},
                      functools.partial(simulate_frozen, sc, opts.seed, ev_trials), sc))
        index.append((sc.name, "frozen", None))
    if is_paper:
        s2 = next(sc for sc in scenarios if sc.name == "s2")
        items.append((cache, "topology", {"scenario": s2.key(), "code": code, "quick": opts.quick},
                      functools.partial(compute_topology, s2, opts.quick),
                      s2))
        index.append(("s2", "topology", None))
    # the longest stages first, so that two workers finish together
    order = sorted(range(len(items)), key=lambda k: {"event": 0, "gridded": 1, "frozen": 2}.get(index[k][1], 3))
    done = parallel_map(_work, [items[k] for k in order], workers=opts.workers, desc="random-comm-filter stages")
    got = {index[k]: v for k, v in zip(order, done)}
    results: dict[str, ScenarioResults] = {}
    for sc in scenarios:
        trials, ev_trials = trial_counts(sc, opts)
        results[sc.name] = ScenarioResults(sc, got[(sc.name, "bounds", None)],
                                           {r: got[(sc.name, "gridded", r)] for r in sc.rates},
                                           got[(sc.name, "event", None)], got[(sc.name, "frozen", None)],
                                           trials, ev_trials)
    topo = got.get(("s2", "topology", None)) if is_paper else None
    return Results(opts.seed, opts.quick, is_paper, results, topo)
