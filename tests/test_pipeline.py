"""The shared pipeline machinery: scenario readers, graphs, seeding, statistics, cache, verdicts."""
import json
import math

import networkx as nx
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from dse.scenario import graphs

from dse.scenario import fields as scenario

from dse.simulate import stats

from dse.verify import rules as verify
from dse.engine.atomic import atomic_path
from dse.engine.cache import StageCache
from dse.errors import CacheMiss, ScenarioError
from dse.simulate.seeding import block_seeds, stream_seed
from dse.simulate.units import parallel_map, run_blocks, trial_blocks


# -- scenario readers -------------------------------------------------------------------------

@pytest.mark.parametrize("value, reason", [(float("nan"), "finite"), (float("inf"), "finite"), (True, "number"),
                                           ("1", "number"), (-1.0, ">")])
def test_as_float_rejects_with_field_name(value, reason):
    with pytest.raises(ScenarioError) as err:
        scenario.as_float(value, "model.r", low=0.0, low_open=True)
    assert str(err.value).startswith("model.r:") and reason in str(err.value)


def test_as_matrix_checks_shape_symmetry_and_psd():
    with pytest.raises(ScenarioError, match=r"^P0: must have shape 2x2"):
        scenario.as_matrix([[1.0]], "P0", shape=(2, 2))
    with pytest.raises(ScenarioError, match=r"^P0: must be symmetric"):
        scenario.as_matrix([[1.0, 2.0], [0.0, 1.0]], "P0", symmetric=True)
    with pytest.raises(ScenarioError, match=r"^P0: must be positive semidefinite"):
        scenario.as_matrix([[1.0, 2.0], [2.0, 1.0]], "P0", psd=True)
    with pytest.raises(ScenarioError, match=r"^P0\[0\]\[1\]: must be finite"):
        scenario.as_matrix([[1.0, float("nan")], [0.0, 1.0]], "P0")
    assert np.array_equal(scenario.as_matrix([[2, 1], [1, 2]], "P0", psd=True), [[2.0, 1.0], [1.0, 2.0]])


def test_unknown_keys_are_named():
    with pytest.raises(ScenarioError, match=r"^model\.rr: unknown key"):
        scenario.reject_unknown({"q": 1, "rr": 2}, {"q", "r"}, "model")


def test_load_toml_errors(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_bytes(b"\xff\xfe\x00garbage")
    with pytest.raises(ScenarioError, match="UTF-8"):
        scenario.load_toml(bad)
    bad.write_text("x = [1, 2")
    with pytest.raises(ScenarioError, match="invalid TOML"):
        scenario.load_toml(bad)
    bad.write_text("")
    with pytest.raises(ScenarioError, match="empty"):
        scenario.load_toml(bad)


# -- graphs -------------------------------------------------------------------------------------

@pytest.mark.parametrize("spec", [{"kind": "line", "n": 5}, {"kind": "ring", "n": 6}, {"kind": "complete", "n": 4},
                                  {"kind": "grid", "rows": 3, "cols": 4},
                                  {"kind": "random_geometric", "n": 30, "radius": 0.4, "seed": 3},
                                  {"kind": "edges", "n": 4, "edges": [[0, 1], [1, 2], [2, 3], [3, 0]]}])
def test_graph_kinds(spec):
    g = graphs.graph(spec)
    G = g.build()
    assert sorted(G.nodes) == list(range(g.n)) and nx.is_connected(G)
    L = graphs.laplacian(G)
    np.testing.assert_allclose(L.sum(axis=1), 0, atol=1e-14)
    assert np.allclose(L, L.T) and np.linalg.eigvalsh(L)[1] > 1e-9  # algebraic connectivity > 0
    assert g.positions().shape == (g.n, 2)
    Q = graphs.metropolis_weights(G)
    graphs.check_consensus_matrix(Q, "Q")
    eps = 0.9 / graphs.max_degree(G)
    graphs.check_consensus_matrix(graphs.laplacian_consensus_weights(G, eps), "Q")


def test_graph_errors():
    with pytest.raises(ScenarioError, match=r"^graph: graph is not connected"):
        graphs.graph({"kind": "edges", "n": 4, "edges": [[0, 1], [2, 3]]})
    with pytest.raises(ScenarioError, match=r"^graph\.edges\[1\]: self-loop"):
        graphs.graph({"kind": "edges", "n": 3, "edges": [[0, 1], [2, 2]]})
    with pytest.raises(ScenarioError, match=r"^graph\.kind: must be one of"):
        graphs.graph({"kind": "star", "n": 3})
    with pytest.raises(ScenarioError, match=r"^graph\.radius: missing"):
        graphs.graph({"kind": "random_geometric", "n": 3})


@settings(max_examples=40, deadline=None)
@given(n=st.integers(2, 25), p=st.floats(0.05, 1.0), seed=st.integers(0, 10_000))
def test_metropolis_weights_property(n, p, seed):
    G = nx.gnp_random_graph(n, p, seed=seed)
    if not nx.is_connected(G):
        return
    Q = graphs.metropolis_weights(G)
    np.testing.assert_allclose(Q.sum(axis=0), 1, atol=1e-12)
    np.testing.assert_allclose(Q.sum(axis=1), 1, atol=1e-12)
    assert Q.min() >= 0 and np.allclose(Q, Q.T)
    lam = np.sort(np.abs(np.linalg.eigvalsh(Q)))
    assert lam[-1] == pytest.approx(1, abs=1e-12) and lam[-2] < 1 - 1e-12  # primitive on a connected graph


# -- seeding and blocks ---------------------------------------------------------------------------

def test_streams_are_named_not_ordered():
    a = np.random.default_rng(stream_seed(7, "carli", 2, 0.5)).standard_normal(4)
    _ = np.random.default_rng(stream_seed(7, "other")).standard_normal(4)
    b = np.random.default_rng(stream_seed(7, "carli", 2, 0.5)).standard_normal(4)
    c = np.random.default_rng(stream_seed(8, "carli", 2, 0.5)).standard_normal(4)
    d = np.random.default_rng(stream_seed(7, "carli", 2, 1.0)).standard_normal(4)
    assert np.array_equal(a, b) and not np.allclose(a, c) and not np.allclose(a, d)
    s1, s2 = block_seeds(stream_seed(1, "x"), 3), block_seeds(stream_seed(1, "x"), 5)
    assert all(np.array_equal(np.random.default_rng(x).random(3), np.random.default_rng(y).random(3)) for x, y in zip(s1, s2))


def test_trial_blocks_cover_exactly():
    assert trial_blocks(120_001, 50_000) == [(0, 50_000), (50_000, 50_000), (100_000, 20_001)]
    with pytest.raises(ValueError):
        trial_blocks(0)


def _square_sum(x):
    return float(np.sum(np.random.default_rng(stream_seed(3, x)).standard_normal(1000) ** 2))


def test_parallel_map_matches_serial():
    assert parallel_map(_square_sum, range(6), workers=2) == parallel_map(_square_sum, range(6), workers=1)


# -- statistics -------------------------------------------------------------------------------------

def test_error_moments_combine_matches_direct():
    rng = np.random.default_rng(0)
    err = rng.standard_normal((1000, 4, 3)) * [1.0, 2.0, 3.0] + 0.1
    parts = [stats.ErrorMoments.of(err[i:i + 300]) for i in range(0, 1000, 300)]
    mom = stats.ErrorMoments.combine(parts)
    np.testing.assert_allclose(mom.variance, err.var(axis=0, ddof=1), rtol=1e-12)
    np.testing.assert_allclose(mom.mean, err.mean(axis=0), rtol=1e-12)
    np.testing.assert_allclose(mom.trace, err.var(axis=0, ddof=1).sum(axis=1), rtol=1e-12)
    tr = (err ** 2).sum(axis=2)
    np.testing.assert_allclose(mom.trace_se, tr.std(axis=0) / np.sqrt(1000), rtol=1e-10)


def test_standard_errors_are_calibrated():
    """The trace SE predicts the spread of the trace estimate over repeated experiments."""
    rng = np.random.default_rng(1)
    estimates = [stats.ErrorMoments.of(rng.standard_normal((2000, 1, 3))).trace[0] for _ in range(400)]
    se = stats.ErrorMoments.of(rng.standard_normal((2000, 1, 3))).trace_se[0]
    assert np.std(estimates) == pytest.approx(se, rel=0.15)  # 400 repeats: the std is known to ~4%


def test_z_for_confidence():
    assert stats.z_for_confidence(0.95) == pytest.approx(1.959964, abs=1e-6)
    assert stats.confidence_of_z(stats.z_for_confidence(0.999, 10), 10) == pytest.approx(0.999, abs=1e-12)


# -- verdicts -------------------------------------------------------------------------------------------

def test_identity_and_inequality_verdicts():
    assert verify.identity([1.0, 2.0], [1.0, 2.0 + 1e-13], rtol=1e-12).status == verify.PASS
    v = verify.identity([1.0, 2.1], [1.0, 2.0], rtol=1e-3)
    assert v.status == verify.FAIL and v.measured == 2.1 and v.margin < 0
    v = verify.inequality([1.0, 2.0], [1.5, 2.1])
    assert v.status == verify.PASS and v.margin == pytest.approx(0.1)
    assert verify.inequality([1.0], [0.9]).status == verify.FAIL
    assert verify.inequality([1.0], [1.0], strict=True).status == verify.FAIL


def test_statistical_verdict():
    v = verify.statistical([1.02], [0.01], [1.0], confidence=0.95, trials=100)
    assert v.status == verify.FAIL and v.margin == pytest.approx(1.959964 - 2.0, abs=1e-5)
    assert verify.statistical([1.019], [0.01], [1.0], confidence=0.95, trials=100).status == verify.PASS


def test_erratum_logic():
    assert verify.erratum([1.0], [2.0], [2.0], rtol=1e-9).status == verify.ERRATUM
    assert verify.erratum([2.0], [1.0], [2.0], rtol=1e-9).status == verify.PASS
    assert verify.erratum([1.0], [1.5], [2.0], rtol=1e-9).status == verify.FAIL


def test_claim_that_raises_is_an_error_not_a_failure():
    claim = verify.Claim("x.y", "eq. (1)", "s", "identity", lambda r: 1 / 0)
    row = claim.evaluate(None)
    assert row["verdict"] == "error" and "ZeroDivisionError" in row["detail"]
    with pytest.raises(ValueError):
        verify.Claim("x", "s", "s", "vibes", lambda r: None)
    with pytest.raises(ValueError):
        verify.Claim("x", "s", "s", "identity", lambda r: None, scope="elsewhere")


def test_hypotheses_gate_conclusions_and_scope_filters_paper_claims():
    hyps = [verify.Hypothesis("h.ok", "holds", lambda r: verify.Holds(True, 0.5, 1.0)),
            verify.Hypothesis("h.no", "does not hold", lambda r: verify.Holds(False, 2.0, 1.0, "2 > 1")),
            verify.Hypothesis("h.undecided", "cannot be decided", lambda r: verify.Holds(None, detail="NaN")),
            verify.Hypothesis("h.broken", "raises", lambda r: [][1])]
    failing = lambda r: verify.Verdict(verify.FAIL, measured=2.0, reference=1.0)
    claims = [verify.Claim("c.ok", "s", "s", "inequality", failing, hypotheses=("h.ok",)),
              verify.Claim("c.no", "s", "s", "inequality", failing, hypotheses=("h.ok", "h.no")),
              verify.Claim("c.undecided", "s", "s", "inequality", failing, hypotheses=("h.undecided",)),
              verify.Claim("c.broken", "s", "s", "inequality", failing, hypotheses=("h.broken",)),
              verify.Claim("c.unknown", "s", "s", "inequality", failing, hypotheses=("h.missing",)),
              verify.Claim("c.paper", "s", "s", "inequality", failing, scope="paper-example")]
    ev = verify.evaluate(claims, hyps, None, paper_run=False)
    got = {r["id"]: r["verdict"] for r in ev.claims}
    assert got == {"c.ok": "fail", "c.no": "not-checkable", "c.undecided": "not-checkable", "c.broken": "error",
                   "c.unknown": "error"}
    assert "h.no does not hold" in ev.claims[1]["detail"] and "counterexample" in ev.claims[0]["detail"]
    assert ev.omitted_paper_example == 1 and [h["holds"] for h in ev.hypotheses] == [True, False, None, None]
    assert ev.hypotheses[3]["error"].startswith("IndexError")
    assert {r["id"] for r in verify.evaluate(claims, hyps, None, paper_run=True).claims} >= {"c.paper"}


def test_nan_is_never_a_failure():
    assert verify.identity([np.nan], [1.0], rtol=1e-9).status == verify.NOT_CHECKABLE
    assert verify.inequality([1.0], [np.inf]).status == verify.NOT_CHECKABLE
    assert verify.statistical([1.0], [np.nan], [1.0], trials=100).status == verify.NOT_CHECKABLE
    claim = verify.Claim("x", "s", "s", "identity", lambda r: verify.Verdict(verify.FAIL, measured=float("nan")))
    assert claim.evaluate(None)["verdict"] == verify.NOT_CHECKABLE


def test_family_wise_confidence_is_shared_by_the_statistical_claims():
    seen = []

    def check(r):
        seen.append(verify.claim_confidence())
        return verify.statistical([0.0], [1.0], [0.0], trials=100)

    claims = [verify.Claim(f"s{i}", "s", "s", "statistical", check) for i in range(4)]
    ev = verify.evaluate(claims, [], None, paper_run=True, family_confidence=0.99)
    assert seen == [pytest.approx(1 - 0.01 / 4)] * 4 and ev.statistics["statistical_claims"] == 4
    assert verify.statistical([0.0], [1.0], [0.0], trials=5, min_trials=10).status == verify.NOT_CHECKABLE


def test_exact_tests_keep_their_level():
    from dse.simulate import stats

    rng = np.random.default_rng(0)
    n, reps = 20, 20000   # a small sample: the χ² law is exact at any n
    p = stats.chi2_two_sided_p(np.square(rng.standard_normal((reps, n))).sum(1), n)
    lo, hi = stats.clopper_pearson(int((p < 0.05).sum()), reps, 0.999)
    assert lo <= 0.05 <= hi
    assert stats.effective_sample_size(np.ones(50)) == pytest.approx(50)
    assert stats.effective_sample_size(np.r_[1e6, np.ones(50)]) < 1.001


# -- atomic writes and the cache -------------------------------------------------------------------

def test_atomic_path_leaves_nothing_on_failure(tmp_path):
    target = tmp_path / "out.json"
    with pytest.raises(RuntimeError):
        with atomic_path(target) as tmp:
            tmp.write_text("partial")
            raise RuntimeError("killed")
    assert list(tmp_path.iterdir()) == []


def test_cache_roundtrip_and_corruption(tmp_path):
    cache = StageCache(tmp_path)
    calls = []

    def compute():
        calls.append(1)
        return {"a": np.arange(5.0), "b": np.eye(2)}

    params = {"x": 1, "arr": np.array([1.0, 2.0])}
    first = cache.get_or_compute("stage", params, compute)
    second = cache.get_or_compute("stage", params, compute)
    assert len(calls) == 1 and np.array_equal(first["a"], second["a"])
    npz = next(tmp_path.glob("*.npz"))
    raw = bytearray(npz.read_bytes())
    raw[len(raw) // 2] ^= 0xFF
    npz.write_bytes(bytes(raw))
    third = cache.get_or_compute("stage", params, compute)
    assert len(calls) == 2 and np.array_equal(third["b"], np.eye(2)) and cache.corrupt_entries
    with pytest.raises(CacheMiss):
        StageCache(tmp_path, read_only=True).get_or_compute("stage", {"x": 2}, compute)


def test_nonfinite_results_are_caught_where_they_appear(tmp_path):
    from dse.errors import NumericalError

    cache = StageCache(tmp_path)
    series = np.ones((5, 2))
    series[3, 1] = np.nan
    with pytest.raises(NumericalError, match=r"stage 'mc', scenario 'demo', array 'trace' at index \(3, 1\)"):
        cache.get_or_compute("mc", {"a": 1}, lambda: {"trace": series}, scenario="demo")
    assert list(tmp_path.iterdir()) == []  # nothing stored
    diverging = np.array([1.0, np.inf])
    out = cache.get_or_compute("mc", {"a": 2}, lambda: {"J": diverging}, scenario="demo", allow_nonfinite=("J",))
    assert np.isinf(out["J"][1])


def test_errors_survive_pickling():
    import pickle

    from dse.errors import NumericalError

    e = pickle.loads(pickle.dumps(NumericalError("mc", "demo", "array 'x' at index (1,)")))
    assert (e.stage, e.scenario, e.where) == ("mc", "demo", "array 'x' at index (1,)") and "stage 'mc'" in str(e)
    s = pickle.loads(pickle.dumps(ScenarioError("model.r", "must be > 0")))
    assert str(s) == "model.r: must be > 0"


def test_viewer_text_replaces_glyphs_the_viewer_cannot_draw():
    from dse.outputs.record import viewer_text

    assert viewer_text("tr 𝒫_i ≤ 𝓛 x̂ σ_c ℓ") == "tr P_i ≤ L x̂ σ_c ℓ"  # drawable characters are kept
    assert viewer_text("Pᵀ, x ∈ S, L⊗I") == "P^T, x  in  S, L(x)I"
    assert viewer_text("plain") == "plain" and viewer_text("🙂") == "?"


def test_shipped_glyph_ranges_match_the_viewer_font():
    from dse.outputs.viewer_check import embedded_font_coverage
    from dse.outputs.viewer_glyphs import INTER_RANGES

    shipped = {c for a, b in INTER_RANGES for c in range(a, b + 1)}
    assert shipped == embedded_font_coverage()


def test_an_identical_run_is_answered_from_its_memo_and_reuses_its_outputs(tmp_path, monkeypatch):
    import dse.api as api
    from dse.engine import cache
    from dse.engine.driver import run
    from test_cli import GOOD

    monkeypatch.setattr(cache, "project_fingerprint", lambda: "fixed-code")
    (tmp_path / "s.toml").write_text(GOOD)
    repro = api.load(tmp_path / "s.toml")
    from dse.engine.driver import RunOptions

    opts = RunOptions(quick=True)
    first = run(repro, tmp_path / "o", opts, out_dir=tmp_path / "o/run/x")
    report = (tmp_path / "o/run/x/report.json").read_text()
    figures = sorted(p.name for p in (tmp_path / "o/run/x").rglob("*.png"))
    calls = []
    monkeypatch.setattr(type(repro), "compute", lambda self, o, c: calls.append(1))
    again = run(repro, tmp_path / "o", opts, out_dir=tmp_path / "o/run/x")
    assert not calls, "the memo should answer without loading the stage results"
    assert {k: again[k] for k in ("pass", "fail")} == {k: first[k] for k in ("pass", "fail")}
    meta = json.loads((tmp_path / "o/run/x/run.json").read_text())
    assert sorted(p.name for p in (tmp_path / "o/run/x").rglob("*.png")) == figures and meta["outputs"]
    assert json.loads((tmp_path / "o/run/x/report.json").read_text())["claims"] == json.loads(report)["claims"]
    memo = next((tmp_path / "o/.cache").rglob("memo.json"))
    memo.parent.joinpath("tables", "claims.parquet").write_bytes(b"tampered")
    monkeypatch.undo()
    monkeypatch.setattr(cache, "project_fingerprint", lambda: "fixed-code")
    run(repro, tmp_path / "o", opts, out_dir=tmp_path / "o/run/x")  # detected, recomputed
    assert json.loads((tmp_path / "o/run/x/report.json").read_text())["counts"] == json.loads(report)["counts"]
