"""A new estimator of the compare arena is one declaration: here the open-loop predictor, declared in this
test module and registered, runs in a compare scenario beside the built-in ones, its exact moments are
checked against the simulation by the family's claims, and every other estimator's numbers are the same
bits as without it (common random numbers)."""
from __future__ import annotations

import numpy as np
import pytest

from dse import registry
from dse.contract.options import RunOptions
from dse.contract.context import StageContext
from dse.engine.cache import MemoryCache
from dse.engine.driver import evaluate_claims
from dse.errors import ScenarioError
from dse.estimators import network
from dse.estimators.protocol import NetworkEstimator, BatchedFilter

from test_compare_family import tiny


class OpenLoopPredictor(BatchedFilter):
    """Every node ignores its measurements and sends nothing: x̂_i(k|k) = x̄_i(k), x̄_i(k+1) = F x̂_i(k|k)
    from x̄_i(0) = x0. Its error x(k) − F^k x0 is N(0, Σ_k), Σ_0 = P0, Σ_{k+1} = F Σ_k Fᵀ + Q."""

    def __init__(self, model, B: int):
        self.F = model.F
        self.xbar = np.broadcast_to(model.x0[None, :, None], (model.N, model.n, B)).copy()

    def step(self, ctx) -> np.ndarray:
        est = self.xbar
        self.xbar = np.matmul(self.F, est)
        return est

    def shift(self, delta: np.ndarray) -> None:
        self.xbar = self.xbar + delta[None]


def predictor_moments(est, K: int) -> dict[str, np.ndarray]:
    m = est.network.model
    S, blocks = m.P0, []
    for _ in range(K):
        blocks.append(np.broadcast_to(S, (m.N, m.n, m.n)))
        S = m.F @ S @ m.F.T + m.Q
    blocks = np.array(blocks)
    return {"blocks": blocks, "mse": np.einsum("kiaa->ki", blocks), "disagreement": np.zeros(K)}


PREDICTOR = NetworkEstimator(name="predictor", title="open-loop predictor (test)", rank=95, exact=predictor_moments,
                             joint_moments=True, cost_weight=1,
                             build=lambda est, B, peers: OpenLoopPredictor(est.network.model, B))


@pytest.fixture
def with_predictor():
    network.register(PREDICTOR)
    yield
    network.unregister("predictor")


def _run(data, seed=4):
    repro = registry.from_dict(data)
    computed = repro.compute(RunOptions(seed=seed, quick=True, workers=1), StageContext(MemoryCache()))
    return repro, computed


def test_a_registered_estimator_runs_beside_the_others_and_changes_none_of_their_numbers(with_predictor):
    data = tiny(model="reliable")
    data["simulation"]["quick_trials"] = 1000
    repro, computed = _run(data)
    res = computed.results
    assert "predictor" in res.mc and "predictor" in res.exact and list(res.mc)[-1] == "predictor"
    B, K = res.trials, data["simulation"]["steps"]
    assert np.allclose(res.mc["predictor"]["msgs"], 0) and np.all(res.mc["predictor"]["nees"] == 0)
    ev = evaluate_claims(repro, computed)
    exact_claim = next(r for r in ev.claims if r["id"] == "compare.exact.monte_carlo")
    assert exact_claim["verdict"] == "pass" and "predictor (χ²" in exact_claim["detail"], exact_claim["detail"]
    assert not [r for r in ev.claims if r["verdict"] in ("fail", "error")]
    table = {spec.name: frame for spec, frame in repro.tables(res)}
    for name in ("estimators", "applicability", "nodes", "series"):
        assert "predictor" in set(table[name]["estimator"]), name

    network.unregister("predictor")
    assert "predictor" not in network.registry()
    _, without = _run(data)
    other = without.results
    assert list(other.mc) == [e for e in res.mc if e != "predictor"]
    for est, sums in other.mc.items():
        for name, arr in sums.items():
            assert np.array_equal(arr, res.mc[est][name]), (est, name)
    for est, moments in other.exact.items():
        for name, arr in moments.items():
            assert np.array_equal(arr, res.exact[est][name]), (est, name)
    assert B == other.trials and K == len(other.steps)


def test_an_estimator_name_is_registered_once(with_predictor):
    with pytest.raises(ValueError, match="already registered"):
        network.register(PREDICTOR)
    with pytest.raises(ScenarioError, match="estimators.include.0.: must be one of"):
        registry.from_dict({**tiny(), "estimators": {"include": ["kalman"]}})


MODULE = '''"""A test's estimator: every node predicts with the plant alone (no measurement, nothing sent)."""
import numpy as np

from dse.estimators.protocol import NetworkEstimator, BatchedFilter


class Predict(BatchedFilter):
    def __init__(self, model, B):
        self.F, self.x = model.F, np.broadcast_to(model.x0[None, :, None], (model.N, model.n, B)).copy()

    def step(self, ctx):
        est, self.x = self.x, np.matmul(self.F, self.x)
        return est

    def shift(self, delta):
        self.x = self.x + delta[None]


ESTIMATOR = NetworkEstimator(name="predict", title="prediction only", rank=99,
                             build=lambda est, B, peers: Predict(est.network.model, B))
'''


def test_a_module_of_the_estimators_package_is_an_estimator_with_no_registration_line(tmp_path, monkeypatch):
    import sys

    import dse.estimators.network as package

    (tmp_path / "predict.py").write_text(MODULE)
    monkeypatch.setattr(package, "__path__", [*package.__path__, str(tmp_path)])
    package.builtin.cache_clear()
    try:
        est = network.registry()["predict"]
        assert est.module == "dse.estimators.network.predict" and list(network.registry())[-1] == "predict"
        assert len(est.key()["code"]) == 16                       # keyed by its own source
        scenario = registry.from_dict(tiny()).scenario
        assert scenario.estimator_names[-1] == "predict"           # runs by default
        design = registry.from_dict(tiny()).design(RunOptions(quick=True), StageContext(MemoryCache()))
        assert design.running["predict"].communication().pattern == "none"
    finally:
        monkeypatch.undo()
        sys.modules.pop("dse.estimators.network.predict", None)
        package.builtin.cache_clear()
    assert "predict" not in network.registry()
