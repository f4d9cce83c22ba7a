"""A table of a run as the site shows it: its declaration (row meaning, each column's unit and
definition, read from the Parquet metadata) and its first rows for the browser.

A table's page holds at most `BROWSE_ROWS` rows (a browser sorts and filters a few thousand rows
at once; the largest tables have millions): the first ones, or of a table of several scenarios the
first ones of each. Every table is downloadable in full as Parquet, and as
CSV when the run wrote its CSV twin (tables of at most 20,000 cells, docs/output.md); the page's
"CSV of these rows" button saves the rows it holds.
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

#: the most rows one table page holds
BROWSE_ROWS = 5000


@dataclass
class TableView:
    """What a table page and the run page show of one table."""

    name: str
    row: str
    description: str
    columns: list[dict[str, str]]          # name, unit, definition, type ("number" or "string")
    num_rows: int
    rows: list[list[Any]] = field(default_factory=list)
    scenarios: list[str] = field(default_factory=list)   # the values of its `scenario` column
    csv: str | None = None                  # file name of the CSV twin, when there is one
    folder: str = "tables/"                 # where the page finds the Parquet and CSV files
    per_scenario: bool = False              # the rows shown are the first ones of each scenario

    @property
    def complete(self) -> bool:
        return len(self.rows) >= self.num_rows

    def data_json(self) -> str:
        """The rows as JSON safe to place inside a <script> element."""
        return json.dumps({"columns": self.columns, "rows": self.rows}, separators=(",", ":")).replace("</", "<\\/")


def _column_values(column) -> list[Any]:
    """A column's values as JSON can carry them: non-finite floats as their names ("nan", "inf", "-inf")."""
    import numpy as np
    import pyarrow.types as pt

    if pt.is_floating(column.type):
        values = column.to_numpy(zero_copy_only=False)
        out = values.tolist()
        for i in np.flatnonzero(~np.isfinite(values)):
            out[i] = "nan" if np.isnan(values[i]) else ("inf" if values[i] > 0 else "-inf")
        return out
    if pt.is_integer(column.type) or pt.is_boolean(column.type) or pt.is_string(column.type) or pt.is_large_string(column.type):
        return column.to_pylist()
    return [None if v is None else str(v) for v in column.to_pylist()]


def _scenarios(path: Path) -> list[str]:
    """The distinct values of a table's `scenario` column (read as a dictionary: its values are the distinct ones)."""
    import pyarrow.parquet as pq

    column = pq.read_table(path, columns=["scenario"], read_dictionary=["scenario"]).column(0)
    values: set = set()
    for chunk in column.chunks:
        values.update(chunk.dictionary.to_pylist() if hasattr(chunk, "dictionary") else chunk.unique().to_pylist())
    return sorted(str(v) for v in values if v is not None)


def _is_number(arrow_type) -> bool:
    import pyarrow.types as pt

    return pt.is_integer(arrow_type) or pt.is_floating(arrow_type)


def _meta(metadata, key: bytes) -> str:
    return (metadata or {}).get(key, b"").decode()


def _head(handle):
    """The table's first `BROWSE_ROWS` rows."""
    import pyarrow as pa

    first = next(handle.iter_batches(batch_size=BROWSE_ROWS), None)
    return pa.Table.from_batches([first], schema=first.schema) if first is not None else handle.schema_arrow.empty_table()


def _head_per_scenario(path: Path, scenarios: list[str]):
    """The first rows of every scenario (`BROWSE_ROWS` in all, shared equally), in the table's order: a claim's
    link to its scenario's rows finds some whatever the scenario's place in a large table."""
    import numpy as np
    import pyarrow.compute as pc
    import pyarrow.parquet as pq

    table = pq.read_table(path)
    column = table.column("scenario")
    per = max(1, BROWSE_ROWS // len(scenarios))
    picks = [pc.indices_nonzero(pc.equal(column, s)).to_numpy()[:per] for s in scenarios]
    return table.take(np.sort(np.concatenate(picks)))


def read_view(path: Path) -> TableView:
    """The declaration of the Parquet table at `path` and at most `BROWSE_ROWS` of its rows: all of them, or the
    first ones, or for a table of several scenarios the first ones of each scenario."""
    import pyarrow.parquet as pq

    handle = pq.ParquetFile(path)
    schema = handle.schema_arrow
    columns = [{"name": f.name, "unit": _meta(f.metadata, b"unit"), "definition": _meta(f.metadata, b"definition"),
                "type": "number" if _is_number(f.type) else "string"} for f in schema]
    scenarios = _scenarios(path) if "scenario" in schema.names else []
    num_rows = handle.metadata.num_rows
    per_scenario = num_rows > BROWSE_ROWS and len(scenarios) > 1
    shown = _head_per_scenario(path, scenarios) if per_scenario else _head(handle)
    rows = [list(row) for row in zip(*(_column_values(c) for c in shown.columns))]
    csv = path.with_suffix(".csv")
    return TableView(name=path.stem, row=_meta(schema.metadata, b"dse.row"),
                     description=_meta(schema.metadata, b"dse.description"), columns=columns,
                     num_rows=num_rows, rows=rows, scenarios=scenarios, csv=csv.name if csv.exists() else None,
                     per_scenario=per_scenario)
