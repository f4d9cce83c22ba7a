"""The template family end to end (it is the example a new family copies, so it must stay runnable),
and what a run records of its stages: report.json's `provenance.stages` says which stage ran, under
which key, and whether it was read back from the cache; a faked edit of a module the stage imports
transitively makes the next run recompute it."""
from __future__ import annotations

import json
import shutil

import numpy as np

from dse import api, registry
from dse.contract import stages as stage_mod
from dse.scenario.fields import load_toml

EXAMPLE = registry.family("template").example_file()


def small(**model):
    data = load_toml(EXAMPLE)
    data["model"] = {**data["model"], **model}
    data["monte_carlo"] = {"trials": 1000}
    return data


def test_example_passes_and_matches_matrix_powers():
    run = api.run(small(rounds=6), seed=3)
    assert run.counts["pass"] == 2 and run.counts["fail"] == run.counts["error"] == 0
    sc, design = run.reproduction.scenario, run.computed.design
    oracle = np.array([sc.model.r * np.diag(np.linalg.matrix_power(sc.W, 2 * t)) for t in range(7)])
    np.testing.assert_allclose(design.mse, oracle, rtol=1e-13, atol=1e-15)
    mse = run.tables["mse"]
    assert len(mse) == 7 * sc.n and set(mse.columns) == {"round", "node", "exact", "monte_carlo", "se"}


def test_disconnected_graph_makes_the_rate_claim_not_checkable():
    data = registry.family("template").generate(0, "disconnected")
    run = api.run(data, quick=True)
    verdicts = {r["id"]: r for r in run.evaluation.claims}
    rate = verdicts[f"{data['name']}.consensus.rate"]
    assert rate["verdict"] == "not-checkable" and "hyp.connected" in rate["detail"]
    assert verdicts[f"{data['name']}.consensus.monte_carlo"]["verdict"] == "pass"


def test_check_needs_no_simulation():
    chk = api.check(small())
    assert [h["holds"] for h in chk.hypotheses] == [True]
    assert "spectrum" in chk.tables and chk.estimate["seconds"] > 0


def _stages(run_dir):
    return json.loads((run_dir / "report.json").read_text())["provenance"]["stages"]


def test_provenance_lists_the_stages_and_a_code_edit_invalidates_them(tmp_path, monkeypatch):
    from dse.engine.driver import RunOptions, run as drive

    data = small(rounds=4)
    repro = api.load(data)
    out = tmp_path / "out"

    def once():
        drive(api.load(data), out, RunOptions(seed=1), out_dir=out / "r", source=data, figures=False)
        shutil.rmtree(out / ".cache" / repro.paper_id / "runs")      # no memo: the stages themselves are read back
        return _stages(out / "r")

    first = once()
    assert [(s["name"], s["cached"]) for s in first] == [("monte_carlo", False)] and first[0]["key"]
    second = once()
    assert second == [{**first[0], "cached": True}]
    # a faked edit of a module the stage imports transitively (the seeding of its random streams)
    real = stage_mod.module_file
    edited = tmp_path / "seeding.py"
    edited.write_bytes(real("dse.simulate.seeding").read_bytes() + b"\n# edited\n")
    monkeypatch.setattr(stage_mod, "module_file", lambda name: edited if name == "dse.simulate.seeding" else real(name))
    stage_mod.code_hash.cache_clear()
    try:
        third = once()
    finally:
        monkeypatch.undo()
        stage_mod.code_hash.cache_clear()
    assert third[0]["cached"] is False and third[0]["key"] != first[0]["key"]
