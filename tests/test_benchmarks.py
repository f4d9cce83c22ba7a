"""Keeps the benchmark harness from rotting: one small benchmark end to end through
`benchmarks.run`, one side-by-side estimator row, and the reproduce runner on a failing run.
Measurements are not asserted against targets (timings depend on the machine); only that the
numbers exist, are positive, and that batching beats a per-trial loop by a wide margin."""
from __future__ import annotations

import json
import math

from benchmarks import bench_savas, run
from benchmarks.reproduce import run_once


def test_run_writes_markdown_and_json(tmp_path):
    assert run.main(["--quick", "--only", "floor", "--repeats", "1", "--out", str(tmp_path)]) == 0
    md = (tmp_path / "bench.md").read_text()
    data = json.loads((tmp_path / "bench.json").read_text())
    assert "## What the machine allows" in md and "ns per draw" in md
    assert data["meta"]["quick"] is True
    draws = data["floor"][0]
    assert draws["unit"] == "ns per draw" and 0 < draws["value"] < 1e3
    lo, hi = draws["spread"]
    assert lo <= draws["value"] <= hi


def test_estimator_row_batched_beats_per_trial_loop():
    rows = bench_savas.bench_filter(quick=True, repeats=1)
    assert len(rows) == 2
    for r in rows:
        assert r["unit"] == "µs/trial-node-step" and r["nodes"] == 3 and r["trials"] == 20_000
        assert math.isfinite(r["batched"]) and r["batched"] > 0
        assert r["ratio"] > 5, f"batched filter only {r['ratio']:.1f}x faster than the per-trial loop"
        assert isinstance(r["met"], bool)


def test_table_merges_median_and_spread():
    text = run.table([{"name": "a", "batched": 1.0, "batched_spread": (0.5, 2.0), "met": False}])
    assert "| 1 (0.5, 2) |" in text and "**no**" in text and "batched_spread" not in text


def test_reproduce_runner_reports_a_failed_run(tmp_path):
    res = run_once("no-such-paper", tmp_path / "out", quick=True)
    assert res["ok"] is False
    assert res["wall_s"] > 0 and res["max_rss_mib"] > 0


def test_estimates_section_measures_a_run_against_its_estimate():
    """`make bench`'s `estimates` row: the estimate and the measured run exist (no timing is asserted)."""
    from benchmarks.bench_estimates import estimate_row
    from pathlib import Path

    example = Path(run.__file__).resolve().parents[1] / "dse" / "families" / "template" / "example.toml"
    row = estimate_row("template", example, workers=1, repeats=1)
    assert row["ok"] and row["estimate_s"] > 0 and row["cpu_s"] > 0 and row["wall_s"] > 0
    assert math.isclose(row["est/cpu"], row["estimate_s"] / row["cpu_s"]) and isinstance(row["met"], bool)
