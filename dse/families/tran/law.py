"""The stage of the seed: the noise intensities of the stochastic runs and the exact law of the
fixed-role error (60) at the check times (principal directions, the variances of (60) and of the
simulated recursion at h and h/2), the exact covariances at the end of the stochastic horizon and
in the steady state, and the centralized Kalman-Bucy reference; and the constants of Prop 4.1.
"""
from __future__ import annotations

import numpy as np

import dse.estimators.lyapunov_bounds as lb
import dse.estimators.observer_network_simulation as sim
from dse.contract.stages import stage
import dse.estimators.input_state_coestimation as ce
from dse.simulate.seeding import stream_seed

from .design import Design, coestimation, gains, t_stochastic
from .reference import kalman_bucy_reference
from .scenario import CoestimationFile

MAX_CHECK_TIMES = 20       # times at which the fixed-role Monte Carlo is compared with the exact law
N_DIRECTIONS = 3           # principal directions of E{zᵀPz} tested at each of those times
LAW_MAY_BE_NAN = ("probe_dirs", "probe_var", "tr_PSigma", "sim_var_h", "sim_var_half", "Sigma_final", "Sigma_steady",
                  "kb_final", "kb_steady", "steady_ok")

#: step operators (φ-functions and exact noise factors) of the last few (network, noise, step) triples: the
#: exact law and the Monte Carlo at the same step share them (forked workers inherit them)
_STEP_OPERATORS: dict[tuple, sim.Prepared] = {}


def step_operators(sc: CoestimationFile, P: np.ndarray, noise: sim.NoiseModel, h: float) -> sim.Prepared:
    """`sim.prepare` of the coestimation network with these P_i, noise and step, computed once per process."""
    key = (sc.name, repr(sc.key()), P.tobytes(), noise.process.tobytes(), noise.measurement.tobytes(), float(h))
    if key not in _STEP_OPERATORS:
        while len(_STEP_OPERATORS) >= 4:
            _STEP_OPERATORS.pop(next(iter(_STEP_OPERATORS)))
        _STEP_OPERATORS[key] = sim.prepare(coestimation(sc, P), h, noise)
    return _STEP_OPERATORS[key]


def noise_model(sc: CoestimationFile, seed: int) -> sim.NoiseModel:
    """v ~ U(0, v_range)^n (one scalar Brownian motion) and h_i ~ U(0, h_range)^m per node (Sec. 5.2)."""
    rng = np.random.default_rng(stream_seed(seed, "tran", "noise-intensities"))
    v = rng.uniform(0.0, sc.stochastic.process_range, size=sc.n)
    h = rng.uniform(0.0, sc.stochastic.measurement_range, size=(sc.N, sc.m))
    return sim.NoiseModel(v[:, None], h[:, :, None])


def noise_input_matrix(sc: CoestimationFile, noise: sim.NoiseModel, g) -> np.ndarray:
    """G = [1_N ⊗ v̄, blockdiag(r_i)], r_i = g_i [−L_i h_i; J_i h_i] ((44)-(45) with dimensions fixed)."""
    G = gains(sc)
    return ce.noise_input_matrix(G["L"], G["J"], noise.process[:, 0], noise.measurement[:, :, 0], g)


def check_indices(sc: CoestimationFile, t_sde: float) -> np.ndarray:
    """Record indices (t > 0) at which the fixed-role Monte Carlo is compared with the exact law."""
    last = int(round(t_sde / sc.simulation.record_dt))
    stride = max(1, int(np.ceil(last / MAX_CHECK_TIMES)))
    return np.arange(stride, last + 1, stride)


@stage(name="law", allow_nonfinite=LAW_MAY_BE_NAN)
def fixed_law(sc: CoestimationFile, core: dict, seed: int, quick: bool) -> dict[str, np.ndarray]:
    """The noise of the seed and the exact law of the fixed-role error z(t) ~ N(m(t), Σ(t)),
    Σ̇ = SΣ + ΣSᵀ + GGᵀ, Σ(0) = 0 ((45), (60)); m is the noise-free run (a simulation, not here).

    tr(PΣ) at every record time of the stochastic horizon; Σ at its end and (S Hurwitz) in the steady
    state, per node block; at the check times the principal directions and the variances var(u_jᵀz) of
    the simulated recursion at h and h/2 (the law the Monte Carlo has exactly); the bounds v*, h*, r* of
    Prop 4.1; the centralized Kalman-Bucy reference of x at the fixed roles."""
    from scipy.linalg import solve_continuous_lyapunov

    noise = noise_model(sc, seed)
    P, S = core["P"], core["S_fixed"]
    N, q = sc.N, sc.q
    t_sde = t_stochastic(sc, quick)
    last = int(round(t_sde / sc.simulation.record_dt))
    idx = check_indices(sc, t_sde)
    gfix = np.asarray(sc.fixed_roles.active, float)
    Gm = noise_input_matrix(sc, noise, gfix)
    keep = sorted(set(int(k) for k in idx) | {last})
    trace, Sig = lb.noise_covariance_traces(S, Gm, sc.simulation.record_dt, last, ce.block_diag(list(P)), keep)
    at = {k: Sig[j] for j, k in enumerate(keep)}
    stable = bool(np.all(np.isfinite(S))) and float(np.linalg.eigvals(S).real.max()) < 0
    with np.errstate(over="ignore", invalid="ignore"):
        steady = solve_continuous_lyapunov(S, -Gm @ Gm.T) if stable else np.full_like(S, np.nan)
    dirs, lam = lb.principal_directions(P, [at[int(k)] for k in idx], N_DIRECTIONS)
    sim_var, net, Z = {}, coestimation(sc, P), ce.error_map(sc.n, sc.p, N)
    for label, h in (("h", sc.stochastic.step), ("half", sc.stochastic.step / 2)):
        # the exact covariance of the simulated recursion at the check times (the law the Monte Carlo has)
        Sz = sim.recorded_error_covariance(net, step_operators(sc, P, noise, h), gfix,
                                           int(round(sc.simulation.record_dt / h)), idx, Z)
        sim_var[label] = np.einsum("ckd,cde,cke->ck", dirs, Sz, dirs)
    r_fixed = max(np.linalg.norm(Gm[:, 1 + i]) for i in range(N))
    r_any = max(np.linalg.norm(noise_input_matrix(sc, noise, np.ones(N))[:, 1 + i]) for i in range(N))
    kb_steady, kb_final = kalman_bucy_reference(sc, noise, gfix, t_sde)
    return {"v": noise.process[:, 0], "h": noise.measurement[:, :, 0], "v_star": np.array(np.linalg.norm(noise.process)),
            "h_star": np.array(np.linalg.norm(noise.measurement[:, :, 0], axis=1).max()), "r_star": np.array(r_fixed),
            "r_star_roles": np.array(r_any), "t_sde": np.array(t_sde), "tr_PSigma": trace, "probe_index": idx,
            "probe_dirs": dirs, "probe_var": lam, "sim_var_h": sim_var["h"], "sim_var_half": sim_var["half"],
            "Sigma_final": ce.node_blocks(at[last], N, q), "Sigma_steady": ce.node_blocks(steady, N, q),
            "steady_ok": np.array(stable), "kb_steady": kb_steady, "kb_final": kb_final}


def mean_square_constants(d: Design, fixed: bool) -> dict[str, float]:
    """κ, η, ψ̄ and (52) of Prop 4.1 with λ_min(Q̄) of the fixed roles (Q̄ = Q + 2α(L⊗I)) or of the
    time-varying roles (Q̄_ε, single ε). r* = max_i ‖r_i‖ over the roles the run can take: the fixed g_i,
    or any g_i ∈ [0, 1] for time-varying roles (‖g_i[−L_ih_i; J_ih_i]‖ ≤ ‖[L_ih_i; J_ih_i]‖)."""
    qmin = float(d["fixed_qbar_min"]) if fixed else float(d["qbar_single"])
    r_star = float(d.law["r_star"]) if fixed else float(d.law["r_star_roles"])
    c = lb.mean_square_constants(d.P, qmin, float(d["phibar"]), float(d.law["v_star"]), r_star, d.scenario.N)
    return {**c, "qmin": qmin, "r_star": r_star}
