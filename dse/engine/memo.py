"""The run memo: an identical re-run's evaluation and tables, read back instead of re-checked.

A memo lives under ``<stage cache>/runs/<what was run>/<that with this code>/``: the evaluation
and the stage list in ``memo.json``, the tables beside it, every file checksummed. It stands on
the stage entries the run went through (figures and `dse verify` load them), so it also records
the size and modification time of each entry's files: a memo whose stage entries were deleted,
replaced or damaged since is stale and the run is computed again (reading the intact entries
back and recomputing the others). Checking a stamp costs one `stat` per file, not a read.
"""
from __future__ import annotations

import hashlib
import json
import os
import shutil
import sys
import tempfile
from dataclasses import asdict
from pathlib import Path
from typing import Any

from dse.engine.atomic import atomic_write_text
from dse.engine.cache import remove_path
from dse.outputs.tables import Tables
from dse.verify.rules import Evaluation


def memo_dir(cache_dir: Path, key: str) -> Path:
    """runs/<what was run>/<that with this code>: a new memo replaces those of older code."""
    ident, code = key.split("-")
    return cache_dir / "runs" / ident / code


def stage_stamps(cache_dir: Path, stages: list[dict[str, Any]]) -> dict[str, list[int]]:
    """[size, mtime in ns] of each file of every stage entry a run went through (a missing file: [-1, -1])."""
    stamps = {}
    for key in dict.fromkeys(s["key"] for s in stages):
        for suffix in (".npz", ".json"):
            try:
                st = os.stat(cache_dir / f"{key}{suffix}")
                stamps[key + suffix] = [st.st_size, st.st_mtime_ns]
            except OSError:
                stamps[key + suffix] = [-1, -1]
    return stamps


def changed_stages(cache_dir: Path, stamps: dict[str, list[int]], stages: list[dict[str, Any]]) -> list[str]:
    """The stage entry files whose size or modification time differ from `stamps` (or that are gone)."""
    now = stage_stamps(cache_dir, stages)
    return sorted(name for name in set(now) | set(stamps) if now.get(name) != stamps.get(name))


def save_memo(cache_dir: Path, key: str, ev: Evaluation, tables: Tables, stages: list[dict[str, Any]]) -> None:
    """Store the memo of run `key` (replacing memos of the same run by older code); the tables are
    then read from it (`tables.source`) so that the run's own tables/ are copies, not re-encoded."""
    target = memo_dir(cache_dir, key)
    target.parent.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=f".{key}.staging-", dir=target.parent))
    try:
        tables.write(staging / "tables")
        atomic_write_text(staging / "memo.json", json.dumps({
            "evaluation": asdict(ev), "stages": stages, "stage_files": stage_stamps(cache_dir, stages),
            "files": manifest(staging, everything=True)}, allow_nan=False))
        for old in target.parent.iterdir():  # memos of the same run made by older code
            if old.name != staging.name:
                remove_path(old)
        os.replace(staging, target)
        tables.source = target / "tables"
    finally:
        shutil.rmtree(staging, ignore_errors=True)


def load_memo(cache_dir: Path, key: str) -> tuple[Evaluation, Tables, list[dict[str, Any]]] | None:
    """The memo of run `key`, or None when there is none or it cannot be trusted: its own files
    damaged, or a stage entry it stands on deleted, replaced or damaged (said in one line on
    stderr, and the memo removed, so the run is computed again)."""
    d = memo_dir(cache_dir, key)
    if not d.is_dir():
        return None
    try:
        memo = json.loads((d / "memo.json").read_text())
        if manifest(d, everything=True) != memo["files"]:
            raise ValueError("checksum mismatch")
        stages = list(memo["stages"])
        changed = changed_stages(cache_dir, memo["stage_files"], stages)
        if changed:
            print(f"dse: the stage entries behind run memo {key} changed or are gone ({', '.join(changed[:3])}"
                  f"{', ...' if len(changed) > 3 else ''}); computing the run again", file=sys.stderr)
            remove_path(d)
            return None
        return Evaluation(**memo["evaluation"]), Tables.read(d / "tables"), stages
    except Exception as exc:  # a damaged memo is recomputed, like any cache entry
        print(f"dse: run memo {key} is damaged ({type(exc).__name__}: {exc}); recomputing", file=sys.stderr)
        remove_path(d)
        return None


def manifest(directory: Path, everything: bool = False) -> dict[str, str]:
    """sha256 of every file under `directory`: of the figures and recordings of a run directory
    (not its report, run.json or tables), or of every file but a top-level memo.json and run.json."""
    skip = {"memo.json", "run.json"} if everything else {"report.json", "report.md", "run.json", "memo.json"}
    out = {}
    for p in sorted(directory.rglob("*")):
        rel = p.relative_to(directory)
        if p.is_file() and str(rel) not in skip and (everything or rel.parts[0] != "tables"):
            out[str(rel)] = sha256_file(p)
    return out


def sha256_file(path: Path) -> str:
    """The SHA-256 of a file's bytes, read in blocks."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()
