"""Stages of the gossip-Kalman family, each cached: deterministic bounds and assumption checks,
the batched GIKF Monte Carlo, the Theorem-8 (switched Riccati) reference sample of μ, and the
auxiliary samplers (other initial laws, a token started at a fixed sensor, forward coupling,
pull-back)."""
from __future__ import annotations

import functools
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.stats import wishart

import estimators.gossip_kalman as gk
import estimators.kalman as kal
import estimators.switched_riccati as sr
import estimators.walk_detectability as wd
from pipeline.cache import StageCache, check_finite, code_fingerprint
from pipeline.reproduction import RunOptions
from pipeline.seeding import stream_seed
from pipeline.simulate import block_generator, parallel_map, run_blocks

from .scenario import GossipKalmanScenario

CODE_MODULES = ("estimators.gossip_kalman", "estimators.switched_riccati", "estimators.walk_detectability",
                "estimators.kalman", "pipeline.simulate", "pipeline.seeding", "reproductions.kar_moura.compute")
J_GRID = np.logspace(0, 12, 49)
COUPLING_C = 1e6
PULLBACK_LAW_T = (5, 20, 100)
PULLBACK_PATH_T = (16, 32, 64, 128, 256)
WITNESS_MAX_LEN = 6
STAT_STRIDE = 5
ABAR_DRAWS = 200_000  # Monte Carlo Ā when no exact form is feasible (greedy matching on a large graph)


def mean_adjacency(sc: GossipKalmanScenario) -> tuple[np.ndarray, np.ndarray, bool, int]:
    """(Ā, standard error of each entry, exact?, draws). Closed forms for single-edge, node-initiated
    and user-given matchings; the greedy-matching protocol (P4) is exact on small graphs (recursion
    over edge sets) and a Monte Carlo estimate otherwise. Where Ā is estimated, the Theorem-8
    chains are driven by the protocol itself (sampler S3) and the claims that need the exact Ā are
    not checked (spec §11 P9)."""
    protocol = sc.protocol.build(sc.graph)
    zero = np.zeros((sc.N, sc.N))
    if isinstance(protocol, gk.GreedyMatchingGossip):
        exact = _exact_greedy_mean(protocol)
        if exact is None:
            rng = block_generator(stream_seed(0, sc.name, "abar-estimate"))
            A, se = protocol.estimate_mean_matrix(ABAR_DRAWS, rng)
            return A, se, False, ABAR_DRAWS
        return exact, zero, True, 0
    return protocol.mean_matrix(), zero, True, 0


@functools.lru_cache(maxsize=16)
def _exact_greedy_mean(protocol: gk.GreedyMatchingGossip) -> np.ndarray | None:
    return protocol.exact_mean_matrix()


def support_matrix(sc: GossipKalmanScenario) -> np.ndarray:
    """A matrix with Ā's support (exact Ā where it is cheap): enough for C.1's structure and D.1."""
    protocol = sc.protocol.build(sc.graph)
    if isinstance(protocol, gk.GreedyMatchingGossip):
        return protocol.support_matrix()
    return protocol.mean_matrix()


def chain_sampler(sc: GossipKalmanScenario, bounds: dict):
    """sample(size, steps, rng, start=None) -> (size, steps) Ā-chain paths: from Ā (S1) when it is
    exact, else driven by an independent copy of the protocol (S3)."""
    if bool(bounds["Abar_exact"]):
        Abar = bounds["Abar"]
        return lambda size, steps, rng, start=None: sr.sample_chain(Abar, size, steps, rng, start=start)
    protocol = sc.protocol.build(sc.graph)
    return lambda size, steps, rng, start=None: sr.sample_protocol_chain(protocol, size, steps, rng, start=start)


@dataclass
class ScenarioResults:
    scenario: GossipKalmanScenario
    seed: int
    runs: int
    reference_runs: int
    slots: int
    quick: bool
    bounds: dict[str, np.ndarray]
    gikf: dict[str, np.ndarray]
    reference: dict[str, np.ndarray]
    aux: dict[str, np.ndarray] = field(default_factory=dict)
    comparison: dict[str, np.ndarray] | None = None

    @property
    def name(self) -> str:
        return self.scenario.name

    @property
    def c1(self) -> bool:
        return bool(self.bounds["c1"])

    @property
    def d1(self) -> bool:
        return bool(self.bounds["d1"])

    @property
    def theorem_applies(self) -> bool:
        return self.c1 and self.d1

    def witness(self) -> tuple[int, ...] | None:
        w = self.bounds["witness"]
        return tuple(int(x) for x in w) if len(w) else None


@dataclass
class Results:
    seed: int
    quick: bool
    scenarios: dict[str, ScenarioResults]

    def get(self, name: str) -> ScenarioResults | None:
        return self.scenarios.get(name)


def sizes(sc: GossipKalmanScenario, opts: RunOptions) -> tuple[int, int, int]:
    runs = opts.trials if opts.trials is not None else (sc.quick_runs if opts.quick else sc.runs)
    ref = sc.quick_reference_runs if opts.quick else sc.reference_runs
    if opts.trials is not None:
        ref = max(ref, runs)
    slots = sc.quick_slots if opts.quick else sc.slots
    return runs, ref, slots


def record_times(sc: GossipKalmanScenario, slots: int) -> list[int]:
    return sorted({t for t in sc.record_times if t <= slots} | {slots} | {t for t in PULLBACK_LAW_T if t <= slots})


# -- bounds -----------------------------------------------------------------------------------------

def compute_bounds(sc: GossipKalmanScenario, slots: int) -> dict[str, np.ndarray]:
    sys_ = sc.system()
    Abar, Abar_se, Abar_exact, Abar_draws = mean_adjacency(sc)
    chk = wd.check_chain(Abar)
    if not Abar_exact:  # C.1's structure from the exact support (an estimate can miss a rare entry)
        s_chk = wd.check_chain(support_matrix(sc))
        chk = wd.ChainCheck(s_chk.irreducible, s_chk.aperiodic, s_chk.n_classes, s_chk.classes, chk.unit_multiplicity,
                            chk.slem, chk.min_eig)
    out: dict[str, Any] = {"Abar": Abar, "Abar_se": Abar_se, "Abar_exact": Abar_exact, "Abar_draws": Abar_draws,
                           "irreducible": chk.irreducible, "aperiodic": chk.aperiodic, "c1": chk.c1,
                           "n_classes": chk.n_classes, "unit_multiplicity": chk.unit_multiplicity, "slem": chk.slem,
                           "min_eig_Abar": chk.min_eig, "tv": wd.tv_to_uniform(Abar, 200)}
    labels = np.zeros(sc.N, dtype=np.int64)
    for c, cls in enumerate(chk.classes):
        labels[list(cls)] = c
    out["class_of"] = labels
    # detectability: each sensor alone, each class of Ā, all sensors
    F = sc.F
    out["sensor_detectable"] = np.array([not wd.pbh_undetectable(F, sys_.C[n]) for n in range(sc.N)])
    bad_all = wd.pbh_undetectable(F, sys_.C_all)
    out["central_detectable"] = not bad_all
    out["central_observable"] = wd.observable(F, sys_.C_all)
    class_rate = np.zeros(sc.N)
    for cls in chk.classes:
        bad = wd.pbh_undetectable(F, sys_.C[list(cls)].reshape(-1, sc.M))
        class_rate[list(cls)] = 2 * np.log(max(abs(b) for b in bad)) if bad else 0.0
    out["divergence_rate"] = class_rate  # predicted growth rate of log tr P per slot (0: no prediction)
    search = wd.search_witness(sys_, Abar if Abar_exact else support_matrix(sc), max_len=WITNESS_MAX_LEN)
    out["d1"] = search.witness is not None
    out["d1_covering"] = search.witness is not None and chk.irreducible
    out["witness"] = np.array(search.witness if search.witness else [], dtype=np.int64)
    out["witness_max_rank"] = search.max_rank
    out["walks_checked"] = search.walks_checked
    out["q_pd"] = bool(np.linalg.eigvalsh(sc.Q).min() > 0)
    out["alpha"] = float(np.linalg.norm(F, 2))
    out["qnorm"] = float(np.linalg.norm(sc.Q, 2))
    if search.witness is not None:
        w = search.witness
        out["gramian"] = search.gramian
        out["gramian_weighted"] = wd.walk_gramian(sys_, w, weighted=True)
        out["sigma_sub"] = wd.sigma_sub(sys_, w)
        out["sigma_sub_printed"] = wd.sigma_sub_printed(sys_, w)
        cs = np.array([1e2, 1e4, 1e6, 1e8])
        out["g_of_cI_c"] = cs
        out["g_of_cI"] = np.array([wd.compose_walk(sys_, w, c * np.eye(sc.M)) for c in cs])
        alpha0 = float(np.linalg.eigvalsh(out["sigma_sub"])[-1])
        out["alpha0"] = alpha0
        windows = search.windows
        a0_multi = max(float(np.linalg.eigvalsh(wd.sigma_sub(sys_, v))[-1]) for v in windows)
        out["alpha0_multi"] = a0_multi
        ks = np.array([wd.k_of_J(out["alpha"], alpha0, out["qnorm"], J) for J in J_GRID])
        km = np.array([wd.k_of_J(out["alpha"], a0_multi, out["qnorm"], J) for J in J_GRID])
        ell = len(w)
        out["kJ"] = ks
        # β needs the exact Ā (an estimated Ā gives an estimated bound): NaN marks "not computed"
        out["beta_single"] = np.array([(wd.tail_bound_single(Abar, w, min(slots, k + ell)) if k >= 0 else 1.0)
                                       if Abar_exact else np.nan for k in ks])
        small = sc.N ** max(ell - 1, 0) <= 2000 and Abar_exact
        out["beta_multi"] = np.array([(wd.tail_bound_multi(Abar, windows, min(slots, k + ell)) if k >= 0 else 1.0)
                                      if small else np.nan for k in km])
        support = (Abar > 1e-12).astype(float)
        n_windows = float(np.linalg.matrix_power(support, ell - 1).sum())
        if n_windows <= 5000 and Abar_exact:
            Z, pi, corr, printed = wd.lifted_chain_stationary(Abar, ell)
            out["lifted_pi"], out["lifted_corrected"], out["lifted_printed"] = pi, corr, printed
    # centralized reference (same P0): our batched filter, filterpy, and the DARE
    cov = kal.kalman_covariances(F, sys_.C_all, sc.Q, sys_.R_all, sc.P0, slots + 1)
    out["P_central"] = cov.P_prior
    out["K_central"] = cov.gains
    out["P_central_filterpy"] = _filterpy_prior(sc, sys_, slots + 1)
    if out["central_detectable"]:
        out["P_central_inf"] = kal.steady_state_prior_covariance(F, sys_.C_all, sc.Q, sys_.R_all)
    env = [sc.P0]
    for _ in range(slots):
        env.append(gk.lyapunov_step(env[-1], F, sc.Q))
    out["envelope"] = np.array(env)
    return {k: np.asarray(v) for k, v in out.items()}


def _filterpy_prior(sc: GossipKalmanScenario, sys_: gk.GossipSystem, steps: int) -> np.ndarray:
    """P(t|t-1) of filterpy's KalmanFilter on the stacked sensors (update, then predict)."""
    from filterpy.kalman import KalmanFilter

    kf = KalmanFilter(dim_x=sc.M, dim_z=sys_.C_all.shape[0])
    kf.F, kf.Q, kf.H, kf.R, kf.P = sc.F.copy(), sc.Q.copy(), sys_.C_all.copy(), sys_.R_all.copy(), sc.P0.copy()
    kf.x = np.zeros((sc.M, 1))
    out = []
    for _ in range(steps):
        out.append(kf.P.copy())
        kf.update(np.zeros((sys_.C_all.shape[0], 1)))
        kf.predict()
    return np.array(out)


# -- Monte Carlo stages -----------------------------------------------------------------------------

def simulate_gikf_stage(sc: GossipKalmanScenario, bounds: dict, seed: int, runs: int, slots: int,
                        which: str = "protocol") -> dict[str, np.ndarray]:
    spec = sc.protocol if which == "protocol" else sc.comparison
    protocol = spec.build(sc.graph)
    sys_ = sc.system()

    def block(size, rng):
        return gk.simulate_gikf(sys_, protocol, size, slots, rng, record_times=record_times(sc, slots),
                                P_central=bounds["P_central"], K_central=bounds["K_central"],
                                envelope=bounds["envelope"], j_grid=J_GRID, n_paths=sc.sample_paths,
                                nees_window=(min(20, slots // 3), min(60, slots)), stat_stride=STAT_STRIDE)

    # one block: the per-(t, n) quantiles over runs need every run at once (memory is O(runs N M²))
    return run_blocks(block, lambda parts: parts[0], runs, stream_seed(seed, sc.name, "gikf", which), block=runs)


def reference_stage(sc: GossipKalmanScenario, bounds: dict, seed: int, ref_runs: int, slots: int) -> dict[str, np.ndarray]:
    """Theorem-8 process from P0 (sampler S1) with its last switch at each record time."""
    sys_ = sc.system()
    rng = block_generator(stream_seed(seed, sc.name, "theorem8"))
    path = chain_sampler(sc, bounds)(ref_runs, slots, rng)
    out = sr.switched_riccati(sys_, path, sc.P0, record_times(sc, slots), keep_final=True)
    return out


def aux_stage(sc: GossipKalmanScenario, bounds: dict, seed: int, ref_runs: int, slots: int) -> dict[str, np.ndarray]:
    """Other initial laws (R5), tokens from fixed sensors (R8), coupling (burn-in), pull-back (R18/R19)."""
    sys_ = sc.system()
    chain = chain_sampler(sc, bounds)
    M = sc.M
    times = record_times(sc, slots)
    half = max(ref_runs // 2, 100)
    out: dict[str, np.ndarray] = {}
    rng = block_generator(stream_seed(seed, sc.name, "aux"))
    inits = {"zero": np.zeros((M, M)), "huge": 1e6 * np.eye(M),
             "wishart": wishart(df=M + 2, scale=np.eye(M)).rvs(size=half, random_state=rng.integers(2**31)).reshape(half, M, M)}
    for label, X0 in inits.items():
        path = chain(half, slots, rng)
        out[f"init_{label}"] = sr.switched_riccati(sys_, path, X0, [slots])["features"][0]
    for n in sorted({0, min(1, sc.N - 1)}):
        path = chain(half, slots, rng, start=n)
        r = sr.switched_riccati(sys_, path, sc.P0, times)
        out[f"token{n}"] = r["features"]
    cpl_times = [t for t in (10, 20, 40, 80, 160, 320) if t <= slots]
    path = chain(min(2000, ref_runs), slots, rng)
    out["coupling_times"] = np.array(cpl_times)
    out["coupling"] = sr.coupling_gap(sys_, path, COUPLING_C, cpl_times)
    law_T = [t for t in PULLBACK_LAW_T if t <= slots]
    back = chain(half, max(law_T), rng)  # Ā symmetric: the reversed stationary chain is again a Ā-chain
    pb = sr.pullback(sys_, back, sc.P0, law_T)
    out["pullback_law_T"] = np.array(law_T)
    out["pullback_law"] = np.array([gk.covariance_features(x) for x in pb])
    # backward paths need not fit in the forward horizon, but a predicted divergence must stay in float64
    rate = float(bounds["divergence_rate"].max())
    path_T = [t for t in PULLBACK_PATH_T if rate <= 0 or t * rate < FLOAT_LOG_BUDGET] or [8, 16, 32]
    back = chain(500, max(path_T), rng)
    lo = sr.pullback(sys_, back, np.zeros((M, M)), path_T)
    hi = sr.pullback(sys_, back, COUPLING_C * np.eye(M), path_T)
    out["pullback_path_T"] = np.array(path_T)
    out["pullback_lo_norm"] = np.linalg.norm(lo, 2, axis=(-2, -1))
    out["pullback_gap"] = np.linalg.norm(hi - lo, 2, axis=(-2, -1)) / out["pullback_lo_norm"]
    steps = np.diff(lo, axis=0)
    out["pullback_step"] = np.linalg.norm(steps, 2, axis=(-2, -1)) / out["pullback_lo_norm"][1:]
    out["ref_final_lo"] = lo[-1]
    return out


GIKF_PARTIAL = ("margins", "feat_q", "feat_n", "quantiles", "path_trace", "path_err", "path_err_c")


def _stage(cache: StageCache, key: dict, name: str, fn, scenario: str = "", allow: tuple[str, ...] = ()):
    return cache.get_or_compute(name, {**key, "stage": name}, fn, scenario=scenario, allow_nonfinite=allow)


def _checked_gikf(fn, scenario: str):
    """GIKF stage: NaN marks slots not evaluated (stride) in 'margins' and, after a float overflow
    (a divergence, reported by the claims with its slot), the unreached slots; anything else
    non-finite is an error."""
    def run():
        out = fn()
        if int(out["overflow"]) < 0:
            check_finite({k: v for k, v in out.items() if k != "margins"}, stage="gikf", scenario=scenario)
        return out
    return run


FLOAT_LOG_BUDGET = 600.0  # log of the largest covariance entry we let a predicted divergence reach (float64: ~709)


def divergence_rate(sc: GossipKalmanScenario) -> float:
    """Largest predicted growth rate 2 log|λ| of log tr P over the classes of Ā that cannot detect λ (0: none)."""
    sys_ = sc.system()
    chk = wd.check_chain(support_matrix(sc))
    rates = [2 * np.log(max(abs(b) for b in bad)) for cls in chk.classes
             if (bad := wd.pbh_undetectable(sc.F, sys_.C[list(cls)].reshape(-1, sc.M)))]
    return float(max(rates, default=0.0))


def horizon(sc: GossipKalmanScenario, slots: int) -> int:
    """A predicted divergence is simulated only as long as it stays inside float64: slots ≤ 600 / rate."""
    rate = divergence_rate(sc)
    return slots if rate <= 0 else int(min(slots, max(10, FLOAT_LOG_BUDGET // rate)))


def compute_scenario(sc: GossipKalmanScenario, opts: RunOptions, cache: StageCache) -> ScenarioResults:
    runs, ref_runs, slots = sizes(sc, opts)
    slots = horizon(sc, slots)
    code = code_fingerprint(CODE_MODULES)
    base = {"scenario": sc.key(), "code": code, "slots": slots}
    bounds = _stage(cache, base, "bounds", lambda: compute_bounds(sc, slots), sc.name, ("beta_multi", "beta_single"))
    mc = {**base, "seed": opts.seed, "runs": runs, "ref_runs": ref_runs}
    gikf = _stage(cache, mc, "gikf", _checked_gikf(lambda: simulate_gikf_stage(sc, bounds, opts.seed, runs, slots), sc.name),
                  sc.name, GIKF_PARTIAL)
    comparison = (_stage(cache, mc, "gikf_comparison",
                         _checked_gikf(lambda: simulate_gikf_stage(sc, bounds, opts.seed, runs, slots, "comparison"), sc.name),
                         sc.name, GIKF_PARTIAL)
                  if sc.comparison is not None else None)
    reference = _stage(cache, mc, "theorem8", lambda: reference_stage(sc, bounds, opts.seed, ref_runs, slots), sc.name)
    aux = _stage(cache, mc, "aux", lambda: aux_stage(sc, bounds, opts.seed, ref_runs, slots), sc.name)
    return ScenarioResults(sc, opts.seed, runs, ref_runs, slots, opts.quick, bounds, gikf, reference, aux, comparison)


def compute(scenarios: list[GossipKalmanScenario], opts: RunOptions, cache: StageCache) -> Results:
    work = functools.partial(compute_scenario, opts=opts, cache=cache)
    outs = parallel_map(work, scenarios, workers=opts.workers, desc="gossip-kalman scenarios")
    return Results(opts.seed, opts.quick, {o.name: o for o in outs})


def roles(sc: GossipKalmanScenario) -> dict[str, bool]:
    """Which claims a scenario gets, from its (cheap, deterministic) assumption checks."""
    sys_ = sc.system()
    Abar = support_matrix(sc)
    chk = wd.check_chain(Abar)
    d1 = wd.search_witness(sys_, Abar, max_len=WITNESS_MAX_LEN).witness is not None
    diverges = any(wd.pbh_undetectable(sc.F, sys_.C[list(cls)].reshape(-1, sc.M)) for cls in chk.classes)
    return {"c1": chk.c1, "d1": d1, "diverges": diverges, "periodic": chk.irreducible and not chk.aperiodic,
            "tv": chk.c1}
