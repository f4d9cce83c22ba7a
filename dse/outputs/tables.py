"""Every number a run computes, as documented tidy tables.

A family declares each table once (`TableSpec`: its name, what one row is, and every
column with its unit and definition) and fills it with a pandas DataFrame. `Tables`
checks that the frame has exactly the declared columns, and writes each table as Parquet
(the column's unit and definition in the Arrow field metadata, the table's description
in the schema metadata) with a CSV twin when it is small, plus `tables/README.md`, the
index a user reads first. Figures and recordings are drawn from these frames.

Conventions: one row per (scenario, node, time, cell, edge, entry, ...); matrices one
row per entry (`row`, `col`, `value`); the first column of a family's tables is
`scenario`. Floats are stored at full precision (float64).
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable, Iterator, Mapping

import numpy as np

#: a table with at most this many cells also gets a CSV twin (spreadsheet users); floats in the
#: CSV are written as Python's shortest round-trip repr, so they read back to the same bits
CSV_CELLS = 20_000


@dataclass(frozen=True)
class Column:
    name: str
    unit: str
    definition: str


@dataclass(frozen=True)
class TableSpec:
    """A table's declaration: `row` says what one row is, `columns` every column in order."""

    name: str
    row: str
    columns: tuple[Column, ...]
    description: str = ""

    def __post_init__(self):
        names = [c.name for c in self.columns]
        if len(set(names)) != len(names):
            raise ValueError(f"table {self.name}: duplicate column names")
        if not self.name.replace("_", "").isalnum():
            raise ValueError(f"table name {self.name!r} must be an identifier")
        for c in self.columns:
            if not c.definition.strip():
                raise ValueError(f"table {self.name}: column {c.name} has no definition")

    @property
    def column_names(self) -> list[str]:
        return [c.name for c in self.columns]


def col(name: str, unit: str, definition: str) -> Column:
    return Column(name, unit, definition)


def spec(name: str, row: str, columns: Iterable[Column | tuple[str, str, str]], description: str = "") -> TableSpec:
    return TableSpec(name, row, tuple(c if isinstance(c, Column) else Column(*c) for c in columns), description)


@dataclass
class Tables:
    """The tables of one run, in the order they were added."""

    specs: dict[str, TableSpec] = field(default_factory=dict)
    frames: dict[str, Any] = field(default_factory=dict)
    #: the directory these tables were read from, unchanged since (see `read`)
    source: Path | None = None

    def add(self, table: TableSpec, frame) -> None:
        """Add (or extend, with the same declaration) a table; its columns must match the declaration exactly."""
        import pandas as pd

        frame = pd.DataFrame(frame) if not isinstance(frame, pd.DataFrame) else frame
        if list(frame.columns) != table.column_names:
            missing = [c for c in table.column_names if c not in frame.columns]
            extra = [c for c in frame.columns if c not in table.column_names]
            raise ValueError(f"table {table.name}: columns differ from the declaration (missing {missing}, "
                             f"undeclared {extra}, or another order)")
        self.source = None
        if table.name in self.specs:
            if self.specs[table.name] != table:
                raise ValueError(f"table {table.name}: declared twice differently")
            frame = pd.concat([self.frames[table.name], frame], ignore_index=True)
        self.specs[table.name] = table
        self.frames[table.name] = frame.reset_index(drop=True)

    def __getitem__(self, name: str):
        return self.frames[name]

    def __contains__(self, name: str) -> bool:
        return name in self.frames

    def __iter__(self) -> Iterator[str]:
        return iter(self.frames)

    def describe(self, name: str):
        """The declaration of one table as a DataFrame (column, unit, definition)."""
        import pandas as pd

        s = self.specs[name]
        return pd.DataFrame([(c.name, c.unit, c.definition) for c in s.columns], columns=["column", "unit", "definition"])

    def write(self, directory: Path) -> list[Path]:
        """Write every table (Parquet, CSV twin when small) and the index; returns the paths.
        Tables read from a directory by `read` are copied from there, not rewritten."""
        if self.source is not None and (self.source / "schema.json").exists():
            return _copy_tree(self.source, directory)
        from dse.engine.atomic import atomic_path, atomic_write_text

        directory.mkdir(parents=True, exist_ok=True)
        written = []
        for name, frame in self.frames.items():
            s = self.specs[name]
            target = directory / f"{name}.parquet"
            with atomic_path(target) as tmp:
                _write_parquet(s, frame, tmp)
            written.append(target)
            if frame.size <= CSV_CELLS:
                target = directory / f"{name}.csv"
                atomic_write_text(target, frame.to_csv(index=False))
                written.append(target)
        atomic_write_text(directory / "README.md", self.index_markdown())
        atomic_write_text(directory / "schema.json", json.dumps(self.schema(), indent=1))
        return written

    @classmethod
    def read(cls, directory: Path) -> "Tables":
        """The tables `write` wrote into `directory` (declarations from schema.json; each frame
        read when first used: a cached re-run that copies the files and reuses its figures and
        recordings reads none, and does not import pandas)."""
        tables = cls(frames=_FramesOnDisk(directory))
        for name, doc in json.loads((directory / "schema.json").read_text()).items():
            table = TableSpec(name, doc["row"], tuple(Column(c["name"], c["unit"], c["definition"]) for c in doc["columns"]),
                              doc["description"])
            tables.specs[name] = table
            tables.frames[name] = None
        tables.source = directory
        return tables

    def schema(self) -> dict[str, Any]:
        return {name: {"row": s.row, "description": s.description, "rows": int(len(self.frames[name])),
                       "columns": [{"name": c.name, "unit": c.unit, "definition": c.definition} for c in s.columns]}
                for name, s in self.specs.items()}

    def index_markdown(self) -> str:
        lines = ["# Tables", "", "Every number of this run, one Parquet file per table (`pandas.read_parquet`), with a "
                 f"CSV twin when the table has at most {CSV_CELLS:,} cells. Units and definitions below are also in each "
                 "Parquet file's field metadata.", ""]
        for name, s in self.specs.items():
            lines += [f"## `{name}` ({len(self.frames[name]):,} rows)", "", f"One row per {s.row}." +
                      (f" {s.description}" if s.description else ""), "", "| column | unit | definition |", "|---|---|---|"]
            lines += [f"| `{c.name}` | {c.unit} | {c.definition} |" for c in s.columns]
            lines.append("")
        return "\n".join(lines)


class _FramesOnDisk(dict):
    """name -> DataFrame, each read from `directory/<name>.parquet` on first access (None until then)."""

    def __init__(self, directory: Path):
        super().__init__()
        self.directory = directory

    def __getitem__(self, name: str):
        frame = super().__getitem__(name)
        if frame is None:
            import pandas as pd

            frame = pd.read_parquet(self.directory / f"{name}.parquet")
            super().__setitem__(name, frame)
        return frame

    def get(self, name: str, default=None):
        return self[name] if name in self else default

    def values(self):
        return [self[name] for name in self]

    def items(self):
        return [(name, self[name]) for name in self]


def _copy_tree(source: Path, target: Path) -> list[Path]:
    """Copy every file of `source` into `target` (copies, not links: a user editing an output
    file must not change the cache it came from)."""
    import shutil

    out = []
    for path in sorted(source.rglob("*")):
        if path.is_file():
            dest = target / path.relative_to(source)
            dest.parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(path, dest)
            out.append(dest)
    return out


def arrow_table(s: TableSpec, frame):
    """The frame as an Arrow table carrying its declaration: each field's unit and definition, the
    table's row meaning and description in the schema metadata."""
    import pyarrow as pa

    table = pa.Table.from_pandas(frame, preserve_index=False)
    fields = [table.schema.field(c.name).with_metadata({"unit": c.unit, "definition": c.definition}) for c in s.columns]
    meta = dict(table.schema.metadata or {})
    meta.update({b"dse.row": s.row.encode(), b"dse.description": s.description.encode()})
    return table.cast(pa.schema(fields, metadata=meta))


def _write_parquet(s: TableSpec, frame, path: Path) -> None:
    import pyarrow.parquet as pq

    pq.write_table(arrow_table(s, frame), path, compression="zstd")


def write_arrow_file(s: TableSpec, frame, path: Path) -> None:
    """The Arrow IPC file format, uncompressed: for internal stores written and read once per sweep point
    (a few hundred microseconds where Parquet with compression takes milliseconds)."""
    import pyarrow as pa

    table = arrow_table(s, frame)
    with pa.OSFile(str(path), "wb") as sink, pa.ipc.new_file(sink, table.schema) as writer:
        writer.write_table(table)


def read_arrow_file(path: Path):
    import pyarrow as pa

    with pa.OSFile(str(path), "rb") as source:         # read into memory (no mapping outlives the file)
        return pa.ipc.open_file(source).read_all()


def read_table(path: Path):
    """A table written by `Tables.write` with its declaration: (DataFrame, {column: (unit, definition)})."""
    import pyarrow.parquet as pq

    t = pq.read_table(path)
    docs = {f.name: ((f.metadata or {}).get(b"unit", b"").decode(), (f.metadata or {}).get(b"definition", b"").decode())
            for f in t.schema}
    return t.to_pandas(), docs


def matrix_rows(matrix: np.ndarray, **keys) -> list[dict[str, Any]]:
    """One row per entry of a matrix: keys..., row, col, value."""
    m = np.atleast_2d(np.asarray(matrix, float))
    return [{**keys, "row": i, "col": j, "value": float(m[i, j])} for i in range(m.shape[0]) for j in range(m.shape[1])]


def records(rows: Iterable[Mapping[str, Any]]) -> list[dict[str, Any]]:
    return [dict(r) for r in rows]
