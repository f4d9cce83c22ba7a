"""Scenario S1 of the reproduction (scalar plant, two nodes): closed forms of the bound (9), of the exact
mean covariance, of the critical rates and of the Lyapunov limits, plus reference numbers of S2/S3."""
from __future__ import annotations

import math

import numpy as np
import pytest

import dse.estimators.gossip_covariance as gc
from dse.estimators.gossip_filter import GossipSystem, kalman_bucy_split_gains
from dse.families.tanwani import reference_values as ref
from dse.families.tanwani.scenario import load_scenario


def s1(L, alpha=0.5, mode="edge"):
    one = np.eye(1)
    return GossipSystem(np.array([[0.5]]), one, (one, one), (one, one), tuple(np.array([[l]]) for l in L), ((0, 1),),
                        alpha, mode)


GAINS = {"s1a": (3.0, 0.0), "s1b": (2.0, 2.0), "s1c": (3.0, 2.0)}


@pytest.mark.parametrize("name", sorted(GAINS))
@pytest.mark.parametrize("lam", [3.0, 5.0, 10.0, 20.0, 100.0, 1000.0])
def test_steady_states_match_closed_forms(name, lam):
    cf = ref.CLOSED_FORMS[name]
    s = s1(GAINS[name])
    if lam <= cf["crit_bound"]:
        assert gc.bound_steady(s, lam) is None
        return
    P = gc.bound_steady(s, lam)[:, 0, 0]
    np.testing.assert_allclose(P, cf["bound"](lam), rtol=1e-12)
    J = gc.joint_steady(s, lam)
    np.testing.assert_allclose([J[0, 0], J[1, 1], J[0, 1]], cf["joint"](lam), rtol=1e-12)
    assert J[0, 1] == pytest.approx(J[1, 0], rel=1e-14)


@pytest.mark.parametrize("name", sorted(GAINS))
def test_lyapunov_limits_and_kalman_bucy(name):
    cf = ref.CLOSED_FORMS[name]
    s = s1(GAINS[name])
    assert gc.lyapunov_S(s)[0, 0] == pytest.approx(cf["S"], rel=1e-14)
    assert gc.lyapunov_S_true(s)[0, 0] == pytest.approx(cf["S_true"], rel=1e-14)
    L, P = kalman_bucy_split_gains(s.A, s.B, s.H, s.V)
    assert P[0, 0] == pytest.approx(1.0, rel=1e-12)           # 2P² − P − 1 = 0
    assert [l[0, 0] for l in L] == pytest.approx([2.0, 2.0], rel=1e-12)


def test_critical_rates_s1a():
    s = s1(GAINS["s1a"])
    assert gc.critical_rate_bound(s) == pytest.approx(2.5, rel=1e-8)            # k = λ/2 > 5/4
    assert gc.critical_rate_joint(s) == pytest.approx((-7 + math.sqrt(369)) / 8, rel=1e-8)
    assert gc.bound_abscissa(s, 2.49) > 0 > gc.bound_abscissa(s, 2.51)


@pytest.mark.parametrize("name", ["s1b", "s1c"])
def test_critical_rate_zero_when_every_node_is_stable(name):
    assert gc.critical_rate_bound(s1(GAINS[name])) == 0.0


def test_critical_rate_zero_when_marginal_at_zero():
    """A node with A_1 = 0 (L_1 = 0.5 on A = 0.5) is only marginally stable: M_9(0) has abscissa 0
    (to round-off), every λ > 0 is stable, and the critical rate is 0, not a rounding-level 1e-16."""
    s = GossipSystem(np.array([[0.5]]), np.eye(1), (np.eye(1), np.eye(1)), (np.eye(1), np.eye(1)),
                     (np.array([[0.5]]), np.array([[1.5]])), ((0, 1),), 0.5)
    assert abs(gc.bound_abscissa(s, 0.0)) <= gc.bound_abscissa_tolerance(s, 0.0)
    assert gc.bound_abscissa(s, 1e-3) < 0
    assert gc.critical_rate_bound(s) == 0.0
    assert gc.critical_rate_joint(s) == 0.0


def test_first_order_deviation_s1a():
    """λ(𝒫^∞ − S) → (15/8, 75/8) for S1a (closed form (15/4, 75/4)/(4k − 5), k = λ/2), and the
    deviation solved for directly keeps its relative accuracy at λ = 1e8 (eps·κ(M_9) ~ 1e-8, where
    forming 𝒫^∞ and subtracting S would leave no digit)."""
    s = s1(GAINS["s1a"])
    np.testing.assert_allclose(gc.first_order_deviation(s)[:, 0, 0], [15 / 8, 75 / 8], rtol=1e-12)
    for lam in (1e2, 1e8):
        d = gc.bound_steady_deviation(s, lam, gc.lyapunov_S(s))[:, 0, 0]
        np.testing.assert_allclose(d, np.array([15 / 4, 75 / 4]) / (2 * lam - 5), rtol=1e-7)


@pytest.mark.parametrize("name", sorted(GAINS))
def test_second_moments_of_the_p_process(name):
    """The mean carried by the second-moment equation is (9); identical nodes (S1b) have a P-process
    that is the same on every clock path, so its variance over the paths vanishes."""
    s = s1(GAINS[name])
    w = np.eye(2)                                    # P_1 and P_2 (scalar nodes: one coordinate each)
    mean, second = gc.bound_second_moments(s, 10.0, 0.1, 20, w)
    P = gc.bound_transient(s, 10.0, 0.1, 20)[:, :, 0, 0]
    np.testing.assert_allclose(mean, P, rtol=1e-10)
    assert np.all(second >= mean ** 2 * (1 - 1e-10))
    if name == "s1b":
        np.testing.assert_allclose(second, mean ** 2, rtol=1e-10)


def test_s1a_distance_is_exactly_order_one_over_lambda():
    s = s1(GAINS["s1a"])
    for lam in (10.0, 100.0, 1e4):
        k = lam / 2
        d = gc.bound_steady(s, lam)[:, 0, 0] - 2.75
        np.testing.assert_allclose(d, np.array([15 / 4, 75 / 4]) / (4 * k - 5), rtol=0, atol=1e-12)  # difference of O(1) solves


def test_s1b_bound_independent_of_rate_and_transient():
    s = s1(GAINS["s1b"])
    for lam in (0.1, 1.0, 10.0, 1e3):
        P = gc.bound_transient(s, lam, 0.25, 20)
        np.testing.assert_allclose(P[:, 0], P[:, 1], rtol=1e-12)
        S_t = gc.bound_transient(s, 0.0, 0.25, 20)                   # no communication: 𝒮(t) itself
        np.testing.assert_allclose(P, S_t, rtol=1e-12)
    assert gc.bound_steady(s, 7.0)[0, 0, 0] == pytest.approx(5 / 3, rel=1e-13)


def test_s1a_transient_reference_values():
    s = s1(GAINS["s1a"])
    P = gc.bound_transient(s, 10.0, 0.1, 50)[:, :, 0, 0]
    J = gc.diagonal_blocks(gc.joint_transient(s, 10.0, 0.1, 50), 2, 1)[:, :, 0, 0]
    for t, (p1, p2, j1, j2) in ref.S1A_TRANSIENT.items():
        k = int(round(t / 0.1))
        np.testing.assert_allclose([P[k, 0], P[k, 1], J[k, 0], J[k, 1]], [p1, p2, j1, j2], atol=6e-7)
    np.testing.assert_allclose(gc.joint_transient(s, 10.0, 0.1, 1)[1], [[1.29473, 0.98058], [0.98058, 1.174167]],
                               atol=6e-6)


def test_ordered_clocks_give_the_same_bound_but_another_covariance():
    a, b = s1(GAINS["s1c"]), s1(GAINS["s1c"], mode="ordered")
    np.testing.assert_allclose(gc.bound_generator(a, 3.0)[0], gc.bound_generator(b, 3.0)[0], atol=1e-14)
    assert not np.allclose(gc.joint_steady(a, 3.0), gc.joint_steady(b, 3.0))


@pytest.mark.parametrize("name, rv", [("s2", ref.S2), ("s3", ref.S3)])
def test_reference_numbers(name, rv):
    s = load_scenario(name).gossip
    assert gc.critical_rate_bound(s) == pytest.approx(rv["crit_bound"], abs=6e-6)
    for lam, (tb, tj) in rv["steady"].items():
        trP = np.trace(gc.bound_steady(s, lam), axis1=1, axis2=2)
        np.testing.assert_allclose(trP[: len(tb)], tb, atol=6e-5)  # S2 lists nodes 1, 2 (3, 4 by symmetry)


def test_s3_explicit_bound_constants():
    s = load_scenario("s3").gossip
    for variant in ("faithful", "tight"):
        eb = gc.explicit_bound(s, variant)
        assert eb.threshold == pytest.approx(ref.S3["lam_thr"][variant], rel=5e-3)
        assert eb.value(1e5) == pytest.approx(ref.S3["B12_1e5"][variant], rel=5e-3)
        assert eb.value(0.5 * eb.threshold) == math.inf
