"""What a sweep point computes (only the claims, tables and metrics the sweep asks for; design shared
between the points of a process), the cells of one point drawn as rows of the figure, and the figures'
confidence bands."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from scipy import stats

from dse.errors import ScenarioError
from dse.sweeps import outputs as so
from dse.sweeps import run as sw
from dse.sweeps.spec import parse_sweep

ROOT = Path(__file__).resolve().parents[1]
SAVAS = ROOT / "dse" / "families" / "savas" / "paper.toml"


def savas(**overrides) -> dict:
    """Two sizes of a 3-agent-ish savas line at 200 trials, two cells (m = 1, 2) per point."""
    data = {"name": "cells", "base": str(SAVAS), "seed": 1, "quick": True, "trials": 200,
            "set": {"sweep.rounds": [1, 2], "sweep.sigma_c": [1.0], "gains.rounds_max": 2},
            "grid": {"graph.n": [3, 4]}}
    data.update(overrides)
    return parse_sweep(data, base_dir=ROOT)


def test_a_point_checks_only_the_claims_asked_for_and_builds_no_table_when_none_is(tmp_path, monkeypatch):
    built = []
    real = sw._point_tables
    monkeypatch.setattr(sw, "_point_tables", lambda *a: built.append(a[3:]) or real(*a))
    spec = savas(claims=["mc.trace", "thm1.*"], tables=[], metrics=[])
    sw.run_sweep(spec, tmp_path, scheduler="inline", log=lambda _: None)
    claims = pd.read_parquet(tmp_path / "sweep" / "cells" / "claims.parquet")
    assert sorted(set(claims["claim"])) == ["paper.mc.trace", "paper.thm1.i", "paper.thm1.i.mc", "paper.thm1.ii",
                                            "paper.thm1.stabilizing"]
    results = pd.read_parquet(tmp_path / "sweep" / "cells" / "results.parquet")
    assert not [c for c in results.columns if c.startswith("metric:")]
    assert not (tmp_path / "sweep" / "cells" / "tables").exists() or not any((tmp_path / "sweep" / "cells" / "tables").iterdir())
    stored = [sw.PointStore(sw.points_dir(tmp_path, "cells")).load(t.key) for t in sw.build_tasks(spec)]
    assert all(r["table_files"] == {} for r in stored)
    # the family's tables were not built: _point_tables returned an empty set of tables for each point
    assert built and all(b == ((), ()) for b in built)


def test_a_claim_pattern_that_matches_nothing_is_refused_before_anything_runs(tmp_path):
    with pytest.raises(ScenarioError, match="no.such: no claim of the points matches") as err:
        sw.run_sweep(savas(claims=["no.such"]), tmp_path, scheduler="inline", log=lambda _: None)
    assert err.value.field == "claims"
    assert not (tmp_path / "sweep").exists()


def test_selected_claims_give_the_verdicts_of_a_full_point_where_confidence_is_not_shared():
    """An identity's verdict and numbers do not depend on which other claims were checked."""
    full = sw.run_point(sw.build_tasks(savas())[0].payload())
    lean = sw.run_point(sw.build_tasks(savas(claims=["thm1.i"], tables=[], metrics=[]))[0].payload())
    [row] = [c for c in full["claims"] if c["id"] == "paper.thm1.i"]
    assert lean["claims"] == [row]
    assert lean["tables"] == {} and lean["metrics"] == {}


@pytest.mark.parametrize("change, field", [
    ({"plot": {"cells": ["m"]}, "tables": ["claims"]}, "plot.cells"),
    ({"plot": {"table": "cells"}}, "plot.table"),
    ({"plot": {"table": "cells", "rows": "cell"}, "tables": ["metrics"]}, "plot.table"),
    ({"plot": {"metrics": ["kf_trP"]}, "metrics": ["carli_trP_mc"]}, "plot.metrics"),
    ({"claims": "mc.trace"}, "claims"),
])
def test_bad_selection_keys_name_the_field(change, field):
    with pytest.raises(ScenarioError) as err:
        savas(**change)
    assert err.value.field == field


def test_points_that_share_a_design_compute_it_once(monkeypatch):
    """The savas design depends on the gains' grid, not on the seed: the second replicate reads it back."""
    monkeypatch.setattr(sw, "_SHARED", None)
    spec = savas(replicates=2, grid={"graph.n": [3]}, claims=[], tables=[], metrics=[])
    tasks = sw.build_tasks(spec)
    first = sw.run_point(tasks[0].payload())
    hits = sw.shared_stages().hits
    sw.run_point(tasks[1].payload())
    assert first["status"] == "ok" and sw.shared_stages().hits > hits


def test_shared_stages_drop_the_least_recently_used_and_copy_in_and_out():
    cache = sw.SharedStages(limit_mib=3 * 8 / 2**20)           # room for three float64 scalars
    for i in range(4):
        cache.save("s", {"i": i}, {"x": np.array([float(i)])})
    assert cache.load("s", {"i": 0}) is None                   # the oldest was dropped
    got = cache.load("s", {"i": 3})
    got["x"][0] = -1.0                                         # a point that writes into what it read
    assert cache.load("s", {"i": 3})["x"][0] == 3.0


def test_cells_of_one_point_are_rows_of_the_figure(tmp_path):
    spec = savas(plot={"x": "m", "cells": ["m"], "metrics": ["carli_trP_mc", "kf_trP"]})
    sw.run_sweep(spec, tmp_path, scheduler="inline", log=lambda _: None)
    tasks = sw.build_tasks(spec)
    store = sw.PointStore(sw.points_dir(tmp_path, "cells"))
    results = [store.load(t.key) for t in tasks]
    frame = so.results_frame(spec, [t.point for t in tasks], results)
    drawn = so.cell_frame(spec, frame, results)
    assert sorted(zip(drawn["graph.n"], drawn["m"])) == [(3, 1), (3, 2), (4, 1), (4, 2)]
    # a metric without cell values (the centralized filter's) is the point's, repeated for each of its cells
    assert drawn.groupby("graph.n")["metric:kf_trP"].nunique().eq(1).all()
    plan = so.plot_plan(spec, drawn)
    assert plan.x == "m" and plan.others == ["graph.n"]
    assert (tmp_path / "sweep" / "cells" / "sweep.png").stat().st_size > 0


def test_bands_are_student_t_over_replicates_and_normal_for_a_standard_error():
    x = np.array([1.0, 1.0, 1.0, 2.0])
    y = np.array([1.0, 2.0, 3.0, 5.0])
    se = np.array([np.nan, np.nan, np.nan, 0.5])
    xs, mid, lo, hi = so.summarise(x, y, se)
    half = stats.t.ppf(0.975, 2) * 1.0 / np.sqrt(3)            # sd of (1, 2, 3) is 1
    assert np.allclose(xs, [1, 2]) and np.allclose(mid, [2, 5])
    assert np.allclose(hi - mid, [half, stats.norm.ppf(0.975) * 0.5]) and np.allclose(mid - lo, hi - mid)
    _, mid, lo, hi = so.summarise(x, y, spread=True)           # random draws of other fields: their range
    assert np.allclose([mid[0], lo[0], hi[0]], [2, 1, 3])


def _arrow(path: Path, frame: pd.DataFrame) -> Path:
    import pyarrow as pa

    table = pa.Table.from_pandas(frame, preserve_index=False)
    with pa.OSFile(str(path), "wb") as sink, pa.ipc.new_file(sink, table.schema) as writer:
        writer.write_table(table)
    return path


def test_tables_of_a_point_become_metrics_named_by_their_rows(tmp_path):
    spec = savas(tables=["estimators"], plot={"table": "estimators", "rows": "estimator"})
    frame = pd.DataFrame({"point": [0, 1]})
    results = [{"table_files": {"estimators": _arrow(tmp_path / f"{i}.arrow", pd.DataFrame(
        {"estimator": ["a", "b"], "label": ["A", "B"], "mse": [1.0 + i, 2.0], "mse_se": [0.1, 0.2]}))}} for i in (0, 1)]
    out = so.table_metrics(spec, frame, results)
    assert out["metric:a.mse"].tolist() == [1.0, 2.0] and out["metric:b.mse_se"].tolist() == [0.2, 0.2]
    assert "metric:a.label" not in out                                  # text columns are not metrics
    assert np.allclose(so.standard_errors(out, "metric:a.mse"), [0.1, 0.1])
    results[1] = {"table_files": {"estimators": _arrow(tmp_path / "dup.arrow", pd.DataFrame(
        {"estimator": ["a", "a"], "mse": [1.0, 2.0]}))}}
    with pytest.raises(ScenarioError, match="names several rows") as err:
        so.table_metrics(spec, frame, results)
    assert err.value.field == "plot.rows"


def test_several_sweep_files_run_in_one_command_on_one_local_cluster(tmp_path, monkeypatch, capsys):
    from dse.cli import main as cli_main

    started = []
    real = sw._start_local
    monkeypatch.setattr(sw, "_start_local", lambda workers: started.append(workers) or real(workers))
    files = []
    for name in ("one", "two"):
        f = tmp_path / f"{name}.toml"
        f.write_text(f'name = "{name}"\nbase = "{SAVAS}"\nquick = true\ntrials = 100\nclaims = []\ntables = []\n'
                     'metrics = []\n[set]\n"sweep.rounds" = [1]\n"sweep.sigma_c" = [1.0]\n"gains.rounds_max" = 1\n'
                     '[grid]\n"graph.n" = [3, 4]\n')
        files.append(str(f))
    assert cli_main(["sweep", *files, "--out", str(tmp_path / "out"), "--scheduler", "local", "--workers", "1"]) == 0
    out = capsys.readouterr().out
    assert "sweep one: 2 points" in out and "sweep two: 2 points" in out
    assert started == [1]                                     # one cluster for both sweeps


def test_a_cluster_gets_the_longest_points_first():
    from dse.sweeps.spec import load_sweep

    tasks = sw.build_tasks(load_sweep(ROOT / "dse" / "families" / "sweeps" / "kar_moura_network_size.toml"))
    order = [t.point.values["graph.n"] for t in sw.heaviest_first(tasks)]
    assert order == sorted(order, reverse=True) and sorted(order) == sorted(t.point.values["graph.n"] for t in tasks)
