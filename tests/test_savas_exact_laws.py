"""The exact laws behind the savas Monte Carlo claims, and scenarios that used to break the checks.

The simulated errors of both filters are Gaussian with the covariance of the recursion (22), so a
batch of R trials gives exactly χ²(R) per-agent sums of squares, exactly normal sums, and a trace
whose Chernoff p-value is conservative. Splitting one long simulation into many small batches
gives many independent p-values: exact ones must be uniform, conservative ones stochastically
larger. This is the calibration at small trial counts that a normal approximation failed.
"""
from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

import dse.estimators.consensus_covariance as cc
import dse.estimators.consensus_filter as cf
import dse.registry
from dse.contract.options import RunOptions
from dse.contract.context import StageContext
from dse.engine.cache import StageCache
from dse.engine.driver import evaluate_claims
from dse.families.savas.exact_laws import chi2_sum_p, normal_sum_p, weighted_chi2_p

Q_RING = np.array([[0.5, 0.25, 0.0, 0.25], [0.25, 0.5, 0.25, 0.0], [0.0, 0.25, 0.5, 0.25], [0.25, 0.0, 0.25, 0.5]])
BATCH, BATCHES = 20, 1500


@pytest.fixture(scope="module")
def batches():
    kw = dict(ell=0.3, m=2, sigma_c=1.5, q=1.0, r=9.0, sigma0=1.0, n_steps=4, reinjection=True, zeta=0.2)
    run = cf.simulate_consensus_filter(Q_RING, x0_mean=0.0, n_trials=BATCH * BATCHES, rng=np.random.default_rng(7), **kw)
    P = cc.predictive_covariance_sequence(Q_RING, **kw)[-1]
    e = run.err_pred[:, -1].reshape(BATCHES, BATCH, 4)
    return e, P


def test_bisections_stopped_once_the_bracket_cannot_change_give_what_all_of_them_give(monkeypatch):
    from dse.families.savas import exact_laws

    rng = np.random.default_rng(3)
    weights = np.abs(rng.standard_normal((400, 5))) * rng.choice([1e-6, 1.0, 1e3], (400, 1))
    weights[::7, 1:] = 0.0                               # one weight: the exact χ² branch
    totals = weights.sum(axis=1) * 50 * rng.choice([0.0, 0.3, 0.9, 1.0, 1.1, 3.0], 400)
    stopped = weighted_chi2_p(totals, weights, 50)
    monkeypatch.setattr(exact_laws, "_converged", lambda mid, lo, hi: False)
    assert np.array_equal(weighted_chi2_p(totals, weights, 50), stopped)


def test_per_agent_chi2_and_mean_p_values_are_uniform(batches):
    e, P = batches
    p_var = chi2_sum_p(np.square(e).sum(axis=1), np.diag(P), BATCH).ravel()
    p_mean = normal_sum_p(e.sum(axis=1), np.diag(P), BATCH).ravel()
    for p in (p_var, p_mean):
        assert stats.kstest(p, "uniform").pvalue > 1e-3


def test_trace_p_values_are_conservative(batches):
    e, P = batches
    lam = np.broadcast_to(np.linalg.eigvalsh(P), (BATCHES, 4))
    p = weighted_chi2_p(np.square(e).sum(axis=(1, 2)), lam, BATCH)
    for alpha in (0.01, 0.05, 0.2):  # rejection rate at most alpha, up to binomial noise
        assert np.mean(p < alpha) <= alpha + 3 * np.sqrt(alpha / BATCHES)
    wrong = weighted_chi2_p(np.square(1.5 * e).sum(axis=(1, 2)), lam, BATCH)  # a 2.25-fold variance is caught
    assert np.mean(wrong < 0.01) > 0.5


def test_exact_laws_edge_values():
    assert chi2_sum_p(0.0, 0.0, 10) == 1.0 and chi2_sum_p(1e-3, 0.0, 10) == 0.0   # zero variance: exactly zero errors
    assert normal_sum_p(0.0, 0.0, 10) == 1.0
    p = weighted_chi2_p(np.array([0.0, 1e9, 20.0]), np.array([[1.0, 1.0]] * 3), 10)
    assert p[0] == 0.0 and p[1] < 1e-12 and p[2] == 1.0
    exact = weighted_chi2_p(np.array([12.0]), np.array([[2.0, 0.0]]), 5)  # one weight: exact χ²
    assert exact[0] == pytest.approx(float(chi2_sum_p(12.0, 2.0, 5)))


def _scenario(rounds, **over):
    data = {"family": "noisy-consensus-filter", "name": "edge", "graph": {"kind": "line", "n": 3},
            "consensus": {"weights": "laplacian", "eps": 0.4}, "model": {"q": 1.0, "r": 25.0},
            "sweep": {"rounds": rounds, "sigma_c": [0.0, 1.0], "n_steps": 6, "eval_step": 3},
            "monte_carlo": {"trials": 300}}
    data.update(over)
    return data


@pytest.mark.parametrize("rounds", [[0], [1], [0, 1]])
def test_zero_or_one_round_with_default_rounds_max_raises_nothing(rounds, tmp_path):
    repro = dse.registry.from_dict(_scenario(rounds))
    ev = evaluate_claims(repro, repro.compute(RunOptions(seed=1, quick=True), StageContext(StageCache(tmp_path))))
    bad = [(r["id"], r["verdict"], r["detail"][:200]) for r in ev.claims if r["verdict"] in ("fail", "error")]
    assert not bad
    assert all(not h["error"] and h["holds"] for h in ev.hypotheses if h["id"] != "edge.hyp.network")
    assert not [r for r in ev.claims if r["scope"] == "paper-example"]


def test_non_normal_Q_makes_the_trace_formula_not_checkable_by_its_hypothesis(tmp_path):
    Q = [[0.5, 0.5, 0.0, 0.0], [0.0, 0.2, 0.8, 0.0], [0.3, 0.0, 0.2, 0.5], [0.2, 0.3, 0.0, 0.5]]
    data = _scenario([0, 2], graph={"kind": "complete", "n": 4}, consensus={"weights": "matrix", "matrix": Q},
                     reinjection={"gains": "fixed", "ell": 0.3, "zeta": 0.2})
    repro = dse.registry.from_dict(data)
    ev = evaluate_claims(repro, repro.compute(RunOptions(seed=2, quick=True), StageContext(StageCache(tmp_path))))
    hyp = {h["id"]: h for h in ev.hypotheses}
    assert hyp["edge.hyp.Q_normal"]["holds"] is False and hyp["edge.hyp.Q_normal"]["value"] > 0.1
    claims = {r["id"]: r for r in ev.claims}
    assert claims["edge.thm1.ii"]["verdict"] == "not-checkable" and "edge.hyp.Q_normal" in claims["edge.thm1.ii"]["detail"]
    for cid in ("edge.thm1.i", "edge.mc.trace", "edge.mc.per_agent", "edge.thm1.stabilizing"):
        assert claims[cid]["verdict"] == "pass", cid
