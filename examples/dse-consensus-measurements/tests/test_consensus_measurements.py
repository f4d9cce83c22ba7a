"""The consensus-on-measurements filter: its algebra on a network of our own (every link working, so that the
equations of its docstring can be checked one by one), then the same filter inside dse's compare arena (entry
point, scenario table, claims on shipped and generated scenarios, the approach to the centralized filter).

Run with `pytest` in this directory (the package installed: `pip install -e .`); dse's own suite runs these
tests too (tests/test_example_plugin.py)."""
from __future__ import annotations

import json
from dataclasses import dataclass
from importlib.metadata import entry_points
from pathlib import Path

import numpy as np
import pytest
from pydantic import ValidationError

from dse.plugin import Inbox, Messages, Problem
from dse_cm.filter import ConsensusOnMeasurements, Parameters, consensus_matrix

EPS = np.finfo(float).eps
SHIPPED = Path(__import__("dse").__file__).parent / "families" / "compare" / "scenarios"


def ring_problem(N: int = 6, rounds: int = 3, noise_std: float = 0.0) -> Problem:
    """A 2-state plant on a ring of N nodes, odd nodes measuring the position, even nodes the velocity; Metropolis
    weights (1/3 on every link of a ring)."""
    edges = np.array([(i, (i + 1) % N) for i in range(N)])
    neighbours = np.array([[(i - 1) % N, (i + 1) % N] for i in range(N)])
    H = np.array([[[1.0, 0.0]] if i % 2 else [[0.0, 1.0]] for i in range(N)])
    R = np.array([[[0.5 + 0.1 * i]] for i in range(N)])
    return Problem(F=np.array([[1.0, 0.3], [0.0, 0.98]]), Q=np.array([[0.02, 0.01], [0.01, 0.1]]),
                   P0=np.array([[2.0, 0.3], [0.3, 1.0]]), x0=np.array([1.0, -0.5]), H=H, R=R,
                   neighbours=neighbours, weights=np.full((N, 2), 1.0 / 3.0), degrees=np.full(N, 2), edges=edges,
                   link_model="reliable", rounds=rounds, noise_std=noise_std, steps=10)


@dataclass
class EveryLink:
    """A network whose links all work, as `dse.plugin.Network`: `noise` (exchanges, N, n, B) is what each
    exchange's `Inbox.noise` holds (σ_c applied)."""

    problem: Problem
    trials: int
    exchanges: int
    noise: np.ndarray | None = None
    k: int = 0
    calls: int = 0

    def exchange(self, payload: np.ndarray) -> Inbox:
        p, B = self.problem, self.trials
        delivered = np.broadcast_to((p.neighbours >= 0)[:, :, None], p.neighbours.shape + (B,))
        values = payload[np.maximum(p.neighbours, 0)] * delivered[:, :, None, :]
        noise = np.zeros((p.N, p.n, B)) if self.noise is None else self.noise[self.calls]
        self.calls += 1
        return Inbox(values, delivered, delivered.any(axis=1), noise)


def measurements(p: Problem, x: np.ndarray, rng, B: int) -> np.ndarray:
    """y_i = H_i x + v_i, (N, m, B), for states x (n, B)."""
    v = np.sqrt(p.R[:, :, 0])[:, :, None] * rng.standard_normal((p.N, p.m, B))
    return np.einsum("imn,nb->imb", p.H, x) + v


# -- the algebra --------------------------------------------------------------------------------------------

def test_sends_the_measurement_pair_each_round():
    p = ring_problem()
    assert ConsensusOnMeasurements.sends(p, Parameters()) == Messages(2 + 3, per="round")


def test_many_rounds_give_the_centralized_correction():
    """With L rounds on the ring, N Πᴸ = 1 1ᵀ + O(N λ₂ᴸ), λ₂ = 1/3 + 2/3 cos(2π/6) = 2/3: at L = 100 the
    consensus error, 6 (2/3)¹⁰⁰ ≈ 1e-17, is below round-off, and one step from the prior (x0, P0) is the
    centralized Kalman correction P_c = (P0⁻¹ + Σ U_j)⁻¹, x̂_c = x0 + P_c Σ H_jᵀ R_j⁻¹ (y_j − H_j x0) at every
    node (to round-off: 100 rounds of sums of 3 terms, then one solve of condition < 1e3)."""
    p, B = ring_problem(rounds=100), 5
    rng = np.random.default_rng(1)
    y = measurements(p, rng.standard_normal((p.n, B)), rng, B)
    f = ConsensusOnMeasurements(p, Parameters(), B)
    est = f.step(0, y, EveryLink(p, B, 100))
    G = np.einsum("imn,imk->ink", p.H, np.linalg.inv(p.R))
    Pc = np.linalg.inv(np.linalg.inv(p.P0) + np.einsum("ink,ikm->nm", G, p.H))
    resid = y - np.einsum("imn,n->im", p.H, p.x0)[:, :, None]
    xc = p.x0[:, None] + Pc @ np.einsum("ink,ikb->nb", G, resid)
    tol = 100 * 3 * 1e3 * EPS
    assert np.abs(est - xc[None]).max() <= tol * max(1.0, np.abs(xc).max())
    assert np.abs(f.covariance() - Pc[None]).max() <= tol * np.abs(Pc).max()


def test_equivariant_adding_c_to_state_and_prediction_adds_c_to_the_estimate():
    """The correction acts on innovations y_j − H_j x̄_i only (class doc): shifting the state (so every y_j by
    H_j c) and the predictions by c shifts the estimates by c, to round-off."""
    p, B = ring_problem(rounds=3), 4
    rng = np.random.default_rng(2)
    x = rng.standard_normal((p.n, B))
    c = 50.0 * rng.standard_normal((p.n, B))
    y = measurements(p, x, rng, B)
    a, b = ConsensusOnMeasurements(p, Parameters(), B), ConsensusOnMeasurements(p, Parameters(), B)
    b.shift(c)
    ea = a.step(0, y, EveryLink(p, B, 3))
    eb = b.step(0, y + np.einsum("imn,nb->imb", p.H, c), EveryLink(p, B, 3))
    assert np.abs(eb - ea - c[None]).max() <= 1e3 * EPS * np.abs(c).max()


@pytest.mark.parametrize("noise_std", [0.0, 0.7])
def test_declared_matrices_are_the_steps_error_map(noise_std):
    """ê = A ē + B v + C ξ (LinearStep) for the estimate `step` computes, at three successive steps, with and
    without communication noise (ξ stacked per exchange, node, component: the class doc's C)."""
    p, B = ring_problem(rounds=3, noise_std=noise_std), 3
    rng = np.random.default_rng(3)
    run, lin = ConsensusOnMeasurements(p, Parameters(), B), ConsensusOnMeasurements(p, Parameters(), 1)
    x = rng.standard_normal((p.n, B))
    for k in range(3):
        ebar = run.xbar - x[None]                                                   # (N, n, B)
        v = np.sqrt(p.R[:, :, 0])[:, :, None] * rng.standard_normal((p.N, p.m, B))
        xi = rng.standard_normal((3, p.N, p.n, B))
        y = np.einsum("imn,nb->imb", p.H, x) + v
        est = run.step(k, y, EveryLink(p, B, 3, noise_std * xi))
        step = lin.matrices(k)
        want = step.A @ ebar.reshape(-1, B) + step.B @ v.reshape(-1, B)
        if noise_std:
            want = want + noise_std * step.C @ xi.reshape(-1, B)
        else:
            assert step.C is None
        scale = np.abs(ebar).max() + np.abs(v).max() + np.abs(xi).max()
        assert np.abs((est - x[None]).reshape(-1, B) - want).max() <= 1e4 * EPS * scale
        w = 0.1 * rng.standard_normal((p.n, B))
        x = p.F @ x + w


def test_consensus_matrix_is_doubly_stochastic():
    W = consensus_matrix(ring_problem())
    assert np.allclose(W.sum(axis=0), 1.0, rtol=0, atol=8 * EPS) and np.allclose(W.sum(axis=1), 1.0, rtol=0, atol=8 * EPS)
    assert (W >= 0).all()


def test_rounds_default_to_the_links_rounds_and_are_unused_under_poisson():
    import dataclasses

    p = ring_problem(rounds=3)
    assert ConsensusOnMeasurements(p, Parameters(), 1).rounds == 3
    assert ConsensusOnMeasurements(p, Parameters(rounds=2), 1).rounds == 2
    assert ConsensusOnMeasurements(dataclasses.replace(p, link_model="poisson"), Parameters(rounds=5), 1).rounds == 0


def test_parameters_are_declared_and_validated():
    field = Parameters.model_fields["rounds"]
    assert field.default is None and field.description
    for bad in ({"rounds": 0}, {"rounds": 101}, {"gamma": 1.0}):
        with pytest.raises(ValidationError):
            Parameters.model_validate(bad)
    with pytest.raises(ValueError, match="rounds = 4 is more than the 3 synchronous rounds"):
        ConsensusOnMeasurements.sends(ring_problem(rounds=3), Parameters(rounds=4))


# -- in the arena -------------------------------------------------------------------------------------------

def test_the_installed_entry_point_is_this_filter():
    eps = {ep.name: ep for ep in entry_points(group="dse.estimators")}
    assert "cm" in eps, "the package is not installed: pip install -e examples/dse-consensus-measurements"
    assert eps["cm"].load() is ConsensusOnMeasurements


SMALL = """family = "compare"
name = "cm_ring"

[plant]
F = [[1.0, 0.3], [0.0, 0.98]]
Q = [[0.02, 0.01], [0.01, 0.1]]

[sensors]
types = [{ H = [[1.0, 0.0]], R = [[0.5]] }, { H = [[0.0, 1.0]], R = [[0.8]] }]

[graph]
kind = "ring"
n = 6

[links]
model = "reliable"
rounds = ROUNDS

[estimators]
include = ["central", "ci"]

[estimators.cm]
TABLE

[simulation]
steps = 20
trials = 1000
"""


def small_scenario(rounds: int, table: str = "") -> str:
    return SMALL.replace("ROUNDS", str(rounds)).replace("TABLE", table)


def plugin_verdicts(report: dict) -> dict[str, str]:
    return {c["id"]: c["verdict"] for c in report["claims"] if c["id"].startswith("compare.plugin.cm.")}


def test_dse_run_with_an_estimators_table(tmp_path, capsys):
    """`dse run` on a scenario whose `[estimators.cm]` table names no factory: the installed filter runs, its
    claims are checked (exact moments on reliable links), and it sends what consensus on information sends."""
    from dse.cli import main

    (tmp_path / "cm_ring.toml").write_text(small_scenario(4, "rounds = 4"))
    assert main(["run", "--quick", str(tmp_path / "cm_ring.toml"), "--out", str(tmp_path / "out")]) == 0
    capsys.readouterr()
    report = json.loads((tmp_path / "out" / "run" / "cm_ring" / "report.json").read_text())
    verdicts = plugin_verdicts(report)
    assert verdicts["compare.plugin.cm.exact_moments"] == "pass", verdicts
    assert verdicts["compare.plugin.cm.orthogonality"] == "pass" and verdicts["compare.plugin.cm.lower_bound"] == "pass"
    assert verdicts["compare.plugin.cm.nees"] == "not-checkable"      # covariance_law = None
    import pandas as pd

    table = pd.read_parquet(tmp_path / "out" / "run" / "cm_ring" / "tables" / "estimators.parquet").set_index("estimator")
    assert table.loc["cm", "scalars_per_step"] == table.loc["ci", "scalars_per_step"] == 4 * 2 * (2 + 3)


def test_a_factory_table_loads_it_and_rounds_beyond_the_links_name_the_table():
    import dse

    dse.check(_toml(small_scenario(4, 'factory = "dse_cm.filter:ConsensusOnMeasurements"\nrounds = 4')))
    with pytest.raises(dse.ScenarioError, match=r"estimators\.cm.*rounds = 5 is more than the 4"):
        dse.check(_toml(small_scenario(4, "rounds = 5")))


def _toml(text: str) -> dict:
    import tomllib

    return tomllib.loads(text)


def exact_excess(rounds: int) -> float:
    """The exact network MSE of cm over the centralized filter's, relative, at the last step."""
    import dse

    run = dse.run(_toml(small_scenario(rounds)), quick=True, seed=1)
    t = run.tables["estimators"].set_index("estimator")
    assert t.loc["cm", "exact"] and t.loc["central", "exact"]
    return float(t.loc["cm", "network_mse"] / t.loc["central", "network_mse"] - 1.0)


def test_on_reliable_links_more_rounds_approach_the_centralized_filter():
    """The excess over the centralized filter is E‖x̂_i − x̂_c‖² (orthogonality), quadratic in the consensus
    error N Πᴸ − 1 1ᵀ = O(6 (2/3)ᴸ): it shrinks with L, and at L = 100 (6 (2/3)¹⁰⁰ ≈ 1e-17) only the round-off
    of the exact recursions (20 steps on 12 × 12 matrices: well below 1e-9 relative) is left."""
    excess = [exact_excess(L) for L in (1, 4, 16, 100)]
    assert excess[0] > excess[1] > excess[2] > 0
    assert abs(excess[3]) < 1e-9


def scenario_with_cm(data: dict) -> dict:
    """A scenario with the centralized filter and cm only (cm's numbers do not depend on the other filters:
    common random numbers)."""
    data = dict(data)
    data["estimators"] = {"include": ["central"], "cm": {}}
    return data


def shipped() -> list[tuple[str, dict]]:
    return [(f.stem, _toml(f.read_text())) for f in sorted(SHIPPED.glob("*.toml"))]


def generated() -> list[tuple[str, dict]]:
    from dse.registry import family

    compare = family("compare")
    edges = ("failures", "matchings", "poisson_noisy", "reliable_noisy_scalar", "two_row_sensors", "unstable_plant",
             "weak_detectability")
    return [(f"generated-{e}", compare.generate(7, e)) for e in edges]


@pytest.mark.parametrize("name,data", shipped() + generated(), ids=lambda v: v if isinstance(v, str) else "")
def test_its_claims_never_fail_or_err(name, data):
    import dse

    run = dse.run(scenario_with_cm(data), quick=True, seed=3)
    claims = run.claims.set_index("id")
    mine = claims[claims.index.str.startswith("compare.plugin.cm.")]
    assert len(mine) == 4 and not mine.verdict.isin(["fail", "error"]).any(), mine[["verdict", "detail"]].to_string()
    assert mine.loc["compare.plugin.cm.orthogonality", "verdict"] == "pass"
    assert run.tables["faults"].empty
