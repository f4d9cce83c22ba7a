"""One run at a time per output directory, no leftovers of killed runs, nothing left by a refused one.

Every command that writes under OUT holds an exclusive lock on ``OUT/.dse.lock`` for its
whole duration: a second run into the same OUT waits (and says so) instead of interleaving
its files with the first. Once the lock is held no other run is writing there, so the
staging directories a killed run left behind (``.<name>.staging-*``, ``.<name>.old-*``)
and temporary files (``.<stem>.*.tmp.<ext>``) are removed. The lock file is removed when the
command ends, whatever the outcome.

A command that fails with invalid input, an unusable output or a numerical failure (exit 2 or
3; or a defect of ours) before it wrote any result leaves OUT as it found it: a directory the command created is
removed, and in an OUT that existed, what the command added under ``.cache/``, ``run/`` and
``sweep/`` (down to five levels: the stage cache entries and memo of the run, an empty ``run/``, a
sweep's stored points) is removed again.
"""
from __future__ import annotations

import contextlib
import fcntl
import os
import sys
from pathlib import Path
from typing import Iterator

from dse.errors import CacheMiss, OutputError

LEFTOVER_PATTERNS = (".*.staging-*", ".*.old-*", ".*.tmp.*")
LOCK_NAME = ".dse.lock"
#: failures after which what the command wrote is kept: a broken pipe (exit 141) comes after the results, and a
#: missing cache entry (exit 1) is `dse verify`'s, which writes nothing. Every other error (exit 2 or 3, or a
#: defect) is undone; an interruption (130, 143) is not an error: it keeps the stage cache to resume from.
KEPT_AFTER = (BrokenPipeError, CacheMiss)
#: what a command writes under OUT before its results (in an OUT that existed, only what is new there is
#: undone: a file someone else put beside them meanwhile is not ours to remove)
OWN_SUBTREES = (".cache", "run", "sweep")
#: how deep under OUT what a refused command added is looked for (a run memo and a sweep point are 5 deep)
SNAPSHOT_DEPTH = 5


class OutputGuard:
    """Held while a command writes under OUT: it marks when results were written (after that, a
    failure leaves them in place)."""

    def __init__(self) -> None:
        self.results_written = False

    def wrote_results(self) -> None:
        self.results_written = True


@contextlib.contextmanager
def output_lock(out_root: Path) -> Iterator[OutputGuard]:
    """Hold OUT's lock for the duration of a command; on a refusal (exit 2 or 3) before any result
    was written, undo what the command added under OUT. The lock file is removed at the end."""
    out_root = Path(out_root)
    fh, created = _acquire(out_root)
    guard = OutputGuard()
    try:
        before = None if created is not None else snapshot(out_root)
        remove_leftovers(out_root)
        yield guard
    except Exception as exc:
        if not guard.results_written and not isinstance(exc, KEPT_AFTER):
            _undo(out_root, created, before)
        raise
    finally:
        _release(out_root, fh)


def _acquire(out_root: Path):
    """Open and lock OUT/.dse.lock (creating OUT if needed); returns the locked file and the topmost
    directory this call created (None if OUT existed). A lock file removed by the run that held it
    while this one waited is opened again, so that two runs never hold two different files."""
    announced = False
    while True:
        created = _topmost_missing(out_root)
        try:
            out_root.mkdir(parents=True, exist_ok=True)
            fh = open(out_root / LOCK_NAME, "a+")
        except OSError as exc:
            raise OutputError(unusable_output(out_root, exc)) from None
        try:
            fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            if not announced:
                fh.seek(0)
                holder = fh.read().strip() or "another process"
                print(f"dse: waiting for the other dse run writing to {out_root} ({holder}) to finish", file=sys.stderr)
                announced = True
            fcntl.flock(fh, fcntl.LOCK_EX)
        if _same_file(fh, out_root / LOCK_NAME):
            fh.seek(0)
            fh.truncate()
            fh.write(f"pid {os.getpid()}")
            fh.flush()
            return fh, created
        fh.close()  # the holder removed it (and perhaps OUT) while we waited: take the lock anew


def _same_file(fh, path: Path) -> bool:
    try:
        a, b = os.fstat(fh.fileno()), os.stat(path)
    except OSError:
        return False
    return (a.st_dev, a.st_ino) == (b.st_dev, b.st_ino)


def _topmost_missing(path: Path) -> Path | None:
    """The outermost directory of `path` that does not exist yet (what `mkdir -p` would create)."""
    path = path.absolute()
    if path.exists():
        return None
    while not path.parent.exists():
        path = path.parent
    return path


def _release(out_root: Path, fh) -> None:
    """Remove the lock file (if still ours), then unlock and close it."""
    try:
        if _same_file(fh, out_root / LOCK_NAME):
            (out_root / LOCK_NAME).unlink()
    except OSError:
        pass
    finally:
        fcntl.flock(fh, fcntl.LOCK_UN)
        fh.close()


def snapshot(out_root: Path, depth: int = SNAPSHOT_DEPTH) -> set[str]:
    """The paths under `out_root` down to `depth` levels (relative), but the lock file."""
    found: set[str] = set()
    level = [out_root]
    for _ in range(depth):
        deeper = []
        for d in level:
            try:
                entries = list(os.scandir(d))
            except OSError:
                continue
            for e in entries:
                found.add(os.path.relpath(e.path, out_root))
                if e.is_dir(follow_symlinks=False):
                    deeper.append(Path(e.path))
        level = deeper
    found.discard(LOCK_NAME)
    return found


def _undo(out_root: Path, created: Path | None, before: set[str] | None) -> None:
    """Remove what a refused command added: the directory it created, or the paths new since `before`."""
    from dse.engine.cache import remove_path

    if created is not None:
        remove_path(created)
        return
    if before is None:
        return
    added = [rel for rel in snapshot(out_root) - before if Path(rel).parts[0] in OWN_SUBTREES]
    for rel in sorted(added, key=lambda r: r.count(os.sep)):
        remove_path(out_root / rel)   # a new directory goes with everything in it; its entries are then gone


def unusable_output(out_root: Path, exc: OSError) -> str:
    """The one line for an output root that cannot be created or written: a file in the way is named as such."""
    blocking = next((p for p in (out_root, *out_root.parents) if p.exists() and not p.is_dir()), None)
    if blocking == out_root:
        return f"--out {out_root} is a file, not a directory: give a directory (it is created if missing)"
    if blocking is not None:
        return f"--out {out_root} cannot be created: {blocking} is a file, not a directory"
    return f"output directory {out_root} is not usable: {exc.strerror or exc}"


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
