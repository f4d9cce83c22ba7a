"""Tests of the batched centralized Kalman reference, ``dse.estimators.kalman``.

Oracles, from strongest to weakest:

* filterpy's ``KalmanFilter``, run one trial at a time (a different implementation of the
  same recursion): means, covariances and gains agree to 1e-12 relative.
* exact rational arithmetic (``fractions.Fraction``) for the scalar random walk, and the
  reference numbers of specs/002_savas_noisy_comm.md §2.4.
* the defining equation of the DARE (its residual), python-control's ``dare``, and the
  limit of the recursion; the closed loop must be Schur stable.
* identities of the optimal filter (Joseph form = short form = information form).
* a Monte Carlo check that the filter's covariance is the covariance of its error.
"""

from __future__ import annotations

from fractions import Fraction

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from dse.estimators.kalman import (
    KalmanCovariances,
    KalmanRun,
    kalman_covariances,
    kalman_filter_batch,
    scalar_random_walk_steady_state,
    steady_state_gain,
    steady_state_prior_covariance,
)


# --------------------------------------------------------------------------- helpers


def assert_rel_close(actual, reference, rtol, what=""):
    """max |actual - reference| <= rtol * max |reference| (a norm-wise relative error).

    Element-wise relative error is meaningless for entries that are zero up to rounding
    (off-diagonal covariances, means near 0), so the error is scaled by the largest entry.
    """
    actual = np.asarray(actual)
    reference = np.asarray(reference)
    assert actual.shape == reference.shape, (what, actual.shape, reference.shape)
    scale = np.max(np.abs(reference))
    err = np.max(np.abs(actual - reference))
    assert err <= rtol * scale, f"{what}: max abs error {err:.3e} > {rtol:.0e} * {scale:.3e}"


def random_system(rng, n, p, radius):
    """A random (F, H, Q, R, P0) with spectral radius of F equal to ``radius``.

    Q, R and P0 are symmetric positive definite, so (F, Q^½) is reachable and the DARE has
    a stabilising solution whenever (F, H) is detectable.
    """
    F = rng.standard_normal((n, n))
    F *= radius / np.max(np.abs(np.linalg.eigvals(F)))
    H = rng.standard_normal((p, n))
    A = rng.standard_normal((n, n))
    Q = A @ A.T / n + 0.1 * np.eye(n)
    B = rng.standard_normal((p, p))
    R = B @ B.T / p + 0.5 * np.eye(p)
    C = rng.standard_normal((n, n))
    P0 = C @ C.T / n + 0.2 * np.eye(n)
    return F, H, Q, R, P0


def simulate(rng, F, H, Q, R, x0_mean, P0, trials, n_steps):
    """True states and measurements of the linear-Gaussian model, shape (trials, K, ·)."""
    n, p = F.shape[0], H.shape[0]
    LQ, LR, L0 = np.linalg.cholesky(Q), np.linalg.cholesky(R), np.linalg.cholesky(P0)
    x = x0_mean + rng.standard_normal((trials, n)) @ L0.T
    xs = np.empty((trials, n_steps, n))
    zs = np.empty((trials, n_steps, p))
    for k in range(n_steps):
        xs[:, k] = x
        zs[:, k] = x @ H.T + rng.standard_normal((trials, p)) @ LR.T
        x = x @ F.T + rng.standard_normal((trials, n)) @ LQ.T
    return xs, zs


def is_detectable(F, H, tol=1e-8):
    """PBH test: every eigenvalue with |λ| >= 1 is observable through H."""
    n = F.shape[0]
    for lam in np.linalg.eigvals(F):
        if abs(lam) >= 1.0 - 1e-9:
            M = np.vstack([lam * np.eye(n) - F, H])
            if np.linalg.svd(M, compute_uv=False)[-1] < tol * max(1.0, np.linalg.norm(M)):
                return False
    return True


def riccati_residual(P, F, H, Q, R):
    """F P Fᵀ - F P Hᵀ (H P Hᵀ + R)⁻¹ H P Fᵀ + Q - P, the filtering DARE."""
    S = H @ P @ H.T + R
    FPHt = F @ P @ H.T
    return F @ P @ F.T - FPHt @ np.linalg.solve(S, FPHt.T) + Q - P


# The N = 3 scalar random walk of specs/002_savas_noisy_comm.md §2.4.
N_SENSORS = 3
RW = dict(F=np.array([[1.0]]), H=np.ones((N_SENSORS, 1)), Q=np.array([[1.0]]), R=25.0 * np.eye(N_SENSORS))


# --------------------------------------------------------------------------- filterpy oracle


@pytest.mark.parametrize(
    "seed, n, p, radius",
    [(0, 2, 1, 0.8), (1, 3, 2, 1.15), (2, 4, 3, 0.95), (3, 4, 1, 1.05), (4, 2, 3, 1.3)],
)
def test_matches_filterpy_one_trial_at_a_time(seed, n, p, radius):
    from filterpy.kalman import KalmanFilter

    rng = np.random.default_rng(seed)
    F, H, Q, R, P0 = random_system(rng, n, p, radius)
    trials, n_steps = 3, 25
    x0 = rng.standard_normal((trials, n))  # a different prior mean per trial
    _, zs = simulate(rng, F, H, Q, R, np.zeros(n), P0, trials, n_steps)

    run = kalman_filter_batch(F, H, Q, R, x0, P0, zs)
    assert isinstance(run, KalmanRun) and isinstance(run.cov, KalmanCovariances)
    assert run.x_prior.shape == run.x_post.shape == (trials, n_steps, n)
    assert run.cov.P_prior.shape == run.cov.P_post.shape == (n_steps, n, n)
    assert run.cov.gains.shape == (n_steps, n, p)

    for t in range(trials):
        kf = KalmanFilter(dim_x=n, dim_z=p)
        kf.F, kf.H, kf.Q, kf.R = F.copy(), H.copy(), Q.copy(), R.copy()
        kf.x, kf.P = x0[t].reshape(n, 1).copy(), P0.copy()
        xp, xf, Pp, Pf, G = [], [], [], [], []
        for k in range(n_steps):
            xp.append(kf.x.ravel().copy())
            Pp.append(kf.P.copy())
            kf.update(zs[t, k])
            xf.append(kf.x.ravel().copy())
            Pf.append(kf.P.copy())
            G.append(kf.K.copy())
            kf.predict()
        assert_rel_close(run.x_prior[t], np.array(xp), 1e-12, f"x_prior trial {t}")
        assert_rel_close(run.x_post[t], np.array(xf), 1e-12, f"x_post trial {t}")
        for k in range(n_steps):
            assert_rel_close(run.cov.P_prior[k], Pp[k], 1e-12, f"P_prior step {k}")
            assert_rel_close(run.cov.P_post[k], Pf[k], 1e-12, f"P_post step {k}")
            assert_rel_close(run.cov.gains[k], G[k], 1e-12, f"gain step {k}")


def test_batch_equals_single_trials_and_broadcast_x0():
    """Trials are independent: filtering a batch equals filtering each trial alone, and a
    shared x0 of shape (n,) equals the same x0 tiled to (trials, n)."""
    rng = np.random.default_rng(11)
    F, H, Q, R, P0 = random_system(rng, 3, 2, 1.1)
    x0 = rng.standard_normal(3)
    _, zs = simulate(rng, F, H, Q, R, x0, P0, 7, 12)
    run = kalman_filter_batch(F, H, Q, R, x0, P0, zs)
    tiled = kalman_filter_batch(F, H, Q, R, np.tile(x0, (7, 1)), P0, zs)
    np.testing.assert_array_equal(run.x_post, tiled.x_post)
    for t in range(7):
        one = kalman_filter_batch(F, H, Q, R, x0, P0, zs[t : t + 1])
        assert_rel_close(one.x_prior[0], run.x_prior[t], 1e-14, "x_prior")
        assert_rel_close(one.x_post[0], run.x_post[t], 1e-14, "x_post")
    assert run.x_prior.dtype == run.cov.P_post.dtype == np.float64
    # Documented layout: per-step slices over trials are contiguous (time-major storage).
    assert run.x_prior[:, 3].flags.c_contiguous and run.x_post[:, 3].flags.c_contiguous
    np.testing.assert_array_equal(run.x_prior[:, 0], np.tile(x0, (7, 1)))


def test_optimal_filter_identities():
    """For the optimal gain: Joseph form = (I - G H) P⁻ = (P⁻⁻¹ + Hᵀ R⁻¹ H)⁻¹ (information
    form); P⁻(k+1) = F P(k|k) Fᵀ + Q; P(k|k) exactly symmetric and positive definite."""
    rng = np.random.default_rng(5)
    F, H, Q, R, P0 = random_system(rng, 4, 2, 1.2)
    cov = kalman_covariances(F, H, Q, R, P0, 30)
    np.testing.assert_array_equal(cov.P_prior[0], P0)
    for k in range(30):
        Pm, Pk, G = cov.P_prior[k], cov.P_post[k], cov.gains[k]
        np.testing.assert_array_equal(Pk, Pk.T)
        assert np.linalg.eigvalsh(Pk).min() > 0
        assert_rel_close(Pk, (np.eye(4) - G @ H) @ Pm, 1e-12, "short form")
        info = np.linalg.inv(np.linalg.inv(Pm) + H.T @ np.linalg.solve(R, H))
        assert_rel_close(Pk, info, 1e-11, "information form")
        if k + 1 < 30:
            assert_rel_close(cov.P_prior[k + 1], F @ Pk @ F.T + Q, 1e-14, "predict")


def test_covariance_is_the_error_covariance_monte_carlo():
    """The filter's P(k|k-1) is the covariance of x(k) - x̂(k|k-1) over trials.

    200,000 trials of the N=3 random walk, P0 = 1. The sample variance of a Gaussian has
    relative standard deviation sqrt(2/T) = 0.32 %; the band below is 5 standard deviations
    (fixed seed, so deterministic; a wrong gain or an off-by-one in the step order moves
    P(4|3) by more than 10 %). The error must also be uncorrelated with the estimate
    (orthogonality principle), checked the same way.
    """
    rng = np.random.default_rng(20240611)
    trials, n_steps = 200_000, 6
    P0 = np.array([[1.0]])
    xs, zs = simulate(rng, RW["F"], RW["H"], RW["Q"], RW["R"], np.zeros(1), P0, trials, n_steps)
    run = kalman_filter_batch(RW["F"], RW["H"], RW["Q"], RW["R"], np.zeros(1), P0, zs)
    sd_rel = np.sqrt(2.0 / trials)
    for k in range(n_steps):
        for est, P in ((run.x_prior, run.cov.P_prior), (run.x_post, run.cov.P_post)):
            err = xs[:, k, 0] - est[:, k, 0]
            assert abs(np.mean(err**2) / P[k, 0, 0] - 1.0) < 5 * sd_rel
            if k > 0:  # at k=0 the prior estimate is the constant 0
                corr = np.corrcoef(err, est[:, k, 0])[0, 1]
                assert abs(corr) < 5 / np.sqrt(trials)


# --------------------------------------------------------------------------- scalar random walk


def exact_scalar_prior(P0, q, r_eff, k):
    """P(k|k-1) of the scalar random walk in exact rational arithmetic."""
    P = Fraction(P0)
    for _ in range(k):
        P = P * r_eff / (P + r_eff) + q
    return P


@pytest.mark.parametrize("P0, reference", [(1.0, 9.533115), (0.0, 8.844364)])
def test_random_walk_finite_horizon(P0, reference):
    """N·P(4|3) for the N=3 random walk (spec 002 §2.4), and the centralized filter with
    H = 1_N, R = r I_N equals the scalar filter with r/N, exactly in rational arithmetic."""
    cov = kalman_covariances(RW["F"], RW["H"], RW["Q"], RW["R"], [[P0]], 5)
    NP = N_SENSORS * cov.P_prior[4, 0, 0]
    assert NP == pytest.approx(reference, abs=1e-6)
    for k in range(5):
        exact = exact_scalar_prior(P0, 1, Fraction(25, 3), k)
        assert cov.P_prior[k, 0, 0] == pytest.approx(float(exact), rel=1e-14, abs=1e-300)


def test_random_walk_steady_state():
    q, r, N = 1.0, 25.0, N_SENSORS
    P_c, K_c = scalar_random_walk_steady_state(q, r / N)
    assert N * P_c == pytest.approx(10.289198, abs=1e-6)
    assert P_c == pytest.approx(3.429733, abs=1e-6)
    assert K_c == pytest.approx(0.291568, abs=1e-6)
    P_1, K_1 = scalar_random_walk_steady_state(q, r)
    assert P_1 == pytest.approx(5.524938, abs=1e-6)
    assert K_1 == pytest.approx(0.180998, abs=1e-6)
    assert N * P_1 == pytest.approx(16.574813, abs=1e-6)
    # The closed form is the positive root of P² - q P - q r = 0.
    for P, re in ((P_c, r / N), (P_1, r)):
        assert P * P - q * P - q * re == pytest.approx(0.0, abs=1e-13)

    # The matrix DARE of the N-sensor system gives the same numbers; the centralized gain
    # (1 × N) applied to N equal measurements sums to the gain per mean measurement.
    P = steady_state_prior_covariance(**RW)
    G = steady_state_gain(**RW)
    assert P.shape == (1, 1) and G.shape == (1, N)
    assert P[0, 0] == pytest.approx(P_c, rel=1e-13)
    assert G.sum() == pytest.approx(K_c, rel=1e-13)
    np.testing.assert_allclose(G, np.full((1, N), K_c / N), rtol=1e-13)
    P1 = steady_state_prior_covariance([[1.0]], [[1.0]], [[q]], [[r]])
    assert P1[0, 0] == pytest.approx(P_1, rel=1e-13)
    assert steady_state_gain([[1.0]], [[1.0]], [[q]], [[r]])[0, 0] == pytest.approx(K_1, rel=1e-13)

    # ... and the recursion converges to it (contraction factor (1 - K_c) per step).
    cov = kalman_covariances(**RW, P0=[[1.0]], n_steps=200)
    assert cov.P_prior[-1, 0, 0] == pytest.approx(P_c, rel=1e-13)
    assert cov.gains[-1].sum() == pytest.approx(K_c, rel=1e-13)


# --------------------------------------------------------------------------- DARE


def check_dare(F, H, Q, R, P0):
    """Residual, python-control, Schur stability of the closed loop, limit of the recursion."""
    import control

    P = steady_state_prior_covariance(F, H, Q, R)
    G = steady_state_gain(F, H, Q, R)
    scale = np.max(np.abs(P))
    np.testing.assert_array_equal(P, P.T)
    assert np.linalg.eigvalsh(P).min() > 0
    assert np.max(np.abs(riccati_residual(P, F, H, Q, R))) <= 1e-10 * scale

    X, _, _ = control.dare(F.T, H.T, Q, R, method="scipy")
    assert_rel_close(P, X, 1e-10, "control.dare")

    # The stabilising solution: x̂(k+1|k) = F (I - G H) x̂(k|k-1) + F G z(k) is Schur stable.
    rho = np.max(np.abs(np.linalg.eigvals(F @ (np.eye(F.shape[0]) - G @ H))))
    assert rho < 1.0

    # P(k|k-1) converges at rate ~rho² per step; run long enough for rho^(2K) < 1e-14.
    steps = int(np.clip(np.ceil(np.log(1e-14) / (2 * np.log(max(rho, 1e-3)))), 50, 5000)) + 50
    cov = kalman_covariances(F, H, Q, R, P0, steps)
    assert_rel_close(cov.P_prior[-1], P, 1e-9, "limit of the recursion")
    assert_rel_close(cov.gains[-1], G, 1e-9, "limit of the gains")


@pytest.mark.parametrize("seed, n, p, radius", [(7, 3, 1, 1.2), (8, 2, 2, 0.7), (9, 4, 2, 1.4)])
def test_dare_fixed_systems(seed, n, p, radius):
    F, H, Q, R, P0 = random_system(np.random.default_rng(seed), n, p, radius)
    assert is_detectable(F, H)
    check_dare(F, H, Q, R, P0)


def test_dare_detectable_but_not_observable():
    """A stable unobserved mode (0.5) is fine: detectability, not observability, is needed;
    its steady-state variance is the Lyapunov solution q / (1 - 0.25)."""
    F = np.array([[1.1, 0.0], [0.0, 0.5]])
    H = np.array([[1.0, 0.0]])
    Q = np.diag([1.0, 2.0])
    R = np.array([[3.0]])
    check_dare(F, H, Q, R, np.eye(2))
    P = steady_state_prior_covariance(F, H, Q, R)
    assert P[1, 1] == pytest.approx(2.0 / 0.75, rel=1e-12)
    assert P[0, 1] == pytest.approx(0.0, abs=1e-12)


@settings(max_examples=15, deadline=None, derandomize=True)
@given(
    seed=st.integers(0, 2**32 - 1),
    n=st.integers(1, 4),
    p=st.integers(1, 3),
    radius=st.floats(0.3, 1.5),
)
def test_dare_property(seed, n, p, radius):
    from hypothesis import assume

    F, H, Q, R, P0 = random_system(np.random.default_rng(seed), n, p, radius)
    assume(is_detectable(F, H, tol=1e-3))
    check_dare(F, H, Q, R, P0)


# --------------------------------------------------------------------------- bad input


def _good():
    return dict(
        F=np.eye(2), H=np.ones((1, 2)), Q=np.eye(2), R=np.eye(1), x0=np.zeros(2), P0=np.eye(2),
        zs=np.zeros((4, 5, 1)),
    )


@pytest.mark.parametrize(
    "name, bad",
    [
        ("F", np.ones((2, 3))),
        ("F", np.ones(2)),
        ("H", np.ones((1, 3))),
        ("H", np.ones(2)),
        ("Q", np.eye(3)),
        ("Q", np.array([[1.0, 0.5], [0.0, 1.0]])),
        ("R", np.eye(2)),
        ("R", np.array([[np.nan]])),
        ("P0", np.eye(3)),
        ("x0", np.zeros(3)),
        ("x0", np.zeros((3, 2))),
        ("x0", np.zeros((4, 3))),
        ("zs", np.zeros((4, 5, 2))),
        ("zs", np.zeros((5, 1))),
        ("zs", np.zeros((4, 5, 1, 1))),
    ],
)
def test_bad_input_names_the_argument(name, bad):
    args = _good()
    args[name] = bad
    with pytest.raises(ValueError, match=rf"^{name} "):
        kalman_filter_batch(**args)


@pytest.mark.parametrize("n_steps", [-1, 2.5, True, "3"])
def test_bad_n_steps(n_steps):
    with pytest.raises(ValueError, match=r"^n_steps "):
        kalman_covariances(np.eye(2), np.ones((1, 2)), np.eye(2), np.eye(1), np.eye(2), n_steps)


@pytest.mark.parametrize("fn", [steady_state_prior_covariance, steady_state_gain])
def test_bad_input_steady_state(fn):
    with pytest.raises(ValueError, match=r"^H "):
        fn(np.eye(2), np.ones((1, 3)), np.eye(2), np.eye(1))
    with pytest.raises(ValueError, match=r"^R "):
        fn(np.eye(2), np.ones((2, 2)), np.eye(2), np.eye(1))


@pytest.mark.parametrize("q, r", [(0.0, 1.0), (1.0, -1.0), (np.inf, 1.0), (1.0, np.nan)])
def test_bad_input_scalar_closed_form(q, r):
    with pytest.raises(ValueError, match=r"^(q|r_eff) "):
        scalar_random_walk_steady_state(q, r)


def test_zero_steps_gives_empty_arrays():
    args = _good()
    args["zs"] = np.zeros((4, 0, 1))
    run = kalman_filter_batch(**args)
    assert run.x_prior.shape == (4, 0, 2) and run.cov.gains.shape == (0, 2, 1)
