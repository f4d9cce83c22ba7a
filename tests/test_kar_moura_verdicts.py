"""Verdicts of the gossip-kalman family that mean what they say: hypotheses decided (and certified when
they fail), round-off allowances that cover what exact arithmetic says, every witness window kept,
iterates that stay finite, statistical tests that keep their level, and the generator of hard cases."""
from __future__ import annotations

import json
from fractions import Fraction

import numpy as np
import pytest

import dse.estimators.gossip_kalman as gk
import dse.estimators.switched_riccati as sr
import dse.estimators.walk_detectability as wd
import dse.families as families
from dse.contract.options import RunOptions
from dse.contract.context import StageContext
from dse.engine.cache import StageCache
from dse.engine.driver import evaluate_claims
from dse.families.kar_moura import generator
from dse.families.kar_moura import stats as kst


def _system(F, C_list, R_list, Q=None):
    F = np.asarray(F, float)
    M = F.shape[0]
    return gk.GossipSystem.build(F, 0.1 * np.eye(M) if Q is None else Q, [np.atleast_2d(c) for c in C_list],
                                 [np.atleast_2d(r) for r in R_list], np.eye(M))


def _rotation(theta):
    return np.array([[np.cos(theta), -np.sin(theta)], [np.sin(theta), np.cos(theta)]])


# -- D.1 decided three ways ---------------------------------------------------------------------------------

def test_d1_certified_failure_for_an_oblique_unseen_direction():
    """Every sensor is blind to an unstable eigenvector that is not a coordinate axis: no witness, and a
    certificate (not just an unsuccessful search) that none exists."""
    V = _rotation(0.7)
    F = V @ np.diag([1.15, 0.6]) @ V.T
    blind = V[:, 0]
    c = np.array([-blind[1], blind[0]])          # orthogonal to the unstable eigenvector
    sys_ = _system(F, [c, 2 * c], [[[1.0]], [[0.5]]])
    A = np.array([[0.5, 0.5], [0.5, 0.5]])
    d = wd.decide_d1(sys_, A, [(0, 1)], c1=True)
    assert d.holds is False and "certificate" in d.how
    lam, _ = wd.unobservable_modes(F, sys_.C_all)
    assert lam is not None and np.allclose(np.abs(lam), 1.15)


def test_d1_holds_by_witness_and_by_the_derived_criterion():
    sys_ = _system(np.diag([1.2, 1.1]), [[1.0, 0.0], [0.0, 1.0]], [[[1.0]], [[1.0]]])
    A = np.array([[0.8, 0.2], [0.2, 0.8]])
    d = wd.decide_d1(sys_, A, [(0, 1)], c1=True)
    assert d.holds is True and d.search.witness == (0, 1)
    # a witness longer than the search depth: F invertible, C.1, (F, C_all) observable => D.1
    d = wd.decide_d1(sys_, A, [(0, 1)], c1=True, max_len=1)
    assert d.holds is True and d.search.witness is None and "longer than the search depth" in d.how


def test_d1_undecided_when_the_gramian_is_numerically_ambiguous():
    """A direction seen with gain 1e-6 relative: Gramian ratio ~1e-12, between 'singular' and 'certainly
    invertible'; F singular, so the derived criterion does not apply: undecided, not guessed."""
    F = np.diag([1.2, 0.0])
    sys_ = _system(F, [[1.0, 1e-6], [1.0, 0.0]], [[[1.0]], [[1.0]]])
    d = wd.decide_d1(sys_, np.full((2, 2), 0.5), [(0, 1)], c1=True)
    assert d.holds is None


def test_singular_f_certificate_e8():
    F = np.diag([1.2, 0.0, 0.0])
    sys_ = _system(F, [np.eye(3)[1], np.eye(3)[2], np.eye(3)[0]], [[[1.0]]] * 3)
    d = wd.decide_d1(sys_, np.full((3, 3), 1 / 3), [(0, 1, 2)], c1=True)
    assert d.holds is False


# -- every witness window -----------------------------------------------------------------------------------

def test_witness_windows_keep_sensors_sharing_c_with_different_r():
    """Walks through sensors with the same C and different R have the same Gramian but different Σ_sub:
    the list of witness windows must keep all of them, so that α0 of all windows is their maximum."""
    c0, c1 = [1.0, 0.0], [0.0, 1.0]
    sys_ = _system(np.diag([1.2, 1.1]), [c0, c0, c1], [[[0.1]], [[10.0]], [[1.0]]])
    A = np.full((3, 3), 1 / 3)
    s = wd.search_witness(sys_, A)
    assert len(s.witness) == 2 and s.windows_complete
    assert {(0, 2), (1, 2), (2, 0), (2, 1)} <= set(s.windows)
    alphas = {w: float(np.linalg.eigvalsh(wd.sigma_sub(sys_, w))[-1]) for w in s.windows}
    assert alphas[(1, 2)] > alphas[(0, 2)] + 1e-3      # the noisier twin has the larger constant


# -- round-off: the allowance covers what exact arithmetic says ------------------------------------------

F_R = np.array([[1.1, 0.3], [0.0, 0.9]])
Q_R = 0.01 * np.eye(2)
C_R = np.array([[1.0, -0.999]])
R_R = np.array([[1e-3]])
X_R = np.array([[319833199.3776641, -320492674.7541014], [-320492674.7541014, 321153511.12574875]])
Z_R = np.array([[0.022184669007777588, -0.012029835570584709], [-0.012029835570584709, 0.006523286139836916]])


def _exact_riccati(X):
    """f(X) in exact rational arithmetic (information-free short form, exact for rationals)."""
    Fm = [[Fraction(x) for x in row] for row in F_R]
    c = [Fraction(x) for x in C_R[0]]
    u = [sum(X[i][j] * c[j] for j in range(2)) for i in range(2)]
    s = sum(c[i] * u[i] for i in range(2)) + Fraction(R_R[0, 0])
    P = [[X[i][j] - u[i] * u[j] / s for j in range(2)] for i in range(2)]
    FP = [[sum(Fm[i][k] * P[k][j] for k in range(2)) for j in range(2)] for i in range(2)]
    return [[sum(FP[i][k] * Fm[j][k] for k in range(2)) + Fraction(Q_R[i, j]) for j in range(2)] for i in range(2)]


def test_roundoff_allowance_covers_a_margin_that_exact_arithmetic_finds_positive():
    """Monotonicity f(X) ⪯ f(Y) with inputs of size 3e8 along the direction C sees: in floating point the
    Loewner margin is about −2e-8 (a fixed relative tolerance of 1e-9 would call it a counterexample),
    in exact rational arithmetic on the same floating-point inputs it is ≥ 0, and the derived round-off
    allowance covers the floating-point deficit."""
    Y = X_R + Z_R
    fX, KX = gk.riccati_step(X_R[None], C_R, R_R, F_R, Q_R, return_gain=True)
    fY, KY = gk.riccati_step(Y[None], C_R, R_R, F_R, Q_R, return_gain=True)
    margin = float(np.linalg.eigvalsh(fY - fX)[0, 0])
    assert margin < -1e-9
    dX, _ = gk.riccati_roundoff(X_R[None], KX, C_R, R_R, F_R, Q_R)
    dY, _ = gk.riccati_roundoff(Y[None], KY, C_R, R_R, F_R, Q_R)
    assert margin + float(dX[0] + dY[0]) >= 0
    Xe = [[Fraction(x) for x in row] for row in X_R]
    Ye = [[Fraction(x) for x in row] for row in Y]
    A, B = _exact_riccati(Xe), _exact_riccati(Ye)
    D = [[B[i][j] - A[i][j] for j in range(2)] for i in range(2)]
    assert D[0][0] + D[1][1] >= 0 and D[0][0] * D[1][1] - D[0][1] * D[1][0] >= 0   # exactly PSD


def test_error_bound_propagation_follows_the_closed_loop():
    """The propagated bound G E Gᵀ + δI stays finite along a long converging composition (a product of
    norms would overflow) and bounds the difference from a square-root computation of the same maps."""
    sys_ = _system(np.array([[1.25, 0.1], [0.0, 1.1]]), [[1.0, 0.3], [0.2, 1.0]], [[[0.5]], [[0.2]]])
    rng = np.random.default_rng(3)
    path = rng.integers(0, 2, (50, 300))
    run = sr.switched_riccati(sys_, path, 1e4 * np.eye(2), [300], keep_final=True)
    sq = sr.switched_riccati(sys_, path, 1e4 * np.eye(2), [300], keep_final=True, sqrt=True)
    assert np.all(np.isfinite(run["final_err"]))
    diff = np.linalg.norm(run["final"] - sq["final"], 2, axis=(1, 2))
    assert np.all(diff <= run["final_err"] + 1e-12 * np.linalg.norm(sq["final"], 2, axis=(1, 2)))


# -- iterates that stay finite ---------------------------------------------------------------------------

def test_square_root_form_agrees_and_stays_finite_where_joseph_breaks():
    rng = np.random.default_rng(0)
    M = 3
    F = rng.standard_normal((M, M))
    Q = 0.1 * np.eye(M)
    C = rng.standard_normal((4, 2, M))
    R = np.tile(0.5 * np.eye(2), (4, 1, 1))
    Z = rng.standard_normal((4, M, M + 1))
    X = Z @ np.swapaxes(Z, -1, -2)
    S = gk.riccati_sqrt_step(gk.factor_psd(X), C, np.linalg.cholesky(R), F, np.linalg.cholesky(Q))
    np.testing.assert_allclose(S @ np.swapaxes(S, -1, -2), gk.riccati_step(X, C, R, F, Q), atol=1e-12)
    # a huge direction that the sensor does not see, not along a coordinate axis
    v = np.array([1.0, 1.0, 1.0]) / np.sqrt(3)
    c = np.array([[1.0, -1.0, 0.0]]) / np.sqrt(2)
    S = gk.factor_psd(1e20 * np.outer(v, v) + np.eye(3))
    for _ in range(50):
        S = gk.riccati_sqrt_step(S, c, np.eye(1), 1.1 * np.eye(3), np.sqrt(0.1) * np.eye(3))
    feats = gk.factor_features(S)
    assert np.all(np.isfinite(feats)) and feats[gk.FEATURES.index("log_lam_min")] > np.log(0.09)


def _issue_crash_scenario() -> dict:
    """Two components; the second sees only c ⟂ the unstable eigenvector v = (cos θ, sin θ) of F."""
    th = 0.55
    V = _rotation(th)
    F = V @ np.diag([1.19, 0.86]) @ V.T
    c = [-np.sin(th), np.cos(th)]
    return {"family": "gossip-kalman", "name": "oblique-c1",
            "model": {"F": F.tolist(), "Q": [[0.1, 0.0], [0.0, 0.1]], "P0": [[1.0, 0.0], [0.0, 1.0]]},
            "sensors": {"types": [0, 0, 1, 1], "C": [[[1.0, 0.0], [0.0, 1.0]], [c]], "R": [[[1.0, 0.0], [0.0, 1.0]], [[1.0]]]},
            "graph": {"kind": "edges", "n": 4, "edges": [[0, 1], [2, 3]]},
            "protocol": {"kind": "single-edge", "edge_prob": 0.4},
            "simulation": {"slots": 256, "runs": 200, "reference_runs": 400, "quick_runs": 200, "quick_reference_runs": 400,
                           "quick_slots": 256}}


def test_c1_failure_with_an_oblique_unseen_direction_is_not_a_crash(tmp_path):
    """C.1 fails (two components) and one component cannot see an eigenvector that is not an axis: the
    theorem's auxiliary stage is not run, the horizon stays where the Joseph form is accurate, no claim
    is an error or a fail, and the divergence is checked."""
    repro = families.from_dict(_issue_crash_scenario())
    computed = repro.compute(RunOptions(seed=0, quick=True), StageContext(StageCache(tmp_path / "c")))
    r = computed.results.get("oblique-c1")
    assert "init_huge" not in r.aux and r.slots < 256
    ev = evaluate_claims(repro, computed)
    bad = [(c["id"], c["verdict"]) for c in ev.claims if c["verdict"] in ("fail", "error")]
    assert not bad, bad
    rows = {c["id"]: c for c in ev.claims}
    assert rows["oblique-c1.negative-control.divergence"]["verdict"] == "pass"
    assert rows["oblique-c1.thm8.initial-law"]["verdict"] == "not-checkable"
    assert "oblique-c1.hyp.c1" in rows["oblique-c1.thm8.initial-law"]["detail"]


# -- statistics ---------------------------------------------------------------------------------------------

def test_tests_keep_their_level_on_samples_of_one_law():
    """Exact KS (continuous and atomic laws), exact binomial, Hoeffding: false rejections at most nominal."""
    rng = np.random.default_rng(1)
    alpha, reps = 0.02, 1500
    ks_cont = [kst.ks_test(rng.standard_normal(25), rng.standard_normal(60))[1] for _ in range(reps)]
    ks_atoms = [kst.ks_test(rng.integers(0, 3, 30).astype(float), rng.integers(0, 3, 80).astype(float))[1]
                for _ in range(reps)]
    binom = kst.binom_p(rng.binomial(40, 0.07, reps), 40, 0.07)
    hoef = [kst.hoeffding_p(abs(rng.random(30).mean() - rng.random(50).mean()), 30, 50) for _ in range(reps)]
    for name, p in (("ks", ks_cont), ("ks atoms", ks_atoms), ("binomial", binom), ("hoeffding", hoef)):
        rate = float(np.mean(np.asarray(p) <= alpha))
        assert rate <= alpha + 3 * np.sqrt(alpha / reps), (name, rate)


def test_snapping_merges_values_within_their_resolution_only():
    a = np.array([0.0, 1.0, 2.0])
    b = a + np.array([1e-9, 1e-3, 0.0])
    x, y = kst.snap_many(a, b)
    assert x[0] == y[0] and x[1] != y[1] and x[2] == y[2]
    x, y = kst.snap_many((a, np.full(3, 1e-2)), b)         # a resolution of 1e-2 merges the second pair too
    assert x[1] == y[1]


# -- generator ----------------------------------------------------------------------------------------------

def test_generator_is_deterministic_valid_and_covers_its_edges():
    for k, edge in enumerate(generator.EDGES):
        a, b = generator.generate(k, edge), generator.generate(k, edge)
        assert a == b and a["family"] == "gossip-kalman"
        repro = families.from_dict(json.loads(json.dumps(a)))   # JSON-able, and valid
        assert repro.scenarios[0].N >= 2
    with pytest.raises(ValueError):
        generator.generate(0, "no-such-edge")
    shared = generator.generate(0, "shared-c-different-r")["sensors"]
    assert shared["C"][0] == shared["C"][1] and shared["R"][0] != shared["R"][1]
