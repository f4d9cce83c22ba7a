"""Finished Monte Carlo units kept while their stage runs, so that an interrupted stage resumes.

A stage computed through a persistent stage cache (`dse.contract.context.StageContext.run`) opens a
directory beside its entry, ``<cache>/units/<stage key>/``; every portable `run_units` call of the stage
stores there (once it has been computing for STORE_AFTER_S seconds) the per-unit partial results of
the units it has computed, one file per range of units
(``<call>-<stream>/<first>-<stop>.pkl``: a SHA-256 line, then the pickled list of partials). A rerun of
the stage (after Ctrl-C, a lost connection, a crash) reads them back instead of computing those units;
the partials are folded in unit order either way, so the result is the same bits. The directory is
removed once the stage's entry is stored. Only the keyed arguments and the code decide a stage's key,
so the stored units are those of the same computation; a damaged file is ignored and recomputed.
The files are pickles, read only from this run's own cache directory (trusted like the code).
"""
from __future__ import annotations

import contextlib
import hashlib
import pickle
import threading
import time
from pathlib import Path
from typing import Any, Iterator

import numpy as np

from dse.engine.atomic import atomic_write_bytes
from dse.engine.cache import remove_path

#: a call keeps its units once it has been computing this long (a shorter one loses little when interrupted, and
#: pickling the partials of tiny units costs up to a few percent of computing them) ...
STORE_AFTER_S = 2.0
#: ... then writes them at least this often (seconds of computing between two files) ...
FLUSH_EVERY_S = 2.0
#: ... and at most this many units are held back for the next file
FLUSH_UNITS = 256

#: per thread (a run on a Dask cluster computes several stages at once, one per thread), the stages being computed
#: with a persistent cache: [units directory, fresh, run_units calls so far]
_LOCAL = threading.local()


def _scopes() -> list:
    if not hasattr(_LOCAL, "scopes"):
        _LOCAL.scopes = []
    return _LOCAL.scopes


@contextlib.contextmanager
def stage_scope(directory: Path | None, *, fresh: bool = False) -> Iterator[None]:
    """While a stage computes: where its `run_units` calls keep their finished units (None: nowhere, e.g.
    a stage cache kept in memory); `fresh`: ignore units stored by an earlier attempt."""
    _scopes().append([directory, fresh, 0])
    try:
        yield
    finally:
        _scopes().pop()


def finish_stage(directory: Path | None) -> None:
    """The stage's entry is stored: its finished units are no longer needed (nor `units/`, once empty)."""
    if directory is not None:
        remove_path(directory)
        try:
            directory.parent.rmdir()
        except OSError:                 # another stage's units are there, or there was never any
            pass


def for_call(seq: np.random.SeedSequence, n_trials: int) -> "UnitCheckpoints | None":
    """The store of the current stage's next `run_units` call (by its rank in the stage and its stream), or
    None outside a stage with a persistent cache."""
    scopes = _scopes()
    if not scopes or scopes[-1][0] is None:
        return None
    scope = scopes[-1]
    scope[2] += 1
    stream = hashlib.sha256(repr((seq.entropy, seq.spawn_key, n_trials)).encode()).hexdigest()[:16]
    return UnitCheckpoints(scope[0] / f"{scope[2]}-{stream}", fresh=scope[1])


class UnitCheckpoints:
    """The finished units of one `run_units` call: `stored()` lists the ranges kept by an earlier attempt,
    `load` reads one back, `add` keeps newly computed units once the call has run STORE_AFTER_S seconds
    (written by `flush`, every FLUSH_EVERY_S seconds or FLUSH_UNITS units, and when the call ends,
    normally or not)."""

    def __init__(self, directory: Path, *, fresh: bool = False):
        self.directory, self.fresh = directory, fresh
        #: consecutive (first unit, number of units, their partials pickled) not yet written: pickled when they
        #: arrive, before the fold sees them (a fold may update a partial in place)
        self._held: list[tuple[int, int, bytes]] = []
        self._started = self._last_flush = time.perf_counter()

    def stored(self) -> list[tuple[int, int, Path]]:
        """(first unit, stop, file) of the stored ranges, in unit order, none overlapping (a range that
        overlaps one before it is skipped)."""
        if self.fresh or not self.directory.is_dir():
            return []
        ranges = []
        for path in self.directory.glob("*-*.pkl"):
            try:
                a, b = (int(x) for x in path.stem.split("-"))
            except ValueError:
                continue
            ranges.append((a, b, path))
        kept, end = [], 0
        for a, b, path in sorted(ranges):
            if a >= end and b > a:
                kept.append((a, b, path))
                end = b
        return kept

    def load(self, path: Path, n_units: int) -> list | None:
        """The partials stored in `path` (None when it is damaged or does not hold `n_units` of them)."""
        try:
            raw = path.read_bytes()
            digest, body = raw.split(b"\n", 1)
            if hashlib.sha256(body).hexdigest().encode() != digest:
                raise ValueError("checksum mismatch")
            parts = [p for group in pickle.loads(body) for p in pickle.loads(group)]
            if len(parts) != n_units:
                raise ValueError("wrong number of units")
            return parts
        except Exception:  # noqa: BLE001 - any damage: compute these units again
            remove_path(path)
            return None

    def add(self, first: int, parts: list, pickled: bytes | None = None) -> None:
        """Units `first`, `first + 1`, ... computed (`pickled`: the list `parts` pickled, when it came so):
        written now or with the next ones (or not kept, in the call's first STORE_AFTER_S seconds)."""
        if time.perf_counter() - self._started < STORE_AFTER_S:
            return
        if self._held and self._held[-1][0] + self._held[-1][1] != first:
            self.flush()
        self._held.append((first, len(parts), pickled or pickle.dumps(list(parts), protocol=pickle.HIGHEST_PROTOCOL)))
        if sum(n for _, n, _ in self._held) >= FLUSH_UNITS or time.perf_counter() - self._last_flush >= FLUSH_EVERY_S:
            self.flush()

    def flush(self) -> None:
        """Write the units held back as one file."""
        self._last_flush = time.perf_counter()
        if not self._held:
            return
        first, n = self._held[0][0], sum(n for _, n, _ in self._held)
        body = pickle.dumps([group for _, _, group in self._held], protocol=pickle.HIGHEST_PROTOCOL)
        self._held = []
        data = hashlib.sha256(body).hexdigest().encode() + b"\n" + body
        try:
            atomic_write_bytes(self.directory / f"{first}-{first + n}.pkl", data)
        except FileNotFoundError:       # `units/` was removed (emptied by a stage that finished) while made: again
            atomic_write_bytes(self.directory / f"{first}-{first + n}.pkl", data)


def checkpoint_summary(directory: Path) -> dict[str, Any]:
    """How many unit files and units a stage's directory holds (for tests and messages)."""
    files = list(directory.rglob("*-*.pkl")) if directory.is_dir() else []
    units = sum(int(p.stem.split("-")[1]) - int(p.stem.split("-")[0]) for p in files)
    return {"files": len(files), "units": units}
