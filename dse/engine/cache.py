"""Stage cache: results keyed by a content hash of the stage's inputs and code.

An entry is one ``.npz`` file of named arrays plus a ``.json`` sidecar holding the
parameters and the SHA-256 of the npz bytes. Both are written atomically, the sidecar
last, so an entry without a valid sidecar is simply absent; an entry whose checksum does
not match is reported, deleted and recomputed, never used (a read-only cache, the one
`dse verify` reads, only records it).
"""
from __future__ import annotations

import functools
import hashlib
import io
import json
import shutil
import sys
from pathlib import Path
from typing import Any, Callable

import numpy as np

from dse.engine.atomic import atomic_write_bytes, atomic_write_text
from dse.errors import CacheMiss, NumericalError


def canonical_json(obj: Any) -> str:
    """Stable JSON for hashing: sorted keys, numpy values converted, floats as repr."""
    return json.dumps(obj, sort_keys=True, default=_jsonable, separators=(",", ":"))


def _jsonable(x: Any) -> Any:
    if isinstance(x, np.ndarray):
        return x.tolist()
    if isinstance(x, np.generic):
        return x.item()
    if isinstance(x, (tuple, set, frozenset)):
        return list(x)
    if hasattr(x, "__dataclass_fields__"):
        from dataclasses import asdict

        return asdict(x)
    raise TypeError(f"cannot hash {type(x).__name__}")


PROJECT_PACKAGES = ("dse",)


@functools.lru_cache(maxsize=1)
def project_fingerprint() -> str:
    """Hash of every source and scenario file of the project's packages: any code change makes
    stored sweep points and run memos stale (a result may depend on any estimator, claim or
    pipeline module, and the papers' scenarios are files)."""
    import importlib

    h = hashlib.sha256()
    for package in PROJECT_PACKAGES:
        root = Path(importlib.import_module(package).__file__).parent
        for path in sorted([*root.rglob("*.py"), *root.rglob("*.toml")]):
            h.update(str(path.relative_to(root.parent)).encode())
            h.update(path.read_bytes())
    return h.hexdigest()[:16]


class StageCache:
    """A directory of cached stage results."""

    def __init__(self, root: str | Path, *, read_only: bool = False, fresh: bool = False):
        """`read_only`: never write or delete (what `dse verify` reads; a damaged entry is recorded in
        `corrupt_entries`, not recomputed); `fresh`: never read, every stage is computed and its entry
        overwritten (`dse run --fresh`; an entry stored by this object is read back)."""
        self.root = Path(root)
        self.read_only = read_only
        self.fresh = fresh
        self.corrupt_entries: list[str] = []
        self._written: set[str] = set()    # entries this object stored (a fresh run reads those back)

    def key(self, stage: str, params: dict[str, Any]) -> str:
        return f"{stage}-{hashlib.sha256(canonical_json(params).encode()).hexdigest()[:24]}"

    def units_dir(self, key: str) -> Path | None:
        """Where the stage `key` keeps its finished Monte Carlo units while it computes
        (`dse.simulate.checkpoints`); None for a read-only cache."""
        return None if self.read_only else self.root / "units" / key

    def _paths(self, key: str) -> tuple[Path, Path]:
        return self.root / f"{key}.npz", self.root / f"{key}.json"

    def load(self, stage: str, params: dict[str, Any]) -> dict[str, np.ndarray] | None:
        key = self.key(stage, params)
        data_path, meta_path = self._paths(key)
        if (self.fresh and key not in self._written) or not meta_path.exists() or not data_path.exists():
            return None
        try:
            meta = json.loads(meta_path.read_text())
            raw = data_path.read_bytes()
            if not isinstance(meta, dict) or hashlib.sha256(raw).hexdigest() != meta.get("sha256"):
                raise ValueError("checksum mismatch")
            with np.load(io.BytesIO(raw), allow_pickle=False) as npz:
                return {k: npz[k] for k in npz.files}
        except Exception as exc:  # any damage to an entry (truncated, edited, replaced by a directory) means: recompute
            reason = f"{type(exc).__name__}: {exc}" if not isinstance(exc, ValueError) else str(exc)
            self.corrupt_entries.append(f"{key}: {reason}")
            if self.read_only:  # the reader says what to do about it (see dse verify)
                return None
            print(f"dse: cache entry {key} is damaged ({reason}); recomputing", file=sys.stderr)
            for p in (meta_path, data_path):
                remove_path(p)
            return None

    def has(self, stage: str, params: dict[str, Any]) -> bool:
        """Whether an entry is stored for these parameters (`load` would read it back unless it is damaged)."""
        if self.fresh and self.key(stage, params) not in self._written:
            return False
        return all(p.is_file() for p in self._paths(self.key(stage, params)))

    def remove_entry(self, key: str) -> None:
        """Delete the files of the entry `key` (a damaged one: nobody can use it)."""
        for p in self._paths(key):
            remove_path(p)

    def save(self, stage: str, params: dict[str, Any], arrays: dict[str, np.ndarray]) -> None:
        if self.read_only:
            return
        key = self.key(stage, params)
        data_path, meta_path = self._paths(key)
        buf = io.BytesIO()
        np.savez(buf, **arrays)
        raw = buf.getvalue()
        for p in (data_path, meta_path):
            if p.is_dir():
                remove_path(p)
        atomic_write_bytes(data_path, raw)
        atomic_write_text(meta_path, json.dumps({"stage": stage, "params": json.loads(canonical_json(params)),
                                                 "sha256": hashlib.sha256(raw).hexdigest()}, indent=1))
        self._written.add(key)

    def get_or_compute(self, stage: str, params: dict[str, Any], compute: Callable[[], dict[str, np.ndarray]], *,
                       scenario: str = "", allow_nonfinite: tuple[str, ...] = ()) -> dict[str, np.ndarray]:
        """Load the entry or compute and store it. A NaN or inf in a computed array (other than
        those named in `allow_nonfinite`, e.g. a predicted divergence) raises NumericalError
        naming the stage, the scenario and where, and nothing is stored."""
        cached = self.load(stage, params)
        if cached is not None:
            return cached
        if self.read_only:
            raise CacheMiss(f"stage '{stage}' is not in the cache at {self.root} ({self.key(stage, params)}); "
                            "run `dse reproduce` first")
        arrays = compute()
        check_finite(arrays, stage=stage, scenario=scenario, allow=allow_nonfinite)
        self.save(stage, params, arrays)
        return arrays


class MemoryCache(StageCache):
    """Stage results kept in this process only, for a run without a cache directory (a sweep
    point, `dse.run` in a script): nothing is encoded or written; the finiteness check stays."""

    def __init__(self) -> None:
        super().__init__(".")
        self._entries: dict[str, dict[str, np.ndarray]] = {}

    def load(self, stage: str, params: dict[str, Any]) -> dict[str, np.ndarray] | None:
        return self._entries.get(self.key(stage, params))

    def has(self, stage: str, params: dict[str, Any]) -> bool:
        return self.key(stage, params) in self._entries

    def units_dir(self, key: str) -> Path | None:
        return None         # nothing on disk: an interrupted run in memory has nothing to resume from

    def save(self, stage: str, params: dict[str, Any], arrays: dict[str, np.ndarray]) -> None:
        self._entries[self.key(stage, params)] = arrays


def remove_path(path: Path) -> None:
    """Remove a file or a directory tree at `path`, if any."""
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, ignore_errors=True)
    else:
        path.unlink(missing_ok=True)


def check_finite(arrays: dict[str, np.ndarray], *, stage: str, scenario: str, allow: tuple[str, ...] = ()) -> None:
    """Raise NumericalError at the first non-finite entry (array name and index; the leading
    index of a time series is its time step)."""
    for name, arr in arrays.items():
        if name in allow or not np.issubdtype(np.asarray(arr).dtype, np.inexact):
            continue
        bad = ~np.isfinite(arr)
        if bad.any():
            where = tuple(int(i) for i in np.argwhere(bad)[0])
            raise NumericalError(stage, scenario, f"array '{name}' at index {where} (value {np.asarray(arr)[where]})")
