"""`dse sweep`: run every point of a sweep as one task, in process or on a Dask cluster.

Each point is a full `dse run` of its scenario without figures or recordings: compute,
then every claim's verdict, the verdict counts and the family's summary metrics. A point's
result depends only on its task (scenario, seed, quick, trials) and the code, never on
where it ran, so the gathered table is the same with one worker, two, or a remote cluster.

Finished points are stored one directory each under ``OUT/.cache/sweeps/<name>/points/``
(keyed by a hash of the task and the code, checksummed), so a sweep that was interrupted, or
lost tasks, resumes where it stopped. A task that raises is retried (Dask's `retries`); a worker that dies is
replaced and its tasks rescheduled by the Dask scheduler.
"""
from __future__ import annotations

import collections
import contextlib
import dataclasses
import fnmatch
import hashlib
import json
import os
import shutil
import socket
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Iterator

from dse.engine.atomic import atomic_write_text
from dse.engine.cache import MemoryCache, canonical_json, project_fingerprint
from dse.errors import NumericalError, ScenarioError
from dse.engine.progress import progress_enabled
from dse.simulate.cluster import SCHEDULERS, WORKER_ENV, check_scheduler, connect, start_local, wait_for_a_worker  # noqa: F401
from dse.sweeps.spec import Point, SweepSpec

#: the fields of a claim's row kept per point (all of them but none of the report's layout)
POINT_CLAIM_FIELDS = ("id", "source", "statement", "kind", "verdict", "measured", "reference", "tolerance", "margin",
                      "confidence", "trials", "printed", "corrected", "detail")


@dataclass(frozen=True)
class Task:
    """What one point computes; its key names its result file and its Dask task."""

    point: Point
    scenario: dict[str, Any]
    quick: bool
    trials: int | None
    key: str
    tables: tuple[str, ...] | None = None
    claims: tuple[str, ...] | None = None
    metrics: tuple[str, ...] | None = None

    def payload(self) -> dict[str, Any]:
        return {"scenario": self.scenario, "seed": self.point.seed, "quick": self.quick, "trials": self.trials,
                "tables": self.tables, "claims": self.claims, "metrics": self.metrics}

    def keyed(self, fingerprint: str, external: str = "") -> "Task":
        """The task with its key: a hash of its payload, the project's code (`fingerprint`) and the code outside
        the project its scenario runs (`external`, a plug-in filter's)."""
        key = hashlib.sha256((canonical_json(self.payload()) + fingerprint + external).encode()).hexdigest()[:24]
        return dataclasses.replace(self, key=key)


def _registry():
    from dse import registry

    return registry


def build_tasks(spec: SweepSpec, log: Callable[[str], None] | None = None) -> list[Task]:
    """Every point's task, each scenario validated by its family before anything runs (with a
    progress line every few seconds for large sweeps); a `claims` pattern that matches no claim of
    the first point is refused."""
    reg = _registry()
    fingerprint = project_fingerprint()
    tasks = []
    points = spec.points()
    started = last = time.perf_counter()
    for point in points:
        now = time.perf_counter()
        if log is not None and now - last > 3.0:
            done = len(tasks)
            log(f"sweep {spec.name}: validated {done:,} of {len(points):,} points "
                f"(about {(now - started) / done * (len(points) - done):.0f} s left)")
            last = now
        scenario = spec.scenario(point)
        try:
            repro = reg.from_dict(scenario)
            external = repro.external_code()
        except ScenarioError as exc:
            where = ", ".join(f"{k} = {json.dumps(v)}" for k, v in point.values.items()) or "the base scenario"
            raise ScenarioError(exc.field, f"{exc.reason} (at the point {where})") from None
        if not tasks and spec.claims:
            _check_claim_patterns(repro, spec.claims)
        tasks.append(Task(point, scenario, spec.quick, spec.trials, "", spec.tables, spec.claims,
                          spec.metrics).keyed(fingerprint, external))
    return tasks


def _claim_name(repro, claim_id: str) -> str:
    """A claim's id without the run's name (what a sweep's `claims` patterns match)."""
    return claim_id.removeprefix(f"{repro.paper_id}.")


def _check_claim_patterns(repro, patterns: tuple[str, ...]) -> None:
    names = [_claim_name(repro, c.id) for c in repro.claims()]
    unmatched = [p for p in patterns if not fnmatch.filter(names, p)]
    if unmatched:
        raise ScenarioError("claims", f"{', '.join(unmatched)}: no claim of the points matches (their claims are "
                                      f"{', '.join(names)})")


#: design work shared by the points a process runs (a stage's key says what it depends on, so points
#: that share a design, say every m of one (σ_c, N), compute it once): stage results kept up to this size
SHARED_STAGES_MIB = 256


class SharedStages(MemoryCache):
    """Stage results kept in this process across sweep points, least recently used dropped first
    beyond `limit_mib`. Entries are copied in and out, so a point that modifies an array it was given
    cannot change what the next point reads."""

    def __init__(self, limit_mib: float = SHARED_STAGES_MIB) -> None:
        super().__init__()
        self._entries: collections.OrderedDict[str, dict[str, Any]] = collections.OrderedDict()
        self.limit = limit_mib * 2**20
        self.size = 0
        self.hits = 0

    def load(self, stage: str, params: dict[str, Any]) -> dict[str, Any] | None:
        key = self.key(stage, params)
        entry = self._entries.get(key)
        if entry is None:
            return None
        self._entries.move_to_end(key)
        self.hits += 1
        return _copied(entry)

    def save(self, stage: str, params: dict[str, Any], arrays: dict[str, Any]) -> None:
        key = self.key(stage, params)
        size = sum(getattr(a, "nbytes", 0) for a in arrays.values())
        if key in self._entries or size > self.limit:
            return
        self._entries[key] = _copied(arrays)
        self.size += size
        while self.size > self.limit:
            _, dropped = self._entries.popitem(last=False)
            self.size -= sum(getattr(a, "nbytes", 0) for a in dropped.values())


def _copied(arrays: dict[str, Any]) -> dict[str, Any]:
    return {k: v.copy() if hasattr(v, "copy") else v for k, v in arrays.items()}


_SHARED: SharedStages | None = None


def shared_stages() -> SharedStages:
    """This process's `SharedStages` (one per Dask worker process, one for an in-process sweep)."""
    global _SHARED
    if _SHARED is None:
        _SHARED = SharedStages()
    return _SHARED


def run_point(payload: dict[str, Any]) -> dict[str, Any]:
    """One point: compute (design shared with the other points of this process), check the claims the
    sweep asks for, build the tables and metrics it asks for.

    A numerical failure (a NaN or inf where the family needs a finite number) is a result of
    the point, not an error of the task: it is reported in the row and not retried.
    """
    from dse.contract.options import RunOptions

    start = time.perf_counter()
    repro = _registry().from_dict(payload["scenario"])
    opts = RunOptions(seed=payload["seed"], trials=payload["trials"], quick=payload["quick"], workers=1)
    where = {"host": socket.gethostname(), "pid": os.getpid()}
    try:
        computed = _compute(repro, opts)
    except NumericalError as exc:
        return {"status": "numerical-error", "error": str(exc), "claims": [], "metrics": {}, "tables": {},
                "wall_s": time.perf_counter() - start, **where}
    ev = _evaluate(repro, computed, payload)
    tables = _point_tables(repro, computed, ev, payload.get("tables"), payload.get("metrics"))
    metrics = network_metrics(tables["metrics"]) if "metrics" in tables else {}
    if payload.get("metrics") is not None:
        metrics = {k: v for k, v in metrics.items() if k in payload["metrics"]}
    kept = [name for name in tables if payload.get("tables") is None or name in payload["tables"]]
    return {"status": "ok", "error": "", "metrics": {k: float(v) for k, v in metrics.items()},
            "claims": [{k: r.get(k) for k in POINT_CLAIM_FIELDS} for r in ev.claims],
            "tables": {name: tables[name] for name in kept}, "table_docs": {name: tables.specs[name] for name in kept},
            "wall_s": time.perf_counter() - start, **where}


def _compute(repro, opts):
    """The point's design and simulation, refused as `dse run` refuses them (options, memory, time)."""
    from dse.api import refuse_beyond_limits
    from dse.contract.context import StageContext
    from dse.contract.cost import refuse_options

    refuse_options(repro, opts)
    refuse_beyond_limits(repro, opts)
    return repro.compute(opts, StageContext(shared_stages()))


def _evaluate(repro, computed, payload: dict[str, Any]):
    """The claims the sweep asks for (all without `claims`), and the hypotheses they rest on (all of
    them when the sweep keeps the `hypotheses` table)."""
    from dse.verify.rules import evaluate

    claims, hypotheses = repro.claims(), repro.hypotheses()
    patterns = payload.get("claims")
    if patterns is not None:
        claims = [c for c in claims if any(fnmatch.fnmatchcase(_claim_name(repro, c.id), p) for p in patterns)]
        tables = payload.get("tables")
        if tables is not None and "hypotheses" not in tables:
            needed = {h for c in claims for h in c.hypotheses}
            hypotheses = [h for h in hypotheses if h.id in needed]
    return evaluate(claims, hypotheses, computed.results, paper_run=repro.is_paper, design=computed.design)


def _point_tables(repro, computed, ev, wanted, metrics):
    """The point's `Tables`: the evaluation's when asked for, and the family's when a family table or a
    metric is asked for (`wanted`/`metrics` None: every one)."""
    from dse.api import evaluation_tables
    from dse.outputs.tables import Tables

    tables = evaluation_tables(ev) if wanted is None or {"claims", "hypotheses"} & set(wanted) else Tables()
    if wanted is None or set(wanted) - {"claims", "hypotheses"} or metrics is None or len(metrics) > 0:
        for table_spec, frame in repro.tables(computed.results):
            tables.add(table_spec, frame)
    return tables


def network_metrics(frame) -> dict[str, float]:
    """The scalar summary of a point for the sweep's results table and plot: each metric of the
    family's tidy `metrics` table that has exactly one network-wide row (node empty). Metrics per
    node or per cell stay in the stacked `tables/metrics.parquet`."""
    network = frame[frame["node"].isna()] if "node" in frame else frame
    counts = network["metric"].value_counts()
    single = network[network["metric"].isin(counts[counts == 1].index)]
    return {str(m): float(v) for m, v in zip(single["metric"], single["value"])}


class PointStore:
    """One directory per finished point: `result.json` (the point's verdicts and metrics, with a
    checksum of itself and of every table file) and `tables/<name>.arrow` (Arrow IPC files: the
    store is internal, and they are written and read an order of magnitude faster than Parquet). A
    damaged, edited or incomplete point is detected by its checksums and recomputed."""

    def __init__(self, root: Path):
        self.root = root

    def _dir(self, key: str) -> Path:
        return self.root / key

    def load(self, key: str) -> dict[str, Any] | None:
        d = self._dir(key)
        try:
            doc = json.loads((d / "result.json").read_text())
            body = doc["result"]
            if hashlib.sha256(canonical_json(body).encode()).hexdigest() != doc["sha256"]:
                raise ValueError("checksum mismatch")
            tables = {}
            for name, digest in doc["tables"].items():
                raw = (d / "tables" / f"{name}.arrow").read_bytes()
                if hashlib.sha256(raw).hexdigest() != digest:
                    raise ValueError(f"table {name}: checksum mismatch")
                tables[name] = raw
            return {**body, "table_files": {n: d / "tables" / f"{n}.arrow" for n in tables}}
        except FileNotFoundError:
            return None
        except Exception as exc:  # damaged in any way: recompute the point
            if d.exists():
                print(f"dse: stored sweep point {key} is damaged ({type(exc).__name__}: {exc}); recomputing",
                      file=sys.stderr)
                shutil.rmtree(d, ignore_errors=True)
            return None

    def save(self, key: str, result: dict[str, Any]) -> dict[str, Any]:
        """Store a point (tables as Arrow IPC files); returns the result as `load` would give it."""
        from dse.engine.atomic import atomic_path
        from dse.outputs.tables import write_arrow_file

        d = self._dir(key)
        staging = Path(tempfile.mkdtemp(prefix=f".{key}.staging-", dir=_mkdir(self.root)))
        try:
            (staging / "tables").mkdir()
            digests = {}
            for name, frame in result.get("tables", {}).items():
                path = staging / "tables" / f"{name}.arrow"
                write_arrow_file(result["table_docs"][name], frame, path)
                digests[name] = hashlib.sha256(path.read_bytes()).hexdigest()
            body = json.loads(json.dumps({k: v for k, v in result.items() if k not in ("tables", "table_docs")},
                                         default=str))
            with atomic_path(staging / "result.json") as tmp:
                tmp.write_text(json.dumps({"sha256": hashlib.sha256(canonical_json(body).encode()).hexdigest(),
                                           "tables": digests, "result": body}))
            if d.exists():
                shutil.rmtree(d)
            os.replace(staging, d)
        finally:
            shutil.rmtree(staging, ignore_errors=True)
        return {**body, "table_files": {n: d / "tables" / f"{n}.arrow" for n in digests}}


def _mkdir(path: Path) -> Path:
    path.mkdir(parents=True, exist_ok=True)
    return path


def choose_scheduler(scheduler: str, pending: int, workers: int) -> str:
    """`auto`: in process for tiny sweeps (at most one pending point, or one worker), else a
    local Dask cluster; `inline`, `local` or a scheduler address (``tcp://HOST:PORT``) as given."""
    if check_scheduler(scheduler) != "auto":
        return scheduler
    return "inline" if pending <= 1 or workers <= 1 else "local"


def execute(tasks: list[Task], *, scheduler: str, workers: int, retries: int,
            on_result: Callable[[Task, dict[str, Any]], None], log: Callable[[str], None] = print,
            fn: Callable[[dict[str, Any]], dict[str, Any]] = run_point, worker_timeout: float = 60.0,
            clusters: LocalClusters | None = None) -> dict[str, str]:
    """Run `fn` (default `run_point`) on every task's payload; hand each result to `on_result`
    as it arrives. Returns {key: error} of the tasks that still failed after `retries` retries.
    `clusters`: where a local cluster is taken from (shared by several sweeps), else one is started."""
    if not tasks:
        return {}
    if scheduler == "inline":
        return _execute_inline(tasks, retries, on_result, fn)
    return _execute_dask(tasks, scheduler, workers, retries, on_result, log, fn, worker_timeout, clusters)


def _bar(total: int):
    from tqdm import tqdm

    return tqdm(total=total, desc="sweep points", unit="pt", disable=not progress_enabled(),
                dynamic_ncols=True, file=sys.stderr)


@contextlib.contextmanager
def _inner_bars_off() -> Iterator[None]:
    """The points' own stage bars stay quiet while the sweep's bar runs in this process."""
    saved = os.environ.get("DSE_PROGRESS")
    os.environ["DSE_PROGRESS"] = "0"
    try:
        yield
    finally:
        if saved is None:
            os.environ.pop("DSE_PROGRESS", None)
        else:
            os.environ["DSE_PROGRESS"] = saved


def _execute_inline(tasks, retries, on_result, fn) -> dict[str, str]:
    failures = {}
    with _bar(len(tasks)) as bar, _inner_bars_off():
        for task in tasks:
            for attempt in range(retries + 1):
                try:
                    on_result(task, fn(task.payload()))
                    break
                except (KeyboardInterrupt, ScenarioError):
                    raise
                except Exception as exc:  # noqa: BLE001 - retried, then reported per point
                    if attempt == retries:
                        failures[task.key] = f"{type(exc).__name__}: {exc}"
            bar.update()
    return failures


class LocalClusters:
    """One local Dask cluster shared by the sweeps run inside this context (`dse sweep A.toml B.toml`):
    started when a sweep first needs it, its workers' imports and shared stages kept for the next sweep,
    closed on leaving the context."""

    def __init__(self) -> None:
        self._open: dict[int, tuple[Any, Any]] = {}

    def client(self, workers: int):
        if workers not in self._open:
            self._open[workers] = _start_local(workers)
        return self._open[workers][1]

    def __enter__(self) -> "LocalClusters":
        return self

    def __exit__(self, *exc) -> None:
        for cluster, client in self._open.values():
            client.close()
            cluster.close()
        self._open.clear()


def _start_local(workers: int):
    return start_local(workers)


def _connect(scheduler: str, workers: int, clusters: LocalClusters | None):
    """(client, whether this sweep closes it, where): a shared local cluster, a new one, or a scheduler's address."""
    if scheduler == "local" and clusters is not None:
        return clusters.client(workers), None, "local cluster"
    if scheduler == "local":
        return _start_local(workers)[::-1] + ("local cluster",)
    return connect(scheduler), None, scheduler


def _execute_dask(tasks, scheduler, workers, retries, on_result, log, fn, worker_timeout,
                  clusters: LocalClusters | None = None) -> dict[str, str]:
    from dask.distributed import as_completed

    client, cluster, where = _connect(scheduler, workers, clusters)
    shared = scheduler == "local" and clusters is not None
    failures = {}
    try:
        wait_for_a_worker(client, scheduler, where, log, worker_timeout)
        owner, futures = {}, []
        for task in heaviest_first(tasks):      # submitted first, run first: the long points do not come last
            futures.append(client.submit(fn, task.payload(), key=f"dse-point-{task.key}", retries=retries))
            owner[futures[-1].key] = task
        with _bar(len(tasks)) as bar:
            for fut in as_completed(futures):
                task = owner[fut.key]
                if fut.status == "finished":
                    on_result(task, fut.result())
                else:
                    exc = fut.exception()
                    failures[task.key] = f"{type(exc).__name__}: {exc}"
                fut.release()
                bar.update()
    finally:
        if not shared:
            client.close()
        if cluster is not None:
            cluster.close()
    return failures


def heaviest_first(tasks: list[Task]) -> list[Task]:
    """The tasks by their family's estimated time (`Family.cost`), longest first, else in point order: on a
    cluster the long points start first and the short ones fill in around them (the results do not
    depend on the order). A task without an estimate counts as 0 s."""
    from dse.contract.options import RunOptions

    def estimate(task: Task) -> float:
        try:
            opts = RunOptions(seed=task.point.seed, trials=task.trials, quick=task.quick, workers=1)
            return -_registry().from_dict(task.scenario).cost(opts).seconds
        except Exception:  # noqa: BLE001 - a task that is not a family's point (a test's) keeps its place
            return 0.0

    return sorted(tasks, key=lambda t: (estimate(t), t.point.index))


def _point_meta(task: Task, result: dict[str, Any] | None, failure: str | None) -> dict[str, Any]:
    """A point in sweep.json: what it varied, its seed, and where and how long it ran (or why not)."""
    meta = {"point": task.point.index, "key": task.key, "values": task.point.values,
            "replicate": task.point.replicate, "seed": task.point.seed}
    if result is None:
        return meta | {"failed": failure or "not run"}
    return meta | {k: result[k] for k in ("wall_s", "host", "pid")}


def points_dir(out_root: Path, name: str) -> Path:
    """Where a sweep's finished points are kept between runs (a cache: safe to delete)."""
    return out_root / ".cache" / "sweeps" / name / "points"


def run_sweep(spec: SweepSpec, out_root: Path, *, scheduler: str = "auto", workers: int = 2, retries: int = 2,
              fresh: bool = False, log: Callable[[str], None] = print, worker_timeout: float = 60.0,
              clusters: LocalClusters | None = None) -> dict[str, Any]:
    """Run the points not yet done, then write results.parquet, claims.parquet, tables/, the figure,
    the recording, summary.md and sweep.json as one set: built beside OUT/sweep/<name>/ and renamed
    into place, so the directory never mixes two runs and an invalid sweep leaves nothing. `clusters`:
    the local Dask cluster is taken from there (several sweeps in one command share one)."""
    from dse.api import _replace_dir, _staging_dir
    from dse.engine.driver import check_output_dir
    from dse.engine.memo import manifest

    choose_scheduler(scheduler, 0, workers)  # a bad --scheduler fails before anything runs
    check_output_dir(out_root)
    out_dir = out_root / "sweep" / spec.name
    start = time.perf_counter()
    tasks = build_tasks(spec, log=log)
    store = PointStore(points_dir(out_root, spec.name))
    results = {} if fresh else {t.key: r for t in tasks if (r := store.load(t.key)) is not None}
    pending = [t for t in tasks if t.key not in results]
    mode = choose_scheduler(scheduler, len(pending), workers)
    if results:
        log(f"sweep {spec.name}: {len(results)} of {len(tasks)} points already done; running the other {len(pending)}")

    def keep(task: Task, result: dict[str, Any]) -> None:
        results[task.key] = store.save(task.key, result)

    failures = execute(pending, scheduler=mode, workers=workers, retries=retries, on_result=keep, log=log,
                       worker_timeout=worker_timeout, clusters=clusters)
    done = [t for t in tasks if t.key in results]
    staging = _staging_dir(out_dir)
    try:
        wall = write_sweep_outputs(spec, staging, done, results, failures, log)
        meta = {"name": spec.name, "family": spec.family, "sweep": spec.source, "base_scenario": spec.base,
                "scheduler": mode, "workers": workers,
                "points": [_point_meta(t, results.get(t.key), failures.get(t.key)) for t in tasks],
                "failures": failures, "wall_s": time.perf_counter() - start,
                "checksums": manifest(staging, everything=True)}   # every file but sweep.json: what verify compares
        atomic_write_text(staging / "sweep.json", json.dumps(meta, indent=1, default=str))
        _replace_dir(staging, out_dir)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return {"name": spec.name, "points": len(tasks), "ran": len(pending) - len(failures),
            "reused": len(tasks) - len(pending), "failed": len(failures), "numerical_errors": wall["numerical_errors"],
            "claims_failed": wall["claims_failed"],
            "wall_s": meta["wall_s"], "out_dir": out_dir, "scheduler": mode}


def write_sweep_outputs(spec: SweepSpec, out_dir: Path, done: list[Task], results: dict[str, dict[str, Any]],
                        failures: dict[str, str], log: Callable[[str], None]) -> dict[str, Any]:
    """The sweep's tables, summary, figure and recording, written into `out_dir`."""
    from dse.sweeps import outputs as so

    frame = so.results_frame(spec, [t.point for t in done], [results[t.key] for t in done])
    claims = so.claims_frame([t.point for t in done], [results[t.key] for t in done])
    so.write_parquet(frame, out_dir / "results.parquet")
    so.write_parquet(claims, out_dir / "claims.parquet")
    so.write_point_tables(spec, [t.point for t in done], [results[t.key] for t in done], out_dir / "tables")
    summary_md = so.summary_markdown(spec, frame, claims, failures)
    point_results = [results[t.key] for t in done]
    drawn = so.cell_frame(spec, so.table_metrics(spec, frame, point_results), point_results)
    if len(drawn):
        plan = so.plot_plan(spec, drawn)
        if plan.unknown_metrics:
            _unknown_metrics(spec, drawn, plan, log)
        so.write_figure(spec, drawn, plan, out_dir / "sweep.png")
        so.write_recording(spec, drawn, plan, summary_md, out_dir / "sweep.rrd")
    atomic_write_text(out_dir / "summary.md", summary_md + "\n")
    return {"numerical_errors": int((frame["status"] != "ok").sum()) if len(frame) else 0,
            "claims_failed": int(claims["verdict"].isin(["fail", "error"]).sum()) if len(claims) else 0}


def sweep_file_diffs(out_dir: Path, meta: dict[str, Any]) -> list[str]:
    """Every file of a sweep directory that differs from the SHA-256 sweep.json recorded (none
    when sweep.json has no checksums: written by an older dse)."""
    from dse.engine.reverify import check_files

    return check_files(out_dir, meta.get("checksums"), skip="sweep.json")[1]


def _unknown_metrics(spec: SweepSpec, frame, plan, log: Callable[[str], None]) -> None:
    """`plot.metrics` names metrics the points do not have: refused in one line when none of them is
    left (a figure of the pass fraction alone is not what was asked for), else said and left out."""
    have = [c.removeprefix("metric:") for c in frame.columns if c.startswith("metric:")]
    missing = ", ".join(plan.unknown_metrics)
    points_have = f"the points' metrics are {', '.join(have)}" if have else "the points have no network-wide metric"
    kept = [m.removeprefix("metric:") for m in plan.metrics if m.startswith("metric:")]
    if not kept:
        raise ScenarioError("plot.metrics", f"{missing}: not a metric of these points ({points_have}); nothing "
                                            "drawn or written: fix plot.metrics and run the sweep again")
    log(f"sweep {spec.name}: plot.metrics: {missing}: not a metric of these points ({points_have}); "
        f"plotting {', '.join(kept)} only")


def verify_sweep(out_dir: Path) -> tuple[list[str], int]:
    """Check a sweep's files against the checksums in sweep.json, re-assemble its results table from
    its stored points (checksums verified) and list every difference from the written files and
    tables (numbers within the relative tolerance of `dse verify`). Returns (differences, points found)."""
    import pandas as pd

    from dse.sweeps import outputs as so
    from dse.errors import OutputError
    from dse.engine.driver import same_number

    try:
        meta = json.loads((out_dir / "sweep.json").read_text())
        from dse.sweeps.spec import parse_sweep

        source = {k: v for k, v in meta["sweep"].items() if k != "base"} | {"scenario": meta["base_scenario"]}
        spec = parse_sweep(source, base_dir=out_dir)
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise OutputError(f"{out_dir}: sweep.json is damaged ({type(exc).__name__}: {exc}); run the sweep again") from None
    store = PointStore(points_dir(out_dir.parent.parent, meta["name"]))
    points = spec.points()
    diffs, done, results = sweep_file_diffs(out_dir, meta), [], []
    for p in meta["points"]:
        if "failed" in p:
            continue
        res = store.load(p["key"])
        if res is None:
            diffs.append(f"point {p['point']}: its stored result is missing or damaged")
            continue
        done.append(points[p["point"]])
        results.append(res)
    frame = so.results_frame(spec, done, results)
    written = pd.read_parquet(out_dir / "results.parquet")
    if list(frame.columns) != list(written.columns) or len(frame) != len(written):
        diffs.append("results.parquet: columns or rows differ from the stored points")
    else:
        for col in frame.columns:
            for i, (a, b) in enumerate(zip(written[col].tolist(), frame[col].tolist())):
                if not (same_number(a, b) or (a != a and b != b)):
                    diffs.append(f"results.parquet row {i} column {col}: {a!r} written, {b!r} from the stored point")
    return diffs, len(done)
