"""Stages of the gossip-Kalman family, each cached: deterministic bounds and assumption checks,
the batched GIKF Monte Carlo, the Theorem-8 (switched Riccati) reference sample of μ, and the
auxiliary samplers (other initial laws, a token started at a fixed sensor, the restarted
stationary process, forward coupling, pull-back), run only where a claim needs them: the
theorem's conclusions where C.1 and D.1 hold, Theorem 26(a) where C.1 holds and a mode is unseen."""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field
from typing import Any, Collection

import numpy as np
import scipy  # scipy.linalg loads on first use (scipy imports submodules lazily): `dse list` skips it

import dse.estimators.gossip_kalman as gk
import dse.estimators.kalman as kal
import dse.estimators.switched_riccati as sr
import dse.estimators.walk_detectability as wd
from dse.engine.cache import StageCache, check_finite, code_fingerprint
from dse.engine.driver import RunOptions
from dse.simulate.seeding import stream_seed
from dse.simulate.units import block_generator, run_jobs, run_units

from .scenario import GossipKalmanScenario

CODE_MODULES = ("dse.estimators.gossip_kalman", "dse.estimators.switched_riccati", "dse.estimators.walk_detectability",
                "dse.estimators.kalman", "dse.simulate.units", "dse.simulate.seeding", "dse.families.kar_moura.compute")
J_GRID = np.logspace(0, 12, 49)
COUPLING_C = 1e6
PULLBACK_LAW_T = (5, 20, 100)
PULLBACK_PATH_T = (16, 32, 64, 128, 256)
WITNESS_MAX_LEN = 6
STAT_STRIDE = 5
EPS = float(np.finfo(float).eps)
#: filterpy (the oracle of our centralized recursion) is run over the first slots only: the claim compares two
#: recursions, and filterpy inverts an N m x N m innovation covariance per step
FILTERPY_STEPS = 300
ABAR_DRAWS = 200_000  # Monte Carlo Ā when no exact form is feasible (greedy matching on a large graph)


def mean_adjacency(sc: GossipKalmanScenario) -> tuple[np.ndarray, np.ndarray, bool, int]:
    """(Ā, standard error of each entry, exact?, draws). Closed forms for single-edge, node-initiated
    and user-given matchings; the greedy-matching protocol (P4) is exact on small graphs (recursion
    over edge sets) and a Monte Carlo estimate otherwise. Where Ā is estimated, the Theorem-8
    chains are driven by the protocol itself (sampler S3) and the claims that need the exact Ā are
    not checked (an estimated Ā would bias the invariant law)."""
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
    """sample(size, steps, rng, start=None, lazy=False) -> (size, steps) Ā-chain paths (a LazyChain, read
    column by column, with `lazy`): from Ā (S1) when it is exact, else driven by an independent copy of the
    protocol (S3)."""
    if bool(bounds["Abar_exact"]):
        Abar = bounds["Abar"]
        return lambda size, steps, rng, start=None, lazy=False: sr.sample_chain(Abar, size, steps, rng, start=start,
                                                                               lazy=lazy)
    protocol = sc.protocol.build(sc.graph)
    return lambda size, steps, rng, start=None, lazy=False: sr.sample_protocol_chain(protocol, size, steps, rng,
                                                                                    start=start, lazy=lazy)


@dataclass
class ScenarioDesign:
    """The deterministic quantities of one scenario (no Monte Carlo): the hypotheses' decisions
    (`assume`) and the `bounds` stage (Ā, spectra, witness walks and the constants of the bounds, the
    centralized filter, the class floors, the Lyapunov envelope)."""

    scenario: GossipKalmanScenario
    slots: int
    runs: int
    reference_runs: int
    quick: bool
    assume: "Assumptions"
    bounds: dict[str, np.ndarray]

    @property
    def name(self) -> str:
        return self.scenario.name

    @property
    def c1(self) -> bool:
        return bool(self.bounds["c1"])

    @property
    def d1(self) -> bool:
        """D.1 holds (decided); False when it fails or cannot be decided."""
        return bool(self.bounds["d1"])

    def witness(self) -> tuple[int, ...] | None:
        w = self.bounds["witness"]
        return tuple(int(x) for x in w) if len(w) else None


@dataclass
class ScenarioResults(ScenarioDesign):
    seed: int = 0
    gikf: dict[str, np.ndarray] = field(default_factory=dict)
    reference: dict[str, np.ndarray] = field(default_factory=dict)
    aux: dict[str, np.ndarray] = field(default_factory=dict)
    comparison: dict[str, np.ndarray] | None = None
    eq74: dict[str, np.ndarray] | None = None        # the margins of claim eq74 (a stage when the claim is made)

    def design(self) -> ScenarioDesign:
        return ScenarioDesign(self.scenario, self.slots, self.runs, self.reference_runs, self.quick, self.assume,
                              self.bounds)


@dataclass
class Design:
    """The design of every scenario of a run (what `dse check` computes; hypotheses evaluate on it)."""

    quick: bool
    scenarios: dict[str, ScenarioDesign]

    def get(self, name: str) -> ScenarioDesign | None:
        return self.scenarios.get(name)


@dataclass
class Results:
    seed: int
    quick: bool
    scenarios: dict[str, ScenarioResults]

    def get(self, name: str) -> ScenarioResults | None:
        return self.scenarios.get(name)

    def design(self) -> Design:
        return Design(self.quick, {k: r.design() for k, r in self.scenarios.items()})


def sizes(sc: GossipKalmanScenario, opts: RunOptions) -> tuple[int, int, int]:
    runs = opts.trials if opts.trials is not None else (sc.quick_runs if opts.quick else sc.runs)
    ref = sc.quick_reference_runs if opts.quick else sc.reference_runs
    if opts.trials is not None:
        ref = max(ref, runs)
    slots = sc.quick_slots if opts.quick else sc.slots
    return runs, ref, slots


def record_times(sc: GossipKalmanScenario, slots: int) -> list[int]:
    return sorted({t for t in sc.record_times if t <= slots} | {slots} | {t for t in PULLBACK_LAW_T if t <= slots})


# -- assumptions (deterministic, shared by the claim catalogue, the stage gating and the hypotheses) --------

@dataclass(frozen=True)
class Assumptions:
    """The theorems' hypotheses decided for one scenario from the support of Ā.

    `d1.holds` and `undetectable` may be None: undecided in floating point (see
    `walk_detectability`). `blind[c]` lists the eigenvalues |λ| ≥ 1 that class c of Ā cannot see,
    or None when its unobservable subspace is undecided; `rate` is the largest 2 log|λ| over them
    (the growth rate of the covariance of a blind class, 0 when none grows exponentially)."""

    c1: bool
    irreducible: bool
    aperiodic: bool
    classes: tuple[tuple[int, ...], ...]
    d1: wd.D1Decision
    blind: tuple[tuple[complex, ...] | None, ...]
    exact_abar: bool
    central_detectable: bool | None
    rate: float

    @property
    def undetectable(self) -> bool | None:
        """Some class of Ā cannot detect an eigenvalue |λ| ≥ 1 (True), none can't (False), undecided (None)."""
        if any(b for b in self.blind if b):
            return True
        return None if any(b is None for b in self.blind) else False

    @property
    def theorem(self) -> bool:
        """C.1 and D.1 hold (S.1 always does: validation requires Q ≻ 0)."""
        return self.c1 and self.d1.holds is True


def assumptions(sc: GossipKalmanScenario) -> Assumptions:
    sys_ = sc.system()
    S = support_matrix(sc)
    chk = wd.check_chain(S)
    d1 = wd.decide_d1(sys_, S, chk.classes, chk.c1, max_len=WITNESS_MAX_LEN)
    blind, rate = [], 0.0
    for cls in chk.classes:
        lam, found = wd.unobservable_modes(sc.F, sys_.C[list(cls)].reshape(-1, sc.M))
        unseen = [complex(x) for x in found if abs(x) >= 1 - 1e-12]
        rate = max([rate] + [2 * float(np.log(abs(x))) for x in unseen])
        blind.append(None if lam is None else tuple(unseen))
    central, _ = wd.unobservable_modes(sc.F, sys_.C_all)
    central_detectable = None if central is None else not any(abs(x) >= 1 - 1e-12 for x in central)
    protocol = sc.protocol.build(sc.graph)
    exact = not isinstance(protocol, gk.GreedyMatchingGossip) or _exact_greedy_mean(protocol) is not None
    return Assumptions(chk.c1, chk.irreducible, chk.aperiodic, chk.classes, d1, tuple(blind), exact, central_detectable,
                       rate)


# -- bounds -----------------------------------------------------------------------------------------

def _centralized(F, C, Q, R, P0, steps: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Prior covariances, update gains and the first-order round-off bound of a centralized filter
    (Joseph form, `riccati_roundoff` carried along the recursion)."""
    cov = kal.kalman_covariances(F, C, Q, R, P0, steps)
    E = np.zeros_like(cov.P_prior)
    r_min = float(np.linalg.eigvalsh(R)[0])
    for t in range(steps - 1):
        delta, G = gk.riccati_roundoff(cov.P_prior[t], cov.gains[t], C, R, F, Q, r_min=r_min)
        E[t + 1] = gk.propagate_error(E[t], G, delta)
    return cov.P_prior, cov.gains, gk.error_norm(E)


def compute_bounds(sc: GossipKalmanScenario, slots: int, assume: Assumptions, *, checks: bool = True) -> dict[str, np.ndarray]:
    """The design quantities of a scenario over `slots` slots; with `checks`, also the independent computations
    that only claims use (filterpy's centralized filter, the lifted chain's stationary law)."""
    sys_ = sc.system()
    Abar, Abar_se, Abar_exact, Abar_draws = mean_adjacency(sc)
    chk = wd.check_chain(Abar)
    out: dict[str, Any] = {"Abar": Abar, "Abar_se": Abar_se, "Abar_exact": Abar_exact, "Abar_draws": Abar_draws,
                           "irreducible": assume.irreducible, "aperiodic": assume.aperiodic, "c1": assume.c1,
                           "n_classes": len(assume.classes), "unit_multiplicity": chk.unit_multiplicity, "slem": chk.slem,
                           "min_eig_Abar": chk.min_eig, "tv": wd.tv_to_uniform(Abar, 200),
                           "Abar_eigenvalues": np.linalg.eigvalsh(0.5 * (Abar + Abar.T)),
                           "random_protocol": sc.protocol.random, "slots": slots}
    labels = np.zeros(sc.N, dtype=np.int64)
    for c, cls in enumerate(assume.classes):
        labels[list(cls)] = c
    out["class_of"] = labels
    F = sc.F
    out["sensor_detectable"] = np.array([not wd.pbh_undetectable(F, sys_.C[n]) for n in range(sc.N)])
    out["central_detectable"] = bool(assume.central_detectable)
    out["central_observable"] = wd.observable(F, sys_.C_all) is True
    ratios = wd.singular_ratios(wd.observability_matrix(F, sys_.C_all), sc.M)
    out["observability_rank"] = int((ratios > wd.SINGULAR_RATIO).sum())
    out["observability_ratio"] = float(ratios[-1])
    out["class_observability_rank"] = np.array([
        int((wd.singular_ratios(wd.observability_matrix(F, sys_.C[list(cls)].reshape(-1, sc.M)), sc.M)
             > wd.SINGULAR_RATIO).sum()) for cls in assume.classes])
    rates = np.zeros(sc.N)
    for cls, unseen in zip(assume.classes, assume.blind):
        rates[list(cls)] = max([0.0] + [2 * np.log(abs(x)) for x in (unseen or ())])
    out["divergence_rate"] = rates  # growth rate of log tr P̂ per slot where a class cannot see |λ| > 1
    out["blind"] = np.array([bool(b) for b in assume.blind])[labels]
    search = assume.d1.search
    out["d1"] = assume.d1.holds is True
    out["d1_decided"] = assume.d1.holds is not None
    out["d1_certificate_ratio"] = float(assume.d1.certificate_ratio)
    out["d1_covering"] = search.witness is not None and assume.irreducible
    out["witness"] = np.array(search.witness if search.witness else [], dtype=np.int64)
    out["witness_ratio"] = float(search.ratio)
    out["witness_max_rank"] = search.max_rank
    out["walks_checked"] = search.walks_checked
    out["q_pd"] = bool(np.linalg.eigvalsh(sc.Q).min() > 0)
    out["alpha"] = float(np.linalg.norm(F, 2))
    out["qnorm"] = float(np.linalg.norm(sc.Q, 2))
    out["accurate_range"] = accurate_range(sc)
    if search.witness is not None:
        _witness_bounds(out, sys_, search, Abar, Abar_exact, slots, checks)
    # centralized reference (same P0): our recursion with its round-off bound, filterpy, and the DARE
    P_c, K_c, err_c = _centralized(F, sys_.C_all, sc.Q, sys_.R_all, sc.P0, slots + 1)
    out["P_central"], out["K_central"], out["P_central_err"] = P_c, K_c, err_c
    if checks:
        out["P_central_filterpy"] = _filterpy_prior(sc, sys_, min(slots, FILTERPY_STEPS) + 1)
    if assume.central_detectable:
        out["P_central_inf"] = kal.steady_state_prior_covariance(F, sys_.C_all, sc.Q, sys_.R_all)
    # the lower bound of each sensor: the centralized filter of its class (tokens never leave a class), one per class
    floor, floor_err = np.empty((slots + 1, len(assume.classes), sc.M, sc.M)), np.empty((slots + 1, len(assume.classes)))
    for c, cls in enumerate(assume.classes):
        idx = list(cls)
        if len(assume.classes) == 1:
            Pk, ek = P_c, err_c
        else:
            with np.errstate(over="ignore", invalid="ignore"):
                Pk, _, ek = _centralized(F, sys_.C[idx].reshape(-1, sc.M), sc.Q, scipy.linalg.block_diag(*sys_.R[idx]),
                                         sc.P0, slots + 1)
        floor[:, c], floor_err[:, c] = Pk, ek
    out["P_floor"], out["P_floor_err"] = floor, floor_err
    out["envelope_log"], out["envelope"], out["envelope_err"] = lyapunov_envelope(F, sc.Q, sc.P0, slots)
    return {k: np.asarray(v) for k, v in out.items()}


def lyapunov_envelope(F: np.ndarray, Q: np.ndarray, P0: np.ndarray, slots: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """f_0^t(P0), t = 0..slots (eq (73)), rescaled: (log s_t, E_t, e_t) with f_0^t(P0) = s_t E_t, ‖E_t‖ = 1
    (or E_t = 0 when P0 = 0 at t = 0), and e_t a bound of the round-off of E_t (relative to s_t). The scaled
    recursion E' = (F E Fᵀ + Q/s_t)/‖·‖ stays finite over any horizon, however fast F grows."""
    M = F.shape[0]
    logs, units, errs = np.empty(slots + 1), np.empty((slots + 1, M, M)), np.empty(slots + 1)
    n0 = float(np.linalg.norm(P0, 2))
    logs[0], units[0] = (math.log(n0), P0 / n0) if n0 > 0 else (0.0, np.zeros((M, M)))
    # the rescaling rounds too: each division by the norm (eps relative), and exp(log s_t) carries the rounding of
    # log s_t, eps·|log s_t| relative
    E_err = EPS * np.eye(M)
    errs[0] = float(gk.error_norm(E_err)) + M * EPS * (2 + abs(logs[0]))
    for t in range(slots):
        Qs = math.exp(-logs[t]) * Q
        delta, G = gk.lyapunov_roundoff(units[t], F, Qs)
        Y = gk.lyapunov_step(units[t], F, Qs)
        norm = float(np.linalg.norm(Y, 2))
        E_err = gk.propagate_error(E_err, G, delta) / norm + EPS * np.eye(M)
        logs[t + 1], units[t + 1] = logs[t] + math.log(norm), Y / norm
        errs[t + 1] = float(gk.error_norm(E_err)) + M * EPS * (2 + abs(logs[t + 1]))
    return logs, units, errs


def envelope_matrix(bounds: dict, t: int) -> np.ndarray:
    """f_0^t(P0) from the rescaled envelope (inf entries where it leaves float64)."""
    with np.errstate(over="ignore"):
        return np.exp(float(bounds["envelope_log"][t])) * bounds["envelope"][t]


def envelope_error(bounds: dict, t: int) -> float:
    with np.errstate(over="ignore"):
        return float(np.exp(float(bounds["envelope_log"][t])) * float(bounds["envelope_err"][t]))


def _witness_bounds(out: dict, sys_: gk.GossipSystem, search: wd.WitnessSearch, Abar: np.ndarray, Abar_exact: bool,
                    slots: int, checks: bool) -> None:
    """Lemma 14's constant along the witness and every witness window, and Lemma 15's tail bounds."""
    w = search.witness
    out["gramian"] = search.gramian
    out["gramian_weighted"] = Gt = wd.walk_gramian(sys_, w, weighted=True)
    out["gramian_cond"] = float(np.linalg.cond(Gt))
    out["sigma_sub"] = wd.sigma_sub(sys_, w)
    out["sigma_sub_printed"] = wd.sigma_sub_printed(sys_, w)
    cs = np.array([1e2, 1e4, 1e6, 1e8])
    out["g_of_cI_c"] = cs
    out["g_of_cI"] = np.array([wd.compose_walk(sys_, w, c * np.eye(sys_.M)) for c in cs])
    alpha0 = float(np.linalg.eigvalsh(out["sigma_sub"])[-1])
    out["alpha0"] = alpha0
    windows = search.windows
    out["n_windows"] = len(windows) if search.windows_complete else -1
    a0_multi = max(float(np.linalg.eigvalsh(wd.sigma_sub(sys_, v))[-1]) for v in windows) if windows else np.nan
    out["alpha0_multi"] = a0_multi
    ks = np.array([wd.k_of_J(out["alpha"], alpha0, out["qnorm"], J) for J in J_GRID])
    ell = len(w)
    out["kJ"] = ks
    # β needs the exact Ā (an estimated Ā gives an estimated bound): NaN marks "not computed"
    # (every J from one propagation up to the longest path; k(J) < 0: bound 1)
    out["beta_single"] = (np.where(ks >= 0, wd.tail_bounds_single(Abar, w, np.minimum(slots, ks + ell)), 1.0)
                          if Abar_exact else np.full(len(ks), np.nan))
    small = sys_.N ** max(ell - 1, 0) <= 2000 and Abar_exact and windows
    km = np.array([wd.k_of_J(out["alpha"], a0_multi, out["qnorm"], J) for J in J_GRID]) if windows else ks
    out["beta_multi"] = (np.where(km >= 0, wd.tail_bounds_multi(Abar, windows, np.minimum(slots, km + ell)), 1.0)
                         if small else np.full(len(km), np.nan))
    support = (Abar > 1e-12).astype(float)
    n_windows = float(np.linalg.matrix_power(support, ell - 1).sum())
    out["n_walks_length_ell"] = n_windows
    if checks and n_windows <= 5000 and Abar_exact:
        Z, pi, corr, printed = wd.lifted_chain_stationary(Abar, ell)
        out["lifted_pi"], out["lifted_corrected"], out["lifted_printed"] = pi, corr, printed
        out["lifted_states"] = len(Z)


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

def nees_slots(slots: int) -> list[int]:
    """Three slots (early, middle, last) at which the per-run NEES is kept for the exact χ² tests."""
    return sorted({max(1, slots // 3), max(1, (2 * slots) // 3), slots})


def simulate_gikf_stage(sc: GossipKalmanScenario, bounds: dict, seed: int, runs: int, slots: int,
                        which: str = "protocol", budget_bytes: float = 192 * 2**20) -> dict[str, np.ndarray]:
    """The GIKF Monte Carlo in RNG units of 1,000 runs, as many per chunk as `budget_bytes` allows: every
    statistic is made per unit and folded in unit order, so the numbers do not depend on the budget. The
    first unit carries the Loewner margins (with their round-off bounds) and the sample runs."""
    from .cost import gikf_bytes_per_run

    spec = sc.protocol if which == "protocol" else sc.comparison
    protocol = spec.build(sc.graph)
    sys_ = sc.system()
    done = [0]

    def chunk(streams):
        first = done[0] == 0
        done[0] += len(streams.sizes)
        acc = gk.standard_accumulators(sys_, slots, record_times=record_times(sc, slots), P_central=bounds["P_central"],
                             envelope=bounds["envelope"],
                             envelope_log=bounds["envelope_log"], envelope_err=bounds["envelope_err"], j_grid=J_GRID,
                             n_paths=sc.sample_paths, check=first, paths=first,
                             nees_window=(max(1, min(20, slots // 3)), min(60, slots)), stat_stride=STAT_STRIDE,
                             P_floor=bounds["P_floor"], floor_index=bounds["class_of"], floor_err=bounds["P_floor_err"],
                             nees_slots=nees_slots(slots), x0=sc.x0)
        return gk.gikf_units(sys_, protocol, list(zip(streams.generators, streams.sizes)), slots,
                             K_central=bounds["K_central"], accumulators=acc)

    acc = run_units(chunk, gk.fold_gikf, runs, stream_seed(seed, sc.name, "gikf", which),
                    bytes_per_trial=gikf_bytes_per_run(sc, slots, spec), budget_bytes=budget_bytes)
    return gk.finish_gikf(acc)


def reference_stage(sc: GossipKalmanScenario, bounds: dict, seed: int, ref_runs: int, slots: int) -> dict[str, np.ndarray]:
    """Theorem-8 process from P0 (sampler S1) with its last switch at each record time; the chain is drawn
    slot by slot (memory does not grow with the horizon)."""
    sys_ = sc.system()
    rng = block_generator(stream_seed(seed, sc.name, "theorem8"))
    path = chain_sampler(sc, bounds)(ref_runs, slots, rng, lazy=True)
    out = sr.switched_riccati(sys_, path, sc.P0, record_times(sc, slots), keep_final=True)
    return out


def restart_slot(Abar: np.ndarray, slots: int, tokens: list[int]) -> tuple[int, np.ndarray]:
    """s for the finite-horizon form of Theorem 10[ii] ((72)-(84)): the first s ≤ T/2 at which the
    tokens' chains are within 1e-3 of uniform in total variation (else T/2), and d_v(p_n(s), U)."""
    N = len(Abar)
    P = np.eye(N)[tokens]
    for s in range(slots // 2 + 1):
        dv = 0.5 * np.abs(P - 1.0 / N).sum(axis=1)
        if dv.max() <= 1e-3 or s == slots // 2:
            return s, dv
        P = P @ Abar
    return slots // 2, dv


def theorem_aux_stage(sc: GossipKalmanScenario, bounds: dict, seed: int, ref_runs: int, slots: int) -> dict[str, np.ndarray]:
    """Samples that only the theorem's conclusions use (run where C.1 and D.1 hold): other initial laws
    (Theorem 8), tokens from fixed sensors and the restarted stationary process Q^s(T) (Theorem 10[ii]),
    forward coupling (burn-in), pull-back (Lemma 23, Theorem 26(b)). Copies started at c·I with c ≫ 1
    run in square-root form, which stays accurate and finite however large the iterates get."""
    sys_ = sc.system()
    chain = chain_sampler(sc, bounds)
    M = sc.M
    times = record_times(sc, slots)
    half = max(ref_runs // 2, 100)
    out: dict[str, np.ndarray] = {}
    rng = block_generator(stream_seed(seed, sc.name, "aux"))
    from scipy.stats import wishart     # here: `dse list` and `dse check` import this module

    wish = wishart(df=M + 2, scale=np.eye(M)).rvs(size=half, random_state=rng.integers(2**31)).reshape(half, M, M)
    out["wishart_lam_max"] = np.linalg.eigvalsh(wish)[:, -1]
    c = max(COUPLING_C, 10.0 * float(np.linalg.norm(sc.P0, 2)))  # the sandwich 0 ⪯ X0 ⪯ cI must contain P0
    out["coupling_c"] = np.array(c)
    for label, X0 in (("zero", np.zeros((M, M))), ("huge", c * np.eye(M)), ("wishart", wish)):
        path = chain(half, slots, rng, lazy=True)
        sqrt = float(np.max(np.linalg.norm(X0, 2, axis=(-2, -1)))) > accurate_range(sc)  # Joseph where it is accurate
        run = sr.switched_riccati(sys_, path, X0, [slots], sqrt=sqrt, track_error=not sqrt)
        out[f"init_{label}"] = run["features"][0]
        out[f"init_{label}_err"] = run["err"][0] if not sqrt else np.zeros(half)
    tokens = sorted({0, min(1, sc.N - 1)})
    for n in tokens:
        path = chain(half, slots, rng, start=n, lazy=True)
        tok = sr.switched_riccati(sys_, path, sc.P0, times, track_error=True)
        out[f"token{n}"], out[f"token{n}_err"] = tok["features"], tok["err"][-1]
    if bool(bounds["Abar_exact"]):
        s, dv = restart_slot(bounds["Abar"], slots, tokens)
        path = chain(half, slots - s, rng, lazy=True)
        out["restart_s"], out["restart_dv"] = np.array(s), dv
        # the same arithmetic as the tokens (Joseph form) unless f_0^s(P0) is beyond its accurate range
        start = envelope_matrix(bounds, s)
        huge = float(bounds["envelope_log"][s]) > math.log(accurate_range(sc))
        rs = sr.switched_riccati(sys_, path, start, [slots - s], sqrt=huge, track_error=not huge)
        out["restart"] = rs["features"][0]
        out["restart_err"] = rs["err"][0] + envelope_error(bounds, s) if not huge else np.zeros(half)
    cpl_times = [t for t in (10, 20, 40, 80, 160, 320) if t <= slots] or [slots]
    path = chain(min(2000, ref_runs), slots, rng, lazy=True)
    out["coupling_times"] = np.array(cpl_times)
    gaps = sr.coupling_gap(sys_, path, c, sorted(set(cpl_times) | {slots}))
    out["coupling"] = gaps[[sorted(set(cpl_times) | {slots}).index(t) for t in cpl_times]]
    out["coupling_final"] = gaps[-1]
    law_T = [t for t in PULLBACK_LAW_T if t <= slots]
    if law_T:
        back = chain(half, max(law_T), rng)  # Ā symmetric: the reversed stationary chain is again a Ā-chain
        pb = sr.pullback(sys_, back, sc.P0, law_T)
        out["pullback_law_T"] = np.array(law_T)
        out["pullback_law"] = np.array([gk.covariance_features(x) for x in pb])
    path_T = [t for t in PULLBACK_PATH_T if t <= max(64, 2 * slots)]  # pathwise convergence: a few horizon doublings
    back = chain(500, max(path_T), rng)
    lo, err = sr.pullback(sys_, back, np.zeros((M, M)), path_T, with_error=True)
    hi = sr.pullback(sys_, back, c * np.eye(M), path_T, sqrt=True)
    _pullback_paths(out, lo, err, path_T)
    out["pullback_gap"] = np.linalg.norm(hi - lo, 2, axis=(-2, -1)) / out["pullback_lo_norm"]
    return out


def _pullback_paths(out: dict, lo: np.ndarray, err: np.ndarray, path_T: list[int]) -> None:
    """Pull-backs L_T from 0 with their round-off bounds: norms, relative changes between horizons, and
    λ_min(L_T' − L_T) (≥ 0 in exact arithmetic: f monotone and f(0) = Q ⪰ 0, so L_T grows with T)."""
    out["pullback_path_T"] = np.array(path_T)
    out["pullback_lo_norm"] = np.linalg.norm(lo, 2, axis=(-2, -1))
    out["pullback_err"] = err
    steps = np.diff(lo, axis=0)
    out["pullback_step"] = np.linalg.norm(steps, 2, axis=(-2, -1)) / out["pullback_lo_norm"][1:]
    out["pullback_monotone"] = np.linalg.eigvalsh(steps)[..., 0]
    out["pullback_monotone_err"] = err[1:] + err[:-1]


def divergent_pullback_stage(sc: GossipKalmanScenario, bounds: dict, seed: int) -> dict[str, np.ndarray]:
    """Theorem 26, alternative (a) (run where C.1 holds and a mode |λ| ≥ 1 is unseen): pull-backs from 0
    along 500 backward paths and the centralized filter from 0 (a pathwise lower bound of every
    pull-back), both in Joseph form with their round-off bounds, at the horizons whose pull-backs stay
    inside the range where the Joseph form is accurate (`accurate_range`)."""
    sys_ = sc.system()
    rng = block_generator(stream_seed(seed, sc.name, "pullback-divergent"))
    horizons = (4, 8, 16, 32, 64, 128, 256)
    back = chain_sampler(sc, bounds)(500, max(horizons), rng)
    limit = accurate_range(sc)
    kept, lows, errs = [], [], []
    with np.errstate(all="ignore"):
        for T in horizons:
            lo, err = sr.pullback(sys_, back, np.zeros((sc.M, sc.M)), [T], with_error=True)
            if not (np.all(np.isfinite(lo)) and np.linalg.norm(lo, 2, axis=(-2, -1)).max() <= limit):
                break
            kept.append(T)
            lows.append(lo[0])
            errs.append(err[0])
    out: dict[str, np.ndarray] = {"pullback_range": np.array(limit)}
    if len(kept) < 2:
        out["pullback_path_T"] = np.array(kept, dtype=np.int64)
        return out
    lo, err = np.array(lows), np.array(errs)
    _pullback_paths(out, lo, err, kept)
    Pc, _, ec = _centralized(sc.F, sys_.C_all, sc.Q, sys_.R_all, np.zeros((sc.M, sc.M)), max(kept) + 1)
    out["central_from_zero"] = Pc[kept]
    out["central_from_zero_err"] = ec[kept]
    out["pullback_vs_central"] = np.linalg.eigvalsh(lo - Pc[kept][:, None])[..., 0]   # (len(kept), 500)
    return out


GIKF_PARTIAL = ("margins", "slack", "feat_q", "feat_n", "quantiles", "path_trace", "path_err", "path_err_c", "nees_q",
                "nees_c", "path_state", "nees", "nees_run", "final_sum", "final_sq")
#: round-off bounds may exceed float64 (a bound that large says only that nothing is resolved: an infinite allowance)
ERROR_BOUNDS = ("final_err", "pullback_err", "pullback_monotone_err", "central_from_zero_err", "token0_err", "token1_err",
                "restart_err", "init_zero_err", "init_huge_err", "init_wishart_err")
BOUNDS_PARTIAL = ("beta_multi", "beta_single", "lifted_printed", "alpha0_multi", "envelope", "envelope_err", "P_floor",
                  "P_floor_err", "P_central", "P_central_err", "P_central_filterpy")


def _stage(cache: StageCache, key: dict, name: str, fn, scenario: str = "", allow: tuple[str, ...] = ()):
    return cache.get_or_compute(name, {**key, "stage": name}, fn, scenario=scenario, allow_nonfinite=allow)


def _checked_gikf(fn, scenario: str):
    """GIKF stage: NaN marks slots not evaluated (stride) in 'margins' and 'slack' and, after a float
    overflow (a divergence, reported by the claims with its slot), the unreached slots; anything else
    non-finite is an error."""
    def run():
        out = fn()
        if int(out["overflow"]) < 0:
            # the sample runs' states grow with an unstable F (their estimates are the states minus the errors)
            check_finite({k: v for k, v in out.items() if k not in ("margins", "slack", "nees_q", "nees_c", "path_state")},
                         stage="gikf", scenario=scenario)
        return out
    return run


FLOAT_LOG_BUDGET = 600.0  # log of the largest covariance entry an iterate may reach (float64: ~709)


def accurate_range(sc: GossipKalmanScenario) -> float:
    """The largest ‖X‖ at which the Joseph form still resolves every sensor's innovation variance:
    C X Cᵀ carries a round-off of ~eps‖X‖‖C‖², kept below 1e-3 λ_min(R) (so a direction that a sensor
    does not see, not along a coordinate axis, cannot make C X Cᵀ + R lose its R)."""
    sys_ = sc.system()
    seen = [n for n in range(sc.N) if np.abs(sys_.C[n]).max() > 0]
    if not seen:
        return math.exp(FLOAT_LOG_BUDGET)
    r_min = min(float(np.linalg.eigvalsh(sys_.R[n])[0]) for n in seen)
    c_max = max(float(np.linalg.norm(sys_.C[n], 2)) ** 2 for n in seen)
    return min(math.exp(FLOAT_LOG_BUDGET), 1e-3 * r_min / (EPS * c_max))


def horizon(sc: GossipKalmanScenario, slots: int, assume: Assumptions) -> int:
    """Where a class of Ā cannot see a mode |λ| > 1, its covariances grow like |λ|^(2t): simulate only
    while they stay inside the range where the Joseph form is accurate (`accurate_range`)."""
    rate = assume.rate
    if rate <= 0:
        return slots
    start = max(1.0, float(np.linalg.norm(sc.P0, 2)), float(np.linalg.norm(sc.Q, 2)))
    budget = math.log(accurate_range(sc) / start)
    return int(min(slots, max(10, budget // rate)))


def scenario_design(sc: GossipKalmanScenario, opts: RunOptions, *, checks: bool = False,
                    cache: StageCache | None = None) -> ScenarioDesign:
    """Sizes, hypotheses and the bounds stage of one scenario (through the stage cache when given)."""
    assume = assumptions(sc)
    runs, ref_runs, slots = sizes(sc, opts)
    slots = horizon(sc, slots, assume)
    if cache is None:
        bounds = compute_bounds(sc, slots, assume, checks=checks)
    else:
        base = {"scenario": sc.key(), "code": code_fingerprint(CODE_MODULES), "slots": slots}
        bounds = _stage(cache, base, "bounds", lambda: compute_bounds(sc, slots, assume, checks=True), sc.name,
                        BOUNDS_PARTIAL)
    return ScenarioDesign(sc, slots, runs, ref_runs, opts.quick, assume, bounds)


def eq74_stage(sc: GossipKalmanScenario, bounds: dict, slots: int) -> dict[str, np.ndarray]:
    """The Riccati sequences of claim eq74 (its own fixed random stream), computed with the Monte Carlo."""
    from .claims import eq74_margins

    return eq74_margins(sc, bounds, slots)


def scenario_stages(d: ScenarioDesign, opts: RunOptions, cache: StageCache, *,
                    structural: bool = True) -> dict[str, tuple[float, Any]]:
    """The Monte Carlo stages of one scenario, given its design: name -> (estimated seconds, callable). They are
    independent of each other (each has its own random stream), so they may run in any order or process.
    `structural`: the scenario gets the structural claims (then the Riccati sequences of eq74 are a stage too)."""
    from .cost import scenario_cost

    sc, runs, ref_runs, slots, assume, bounds = d.scenario, d.runs, d.reference_runs, d.slots, d.assume, d.bounds
    cost = scenario_cost(sc, opts, assume)
    budget = opts.chunk_budget_bytes()
    mc = {"scenario": sc.key(), "code": code_fingerprint(CODE_MODULES), "slots": slots, "seed": opts.seed,
          "runs": runs, "ref_runs": ref_runs}

    def gikf(which: str):
        return functools.partial(_stage, cache, mc, "gikf" if which == "protocol" else "gikf_comparison",
                                 _checked_gikf(lambda: simulate_gikf_stage(sc, bounds, opts.seed, runs, slots, which,
                                                                           budget_bytes=budget), sc.name),
                                 sc.name, GIKF_PARTIAL)

    stages: dict[str, tuple[float, Any]] = {"gikf": (cost["gikf_s"] / (2 if sc.comparison is not None else 1),
                                                     gikf("protocol"))}
    if sc.comparison is not None:
        stages["comparison"] = (stages["gikf"][0], gikf("comparison"))
    stages["reference"] = (cost["ref_s"], functools.partial(
        _stage, cache, mc, "theorem8", lambda: reference_stage(sc, bounds, opts.seed, ref_runs, slots), sc.name,
        ERROR_BOUNDS))
    if assume.theorem:
        stages["aux"] = (cost["aux_s"], functools.partial(
            _stage, cache, mc, "aux", lambda: theorem_aux_stage(sc, bounds, opts.seed, ref_runs, slots), sc.name,
            ERROR_BOUNDS))
    if assume.c1 and assume.undetectable is True:
        stages["pullback_divergent"] = (cost["pullback_s"], functools.partial(
            _stage, cache, mc, "pullback_divergent", lambda: divergent_pullback_stage(sc, bounds, opts.seed), sc.name,
            ERROR_BOUNDS))
    if structural:
        key = {"scenario": sc.key(), "code": code_fingerprint(CODE_MODULES + ("dse.families.kar_moura.claims",)),
               "slots": slots}
        stages["eq74"] = (EQ74_S_PER_STEP * min(slots, 120) * sc.M ** 2, functools.partial(
            _stage, cache, key, "eq74", lambda: eq74_stage(sc, bounds, slots), sc.name, ("slack", "raw", "gap")))
    return stages


#: seconds per slot and M² of the eq74 sequences (2 tokens × 500 paths × up to 7 restarts): E1 0.5 s at 120 slots
EQ74_S_PER_STEP = 1e-3


def _results(d: ScenarioDesign, opts: RunOptions, out: dict[str, Any]) -> ScenarioResults:
    aux: dict[str, np.ndarray] = {**out.get("aux", {}), **out.get("pullback_divergent", {})}
    return ScenarioResults(d.scenario, d.slots, d.runs, d.reference_runs, opts.quick, d.assume, d.bounds, seed=opts.seed,
                           gikf=out["gikf"], reference=out["reference"], aux=aux, comparison=out.get("comparison"),
                           eq74=out.get("eq74"))


def compute(scenarios: list[GossipKalmanScenario], opts: RunOptions, cache: StageCache, *,
            structural: Collection[str] | None = None, costs: dict[str, dict] | None = None) -> Results:
    """Every scenario's design, then every Monte Carlo stage of every scenario, each as one job of `opts.workers`
    forked processes, the heaviest first (by the cost model of `dse check`): the light ones fill in around them, and
    a single scenario's stages run side by side. `structural`: the scenarios that get the structural claims (all when
    None); `costs`: `cost.scenario_cost` of each scenario when known."""
    from .cost import scenario_cost

    # imported once here and inherited by every forked worker (about 1 s each): the designs' filterpy reference,
    # the Wishart starts of the auxiliary stage and the claims' exact KS tests all need scipy.stats
    import filterpy.kalman  # noqa: F401
    import scipy.stats  # noqa: F401

    costs = costs or {sc.name: scenario_cost(sc, opts) for sc in scenarios}
    designs = run_jobs([(costs[sc.name]["design_s"], functools.partial(scenario_design, sc, opts, cache=cache))
                        for sc in scenarios], workers=opts.workers, desc="gossip-kalman designs")
    stages = [(d.name, name, job) for d in designs
              for name, job in scenario_stages(d, opts, cache, structural=structural is None or d.name in structural).items()]
    outs = run_jobs([job for _, _, job in stages], workers=opts.workers, desc="gossip-kalman Monte Carlo")
    done: dict[str, dict[str, Any]] = {d.name: {} for d in designs}
    for (scenario, name, _), out in zip(stages, outs):
        done[scenario][name] = out
    return Results(opts.seed, opts.quick, {d.name: _results(d, opts, done[d.name]) for d in designs})


def design(scenarios: list[GossipKalmanScenario], opts: RunOptions) -> Design:
    """The design of every scenario, without Monte Carlo and without the claims' own reference computations."""
    return Design(opts.quick, {sc.name: scenario_design(sc, opts) for sc in scenarios})


def roles(sc: GossipKalmanScenario) -> dict[str, bool]:
    """Which optional claims a scenario gets: the comparison of two protocols (Remark 9) when the
    scenario names a second protocol."""
    return {"comparison": sc.comparison is not None}
