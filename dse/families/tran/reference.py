"""The centralized references (project additions, not in the paper).

`central_deterministic`, `central_stochastic` (stages): a Kalman filter on the augmented state s = [x; w]
with all currently active sensors, along the deterministic run and the first stochastic run. Its steps
(`_predict`, `_update`) are filterpy's KalmanFilter.predict and .update operation for operation (the same
numpy calls in the same order, hence the same bits: tests/test_tran_reference.py runs filterpy beside it),
without importing filterpy, which imports scipy.stats (about 0.3 s of a small run).

The unknown input is modelled as a random walk ẇ = q_w^{1/2} ξ; the model ṡ = F s + noise,
F = [[A, B], [0, 0]], is discretised exactly at dt by Van Loan's method. Node i contributes
y_i = C_i x + noise at a step when g_i(t) > 1/2. In the deterministic example the sensors are
noise-free and a small fictitious R = r I is used; in the stochastic example continuous white
noise h_i dS_i/dt sampled at dt has covariance h_i h_iᵀ / dt (rank one, plus 1e-9 I jitter), and
the process noise v dW_v adds v vᵀ to the model's intensity.

`kalman_bucy_reference`: the error covariance of the best estimate of x from every sensor of the
fixed roles when w is known: the Kalman-Bucy filter of dx = (Ax + Bw)dt + v dW_v with the
measurements C_i x dt + h_i dS_i (steady state and at the end of the stochastic horizon, P(0) = 0:
x(0) is known). Every distributed estimate of x from these measurements has an error covariance at
least this large.
"""
from __future__ import annotations

import numpy as np
import scipy  # scipy.linalg loads on first use (scipy imports submodules lazily): `dse list` skips it

from dse.contract.stages import stage
from dse.estimators.kalman_bucy import kalman_bucy_riccati, kalman_bucy_steady
from dse.estimators.lyapunov_bounds import discrete_noise
from dse.simulate.seeding import stream_seed

from .scenario import CoestimationFile

#: the measurement noise blockdiag(h_i h_iᵀ) of the Kalman-Bucy reference is rank one per node; this
#: fraction of its largest entry (or this value when the noise is zero) is added on the diagonal so that
#: its Riccati equation is regular (the reference then uses slightly more noise than the true one)
KB_JITTER = 1e-9


def van_loan(F: np.ndarray, Qc: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    d = F.shape[0]
    M = np.zeros((2 * d, 2 * d))
    M[:d, :d], M[:d, d:], M[d:, d:] = -F, Qc, F.T
    X = scipy.linalg.expm(M * dt)
    Phi = X[d:, d:].T
    Qd = Phi @ X[:d, d:]
    return Phi, (Qd + Qd.T) / 2


def run_kalman(sc: CoestimationFile, t: np.ndarray, x: np.ndarray, g: np.ndarray, *, noise=None, rng=None) -> dict[str, np.ndarray]:
    """Filter the truth x (T, n) sampled at t (uniform, step = reference.dt); returns the estimates (T, n + p)."""
    n, p = sc.n, sc.p
    dt = float(t[1] - t[0])
    F = np.block([[sc.A, sc.B], [np.zeros((p, n + p))]])
    Qc = np.zeros((n + p, n + p))
    Qc[n:, n:] = sc.reference.q_w * np.eye(p)
    if noise is not None:
        v = noise.process[:, 0]
        Qc[:n, :n] += np.outer(v, v)
    Phi, Qd = van_loan(F, Qc, dt)
    s = sc.e0.mean(axis=0)               # the nodes' initial estimates, averaged
    P = 10.0 * np.eye(n + p)
    C = sc.per_node("C")
    out = np.zeros((len(t), n + p))
    for k in range(len(t)):
        if k:
            s, P = _predict(s, P, Phi, Qd)
        act = np.flatnonzero(g[k] > 0.5)
        if len(act):
            H = np.hstack([np.vstack([C[i] for i in act]), np.zeros((len(act) * sc.m, p))])
            y = H[:, :n] @ x[k]
            if noise is None:
                R = sc.reference.r_deterministic * np.eye(len(y))
            else:
                blocks = [np.outer(noise.measurement[i, :, 0], noise.measurement[i, :, 0]) / dt for i in act]
                R = np.zeros((len(y), len(y)))
                for j, b in enumerate(blocks):
                    R[j * sc.m:(j + 1) * sc.m, j * sc.m:(j + 1) * sc.m] = b
                R += 1e-9 * np.eye(len(y))
                y = y + rng.multivariate_normal(np.zeros(len(y)), R)
            s, P = _update(s, P, y, R, H)
        out[k] = s
    return {"t": t, "s": out}


def _predict(s: np.ndarray, P: np.ndarray, F: np.ndarray, Q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """s = F s, P = F P Fᵀ + Q, as filterpy's KalmanFilter.predict computes them (its fading-memory factor
    is 1.0, and multiplying by 1.0 changes no bit)."""
    return np.dot(F, s), np.dot(np.dot(F, P), F.T) + Q


def _update(s: np.ndarray, P: np.ndarray, z: np.ndarray, R: np.ndarray, H: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The measurement update as filterpy's KalmanFilter.update computes it: the gain P Hᵀ S⁻¹ with S inverted
    (np.linalg.inv), and the Joseph form (I - K H) P (I - K H)ᵀ + K R Kᵀ."""
    innovation = z - np.dot(H, s)
    PHT = np.dot(P, H.T)
    K = np.dot(PHT, np.linalg.inv(np.dot(H, PHT) + R))
    s = s + np.dot(K, innovation)
    I_KH = np.eye(len(s)) - np.dot(K, H)
    return s, np.dot(np.dot(I_KH, P), I_KH.T) + np.dot(np.dot(K, R), K.T)


def _stride(sc: CoestimationFile) -> int:
    return int(round(sc.reference.dt / sc.simulation.record_dt))


@stage(name="central-det", allow_nonfinite=("det_s", "det_all_s"))
def central_deterministic(sc: CoestimationFile, det_run: dict) -> dict[str, np.ndarray]:
    """The filter along the deterministic run, with the active sensors and with every sensor."""
    stride = _stride(sc)
    det = run_kalman(sc, det_run["t"][::stride], det_run["x"][::stride], det_run["g"][::stride])
    every = run_kalman(sc, det_run["t"][::stride], det_run["x"][::stride], np.ones_like(det_run["g"][::stride]))
    return {"det_t": det["t"], "det_s": det["s"], "det_all_s": every["s"]}


@stage(name="central-sde", allow_nonfinite=("sde_s",))
def central_stochastic(sc: CoestimationFile, sde_run: dict, law: dict) -> dict[str, np.ndarray]:
    """The filter along the first stored stochastic trial (none without one), with the seed's noise."""
    from .design import noise_of

    if not sde_run["kept_x"].size:
        return {}
    noise, stride = noise_of(law), _stride(sc)
    rng = np.random.default_rng(stream_seed(0, "tran", "central-kf-noise"))
    st = run_kalman(sc, sde_run["t"][::stride], sde_run["kept_x"][0, ::stride], sde_run["kept_g"][0, ::stride],
                    noise=noise, rng=rng)
    return {"sde_t": st["t"], "sde_s": st["s"]}


def kalman_bucy_reference(sc: CoestimationFile, noise, g, t_final: float) -> tuple[np.ndarray, np.ndarray]:
    """(steady-state, final-time) Kalman-Bucy covariance of x with the sensors of the nodes with g_i > 0,
    R = blockdiag(h_i h_iᵀ) + jitter·I (KB_JITTER), P(0) = 0. The steady state is NaN when scipy's CARE
    solver cannot reorder the Hamiltonian pencil (a nearly singular R); the final-time covariance then
    comes from the Hamiltonian flow (`kalman_bucy_riccati`), or is NaN when that flow is too stiff."""
    from scipy.linalg import block_diag, solve_continuous_lyapunov

    Bv = noise.process
    act = np.flatnonzero(np.asarray(g) > 0)
    if len(act) == 0:    # no sensor: the open-loop covariance of x
        return solve_continuous_lyapunov(sc.A, -Bv @ Bv.T), discrete_noise(sc.A, Bv @ Bv.T, t_final)[1]
    C = sc.per_node("C")
    H = np.vstack([C[i] for i in act])
    V = block_diag(*[np.outer(noise.measurement[i, :, 0], noise.measurement[i, :, 0]) for i in act])
    scale = float(np.abs(V).max())
    V = V + KB_JITTER * (scale if scale > 0 else 1.0) * np.eye(len(V))
    try:
        steady = kalman_bucy_steady(sc.A, Bv, H, V)[0]
    except (ValueError, np.linalg.LinAlgError):    # scipy cannot order the Hamiltonian pencil (ill-conditioned V)
        steady = np.full_like(sc.A, np.nan)          # a reference of the tables only: reported as not available
    try:
        final = kalman_bucy_riccati(sc.A, Bv, H, V, np.zeros_like(sc.A), t_final, 1)[-1]
    except np.linalg.LinAlgError:                    # too stiff for the Hamiltonian flow without a steady state
        final = np.full_like(sc.A, np.nan)
    return steady, final
