"""The design stage of the random-comm-filter family: every deterministic quantity the theorems
are made of, without Monte Carlo (what `dse check` prints and what the hypotheses are decided on).

Per scenario: Ā = (1/N)Σ A_i and its spectrum; R of (10), S of (11), the large-rate limit S_true
of the true covariance and the first-order coefficient of (9) in 1/λ; the explicit constants of
(12) (paper-faithful and tight); the critical rates of (9) and of the exact mean covariance; the
Kalman–Bucy reference (steady and from P0); at every simulated λ the transients of (9) and of the
exact mean joint covariance on the output grid and their per-node steady states; the λ sweep of
the steady states, their deviations from S and S_true and the spectral abscissae; the gridded
simulator's step and how it was chosen; and a few clock paths drawn from the seed on which two
independent computations of the per-path covariances are compared (hypothesis `numerics`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy  # scipy.linalg loads on first use (scipy imports submodules lazily): `dse list` skips it

import dse.estimators.gossip_covariance as gc
import dse.estimators.gossip_filter as gf
import dse.estimators.kalman_bucy as kb
from dse.estimators.linear_flows import abscissa_tolerance
from dse.contract.stages import stage
from dse.simulate.seeding import stream_seed
from dse.simulate.units import block_generator

from .scenario import MAX_SWEEP_RATE, RandomCommFile

QUICK_SWEEP_POINTS = 15
#: the λ sweep gets points at these multiples of the explicit threshold λ_thr of (12)
THRESHOLD_MULTIPLES = (1.5, 3.0, 10.0, 30.0, 100.0)
EXPLICIT_FIELDS = ("C0", "C1", "C2", "C3", "a1", "a2", "sigma_G", "sigma1_R", "sigman_R", "kappa", "fiedler", "S_norm",
                   "threshold")
#: clock paths of the `numerics` hypothesis: how many, and how much of the horizon (outputs, expected events)
NUMERICS_PATHS = 3
NUMERICS_OUTPUTS = 200
NUMERICS_EVENTS = 400
#: the sweep's abscissae of the exact covariance generator are computed up to this size (symmetric coordinates);
#: beyond, stability is decided by a linear solve (`gossip_covariance.joint_hurwitz`) and the abscissa is NaN
SWEEP_EIG_MAX = 300
CARE_COND_MAX = 1e8        # relative condition number of the filter CARE above which its solution is not trusted


@dataclass
class ScenarioDesign:
    """The design arrays of one scenario (`bounds`, a dict of arrays as the stage cache stores them)."""

    scenario: RandomCommFile
    bounds: dict[str, np.ndarray]

    @property
    def sys(self) -> gf.GossipSystem:
        return self.scenario.gossip

    def bound(self, rate: float) -> np.ndarray:
        return self.bounds[f"bound_t_{self.scenario.rates.index(rate)}"]

    def joint(self, rate: float) -> np.ndarray | None:
        return self.bounds.get(f"joint_t_{self.scenario.rates.index(rate)}")


@dataclass
class Design:
    """Every scenario's design, by name (the object the hypotheses are evaluated on)."""

    scenarios: dict[str, ScenarioDesign]


def joint_ok(sys: gf.GossipSystem) -> bool:
    return sys.N * sys.n <= gc.MAX_JOINT_DIM


def grid_regime(sc: RandomCommFile, rate: float) -> float:
    """h·(max‖A_i‖₂ + λ d_max): the gridded simulator's step against the fastest rate of its flows and jumps."""
    s = sc.gossip
    return float(sc.grid_step * (max(np.linalg.norm(A, 2) for A in s.Ai) + rate * int(s.degrees.max())))


def kalman_bucy_transient(sc) -> np.ndarray:
    """P_KB at the output times (the centralized reference curve); NaN when the CARE has no stabilising
    solution and the Riccati flow is too stiff for the Hamiltonian sub-steps (see `kalman_bucy_riccati`)."""
    s = sc.gossip
    try:
        return kb.kalman_bucy_riccati(s.A, s.B, np.vstack(s.H), scipy.linalg.block_diag(*s.V), s.P0, sc.output_step,
                                      sc.n_outputs)
    except np.linalg.LinAlgError:
        return np.full((sc.n_outputs + 1, s.n, s.n), np.nan)


@stage(name="design", allow_nonfinite=lambda sc, **_: nonfinite_allowed(sc))
def scenario_design(sc: RandomCommFile, quick: bool = False, seed: int = 0) -> dict[str, np.ndarray]:
    """The design arrays of one scenario (quick: a coarser λ sweep)."""
    s = sc.gossip
    N, n = s.N, s.n
    out: dict[str, np.ndarray] = {}
    Hs, Vs = np.vstack(s.H), scipy.linalg.block_diag(*s.V)
    T = sc.n_outputs
    try:
        P_kb, K_kb = kb.kalman_bucy_steady(s.A, s.B, Hs, Vs)
        Ac = s.A - K_kb @ Hs
        if np.all(np.isfinite(P_kb)) and np.max(np.linalg.eigvals(Ac).real) < 0:
            out["P_kb"], out["K_kb"] = P_kb, K_kb
            out["kb_condition"] = np.array(kb.care_condition(s.A, s.B, Hs, Vs, P_kb))
    except (np.linalg.LinAlgError, ValueError):
        pass
    out["P_kb_t"] = kalman_bucy_transient(sc)
    ev = np.linalg.eigvals(s.Abar)
    out["abar_eig"] = np.stack([ev.real, ev.imag], axis=1)
    out["ai_eig"] = np.array([[[z.real, z.imag] for z in np.linalg.eigvals(A)] for A in s.Ai])
    abar = float(np.max(ev.real))
    out["abar_abscissa"] = np.array(abar)
    out["abar_tolerance"] = np.array(abscissa_tolerance(s.Abar))
    out["fiedler"] = np.array(float(np.sort(np.linalg.eigvalsh(s.laplacian))[1]))
    out["laplacian_eig"] = np.linalg.eigvalsh(s.laplacian)
    out["crit_bound"] = np.array(gc.critical_rate_bound(s))
    if joint_ok(s):
        out["crit_joint"] = np.array(gc.critical_rate_joint(s, upper=float(out["crit_bound"])))
    for r, lam in enumerate(sc.rates):
        out[f"bound_t_{r}"] = gc.bound_transient(s, lam, sc.output_step, T)
        out[f"absc_bound_{r}"] = np.array([gc.bound_abscissa(s, lam), gc.bound_abscissa_tolerance(s, lam)])
        p = gc.bound_steady(s, lam)
        out[f"bound_inf_{r}"] = p if p is not None else np.full((N, n, n), np.nan)
        out[f"grid_regime_{r}"] = np.array(grid_regime(sc, lam))
        if joint_ok(s):
            out[f"joint_t_{r}"] = gc.joint_transient(s, lam, sc.output_step, T)
            out[f"absc_joint_{r}"] = np.array(gc.joint_abscissa(s, lam))
            J = gc.joint_steady(s, lam)
            out[f"joint_inf_{r}"] = J if J is not None else np.full((N * n, N * n), np.nan)
    hurwitz = abar < -float(out["abar_tolerance"])
    if hurwitz:
        out["S"], out["R"] = gc.lyapunov_S(s), gc.lyapunov_R(s.Abar)
        out["S_true"] = gc.lyapunov_S_true(s)
        out["first_order"] = gc.first_order_deviation(s)
    lo, hi, pts = sc.sweep
    pts = min(pts, QUICK_SWEEP_POINTS) if quick else pts
    lams = np.geomspace(lo, hi, pts)
    extra = []
    if hurwitz:
        for variant in ("faithful", "tight"):
            c = gc.explicit_bound(s, variant)
            out[f"explicit_{variant}"] = np.array([getattr(c, f) for f in EXPLICIT_FIELDS])
            if math.isfinite(c.threshold) and c.threshold > 0:
                extra += [c.threshold * f for f in THRESHOLD_MULTIPLES]
    lams = np.unique(np.concatenate([lams, [x for x in extra if x <= MAX_SWEEP_RATE]]))
    out["sweep"] = lams
    out.update(gc.steady_state_sweep(s, lams, out.get("S"), out.get("S_true"), SWEEP_EIG_MAX))
    out.update(numerics_paths(sc, seed))
    return out


def numerics_times(sc: RandomCommFile) -> np.ndarray:
    """The output times of the `numerics` paths: at most NUMERICS_OUTPUTS steps and about NUMERICS_EVENTS
    expected rings (the per-interval reference costs one matrix exponential per ring), at least one step."""
    s = sc.gossip
    per_step = sc.main_rate * len(s.clocks) * sc.output_step
    k = max(1, min(sc.n_outputs, NUMERICS_OUTPUTS, int(NUMERICS_EVENTS / max(per_step, 1e-300))))
    return sc.output_times[:k + 1]


def numerics_paths(sc: RandomCommFile, seed: int) -> dict[str, np.ndarray]:
    """NUMERICS_PATHS clock paths drawn from the seed at the main rate: the batched propagation of P_i(t; τ)
    and Σ_ii(t; τ) (as the event-driven simulator does it) and a plain per-interval Van Loan computation."""
    s = sc.gossip
    times = numerics_times(sc)
    rng = block_generator(stream_seed(seed, "design-paths", sc.name))
    run = gf.simulate_event_driven(s, sc.main_rate, times, NUMERICS_PATHS, rng, sample=False)
    ref_P, ref_S = [], []
    for p in range(NUMERICS_PATHS):
        t, c = run.event_times[p], run.event_clocks[p]
        P, Sig = gc.path_bound_and_covariance(s, t[c >= 0], c[c >= 0], times)
        ref_P.append(P), ref_S.append(gc.diagonal_blocks(Sig, s.N, s.n))
    return {"numerics_times": times, "numerics_event_times": run.event_times, "numerics_event_clocks": run.event_clocks,
            "numerics_pbound": run.pbound, "numerics_sigma": run.sigma, "numerics_ref_pbound": np.array(ref_P),
            "numerics_ref_sigma": np.array(ref_S), "numerics_condition": np.array(run.condition)}


#: arrays of the design where inf or NaN is a result (a bound that diverges below the critical rate, an explicit
#: bound below its threshold, the padding of event lists)
NONFINITE = ("sweep_bound", "sweep_joint", "sweep_dev_bound", "sweep_dev_joint", "sweep_absc_joint",
             "sweep_explicit_faithful", "sweep_explicit_tight", "crit_bound", "crit_joint", "explicit_faithful",
             "explicit_tight", "P_kb_t", "sweep_dev_err", "sweep_dev_joint_err", "sweep_cond", "numerics_event_times",
             "numerics_pbound", "numerics_sigma", "numerics_ref_pbound", "numerics_ref_sigma", "kb_condition")


def nonfinite_allowed(sc: RandomCommFile) -> tuple[str, ...]:
    per_rate = ("bound_t", "joint_t", "bound_inf", "joint_inf", "absc_bound", "absc_joint")
    return NONFINITE + tuple(f"{k}_{r}" for k in per_rate for r in range(len(sc.rates)))
