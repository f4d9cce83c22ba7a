"""`dse sweep`: sweep files, points and seeds, and runs in process, on a local Dask cluster and
on a separately started scheduler with workers (loopback only)."""
from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import cloudpickle
import numpy as np
import pandas as pd
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from dse.simulate.cluster import QUIET_CONFIG
from dse.sweeps import run as sw
from dse.cli import main as cli_main
from dse.errors import ScenarioError
from dse.sweeps.spec import parse_sweep, point_seed, set_field

ROOT = Path(__file__).resolve().parents[1]
BASE = ROOT / "dse" / "families" / "tanwani" / "example.toml"
cloudpickle.register_pickle_by_value(sys.modules[__name__])  # the flaky task functions below run on workers


def tiny(**overrides) -> dict:
    """A sweep of 2 rates × 2 replicates of the tanwani example, about a second per point."""
    data = {"name": "tiny", "base": str(BASE), "seed": 3, "replicates": 2, "quick": True, "trials": 200,
            "set": {"simulation.horizon": 0.5, "simulation.quick_event_trials": 50,
                    "communication.sweep": [0.1, 100.0, 5]},
            "grid": {"communication.rates": [[1.0], [4.0]]}}
    data.update(overrides)
    return data


def spec_of(data: dict):
    return parse_sweep(data, base_dir=ROOT)


# -- sweep files ---------------------------------------------------------------------------------------------

@pytest.mark.parametrize("change, field", [
    ({"colour": 1}, "colour"),
    ({"name": "a b"}, "name"),
    ({"base": None, "scenario": None}, "base"),
    ({"grid": {"communication.rates": 3}}, "grid.communication.rates"),
    ({"grid": {"communication.rates": [[1.0], [1.0]]}}, "grid.communication.rates"),
    ({"grid": {"nosuch.table.x": [1, 2]}}, "nosuch.table.x"),
    ({"grid": {"sensors.7.V": [1, 2]}}, "sensors.7.V"),
    ({"set": {"simulation.horizon": 1.0}, "grid": {"simulation.horizon": [1.0, 2.0]}}, "simulation.horizon"),
    ({"random": {"samples": 3, "system.P0": {"normal": [0, 1]}}}, "random.system.P0.normal"),
    ({"random": {"samples": 3, "x.y": {"uniform": [2.0, 1.0]}}}, "random.x.y.uniform"),
    ({"random": {"samples": 0, "x.y": {"uniform": [0.0, 1.0]}}}, "random.samples"),
    ({"replicates": 0}, "replicates"),
    ({"grid": {"communication.rates": [[float(i)] for i in range(1, 400)], "simulation.output_step": list(range(300))},
      "replicates": 2}, "grid"),
    ({"plot": {"x": "graph.kind"}}, "plot.x"),
])
def test_bad_sweep_files_name_the_field(change, field):
    data = {k: v for k, v in {**tiny(), **change}.items() if v is not None}
    with pytest.raises(ScenarioError) as err:
        spec = spec_of(data)
        sw.build_tasks(spec)
    assert err.value.field == field


def test_a_point_that_its_family_rejects_is_named_before_anything_runs(tmp_path):
    spec = spec_of(tiny(grid={"communication.rates": [[1.0], [-2.0]]}))
    with pytest.raises(ScenarioError, match=r"at the point communication.rates = \[-2.0\]"):
        sw.run_sweep(spec, tmp_path, scheduler="inline")
    assert not (tmp_path / "sweep").exists() and not sw.points_dir(tmp_path, "tiny").exists()


def test_set_field_follows_tables_and_list_indices():
    data = {"a": {"b": [{"c": 1}, {"c": 2}]}, "v": 3}
    set_field(data, "a.b.1.c", 9)
    set_field(data, "a.new", [1])
    assert data == {"a": {"b": [{"c": 1}, {"c": 9}], "new": [1]}, "v": 3}
    for path in ("a.b.2.c", "v.x", "z.y", "a.b.x"):
        with pytest.raises(ScenarioError):
            set_field(data, path, 0)


def test_nested_tables_and_dotted_keys_mean_the_same_field():
    a = spec_of(tiny(grid={"communication.rates": [[1.0], [4.0]]}))
    b = spec_of(tiny(grid={"communication": {"rates": [[1.0], [4.0]]}}))
    assert [p.values for p in a.points()] == [p.values for p in b.points()]
    assert [p.seed for p in a.points()] == [p.seed for p in b.points()]


def test_points_are_the_grid_product_times_samples_times_replicates():
    spec = spec_of(tiny(grid={"communication.rates": [[1.0], [2.0], [4.0]], "graph.kind": ["line", "complete"]},
                        random={"samples": 4, "system.P0.0.0": {"log_uniform": [0.5, 5.0]}}, replicates=3))
    points = spec.points()
    assert len(points) == 3 * 2 * 4 * 3
    assert [p.index for p in points] == list(range(len(points)))
    assert points[0].values["graph.kind"] == "line" and points[12].values["graph.kind"] == "complete"
    assert len({p.seed for p in points}) == len(points)
    draws = [p.values["system.P0.0.0"] for p in points]
    assert all(0.5 <= d <= 5.0 for d in draws)
    assert len(set(draws)) == 4  # the same 4 random samples are crossed with every grid cell
    assert spec_of(tiny(grid=spec.grid, random=spec.source["random"], replicates=3)).points() == points


def test_a_points_seed_does_not_depend_on_the_rest_of_the_sweep():
    small = spec_of(tiny(grid={"communication.rates": [[1.0], [4.0]]})).points()
    large = spec_of(tiny(grid={"communication.rates": [[0.5], [1.0], [2.0], [4.0]]})).points()
    seeds = {(json.dumps(p.values), p.replicate): p.seed for p in large}
    assert all(seeds[(json.dumps(p.values), p.replicate)] == p.seed for p in small)
    assert point_seed(3, {"x": 1}, 0) != point_seed(4, {"x": 1}, 0) != point_seed(3, {"x": 1}, 1)


@settings(max_examples=40, deadline=None)
@given(low=st.integers(-50, 50), span=st.integers(0, 50), samples=st.integers(1, 30), seed=st.integers(0, 2**32))
def test_random_integer_samples_stay_in_their_inclusive_range(low, span, samples, seed):
    spec = spec_of(tiny(grid={}, seed=seed, replicates=1,
                        random={"samples": samples, "simulation.trials": {"integers": [low, low + span]}}))
    values = [p.values["simulation.trials"] for p in spec.points()]
    assert len(values) == samples and all(low <= v <= low + span for v in values)
    assert values == [p.values["simulation.trials"] for p in spec.points()]  # deterministic


# -- running -----------------------------------------------------------------------------------------------

def _read(out: Path, name: str = "tiny") -> tuple[bytes, bytes]:
    d = out / "sweep" / name
    return (d / "results.parquet").read_bytes(), (d / "claims.parquet").read_bytes()


@pytest.fixture(scope="module")
def inline_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("inline")
    summary = sw.run_sweep(spec_of(tiny()), out, scheduler="inline", log=lambda s: None)
    return out, summary


def test_inline_sweep_writes_table_figure_and_recording(inline_run):
    out, summary = inline_run
    assert summary["points"] == 4 and summary["ran"] == 4 and summary["failed"] == 0
    d = out / "sweep" / "tiny"
    frame = pd.read_parquet(d / "results.parquet")
    assert list(frame["point"]) == [0, 1, 2, 3] and list(frame["replicate"]) == [0, 1, 0, 1]
    assert set(frame["status"]) == {"ok"}
    metrics = [c for c in frame.columns if c.startswith("metric:")]
    assert "metric:mse_final_mean" in metrics and np.isfinite(frame[metrics].to_numpy(float)).all()
    # replicates differ (independent seeds), the exact bound does not
    assert frame["metric:mse_final_mean"][0] != frame["metric:mse_final_mean"][1]
    assert frame["metric:bound_final_mean"][0] == frame["metric:bound_final_mean"][1]
    claims = pd.read_parquet(d / "claims.parquet")
    verdict_cols = [c for c in frame.columns if c.endswith(":verdict")]
    assert len(claims) == 4 * len(verdict_cols)
    assert (frame[["pass", "fail", "erratum", "not-checkable", "error"]].sum(axis=1) == len(verdict_cols)).all()
    assert (d / "sweep.png").stat().st_size > 10_000
    from dse.outputs.record import blueprint_view_kinds, read_scalars

    assert blueprint_view_kinds(d / "sweep.rrd").count("TimeSeries") >= 2
    series = read_scalars(d / "sweep.rrd", "communication.rates")  # rates 1 and 4: integers, the values themselves
    assert any("mse_final_mean" in k for k in series)
    meta = json.loads((d / "sweep.json").read_text())
    assert len(meta["points"]) == 4 and all("wall_s" in p for p in meta["points"])


def test_rerun_reuses_every_point_and_gives_the_same_bytes(inline_run, tmp_path):
    out, _ = inline_run
    before = _read(out)
    summary = sw.run_sweep(spec_of(tiny()), out, scheduler="inline", log=lambda s: None)
    assert summary["reused"] == 4 and summary["ran"] == 0
    assert _read(out) == before


def test_interrupted_sweep_resumes_with_the_points_not_done(inline_run, tmp_path):
    calls = []

    def interrupt_after_two(payload):
        if len(calls) == 2:
            raise KeyboardInterrupt
        calls.append(payload["seed"])
        return sw.run_point(payload)

    spec = spec_of(tiny())
    tasks = sw.build_tasks(spec)
    store = sw.PointStore(sw.points_dir(tmp_path, "tiny"))
    with pytest.raises(KeyboardInterrupt):
        sw.execute(tasks, scheduler="inline", workers=1, retries=0, fn=interrupt_after_two,
                   on_result=lambda t, r: store.save(t.key, r))
    assert len(list(store.root.glob("*/result.json"))) == 2
    summary = sw.run_sweep(spec, tmp_path, scheduler="inline", log=lambda s: None)
    assert (summary["reused"], summary["ran"]) == (2, 2)
    assert _read(tmp_path) == _read(inline_run[0])


def fail_first_attempt(payload):
    """Raises on the first attempt of each task (a marker file remembers across processes)."""
    marker = Path(payload["flaky_dir"]) / f"{payload['seed']}.tried"
    if not marker.exists():
        marker.write_text("1")
        raise RuntimeError("transient failure")
    return {"seed": payload["seed"], "pid": os.getpid()}


def die_on_first_attempt(payload):
    """Kills its worker process on the first attempt of each task: the task is lost, not failed."""
    marker = Path(payload["flaky_dir"]) / f"{payload['seed']}.died"
    if not marker.exists():
        marker.write_text("1")
        os._exit(1)
    return {"seed": payload["seed"], "pid": os.getpid()}


def always_fail(payload):
    raise ValueError("broken point")


class FakeTask(sw.Task):
    """A task whose payload only names its seed and a directory for marker files."""

    def payload(self):
        return {"seed": self.point.seed, "flaky_dir": self.scenario["flaky_dir"]}


def _fake_tasks(n: int, flaky_dir: Path) -> list[sw.Task]:
    from dse.sweeps.spec import Point

    return [FakeTask(Point(i, {"i": i}, 0, 1000 + i), {"flaky_dir": str(flaky_dir)}, True, None, f"k{i}")
            for i in range(n)]


def test_inline_retries_a_failed_task_then_reports_it(tmp_path):
    got = {}
    failures = sw.execute(_fake_tasks(3, tmp_path), scheduler="inline", workers=1, retries=1, fn=fail_first_attempt,
                          on_result=lambda t, r: got.__setitem__(t.key, r))
    assert failures == {} and sorted(got) == ["k0", "k1", "k2"]
    failures = sw.execute(_fake_tasks(2, tmp_path), scheduler="inline", workers=1, retries=2, fn=always_fail,
                          on_result=lambda t, r: None)
    assert failures == {"k0": "ValueError: broken point", "k1": "ValueError: broken point"}


def test_local_cluster_matches_inline_and_survives_failures_and_lost_workers(inline_run, tmp_path):
    """The sweep and the two faulty task sets run on one local cluster, as `dse sweep` shares one between its sweeps
    (`LocalClusters`; a sweep that starts and closes its own cluster is tests/test_arena.py's): starting a cluster
    is most of the test's CPU."""
    out = tmp_path / "local"
    with sw.LocalClusters() as clusters:
        summary = sw.run_sweep(spec_of(tiny()), out, scheduler="local", workers=2, log=lambda s: None,
                               clusters=clusters)
        assert summary["scheduler"] == "local" and summary["ran"] == 4
        assert _read(out) == _read(inline_run[0])
        meta = json.loads((out / "sweep" / "tiny" / "sweep.json").read_text())
        assert all(p["pid"] != os.getpid() for p in meta["points"])  # the points ran in the cluster's workers
        # a task that raises once is retried; a worker that dies is replaced and its task rescheduled
        got = {}
        failures = sw.execute(_fake_tasks(4, tmp_path), scheduler="local", workers=2, retries=1, fn=fail_first_attempt,
                              on_result=lambda t, r: got.__setitem__(t.key, r), log=lambda s: None, clusters=clusters)
        assert failures == {} and len(got) == 4
        got.clear()
        failures = sw.execute(_fake_tasks(2, tmp_path), scheduler="local", workers=2, retries=1,
                              fn=die_on_first_attempt, on_result=lambda t, r: got.__setitem__(t.key, r),
                              log=lambda s: None, clusters=clusters)
        assert failures == {} and len(got) == 2


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture
def loopback_cluster():
    """A Dask scheduler and two single-thread workers started as separate processes, with the settings a local
    cluster has (`cluster.QUIET_CONFIG`, as environment variables) and no dashboard: the dashboard's web server and
    the workers' profiler cost CPU that no test here reads."""
    port, bin_dir = _free_port(), Path(sys.executable).parent
    quiet = {"DASK_" + key.upper().replace(".", "__").replace("-", "_"): str(value)
             for key, value in QUIET_CONFIG.items()}
    env = {**os.environ, **sw.WORKER_ENV, **quiet}
    procs = [subprocess.Popen([str(bin_dir / "dask"), "scheduler", "--host", "127.0.0.1", "--port", str(port),
                               "--no-dashboard"], env=env,
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)]
    address = f"tcp://127.0.0.1:{port}"
    deadline = time.time() + 30
    while time.time() < deadline:
        with socket.socket() as s:
            if s.connect_ex(("127.0.0.1", port)) == 0:
                break
        time.sleep(0.2)
    procs.append(subprocess.Popen([str(bin_dir / "dask"), "worker", address, "--nworkers", "2", "--nthreads", "1",
                                   "--host", "127.0.0.1", "--no-dashboard"], env=env, cwd=str(ROOT),
                                  stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True))
    from dask.distributed import Client

    with Client(address, timeout="30s") as client:
        client.wait_for_workers(2, timeout=60)
    try:
        yield address
    finally:
        for p in procs[::-1]:
            os.killpg(p.pid, signal.SIGTERM)
        for p in procs:
            try:
                p.wait(timeout=20)
            except subprocess.TimeoutExpired:
                os.killpg(p.pid, signal.SIGKILL)
                p.wait()


def test_remote_scheduler_gives_the_same_parquet_as_in_process(inline_run, loopback_cluster, tmp_path):
    summary = sw.run_sweep(spec_of(tiny()), tmp_path, scheduler=loopback_cluster, log=lambda s: None)
    assert summary["ran"] == 4 and summary["failed"] == 0
    meta = json.loads((tmp_path / "sweep" / "tiny" / "sweep.json").read_text())
    assert all(p["pid"] != os.getpid() for p in meta["points"])  # the points ran in the separate workers
    assert _read(tmp_path) == _read(inline_run[0])


# -- command line ------------------------------------------------------------------------------------------

def test_cli_sweep_errors_exit_2_with_one_line(tmp_path, capsys):
    bad = tmp_path / "bad.toml"
    bad.write_text('name = "x"\nbase = "missing.toml"\n')
    assert cli_main(["sweep", str(bad), "--out", str(tmp_path / "o")]) == 2
    assert "missing.toml" in capsys.readouterr().err
    good = tmp_path / "good.toml"
    good.write_text(f'name = "x"\nbase = "{BASE}"\n[grid]\n"communication.rates" = [[1.0]]\n')
    assert cli_main(["sweep", str(good), "--out", str(tmp_path / "o"), "--scheduler", "bogus"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--scheduler" in err[0]
    assert not (tmp_path / "o" / "sweep").exists()


@pytest.mark.parametrize("path", sorted((ROOT / "dse" / "families" / "sweeps").glob("*.toml")), ids=lambda p: p.stem)
def test_shipped_sweeps_are_valid_at_every_point(path):
    from dse.sweeps.spec import load_sweep

    spec = load_sweep(path)
    tasks = sw.build_tasks(spec)  # every point's scenario is validated by its family
    assert len(tasks) == len(spec.points()) and len({t.key for t in tasks}) == len(tasks)
    assert len(tasks) >= 10 or (spec.plot_cells and len(tasks) >= 3)   # cells: several rows of the figure per point
