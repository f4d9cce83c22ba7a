"""`dse verify` on a run directory: are the files the ones the run wrote, and are its numbers
what the code computes from the cached stage results?

Three checks, each said in the output with what it covered:

- files: every file of the run directory against the SHA-256 recorded in run.json when it was
  written (an edited, missing or added file is named, one line each);
- tables: every table recomputed from the stage cache and compared with tables/*.parquet cell
  by cell, exactly (the same stage bits through the same code give the same bits: a table's
  numbers are computed in the main process, one BLAS thread, from the arrays the cache holds; a
  difference means an edited file or changed code);
- claims: every claim re-evaluated from the stage cache and compared with report.json: its
  verdict, and its measured, reference and margin numbers within `dse.engine.driver.REVERIFY_RTOL`.

Nothing is simulated: a stage missing from the cache, or damaged there, is named with the exact
command that recomputes it.
"""
from __future__ import annotations

import dataclasses
import json
import shlex
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from dse.engine.driver import cache_for, evaluate_claims, same_number
from dse.engine.memo import manifest
from dse.errors import CacheMiss

#: at most this many differing cells are listed per table (then how many more)
CELLS_LISTED = 5


@dataclass
class Verification:
    """What `verify_run` checked and every difference it found."""

    files: int = 0                      # files compared with run.json's checksums (0: run.json has none)
    file_diffs: list[str] = field(default_factory=list)
    tables: int = 0                     # tables recomputed and compared
    cells: int = 0                      # cells compared
    table_diffs: list[str] = field(default_factory=list)
    claims: list[dict] = field(default_factory=list)   # the re-checked claim rows
    claim_diffs: list[str] = field(default_factory=list)

    @property
    def diffs(self) -> list[str]:
        return self.file_diffs + self.table_diffs + self.claim_diffs


def check_files(out_dir: Path, checksums: dict[str, str] | None, skip: str = "run.json") -> tuple[int, list[str]]:
    """Compare every file of `out_dir` (but `skip`, the file holding the checksums) with `checksums`."""
    if not isinstance(checksums, dict):
        return 0, []
    now = {rel: digest for rel, digest in manifest(out_dir, everything=True).items() if rel != skip}
    diffs = [f"{rel}: edited since it was written (its SHA-256 differs from {skip})"
             for rel, digest in sorted(checksums.items()) if rel in now and now[rel] != digest]
    diffs += [f"{rel}: missing (it was written)" for rel in sorted(set(checksums) - set(now))]
    diffs += [f"{rel}: not written by the run (absent from {skip})" for rel in sorted(set(now) - set(checksums))]
    return len(checksums), diffs


def compare_tables(written_dir: Path, recomputed) -> tuple[int, list[str]]:
    """Compare every recomputed table (`Tables`) with `written_dir/<name>.parquet`, exactly (NaN
    equals NaN); returns the number of cells compared and one line per difference."""
    import pandas as pd

    cells, diffs = 0, []
    written_names = {p.stem for p in written_dir.glob("*.parquet")}
    for name in recomputed:
        path = written_dir / f"{name}.parquet"
        try:
            written = pd.read_parquet(path)
        except Exception as exc:  # missing, truncated or not Parquet: a difference, said in one line
            diffs.append(f"tables/{name}.parquet: cannot be read ({type(exc).__name__})")
            continue
        frame = recomputed[name]
        if list(written.columns) != list(frame.columns) or len(written) != len(frame):
            diffs.append(f"tables/{name}.parquet: {len(written)} rows, columns {list(written.columns)} written; "
                         f"{len(frame)} rows, columns {list(frame.columns)} recomputed")
            continue
        cells += frame.size
        diffs += _cell_diffs(name, written, frame)
    diffs += [f"tables/{name}.parquet: not a table of this run" for name in sorted(written_names - set(recomputed))]
    return cells, diffs


def _cell_diffs(name: str, written, frame) -> list[str]:
    """The cells where two frames of the same shape and columns differ (at most CELLS_LISTED, then a count)."""
    out, more = [], 0
    for col in frame.columns:
        if _same_column(written[col], frame[col]):
            continue
        for i, (a, b) in enumerate(zip(written[col].tolist(), frame[col].tolist())):
            if _same_cell(a, b):
                continue
            if len(out) < CELLS_LISTED:
                out.append(f"tables/{name}.parquet row {i} column {col}: {a!r} written, {b!r} recomputed{_relative(a, b)}")
            else:
                more += 1
    return out + ([f"tables/{name}.parquet: {more} more differing cells"] if more else [])


def _same_column(a, b) -> bool:
    """A fast exact comparison of two columns (NaN and missing values equal each other); False means:
    compare cell by cell (which names the cells)."""
    import numpy as np
    import pandas as pd

    x, y = a.to_numpy(), b.to_numpy()
    if x.shape != y.shape:
        return False
    if x.dtype.kind in "fiub" and y.dtype.kind in "fiub":
        return bool(np.array_equal(x, y, equal_nan=x.dtype.kind == "f" and y.dtype.kind == "f"))
    try:
        missing_x, missing_y = pd.isna(x), pd.isna(y)
        equal = np.asarray(x == y, dtype=object)
        return bool(np.all(np.where(missing_x | missing_y, missing_x & missing_y, equal == True)))  # noqa: E712
    except (TypeError, ValueError):
        return False


def _relative(a: Any, b: Any) -> str:
    """' (relative difference r)' for two finite numbers (whether a difference is round-off or an edit), else ''."""
    import math

    if isinstance(a, bool) or isinstance(b, bool) or not all(isinstance(x, (int, float)) for x in (a, b)):
        return ""
    if not (math.isfinite(a) and math.isfinite(b)) or max(abs(a), abs(b)) == 0:
        return ""
    return f" (relative difference {abs(a - b) / max(abs(a), abs(b)):.2g})"


def _same_cell(a: Any, b: Any) -> bool:
    """Equal values: NaN (or a missing value) equals NaN, a number equals the same number of another type."""
    import pandas as pd

    if a is None or b is None or a is pd.NA or b is pd.NA or (isinstance(a, float) and a != a):
        return _is_missing(a) and _is_missing(b)
    try:
        return bool(a == b)
    except (TypeError, ValueError):  # arrays in a cell
        import numpy as np

        return bool(np.array_equal(np.asarray(a), np.asarray(b), equal_nan=True))


def _is_missing(x: Any) -> bool:
    import pandas as pd

    return x is None or x is pd.NA or (isinstance(x, float) and x != x)


def compare_claims(rows: list[dict], stored_rows: list[dict]) -> list[str]:
    """Every difference between re-checked claim rows and report.json's: a verdict, or a measured,
    reference or margin number beyond REVERIFY_RTOL."""
    stored = {r["id"]: r for r in stored_rows}
    diffs = []
    for r in rows:
        old = stored.pop(r["id"], None)
        if old is None:
            diffs.append(f"{r['id']}: not in report.json (re-check gives {r['verdict']})")
            continue
        if old["verdict"] != r["verdict"]:
            diffs.append(f"{r['id']}: report says {old['verdict']}, re-check gives {r['verdict']}")
        for key in ("measured", "reference", "margin"):
            if not same_number(old.get(key), r.get(key)):
                diffs.append(f"{r['id']}: {key} {old.get(key)!r} in report.json, {r.get(key)!r} re-checked")
    return diffs + [f"{cid}: in report.json, not re-checked" for cid in stored]


def verify_run(repro, out_root: Path, out_dir: Path, meta: dict[str, Any] | None = None) -> Verification:
    """Check a run directory's files against run.json, then recompute its tables and claims from the
    stage cache under `out_root` and compare them with what is written. Raises CacheMiss (naming the
    damaged or missing stages and the command that recomputes them) when the cache cannot answer."""
    from dse.api import evaluation_tables
    from dse.contract.context import StageContext
    from dse.contract.options import RunOptions

    meta = meta if meta is not None else json.loads((out_dir / "run.json").read_text())
    v = Verification()
    v.files, v.file_diffs = check_files(out_dir, meta.get("checksums"))
    cache = cache_for(out_root, repro.paper_id, read_only=True)
    # in this process (the stages are only read back): a damaged entry is recorded in this cache object
    opts = dataclasses.replace(RunOptions(**meta["options"]), workers=1)
    try:
        computed = repro.compute(opts, StageContext(cache))
    except CacheMiss as exc:
        raise CacheMiss(cache_advice(cache, meta, out_root, str(exc))) from None
    ev = evaluate_claims(repro, computed)
    tables = evaluation_tables(ev)
    for table_spec, frame in repro.tables(computed.results):
        tables.add(table_spec, frame)
    v.tables = len(list(tables))
    v.cells, v.table_diffs = compare_tables(out_dir / "tables", tables)
    v.claims = ev.claims
    v.claim_diffs = compare_claims(ev.claims, json.loads((out_dir / "report.json").read_text())["claims"])
    return v


def cache_advice(cache, meta: dict[str, Any], out_root: Path, miss: str) -> str:
    """One line: which stage entries are damaged (then removed, so that the next run recomputes them)
    or missing, and the exact command that recomputes them."""
    command, note = rerun_command(meta, out_root), changed_file_note(meta)
    if cache.corrupt_entries:
        damaged = [entry.split(":")[0] for entry in cache.corrupt_entries]
        for key in damaged:
            cache.remove_entry(key)
        return (f"the stage cache under {cache.root} has damaged entries ({'; '.join(cache.corrupt_entries)}); verify "
                f"does not simulate, so it removed them: run `{command}` to recompute them{note}, then verify again")
    return (f"the stage cache under {cache.root} lacks a stage of this run ({miss.split(';')[0]}): the code changed "
            f"since the run, or the cache was deleted; run `{command}` to recompute it{note}, then verify again")


def rerun_command(meta: dict[str, Any], out_root: Path) -> str:
    """The command that recomputes this run into the same output root, with the options it had."""
    opts = meta.get("options", {})
    flags = f" --out {shlex.quote(str(out_root))} --seed {opts.get('seed', 0)}"
    flags += (f" --trials {opts['trials']}" if opts.get("trials") else "") + (" --quick" if opts.get("quick") else "")
    if not meta.get("scenario"):
        return f"dse reproduce {meta['paper']}{flags}"
    file = meta.get("scenario_file")
    if not file:
        return f"dse run <the scenario file (its contents are in run.json)>{flags}"
    return f"dse run {shlex.quote(file)}{flags}"


def changed_file_note(meta: dict[str, Any]) -> str:
    """' (note: ...)' when the scenario file a run was read from no longer holds that scenario, else ''."""
    file = meta.get("scenario_file")
    if not meta.get("scenario") or not file or _same_scenario(file, meta["scenario"]):
        return ""
    return f" (note: {file} changed or is gone since the run; the scenario as run is `scenario` in run.json)"


def _same_scenario(file: str, scenario: dict[str, Any]) -> bool:
    """Whether `file` still holds the scenario a run was made of."""
    from dse.scenario.fields import load_toml

    try:
        return load_toml(file) == scenario
    except Exception:  # gone, unreadable or invalid: not the same
        return False
