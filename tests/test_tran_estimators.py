"""Coestimation estimators against independent oracles on random systems and graphs:
scipy's stiff ODE solver, Van Loan covariances, cvxpy with another solver, closed forms."""
from __future__ import annotations

import networkx as nx
import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st
from scipy.integrate import solve_ivp
from scipy.linalg import expm

import dse.estimators.common_lyapunov as cl
import dse.estimators.input_state_coestimation as ce
import dse.estimators.lyapunov_bounds as lb
import dse.estimators.observer_network_simulation as sim
from dse.estimators.exponential_integrators import phi_functions
from dse.scenario.graphs import laplacian

SETTINGS = settings(max_examples=6, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def random_network(seed: int, N: int = 4, n: int = 3, p: int = 1, m: int = 1, alpha: float = 5.0,
                   property_test: bool = False):
    """A random Hurwitz process, a random connected graph, gains making every Ā_i(g) Hurwitz and
    P_i a common Lyapunov matrix of the two vertices (from the LMI)."""
    rng = np.random.default_rng(seed)
    X = rng.standard_normal((n, n))
    A = X - (np.abs(np.linalg.eigvals(X)).max() + 0.5) * np.eye(n)
    B = rng.standard_normal((n, p))
    G = nx.connected_watts_strogatz_graph(N, 2, 0.5, seed=seed) if N > 3 else nx.path_graph(N)
    lap = laplacian(G)
    C = rng.standard_normal((N, m, n))
    L = 0.3 * rng.standard_normal((N, n, m))
    J = 0.3 * rng.standard_normal((N, p, m))
    K = np.stack([np.eye(p)] * N)
    sigma = rng.uniform(0.5, 1.0, N)
    P = []
    for i in range(N):
        r = cl.common_lyapunov(ce.error_vertices(A, B, C[i], L[i], J[i], sigma[i], K[i]), 1e-6)
        ok = r.P is not None and r.margin > 0
        if property_test:
            assume(ok)
        assert ok, f"seed {seed}: node {i} has no common Lyapunov matrix"
        P.append(r.P)
    return dict(A=A, B=B, C=C, L=L, J=J, K=K, sigma=sigma, P=np.array(P), lap=lap, alpha=alpha, rng=rng)


@SETTINGS
@given(st.integers(0, 10_000))
def test_estimate_form_equals_error_form(seed):
    """(22)-(23) in estimate coordinates give exactly the error system (26) with φ_i = [0; −σKw − ẇ]."""
    s = random_network(seed, property_test=True)
    rng = s.pop("rng")
    net = ce.coestimation_network(**s)
    n, p, N = net.n, net.p, net.N
    x, w, wdot = rng.standard_normal(n), rng.standard_normal(p), rng.standard_normal(p)
    e, g = rng.standard_normal((N, n + p)), rng.uniform(size=N)
    edot = net.estimate_rhs(x, e, g, w)
    xdot = s["A"] @ x + s["B"] @ w
    zdot_est = np.concatenate([xdot[None] - edot[:, :n], edot[:, n:] - wdot[None]], axis=1).reshape(-1)
    z = ce.errors_from_estimates(x, w, e, n).reshape(-1)
    S = ce.stacked_error_matrix(s["A"], s["B"], s["C"], s["L"], s["J"], s["K"], s["sigma"], s["P"], s["lap"],
                                s["alpha"], g)
    phi = np.zeros((N, n + p))
    phi[:, n:] = ce.input_forcing(s["K"], s["sigma"], w, wdot)
    np.testing.assert_allclose(zdot_est, S @ z + phi.reshape(-1), rtol=1e-12, atol=1e-12 * np.abs(zdot_est).max())


@SETTINGS
@given(st.integers(0, 10_000))
def test_lyapunov_identity_and_hurwitz(seed):
    """(54): SᵀP + PS = −Q̄ for fixed roles, and S Hurwitz; residual to machine precision."""
    s = random_network(seed, property_test=True)
    s.pop("rng")
    N = len(s["P"])
    g = (np.arange(N) % 2).astype(float)
    Abars = [ce.error_matrix(s["A"], s["B"], s["C"][i], s["L"][i], s["J"][i], s["sigma"][i], s["K"][i], g[i])
             for i in range(N)]
    S = ce.stacked_error_matrix(s["A"], s["B"], s["C"], s["L"], s["J"], s["K"], s["sigma"], s["P"], s["lap"],
                                s["alpha"], g)
    Pb = ce.block_diag(list(s["P"]))
    Qbar = lb.qbar_fixed(Abars, s["P"], s["lap"], s["alpha"])
    np.testing.assert_allclose(S.T @ Pb + Pb @ S, -Qbar, atol=1e-11 * np.abs(Qbar).max())
    assert np.linalg.eigvalsh(Qbar).min() > 0
    assert np.linalg.eigvals(S).real.max() < 0


def test_qbar_eps_min_eigenvalue_is_eps():
    """λ_min(εI + 2α(L⊗I)) = ε exactly for any graph (L has the null vector 1)."""
    lap = laplacian(nx.petersen_graph())
    v = np.linalg.eigvalsh(lb.qbar_eps(np.full(10, 3e-6), lap, 25.0, 6))[0]
    assert abs(v - 3e-6) < 1e-12


@SETTINGS
@given(st.integers(0, 10_000))
def test_lmi_certificate_and_second_solver(seed):
    """Clarabel's max-margin P certifies (28)-(29) by numpy eigenvalues, and SCS finds the same optimum."""
    import cvxpy as cp

    s = random_network(seed, N=2, property_test=True)
    verts = ce.error_vertices(s["A"], s["B"], s["C"][0], s["L"][0], s["J"][0], s["sigma"][0], s["K"][0])
    r = cl.common_lyapunov(verts, 1e-6)
    assert r.status == "optimal" and r.margin > 0
    assert abs(cl.vertex_margin(verts, r.P) + r.margin) <= 1e-6 * max(1.0, r.margin)
    d = verts[0].shape[0]
    P, t = cp.Variable((d, d), symmetric=True), cp.Variable()
    cons = [P >> 0, cp.trace(P) == d] + [A.T @ P + P @ A << -t * np.eye(d) for A in verts]
    cp.Problem(cp.Maximize(t), cons).solve(solver="SCS", eps=1e-9, max_iters=200_000)
    assert abs(t.value - r.margin) <= 2e-4 * max(1.0, abs(r.margin))


def test_lmi_infeasible_reports_status_not_crash():
    """An unstable vertex makes (28)-(29) infeasible: negative margin and a solver status, no exception."""
    A0 = np.array([[0.2, 1.0], [0.0, -1.0]])
    r = cl.common_lyapunov([A0, -np.eye(2)], 1e-6)
    assert r.margin < 0
    assert r.status in ("infeasible", "infeasible_inaccurate") or r.status.startswith("solver_error")
    assert r.feasible_P is None


def test_phi_functions_against_series():
    rng = np.random.default_rng(0)
    M = rng.standard_normal((5, 5)) * 0.3
    E, P1, P2 = phi_functions(M, 0.7)
    Z = 0.7 * M
    from math import factorial
    s1 = sum(np.linalg.matrix_power(Z, k) / factorial(k + 1) for k in range(30))
    s2 = sum(np.linalg.matrix_power(Z, k) / factorial(k + 2) for k in range(30))
    np.testing.assert_allclose(E, expm(Z), atol=1e-13)
    np.testing.assert_allclose(P1, s1, atol=1e-13)
    np.testing.assert_allclose(P2, s2, atol=1e-13)


@pytest.mark.parametrize("seed", [1, 2, 6])
def test_simulation_against_stiff_scipy_solver(seed):
    """ETD2RK (fixed roles) against scipy's Radau at rtol 1e-10 on a stiff random network (α = 200)."""
    s = random_network(seed, alpha=200.0)
    s.pop("rng")
    net = ce.coestimation_network(**s)
    n, N, q = net.n, net.N, net.q
    signal = sim.SinusoidalInput(np.array([0.5]), np.array([[1.0, 0.3]]), np.array([[0.7, 1.9]]), np.array([[0.0, 1.0]]))
    g = (np.arange(N) % 2 == 0).astype(float)
    x0 = np.linspace(-1, 1, n)
    tr = sim.simulate(net, sim.FixedRoles(g), signal, x0, np.zeros((N, q)), t_end=4.0, h=0.004, record_every=25)
    M = net.augmented_drift()

    def rhs(t, u):
        out = M @ u
        out[:n] += net.B @ signal(t)
        out[n:] += net.injection(u[None, :n], u[None, n:].reshape(1, N, q), g[None])[0].reshape(-1)
        return out

    assert np.linalg.eigvals(M).real.min() < -100  # stiff
    ref = solve_ivp(rhs, (0, 4.0), np.r_[x0, np.zeros(N * q)], method="Radau", rtol=1e-10, atol=1e-12, t_eval=tr.t)
    np.testing.assert_allclose(tr.e[0].reshape(len(tr.t), -1), ref.y[n:].T, atol=2e-5)
    np.testing.assert_allclose(tr.x[0], ref.y[:n].T, atol=2e-6)


def test_noise_factors_reproduce_exact_covariance():
    """Σ_c F_cᵀF_c equals ∫_0^h e^{Ms} G Gᵀ e^{Mᵀs} ds (adaptive quadrature) with all roles active, on a
    stiff network (|λ| h ≫ 1, where Van Loan's exponential at the full step loses digits)."""
    from scipy.integrate import quad_vec

    s = random_network(8, alpha=50.0)
    s.pop("rng")
    net = ce.coestimation_network(**s)
    rng = np.random.default_rng(1)
    noise = sim.NoiseModel(rng.uniform(0, 0.3, (net.n, 1)), rng.uniform(0, 0.5, (net.N, net.C.shape[1], 1)))
    M = net.augmented_drift()
    h = 0.05
    assert np.abs(np.linalg.eigvals(M)).max() * h > 10
    F, scale = sim.noise_factors(M, net, noise, h)
    D = M.shape[0]
    G = np.zeros((D, 1 + net.N))
    G[:net.n, 0] = noise.process[:, 0]
    LJH = np.einsum("iqm,imk->iqk", net.LJ, noise.measurement)
    for i in range(net.N):
        G[net.n + i * net.q:net.n + (i + 1) * net.q, 1 + i] = LJH[i, :, 0]
    GG = G @ G.T
    Sig = quad_vec(lambda u: (lambda E: E @ GG @ E.T)(expm(M * u)), 0.0, h, epsabs=1e-14, epsrel=1e-12)[0]
    np.testing.assert_allclose(F.T @ F, Sig, atol=1e-9 * np.abs(Sig).max())
    np.testing.assert_allclose(lb.discrete_noise(M, GG, h)[1], Sig, atol=1e-9 * np.abs(Sig).max())


def test_role_law_matches_the_exponential_formulas():
    """g = 1 − e^{−β(t − t_on)} after entering the disc and e^{−β(t − t_off)} after leaving (Sec. 5)."""
    roles = sim.ProximityRoles(np.array([[0.0, 0.0]]), 1.0, 2.0, (0, 1))
    h, T = 1e-3, 3.0
    ts = np.arange(0, T + h / 2, h)
    pos = np.c_[-1.5 + ts, np.zeros_like(ts)]      # enters at t = 0.5, leaves at t = 2.5
    g = roles.initial(pos[:1])
    out = [g[0, 0]]
    for k in range(len(ts) - 1):
        g = roles.advance(g, pos[k:k + 1], pos[k + 1:k + 2], h)
        out.append(g[0, 0])
    out = np.array(out)
    expect = np.where(ts < 0.5, 0.0, 1 - np.exp(-2.0 * (ts - 0.5)))
    after = ts >= 2.5
    g_off = 1 - np.exp(-2.0 * 2.0)
    expect[after] = g_off * np.exp(-2.0 * (ts[after] - 2.5))
    np.testing.assert_allclose(out, expect, atol=1e-9)


def test_mean_square_bound_dominates_exact_moments_random():
    """(46) against the exact E{V} of a random fixed-role network with noise (Prop. 4.1)."""
    s = random_network(7, alpha=10.0)
    s.pop("rng")
    N, n, p = len(s["P"]), s["A"].shape[0], s["B"].shape[1]
    q = n + p
    g = np.ones(N)
    S = ce.stacked_error_matrix(s["A"], s["B"], s["C"], s["L"], s["J"], s["K"], s["sigma"], s["P"], s["lap"], s["alpha"], g)
    Abars = [ce.error_matrix(s["A"], s["B"], s["C"][i], s["L"][i], s["J"][i], s["sigma"][i], s["K"][i], 1.0) for i in range(N)]
    qmin = np.linalg.eigvalsh(lb.qbar_fixed(Abars, s["P"], s["lap"], s["alpha"]))[0]
    v, h = 0.2 * np.ones(n), 0.3 * np.ones((N, 1))
    G = np.zeros((N * q, 1 + N))
    G[:, 0] = np.tile(np.r_[v, np.zeros(p)], N)
    for i in range(N):
        G[i * q:(i + 1) * q, 1 + i] = np.r_[-s["L"][i] @ h[i], s["J"][i] @ h[i]]
    Sig = lb.noise_covariance_sequence(S, G, 0.05, 200)
    z0 = np.tile(np.r_[np.ones(n), -np.ones(p)], N)
    t = 0.05 * np.arange(201)
    m = np.stack([expm(S * tk) @ z0 for tk in t])  # w ≡ 0: φ = 0
    Pb = ce.block_diag(list(s["P"]))
    EV = np.einsum("ti,ij,tj->t", m, Pb, m) + np.einsum("ij,tji->t", Pb, Sig)
    r_star = max(np.linalg.norm(G[:, 1 + i]) for i in range(N))
    c = lb.mean_square_constants(s["P"], qmin, 0.0, float(np.linalg.norm(v)), r_star, N)
    assert np.all(EV <= lb.mean_square_bound(t, EV[0], c["kappa"], c["eta"]) + 1e-12)
