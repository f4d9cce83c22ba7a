"""Running the arena: one task per suite scenario (`suite`), each a compare run of every built-in estimator
and the filter with the tables the leaderboard reads, on the sweep machinery (`dse.sweeps.run`: in process
or on a Dask cluster, finished scenarios stored and reused, a dead worker's tasks rescheduled). A scenario's
result depends only on its task and the code, so the leaderboard is the same bits on one worker, two, or a
cluster.
"""
from __future__ import annotations

import json
import shutil
import time
from pathlib import Path
from typing import Any, Callable

from dse.engine.cache import project_fingerprint
from dse.errors import ScenarioError

from . import suite

#: the tables each scenario's run keeps for the leaderboard
TABLES = ("estimators", "faults")


def filter_table(name: str, factory: str | None, params: dict[str, Any]) -> dict[str, Any]:
    """The filter's scenario table: its factory (when not installed under `name`) and its parameters."""
    return {**({"factory": factory} if factory else {}), **params}


def tasks_of(name: str, table: dict[str, Any], quick: bool, seed: int) -> list:
    """One sweep task per suite scenario, each validated first (a bad filter is one line, before anything runs)."""
    from dse import registry
    from dse.sweeps.run import Task
    from dse.sweeps.spec import Point

    fingerprint = project_fingerprint()
    out = []
    for i, entry in enumerate(suite.entries(quick)):
        scenario = suite.with_filter(entry.scenario, name, table)
        external = registry.from_dict(scenario).external_code()     # a bad filter: a ScenarioError naming the key
        out.append(Task(Point(i, {"scenario": entry.name}, 0, seed), scenario, quick, None, "", TABLES)
                   .keyed(fingerprint, external))
    return out


def run_arena(name: str, *, factory: str | None = None, params: dict[str, Any] | None = None, out_root: Path,
              quick: bool = False, seed: int = 0, scheduler: str = "auto", workers: int = 2, retries: int = 1,
              fresh: bool = False, log: Callable[[str], None] = print) -> dict[str, Any]:
    """Run the suite (module doc) and write OUT/arena/<name>/ as one set (`outputs.write_arena`)."""
    from dse.api import _replace_dir, _staging_dir
    from dse.engine.driver import check_output_dir
    from dse.sweeps.run import PointStore, choose_scheduler, execute

    from .outputs import write_arena

    if not name or not all(c.isalnum() or c in "_-" for c in name) or len(name) > 40:
        raise ScenarioError("NAME", f"a filter's name has 1 to 40 letters, digits, '-' or '_', got {name!r}")
    choose_scheduler(scheduler, 0, workers)
    check_output_dir(out_root)
    start = time.perf_counter()
    table = filter_table(name, factory, params or {})
    tasks = tasks_of(name, table, quick, seed)
    store = PointStore(out_root / ".cache" / "arena" / name / "points")
    results = {} if fresh else {t.key: r for t in tasks if (r := store.load(t.key)) is not None}
    pending = [t for t in tasks if t.key not in results]
    mode = choose_scheduler(scheduler, len(pending), workers)
    if results:
        log(f"arena {name}: {len(results)} of {len(tasks)} scenarios already done; running the other {len(pending)}")

    def keep(task, result: dict[str, Any]) -> None:
        results[task.key] = store.save(task.key, result)

    failures = execute(pending, scheduler=mode, workers=workers, retries=retries, on_result=keep, log=log)
    out_dir = out_root / "arena" / name
    staging = _staging_dir(out_dir)
    try:
        summary = write_arena(name, table, tasks, results, failures, staging, quick=quick, seed=seed)
        meta = {"filter": name, "table": table, "quick": quick, "seed": seed, "scheduler": mode, "workers": workers,
                "scenarios": [{"name": t.point.values["scenario"], "key": t.key,
                               "status": "failed" if t.key in failures else results[t.key].get("status", "ok")}
                              for t in tasks], "failures": failures, "wall_s": time.perf_counter() - start}
        (staging / "arena.json").write_text(json.dumps(meta, indent=1, default=str))
        _replace_dir(staging, out_dir)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return {**summary, "out_dir": out_dir, "scheduler": mode, "failed": len(failures), "scenarios": len(tasks),
            "reused": len(tasks) - len(pending), "wall_s": time.perf_counter() - start}
