"""The references stage of the random-comm-filter family: per scenario, the exact values the Monte
Carlo checks are compared with, beyond the design. At the test cells (`test_times` × nodes ×
`directions`, main rate): the bound (9), the exact mean covariance, P_KB(t) and the mean and second
moment over clock paths of the per-path bound (14); the gridded simulator's own exact mean covariance
against the model's (its discretisation bias, at h and h/2); filterpy's discrete filter on the sampled
model at four sampling steps, with scipy's DARE solution and the difference their residuals allow; and
the independent oracles of the claims on the Kalman–Bucy covariance and on (10)-(11) (python-control's
care, lqe and lyap, scipy's Radau integration of the Riccati ODE: `oracles`).
"""
from __future__ import annotations

import numpy as np
import scipy  # scipy.linalg loads on first use (scipy imports submodules lazily): `dse list` skips it

import dse.estimators.gossip_covariance as gc
import dse.estimators.kalman_bucy as kb
from dse.contract.stages import stage

from .design import joint_ok, kalman_bucy_transient
from .scenario import RandomCommFile

MAX_TEST_TIMES = 10        # output times at which the Monte Carlo means are tested
MAX_SCHEME_DIM = 20        # N·n above which the gridded scheme's own mean covariance is not formed
FILTERPY_FRACTIONS = (1.0, 0.5, 0.25, 0.125)
FILTERPY_MAX_STEPS = 6000
RADAU_RTOL = 1e-11         # local tolerance of the reference Riccati integration


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
    """Indices (≥ 1) of at most MAX_TEST_TIMES output times spread evenly over (0, T], and the first output
    time (where a wrong start, such as errors not starting at x(0) − m0, shows most)."""
    T = sc.n_outputs
    k = min(T, MAX_TEST_TIMES)
    return np.unique(np.r_[1, np.round(np.linspace(T / k, T, k)).astype(int)])


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
        out.update(kb.sampled_filter_reference(s.A, s.B, Hs, Vs, s.P0, P_kb, FILTERPY_FRACTIONS, FILTERPY_MAX_STEPS))
        out.update(_stored(kalman_bucy_oracles, sc, P_kb))
    out.update(_stored(lyapunov_oracles, s))
    return out


# -- the claims' independent oracles -----------------------------------------------------------------------
# Computed here, in the stage's worker (which imports scipy.stats for filterpy already), rather than in the
# claims: python-control and scipy.integrate then stay out of the main process, which imports its output
# libraries meanwhile. A claim whose oracle arrays are missing (the oracle raised, or did not succeed, here)
# calls the same function itself, so that it reports what it reported before.

def kalman_bucy_oracles(sc: RandomCommFile, P_kb: np.ndarray) -> tuple[dict[str, np.ndarray] | None, str]:
    """python-control's care and lqe (gain and covariance) of the filter CARE, and scipy's Radau
    integration of the Riccati ODE from P0 on the output grid (local tolerances rtol = RADAU_RTOL,
    atol = rtol·max(1, |P_KB|)); None with Radau's message when the integration failed."""
    import control as ct
    from scipy.integrate import solve_ivp

    s = sc.gossip
    Hs, Vs = np.vstack(s.H), scipy.linalg.block_diag(*s.V)
    Sinv = Hs.T @ np.linalg.solve(Vs, Hs)
    X, _, _ = ct.care(s.A.T, Hs.T, s.B @ s.B.T, Vs, method="scipy")
    Lq, Pq, _ = ct.lqe(s.A, s.B, Hs, np.eye(s.B.shape[1]), Vs, method="scipy")

    def rhs(t, p):
        Pt = p.reshape(s.n, s.n)
        return (s.A @ Pt + Pt @ s.A.T + s.B @ s.B.T - Pt @ Sinv @ Pt).ravel()

    ts = sc.output_times
    atol = RADAU_RTOL * max(1.0, float(np.abs(P_kb).max()))
    sol = solve_ivp(rhs, (0, ts[-1]), s.P0.ravel(), method="Radau", t_eval=ts, rtol=RADAU_RTOL, atol=atol)
    if not sol.success:
        return None, sol.message
    return {"oracle_care": X, "oracle_lqe_gain": Lq, "oracle_lqe": Pq,
            "oracle_riccati_ode": sol.y.T.reshape(-1, s.n, s.n)}, ""


def lyapunov_oracles(s) -> tuple[dict[str, np.ndarray], str]:
    """python-control's lyap of (11) (S) and of (10) (R), for the check of scipy's solutions."""
    import control as ct

    Gbar = (s.Gbar + s.Gbar.T) / 2
    return {"oracle_lyap_S": ct.lyap(s.Abar, Gbar, method="scipy"),
            "oracle_lyap_R": ct.lyap(s.Abar.T, np.eye(s.n), method="scipy")}, ""


def _stored(oracle, *args) -> dict[str, np.ndarray]:
    """An oracle's arrays for the stage's result, or none if it raised, did not succeed or gave non-finite
    values (the claim then calls it again, and reports that)."""
    try:
        arrays, _ = oracle(*args)
    except Exception:
        return {}
    if arrays is None or not all(np.all(np.isfinite(a)) for a in arrays.values()):
        return {}
    return arrays


def oracle_arrays(bounds: dict[str, np.ndarray], oracle, *args) -> tuple[dict[str, np.ndarray] | None, str]:
    """The arrays of `oracle` stored by the references stage, else the oracle called here (see `_stored`)."""
    names = {kalman_bucy_oracles: KB_ORACLES, lyapunov_oracles: LYAPUNOV_ORACLES}[oracle]
    if all(k in bounds for k in names):
        return {k: bounds[k] for k in names}, ""
    return oracle(*args)


KB_ORACLES = ("oracle_care", "oracle_lqe_gain", "oracle_lqe", "oracle_riccati_ode")
LYAPUNOV_ORACLES = ("oracle_lyap_S", "oracle_lyap_R")


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
