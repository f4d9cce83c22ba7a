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
from dse.estimators.input_state_coestimation import block_diag
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
    N, q = sc.N, sc.q
    LJ = gains(sc)
    vbar = np.concatenate([noise.process[:, 0], np.zeros(sc.p)])
    Gm = np.zeros((N * q, 1 + N))
    Gm[:, 0] = np.tile(vbar, N)
    for i in range(N):
        hi = noise.measurement[i, :, 0]
        Gm[i * q:(i + 1) * q, 1 + i] = g[i] * np.concatenate([-LJ["L"][i] @ hi, LJ["J"][i] @ hi])
    return Gm


def check_indices(sc: CoestimationFile, t_sde: float) -> np.ndarray:
    """Record indices (t > 0) at which the fixed-role Monte Carlo is compared with the exact law."""
    last = int(round(t_sde / sc.simulation.record_dt))
    stride = max(1, int(np.ceil(last / MAX_CHECK_TIMES)))
    return np.arange(stride, last + 1, stride)


def error_map(sc: CoestimationFile) -> np.ndarray:
    """Z with z = Z u + (terms in w): z_i = [x − x̂_i; ŵ_i − w] from u = [x; e_1; …; e_N]."""
    n, p, N = sc.n, sc.p, sc.N
    q = n + p
    Z = np.zeros((N * q, n + N * q))
    for i in range(N):
        Z[i * q:i * q + n, :n] = np.eye(n)
        Z[i * q:i * q + n, n + i * q:n + i * q + n] = -np.eye(n)
        Z[i * q + n:(i + 1) * q, n + i * q + n:n + (i + 1) * q] = np.eye(p)
    return Z


def _power_sum(Phi: np.ndarray, Q: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """(Φᵏ, Σ_{j<k} Φʲ Q Φʲᵀ) by binary doubling: the k-step composition of u⁺ = Φu + κ, κ ~ N(0, Q)
    (only positive semidefinite sums, O(log k) products)."""
    D = len(Phi)
    P_acc, Q_acc = np.eye(D), np.zeros_like(Q)
    P_pow, Q_pow = Phi, Q                      # the 2^j-step composition
    while k:
        if k & 1:                              # append 2^j steps after the accumulated ones
            Q_acc = P_pow @ Q_acc @ P_pow.T + Q_pow
            P_acc = P_pow @ P_acc
        k >>= 1
        if k:
            Q_pow = P_pow @ Q_pow @ P_pow.T + Q_pow
            P_pow = P_pow @ P_pow
    return P_acc, (Q_acc + Q_acc.T) / 2


def simulated_error_covariance(sc: CoestimationFile, P: np.ndarray, noise: sim.NoiseModel, h: float,
                               idx: np.ndarray) -> np.ndarray:
    """The exact covariance of the simulated fixed-role error at the record indices `idx` (an arithmetic
    sequence from its step): the recursion u⁺ = Φu + κ, κ ~ N(0, Q) of `sim.linear_gaussian_step`,
    composed over the record step and over the stride between checks (positive semidefinite sums only)."""
    net = coestimation(sc, P)
    Phi, Q = sim.linear_gaussian_step(net, step_operators(sc, P, noise, h), np.asarray(sc.fixed_roles.active, float))
    with np.errstate(over="ignore", invalid="ignore"):
        Phi, Q = _power_sum(Phi, Q, int(round(sc.simulation.record_dt / h)))
        Phi, Q = _power_sum(Phi, Q, int(idx[0]))
        Z = error_map(sc)
        out, Sig = [], np.zeros_like(Q)
        for _ in idx:
            Sig = Phi @ Sig @ Phi.T + Q
            out.append(Z @ Sig @ Z.T)
    return np.array(out)


def _node_blocks(M: np.ndarray, N: int, q: int) -> np.ndarray:
    return np.stack([M[i * q:(i + 1) * q, i * q:(i + 1) * q] for i in range(N)])


def _principal_directions(P: np.ndarray, covariances) -> tuple[np.ndarray, np.ndarray]:
    """At each check time the principal directions u_j = P^{1/2}v_j of P^{1/2}ΣP^{1/2} (v_j its eigenvectors,
    λ_j = var(u_jᵀz) its largest eigenvalues, Σ_j λ_j = tr(PΣ)); NaN where Σ overflowed (an unstable S)."""
    root = block_diag([(U * np.sqrt(np.maximum(w, 0))) @ U.T for w, U in (np.linalg.eigh(Pi) for Pi in P)])
    dirs, lam = [], []
    for S_k in covariances:
        if not np.all(np.isfinite(S_k)):   # an unstable S overflows: no law to compare with
            dirs.append(np.full((N_DIRECTIONS, len(S_k)), np.nan))
            lam.append(np.full(N_DIRECTIONS, np.nan))
            continue
        w, V = np.linalg.eigh(root @ S_k @ root)
        order = np.argsort(w)[::-1][:N_DIRECTIONS]
        # directions below the numerical rank of Σ (λ_j ≤ 1e-8 λ_1: eigh's relative error there is eps·λ_1/λ_j)
        # carry round-off, not noise: not tested
        lost = w[order] <= 1e-8 * max(w[order[0]], 0.0)
        lam.append(np.where(lost, 0.0, w[order]))
        dirs.append(np.where(lost[:, None], np.nan, (root @ V[:, order]).T))
    return np.array(dirs), np.array(lam)


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
    trace, Sig = lb.noise_covariance_traces(S, Gm, sc.simulation.record_dt, last, block_diag(list(P)), keep)
    at = {k: Sig[j] for j, k in enumerate(keep)}
    stable = bool(np.all(np.isfinite(S))) and float(np.linalg.eigvals(S).real.max()) < 0
    with np.errstate(over="ignore", invalid="ignore"):
        steady = solve_continuous_lyapunov(S, -Gm @ Gm.T) if stable else np.full_like(S, np.nan)
    dirs, lam = _principal_directions(P, [at[int(k)] for k in idx])
    sim_var = {}
    for label, h in (("h", sc.stochastic.step), ("half", sc.stochastic.step / 2)):
        Sz = simulated_error_covariance(sc, P, noise, h, idx)
        sim_var[label] = np.einsum("ckd,cde,cke->ck", dirs, Sz, dirs)
    r_fixed = max(np.linalg.norm(Gm[:, 1 + i]) for i in range(N))
    r_any = max(np.linalg.norm(noise_input_matrix(sc, noise, np.ones(N))[:, 1 + i]) for i in range(N))
    kb_steady, kb_final = kalman_bucy_reference(sc, noise, gfix, t_sde)
    return {"v": noise.process[:, 0], "h": noise.measurement[:, :, 0], "v_star": np.array(np.linalg.norm(noise.process)),
            "h_star": np.array(np.linalg.norm(noise.measurement[:, :, 0], axis=1).max()), "r_star": np.array(r_fixed),
            "r_star_roles": np.array(r_any), "t_sde": np.array(t_sde), "tr_PSigma": trace, "probe_index": idx,
            "probe_dirs": dirs, "probe_var": lam, "sim_var_h": sim_var["h"], "sim_var_half": sim_var["half"],
            "Sigma_final": _node_blocks(at[last], N, q), "Sigma_steady": _node_blocks(steady, N, q),
            "steady_ok": np.array(stable), "kb_steady": kb_steady, "kb_final": kb_final}


def mean_square_constants(d: Design, fixed: bool) -> dict[str, float]:
    """κ, η, ψ̄ and (52) of Prop 4.1 with λ_min(Q̄) of the fixed roles (Q̄ = Q + 2α(L⊗I)) or of the
    time-varying roles (Q̄_ε, single ε). r* = max_i ‖r_i‖ over the roles the run can take: the fixed g_i,
    or any g_i ∈ [0, 1] for time-varying roles (‖g_i[−L_ih_i; J_ih_i]‖ ≤ ‖[L_ih_i; J_ih_i]‖)."""
    qmin = float(d["fixed_qbar_min"]) if fixed else float(d["qbar_single"])
    r_star = float(d.law["r_star"]) if fixed else float(d.law["r_star_roles"])
    c = lb.mean_square_constants(d.P, qmin, float(d["phibar"]), float(d.law["v_star"]), r_star, d.scenario.N)
    return {**c, "qmin": qmin, "r_star": r_star}
