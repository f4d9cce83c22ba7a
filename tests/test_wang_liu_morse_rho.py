"""ρ of (17) by the structured search (dse/estimators/projection_products.py) against independent
computations: the definition (every product of N factors) for m = 3, every repeat-free word for
m = 4, and a plain level-by-level enumeration of every repeat-free word (no first/last-letter
reduction, no merging, no tail bound; prefixes pruned only by their norm against a verified word)
for m = 5 and 6. Then the class of issue 26: 6 to 8 agents of an oscillatory system observing
modes, several agents with the same unobservable space, ρ = 0 up to round-off."""
from __future__ import annotations

import itertools
import time

import numpy as np
import pytest

import dse.estimators.jointly_observable_design as jd
import dse.estimators.projection_products as pp


def modal_projections(seed: int, m: int, n: int, cond: float) -> np.ndarray:
    """P_i of an oscillatory system A = V J V^-1 (n/2 rotation blocks, V of condition `cond`: 1 is
    orthogonal) whose agent i observes a random proper subset of the blocks (every block observed by
    someone), C_i = R_i V^-1[rows of its blocks]."""
    rng = np.random.default_rng(seed)
    blocks = n // 2
    J = np.zeros((n, n))
    for b in range(blocks):
        w = 0.5 + b + float(rng.uniform(0, 0.5))
        J[2 * b:2 * b + 2, 2 * b:2 * b + 2] = [[0.0, w], [-w, 0.0]]
    U, _ = np.linalg.qr(rng.standard_normal((n, n)))
    W, _ = np.linalg.qr(rng.standard_normal((n, n)))
    V = U @ np.diag(np.geomspace(1.0, cond, n)) @ W
    Vi = np.linalg.inv(V)
    sees = [{i % blocks} for i in range(m)]
    for s in sees:
        s.update(b for b in range(blocks) if rng.random() < 0.4)
        if len(s) == blocks and blocks > 1:
            s.discard(max(s))
    for b in range(blocks):
        sees[b].add(b)
        if len(sees[b]) == blocks and blocks > 1:
            sees[b].discard((b + 1) % blocks)
    A = V @ J @ Vi
    P = []
    for s in sees:
        rows = np.vstack([Vi[2 * b:2 * b + 2] for b in sorted(s)])
        P.append(jd.local_design(A, rng.standard_normal((1, len(rows))) @ rows).P)
    return np.array(P)


def subspace_projections(seed: int, m: int, n: int, cond: float = 3.0) -> np.ndarray:
    """Orthogonal projections on spans of subsets of the columns of a non-orthogonal basis: letters
    sharing a column leave it fixed (the tail bound's case)."""
    rng = np.random.default_rng(seed)
    U, _ = np.linalg.qr(rng.standard_normal((n, n)))
    V = U @ np.diag(np.geomspace(1.0, cond, n))
    out = []
    for _ in range(m):
        cols = rng.choice(n, size=int(rng.integers(1, n)), replace=False)
        Q, _ = np.linalg.qr(V[:, cols])
        out.append(Q @ Q.T)
    return np.array(out)


def definition_rho(P: np.ndarray) -> float:
    """(17) as written: every product of N = (m-1)² + 1 factors containing every P_i."""
    m = len(P)
    best = 0.0
    for w in itertools.product(range(m), repeat=(m - 1) ** 2 + 1):
        if len(set(w)) == m:
            best = max(best, float(np.linalg.norm(np.linalg.multi_dot([P[i] for i in w]), 2)))
    return best


def enumerated_rho(P: np.ndarray, lower: float) -> float:
    """The largest norm of a repeat-free word of length <= N containing every letter, by growing
    every repeat-free word level by level; a prefix whose norm is below `lower` (the norm of a word
    the caller computed) is dropped, since no extension of it can exceed `lower`."""
    m = len(P)
    N = (m - 1) ** 2 + 1
    best = lower
    M, last, used = np.array(P, float), np.arange(m), 1 << np.arange(m)
    for length in range(1, N + 1):
        norms = np.linalg.norm(M, 2, axis=(1, 2))
        complete = used == (1 << m) - 1
        if complete.any():
            best = max(best, float(norms[complete].max()))
        keep = ~complete & (norms >= lower * (1 - 1e-12))           # a complete word is not extended
        M, last, used = M[keep], last[keep], used[keep]
        assert len(M) < 300_000, "the enumeration is too wide for a test"
        if length == N or not len(M):
            break
        ext = [(last != a, a) for a in range(m)]
        M = np.concatenate([M[k] @ P[a] for k, a in ext])
        used = np.concatenate([used[k] | (1 << a) for k, a in ext])
        last = np.concatenate([np.full(k.sum(), a) for k, a in ext])
    return best


def word_norm(P: np.ndarray, word) -> float:
    return float(np.linalg.norm(np.linalg.multi_dot([P[i] for i in word] + [np.eye(P.shape[1])]), 2))


def check_witness(P: np.ndarray, res) -> None:
    """The witness is a word of (17) (every agent, length <= N) whose norm is `rho`."""
    m = len(P)
    w = res.worst_word
    assert set(w) == set(range(m)) and len(w) <= (m - 1) ** 2 + 1
    slack = ((m - 1) ** 2 + 1) * res.merge_deviation + res.roundoff
    assert abs(word_norm(P, w) - res.rho) <= 1e-12 * res.rho + slack


@pytest.mark.parametrize("seed", range(6))
def test_m3_equals_the_definition(seed):
    P = subspace_projections(seed, 3, 3) if seed % 2 else modal_projections(seed, 3, 4, 2.0)
    res = pp.rho_exact(P)
    assert res.exact and res.rho <= res.upper <= res.rho + res.roundoff
    assert res.rho == pytest.approx(definition_rho(P), rel=1e-12, abs=1e-14)
    check_witness(P, res)


@pytest.mark.parametrize("seed", range(4))
def test_m4_shared_fixed_spaces_against_every_repeat_free_word(seed):
    """Letters that leave common vectors fixed (the tail bound prunes there) against every word."""
    P = subspace_projections(seed, 4, 4)
    res = pp.rho_exact(P)
    assert res.exact
    assert res.rho == pytest.approx(enumerated_rho(P, 0.0), rel=1e-12, abs=1e-14)
    check_witness(P, res)


def random_projections(seed: int, m: int, n: int, most: int) -> np.ndarray:
    """Orthogonal projections on random subspaces of dimension 1..most."""
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(m):
        Q, _ = np.linalg.qr(rng.standard_normal((n, int(rng.integers(1, most + 1)))))
        out.append(Q @ Q.T)
    return np.array(out)


@pytest.mark.parametrize("m, n, most, seed", [(5, 3, 2, 3), (5, 4, 2, 0), (5, 4, 2, 3), (5, 4, 2, 4), (6, 3, 1, 0),
                                              (6, 3, 1, 2), (6, 3, 1, 3)])
def test_m5_m6_against_the_plain_enumeration(m, n, most, seed):
    P = random_projections(seed, m, n, most)
    res = pp.rho_exact(P)
    assert res.exact
    check_witness(P, res)
    lower = word_norm(P, res.worst_word)
    assert enumerated_rho(P, lower) <= res.upper * (1 + 1e-12) + res.roundoff


@pytest.mark.parametrize("m, n, seed", [(6, 4, 11), (6, 6, 2), (7, 6, 5), (8, 6, 0), (8, 8, 4), (8, 8, 7)])
def test_issue26_six_to_eight_agents_rho_near_zero_exact(m, n, seed):
    """Issue 26: with an orthogonal modal basis ρ = 0 (commuting projections, (16)); the search
    used to stop after 524,287 products with the bracket [~1e-16, 1]. Now exact, the bracket within
    the round-off allowance, in a few thousand prefixes."""
    P = modal_projections(seed, m, n, 1.0)
    t0 = time.process_time()
    res = pp.rho_exact(P)
    assert res.exact and res.upper <= 1e-11 and res.rho <= res.upper <= res.rho + res.roundoff
    assert res.distinct < m and res.merge_deviation < 1e-13      # agents observing the same modes: one letter
    assert res.prefixes < 50_000 and time.process_time() - t0 < 20.0
    check_witness(P, res)


def test_near_equal_projections_are_merged_and_the_deviation_reported():
    rng = np.random.default_rng(5)
    base = subspace_projections(5, 3, 4)
    E = rng.standard_normal((4, 4)) * 1e-15
    P = np.array([base[0], base[1], base[2], base[1] + (E + E.T)])
    res = pp.rho_exact(P)
    assert res.exact and res.distinct == 3 and 0 < res.merge_deviation < 1e-14
    assert res.rho == pytest.approx(enumerated_rho(P, 0.0), rel=1e-12, abs=1e-14)
    check_witness(P, res)


def test_tail_bounds_are_upper_bounds_of_sampled_continuations():
    """B(T) >= ||Π_T R U_b|| for random valid continuations R (every letter outside T, completed at b)."""
    rng = np.random.default_rng(9)
    P = subspace_projections(9, 5, 4)
    N = 17
    Pi, eps = pp.fixed_spaces(P)
    B = pp.tail_bounds(P, Pi, eps, N)
    U = pp.range_bases(P)
    for T in range(1, 31):
        missing = [c for c in range(5) if not T >> c & 1]
        for _ in range(40):
            b = int(rng.choice(missing))
            body = list(rng.integers(0, 5, size=int(rng.integers(0, N - len(missing)))))
            body += [c for c in missing if c != b]
            rng.shuffle(body)
            R = np.linalg.multi_dot([Pi[T]] + [P[c] for c in body] + [U[b], np.eye(U[b].shape[1])])
            assert np.linalg.norm(R, 2) <= B[T] + 1e-12
