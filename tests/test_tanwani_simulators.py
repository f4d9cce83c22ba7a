"""The estimators behind the random-communication reproduction, on random systems and graphs
not among the reproduction's scenarios: exact flows, clocks, both simulators, the per-path and mean bounds, the
centralized references (scipy, python-control, filterpy)."""
from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg as sla
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from scipy.integrate import solve_ivp

import dse.estimators.gossip_covariance as gc
import dse.estimators.gossip_filter as gf
import dse.estimators.kalman_bucy as kb
from dse.estimators.linear_flows import BlockDiagonalFlow, affine_flow_grid, van_loan
from dse.simulate.matrix_moments import MatrixMoments
from dse.simulate.stats import z_for_confidence

SETTINGS = settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def random_system(seed: int, mode: str = "edge", kb_gains: bool = False) -> gf.GossipSystem:
    rng = np.random.default_rng(seed)
    n, N = int(rng.integers(1, 4)), int(rng.integers(2, 5))
    A = rng.normal(size=(n, n)) * 0.6 - 0.2 * np.eye(n)
    B = rng.normal(size=(n, int(rng.integers(1, n + 1))))
    H = tuple(rng.normal(size=(1, n)) for _ in range(N))
    V = tuple(np.array([[rng.uniform(0.2, 2.0)]]) for _ in range(N))
    L = gf.kalman_bucy_split_gains(A, B, H, V)[0] if kb_gains else tuple(rng.normal(size=(n, 1)) for _ in range(N))
    edges = {(i, i + 1) for i in range(N - 1)}                  # a path keeps it connected
    for i in range(N):
        for j in range(i + 2, N):
            if rng.random() < 0.4:
                edges.add((i, j))
    deg = np.zeros(N)
    for i, j in edges:
        deg[i] += 1
        deg[j] += 1
    alpha = float(rng.uniform(0.2, 1.0)) / deg.max()
    X = rng.normal(size=(n, n))
    return gf.GossipSystem(A, B, H, V, L, tuple(sorted(edges)), alpha, mode, X @ X.T + 0.3 * np.eye(n),
                           rng.normal(size=n) * 0.3)


# -- exact flows -----------------------------------------------------------------------------------

@SETTINGS
@given(st.integers(0, 10_000), st.sampled_from([1e-7, 1e-3, 0.05, 0.7, 3.0]))
def test_batched_van_loan_equals_block_exponential(seed, delta):
    rng = np.random.default_rng(seed)
    b, n = int(rng.integers(1, 4)), int(rng.integers(1, 4))
    blocks = [rng.normal(size=(n, n)) for _ in range(b)]
    if seed % 3 == 0:
        blocks[0] = np.zeros((n, n))                                   # eigenvalue sums that vanish exactly
    F = rng.normal(size=(b * n, b * n))
    G = F @ F.T
    flow = BlockDiagonalFlow.of(blocks, G)
    Phi, Q = van_loan(sla.block_diag(*blocks), G, delta)
    Pb = flow.transition(np.array([delta, 0.0]))
    Qb = flow.noise(np.array([delta, 0.0]))
    for a in range(b):
        np.testing.assert_allclose(Pb[0, a], Phi[a * n:(a + 1) * n, a * n:(a + 1) * n], atol=1e-11 * max(1, np.abs(Phi).max()))
    np.testing.assert_allclose(Qb[0], Q, atol=1e-11 * max(1, np.abs(Q).max()), rtol=1e-8)
    np.testing.assert_allclose(Qb[1], 0.0, atol=1e-15)


def test_affine_flow_grid_equals_ode_solution():
    rng = np.random.default_rng(3)
    M = rng.normal(size=(5, 5)) - 8 * np.eye(5)
    M[0, 0] = -800.0                                                     # stiff
    g, p0 = rng.normal(size=5), rng.normal(size=5)
    p = affine_flow_grid(M, g, p0, 0.1, 10)
    sol = solve_ivp(lambda t, x: M @ x + g, (0, 1), p0, method="Radau", t_eval=np.linspace(0, 1, 11), rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(p, sol.y.T, atol=1e-8)


# -- clocks and jumps ---------------------------------------------------------------------------------

def test_poisson_clock_events():
    rng = np.random.default_rng(0)
    times, ids = gf.sample_clock_events(3, 2.0, 5.0, 20_000, rng)
    valid = ids >= 0
    filled = np.where(valid, times, 1e9)
    assert np.all(np.diff(filled, axis=1) >= 0)
    assert np.all((times[valid] >= 0) & (times[valid] <= 5.0)) and np.all(np.isinf(times[~valid]))
    counts = np.stack([(ids == c).sum(1) for c in range(3)], 1)
    z = z_for_confidence(0.999, 6)
    assert np.all(np.abs(counts.mean(0) - 10.0) <= z * np.sqrt(10.0 / 20_000))
    assert np.all(np.abs(counts.var(0) - 10.0) <= z * np.sqrt((10 + 2 * 100) / 20_000))
    # given its count, a clock's times are uniform: mean T/2
    t0 = times[ids == 0]
    assert abs(t0.mean() - 2.5) <= z * np.sqrt(25 / 12 / t0.size)


@pytest.mark.parametrize("mode", ["edge", "ordered"])
def test_jump_powers(mode):
    s = random_system(5, mode)
    for c in range(len(s.clocks)):
        i, j = s.clocks[c]
        for k in range(5):
            Jk = np.linalg.matrix_power(s.jump(c), k)
            keep, take = s.jump_coefficients(np.array([k]))
            assert Jk[i, i] == pytest.approx(keep[0], abs=1e-14) and Jk[i, j] == pytest.approx(take[0], abs=1e-14)
    jump_sum = sum(s.jump(c) - np.eye(s.N) for c in range(len(s.clocks)))
    np.testing.assert_allclose(jump_sum, -s.alpha * s.laplacian, atol=1e-14)


# -- the deterministic bounds --------------------------------------------------------------------------

@SETTINGS
@given(st.integers(0, 10_000))
def test_bound_generator_is_equation_9(seed):
    s = random_system(seed)
    rng = np.random.default_rng(seed)
    lam = float(rng.uniform(0.1, 10))
    X = rng.normal(size=(s.N, s.n, s.n))
    X = X + X.transpose(0, 2, 1)
    M, g = gc.bound_generator(s, lam)
    lhs = gc.unvec((M @ np.concatenate([gc.vec(x) for x in X]) + g).reshape(s.N, -1), s.n)
    for i in range(s.N):
        nb = np.flatnonzero(s.laplacian[i] < 0)
        rhs = s.Ai[i] @ X[i] + X[i] @ s.Ai[i].T + s.Gi[i] + lam * s.alpha * sum(X[j] - X[i] for j in nb)
        np.testing.assert_allclose(lhs[i], rhs, atol=1e-11 * max(1, np.abs(rhs).max()))


@SETTINGS
@given(st.integers(0, 10_000))
def test_joint_generator_is_d1(seed):
    s = random_system(seed)
    rng = np.random.default_rng(seed)
    lam = float(rng.uniform(0.1, 10))
    D = s.N * s.n
    X = rng.normal(size=(D, D))
    X = X + X.T
    M, g = gc.joint_generator(s, lam)
    lhs = gc.unvec(M @ gc.vec(X) + g, D)
    Ab = sla.block_diag(*s.Ai)
    Ln = np.kron(s.laplacian, np.eye(s.n))
    F = Ab - lam * s.alpha * Ln
    rhs = F @ X + X @ F.T + s.joint_noise[s.n:, s.n:]
    for i, j in s.edges:                                     # exact mean covariance (D1): + λα² Σ D_ij Σ D_ij
        d = np.zeros(s.N)
        d[i], d[j] = 1, -1
        Dm = np.kron(np.outer(d, d), np.eye(s.n))
        rhs += lam * s.alpha ** 2 * Dm @ X @ Dm
    np.testing.assert_allclose(lhs, rhs, atol=1e-10 * max(1, np.abs(rhs).max()))


@SETTINGS
@given(st.integers(0, 10_000), st.sampled_from(["edge", "ordered"]))
def test_bound_dominates_exact_mean_covariance(seed, mode):
    """Theorem III.1 item 1 on random systems: 𝒫_i(t) − E[e_ie_iᵀ](t) ⪰ 0, and P_KB(t) ⪯ E[e_ie_iᵀ](t)."""
    s = random_system(seed, mode, kb_gains=bool(seed % 2))
    lam = float(np.random.default_rng(seed).uniform(0.2, 8))
    P = gc.bound_transient(s, lam, 0.1, 30)
    J = gc.diagonal_blocks(gc.joint_transient(s, lam, 0.1, 30), s.N, s.n)
    gap = np.linalg.eigvalsh(P - J)[..., 0] / np.maximum(1, np.linalg.norm(P, axis=(2, 3)))
    assert gap.min() >= -1e-9
    if seed % 2:
        Pkb = kb.kalman_bucy_riccati(s.A, s.B, np.vstack(s.H), sla.block_diag(*s.V), s.P0, 0.1, 30)
        low = np.linalg.eigvalsh(J - Pkb[:, None])[..., 0] / np.maximum(1, np.linalg.norm(J, axis=(2, 3)))
        assert low.min() >= -1e-9


@SETTINGS
@given(st.integers(0, 10_000))
def test_critical_rates_are_ordered(seed):
    s = random_system(seed)
    c9 = gc.critical_rate_bound(s)
    cS = gc.critical_rate_joint(s)
    assert cS <= c9 * (1 + 1e-8) + 1e-12
    if 0 < c9 < np.inf:
        assert gc.bound_abscissa(s, 1.01 * c9) < 0 <= gc.bound_abscissa(s, 0.99 * c9)


# -- the simulators ---------------------------------------------------------------------------------------

@SETTINGS
@given(st.integers(0, 10_000), st.sampled_from(["edge", "ordered"]))
def test_event_driven_per_path_matches_van_loan_and_bound(seed, mode):
    s = random_system(seed, mode)
    times = np.linspace(0, 2.0, 11)
    run = gf.simulate_event_driven(s, 1.5, times, 3, np.random.default_rng(seed))
    assert (run.min_gap / np.maximum(1, run.scale)).min() >= -1e-9          # Prop. III.2 along every path
    for p in range(3):
        t, c = run.event_times[p], run.event_clocks[p]
        P, Sig = gc.path_bound_and_covariance(s, t[c >= 0], c[c >= 0], times)
        scale = max(1.0, np.abs(P).max())
        np.testing.assert_allclose(run.pbound[p], P, atol=1e-9 * scale)
        np.testing.assert_allclose(run.sigma[p], gc.diagonal_blocks(Sig, s.N, s.n), atol=1e-9 * scale)


def _conditional_z(run, s):
    e = run.z[:, :, s.n:].reshape(run.z.shape[0], run.z.shape[1], s.N, s.n)
    resid = (e[..., :, None] * e[..., None, :] - run.sigma).sum(0)
    dg = np.diagonal(run.sigma, axis1=-2, axis2=-1)
    var = (run.sigma ** 2 + dg[..., :, None] * dg[..., None, :]).sum(0)
    return np.abs(resid[1:]) / np.sqrt(np.maximum(var[1:], 1e-300))


@pytest.mark.parametrize("seed", [1, 2])
def test_event_driven_samples_exact_conditional_law(seed):
    s = random_system(seed)
    times = np.linspace(0, 2.0, 5)
    run = gf.simulate_event_driven(s, 2.0, times, 4000, np.random.default_rng(seed))
    z = _conditional_z(run, s)
    assert z.max() <= z_for_confidence(0.999, z.size)


def test_frozen_path_is_shared_by_every_trial():
    s = random_system(7)
    path = (np.array([0.3, 0.9, 1.4]), np.array([0, len(s.clocks) - 1, 0]))
    run = gf.simulate_event_driven(s, 1.0, np.linspace(0, 2, 5), 2000, np.random.default_rng(0), clock_path=path)
    np.testing.assert_allclose(run.sigma, np.broadcast_to(run.sigma[:1], run.sigma.shape))
    P, Sig = gc.path_bound_and_covariance(s, *path, np.linspace(0, 2, 5))
    np.testing.assert_allclose(run.sigma[0], gc.diagonal_blocks(Sig, s.N, s.n), atol=1e-9 * max(1, np.abs(Sig).max()))
    z = _conditional_z(run, s)
    assert z.max() <= z_for_confidence(0.999, z.size)


def test_gridded_simulator_matches_exact_mean_covariance():
    """S1c (every node stable, light tails), 20,000 trials, Strang step h = 0.01."""
    one = np.eye(1)
    s = gf.GossipSystem(np.array([[0.5]]), one, (one, one), (one, one), (np.array([[3.0]]), np.array([[2.0]])),
                        ((0, 1),), 0.5)
    run = gf.simulate_gridded(s, 4.0, 0.01, 200, 20, 20_000, np.random.default_rng(11))
    e = run.z[:, :, 1:].reshape(20_000, -1, 2, 1)
    mom = MatrixMoments.of(e)
    est, se = mom.entries()
    J = gc.diagonal_blocks(gc.joint_transient(s, 4.0, 0.2, 10), 2, 1)
    z = np.abs(est[1:] - J[1:]) / se[1:]
    assert z.max() <= z_for_confidence(0.999, z.size)


# -- the centralized reference ------------------------------------------------------------------------------

@settings(max_examples=4, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.integers(0, 10_000))
def test_kalman_bucy_against_scipy_control_and_ode(seed):
    import control as ct

    s = random_system(seed, kb_gains=True)
    Hs, Vs = np.vstack(s.H), sla.block_diag(*s.V)
    P, K = kb.kalman_bucy_steady(s.A, s.B, Hs, Vs)
    X, _, _ = ct.care(s.A.T, Hs.T, s.B @ s.B.T, Vs, method="scipy")
    np.testing.assert_allclose(P, X, atol=1e-9 * max(1, np.abs(P).max()))
    res = s.A @ P + P @ s.A.T + s.B @ s.B.T - P @ Hs.T @ np.linalg.solve(Vs, Hs) @ P
    assert np.abs(res).max() <= 1e-9 * max(1, np.abs(P).max())
    Pt = kb.kalman_bucy_riccati(s.A, s.B, Hs, Vs, s.P0, 0.1, 20)
    Sinv = Hs.T @ np.linalg.solve(Vs, Hs)
    sol = solve_ivp(lambda t, p: (s.A @ p.reshape(s.n, s.n) + p.reshape(s.n, s.n) @ s.A.T + s.B @ s.B.T
                                  - p.reshape(s.n, s.n) @ Sinv @ p.reshape(s.n, s.n)).ravel(),
                    (0, 2), s.P0.ravel(), method="Radau", t_eval=np.linspace(0, 2, 21), rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(Pt, sol.y.T.reshape(-1, s.n, s.n), atol=1e-6 * max(1, np.abs(Pt).max()))


def test_filterpy_converges_to_kalman_bucy_at_rate_h():
    s = random_system(4, kb_gains=True)
    Hs, Vs = np.vstack(s.H), sla.block_diag(*s.V)
    P, _ = kb.kalman_bucy_steady(s.A, s.B, Hs, Vs)
    errs = []
    for h in (0.04, 0.02, 0.01):
        prior, post = kb.discretised_kalman_covariances(s.A, s.B, Hs, Vs, s.P0, h, int(40 / h))
        F, Qd = van_loan(s.A, s.B @ s.B.T, h)
        np.testing.assert_allclose(prior[-1], sla.solve_discrete_are(F.T, Hs.T, Qd, Vs / h), rtol=1e-7, atol=1e-10)
        errs.append(np.linalg.norm(prior[-1] - P))
    ratios = np.array(errs[:-1]) / np.array(errs[1:])
    assert np.all((ratios > 1.7) & (ratios < 2.3))                 # first order in h


def test_defective_plant_uses_the_dense_flow():
    """A double integrator (not diagonalisable): the event-driven simulator stays exact."""
    A = np.array([[0.0, 1.0], [0.0, 0.0]])
    B = np.array([[0.0], [1.0]])
    H = (np.array([[1.0, 0.0]]), np.array([[1.0, 0.0]]), np.array([[0.0, 1.0]]))
    V = (np.eye(1), 2 * np.eye(1), 0.5 * np.eye(1))
    L, _ = gf.kalman_bucy_split_gains(A, B, H, V)
    s = gf.GossipSystem(A, B, H, V, L, ((0, 1), (1, 2)), 0.5)
    times = np.linspace(0, 1.5, 4)
    run = gf.simulate_event_driven(s, 2.0, times, 1500, np.random.default_rng(2))
    for p in range(2):
        t, c = run.event_times[p], run.event_clocks[p]
        P, Sig = gc.path_bound_and_covariance(s, t[c >= 0], c[c >= 0], times)
        np.testing.assert_allclose(run.sigma[p], gc.diagonal_blocks(Sig, s.N, s.n), atol=1e-9 * max(1, np.abs(Sig).max()))
    z = _conditional_z(run, s)
    assert z.max() <= z_for_confidence(0.999, z.size)
    assert (run.min_gap / np.maximum(1, run.scale)).min() >= -1e-9


def test_gridded_scheme_bias_is_second_order():
    s = random_system(9)
    ex = gc.joint_transient(s, 3.0, 0.2, 10)
    errs = []
    for h in (0.02, 0.01):
        every = int(round(0.2 / h))
        g = gc.gridded_scheme_covariance(s, 3.0, h, 10 * every, every)
        errs.append(np.abs(g - ex).max())
    assert 3.0 <= errs[0] / errs[1] <= 5.0


def test_monte_carlo_stages_are_deterministic_per_seed():
    from dse.families.tanwani import monte_carlo
    from dse.families.tanwani.scenario import load_scenario

    sc = load_scenario("s1c")
    a = monte_carlo.simulate_gridded_rate(sc, 5, 300, sc.main_rate)
    b = monte_carlo.simulate_gridded_rate(sc, 5, 300, sc.main_rate)
    c = monte_carlo.simulate_gridded_rate(sc, 6, 300, sc.main_rate)
    assert all(np.array_equal(a[k], b[k]) for k in a)
    assert not np.array_equal(a["e_s2"], c["e_s2"])
    e1, e2 = monte_carlo.simulate_event_rate(sc, 5, 60), monte_carlo.simulate_event_rate(sc, 5, 60)
    assert all(np.array_equal(e1[k], e2[k]) for k in e1)
