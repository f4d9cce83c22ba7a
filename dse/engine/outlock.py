"""One run at a time per output directory, and no leftovers of killed runs.

Every command that writes under OUT holds an exclusive lock on ``OUT/.dse.lock`` for its
whole duration: a second run into the same OUT waits (and says so) instead of interleaving
its files with the first. Once the lock is held no other run is writing there, so the
staging directories a killed run left behind (``.<name>.staging-*``, ``.<name>.old-*``)
and temporary files (``.<stem>.*.tmp.<ext>``) are removed.
"""
from __future__ import annotations

import contextlib
import fcntl
import os
import sys
from pathlib import Path
from typing import Iterator

from dse.errors import OutputError

LEFTOVER_PATTERNS = (".*.staging-*", ".*.old-*", ".*.tmp.*")


@contextlib.contextmanager
def output_lock(out_root: Path) -> Iterator[None]:
    try:
        out_root.mkdir(parents=True, exist_ok=True)
        fh = open(out_root / ".dse.lock", "a+")
    except OSError as exc:
        raise OutputError(f"output directory {out_root} is not usable: {exc.strerror or exc}") from None
    with fh:
        try:
            fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            fh.seek(0)
            holder = fh.read().strip() or "another process"
            print(f"dse: waiting for the other dse run writing to {out_root} ({holder}) to finish", file=sys.stderr)
            fcntl.flock(fh, fcntl.LOCK_EX)
        fh.seek(0)
        fh.truncate()
        fh.write(f"pid {os.getpid()}")
        fh.flush()
        remove_leftovers(out_root)
        try:
            yield
        finally:
            fh.seek(0)
            fh.truncate()
            fcntl.flock(fh, fcntl.LOCK_UN)


def remove_leftovers(out_root: Path) -> list[Path]:
    """Remove what killed runs left under `out_root` (call only while holding the lock)."""
    from dse.engine.cache import remove_path

    removed = []
    for parent in (out_root, out_root / "run", out_root / "sweep", *out_root.glob("*/figures"), *out_root.glob("run/*/figures"),
                   *out_root.glob("sweep/*")):
        if not parent.is_dir():
            continue
        for pattern in LEFTOVER_PATTERNS:
            for path in parent.glob(pattern):
                remove_path(path)
                removed.append(path)
    return removed
