"""Sweep files: a base scenario, the fields to vary, and the points they expand to.

A sweep file (TOML) names a base scenario of any family and the scenario fields to vary::

    name = "savas-noise"               # output goes to OUT/sweep/<name>/
    base = "../savas/paper.toml"       # relative to the sweep file (or an inline [scenario] table)
    seed = 0                           # the sweep's root seed
    replicates = 2                     # independent seeds per parameter point
    quick = false                      # RunOptions.quick of every point
    trials = 5000                      # optional RunOptions.trials of every point
    tables = ["nodes", "claims"]       # optional: the point tables gathered in OUT/sweep/<name>/tables/
                                       # (default: every table of every point; [] for none)
    claims = ["mc.trace", "thm1.*"]    # optional: the claims each point checks, by id without the run's
                                       # name (shell patterns; default: every claim; [] for none)
    metrics = ["carli_trP_mc"]         # optional: the family metrics kept per point (default: every one;
                                       # [] for none: the family's tables are then built only for `tables`)

    [set]                              # fixed overrides applied to every point
    "monte_carlo.trials" = 5000

    [grid]                             # cartesian product, in the order written
    "sweep.sigma_c" = [[0.5], [1.0], [2.0]]
    "graph.n" = [3, 5, 8]

    [random]                           # `samples` draws, crossed with the grid
    samples = 10
    "model.r" = { uniform = [1.0, 50.0] }      # also log_uniform, integers (inclusive), choice

    [plot]
    x = "graph.n"                      # default: the first numeric grid field
    log_x = false
    metrics = ["tr_P"]                 # default: every metric of the family (a name no point has is refused)
    cells = ["m", "sigma_c"]           # optional: columns of the points' `metrics` table that index cells of
                                       # one point (a scenario that computes several m, say); x may be one
    table = "estimators"               # optional, with `rows`: the metrics of a point are also read from this
    rows = "estimator"                 # table of it, one row per value of `rows`: `<row>.<column>`

With `plot.cells`, one point holds several cells (savas's `sweep.rounds` list, tanwani's `communication.rates`,
computed on one shared design) and the figure has a row per (point, cell): the network-wide rows of each
point's `metrics` table, by metric, a row without cell values (the centralized filter's, say) repeated
for every cell of its point; one curve per value of the other cells and grid fields. With `plot.table`
and `plot.rows`, each row of that table of a point adds its numeric columns to the point's metrics, named
`<value of rows>.<column>` (compare's `estimators` table: `gikf.network_mse_mc` and its `_se`).

A point computes only what the sweep asks for: the claims `claims` names (and the hypotheses they rest
on; the family-wise confidence is shared among the statistical claims checked), the tables `tables` names
and the metrics `metrics` names (the family's tables are not built at all when neither needs them).

A field is a dotted path into the scenario (``sensors.0.V`` indexes a list). Its parent must
exist in the base scenario; the leaf may be new (an optional field left at its default).
Every point's seed is derived from the sweep's seed, the point's values and its replicate,
so a point has the same seed whatever else the sweep contains and wherever it runs.
`dse sweep --seed/--trials/--quick` replace the file's `seed`, `trials` and `quick` (`with_options`).
"""
from __future__ import annotations

import copy
import dataclasses
import hashlib
import itertools
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from dse.engine.cache import canonical_json
from dse.errors import ScenarioError
from dse.scenario.fields import as_float, as_int, as_list, as_str, load_toml, reject_unknown, section

#: the largest sweep accepted (each point is one task and one result file)
MAX_POINTS = 100_000
DISTRIBUTIONS = ("uniform", "log_uniform", "integers", "choice")
TOP_LEVEL = ("name", "description", "base", "scenario", "seed", "replicates", "quick", "trials", "tables",
             "claims", "metrics", "set", "grid", "random", "plot")


@dataclass(frozen=True)
class Point:
    """One task of a sweep: the varied values, its replicate number and its derived seed."""

    index: int
    values: dict[str, Any]
    replicate: int
    seed: int


@dataclass(frozen=True)
class SweepSpec:
    """A parsed sweep file (see the module docstring); `source` is the file's table as read."""

    name: str
    description: str
    base: dict[str, Any]
    seed: int
    replicates: int
    quick: bool
    trials: int | None
    fixed: dict[str, Any]
    grid: dict[str, list[Any]]
    random: dict[str, tuple[str, list[Any]]]
    samples: int
    plot_x: str | None
    log_x: bool
    plot_metrics: tuple[str, ...] | None
    tables: tuple[str, ...] | None = None
    plot_cells: tuple[str, ...] = ()
    plot_table: tuple[str, str] | None = None
    claims: tuple[str, ...] | None = None
    metrics: tuple[str, ...] | None = None
    source: dict[str, Any] = field(repr=False, compare=False, default_factory=dict)

    @property
    def fields(self) -> list[str]:
        """The varied fields, grid first, in the order written."""
        return list(self.grid) + list(self.random)

    @property
    def family(self) -> str:
        return str(self.base.get("family", ""))

    def points(self) -> list[Point]:
        """Grid × random samples × replicates, in a fixed order."""
        grid_rows = [dict(zip(self.grid, combo)) for combo in itertools.product(*self.grid.values())]
        random_rows = self._random_rows()
        out = []
        for g in grid_rows:
            for r in random_rows:
                values = {**g, **r}
                for rep in range(self.replicates):
                    out.append(Point(len(out), values, rep, point_seed(self.seed, values, rep)))
        return out

    def _random_rows(self) -> list[dict[str, Any]]:
        if not self.random:
            return [{}]
        rng = np.random.Generator(np.random.SFC64(np.random.SeedSequence(self.seed, spawn_key=(0x5EED,))))
        rows = [{} for _ in range(self.samples)]
        for name, (dist, args) in self.random.items():
            draws = _draw(rng, dist, args, self.samples)
            for row, v in zip(rows, draws):
                row[name] = v
        return rows

    def scenario(self, point: Point) -> dict[str, Any]:
        """The base scenario with the fixed overrides and the point's values applied."""
        data = copy.deepcopy(self.base)
        for path, value in {**self.fixed, **point.values}.items():
            set_field(data, path, value)
        return data


def with_options(spec: SweepSpec, *, seed: int | None = None, trials: int | None = None,
                 quick: bool = False) -> SweepSpec:
    """The sweep with the command line's options applied to every point: `seed` replaces the sweep's root
    seed, `trials` its trials, `quick=True` its quick; the source is updated too, so that sweep.json (and
    `dse verify`) describe the sweep that ran."""
    changes = {k: v for k, v in (("seed", seed), ("trials", trials), ("quick", quick or None)) if v is not None}
    return dataclasses.replace(spec, **changes, source={**spec.source, **changes}) if changes else spec


def point_seed(sweep_seed: int, values: Mapping[str, Any], replicate: int) -> int:
    """A 63-bit seed that depends only on the sweep seed, the point's values and the replicate."""
    digest = hashlib.sha256(canonical_json({"seed": sweep_seed, "values": dict(values), "replicate": replicate}).encode())
    return int.from_bytes(digest.digest()[:8], "little") >> 1


def _draw(rng: np.random.Generator, dist: str, args: list[Any], n: int) -> list[Any]:
    if dist == "uniform":
        return [float(x) for x in rng.uniform(args[0], args[1], n)]
    if dist == "log_uniform":
        return [float(x) for x in np.exp(rng.uniform(math.log(args[0]), math.log(args[1]), n))]
    if dist == "integers":
        return [int(x) for x in rng.integers(args[0], args[1], n, endpoint=True)]
    return [args[int(i)] for i in rng.integers(0, len(args), n)]


# -- dotted field paths ----------------------------------------------------------------------------------

def set_field(data: dict[str, Any], path: str, value: Any) -> None:
    """Set `path` (dotted; integer parts index lists) in `data`; the parent must exist."""
    parts = path.split(".")
    node: Any = data
    for depth, part in enumerate(parts[:-1]):
        node = _child(node, part, ".".join(parts[:depth + 1]), path)
    leaf = parts[-1]
    if isinstance(node, list):
        index = _index(node, leaf, path)
        node[index] = copy.deepcopy(value)
    elif isinstance(node, dict):
        node[leaf] = copy.deepcopy(value)
    else:
        raise ScenarioError(path, f"'{'.'.join(parts[:-1])}' is a value, not a table or list, in the base scenario")


def _child(node: Any, part: str, prefix: str, path: str) -> Any:
    if isinstance(node, dict):
        if part not in node:
            raise ScenarioError(path, f"the base scenario has no '{prefix}'")
        return node[part]
    if isinstance(node, list):
        return node[_index(node, part, path)]
    raise ScenarioError(path, f"'{prefix}' goes below a value of the base scenario")


def _index(node: list, part: str, path: str) -> int:
    if not part.lstrip("-").isdigit() or not -len(node) <= int(part) < len(node):
        raise ScenarioError(path, f"'{part}' is not an index of a list of {len(node)} items")
    return int(part)


def _flatten(table: Mapping[str, Any], prefix: str, is_leaf) -> dict[str, Any]:
    """Nested TOML tables (``[grid.graph] n = [...]``) and quoted dotted keys mean the same path."""
    out: dict[str, Any] = {}
    for key, value in table.items():
        path = f"{prefix}.{key}" if prefix else str(key)
        if isinstance(value, dict) and not is_leaf(value):
            out.update(_flatten(value, path, is_leaf))
        else:
            out[path] = value
    return out


# -- reading a sweep file ----------------------------------------------------------------------------------

def load_sweep(path: str | Path) -> SweepSpec:
    path = Path(path)
    data = load_toml(path)
    if "family" in data and not {"base", "scenario", "grid", "random"} & set(data):
        raise ScenarioError(str(path), f"is a scenario file (family = {data['family']!r}), not a sweep file: run it "
                                       f"with `dse run {path}`, or name it as `base` of a sweep file")
    return parse_sweep(data, base_dir=path.parent)


def parse_sweep(data: Mapping[str, Any], *, base_dir: Path) -> SweepSpec:
    reject_unknown(data, TOP_LEVEL)
    name = as_str(data.get("name"), "name")
    if not name or not all(c.isalnum() or c in "-_." for c in name) or name.startswith("."):
        raise ScenarioError("name", f"must be a non-empty name of letters, digits, '-', '_' or '.', got {name!r}")
    base = _base(data, base_dir)
    seed = as_int(data.get("seed", 0), "seed", low=0)
    replicates = as_int(data.get("replicates", 1), "replicates", low=1, high=10_000)
    quick = data.get("quick", False)
    if not isinstance(quick, bool):
        raise ScenarioError("quick", f"must be true or false, got {quick!r}")
    trials = None if data.get("trials") is None else as_int(data["trials"], "trials", low=1, high=10**9)
    tables, claims, metrics = (_names(data, key) for key in ("tables", "claims", "metrics"))
    fixed = _flatten(section(data["set"], "set") if "set" in data else {}, "", lambda v: False)
    grid = _grid(data)
    random, samples = _random(data)
    overlap = (set(grid) & set(random)) | (set(fixed) & (set(grid) | set(random)))
    if overlap:
        raise ScenarioError(sorted(overlap)[0], "is set or varied twice (in more than one of [set], [grid], [random])")
    n_points = math.prod(len(v) for v in grid.values()) * (samples if random else 1) * replicates
    if n_points > MAX_POINTS:
        raise ScenarioError("grid", f"the sweep has {n_points:,} points; at most {MAX_POINTS:,} are allowed")
    plot = section(data["plot"], "plot") if "plot" in data else {}
    reject_unknown(plot, ("x", "log_x", "metrics", "cells", "table", "rows"), "plot")
    plot_table = _plot_table(plot, tables)
    cells = _names(plot, "cells", "plot.") or ()
    if cells and tables is not None and "metrics" not in tables:
        raise ScenarioError("plot.cells", "the cells are read from the points' `metrics` table: add \"metrics\" to "
                                          "`tables`")
    plot_x = None if plot.get("x") is None else as_str(plot["x"], "plot.x", list(grid) + list(random) + list(cells))
    log_x = plot.get("log_x", False)
    if not isinstance(log_x, bool):
        raise ScenarioError("plot.log_x", f"must be true or false, got {log_x!r}")
    plot_metrics = None if plot.get("metrics") is None else tuple(
        as_str(m, f"plot.metrics[{i}]") for i, m in enumerate(as_list(plot["metrics"], "plot.metrics")))
    if metrics is not None and plot_metrics is not None and set(plot_metrics) - set(metrics):
        raise ScenarioError("plot.metrics", f"{', '.join(sorted(set(plot_metrics) - set(metrics)))}: not among the "
                                            f"metrics the points keep (metrics = {list(metrics)})")
    spec = SweepSpec(name=name, description=str(data.get("description", "")), base=base, seed=seed,
                     replicates=replicates, quick=quick, trials=trials, fixed=fixed, grid=grid, random=random,
                     samples=samples, plot_x=plot_x, log_x=log_x, plot_metrics=plot_metrics, tables=tables,
                     plot_cells=cells, plot_table=plot_table, claims=claims, metrics=metrics, source=dict(data))
    for path, value in fixed.items():  # check the overrides' paths once, before any point runs
        set_field(copy.deepcopy(base), path, value)
    return spec


def _names(data: Mapping[str, Any], key: str, where: str = "") -> tuple[str, ...] | None:
    """A list of names (`tables`, `claims`, `metrics`, `plot.cells`): None when the key is absent (everything)."""
    if key not in data:
        return None
    name = f"{where}{key}"
    return tuple(as_str(t, f"{name}[{i}]") for i, t in enumerate(as_list(data[key], name, min_len=0)))


def _plot_table(plot: Mapping[str, Any], tables: tuple[str, ...] | None) -> tuple[str, str] | None:
    """`plot.table` and `plot.rows` (both or neither); the table must be one the points keep."""
    if "table" not in plot and "rows" not in plot:
        return None
    if "table" not in plot or "rows" not in plot:
        raise ScenarioError("plot.table", "give both `table` (a table of the points) and `rows` (its column whose "
                                          "values name the metrics), or neither")
    table, rows = as_str(plot["table"], "plot.table"), as_str(plot["rows"], "plot.rows")
    if tables is not None and table not in tables:
        raise ScenarioError("plot.table", f"{table!r} is not among the tables the points keep: add it to `tables`")
    return table, rows


def _base(data: Mapping[str, Any], base_dir: Path) -> dict[str, Any]:
    if ("base" in data) == ("scenario" in data):
        raise ScenarioError("base", "give exactly one of `base = \"FILE.toml\"` or an inline [scenario] table")
    if "scenario" in data:
        base = dict(section(data["scenario"], "scenario"))
    else:
        base_path = Path(as_str(data["base"], "base"))
        resolved = base_path if base_path.is_absolute() else base_dir / base_path
        try:
            base = load_toml(resolved)
        except ScenarioError as exc:
            raise ScenarioError("base", f"{str(base_path)!r} (resolved against the sweep file's folder: "
                                        f"{resolved.resolve()}): {exc.reason}") from None
    if "family" not in base:
        raise ScenarioError("base.family", "the base scenario names no family")
    return base


def _grid(data: Mapping[str, Any]) -> dict[str, list[Any]]:
    grid = _flatten(section(data["grid"], "grid") if "grid" in data else {}, "", lambda v: False)
    for path, values in grid.items():
        values = as_list(values, f"grid.{path}")
        if len(values) > MAX_POINTS:
            raise ScenarioError(f"grid.{path}", f"has {len(values):,} values; at most {MAX_POINTS:,}")
        if len({canonical_json(v) for v in values}) != len(values):
            raise ScenarioError(f"grid.{path}", "lists a value twice")
        grid[path] = values
    return grid


def _random(data: Mapping[str, Any]) -> tuple[dict[str, tuple[str, list[Any]]], int]:
    if "random" not in data:
        return {}, 0
    table = dict(section(data["random"], "random"))
    samples = as_int(table.pop("samples", None), "random.samples", low=1, high=MAX_POINTS)
    is_dist = lambda v: bool(v) and set(v) <= set(DISTRIBUTIONS)  # noqa: E731
    fields = _flatten(table, "", is_dist)
    if not fields:
        raise ScenarioError("random", "names no field to sample")
    out = {}
    for path, spec in fields.items():
        where = f"random.{path}"
        if not isinstance(spec, dict) or len(spec) != 1 or not is_dist(spec):
            raise ScenarioError(where, f"must be one of {{{' | '.join(f'{d} = [...]' for d in DISTRIBUTIONS)}}}")
        (dist, args), = spec.items()
        args = as_list(args, f"{where}.{dist}")
        if dist == "choice":
            out[path] = (dist, args)
            continue
        if len(args) != 2:
            raise ScenarioError(f"{where}.{dist}", f"must be [low, high], got {args!r}")
        if dist == "integers":
            low, high = (as_int(a, f"{where}.{dist}") for a in args)
        else:
            low, high = (as_float(a, f"{where}.{dist}", low=0.0 if dist == "log_uniform" else None,
                                  low_open=dist == "log_uniform") for a in args)
        if not low < high if dist != "integers" else not low <= high:
            raise ScenarioError(f"{where}.{dist}", f"low must be below high, got [{low}, {high}]")
        out[path] = (dist, [low, high])
    return out, samples
