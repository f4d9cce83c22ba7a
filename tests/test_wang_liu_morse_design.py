"""Design quantities of the hybrid observer: per-agent objects, ρ, α, q, σ, c_i, norms, graphs.

Reference numbers for the paper's example were computed independently (numpy/scipy scratch
computations, not this code); random systems are checked against brute-force definitions."""
from __future__ import annotations

import itertools
import math

import control as ct
import networkx as nx
import numpy as np
import pytest
import scipy.linalg as sla
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import dse.estimators.jointly_observable_design as jd

A_PAPER = np.array([[-0.1, 0.4, 0, 0], [-0.1, -0.1, 0, 0], [0, 0, -0.2, 0.2], [0, 0, -2, 0.1]])
C_PAPER = [np.eye(4)[[i]] for i in range(4)]
L_PAPER = [np.array([[0, 1, 0, 0], [1, 0, 0, 0.]]), np.array([[-1, 0, 0, 0], [0, 1, 0, 0.]]),
           np.array([[0, 0, 0, 1], [0, 0, 1, 0.]]), np.array([[0, 0, -1, 0], [0, 0, 0, 1.]])]
K_PAPER = [-np.array([[13.7], [4.8]]), -np.array([[54.7], [4.8]]), -np.array([[30.6], [4.9]]), -np.array([[2.32], [4.9]])]
SETTINGS = settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def random_jointly_observable(seed: int, n: int = 4, m: int = 3):
    """A = V J V^{-1} with real modes; agent i observes a random nonempty subset of modes."""
    rng = np.random.default_rng(seed)
    V = rng.standard_normal((n, n)) + 2 * np.eye(n)
    Vi = np.linalg.inv(V)
    lam = rng.uniform(-1, 0.5, n)
    A = V @ np.diag(lam) @ Vi
    subsets = [[i % n] for i in range(m)]
    for i in range(m):
        extra = rng.integers(0, n)
        if extra not in subsets[i] and len(subsets[i]) < n - 1:
            subsets[i].append(int(extra))
    for j in range(n):                                  # every mode seen by someone
        if not any(j in s for s in subsets):
            subsets[j % m].append(j)
    C = [np.sum(Vi[s], axis=0, keepdims=True) for s in subsets]
    return A, C


def test_paper_local_design_and_footnote3():
    for C, L in zip(C_PAPER, L_PAPER):
        given_L = jd.local_design(A_PAPER, C, L=L)
        svd_L = jd.local_design(A_PAPER, C)
        assert np.abs(given_L.L @ A_PAPER - given_L.Abar @ given_L.L).max() == 0.0
        assert np.abs(C - given_L.Cbar @ given_L.L).max() == 0.0
        assert np.abs(given_L.P - svd_L.P).max() < 1e-15          # P_i independent of L_i (Krylov basis)
        assert jd.same_kernel(L, A_PAPER, C)
    assert not jd.same_kernel(np.eye(4)[2:], A_PAPER, C_PAPER[0])        # agent 1 sees (x1, x2), not (x3, x4)
    assert not jd.same_kernel(np.eye(4)[:1], A_PAPER, C_PAPER[0])        # too small a row space


@SETTINGS
@given(st.integers(0, 10_000))
def test_random_local_design_defining_equations(seed):
    A, Cs = random_jointly_observable(seed)
    for C in Cs:
        d = jd.local_design(A, C)
        O = jd.observability_matrix(A, C)
        assert d.n_i == np.linalg.matrix_rank(O, tol=1e-9 * np.linalg.norm(O, 2))
        assert np.abs(d.L @ A - d.Abar @ d.L).max() < 1e-9 * max(1, np.abs(A).max())
        assert np.abs(C - d.Cbar @ d.L).max() < 1e-10 * max(1, np.abs(C).max())
        assert np.linalg.matrix_rank(jd.observability_matrix(d.Abar, d.Cbar)) == d.n_i
        assert np.abs(d.P @ d.P - d.P).max() < 1e-12 and np.abs(d.P - d.P.T).max() < 1e-12
        assert np.abs(O @ d.P).max() < 1e-8 * max(1, np.linalg.norm(O, 2))   # image P_i = unobservable space


def brute_rho(P):
    m = len(P)
    N = (m - 1) ** 2 + 1
    best = 0.0
    for w in itertools.product(range(m), repeat=N):
        if len(set(w)) < m:
            continue
        M = np.linalg.multi_dot([P[i] for i in w])
        best = max(best, np.linalg.norm(M, 2))
    return best


@SETTINGS
@given(st.integers(0, 10_000))
def test_rho_reduction_equals_definition(seed):
    """(17) by its definition (all m^N products) vs the repeat-free minimal-word enumeration."""
    rng = np.random.default_rng(seed)
    n = 3
    P = []
    for _ in range(3):                                   # orthogonal projections onto random planes/lines
        k = int(rng.integers(1, 3))
        Qm, _ = np.linalg.qr(rng.standard_normal((n, k)))
        P.append(Qm @ Qm.T)
    P = np.array(P)
    fast = jd.rho_exact(P)
    assert fast.exact
    assert fast.rho == pytest.approx(brute_rho(P), rel=1e-10, abs=1e-14)


def test_paper_rho_sigma_q_regressions():
    P = np.array([jd.local_design(A_PAPER, C, L=L).P for C, L in zip(C_PAPER, L_PAPER)])
    assert jd.rho_exact(P).rho == 0.0
    nA = np.linalg.norm(A_PAPER, 2)
    assert nA == pytest.approx(2.0135501568, abs=1e-10)
    sq = jd.sufficient_q(0.0, 4, nA, 2.0, 1.0)
    assert (sq.q_thm22, sq.q_minimal, sq.q_thm22_printed_alpha, sq.q_minimal_printed_alpha) == (3_507_081, 3_507_080, 471, 470)
    assert sq.q_thm21 == 10 * (math.ceil(float(sq.r_lemma5)) + 1)
    assert float(sq.alpha_lemma5) == pytest.approx(1 - 3 / 4 ** 9, abs=1e-16)
    sig, worst, vals = jd.sigma_symmetric(P)
    assert len(vals) == 38 and sig == pytest.approx(0.929855, abs=1e-6)
    assert jd.q_symmetric(sig, nA, 2.0, 1.0) == 57


def test_counts_of_graphs_and_words():
    assert len(jd.strongly_connected_digraphs(4)) == 1606
    assert len(jd.connected_undirected_graphs(4)) == 38
    assert jd.count_complete_repeat_free_words(4, 10) == 105_936
    for m, L in ((3, 5), (3, 6), (4, 6)):
        brute = sum(1 for k in range(1, L + 1) for w in itertools.product(range(m), repeat=k)
                    if len(set(w)) == m and all(a != b for a, b in zip(w, w[1:])))
        assert jd.count_complete_repeat_free_words(m, L) == brute
    # strong connectivity agrees with networkx on random digraphs (arc j -> i iff N[i, j])
    rng = np.random.default_rng(0)
    for _ in range(200):
        N = rng.random((5, 5)) < 0.3
        G = nx.DiGraph([(j, i) for i in range(5) for j in range(5) if N[i, j] and i != j])
        G.add_nodes_from(range(5))
        assert jd.is_strongly_connected(N) == nx.is_strongly_connected(G)


def test_alpha_q_in_logs_no_overflow():
    nA = 2.0
    for m in (2, 3, 5, 10, 20, 40):
        sq = jd.sufficient_q(0.3, m, nA, 1.0, 1.0)
        expected_log10 = math.log10(m - 1) + math.log10(0.7) - (m - 1) ** 2 * math.log10(m)
        assert sq.log10_one_minus_alpha == pytest.approx(expected_log10, abs=1e-9)
        N = (m - 1) ** 2 + 1
        # q ≈ N (λ+||A||)T / (1-α): compare digits in logs
        if m >= 5:                                    # 1 - α < 1e-9: ln(1/α) = (1-α)(1 + O(1-α))
            approx = math.log10(N) + math.log10(3.0) - expected_log10
            assert math.log10(sq.q_thm22) == pytest.approx(approx, abs=1e-6)
        assert sq.q_thm22 > sq.q_minimal and sq.q_thm21 >= sq.q_thm22 - 1
    two = jd.sufficient_q(0.4, 2, nA, 1.0, 1.0)
    assert float(two.alpha_lemma5) == pytest.approx(0.7, abs=1e-15) == float(two.alpha_printed)
    # moderate m: the decimal computation matches the float formula with log1p
    sq = jd.sufficient_q(0.25, 3, 1.5, 0.5, 0.4)
    u = 2 * 0.75 / 3 ** 4
    assert float(sq.r_lemma5) == pytest.approx((0.5 + 1.5) * 0.4 / -math.log1p(-u), rel=1e-13)


def test_transient_constants_and_gains():
    expected = [13.72, 55.21, 31.62, 4.63]            # independent values, λ̄ = 2
    for C, L, K, c in zip(C_PAPER, L_PAPER, K_PAPER, expected):
        d = jd.local_design(A_PAPER, C, L=L)
        F = d.Abar + K @ d.Cbar
        val = jd.transient_constant(F, 2.0)
        assert val == pytest.approx(c, abs=6e-3)
        # the sup is an upper envelope of ||e^{Fτ}|| e^{2τ} at independent sample points
        taus = np.random.default_rng(1).uniform(0, 30, 40)
        assert max(np.linalg.norm(sla.expm(F * t), 2) * np.exp(2 * t) for t in taus) <= val * (1 + 1e-9)
        # pole placement: same closed loop as python-control's `place` on the dual system
        poles = [-2.5, -3.5]
        Kp = jd.place_gain(d.Abar, d.Cbar, poles)
        Kc = ct.place(d.Abar.T, d.Cbar.T, poles).T
        assert np.allclose(Kp, -Kc, rtol=1e-9, atol=1e-9)
        assert np.allclose(np.sort(np.linalg.eigvals(d.Abar + Kp @ d.Cbar).real), [-3.5, -2.5], atol=1e-9)
    assert jd.transient_constant(np.array([[0.1]]), 0.0) == math.inf


@SETTINGS
@given(st.integers(0, 10_000))
def test_mixed_norm_properties(seed):
    rng = np.random.default_rng(seed)
    m, n = 3, 2
    S = rng.random((m, m))
    S /= S.sum(axis=1, keepdims=True)
    assert jd.mixed_norm(np.kron(S, np.eye(n)), [n] * m, [n] * m) == pytest.approx(1.0, abs=1e-12)
    X, Y = rng.standard_normal((2, m * n, m * n))
    nx_, ny_, nxy = (jd.mixed_norm(M, [n] * m, [n] * m) for M in (X, Y, X @ Y))
    assert nxy <= nx_ * ny_ * (1 + 1e-12)
    # block norms by SVD (independent of the eigenvalue route)
    blocks = np.array([[np.linalg.norm(X[a * n:(a + 1) * n, b * n:(b + 1) * n], 2) for b in range(m)] for a in range(m)])
    assert nx_ == pytest.approx(blocks.sum(axis=1).max(), rel=1e-12)


@SETTINGS
@given(st.integers(0, 10_000))
def test_lemma6_on_random_instances(seed):
    A, Cs = random_jointly_observable(seed)
    P = np.array([jd.local_design(A, C).P for C in Cs])
    rng = np.random.default_rng(seed)
    m, n = len(P), A.shape[0]
    perms = [np.eye(m)[rng.permutation(m)] for _ in range(2)] + [np.roll(np.eye(m), 1, axis=1)]
    w = rng.dirichlet(np.ones(4))
    F = w[0] * np.eye(m) + sum(wi * Pm for wi, Pm in zip(w[1:], perms))
    assert np.linalg.norm(sla.block_diag(*P) @ np.kron(F, np.eye(n)), 2) < 1 - 1e-12
    sig, _, _ = jd.sigma_symmetric(P)
    assert sig < 1


def repeat_free_rho(P, max_len=None):
    """ρ by growing every repeat-free word (no pruning, no first/last-letter reduction), the words of
    one length as one stack: their products, last letters and sets of letters used."""
    m = len(P)
    N = (m - 1) ** 2 + 1 if max_len is None else max_len
    best = 0.0
    M, last, used = np.array(P, float), np.arange(m), 1 << np.arange(m)
    for length in range(1, N + 1):
        complete = used == (1 << m) - 1
        if complete.any():
            best = max(best, float(np.linalg.norm(M[complete], 2, axis=(1, 2)).max()))
        if length < N:
            ext = [(last != a, a) for a in range(m)]
            M = np.concatenate([M[keep] @ P[a] for keep, a in ext])
            used = np.concatenate([used[keep] | (1 << a) for keep, a in ext])
            last = np.concatenate([np.full(keep.sum(), a) for keep, a in ext])
    return best


def random_projections(rng, m, n, dims=None):
    out = []
    for i in range(m):
        k = int(rng.integers(1, n)) if dims is None else dims[i]
        Qm, _ = np.linalg.qr(rng.standard_normal((n, k)))
        out.append(Qm @ Qm.T)
    return np.array(out)


@pytest.mark.parametrize("seed", range(4))
def test_rho_branch_and_bound_m4_against_all_words(seed):
    """m = 4: every repeat-free word of length <= 10 (118,096 words) against the branch and bound."""
    P = random_projections(np.random.default_rng(seed), 4, 3)
    res = jd.rho_exact(P)
    assert res.exact and res.rho <= res.upper <= res.rho + res.roundoff
    assert res.rho == pytest.approx(repeat_free_rho(P), rel=1e-12, abs=1e-15)
    w = res.worst_word
    assert len(set(w)) == 4 and len(w) <= 10 and all(a != b for a, b in zip(w, w[1:]))
    assert np.linalg.norm(np.linalg.multi_dot([P[i] for i in w]), 2) == pytest.approx(res.rho, rel=1e-12)


def test_rho_five_agents_exact_and_fast():
    """m = 5 (N = 17): exact in well under a second, and never below any sampled complete word."""
    import time

    rng = np.random.default_rng(11)
    P = random_projections(rng, 5, 4)
    t0 = time.process_time()
    res = jd.rho_exact(P)
    assert res.exact and time.process_time() - t0 < 5.0          # CPU time: not the machine's load
    for _ in range(300):
        L = int(rng.integers(5, 18))
        w = [int(rng.integers(5))]
        while len(w) < L:
            a = int(rng.integers(4))
            w.append(a if a < w[-1] else a + 1)
        if len(set(w)) == 5:
            assert np.linalg.norm(np.linalg.multi_dot([P[i] for i in w]), 2) <= res.rho * (1 + 1e-12) + 1e-15


def test_rho_repeated_projections_are_merged():
    """Agents sharing a projection: the merged search equals the definition for m = 4."""
    rng = np.random.default_rng(3)
    for _ in range(4):
        base = random_projections(rng, 3, 3)
        P = base[[0, 1, 0, 2]]
        res = jd.rho_exact(P)
        assert res.exact and res.rho == pytest.approx(repeat_free_rho(P), rel=1e-12, abs=1e-15)
        w = res.worst_word
        assert len(set(w)) == 4 and len(w) <= 10
        assert np.linalg.norm(np.linalg.multi_dot([P[i] for i in w]), 2) == pytest.approx(res.rho, rel=1e-12)


def test_rho_bracket_when_the_search_is_cut():
    """With a tiny state budget the search stops with a proven bracket around the exact value."""
    P = random_projections(np.random.default_rng(7), 5, 4, dims=[2] * 5)
    exact = jd.rho_exact(P)
    cut = jd.rho_exact(P, max_states=400)
    assert exact.exact and not cut.exact
    assert cut.rho <= exact.rho * (1 + 1e-12) and cut.upper >= exact.rho * (1 - 1e-12)
    w = cut.worst_word
    assert np.linalg.norm(np.linalg.multi_dot([P[i] for i in w]), 2) == pytest.approx(cut.rho, rel=1e-12)


def test_rho_zero_projection():
    P = random_projections(np.random.default_rng(2), 3, 3)
    P[1] = 0.0
    assert jd.rho_exact(P).rho == 0.0 and jd.rho_exact(P).exact


@pytest.mark.parametrize("kappa", [1e2, 1e4, 1e6])
def test_projection_from_an_ill_conditioned_basis(kappa):
    """Footnote 3 with a change of basis of condition κ: P_i from M L_i (QR, no (L L')^-1) equals P_i
    from L_i to 10·n·n_i·eps·(1 + κ(M L_i)); the explicit inverse of L L' (κ²) did not."""
    rng = np.random.default_rng(int(kappa))
    n, k = 6, 3
    L, _ = np.linalg.qr(rng.standard_normal((n, k)))
    L = L.T
    U, _ = np.linalg.qr(rng.standard_normal((k, k)))
    V, _ = np.linalg.qr(rng.standard_normal((k, k)))
    M = U @ np.diag(np.geomspace(1.0, kappa, k)) @ V
    _, P, _ = jd.pseudo_inverse_rows(L)
    Q2, P2, cond = jd.pseudo_inverse_rows(M @ L)
    assert cond == pytest.approx(kappa, rel=1e-6)
    assert np.abs(P2 - P).max() <= 10 * n * k * np.finfo(float).eps * (1 + cond)
    assert np.abs((M @ L) @ Q2 - np.eye(k)).max() <= 10 * n * k * np.finfo(float).eps * cond


def test_observable_basis_badly_scaled_system():
    """||A|| = 40, n = 6: the observable space of each agent has the planted dimension, and the
    rows are A-invariant to round-off (the rank decision on [C; CA; ...; CA^5] mixes scales 1 to 40^5)."""
    rng = np.random.default_rng(5)
    n = 6
    V = rng.standard_normal((n, n)) + 3 * np.eye(n)
    Vi = np.linalg.inv(V)
    lam = np.array([-40.0, -25.0, -3.0, -1.0, 0.5, 0.05])
    A = V @ np.diag(lam) @ Vi
    for seen in ([0, 5], [1, 2, 3], [4], [0, 1, 2, 3, 4]):
        C = rng.standard_normal((1, len(seen))) @ Vi[seen]
        basis = jd.observable_basis(A, C)
        assert basis.rows.shape[0] == len(seen)
        R = basis.rows
        assert np.abs(R @ R.T - np.eye(len(seen))).max() < 1e-14
        assert np.linalg.norm(R @ A @ (np.eye(n) - R.T @ R), 2) <= 1e-12 * np.linalg.norm(A, 2)
        # the row space is spanned by the planted left eigenvectors
        W = Vi[seen] / np.linalg.norm(Vi[seen], axis=1, keepdims=True)
        assert np.linalg.norm(W - (W @ R.T) @ R, 2) < 1e-10


def test_stacked_gain_with_repeated_outputs():
    A, Cs = random_jointly_observable(4)
    C = np.vstack(Cs + Cs)                                    # every output twice
    K = jd.stacked_gain(A, C, [-1.0, -1.5, -2.0, -2.5])
    assert np.allclose(np.sort(np.linalg.eigvals(A + K @ C).real), [-2.5, -2.0, -1.5, -1.0], atol=1e-8)


@pytest.mark.parametrize("rank", ["one", "full"])
def test_place_gain_is_scipys_place_poles_bit_for_bit(rank):
    """One output or outputs of full rank take the scipy-free path (no iteration to reproduce):
    the same gain as scipy.signal.place_poles to the last bit (other ranks call scipy itself)."""
    from scipy.signal import place_poles

    rng = np.random.default_rng({"one": 1, "full": 2}[rank])
    for case in range(60):
        n = int(rng.integers(2, 7))
        r = 1 if rank == "one" else n
        A = rng.standard_normal((n, n)) * [0.1, 1.0, 10.0][case % 3]
        C = rng.standard_normal((r, n))
        poles = -rng.permutation(np.arange(1, n + 1) * rng.uniform(0.5, 2.0))
        np.testing.assert_array_equal(jd.place_gain(A, C, poles), -place_poles(A.T, C.T, poles).gain_matrix.T)
