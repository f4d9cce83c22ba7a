"""Gossip Kalman filtering (GIKF), the switched Riccati process and the walk-detectability tools.

Oracles: filterpy's KalmanFilter (one object per sensor, states swapped by hand, H and R passed
explicitly), the information form of the Riccati map, brute-force path enumeration, and the
reference numbers of an independent prototype for example E1.
"""
from __future__ import annotations

import itertools

import numpy as np
import pytest
from filterpy.kalman import KalmanFilter
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import dse.estimators.gossip_kalman as gk
import dse.estimators.switched_riccati as sr
import dse.estimators.walk_detectability as wd

HYP = settings(max_examples=30, deadline=None, database=None, suppress_health_check=[HealthCheck.too_slow])

F1 = np.diag([1.2, 1.1])
Q1 = 0.1 * np.eye(2)


def e1_system(N=10):
    C = [np.array([[1.0, 0.0]]) if n % 2 == 0 else np.array([[0.0, 1.0]]) for n in range(N)]
    return gk.GossipSystem.build(F1, Q1, C, [np.eye(1)] * N, np.eye(2))


def ring_protocol(N=10, p=0.1):
    return gk.MatchingDistribution.single_edge(N, [(n, (n + 1) % N) for n in range(N)], [p] * N)


def random_system(seed, M, m, N, zero_sensor=True):
    rng = np.random.default_rng(seed)
    F = rng.normal(size=(M, M)) * 0.8
    B = rng.normal(size=(M, M))
    Q = B @ B.T / M + 0.05 * np.eye(M)
    Cs, Rs = [], []
    for n in range(N):
        if zero_sensor and n == N - 1:
            Cs.append(np.zeros((0, M)))
            Rs.append(np.zeros((0, 0)))
            continue
        mn = int(rng.integers(1, m + 1))
        Cs.append(rng.normal(size=(mn, M)))
        A = rng.normal(size=(mn, mn))
        Rs.append(A @ A.T + 0.5 * np.eye(mn))
    A0 = rng.normal(size=(M, M))
    return gk.GossipSystem.build(F, Q, Cs, Rs, A0 @ A0.T + np.eye(M)), rng


def random_psd(rng, M, scale=1.0, size=None):
    shape = (M, M + 1) if size is None else (size, M, M + 1)
    Z = rng.normal(size=shape)
    return scale * Z @ np.swapaxes(Z, -1, -2)


# -- Riccati maps -------------------------------------------------------------------------------------

@HYP
@given(seed=st.integers(0, 10_000), M=st.integers(1, 4), m=st.integers(1, 3))
def test_riccati_joseph_equals_information_form_and_filterpy(seed, M, m):
    sys_, rng = random_system(seed, M, m, 3, zero_sensor=False)
    X = random_psd(rng, M) + 0.1 * np.eye(M)
    for n in range(sys_.N):
        got = gk.riccati_step(X, sys_.C[n], sys_.R[n], sys_.F, sys_.Q)
        info = sys_.F @ np.linalg.inv(np.linalg.inv(X) + sys_.C[n].T @ np.linalg.solve(sys_.R[n], sys_.C[n])) @ sys_.F.T + sys_.Q
        np.testing.assert_allclose(got, info, rtol=1e-9, atol=1e-9 * np.abs(info).max())
        kf = KalmanFilter(dim_x=M, dim_z=sys_.C.shape[1])
        kf.F, kf.Q, kf.P, kf.x = sys_.F, sys_.Q, X.copy(), np.zeros((M, 1))
        kf.update(np.zeros((sys_.C.shape[1], 1)), R=sys_.R[n], H=sys_.C[n])
        kf.predict()
        np.testing.assert_allclose(got, kf.P, rtol=1e-9, atol=1e-9 * np.abs(info).max())
        assert np.array_equal(got, got.T)


@HYP
@given(seed=st.integers(0, 10_000), M=st.integers(1, 4))
def test_riccati_bounds_and_zero_observation_is_lyapunov(seed, M):
    sys_, rng = random_system(seed, M, 1, 3)
    X = random_psd(rng, M, 10.0 ** rng.uniform(-2, 8), size=20)
    for n in range(sys_.N):
        f = gk.riccati_step(X, sys_.C[n], sys_.R[n], sys_.F, sys_.Q)
        f0 = gk.lyapunov_step(X, sys_.F, sys_.Q)
        scale = np.maximum(1.0, np.linalg.norm(f0, 2, axis=(1, 2)))
        assert (np.linalg.eigvalsh(f - sys_.Q)[:, 0] / scale).min() > -1e-9      # f_n(X) ⪰ Q
        assert (np.linalg.eigvalsh(f0 - f)[:, 0] / scale).min() > -1e-9          # f_n(X) ⪯ f_0(X)
    last = sys_.N - 1  # a sensor with C = 0: exactly the Lyapunov map
    f0 = gk.lyapunov_step(X, sys_.F, sys_.Q)
    np.testing.assert_allclose(gk.riccati_step(X, sys_.C[last], sys_.R[last], sys_.F, sys_.Q), f0, rtol=0,
                               atol=1e-14 * np.abs(f0).max())


def test_scalar_and_matrix_observation_paths_agree():
    sys_, rng = random_system(3, 3, 1, 4, zero_sensor=False)
    X = random_psd(rng, 3, size=50)
    C2 = np.concatenate([sys_.C[0], np.zeros((1, 3))])  # padded to two rows: the matrix-gain path
    R2 = np.diag([sys_.R[0, 0, 0], 1.0])
    a = gk.riccati_step(X, sys_.C[0], sys_.R[0], sys_.F, sys_.Q)
    b = gk.riccati_step(X, C2, R2, sys_.F, sys_.Q)
    np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-12)


def test_joseph_form_accurate_for_huge_covariances():
    rng = np.random.default_rng(0)
    X = random_psd(rng, 2, 1e14, size=100)
    C, R = np.array([[1.0, 0.0]]), np.eye(1)
    got = gk.riccati_step(X, C, R, F1, Q1)
    info = F1 @ np.linalg.inv(np.linalg.inv(X) + C.T @ C) @ F1.T + Q1
    assert np.abs(got - info)[:, 0, 0].max() < 1e-9
    textbook = gk.riccati_textbook(X, C, R, F1, Q1)
    assert np.abs(textbook - info)[:, 0, 0].max() > 1e-6  # the round-off the Joseph form avoids


def test_entrywise_roundoff_bound_is_the_matrix_form(monkeypatch):
    """The round-off bound of small states, computed entry by entry, is the matrix-form bound (the same
    formula; sums in another order: equal to a few eps), and so is its propagation G E Gᵀ + δI."""
    rng = np.random.default_rng(11)
    for M, m in ((1, 1), (2, 1), (2, 2), (3, 1), (3, 2), (3, 3)):
        sys_, _ = random_system(M * 10 + m, M, m, 4, zero_sensor=True)
        X = random_psd(rng, M, 10.0 ** rng.uniform(-2, 9), size=(64 * 4)).reshape(64, 4, M, M)
        _, K = gk.riccati_step(X, sys_.C, sys_.R, sys_.F, sys_.Q, return_gain=True)
        E = random_psd(rng, M, 1e-12, size=64 * 4).reshape(64, 4, M, M)
        d_entry, G_entry = gk.riccati_roundoff(X, K, sys_.C, sys_.R, sys_.F, sys_.Q)
        E_entry = gk.propagate_error(E, G_entry, d_entry)
        monkeypatch.setattr(gk, "ENTRYWISE_MAX_M", 0)
        d_mat, G_mat = gk.riccati_roundoff(X, K, sys_.C, sys_.R, sys_.F, sys_.Q)
        E_mat = gk.propagate_error(E, G_mat, d_mat)
        monkeypatch.undo()
        np.testing.assert_allclose(d_entry, d_mat, rtol=1e-14)
        np.testing.assert_allclose(G_entry, G_mat, rtol=0, atol=1e-14 * np.abs(G_mat).max())
        np.testing.assert_allclose(E_entry, E_mat, rtol=0, atol=1e-14 * np.abs(E_mat).max())
        assert np.array_equal(E_entry, np.swapaxes(E_entry, -1, -2))


def test_closed_form_2x2_eigenvalues_are_lapacks_bit_for_bit():
    """gk.eigvalsh of 2×2 batches is LAPACK's arithmetic (split test, dlae2): the same bits as
    np.linalg.eigvalsh on random, PSD, diagonal, nearly split, equal-diagonal, zero, tiny and huge matrices."""
    rng = np.random.default_rng(5)
    n = 40_000
    cases = []
    for scale in (0.0, 8.0, 40.0, 300.0):
        A = rng.standard_normal((n, 2, 2)) * np.exp(rng.uniform(-scale, scale, (n, 1, 1)))
        cases.append(A)
        cases.append(A @ np.swapaxes(A, -1, -2) + 1e-3 * np.eye(2))
    B = rng.standard_normal((n, 2, 2))
    B[:, 1, 0] = B[:, 0, 0] * np.exp(rng.uniform(-40, -30, n))            # off-diagonal at the split threshold
    C = rng.standard_normal((n, 2, 2))
    C[:, 1, 1] = C[:, 0, 0] * (1 + 1e-16 * rng.integers(-3, 4, n))        # equal diagonal
    C[:, 1, 0] *= 1e-17
    Z = np.zeros((4, 2, 2))
    Z[1, 0, 0] = 1.0
    cases += [B, C, Z, rng.standard_normal((n, 2, 2)) * 1e-130]
    for A in cases:
        with np.errstate(over="ignore", invalid="ignore"):
            A = 0.5 * (A + np.swapaxes(A, -1, -2))
        A = A[np.isfinite(A).all(axis=(1, 2))]
        assert np.array_equal(gk.eigvalsh(A), np.linalg.eigvalsh(A))
    assert np.array_equal(gk.eigvalsh(A.reshape(-1, 4, 2, 2)), np.linalg.eigvalsh(A.reshape(-1, 4, 2, 2)))


# -- gossip protocols -----------------------------------------------------------------------------------

def test_matchings_are_valid_and_mean_matrix_matches_frequencies():
    rng = np.random.default_rng(1)
    import networkx as nx

    G = nx.random_regular_graph(3, 8, seed=2)
    edges = sorted(G.edges())
    protocols = [gk.MatchingDistribution.single_edge(8, edges, [1.0 / len(edges)] * len(edges)),
                 gk.NodeInitiatedGossip(tuple(tuple(sorted(G.neighbors(i))) for i in range(8))),
                 gk.MatchingDistribution.from_matchings(8, [list(nx.max_weight_matching(G))], [0.3])]
    n_draws = 200_000
    for prot in protocols:
        p = prot.sample(n_draws, rng)
        assert np.all(p[np.arange(n_draws)[:, None], p] == np.arange(8))  # involution
        moved = p != np.arange(8)
        rows, cols = np.nonzero(moved)
        assert all(G.has_edge(int(i), int(p[r, i])) for r, i in zip(rows[:2000], cols[:2000]))
        Abar = prot.mean_matrix()
        assert np.allclose(Abar, Abar.T) and np.allclose(Abar.sum(1), 1) and Abar.min() >= 0
        emp = np.zeros((8, 8))
        np.add.at(emp, (np.tile(np.arange(8), n_draws), p.ravel()), 1.0)
        emp /= n_draws
        se = np.sqrt(Abar * (1 - Abar) / n_draws) + 1e-12
        assert np.abs(emp - Abar).max() / se[np.unravel_index(np.argmax(np.abs(emp - Abar)), se.shape)] < 5.5


# -- one GIKF slot against per-sensor filterpy objects --------------------------------------------------

def test_gikf_step_and_error_recursion_match_filterpy_objects_with_swaps():
    """Per-sensor filterpy filters whose (x, P) are swapped along the matching, updated with the
    sensor's own (H, R) passed explicitly; x is simulated explicitly (short horizon)."""
    sys_, rng = random_system(5, 3, 2, 5)
    sys_ = gk.GossipSystem(0.9 * sys_.F / max(1, np.abs(np.linalg.eigvals(sys_.F)).max()), sys_.Q, sys_.C, sys_.R, sys_.P0)
    prot = gk.MatchingDistribution.single_edge(5, [(0, 1), (1, 2), (2, 3), (3, 4), (4, 0)], [0.15] * 5)
    B, T, N, M, m = 4, 25, 5, 3, sys_.C.shape[1]
    Lq, Lr = np.linalg.cholesky(sys_.Q), sys_.R_chol
    x = rng.normal(size=(B, M)) @ np.linalg.cholesky(sys_.P0).T
    P = np.broadcast_to(sys_.P0, (B, N, M, M)).copy()
    e = np.broadcast_to(x[:, None, :], (B, N, M)).copy()
    kfs = [[KalmanFilter(dim_x=M, dim_z=m) for _ in range(N)] for _ in range(B)]
    for b in range(B):
        for kf in kfs[b]:
            kf.F, kf.Q, kf.P, kf.x = sys_.F, sys_.Q, sys_.P0.copy(), np.zeros((M, 1))
    for t in range(T):
        partners = np.tile(np.arange(N), (B, 1)) if t == 0 else prot.sample(B, rng)
        w = rng.normal(size=(B, M)) @ Lq.T
        v = np.einsum("nij,bnj->bni", Lr, rng.normal(size=(B, N, m)))
        P_new, K = gk.gikf_covariance_step(P, partners, sys_, return_gain=True)
        e = gk.gikf_error_step(e, partners, K, sys_, w, v)
        P = P_new
        for b in range(B):
            old = [(kf.x.copy(), kf.P.copy()) for kf in kfs[b]]
            for n, kf in enumerate(kfs[b]):
                kf.x, kf.P = old[partners[b, n]][0].copy(), old[partners[b, n]][1].copy()
                y = sys_.C[n] @ x[b][:, None] + v[b, n][:, None]
                kf.update(y, R=sys_.R[n], H=sys_.C[n])
                kf.predict()
            x_next = sys_.F @ x[b] + w[b]
            for n, kf in enumerate(kfs[b]):
                np.testing.assert_allclose(kf.P, P[b, n], rtol=1e-10, atol=1e-10)
                np.testing.assert_allclose(x_next - kf.x[:, 0], e[b, n], rtol=1e-8, atol=1e-8)
            x[b] = x_next


def test_simulate_gikf_is_deterministic_and_consistent():
    sys_ = e1_system()
    prot = ring_protocol()
    import dse.estimators.kalman as kal

    T = 40
    cov = kal.kalman_covariances(F1, sys_.C_all, Q1, sys_.R_all, np.eye(2), T + 1)
    env = [np.eye(2)]
    for _ in range(T):
        env.append(gk.lyapunov_step(env[-1], F1, Q1))
    kw = dict(record_times=[1, 2, 40], P_central=cov.P_prior, K_central=cov.gains, envelope=np.array(env),
              j_grid=np.logspace(0, 6, 7), nees_window=(10, 40))
    a = gk.simulate_gikf(sys_, prot, 500, T, np.random.default_rng(3), **kw)
    b = gk.simulate_gikf(sys_, prot, 500, T, np.random.default_rng(3), **kw)
    for k in a:
        np.testing.assert_array_equal(a[k], b[k])
    assert np.nanmin(a["margins"][:, 0]) > -1e-12     # dominates the centralized filter
    assert np.nanmin(a["margins"][1:, 1]) > -1e-12    # ⪰ Q
    s, above, n = a["nees"][:3]
    assert abs(s / n / 2 - 1) < 0.05
    # t = 1: two atoms f_even(P0), f_odd(P0) with traces 2.13 and 2.245 (exact small-t law)
    tr1 = np.exp(a["feat_q"][0][0])
    assert set(np.round(tr1, 6)) == {2.13, 2.245}


# -- switched Riccati process ---------------------------------------------------------------------------

def test_pullback_is_forward_on_reversed_path():
    sys_ = e1_system()
    Abar = ring_protocol().mean_matrix()
    rng = np.random.default_rng(4)
    back = sr.sample_chain(Abar, 50, 30, rng)
    pb = sr.pullback(sys_, back, np.eye(2), [30])[0]
    fwd = sr.switched_riccati(sys_, back[:, ::-1].copy(), np.eye(2), [], keep_final=True)["final"]
    np.testing.assert_allclose(pb, fwd, rtol=1e-13)


def test_exact_small_t_law_matches_brute_force():
    sys_ = e1_system(4)
    Abar = ring_protocol(4, 0.2).mean_matrix()
    atoms, probs = sr.exact_small_t_law(sys_, Abar, 3, np.eye(2))
    assert abs(probs.sum() - 1) < 1e-12
    brute = {}
    for path in itertools.product(range(4), repeat=3):
        p = 0.25 * Abar[path[0], path[1]] * Abar[path[1], path[2]]
        if p:
            X = wd.compose_walk(sys_, path, np.eye(2))
            k = round(float(np.log(np.trace(X))), 9)
            brute[k] = brute.get(k, 0) + p
    np.testing.assert_allclose(probs, [brute[k] for k in atoms], rtol=1e-12)


def test_chain_sampler_transition_frequencies():
    Abar = ring_protocol().mean_matrix()
    path = sr.sample_chain(Abar, 4000, 60, np.random.default_rng(5))
    counts = np.zeros((10, 10))
    np.add.at(counts, (path[:, :-1].ravel(), path[:, 1:].ravel()), 1)
    freq = counts / counts.sum(1, keepdims=True)
    n = counts.sum(1, keepdims=True)
    z = np.abs(freq - Abar) / np.sqrt(Abar * (1 - Abar) / n + 1e-300)
    assert np.all(freq[Abar == 0] == 0) and z[Abar > 0].max() < 5


# -- assumptions, constants, bounds ------------------------------------------------------------------------

def test_chain_checks():
    assert wd.check_chain(ring_protocol().mean_matrix()).c1
    two_rings = gk.MatchingDistribution.single_edge(6, [(0, 2), (2, 4), (4, 0), (1, 3), (3, 5), (5, 1)], [0.1] * 6)
    chk = wd.check_chain(two_rings.mean_matrix())
    assert not chk.irreducible and chk.unit_multiplicity == 2 and chk.n_classes == 2
    swap = gk.MatchingDistribution.from_matchings(2, [[(0, 1)]], [1.0])
    chk = wd.check_chain(swap.mean_matrix())
    assert chk.irreducible and not chk.aperiodic and abs(chk.min_eig + 1) < 1e-12
    even_ring = gk.MatchingDistribution.from_matchings(4, [[(0, 1), (2, 3)], [(1, 2), (3, 0)]], [0.5, 0.5])
    assert not wd.check_chain(even_ring.mean_matrix()).aperiodic  # example E7's second trap


def test_witness_search_and_lemma14_constants_e1():
    sys_ = e1_system()
    res = wd.search_witness(sys_, ring_protocol().mean_matrix())
    assert res.witness == (0, 1)
    np.testing.assert_allclose(res.gramian, np.diag([1.0, 1.21]), atol=1e-14)
    S = wd.sigma_sub(sys_, res.witness)
    np.testing.assert_allclose(np.diag(S), [2.3176, 1.31], atol=5e-5)   # prototype value
    g = wd.compose_walk(sys_, res.witness, 1e10 * np.eye(2))
    np.testing.assert_allclose(g, S, atol=1e-6)                          # minimal walk: sup g = Σ_sub
    S3 = wd.sigma_sub(sys_, (0, 0, 1))
    np.testing.assert_allclose(np.diag(S3), [1.5026, 1.31], atol=5e-5)  # non-minimal: strictly larger


def test_witness_search_negative_cases():
    F = np.array([[0.0, -1.0], [1.0, 0.0]])
    rot = gk.GossipSystem.build(F, 0.1 * np.eye(2), [np.array([[1.0, 0.0]]), np.array([[0.0, 1.0]])], [np.eye(1)] * 2, np.eye(2))
    assert np.linalg.eigvalsh(wd.walk_gramian(rot, (0, 1)))[0] < 1e-14   # Remark 3's counterexample
    assert wd.search_witness(rot, np.full((2, 2), 0.5)).witness is not None
    F8 = np.diag([1.2, 0.0, 0.0])
    e8 = gk.GossipSystem.build(F8, 0.1 * np.eye(3), [np.eye(3)[[1]], np.eye(3)[[2]], np.eye(3)[[0]]], [np.eye(1)] * 3, np.eye(3))
    res = wd.search_witness(e8, np.full((3, 3), 1 / 3))
    assert res.witness is None and res.max_rank == 2


@HYP
@given(seed=st.integers(0, 1000), L=st.integers(1, 7))
def test_tail_bounds_equal_brute_force_path_enumeration(seed, L):
    rng = np.random.default_rng(seed)
    N = 4
    A = rng.uniform(size=(N, N)) * (rng.uniform(size=(N, N)) < 0.7)
    A = A + A.T + np.eye(N) * 0.1
    # symmetric doubly stochastic by Sinkhorn
    for _ in range(500):
        A = A / A.sum(1, keepdims=True)
        A = (A + A.T) / 2
    A = A / A.sum(1, keepdims=True)
    w = tuple(int(x) for x in rng.integers(0, N, 2))
    windows = [w, tuple(int(x) for x in rng.integers(0, N, 2))]
    brute_single = brute_multi = 0.0
    for path in itertools.product(range(N), repeat=L):
        p = 1.0 / N
        for a, b in zip(path[:-1], path[1:]):
            p *= A[a, b]
        wins = {path[i:i + 2] for i in range(L - 1)}
        brute_single += p * (w not in wins)
        brute_multi += p * all(v not in wins for v in windows)
    assert abs(wd.tail_bound_single(A, w, L) - brute_single) < 1e-12
    assert abs(wd.tail_bound_multi(A, windows, L) - brute_multi) < 1e-12
    # every length from one propagation: each equals its own (0 and 1 node: no window fits, bound 1)
    lengths = [L, 0, 7, 1, L, 3]
    assert wd.tail_bounds_single(A, w, lengths).tolist() == [wd.tail_bound_single(A, w, n) for n in lengths]
    assert wd.tail_bounds_multi(A, windows, lengths).tolist() == [wd.tail_bound_multi(A, windows, n) for n in lengths]
    assert wd.tail_bound_single(A, w, 1) == wd.tail_bound_multi(A, windows, 0) == 1.0


@HYP
@given(seed=st.integers(0, 10_000), n=st.integers(1, 14), p=st.floats(0.0, 0.5), symmetric=st.booleans())
def test_strong_components_are_scipys(seed, n, p, symmetric):
    """C.1's classes: our labelling of a symmetric support (no scipy.sparse import) is scipy's, label for label."""
    import scipy.sparse.csgraph as csg

    A = (np.random.default_rng(seed).uniform(size=(n, n)) < p).astype(int)
    if symmetric:
        A = np.maximum(A, A.T)
    k, labels = csg.connected_components(A, directed=True, connection="strong")
    k2, labels2 = wd._strong_components(A)
    assert k2 == k and np.array_equal(labels2, labels)


def test_k_of_J_special_cases():
    assert wd.k_of_J(1.0, 2.0, 0.5, 10.0) == 16            # α = 1: 2 + 0.5 k ≤ 10
    assert wd.k_of_J(1.2, 2.3176, 0.1, 10.0) == 3           # prototype: k(1e1) = 3
    assert wd.k_of_J(1.2, 2.3176, 0.1, 1e5) == 29
    assert wd.k_of_J(1.2, 2.3176, 0.1, 1.0) == -1           # J < α0


def test_lifted_chain_stationary_law():
    Abar = ring_protocol().mean_matrix()
    Z, pi, corr, printed = wd.lifted_chain_stationary(Abar, 3)
    np.testing.assert_allclose(pi, corr, atol=1e-13)
    assert np.abs(printed - pi).max() > 1e-3


@settings(max_examples=15, deadline=None, database=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 10_000), N=st.integers(2, 7), M=st.integers(1, 3))
def test_random_graphs_tokens_and_centralized_domination(seed, N, M):
    """On random connected graphs and random systems (with an actuator): the corrected token recursion
    reproduces every sensor's covariance pathwise (19), and every sensor dominates the centralized
    filter started from the same P0."""
    import networkx as nx

    import dse.estimators.kalman as kal

    rng = np.random.default_rng(seed)
    G = nx.connected_watts_strogatz_graph(N, 2, 0.5, seed=seed) if N > 2 else nx.path_graph(N)
    edges = sorted(G.edges())
    sys_, _ = random_system(seed, M, 2, N)
    prot = gk.MatchingDistribution.single_edge(N, edges, [1.0 / len(edges)] * len(edges))
    B, T = 16, 25
    P = np.broadcast_to(sys_.P0, (B, N, M, M)).copy()
    Pc = kal.kalman_covariances(sys_.F, sys_.C_all, sys_.Q, sys_.R_all, sys_.P0, T + 1).P_prior
    loc = np.tile(np.arange(N), (B, 1))
    tok = P.copy()
    rows = np.arange(B)[:, None]
    for t in range(T):
        partners = np.tile(np.arange(N), (B, 1)) if t == 0 else prot.sample(B, rng)
        # the rounding of a step is relative to its inputs: a sensor may receive a covariance of norm 1e14 (an
        # unobserved unstable mode) and bring it down to 1e5 by cancellation (seed 1736, N 6, M 3: a gap of −1e-2
        # after a prior of norm 2.8e14, i.e. −3e-17 of the input)
        inputs = np.maximum(1.0, np.linalg.norm(P, 2, axis=(-2, -1)).max(axis=1))[:, None]
        P = gk.gikf_covariance_step(P, partners, sys_)
        loc = partners[rows, loc]
        tok = gk.riccati_step(tok, sys_.C[loc], sys_.R[loc], sys_.F, sys_.Q)
        np.testing.assert_allclose(tok, P[rows, loc], rtol=0, atol=1e-12 * max(1.0, np.abs(P).max()))
        scale = np.maximum(inputs, np.linalg.norm(P, 2, axis=(-2, -1)))
        assert (np.linalg.eigvalsh(P - Pc[t + 1])[..., 0] / scale).min() > -1e-9
