"""Incremental and atomic site writing.

The site is built in a staging directory beside the target (`<DIR>.staging-<pid>`) that starts as
hard links to the current site's files; a page is written again only when the key of its inputs
changed (the keys are stored in `<DIR>/.dse-site.json`), a copied file only when its source's size or
modification time changed. Every write replaces a file by renaming a new one over it, so the current
site's files (which the staging directory shares) are never modified. When everything is written,
the staging directory is renamed into place and the previous site removed: a reader sees the old
site or the new one, never a half-built one, and a failed build leaves the old site as it was.
"""
from __future__ import annotations

import hashlib
import json
import os
import shutil
from pathlib import Path
from typing import Callable, Iterable


MANIFEST = ".dse-site.json"


def file_key(paths: Iterable[Path], root: Path, *extra: str) -> str:
    """A key of files by name, size and modification time (and `extra` strings): cheap for large files."""
    h = hashlib.sha256()
    for text in extra:
        h.update(text.encode())
    for p in paths:
        st = p.stat()
        h.update(f"{p.relative_to(root) if p.is_relative_to(root) else p}\0{st.st_size}\0{st.st_mtime_ns}\n".encode())
    return h.hexdigest()


def _link_tree(source: Path, target: Path) -> None:
    """Hard-link every file of `source` under `target` (copying where links are not possible)."""
    for dirpath, _dirs, files in os.walk(source):
        here = target / Path(dirpath).relative_to(source)
        here.mkdir(parents=True, exist_ok=True)
        for name in files:
            _link_or_copy(Path(dirpath) / name, here / name)


def _link_or_copy(source: Path, target: Path) -> None:
    try:
        os.link(source, target)
    except OSError:
        shutil.copy2(source, target)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:         # another user's process
        return True
    return True


def remove_leftovers(site: Path) -> None:
    """Remove the staging and old directories of builds that were killed (their process is gone)."""
    for path in site.parent.glob(f"{site.name}.*-*"):
        kind, _, pid = path.name[len(site.name) + 1:].partition("-")
        if kind in ("staging", "old") and pid.isdigit() and int(pid) != os.getpid() and not _alive(int(pid)):
            shutil.rmtree(path, ignore_errors=True)


class Staging:
    """A site being built: `page(...)` and `copy(...)` write into it, `commit()` swaps it into place."""

    def __init__(self, site: Path, code_key: str):
        self.site = site
        self.code_key = code_key
        self.root = site.parent / f"{site.name}.staging-{os.getpid()}"
        remove_leftovers(site)
        shutil.rmtree(self.root, ignore_errors=True)
        self.root.mkdir(parents=True)
        if site.is_dir():
            _link_tree(site, self.root)
        old = self.root / MANIFEST
        self.old_keys: dict[str, str] = json.loads(old.read_text()) if old.exists() else {}
        self.keys: dict[str, str] = {}
        self.kept: set[str] = {MANIFEST}
        self.written: list[str] = []
        self.skipped: list[str] = []

    def needs(self, rel: str, key: str) -> bool:
        """Whether page `rel` must be written for inputs of `key` (and records the key)."""
        key = hashlib.sha256(f"{self.code_key}\0{key}".encode()).hexdigest()
        self.keys[rel] = key
        self.kept.add(rel)
        fresh = self.old_keys.get(rel) == key and (self.root / rel).exists()
        (self.skipped if fresh else self.written).append(rel)
        return not fresh

    def page(self, rel: str, key: str, render: Callable[[], str]) -> None:
        """Write page `rel` with `render()` unless its inputs' `key` is the one it was written with."""
        if self.needs(rel, key):
            self.write(rel, render())

    def write(self, rel: str, text: str) -> None:
        """Write `text` to a new file renamed over `rel` (never into the file, which the current site may share).
        No fsync: the staging directory as a whole is what becomes visible, and it can always be built again."""
        target = self.root / rel
        target.parent.mkdir(parents=True, exist_ok=True)
        tmp = target.with_name(f".{target.name}.tmp-{os.getpid()}")
        tmp.write_text(text, encoding="utf-8")
        os.replace(tmp, target)

    def copy(self, source: Path, rel: str) -> None:
        """Place `source` at `rel` (a hard link when possible) unless the same file is there already."""
        target = self.root / rel
        self.kept.add(rel)
        if target.exists():
            a, b = source.stat(), target.stat()
            if (a.st_size, a.st_mtime_ns) == (b.st_size, b.st_mtime_ns):
                return
        target.parent.mkdir(parents=True, exist_ok=True)
        tmp = target.with_name(f".{target.name}.tmp-{os.getpid()}")
        tmp.unlink(missing_ok=True)
        _link_or_copy(source, tmp)
        os.replace(tmp, target)

    def _prune(self) -> None:
        """Remove what the new site no longer has (a deleted run's pages, a renamed table)."""
        for dirpath, _dirs, files in os.walk(self.root, topdown=False):
            for name in files:
                rel = (Path(dirpath) / name).relative_to(self.root).as_posix()
                if rel not in self.kept:
                    (Path(dirpath) / name).unlink()
            if Path(dirpath) != self.root and not any(Path(dirpath).iterdir()):
                Path(dirpath).rmdir()

    def commit(self) -> None:
        """Swap the staging directory into place of the site."""
        self.write(MANIFEST, json.dumps(self.keys, indent=0, sort_keys=True))
        self._prune()
        old = self.site.parent / f"{self.site.name}.old-{os.getpid()}"
        if self.site.exists():
            os.rename(self.site, old)
        os.rename(self.root, self.site)
        shutil.rmtree(old, ignore_errors=True)

    def abandon(self) -> None:
        shutil.rmtree(self.root, ignore_errors=True)
