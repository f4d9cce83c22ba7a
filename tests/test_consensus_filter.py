"""Consensus filters for a scalar random walk under noisy communication.

Checks the exact covariance machinery (recursion (22), unrolled (23), steady state (15) by
three methods, trace formula (16) printed and corrected), the plain filter's closed forms
and bounds, and the Monte Carlo simulator (pathwise identities (17), (19), (20) and second moments against the exact
recursion).  Reference numbers are our independently computed values for the paper's
example: 3-node path graph, Q = I - 0.4 L, q = 1, r = 25. The gain optimiser is tested in
tests/test_savas_gain_tuning.py.
"""

from __future__ import annotations

import networkx as nx
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from dse.estimators.consensus_covariance import (
    asymptotic_covariance_lyapunov,
    asymptotic_covariance_modal,
    asymptotic_covariance_series,
    communication_noise_gain,
    error_transition_matrix,
    filtered_covariance,
    geometric_gram_sum,
    predictive_covariance_sequence,
    predictive_covariance_unrolled,
    reinjection_matrix,
    round_noise_gram,
)
from dse.estimators.consensus_filter import ConsensusFilterRun, simulate_consensus_filter
from dse.estimators.consensus_trace import (
    asymptotic_trace_from_spectrum,
    averaged_iterates_deviation_norm,
    averaged_iterates_deviation_norm_modal,
    averaged_round_noise_covariance,
    carli_asymptotic_trace,
    carli_trace_lower_bound,
    carli_trace_lower_bound_asymptotic,
    consensus_mode_variance,
    trace_formula_corrected,
    trace_formula_printed,
)
from dse.estimators.gain_tuning import optimal_carli_gain, optimal_gain_no_communication, optimal_reinjection_gains

Q_PATH = np.eye(3) - 0.4 * np.array([[1.0, -1.0, 0.0], [-1.0, 2.0, -1.0], [0.0, -1.0, 1.0]])
QR = dict(q=1.0, r=25.0)
N_PATH = 3

HYP = settings(max_examples=25, deadline=None, database=None, suppress_health_check=[HealthCheck.too_slow])


def rel_err(a, b) -> float:
    a, b = np.asarray(a), np.asarray(b)
    return float(np.max(np.abs(a - b)) / max(np.max(np.abs(b)), 1e-300))


def kf_prior_variances(sigma0, n_steps, n, q=1.0, r=25.0):
    """Centralised Kalman filter prior variance P_KF(k|k-1): a scalar KF on the mean of n sensors."""
    out, P = [], sigma0
    for _ in range(n_steps):
        out.append(P)
        P = P * (r / n) / (P + r / n) + q
    return np.array(out)


# --------------------------------------------------------------------------------------
# strategies
# --------------------------------------------------------------------------------------


@st.composite
def connected_consensus_matrices(draw, max_nodes=7):
    """Q = I - eps L on a random connected graph, 0 < eps < 1/d_max (symmetric, nonnegative, primitive)."""
    n = draw(st.integers(2, max_nodes))
    G = nx.random_labeled_tree(n, seed=draw(st.integers(0, 2**31 - 1)))
    extra = draw(st.lists(st.tuples(st.integers(0, n - 1), st.integers(0, n - 1)), max_size=2 * n))
    G.add_edges_from((i, j) for i, j in extra if i != j)
    L = nx.laplacian_matrix(G, nodelist=range(n)).toarray().astype(np.float64)
    frac = draw(st.floats(0.05, 0.95))
    return np.eye(n) - frac / L.diagonal().max() * L


filter_params = st.fixed_dictionaries(
    dict(
        ell=st.floats(0.02, 1.0),
        zeta=st.floats(0.0, 1.0),
        m=st.integers(0, 8),
        sigma_c=st.floats(0.0, 3.0),
        q=st.floats(0.1, 3.0),
        r=st.floats(0.5, 40.0),
    )
)


# --------------------------------------------------------------------------------------
# V1, V2: consensus matrix and the re-injection matrix
# --------------------------------------------------------------------------------------


def test_v1_path_graph_consensus_matrix():
    Q = Q_PATH
    np.testing.assert_allclose(Q, [[0.6, 0.4, 0.0], [0.4, 0.2, 0.4], [0.0, 0.4, 0.6]], atol=1e-15)
    assert np.array_equal(Q, Q.T) and np.all(Q >= 0)
    np.testing.assert_allclose(Q.sum(axis=0), 1.0, atol=1e-12)
    np.testing.assert_allclose(Q.sum(axis=1), 1.0, atol=1e-12)
    np.testing.assert_allclose(np.linalg.eigvalsh(Q), [-0.2, 0.6, 1.0], atol=1e-12)


@given(Q=connected_consensus_matrices(), zeta=st.floats(0.0, 1.0), m=st.integers(0, 10))
@HYP
def test_v2_reinjection_matrix_is_stochastic_with_unit_spectral_radius(Q, zeta, m):
    Qd = reinjection_matrix(Q, m, zeta)
    n = Q.shape[0]
    explicit = zeta * np.eye(n) + (1 - zeta) / (m + 1) * sum(np.linalg.matrix_power(Q, i) for i in range(m + 1))
    np.testing.assert_allclose(Qd, explicit, atol=1e-12)
    np.testing.assert_allclose(Qd @ np.ones(n), 1.0, atol=1e-12)
    assert np.all(Qd >= -1e-15)
    assert abs(np.max(np.abs(np.linalg.eigvals(Qd))) - 1.0) < 1e-12
    S = round_noise_gram(Q, m)
    explicit_S = sum((np.linalg.matrix_power(Q, j) @ np.linalg.matrix_power(Q, j).T for j in range(m)), np.zeros((n, n)))
    np.testing.assert_allclose(S, explicit_S, atol=1e-12)


def test_zero_rounds_means_no_communication():
    for zeta in (0.0, 0.3, 1.0):
        np.testing.assert_array_equal(reinjection_matrix(Q_PATH, 0, zeta), np.eye(3))
    np.testing.assert_array_equal(round_noise_gram(Q_PATH, 0), np.zeros((3, 3)))
    np.testing.assert_array_equal(error_transition_matrix(Q_PATH, 0, 0.5, reinjection=False), np.eye(3))
    assert communication_noise_gain(3, 0.4, reinjection=True) == pytest.approx(0.15)
    assert communication_noise_gain(3, 0.4, reinjection=False) == 1.0
    # A2 with zeta = 1 (any m), A2 with m = 0 (any zeta) and A1 with m = 0 are one filter.
    kw = dict(ell=0.3, sigma_c=1.7, sigma0=1.0, n_steps=8, **QR)
    ref = predictive_covariance_sequence(Q_PATH, m=0, reinjection=False, **kw)
    for m, zeta in ((0, 0.0), (0, 0.6), (4, 1.0)):
        np.testing.assert_allclose(
            predictive_covariance_sequence(Q_PATH, m=m, zeta=zeta, reinjection=True, **kw), ref, rtol=1e-13
        )


# --------------------------------------------------------------------------------------
# V4, V5, V6: recursion vs unrolled; Lyapunov vs series vs modal; (16) corrected vs Lyapunov
# --------------------------------------------------------------------------------------


@given(Q=connected_consensus_matrices(), p=filter_params, sigma0=st.floats(0.0, 5.0), reinjection=st.booleans())
@HYP
def test_v4_unrolled_closed_form_23_equals_recursion_22(Q, p, sigma0, reinjection):
    kw = dict(p, sigma0=sigma0, n_steps=21, reinjection=reinjection)
    rec = predictive_covariance_sequence(Q, **kw)
    unr = predictive_covariance_unrolled(Q, **kw)
    assert rel_err(unr, rec) < 1e-12
    np.testing.assert_allclose(rec[0], sigma0 * np.ones(Q.shape * 1))


@given(Q=connected_consensus_matrices(), p=filter_params, reinjection=st.booleans())
@HYP
def test_v5_steady_state_lyapunov_series_modal_agree(Q, p, reinjection):
    lyap = asymptotic_covariance_lyapunov(Q, reinjection=reinjection, **p)
    series = asymptotic_covariance_series(Q, reinjection=reinjection, **p)
    modal = asymptotic_covariance_modal(Q, reinjection=reinjection, **p)
    assert rel_err(series, lyap) < 1e-10
    assert rel_err(modal, lyap) < 1e-10
    # the defining (Stein) equation's residual
    A = error_transition_matrix(Q, p["m"], p["zeta"], reinjection=reinjection)
    g = communication_noise_gain(p["m"], p["zeta"], reinjection=reinjection)
    n = Q.shape[0]
    B = p["ell"] ** 2 * p["r"] * A @ A.T + p["q"] * np.ones((n, n)) + (g * p["sigma_c"]) ** 2 * round_noise_gram(Q, p["m"])
    resid = (1 - p["ell"]) ** 2 * A @ lyap @ A.T + B - lyap
    assert np.max(np.abs(resid)) < 1e-10 * np.max(np.abs(lyap))


def test_recursion_converges_to_steady_state():
    p = dict(ell=0.25, zeta=0.3, m=3, sigma_c=1.0, **QR)
    seq = predictive_covariance_sequence(Q_PATH, sigma0=1.0, n_steps=400, reinjection=True, **p)
    assert rel_err(seq[-1], asymptotic_covariance_lyapunov(Q_PATH, reinjection=True, **p)) < 1e-12


def test_transient_term_is_N_sigma0_decay():
    """(23): with P(0|-1) = sigma0 11^T the sigma0 term is sigma0 (1-ell)^{2k} 11^T (trace N sigma0 (1-ell)^{2k})."""
    for reinjection in (False, True):
        kw = dict(ell=0.25, zeta=0.4, m=3, sigma_c=1.5, n_steps=10, reinjection=reinjection, **QR)
        d = predictive_covariance_sequence(Q_PATH, sigma0=1.0, **kw) - predictive_covariance_sequence(Q_PATH, sigma0=0.0, **kw)
        k = np.arange(10)
        np.testing.assert_allclose(d, 0.75 ** (2 * k)[:, None, None] * np.ones((10, 3, 3)), atol=1e-13)
    assert 3 * 0.75**8 == pytest.approx(0.3003, abs=5e-5)


@given(Q=connected_consensus_matrices(), p=filter_params)
@HYP
def test_v6_corrected_trace_formula_16_equals_lyapunov_trace(Q, p):
    lyap = np.trace(asymptotic_covariance_lyapunov(Q, reinjection=True, **p))
    assert abs(trace_formula_corrected(Q, **p) - lyap) < 1e-10 * lyap


@given(Q=connected_consensus_matrices(), p=filter_params)
@HYP
def test_carli_closed_form_equals_lyapunov_trace(Q, p):
    p = {k: v for k, v in p.items() if k != "zeta"}
    lyap = np.trace(asymptotic_covariance_lyapunov(Q, reinjection=False, **p))
    assert abs(carli_asymptotic_trace(Q, **p) - lyap) < 1e-10 * lyap


def test_trace_formula_vectorises_over_gains():
    ell = np.array([[0.1], [0.4], [1.0]])
    zeta = np.array([[0.0, 0.5, 1.0]])
    J = trace_formula_corrected(Q_PATH, ell=ell, zeta=zeta, m=3, sigma_c=1.2, **QR)
    assert J.shape == (3, 3)
    for i in range(3):
        for j in range(3):
            lyap = asymptotic_covariance_lyapunov(Q_PATH, ell=ell[i, 0], zeta=zeta[0, j], m=3, sigma_c=1.2, reinjection=True, **QR)
            assert J[i, j] == pytest.approx(np.trace(lyap), rel=1e-12)


def test_geometric_gram_sum_is_accurate_near_unit_modulus():
    for lam in (1.0, -1.0, 1 - 2.0**-52, 1 - 1e-9, -(1 - 1e-12), 0.999, 0.0, 0.5j + 0.5):
        for p in (0, 1, 2, 7, 50):
            direct = sum(abs(lam) ** (2 * j) for j in range(p))
            assert float(geometric_gram_sum(lam, p)) == pytest.approx(direct, rel=1e-12, abs=0.0)


def test_modal_per_agent_variances_on_path_graph():
    """§3.3: agents 1, 3 have p0/3 + p1/2 + p2/6, the middle agent p0/3 + 2 p2/3."""
    P = asymptotic_covariance_modal(Q_PATH, ell=0.25, zeta=0.2, m=2, sigma_c=1.0, reinjection=True, **QR)
    V = np.column_stack([np.ones(3) / np.sqrt(3), np.array([1, 0, -1]) / np.sqrt(2), np.array([1, -2, 1]) / np.sqrt(6)])
    p = np.diag(V.T @ P @ V)
    np.testing.assert_allclose(V.T @ P @ V, np.diag(p), atol=1e-12)
    np.testing.assert_allclose(np.diag(P), [p[0] / 3 + p[1] / 2 + p[2] / 6, p[0] / 3 + 2 * p[2] / 3, p[0] / 3 + p[1] / 2 + p[2] / 6], rtol=1e-12)
    assert P[1, 1] < P[0, 0]


# --------------------------------------------------------------------------------------
# V7, V8: the printed (16) and the non-normal counterexample
# --------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "ell, zeta, m, sigma_c, lyap_ref, printed_ref",
    [
        (0.25, 0.3, 3, 1.0, 12.065038, 12.059614),
        (0.5, 0.1, 1, 2.0, 21.690307, 19.861390),
        (0.2, 0.0, 5, 0.5, 11.421924, 11.421795),
        (0.3, 0.7, 2, 3.0, 15.939498, 15.880936),
    ],
)
def test_v7_printed_trace_formula_differs_from_the_steady_state(ell, zeta, m, sigma_c, lyap_ref, printed_ref):
    p = dict(ell=ell, zeta=zeta, m=m, sigma_c=sigma_c, **QR)
    lyap = np.trace(asymptotic_covariance_lyapunov(Q_PATH, reinjection=True, **p))
    corrected = trace_formula_corrected(Q_PATH, **p)
    printed = trace_formula_printed(Q_PATH, **p)
    assert lyap == pytest.approx(lyap_ref, abs=6e-7)
    assert corrected == pytest.approx(lyap, rel=1e-12)
    assert printed == pytest.approx(printed_ref, abs=6e-7)
    assert lyap - printed > 1e-5  # printed (16) is too small for every m >= 1 with sigma_c > 0, zeta < 1


def test_v7_printed_formula_m0_pathologies_are_returned_verbatim():
    kw = dict(ell=0.25, m=0, sigma_c=1.0, **QR)
    ref = trace_formula_corrected(Q_PATH, zeta=0.3, **kw)  # m = 0: no rounds, independent of zeta
    assert ref == pytest.approx(3 * (0.25**2 * 25 + 1) / (1 - 0.75**2), rel=1e-14)
    # bracket (1 - lam^-2)/(1 - lam^2) = -1/lam^2 < 0 makes the printed value too small ...
    beta2 = (1 - 0.3) ** 2
    extra = beta2 * sum(-1 / lam**2 / (1 - 0.75**2) for lam in (0.6, -0.2))
    assert trace_formula_printed(Q_PATH, zeta=0.3, **kw) == pytest.approx(ref + extra, rel=1e-12)
    # ... unless zeta = 1 (or sigma_c = 0), which removes the term: the paper's "zeta = 1 for m = 0"
    assert trace_formula_printed(Q_PATH, zeta=1.0, **kw) == pytest.approx(ref, rel=1e-14)
    # a zero eigenvalue makes it -inf; the complete graph's Q = 11^T/N has eigenvalues 0 up to rounding
    assert asymptotic_trace_from_spectrum([1.0, 0.0, 0.0], printed=True, zeta=0.3, **kw) == -np.inf
    assert asymptotic_trace_from_spectrum([1.0, 0.0, 0.0], printed=True, zeta=1.0, **kw) == pytest.approx(ref, rel=1e-14)
    Q_avg = np.full((3, 3), 1 / 3)
    assert trace_formula_printed(Q_avg, zeta=0.3, **kw) < -1e20
    assert trace_formula_printed(Q_avg, zeta=1.0, **kw) == pytest.approx(ref, rel=1e-14)


def _non_normal_doubly_stochastic():
    P_cycle = np.roll(np.eye(4), 1, axis=1)
    P_swap = np.eye(4)[[1, 0, 2, 3]]
    return 0.4 * np.eye(4) + 0.35 * P_cycle + 0.25 * P_swap


def test_v8_non_normal_Q_breaks_the_trace_formula():
    Q = _non_normal_doubly_stochastic()
    assert np.all(Q >= 0)
    np.testing.assert_allclose(Q.sum(0), 1, atol=1e-15)
    np.testing.assert_allclose(Q.sum(1), 1, atol=1e-15)
    assert np.max(np.abs(Q @ Q.T - Q.T @ Q)) > 0.1  # not normal
    p = dict(ell=0.25, zeta=0.3, m=3, sigma_c=1.0, **QR)
    lyap = asymptotic_covariance_lyapunov(Q, reinjection=True, **p)
    assert rel_err(asymptotic_covariance_series(Q, reinjection=True, **p), lyap) < 1e-10
    formula = asymptotic_trace_from_spectrum(np.linalg.eigvals(Q), **p)
    assert abs(formula - np.trace(lyap)) > 1e-3 * np.trace(lyap)
    with pytest.raises(ValueError, match="symmetric"):
        trace_formula_corrected(Q, **p)
    with pytest.raises(ValueError, match="symmetric"):
        asymptotic_covariance_modal(Q, reinjection=True, **p)


def test_trace_formula_holds_for_normal_non_symmetric_Q():
    """A circulant (normal, complex spectrum) Q: (16) with the paper's |.| is exact."""
    Q = 0.5 * np.eye(5) + 0.3 * np.roll(np.eye(5), 1, axis=1) + 0.2 * np.roll(np.eye(5), 2, axis=1)
    assert np.allclose(Q @ Q.T, Q.T @ Q) and not np.allclose(Q, Q.T)
    p = dict(ell=0.2, zeta=0.35, m=4, sigma_c=1.3, **QR)
    lyap = np.trace(asymptotic_covariance_lyapunov(Q, reinjection=True, **p))
    assert asymptotic_trace_from_spectrum(np.linalg.eigvals(Q), **p) == pytest.approx(lyap, rel=1e-10)


# --------------------------------------------------------------------------------------
# V15, C-III: the plain filter (Fig. 1)
# --------------------------------------------------------------------------------------

FIG1 = {  # A1, ell = 0.25, exact tr P(4|3), sigma0 = 1, m = 0..5
    0.0: (16.113, 10.453, 9.906, 9.760, 9.711, 9.694),
    0.25: (16.113, 10.724, 10.320, 10.306, 10.388, 10.500),
    0.5: (16.113, 11.536, 11.561, 11.945, 12.416, 12.915),
    1.0: (16.113, 14.785, 16.527, 18.502, 20.531, 22.579),
    1.5: (16.113, 20.199, 24.804, 29.429, 34.057, 38.684),
    2.0: (16.113, 27.780, 36.392, 44.728, 52.992, 61.232),
    3.0: (16.113, 49.438, 69.500, 88.438, 107.092, 125.654),
}


def _trace_P43(Q, *, reinjection, sigma0=1.0, zeta=1.0, **kw):
    return float(np.trace(predictive_covariance_sequence(Q, sigma0=sigma0, n_steps=5, reinjection=reinjection, zeta=zeta, **kw)[4]))


def test_fig1_exact_values_and_lower_bounds():
    for sigma_c, row in FIG1.items():
        for m, ref in enumerate(row):
            t = _trace_P43(Q_PATH, ell=0.25, m=m, sigma_c=sigma_c, reinjection=False, **QR)
            assert t == pytest.approx(ref, abs=5e-4)
            bound = carli_trace_lower_bound(ell=0.25, m=m, sigma_c=sigma_c, k=4)
            assert t >= bound
    # sum_{i<4} 0.75^{2i} = 2.056884765625 (2.0566 when truncated to 4 decimals)
    assert carli_trace_lower_bound(ell=0.25, m=1, sigma_c=1.0, k=4) == pytest.approx(2.056884765625, rel=1e-15)


def test_v15_carli_asymptotic_trace_values_and_bounds():
    refs = {
        0.0: (17.571, 11.198, 10.649, 10.504, 10.455, 10.438),
        1.0: (17.571, 15.760, 17.729, 19.932, 22.191, 24.467),
        2.0: (17.571, 29.448, 38.967, 48.218, 57.397, 66.552),
    }
    for sigma_c, row in refs.items():
        for m, ref in enumerate(row):
            J = carli_asymptotic_trace(Q_PATH, ell=0.25, m=m, sigma_c=sigma_c, **QR)
            assert J == pytest.approx(ref, abs=5e-4)
    for ell in (0.05, 0.25, 0.7, 1.0):
        for m in range(0, 40, 3):
            for sigma_c in (0.0, 0.3, 2.0):
                J = carli_asymptotic_trace(Q_PATH, ell=ell, m=m, sigma_c=sigma_c, **QR)
                lb = carli_trace_lower_bound_asymptotic(ell=ell, m=m, sigma_c=sigma_c)
                assert J >= lb >= sigma_c**2 * m
                assert lb == pytest.approx(sigma_c**2 * m / (ell * (2 - ell)))
    # J_C grows without bound in m even with a re-optimised gain (§III-B made precise)
    Js = [optimal_carli_gain(Q_PATH, m=m, sigma_c=1.0, **QR).J for m in (1, 10, 100)]
    assert Js[0] < Js[1] < Js[2] and Js[2] >= 100 * 1.0


def test_c3_threshold_noise_levels_for_increase_in_m():
    """tr P(4|3) of A1 (ell = 0.25) increases from m to m+1 iff sigma_c exceeds the threshold."""
    kw = dict(ell=0.25, reinjection=False, **QR)
    finite_ref = (1.1431, 0.4888, 0.2624, 0.1527, 0.0908)
    asym_ref = (1.1819, 0.4668, 0.2493, 0.1449, 0.0861)
    for m in range(5):
        # tr P is affine in sigma_c^2: T(m) = T0(m) + sigma_c^2 G(m)
        T0 = [_trace_P43(Q_PATH, m=mm, sigma_c=0.0, **kw) for mm in (m, m + 1)]
        G = [_trace_P43(Q_PATH, m=mm, sigma_c=1.0, **kw) - t0 for mm, t0 in zip((m, m + 1), T0)]
        thr = np.sqrt((T0[0] - T0[1]) / (G[1] - G[0]))
        assert thr == pytest.approx(finite_ref[m], abs=5e-5)
        for s, increases in ((0.99 * thr, False), (1.01 * thr, True)):
            assert (_trace_P43(Q_PATH, m=m + 1, sigma_c=s, **kw) > _trace_P43(Q_PATH, m=m, sigma_c=s, **kw)) is increases
        J0 = [carli_asymptotic_trace(Q_PATH, ell=0.25, m=mm, sigma_c=0.0, **QR) for mm in (m, m + 1)]
        J1 = [carli_asymptotic_trace(Q_PATH, ell=0.25, m=mm, sigma_c=1.0, **QR) - j for mm, j in zip((m, m + 1), J0)]
        assert np.sqrt((J0[0] - J0[1]) / (J1[1] - J1[0])) == pytest.approx(asym_ref[m], abs=5e-5)


def test_v17_kalman_lower_bound_on_every_agent():
    for sigma0 in (0.0, 1.0):
        kf = kf_prior_variances(sigma0, 10, 3)
        if sigma0 == 1.0:
            assert 3 * kf[4] == pytest.approx(9.533115, abs=1e-6)
            assert kf[4] == pytest.approx(3.1777, abs=5e-5)
        else:
            assert 3 * kf[4] == pytest.approx(8.844364, abs=1e-6)
        for reinjection, zeta in ((False, 1.0), (True, 0.0), (True, 0.5)):
            for m in (0, 1, 3, 5):
                for sigma_c in (0.0, 1.0):
                    P = predictive_covariance_sequence(
                        Q_PATH, ell=0.25, m=m, sigma_c=sigma_c, sigma0=sigma0, n_steps=10, reinjection=reinjection, zeta=zeta, **QR
                    )
                    assert np.all(np.diagonal(P, axis1=1, axis2=2) >= kf[:, None] - 1e-12)
    P = predictive_covariance_sequence(Q_PATH, ell=0.25, m=5, sigma_c=0.0, sigma0=1.0, n_steps=5, reinjection=False, **QR)
    np.testing.assert_allclose(np.diag(P[4]), [3.2330, 3.2283, 3.2330], atol=5e-5)


# --------------------------------------------------------------------------------------
# C-IV: round-noise heuristics
# --------------------------------------------------------------------------------------


@given(Q=connected_consensus_matrices(), m=st.integers(0, 30), sigma_c=st.floats(0.1, 3.0))
@HYP
def test_c4_round_noise_heuristics(Q, m, sigma_c):
    n = Q.shape[0]
    assert consensus_mode_variance(Q, m) == pytest.approx(m, abs=1e-10)
    dev = averaged_iterates_deviation_norm(Q, m)
    assert dev == pytest.approx(averaged_iterates_deviation_norm_modal(Q, m), rel=1e-9, abs=1e-12)
    lam = np.sort(np.linalg.eigvalsh(Q))[:-1]
    assert dev <= 2.0 / ((m + 1) * (1 - np.max(np.abs(lam)))) + 1e-12  # O(1/m)
    C = averaged_round_noise_covariance(Q, m, sigma_c)
    v0 = np.ones(n) / np.sqrt(n)
    assert v0 @ C @ v0 == pytest.approx(m * sigma_c**2 / (m + 1) ** 2, rel=1e-10, abs=1e-14)
    s_all = geometric_gram_sum(np.linalg.eigvalsh(Q), m)
    assert np.trace(C) == pytest.approx(sigma_c**2 * s_all.sum() / (m + 1) ** 2, rel=1e-10, abs=1e-14)


# --------------------------------------------------------------------------------------
# simulator: pathwise identities (V3, (17)) and Monte Carlo moments (V9-V11)
# --------------------------------------------------------------------------------------


def _simulate(Q=Q_PATH, *, reinjection, m=3, sigma_c=1.3, zeta=0.35, ell=0.25, n_trials=50, n_paths=5, seed=0, n_steps=8, sigma0=1.0):
    return simulate_consensus_filter(
        Q, ell=ell, m=m, sigma_c=sigma_c, sigma0=sigma0, x0_mean=2.5, n_steps=n_steps, n_trials=n_trials,
        rng=np.random.default_rng(seed), reinjection=reinjection, zeta=zeta, n_paths=n_paths, **QR,
    )  # fmt: skip


@pytest.mark.parametrize("reinjection", [False, True])
@pytest.mark.parametrize("m", [0, 1, 4])
def test_v3_pathwise_identities(reinjection, m):
    ell, zeta, sigma_c = 0.25, 0.35, 1.3
    run = _simulate(reinjection=reinjection, m=m, ell=ell, zeta=zeta, sigma_c=sigma_c)
    P, K, N = run.xhat_pred.shape
    assert isinstance(run, ConsensusFilterRun)
    assert run.z_rounds.shape == (P, K, m + 1, N) and run.u.shape == (P, K, m, N)
    ones = np.ones(N)
    Qp = [np.linalg.matrix_power(Q_PATH, i) for i in range(m + 1)]
    tol = dict(rtol=1e-10, atol=1e-10)
    # bookkeeping: (3), (5), (10), (14)
    np.testing.assert_allclose(run.x[:, 1:], run.x[:, :-1] + run.w[:, :-1], **tol)
    np.testing.assert_allclose(run.y, run.x[..., None] + run.n, **tol)
    np.testing.assert_allclose(run.err_pred[:P], run.x[..., None] - run.xhat_pred, **tol)
    np.testing.assert_allclose(run.err_filt[:P], run.x[..., None] - run.xhat_filt, **tol)
    np.testing.assert_allclose(run.xhat_pred[:, 0], 2.5, atol=0)
    np.testing.assert_array_equal(run.z_rounds[:, :, 0], run.xhat_filt)
    # (17)
    np.testing.assert_allclose(run.err_filt[:P], (1 - ell) * run.err_pred[:P] - ell * run.n, **tol)
    # noise pushed through the rounds: sigma_c sum_{i=1}^m Q^{m-i} u(k + i/m)
    pushed = sigma_c * sum((run.u[:, :, i - 1] @ Qp[m - i].T for i in range(1, m + 1)), np.zeros((P, K, N)))
    if reinjection:
        # (19): z(k+1|k) = sum_{i=0}^m Q^i xhat(k|k) + sigma_c sum_{i=1}^m Q^{m-i} u(k+i/m)
        z_closed = run.xhat_filt @ sum(Qp).T + pushed
        np.testing.assert_allclose(run.z_rounds[:, :, m], z_closed, **tol)
        # (13)
        np.testing.assert_allclose(run.xhat_pred[:, 1:], (zeta * run.xhat_filt + (1 - zeta) * run.z_rounds[:, :, m] / (m + 1))[:, :-1], **tol)
        # (20) with w(k) (the paper's w(k+1) is a typo)
        Qd = reinjection_matrix(Q_PATH, m, zeta)
        rhs = run.err_filt[:P] @ Qd.T + run.w[..., None] * ones - (1 - zeta) / (m + 1) * pushed
    else:
        z_closed = run.xhat_filt @ Qp[m].T + pushed  # (9) unrolled
        np.testing.assert_allclose(run.z_rounds[:, :, m], z_closed, **tol)
        np.testing.assert_allclose(run.xhat_pred[:, 1:], run.z_rounds[:, :-1, m], **tol)
        rhs = run.err_filt[:P] @ Qp[m].T + run.w[..., None] * ones - pushed
    np.testing.assert_allclose(run.err_pred[:P, 1:], rhs[:, :-1], **tol)


def test_noise_free_rounds_are_plain_consensus_8():
    run = _simulate(reinjection=False, m=3, sigma_c=0.0)
    for h in range(1, 4):
        np.testing.assert_allclose(run.z_rounds[:, :, h], run.z_rounds[:, :, h - 1] @ Q_PATH.T, rtol=1e-13, atol=1e-13)


def test_simulator_is_reproducible_and_paths_do_not_change_draws():
    a = _simulate(reinjection=True, n_paths=0, seed=7)
    b = _simulate(reinjection=True, n_paths=4, seed=7)
    c = _simulate(reinjection=True, n_paths=4, seed=7)
    np.testing.assert_array_equal(a.err_pred, b.err_pred)
    np.testing.assert_array_equal(a.err_filt, b.err_filt)
    for name in ("x", "y", "xhat_pred", "xhat_filt", "z_rounds", "u", "w", "n"):
        np.testing.assert_array_equal(getattr(b, name), getattr(c, name))
    assert a.x.shape == (0, 8) and a.z_rounds.shape == (0, 8, 4, 3)
    # sigma_c only scales u: the same seed gives the same process and measurement noise
    d = _simulate(reinjection=True, n_paths=4, seed=7, sigma_c=0.0)
    np.testing.assert_array_equal(b.w, d.w)
    np.testing.assert_array_equal(b.n, d.n)
    np.testing.assert_array_equal(b.u, d.u)


def _assert_moments_match(err, P, label):
    """Zero mean and second moments of ``err`` (R, K, N) against the exact ``P`` (K, N, N), within 5 SE."""
    R = err.shape[0]
    d = np.sqrt(np.diagonal(P, axis1=1, axis2=2))  # (K, N)
    mean = err.mean(axis=0)
    assert np.all(np.abs(mean) <= 5 * d / np.sqrt(R) + 1e-12), f"{label}: mean"
    M = np.einsum("rki,rkj->kij", err, err) / R
    se = np.sqrt((d[:, :, None] ** 2 * d[:, None, :] ** 2 + P**2) / R)  # SE of the sample E[e_i e_j]
    assert np.all(np.abs(M - P) <= 5 * se + 1e-12), f"{label}: second moments, worst z = {np.max(np.abs(M - P) / (se + 1e-300)):.2f}"
    tr = np.einsum("rki,rki->rk", err, err).mean(axis=0)
    tr_exact = np.trace(P, axis1=1, axis2=2)
    se_tr = np.sqrt(2.0 * np.einsum("kij,kji->k", P, P) / R)
    assert np.all(np.abs(tr - tr_exact) <= 5 * se_tr), f"{label}: trace"


@pytest.mark.parametrize(
    "label, reinjection, sigma_c, zeta",
    [("A0", False, 0.0, 1.0), ("A1", False, 1.5, 1.0), ("A2", True, 1.5, 0.3), ("A2-zeta0", True, 2.0, 0.0)],
)
def test_v9_v10_v11_monte_carlo_matches_exact_recursion(label, reinjection, sigma_c, zeta):
    kw = dict(ell=0.25, m=3, sigma_c=sigma_c, sigma0=1.0, n_steps=10, reinjection=reinjection, zeta=zeta, **QR)
    run = simulate_consensus_filter(
        Q_PATH, x0_mean=-1.0, n_trials=20_000, rng=np.random.default_rng(20240601), **kw
    )
    P_pred = predictive_covariance_sequence(Q_PATH, **kw)
    _assert_moments_match(run.err_pred, P_pred, label + " predictive")
    _assert_moments_match(run.err_filt, filtered_covariance(P_pred, 0.25, 25.0), label + " filtered (18)")


def test_v8_monte_carlo_matches_exact_for_non_normal_Q():
    Q = _non_normal_doubly_stochastic()
    kw = dict(ell=0.3, m=2, sigma_c=1.0, sigma0=0.5, n_steps=10, reinjection=True, zeta=0.2, **QR)
    run = simulate_consensus_filter(Q, x0_mean=0.0, n_trials=20_000, rng=np.random.default_rng(5), **kw)
    _assert_moments_match(run.err_pred, predictive_covariance_sequence(Q, **kw), "non-normal")


# --------------------------------------------------------------------------------------
# malformed input
# --------------------------------------------------------------------------------------

_GOOD = dict(
    ell=0.25, m=2, sigma_c=1.0, q=1.0, r=25.0, sigma0=1.0, x0_mean=0.0, n_steps=3, n_trials=4, reinjection=True, zeta=0.5, n_paths=1
)


@pytest.mark.parametrize(
    "override, name",
    [
        (dict(Q=np.ones((2, 3)) / 3), "Q"),
        (dict(Q=np.array([[0.5, 0.4], [0.5, 0.5]])), "Q"),
        (dict(Q=np.array([[np.nan, 1.0], [0.5, 0.5]])), "Q"),
        (dict(ell=0.0), "ell"),
        (dict(ell=1.5), "ell"),
        (dict(zeta=-0.1), "zeta"),
        (dict(zeta=1.1), "zeta"),
        (dict(m=-1), "m"),
        (dict(m=1.5), "m"),
        (dict(m=True), "m"),
        (dict(q=-1.0), "q"),
        (dict(r=-1.0), "r"),
        (dict(sigma0=-1.0), "sigma0"),
        (dict(sigma_c=-0.1), "sigma_c"),
        (dict(sigma_c=np.inf), "sigma_c"),
        (dict(x0_mean=np.nan), "x0_mean"),
        (dict(n_steps=0), "n_steps"),
        (dict(n_trials=0), "n_trials"),
        (dict(n_paths=5), "n_paths"),
    ],
)
def test_simulator_rejects_malformed_input(override, name):
    kw = dict(_GOOD, Q=Q_PATH, rng=np.random.default_rng(0))
    kw.update(override)
    Q = kw.pop("Q")
    with pytest.raises(ValueError, match=rf"\b{name}\b"):
        simulate_consensus_filter(Q, **kw)


def test_simulator_rejects_a_non_generator_rng():
    kw = dict(_GOOD, rng=np.random.RandomState(0))
    with pytest.raises(TypeError, match="rng"):
        simulate_consensus_filter(Q_PATH, **kw)


def test_covariance_functions_reject_malformed_input():
    p = dict(m=2, sigma_c=1.0, zeta=0.5, **QR)
    with pytest.raises(ValueError, match="ell"):
        asymptotic_covariance_lyapunov(Q_PATH, ell=0.0, reinjection=True, **p)
    with pytest.raises(ValueError, match="zeta"):
        trace_formula_corrected(Q_PATH, ell=0.2, **dict(p, zeta=np.array([0.2, 1.2])))
    with pytest.raises(ValueError, match="symmetric"):
        trace_formula_printed(_non_normal_doubly_stochastic(), ell=0.2, **p)
    with pytest.raises(ValueError, match="symmetric"):
        carli_asymptotic_trace(_non_normal_doubly_stochastic(), ell=0.2, m=2, sigma_c=1.0, **QR)
    with pytest.raises(ValueError, match="P_pred"):
        filtered_covariance(np.ones(3), 0.2, 1.0)
    # Q = I - eps L with eps > 1/d_max has negative entries and, here, no steady state
    Q_bad = np.eye(3) - 1.2 * (np.eye(3) * [1, 2, 1] - np.array([[0, 1, 0], [1, 0, 1], [0, 1, 0]]))
    with pytest.raises(ValueError, match="steady state"):
        asymptotic_covariance_lyapunov(Q_bad, ell=0.25, m=1, sigma_c=0.0, reinjection=False, **QR)
    with pytest.raises(ValueError, match="formula"):
        optimal_reinjection_gains(Q_PATH, m=1, sigma_c=1.0, formula="paper", **QR)
    with pytest.raises(ValueError, match="grid"):
        optimal_reinjection_gains(Q_PATH, m=1, sigma_c=1.0, grid=(2, 400), **QR)
    with pytest.raises(ValueError, match="n_agents"):
        optimal_gain_no_communication(1.0, 25.0, 0)


def test_configurations_share_draws_and_equal_single_runs():
    """Each configuration of a common-random-numbers run is bit-identical to the single run
    with the same seed (same draw order), for both filters."""
    from dse.estimators.consensus_filter import simulate_consensus_filter_configs

    ells, sigmas, zetas = [0.2, 0.35, 0.5], [0.0, 0.8, 2.0], [0.0, 0.4, 1.0]
    for reinjection in (False, True):
        kw = dict(m=3, q=1.0, r=25.0, sigma0=1.0, x0_mean=0.5, n_steps=6, n_trials=300, reinjection=reinjection, n_paths=2)
        many = simulate_consensus_filter_configs(Q_PATH, ell=ells, sigma_c=sigmas, zeta=zetas,
                                                 rng=np.random.default_rng(11), **kw)
        for c in range(3):
            one = simulate_consensus_filter(Q_PATH, ell=ells[c], sigma_c=sigmas[c], zeta=zetas[c],
                                            rng=np.random.default_rng(11), **kw)
            assert np.array_equal(many.err_pred[:, c], one.err_pred)
            assert np.array_equal(many.err_filt[:, c], one.err_filt)
            assert np.array_equal(many.z_rounds[:, c], one.z_rounds)
            assert np.array_equal(many.u, one.u) and np.array_equal(many.y, one.y)
    with pytest.raises(ValueError, match="common length"):
        simulate_consensus_filter_configs(Q_PATH, ell=[0.2, 0.3], sigma_c=[0.1, 0.2, 0.3], m=1, q=1, r=1, sigma0=1,
                                          x0_mean=0, n_steps=2, n_trials=5, rng=np.random.default_rng(0),
                                          reinjection=False)
