"""The compiled kernels (`dse.estimators.gikf_compiled`) give the same doubles, bit for bit, as their numpy
references, on seeded random batches with zero, tiny, huge, infinite and NaN entries, M = 1..3, m = 1..2, and
batches of one matrix (the dispatch threshold is lowered so that every batch goes to the kernels); M = 4: the
m = 1 Riccati step (the round-off bound is numpy matrix products from M = 4 on)."""
from __future__ import annotations

import numpy as np
import pytest

from dse.estimators import gikf_maps as gm
from dse.estimators.gossip_protocols import GreedyMatchingGossip


def _compiled(monkeypatch, on: bool):
    """Every batch to the compiled kernels (on), or none."""
    monkeypatch.setattr(gm, "COMPILED_MIN_BATCH", 1 if on else 10**18)
    monkeypatch.setattr(gm, "COMPILE_AFTER_S", 0.0)
    monkeypatch.setattr(gm, "compiled_allowed", True)


@pytest.fixture
def always_compiled(monkeypatch):
    _compiled(monkeypatch, True)


def _psd(rng, shape, M, special):
    """Random symmetric PSD matrices, some scaled to extreme magnitudes or with special entries."""
    L = rng.standard_normal(shape + (M, M))
    X = L @ np.swapaxes(L, -1, -2)
    scale = 10.0 ** rng.choice([-300, -150, -8, 0, 0, 0, 8, 150, 300], size=shape)
    X = X * scale[..., None, None]
    if special:
        flat = X.reshape(-1, M, M)
        k = rng.integers(0, len(flat), size=max(1, len(flat) // 5))
        flat[k, rng.integers(0, M, len(k)), rng.integers(0, M, len(k))] = rng.choice([0.0, -0.0, np.inf, -np.inf, np.nan,
                                                                                     1e308], size=len(k))
    return X


def _system(rng, M, m, zero_rows):
    F = rng.standard_normal((M, M))
    if zero_rows and M > 1:
        F[0] = 0.0          # a zero row of F, and zero entries skipped by the sums
        F[-1, 0] = -0.0
    Q = np.eye(M) * rng.uniform(0.01, 1.0)
    Q[0, 0] = -0.0 if zero_rows else Q[0, 0]
    return F, Q


def _same_zero_signs(a, b):
    """-0.0 where the reference has -0.0 (assert_array_equal takes -0.0 == 0.0). Not for NaN: which NaN an
    operation on two NaNs returns depends on its operand order, which the compiler may swap (a + b = b + a);
    a NaN is a NaN in both, which assert_array_equal checks."""
    finite = ~np.isnan(b)
    np.testing.assert_array_equal(np.signbit(a)[finite], np.signbit(b)[finite])


CASES = [(M, m, B, special) for M in (1, 2, 3, 4) for m in (1, 2) for B in (1, 7, 200) for special in (False, True)]


@pytest.mark.parametrize("M, m, B, special", CASES)
def test_riccati_roundoff_and_propagation_match_the_numpy_reference_bit_for_bit(M, m, B, special, monkeypatch):
    rng = np.random.default_rng(1000 * M + 100 * m + B + special)
    F, Q = _system(rng, M, m, special)
    N = 3
    X = _psd(rng, (B, N), M, special)
    C = rng.standard_normal((N, m, M)) * rng.choice([0.0, 1.0, 1e-200, 1e200], size=(N, m, 1))
    Rl = rng.standard_normal((N, m, m))
    R = Rl @ np.swapaxes(Rl, -1, -2) + 0.1 * np.eye(m)
    E = _psd(rng, (B, N), M, special)
    with np.errstate(all="ignore"):
        for compiled in (False, True):
            _compiled(monkeypatch, compiled)
            if m == 1:
                step = gm.riccati_step(X, C, R, F, Q, return_gain=True)
                if compiled:
                    np.testing.assert_array_equal(step[0], ref_step[0])
                    np.testing.assert_array_equal(step[1], ref_step[1])
                    _same_zero_signs(step[0], ref_step[0])
                ref_step = step
            K = rng.standard_normal((B, N, M, m)) if not compiled else K
            got = gm.riccati_roundoff(X, K, C, R, F, Q)
            prop = gm.propagate_error(E, got[1], got[0])
            if compiled:
                np.testing.assert_array_equal(got[0], ref[0])
                np.testing.assert_array_equal(got[1], ref[1])
                np.testing.assert_array_equal(prop, ref_prop)
                for a, b in ((got[0], ref[0]), (got[1], ref[1]), (prop, ref_prop)):
                    _same_zero_signs(a, b)
            ref, ref_prop = got, prop


@pytest.mark.parametrize("M", [1, 2, 3])
@pytest.mark.filterwarnings("ignore::RuntimeWarning")
def test_switched_batches_with_per_run_sensors_and_a_scalar_r_min(M, always_compiled):
    """The shapes of switched_riccati (C[nodes], R[nodes] per run) and of gikf_roundoff (r_min given)."""
    rng = np.random.default_rng(M)
    F, Q = _system(rng, M, 1, True)
    B = 50
    X = _psd(rng, (B,), M, False)
    C = rng.standard_normal((B, 1, M))
    R = rng.uniform(0.1, 2.0, (B, 1, 1))
    for r_min in (None, 0.05):
        got = gm.riccati_step(X, C, R, F, Q, return_gain=True)
        d, G = gm.riccati_roundoff(X, got[1], C, R, F, Q, r_min=r_min)
        gm.COMPILED_MIN_BATCH = 10**18
        ref = gm.riccati_step(X, C, R, F, Q, return_gain=True)
        rd, rG = gm.riccati_roundoff(X, ref[1], C, R, F, Q, r_min=r_min)
        gm.COMPILED_MIN_BATCH = 1
        for a, b in zip((*got, d, G), (*ref, rd, rG)):
            np.testing.assert_array_equal(a, b)


def _random_graph(rng, n, n_edges):
    edges = set()
    while len(edges) < n_edges:
        a, b = sorted(rng.choice(n, 2, replace=False).tolist())
        edges.add((a, b))
    return tuple(sorted(edges))


@pytest.mark.parametrize("n, n_edges, p_link", [(2, 1, 1.0), (4, 5, 0.5), (30, 118, 0.5), (30, 118, 1.0), (80, 200, 0.7)])
@pytest.mark.parametrize("size", [1, 64, 300])
def test_the_greedy_matching_sampler_draws_the_same_partners_and_leaves_the_generator_in_the_same_state(
        n, n_edges, p_link, size, monkeypatch):

    protocol = GreedyMatchingGossip(n, _random_graph(np.random.default_rng(n), n, n_edges), p_link)
    got = []
    for compiled in (False, True):
        _compiled(monkeypatch, compiled)
        rng = np.random.default_rng(size + n)
        got.append((protocol.sample(size, rng), protocol.sample(size, rng), rng.random()))
    for a, b in zip(*got):
        np.testing.assert_array_equal(a, b)


def test_the_compiled_greedy_scan_follows_numpy_s_order_also_for_tied_priorities():
    from dse.estimators import gikf_compiled

    u, v = np.array([0, 1, 0, 2]), np.array([1, 2, 2, 3])
    priority = np.array([[0.3, 0.1, 0.2, 0.4], [0.5, 0.5, 0.5, 0.5], [0.0, 0.0, 0.9, 0.0]])
    protocol = GreedyMatchingGossip(4, tuple(zip(u.tolist(), v.tolist())), 1.0)
    order, words, flags = np.argsort(priority, axis=1), np.zeros(priority.shape, bool), np.zeros(priority.shape, bool)
    gikf_compiled.greedy_chosen_words(order, (1 << u | 1 << v).astype(np.uint64), words)
    gikf_compiled.greedy_chosen_flags(order, u, v, 4, flags)
    np.testing.assert_array_equal(words, protocol.greedy_chosen(priority))
    np.testing.assert_array_equal(flags, protocol.greedy_chosen(priority))


@pytest.mark.parametrize("n", [1, 3, 30])
def test_the_compiled_chain_step_draws_the_same_abar_chain(n, monkeypatch):
    from dse.estimators import switched_riccati as sr

    rng = np.random.default_rng(n)
    A = rng.random((n, n)) ** 3
    A[rng.random((n, n)) < 0.5] = 0.0
    A += np.eye(n)
    A /= A.sum(axis=1, keepdims=True)
    paths = []
    for compiled in (False, True):
        _compiled(monkeypatch, compiled)
        paths.append(sr.sample_chain(A, 200, 30, np.random.default_rng(7)))
    np.testing.assert_array_equal(*paths)


def test_the_compiled_2x2_eigenvalues_match_the_numpy_closed_form(always_compiled, monkeypatch):
    """On the closed form's whole input range and beyond (its comparison with LAPACK is in test_kar_moura_*)."""
    rng = np.random.default_rng(5)
    n = 20000
    X = rng.standard_normal((n, 2, 2)) * 10.0 ** rng.integers(-130, 150, (n, 1, 1))
    X[:, 0, 1] = X[:, 1, 0]
    pick = rng.random((n, 2, 2)) < 0.15                  # exact zeros of either sign, equal diagonals, inf, NaN
    X[pick] = rng.choice([0.0, -0.0, 1.0, -1.0, np.inf, np.nan], size=pick.sum())
    X[::7, 1, 1] = X[::7, 0, 0]
    X[::11, 1, 0] = X[::11, 0, 1] = 0.0
    X[::13] = rng.choice([0.0, -0.0], size=(len(X[::13]), 2, 2))
    X[::17, 1, 0] *= 1e-9
    with np.errstate(all="ignore"):
        got = gm.eigvalsh(X)
        _compiled(monkeypatch, False)
        ref = gm.eigvalsh(X)
    np.testing.assert_array_equal(got, ref)
    _same_zero_signs(got, ref)


def test_a_process_uses_the_kernels_once_its_numpy_work_would_have_repaid_loading_numba(monkeypatch):
    monkeypatch.setattr(gm, "_numpy_s", 0.0)
    monkeypatch.setattr(gm, "COMPILE_AFTER_S", 1.0)
    monkeypatch.setattr(gm, "compiled_allowed", True)
    calls = 0
    while not gm.use_compiled(10_000):
        calls += 1
    assert 800 < calls < 1000                                    # ~1.1 ms of numpy per call of 10,000 matrices
    assert gm.use_compiled(gm.COMPILED_MIN_BATCH) and not gm.use_compiled(gm.COMPILED_MIN_BATCH - 1)
    assert not gm.use_compiled(10_000, np.zeros((2, 2), np.float32))
    monkeypatch.setattr(gm, "compiled_allowed", False)        # a run whose memory budget has no room for numba
    assert not gm.use_compiled(10_000)


def test_listing_and_checking_a_scenario_do_not_import_numba(tmp_path):
    import json
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parent.parent
    env = {"PYTHONPATH": str(root), "PATH": "/usr/bin:/bin", "OPENBLAS_NUM_THREADS": "1", "DSE_PROGRESS": "0"}
    code = ("import contextlib, io, json, sys; from dse.cli import main\n"
            "with contextlib.redirect_stdout(io.StringIO()): code = main(sys.argv[1:])\n"
            "print(json.dumps({'code': code, 'numba': 'numba' in sys.modules}))")
    scenario = root / "dse" / "families" / "kar_moura" / "scenarios" / "e9.toml"
    for args in (["list"], ["check", str(scenario), "--out", str(tmp_path / "out")]):
        proc = subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True, env=env, cwd=root,
                              timeout=600)
        assert proc.returncode == 0, proc.stderr[-2000:]
        assert json.loads(proc.stdout.splitlines()[-1]) == {"code": 0, "numba": False}, args


def test_the_set_up_s_warm_up_compiles_the_types_the_estimators_call_the_kernels_with(always_compiled):
    """`warm_cache` (run by the Makefile's set-up) leaves nothing for a run to compile: after it, the calls the
    estimators make (every wrapper of gikf_maps, M = 1..3 and m ≤ M; the m = 1 Riccati step up to M = 6; the
    matching sampler on ≤ 64 and > 64 nodes; the Ā chain) add no signature to any kernel."""
    from dse.estimators import gikf_compiled
    from dse.estimators import switched_riccati as sr

    gikf_compiled.warm_cache()
    kernels = {name: k for name, k in vars(gikf_compiled).items() if hasattr(k, "signatures")}
    warmed = {name: set(k.signatures) for name, k in kernels.items()}
    rng = np.random.default_rng(0)
    psd = lambda shape, M: (lambda L: L @ np.swapaxes(L, -1, -2) + np.eye(M))(rng.standard_normal(shape + (M, M)))
    for M in range(1, 7):
        F, Q = _system(rng, M, 1, False)
        X, C, R = psd((5, 3), M), rng.standard_normal((3, 1, M)), rng.uniform(0.5, 1.0, (3, 1, 1))
        _, K = gm.riccati_step(X, C, R, F, Q, return_gain=True)
        for m in range(1, min(M, gm.ENTRYWISE_MAX_M) + 1):
            Cm, Rm = rng.standard_normal((3, m, M)), np.eye(m) + np.zeros((3, m, m))
            delta, G = gm.riccati_roundoff(X, rng.standard_normal((5, 3, M, m)), Cm, Rm, F, Q)
            gm.propagate_error(X, G, delta)
    gm.eigvalsh(psd((40,), 2))
    for n, n_edges in ((4, 5), (80, 200)):
        GreedyMatchingGossip(n, _random_graph(rng, n, n_edges), 0.5).sample(10, rng)
    sr.sample_chain(np.full((3, 3), 1 / 3), 10, 5, rng)
    assert {name: set(k.signatures) for name, k in kernels.items()} == warmed
