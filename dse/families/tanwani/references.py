"""The references stage of the random-comm-filter family: per scenario, the exact values the Monte
Carlo checks are compared with, beyond the design. At the test cells (`test_times` × nodes ×
`directions`, main rate): the bound (9), the exact mean covariance, P_KB(t) and the mean and second
moment over clock paths of the per-path bound (14); the gridded simulator's own exact mean covariance
against the model's (its discretisation bias, at h and h/2); filterpy's discrete filter on the sampled
model at four sampling steps, with scipy's DARE solution and the difference their residuals allow.
"""
from __future__ import annotations

import numpy as np
import scipy  # scipy.linalg loads on first use (scipy imports submodules lazily): `dse list` skips it

import dse.estimators.gossip_covariance as gc
import dse.estimators.kalman_bucy as kb
from dse.contract.stages import stage
from dse.estimators.linear_flows import van_loan

from .design import joint_ok, kalman_bucy_transient
from .scenario import RandomCommFile

MAX_TEST_TIMES = 10        # output times at which the Monte Carlo means are tested
MAX_SCHEME_DIM = 20        # N·n above which the gridded scheme's own mean covariance is not formed
FILTERPY_FRACTIONS = (1.0, 0.5, 0.25, 0.125)
FILTERPY_MAX_STEPS = 6000
EPS = float(np.finfo(float).eps)


def directions(n: int) -> np.ndarray:
    """The test directions (q = n(n+1)/2, n): the axes e_a and (e_a + e_b)/√2 (a < b), in the
    order of `gc.vech_pairs`; the quadratic forms uᵀXu along them determine a symmetric X."""
    U = []
    for a, b in gc.vech_pairs(n):
        u = np.zeros(n)
        u[a] += 1.0
        u[b] += 1.0
        U.append(u / np.linalg.norm(u))
    return np.array(U)


def test_times(sc: RandomCommFile) -> np.ndarray:
    """Indices (≥ 1) of at most MAX_TEST_TIMES output times spread evenly over (0, T]."""
    T = sc.n_outputs
    k = min(T, MAX_TEST_TIMES)
    return np.unique(np.round(np.linspace(T / k, T, k)).astype(int))


def quadratic_forms(U: np.ndarray, X: np.ndarray) -> np.ndarray:
    """uᵀXu for every direction: X (…, n, n) → (…, q)."""
    return np.einsum("da,...ab,db->...d", U, X, U)


@stage(name="references", allow_nonfinite=("cell_bound", "cell_joint", "cell_P_mean", "cell_P_second", "cell_P_accuracy",
                                           "cell_kb", "scheme_bias_h", "scheme_bias_h2"))
def compute_references(sc: RandomCommFile) -> dict[str, np.ndarray]:
    """What the claims compare the Monte Carlo and the references with, beyond the design: the test-cell
    references (with the second moments of the P-process), the gridded scheme's exact bias and filterpy's
    sampled filter."""
    s = sc.gossip
    Hs, Vs = np.vstack(s.H), scipy.linalg.block_diag(*s.V)
    base = {"bound_t_0": gc.bound_transient(s, sc.main_rate, sc.output_step, sc.n_outputs),
            "P_kb_t": kalman_bucy_transient(sc)}
    if joint_ok(s):
        base["joint_t_0"] = gc.joint_transient(s, sc.main_rate, sc.output_step, sc.n_outputs)
    out = test_cell_references(sc, base)
    out.update(scheme_bias(sc))
    try:
        P_kb, K_kb = kb.kalman_bucy_steady(s.A, s.B, Hs, Vs)
        stable = np.all(np.isfinite(P_kb)) and np.max(np.linalg.eigvals(s.A - K_kb @ Hs).real) < 0
    except (np.linalg.LinAlgError, ValueError):
        stable = False
    if stable:
        out.update(filterpy_reference(s, Hs, Vs, P_kb))
    return out


def test_cell_references(sc: RandomCommFile, b: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Exact references of the Monte Carlo test cells (main rate, `test_times` × nodes ×
    `directions`): the mean and second moment over clock paths of uᵀP_i(t; τ)u (eq. 14), the
    mean uᵀ𝒫_i(t)u of (9), the exact uᵀE[e_ie_iᵀ](t)u, and uᵀP_KB(t)u."""
    s = sc.gossip
    U, idx = directions(s.n), test_times(sc)
    q = len(U)
    out = {"cell_times": idx, "cell_dirs": U,
           "cell_bound": quadratic_forms(U, b["bound_t_0"][idx]),
           "cell_kb": quadratic_forms(U, b["P_kb_t"][idx])}
    if "joint_t_0" in b:
        out["cell_joint"] = quadratic_forms(U, gc.diagonal_blocks(b["joint_t_0"][idx], s.N, s.n))
    w = gc.vech_weights(U)
    weights = np.zeros((s.N * q, s.N * q))
    for i in range(s.N):
        weights[i * q:(i + 1) * q, i * q:(i + 1) * q] = w
    mom = gc.bound_second_moments(s, sc.main_rate, sc.output_step, sc.n_outputs, weights, check=True)
    if mom is not None:
        out["cell_P_mean"] = mom[0][idx].reshape(len(idx), s.N, q)
        out["cell_P_second"] = mom[1][idx].reshape(len(idx), s.N, q)
        out["cell_P_accuracy"] = np.array(mom[2])
    return out


def scheme_bias(sc: RandomCommFile) -> dict[str, np.ndarray]:
    """The gridded simulator's own exact mean covariance minus the model's (main rate), at the
    scenario's step h and at h/2, on the output grid: its discretisation bias."""
    s = sc.gossip
    if s.N * s.n > MAX_SCHEME_DIM:
        return {}
    lam, h = sc.main_rate, sc.grid_step
    every = int(round(sc.output_step / h))
    exact = gc.diagonal_blocks(gc.joint_transient(s, lam, sc.output_step, sc.n_outputs), s.N, s.n)
    b1 = gc.diagonal_blocks(gc.gridded_scheme_covariance(s, lam, h, every * sc.n_outputs, every), s.N, s.n) - exact
    b2 = gc.diagonal_blocks(gc.gridded_scheme_covariance(s, lam, h / 2, 2 * every * sc.n_outputs, 2 * every),
                            s.N, s.n) - exact
    return {"scheme_bias_h": b1, "scheme_bias_h2": b2}


def _dare_residual(F, Qd, Hs, R, X) -> np.ndarray:
    Inn = Hs @ X @ Hs.T + R
    return F @ X @ F.T - F @ X @ Hs.T @ np.linalg.solve(Inn, Hs @ X @ F.T) + Qd - X


def filterpy_reference(s, Hs: np.ndarray, Vs: np.ndarray, P_kb: np.ndarray) -> dict[str, np.ndarray]:
    """filterpy's discrete filter on the sampled model at four sampling steps h, each run until its
    covariance stops changing (at most FILTERPY_MAX_STEPS steps; `filterpy_steady` says whether it
    did), with scipy's DARE solution X and what their difference may be: to first order an
    approximate solution Y of the DARE differs from the exact one by 𝒮⁻¹(R(Y)), 𝒮(Z) = Z − F_cZF_cᵀ
    (F_c the closed loop) and R the residual, so two approximate solutions differ by at most
    ‖𝒮⁻¹‖(‖R(X)‖ + ‖R(Y)‖), doubled for second-order terms, plus rounding (`filterpy_allow`).

    The steps scale with the fastest mode ν of the Kalman–Bucy closed loop A − P_KB HᵀV⁻¹H:
    h = min(0.1, 0.5/ν)·(1, 1/2, 1/4, 1/8), so that hν ≤ 1/2 (the first-order regime of
    the sampled filter)."""
    Ac = s.A - P_kb @ Hs.T @ np.linalg.solve(Vs, Hs)
    nu = float(np.abs(np.linalg.eigvals(Ac)).max())
    hs = min(0.1, 0.5 / max(nu, 1e-12)) * np.array(FILTERPY_FRACTIONS)
    pri, post, dare, steady, allow = [], [], [], [], []
    for h in hs:
        F, Qd = van_loan(s.A, s.B @ s.B.T, h)
        X = scipy.linalg.solve_discrete_are(F.T, Hs.T, Qd, Vs / h)
        Kd = X @ Hs.T @ np.linalg.inv(Hs @ X @ Hs.T + Vs / h)
        Fc = F @ (np.eye(s.n) - Kd @ Hs)
        inv_norm = 1.0 / float(np.linalg.svd(np.eye(s.n * s.n) - np.kron(Fc, Fc), compute_uv=False)[-1])
        prior, posterior = kb.discretised_kalman_covariances(s.A, s.B, Hs, Vs, s.P0, h, FILTERPY_MAX_STEPS,
                                                             until_steady=True)
        res = [float(np.linalg.norm(_dare_residual(F, Qd, Hs, Vs / h, Y), 2)) for Y in (X, prior[-1])]
        allow.append(2 * inv_norm * sum(res) + 10 * 4 * s.n * EPS * float(np.linalg.norm(X, 2)))
        pri.append(prior[-1]), post.append(posterior[-1]), dare.append(X)
        steady.append(len(prior) < FILTERPY_MAX_STEPS)
    return {"filterpy_h": hs, "filterpy_prior": np.array(pri), "filterpy_post": np.array(post),
            "dare_prior": np.array(dare), "filterpy_steady": np.array(steady), "filterpy_allow": np.array(allow),
            "kb_fastest_mode": np.array(nu)}
