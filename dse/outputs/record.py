"""Rerun recordings (rerun-sdk pinned exactly in pyproject.toml: its API changes between releases).

Conventions (docs/design.md, "Recordings"): timeline ``k`` (sequence) for discrete time and ``t``
(duration, integer nanoseconds) for continuous time; bulk data with ``send_columns``;
styling logged once as static. A recording is written to a temporary file and renamed
into place only once it is complete (footer written), so a final path never holds a
truncated file.
"""
from __future__ import annotations

import contextlib
import functools
import os
from pathlib import Path
from typing import Any, Iterator, Sequence

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from dse.engine.atomic import atomic_path
from dse.outputs.palette import PALETTE, color  # noqa: F401 (re-exported)
from dse.outputs.viewer_glyphs import viewer_text


def on_dark(rgb) -> tuple[int, int, int]:
    """The viewer draws on a dark background: near-black series (the usual colour of a
    reference curve in a matplotlib figure) become light grey instead of invisible."""
    r, g, b = (int(x) for x in rgb[:3])
    return (220, 220, 220) if 0.2126 * r + 0.7152 * g + 0.0722 * b < 40 else (r, g, b)


def _texts(values):
    return None if values is None else [viewer_text(str(v)) for v in values]


@contextlib.contextmanager
def recording(path: str | os.PathLike, *, application_id: str, recording_id: str,
              blueprint: rrb.Blueprint, properties: dict[str, Any] | None = None) -> Iterator[rr.RecordingStream]:
    """Open a recording that lands at `path` only when the block finishes without error."""
    with atomic_path(path) as tmp:
        rec = rr.RecordingStream(application_id, recording_id=recording_id)
        rec.save(str(tmp), default_blueprint=blueprint)
        rec.set_log_time_enabled(False)
        rec.send_recording_name(viewer_text(recording_id))
        if properties:
            rec.send_property("provenance", rr.AnyValues(**{k: _property(v) for k, v in properties.items()}))
        try:
            yield rec
        finally:
            flushed = _flush(rec)
            if flushed:         # after a failed write, rerun's disconnect can block for ever: left undone
                rec.disconnect()
        if not flushed:
            _abandon(rec)
            raise _not_written(tmp, "rerun's file writer failed")
        check_complete(tmp)


#: how long the recording's last messages may take to reach the file (a healthy writer needs well
#: under a second for the largest recording here); after a failed write, flush may wait this long
FLUSH_TIMEOUT_S = 300.0


def _flush(rec: rr.RecordingStream) -> bool:
    """Whether every message reached the file (False when rerun's writer failed or timed out)."""
    try:
        rec.flush(timeout_sec=FLUSH_TIMEOUT_S)
        return True
    except RuntimeError:
        return False


class _AbandonedStream(rr.RecordingStream):
    """A stream whose file writer failed. rerun-sdk 0.41 waits for ever on such a stream when it is
    disconnected, garbage-collected or flushed at exit: it is left as it is, for the process's exit."""

    def __del__(self):
        pass


def _abandon(rec: rr.RecordingStream) -> None:
    rec.__class__ = _AbandonedStream
    rr.unregister_shutdown()    # its exit handler would flush every stream again; ours are closed here


def _not_written(path: Path, why: str) -> OSError:
    import errno

    stat = os.statvfs(path.parent)
    full = stat.f_bavail * stat.f_frsize < 2**20
    code = errno.ENOSPC if full else errno.EIO
    return OSError(code, f"{os.strerror(code)}; the recording is incomplete: {why}", str(path))


#: the last bytes of a complete .rrd file of the pinned rerun-sdk: the footer's magic and its version
RRD_END = b"RRF2FOOT"


def check_complete(path: Path) -> None:
    """OSError naming `path` unless the recording there ends with its footer: rerun's file sink
    fails in a background thread (a full disk, a file size limit) without raising, and its own
    log lines are off (dse/__init__.py)."""
    with open(path, "rb") as fh:
        fh.seek(0, os.SEEK_END)
        fh.seek(max(fh.tell() - len(RRD_END) - 4, 0))
        tail = fh.read()
    if not tail.startswith(RRD_END):
        raise _not_written(Path(path), "no footer")


#: the largest magnitude of rerun's float32 components (positions in the plane and in graphs)
FLOAT32_MAX = float(np.finfo(np.float32).max)


def as_float32(values) -> np.ndarray:
    """`values` for a float32 component of rerun: an entry beyond float32's range (a diverging
    estimate, say) becomes NaN, not drawn, instead of an overflow in rerun's cast; the number
    itself is in the run's tables."""
    v = np.asarray(values, dtype=np.float64)
    return np.where(np.abs(v) <= FLOAT32_MAX, v, np.nan).astype(np.float32)


def _property(v: Any) -> Any:
    if isinstance(v, (str, int, float, bool)):
        return v
    return str(v)


def sequence_index(name: str, values: Sequence[int] | np.ndarray) -> list[rr.TimeColumn]:
    return [rr.TimeColumn(name, sequence=np.asarray(values, dtype=np.int64))]


def duration_index(name: str, nanoseconds: np.ndarray) -> list[rr.TimeColumn]:
    """Continuous time as integer nanoseconds (a float-seconds array would be truncated)."""
    return [rr.TimeColumn(name, duration=np.asarray(nanoseconds, dtype=np.int64).astype("timedelta64[ns]"))]


def send_series(rec: rr.RecordingStream, entity: str, index: list[rr.TimeColumn], values: np.ndarray, *,
                names: Sequence[str] | str | None = None, colors: Sequence[tuple[int, int, int]] | None = None,
                points: bool = False, width: float = 1.5) -> None:
    """One entity holding T rows of k scalars (k series), styled once as static."""
    values = np.asarray(values, dtype=np.float64)
    if values.ndim == 1:
        values = values[:, None]
    k = values.shape[1]
    names = _texts([names] * k if isinstance(names, str) else names)
    colors = [on_dark(c) for c in colors] if colors is not None else [color(i) for i in range(k)]
    style = _series_style(k, None if names is None else tuple(names), tuple(tuple(c) for c in colors), bool(points),
                          float(width))
    rec.log(entity, style, static=True)
    rec.send_columns(entity, indexes=index, columns=rr.Scalars.columns(scalars=values))


@functools.lru_cache(maxsize=512)
def _series_style(k: int, names: tuple[str, ...] | None, colors: tuple[tuple[int, ...], ...], points: bool,
                  width: float) -> rr.SeriesLines | rr.SeriesPoints:
    """The static style of a `send_series` entity. Built once per distinct style: building the
    archetype (colour conversion to arrow) was ~30% of the cost of writing a short series."""
    names_l = None if names is None else list(names)
    colors_l = [tuple(c) for c in colors]
    if points:
        return rr.SeriesPoints(names=names_l, colors=colors_l, markers=["circle"] * k, marker_sizes=[3.0] * k)
    return rr.SeriesLines(names=names_l, colors=colors_l, widths=[width] * k)


def log_graph(rec: rr.RecordingStream, entity: str, positions: np.ndarray, edges: Sequence[tuple[int, int]], *,
              labels: Sequence[str] | None = None, directed: bool = False, colors=None, radii: float = 12.0) -> None:
    """A fixed graph (static) with nodes at the given positions (any units: rescaled so that
    the closest two nodes are 160 px apart and their labels do not overlap)."""
    n = len(positions)
    ids = [str(i) for i in range(n)]
    rec.log(entity,
            rr.GraphNodes(ids, positions=display_positions(positions), labels=_texts(labels or ids),
                          colors=colors if colors is not None else [color(0)] * n, radii=radii, show_labels=True),
            rr.GraphEdges([(str(u), str(v)) for u, v in edges],
                          graph_type=rr.GraphType.Directed if directed else rr.GraphType.Undirected),
            static=True)


def display_positions(positions: np.ndarray, spacing: float = 160.0) -> np.ndarray:
    """Positions scaled so that the closest pair of nodes is `spacing` pixels apart (float32, as
    rerun stores them; beyond its range NaN, see `as_float32`)."""
    pos = np.asarray(positions, float)
    if len(pos) < 2:
        return as_float32(pos)
    with np.errstate(over="ignore", invalid="ignore"):    # positions up to 1e100 apart: inf is handled below
        d = np.sqrt(((pos[:, None, :] - pos[None, :, :]) ** 2).sum(-1))
        closest = d[~np.eye(len(pos), dtype=bool)].min()
        return as_float32(pos * (spacing / closest) if 0 < closest < np.inf else pos)


def log_markdown(rec: rr.RecordingStream, entity: str, text: str) -> None:
    rec.log(entity, rr.TextDocument(viewer_text(text), media_type=rr.MediaType.MARKDOWN), static=True)


def _short(value, width: int) -> str:
    import json

    return json.dumps(value, ensure_ascii=False, default=str)[:width]


def log_claims(rec: rr.RecordingStream, claims: Sequence[dict], header: str, *,
               details: Sequence[dict] | None = None, width: int = 40) -> None:
    """`/report`, one document: `header`, a table of `claims` (verdict, measured, reference, margin), then each
    claim of `details` (default: `claims`) in full. (One document per claim under `/claims/<id>` could not be
    shown: rerun's text view shows one document at a time.)"""
    rows = [header, "", "| claim | verdict | measured | reference | margin |", "|---|---|---|---|---|"]
    rows += [f"| `{c['id']}` | **{c['verdict']}** | {_short(c.get('measured'), width)} | "
             f"{_short(c.get('reference'), width)} | {_short(c.get('margin'), 16)} |" for c in claims]
    full = [f"### `{c['id']}`: {c['verdict']}\n\n*{c['source']}*: {c['statement']}\n\n"
            f"- measured: {c.get('measured')}\n- reference: {c.get('reference')}\n- margin: {c.get('margin')}"
            f"\n\n{c.get('detail', '')}" for c in (claims if details is None else details)]
    if full:
        rows += ["", "## Each claim in full", "", *full]
    log_markdown(rec, "report", "\n".join(rows))


def log_tensor(rec: rr.RecordingStream, entity: str, matrix: np.ndarray, dim_names=("row", "col")) -> None:
    rec.log(entity, rr.Tensor(np.asarray(matrix, float), dim_names=list(dim_names)), static=True)


# -- reading back (tests, `dse verify`) ------------------------------------------------------

def read_scalars(path: str | Path, index: str, content: str = "/**") -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """entity path -> (index values (T,), scalars (T, k)), read with rerun's own reader."""
    import pyarrow as pa

    parts: dict[str, list] = {}
    stream = rr.chunk.RrdReader(str(path)).stream().filter(content=content, is_static=False, components="Scalars:scalars")
    for chunk in stream:
        if index not in chunk.timeline_names:
            continue
        parts.setdefault(chunk.entity_path, []).append(chunk.to_record_batch())
    out = {}
    for ent, batches in parts.items():
        table = pa.Table.from_batches(batches).sort_by(index)
        vals = table.column("Scalars:scalars").combine_chunks()
        out[ent] = (table.column(index).to_numpy(), vals.flatten().to_numpy().reshape(table.num_rows, -1))
    return out


def read_static(path: str | Path, entity: str) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for chunk in rr.chunk.RrdReader(str(path)).stream().filter(content=entity, is_static=True):
        for k, v in chunk.to_record_batch().to_pydict().items():
            if not k.startswith("rerun.controls"):
                out[k] = v[-1]
    return out


def blueprint_view_kinds(path: str | Path) -> list[str]:
    """Class identifiers of the views in the recording's default blueprint."""
    reader = rr.chunk.RrdReader(str(path))
    kinds = []
    for chunk in reader.stream(store=reader.blueprints()[0]):
        for k, v in chunk.to_record_batch().to_pydict().items():
            if k.endswith("class_identifier"):
                kinds.extend(x for row in v if row for x in (row if isinstance(row, list) else [row]))
    return kinds
