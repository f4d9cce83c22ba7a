"""The random-comm-filter family end to end: the paper in quick mode, a user's scenario on a
system and graph not among the reproduction's scenarios, an honest report when the bound diverges, bad input."""
from __future__ import annotations

import json
import subprocess
import sys
import tomllib
from pathlib import Path

import numpy as np
import pytest

from dse import registry
from dse.errors import ScenarioError
from dse.engine.driver import RunOptions, run
from dse.families.tanwani.scenario import scenario_from_dict
from dse.outputs import record

RERUN = Path(sys.executable).parent / "rerun"

USER = """
family = "random-comm-filter"
name = "damped3"
[system]
A = [[0.0, 1.0], [-2.0, -0.3]]
B = [[0.0], [1.0]]
P0 = [[2.0, 0.0], [0.0, 1.0]]
[[sensors]]
H = [[1.0, 0.0]]
V = [[0.5]]
[[sensors]]
H = [[0.0, 1.0]]
V = [[0.2]]
[[sensors]]
H = [[1.0, 1.0]]
V = [[1.0]]
[graph]
kind = "line"
n = 3
[communication]
mode = "ordered"
rates = [3.0]
sweep = [0.1, 1e4, 12]
[simulation]
horizon = 3.0
output_step = 0.1
grid_step = 0.01
trials = 3000
event_trials = 300
quick_trials = 3000
quick_event_trials = 300
"""

# S1a's plant with λ below the critical rate 2.5 of (9): the bound diverges, the true covariance does not
DIVERGING = """
family = "random-comm-filter"
name = "below-critical"
[system]
A = [[0.5]]
B = [[1.0]]
[[sensors]]
H = [[1.0]]
V = [[1.0]]
L = [[3.0]]
[[sensors]]
H = [[1.0]]
V = [[1.0]]
L = [[0.0]]
[graph]
kind = "line"
n = 2
[communication]
rates = [2.0]
sweep = [0.5, 100.0, 10]
[gains]
rule = "given"
[simulation]
horizon = 2.0
quick_trials = 2000
quick_event_trials = 300
"""

NOT_HURWITZ = DIVERGING.replace('name = "below-critical"', 'name = "abar-unstable"').replace(
    "L = [[3.0]]", "L = [[0.2]]")


def load_toml_text(text):
    return tomllib.loads(text)


def _user(text):
    """What `dse run FILE.toml` does once the family is registered: parse, drop `family`, from_dict."""
    data = load_toml_text(text)
    assert data["family"] == "random-comm-filter"
    return registry.from_dict(data)


def read_by_the_tests(view_file: str) -> bool:
    """The views of the paper's run that the tests below read: the main scenario S2's recording and figures, F1 and
    the topology sweep. Every scenario's are drawn by `make reproduce` and by the CI's `make check-outputs` (and
    opened in the viewer by `make check-viewer`); the other four scenarios' were three quarters of the views' CPU."""
    return view_file == "s2.rrd" or view_file.endswith("_s2.png") or view_file in (
        "figures/fig1_network_events.png", "figures/fig_topology.png")


@pytest.fixture(scope="module")
def paper_run(tmp_path_factory):
    """The paper in quick mode with two forked workers, as `dse reproduce` computes it (one BLAS thread per process:
    tests/conftest.py sets it before numpy is imported), its report and tables written, and the views the tests
    read drawn into the run's directory."""
    from dse.api import execute
    from dse.contract.views import Outputs
    from dse.outputs.figures import draw_all

    out = tmp_path_factory.mktemp("tanwani")
    repro = registry.paper("tanwani")
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("DSE_PROGRESS", "0")
        result = execute(repro, RunOptions(quick=True, workers=2))
        d = result.write(out / "tanwani", figures=False)
        views = repro.views(Outputs(repro, result.results, result.tables, result.evaluation.claims, result.provenance))
        draw_all([lambda v=v: v.draw(d / v.file) for v in views if read_by_the_tests(v.file)], workers=2)
    return out, result.counts


def test_paper_quick_report(paper_run):
    out, summary = paper_run
    doc = json.loads((out / "tanwani" / "report.json").read_text())
    assert doc["paper"] == "tanwani"
    ids = {c["id"]: c for c in doc["claims"]}
    for name in ("s1a", "s1b", "s1c", "s2", "s3"):
        for what in ("thm3_1.item1_exact", "prop3_2.per_path", "prop3_4.mean_of_P", "reference_values",
                     "sim.event_exact_given_clocks", "reference.kalman_bucy"):
            assert ids[f"tanwani.{what}.{name}"]["verdict"] == "pass", (what, name, ids[f"tanwani.{what}.{name}"])
    for c in doc["claims"]:
        assert c["verdict"] in ("pass", "fail", "erratum", "not-checkable")
        if c["kind"] == "statistical" and c["verdict"] in ("pass", "fail"):
            assert c["confidence"] and c["trials"]
        if c["verdict"] == "erratum":
            assert c["printed"] is not None and c["corrected"] is not None
    assert ids["tanwani.errata.pi_sign"]["verdict"] == "erratum"
    assert ids["tanwani.thm3_1.item2_rate.s2"]["verdict"] == "pass"            # O(1/λ)
    figs = {p.name for p in (out / "tanwani" / "figures").glob("*.png")}
    assert {"fig1_network_events.png", "fig2_traces_s2.png", "fig3_sample_path_s2.png", "fig4_gaps_s2.png",
            "fig5_rate_s2.png", "fig6_traces_vs_rate_s2.png", "fig7_abscissa_s2.png", "fig_topology.png"} <= figs


def test_paper_recording_reads_back(paper_run):
    out, _ = paper_run
    path = out / "tanwani" / "s2.rrd"
    assert subprocess.run([str(RERUN), "rrd", "verify", str(path)], capture_output=True).returncode == 0
    data = record.read_scalars(path, "t")
    t, vals = data["/nodes/0/cov_trace/lam2"]
    np.testing.assert_array_equal(t.astype("timedelta64[ns]").astype(np.int64), np.round(np.arange(101) * 0.1 * 1e9))
    assert vals.shape == (101, 6)
    assert vals[0, 0] == pytest.approx(4.0) and vals[0, 1] == pytest.approx(4.0)     # tr P0 at t = 0
    assert np.all(vals[1:, 0] >= vals[1:, 1] - 1e-9)                                  # bound ≥ exact
    assert any(k.startswith("/events/edge_") for k in data)
    kinds = record.blueprint_view_kinds(path)
    assert "TimeSeries" in kinds and "Graph" in kinds
    edges = record.read_static(path, "/graph")
    assert len(edges["GraphEdges:edges"]) == 4


def test_user_scenario_runs(tmp_path):
    repro = _user(USER)
    summary = run(repro, tmp_path, RunOptions(quick=True, workers=2), out_dir=tmp_path / "run" / "damped3")
    doc = json.loads((tmp_path / "run" / "damped3" / "report.json").read_text())
    ids = {c["id"]: c for c in doc["claims"]}
    assert ids["damped3.thm3_1.item1_exact"]["verdict"] == "pass"
    assert ids["damped3.prop3_2.per_path"]["verdict"] == "pass"
    assert ids["damped3.limit.true_covariance"]["verdict"] == "not-checkable"    # ordered clocks
    assert not any(".reference_values." in k or ".nc." in k for k in ids)            # about the paper's scenarios
    assert all(h["error"] == "" for h in doc["hypotheses"])
    text = json.dumps(doc, ensure_ascii=False) + (tmp_path / "run" / "damped3" / "report.md").read_text()
    assert "spec" not in text.lower().replace("spectral", "")
    assert summary["fail"] == 0, [c["id"] for c in doc["claims"] if c["verdict"] == "fail"]
    assert (tmp_path / "run" / "damped3" / "damped3.rrd").exists()


@pytest.mark.parametrize("text, unbounded", [(DIVERGING, "λ_crit of (9) = 2.5"), (NOT_HURWITZ, "abar_hurwitz")])
def test_diverging_bound_is_reported_not_crashed(tmp_path, text, unbounded):
    repro = _user(text)
    name = repro.paper_id
    run(repro, tmp_path, RunOptions(quick=True, workers=2), out_dir=tmp_path / name)
    doc = json.loads((tmp_path / name / "report.json").read_text())
    text_all = json.dumps(doc, ensure_ascii=False)
    assert unbounded in text_all
    ids = {c["id"]: c for c in doc["claims"]}
    assert ids[f"{name}.thm3_1.item1_exact"]["verdict"] == "pass"      # item 1 holds for every λ
    if "hurwitz" in unbounded:
        hyps = {h["id"]: h for h in doc["hypotheses"]}
        assert hyps[f"{name}.hyp.abar_hurwitz"]["holds"] is False
        row = ids[f"{name}.thm3_1.item2_convergence"]
        assert row["verdict"] == "not-checkable" and "abar_hurwitz" in row["detail"]


BAD = [
    ("rates = [3.0]", "rates = [-1.0]", "communication.rates[0]: must be >"),
    ("mode = \"ordered\"", "mode = \"both\"", "communication.mode: must be one of"),
    ("V = [[0.5]]", "V = [[-0.5]]", "sensors[0].V: must be positive definite"),
    ("H = [[1.0, 0.0]]", "H = [[1.0, 0.0, 3.0]]", "sensors[0].H: must have 2 columns"),
    ("kind = \"line\"\nn = 3", "kind = \"line\"\nn = 1", "graph.n: must be >= 2, got 1"),
    ("P0 = [[2.0, 0.0], [0.0, 1.0]]", "P0 = [[1.0, 1.0], [1.0, 0.9999999995]]", "system.P0: must be positive semidefinite"),
    ("V = [[0.5]]", "V = [[0.5]]\nP_init = [[1.0, 0.0], [0.0, -1e-3]]", "sensors[0].P_init: must be positive semidefinite"),
    ("kind = \"line\"\nn = 3", "kind = \"edges\"\nn = 3\nedges = [[0, 1], [1, 0]]", "graph.edges[1]: repeats edge"),
    ("kind = \"line\"\nn = 3", "kind = \"ring\"\nn = 4", "sensors: must list one sensor per graph node (4)"),
    ("mode = \"ordered\"", "mode = \"ordered\"\nalpha = 0.9", "communication.alpha: must be <= 0.5"),
    ("V = [[0.5]]", "V = [[0.5]]\nL = [[1.0], [0.0]]", "sensors[0].L: only allowed with gains.rule = 'given'"),
    ("grid_step = 0.01", "grid_step = 0.03", "simulation.grid_step: must divide simulation.output_step"),
    ("B = [[0.0], [1.0]]", "B = [[0.0, 1.0]]", "system.B: must have 2 rows"),
    ("[simulation]", "[simulation]\nsteps = 3", "simulation.steps: unknown key"),
]


@pytest.mark.parametrize("old, new, message", BAD, ids=[m for _, _, m in BAD])
def test_bad_input_names_the_field(old, new, message):
    assert old in USER
    data = load_toml_text(USER.replace(old, new, 1))
    data.pop("family")
    with pytest.raises(ScenarioError) as exc:
        scenario_from_dict(data)
    assert message in str(exc.value)
