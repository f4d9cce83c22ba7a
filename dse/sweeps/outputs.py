"""A sweep's outputs: the results table (Parquet), a figure and a recording.

`results.parquet` holds one row per point: the varied values, replicate and seed, the
run's status, verdict counts, the family's summary metrics (``metric:<name>``) and, for
every claim, its verdict, margin, measured and reference numbers (``claim:<id>:<field>``).
`claims.parquet` holds one row per (point, claim) with the claim's source and statement and
every field of its verdict, the detail text included. Neither holds wall times or host names, so both are identical
wherever the points ran; those go to `sweep.json`.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

import numpy as np
import pandas as pd
import rerun.blueprint as rrb

from dse.outputs import record
from dse.engine.atomic import atomic_path
from dse.outputs.figures import new_figure, save_figure, sequential_colors
from dse.sweeps.spec import SweepSpec
from dse.errors import ScenarioError
from dse.verify.rules import STATUSES

STATUS_COUNTS = STATUSES
CLAIM_COLUMNS = ("verdict", "margin", "measured", "reference")
MAX_PLOTTED_METRICS = 6
#: more curves than this and the viewer's legend would cover the plot: the names show on hover
MAX_LEGEND_ENTRIES = 8


def number(x: Any) -> float:
    """A claim's headline number as a float (NaN when it is not one number)."""
    if isinstance(x, bool):
        return float(x)
    if isinstance(x, (int, float)):
        return float(x)
    if isinstance(x, str):
        try:
            return float(x)  # "inf", "-inf", "nan" as written by the verdict rows
        except ValueError:
            return math.nan
    return math.nan


def cell(value: Any) -> Any:
    """A varied value as a table cell: scalars as they are, anything else as canonical JSON."""
    if isinstance(value, (bool, int, float, str)):
        return value
    return json.dumps(value, sort_keys=True)


def plot_value(value: Any) -> float | None:
    """The number a varied value is plotted at: a number, or a list holding one number."""
    while isinstance(value, list) and len(value) == 1:
        value = value[0]
    if isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, (bool, np.bool_)):
        return float(value)
    return None


def results_frame(spec: SweepSpec, points: Sequence, results: Sequence[dict[str, Any]]) -> pd.DataFrame:
    """One row per point, in point order (see the module docstring for the columns)."""
    rows = []
    for point, res in zip(points, results):
        row: dict[str, Any] = {"point": point.index, "replicate": point.replicate, "seed": point.seed}
        row.update({f: cell(point.values[f]) for f in spec.fields})
        row["status"], row["error"] = res["status"], res["error"]
        for s in STATUS_COUNTS:
            row[s] = sum(c["verdict"] == s for c in res["claims"])
        row.update({f"metric:{k}": v for k, v in sorted(res["metrics"].items())})
        for c in res["claims"]:
            row[f"claim:{c['id']}:verdict"] = c["verdict"]
            for k in CLAIM_COLUMNS[1:]:
                row[f"claim:{c['id']}:{k}"] = number(c.get(k))
        rows.append(row)
    frame = pd.DataFrame(rows)
    for col in frame.columns:  # a column mixing strings and numbers is stored as strings
        kinds = {type(v) for v in frame[col] if v is not None and not (isinstance(v, float) and math.isnan(v))}
        if str in kinds and len(kinds) > 1:
            frame[col] = frame[col].map(lambda v: None if v is None else str(v))
    return frame


def table_metrics(spec: SweepSpec, frame: pd.DataFrame, results: Sequence[dict[str, Any]]) -> pd.DataFrame:
    """With `plot.table` and `plot.rows`, `frame` with each point's rows of that table as metrics
    ``metric:<row>.<column>`` (its numeric columns); else `frame` itself."""
    from dse.outputs.tables import read_arrow_file

    if spec.plot_table is None:
        return frame
    name, rows = spec.plot_table
    extra = []
    for res in results:
        path = res.get("table_files", {}).get(name)
        t = read_arrow_file(path).to_pandas() if path is not None else pd.DataFrame()
        if len(t) and rows not in t:
            raise ScenarioError("plot.rows", f"{rows!r} is not a column of the points' {name} table (its columns "
                                             f"are {', '.join(map(str, t.columns))})")
        repeated = t[rows].duplicated() if len(t) else pd.Series(dtype=bool)
        if repeated.any():
            raise ScenarioError("plot.rows", f"{rows} = {t.loc[repeated, rows].iloc[0]!r} names several rows of a "
                                             f"point's {name} table: choose a column with one row per value")
        numeric = [c for c in t.columns if c != rows and pd.api.types.is_numeric_dtype(t[c])
                   and not pd.api.types.is_bool_dtype(t[c])]
        extra.append({f"metric:{r[rows]}.{c}": float(r[c]) for _, r in t.iterrows() for c in numeric})
    return pd.concat([frame.reset_index(drop=True), pd.DataFrame(extra, index=range(len(frame)))], axis=1)


def cell_frame(spec: SweepSpec, frame: pd.DataFrame, results: Sequence[dict[str, Any]]) -> pd.DataFrame:
    """With `plot.cells`, the figure's rows: one per (point, cell), the point's columns (varied values,
    verdict counts) followed by each network-wide metric of the cell as ``metric:<name>``; a metric without
    cell values is the point's and is repeated for each of its cells. Without `plot.cells`, `frame` itself."""
    from dse.outputs.tables import read_arrow_file

    if not spec.plot_cells:
        return frame
    cells, parts = list(spec.plot_cells), []
    for (_, row), res in zip(frame.iterrows(), results):
        path = res.get("table_files", {}).get("metrics")
        if path is None:
            continue
        t = read_arrow_file(path).to_pandas()
        t = t[t["node"].isna()] if "node" in t else t
        missing = [c for c in cells if c not in t.columns]
        if missing:
            raise ScenarioError("plot.cells", f"{', '.join(missing)}: not a column of the points' metrics table "
                                              f"(its columns are {', '.join(map(str, t.columns))})")
        own = t[cells].isna().all(axis=1)
        wide = t[~own].pivot_table(index=cells, columns="metric", values="value", aggfunc="first").reset_index()
        for m, v in zip(t.loc[own, "metric"], t.loc[own, "value"]):
            wide[m] = v
        wide = wide.rename(columns={m: f"metric:{m}" for m in wide.columns if m not in cells})
        keep = row.drop([c for c in row.index if str(c).startswith(("metric:", "claim:"))])
        parts.append(wide.assign(**{str(k): v for k, v in keep.items()}))
    if not parts:
        return frame.iloc[0:0]
    return pd.concat(parts, ignore_index=True)


def claims_frame(points: Sequence, results: Sequence[dict[str, Any]]) -> pd.DataFrame:
    """One row per (point, claim) with every field of the verdict."""
    rows = []
    for point, res in zip(points, results):
        for c in res["claims"]:
            rows.append({"point": point.index, "claim": c["id"], "source": c.get("source", ""),
                         "statement": c.get("statement", ""), "kind": c["kind"], "verdict": c["verdict"],
                         "measured": number(c.get("measured")), "reference": number(c.get("reference")),
                         "margin": number(c.get("margin")), "tolerance": number(c.get("tolerance")),
                         "confidence": number(c.get("confidence")), "trials": number(c.get("trials")),
                         "measured_json": json.dumps(c.get("measured"), default=str),
                         "reference_json": json.dumps(c.get("reference"), default=str),
                         "printed_json": json.dumps(c.get("printed"), default=str),
                         "corrected_json": json.dumps(c.get("corrected"), default=str),
                         "detail": str(c.get("detail") or "")})
    columns = ["point", "claim", "source", "statement", "kind", "verdict", "measured", "reference", "margin",
               "tolerance", "confidence", "trials", "measured_json", "reference_json", "printed_json", "corrected_json",
               "detail"]
    return pd.DataFrame(rows, columns=columns)


def write_parquet(frame: pd.DataFrame, path: Path) -> None:
    with atomic_path(path) as tmp:
        frame.to_parquet(tmp, index=False, engine="pyarrow", compression="zstd")


# -- what is plotted ---------------------------------------------------------------------------------------

LINE_STYLES = ("-", "--", ":", "-.")


@dataclass(frozen=True)
class Group:
    """The points of one curve: `name` for legends, `colour` indexes the values of the first
    other grid field, `style` the combinations of the remaining ones."""

    colour_label: str
    style_label: str
    mask: np.ndarray
    colour: int
    style: int

    @property
    def name(self) -> str:
        return ", ".join(x for x in (self.colour_label, self.style_label) if x)


@dataclass(frozen=True)
class PlotPlan:
    """x: the varied field on the horizontal axis (None: the point index); groups: one curve per
    combination of the other grid fields (colour: the first of them, line style: the rest);
    metrics: the columns plotted."""

    x: str | None
    x_label: str
    others: list[str]
    groups: list[Group]
    metrics: list[str]
    scatter: bool
    unknown_metrics: list[str]


def plot_plan(spec: SweepSpec, frame: pd.DataFrame) -> PlotPlan:
    """What `frame` (the results, or with `plot.cells` the cell frame) is drawn as."""
    axes = spec.fields + list(spec.plot_cells)
    numeric = [f for f in axes if all(plot_value(v) is not None for v in _raw(spec, frame, f))]
    x = spec.plot_x or next((f for f in spec.grid if f in numeric), None) or (numeric[0] if numeric else None)
    if x is not None and x not in numeric:
        x = None
    others = [c for c in spec.plot_cells if c != x and c in frame and frame[c].nunique(dropna=False) > 1]
    others += [f for f in spec.grid if f != x and len(spec.grid[f]) > 1]
    groups = []
    if others:
        first = (others[0] + "=" + frame[others[0]].astype(str)).to_numpy()
        rest = np.array(["; ".join(f"{f}={row[f]}" for f in others[1:]) for _, row in frame[others[1:]].astype(str).iterrows()]
                        if len(others) > 1 else [""] * len(frame), dtype=object)
        colour_of = {v: i for i, v in enumerate(dict.fromkeys(first))}
        style_of = {v: i for i, v in enumerate(dict.fromkeys(rest))}
        for a, b in dict.fromkeys(zip(first, rest)):
            groups.append(Group(a, b, (first == a) & (rest == b), colour_of[a], style_of[b]))
    else:
        groups = [Group("all points", "", np.ones(len(frame), bool), 0, 0)]
    available = [c.removeprefix("metric:") for c in frame.columns if c.startswith("metric:")]
    wanted = list(spec.plot_metrics) if spec.plot_metrics else available[:MAX_PLOTTED_METRICS]
    metrics = [f"metric:{m}" for m in wanted if m in available] + ["pass fraction"]
    return PlotPlan(x=x, x_label=x or "point", others=others, groups=groups, metrics=metrics, scatter=x in spec.random,
                    unknown_metrics=[m for m in wanted if m not in available])


def _raw(spec: SweepSpec, frame: pd.DataFrame, field: str) -> list[Any]:
    return [json.loads(v) if isinstance(v, str) and v[:1] in "[{" else v for v in frame[field]] if field in frame else []


def x_values(spec: SweepSpec, frame: pd.DataFrame, plan: PlotPlan) -> np.ndarray:
    if plan.x is None:
        return frame["point"].to_numpy(float)
    return np.array([plot_value(v) for v in _raw(spec, frame, plan.x)], float)


def metric_values(frame: pd.DataFrame, metric: str) -> np.ndarray:
    if metric == "pass fraction":
        total = frame[list(STATUS_COUNTS)].sum(axis=1).to_numpy(float)
        return np.where(total > 0, frame["pass"].to_numpy(float) / np.maximum(total, 1), np.nan)
    return frame[metric].to_numpy(float)


#: the two-sided level of the figures' confidence bands
BAND_LEVEL = 0.95


def summarise(x: np.ndarray, y: np.ndarray, se: np.ndarray | None = None, *, spread: bool = False
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Centre and 95 % confidence band of y at each x: over replicates, their mean and Student's t interval
    of it; for one value with a standard error `se` (a Monte Carlo mean), y ± z·se; else y, no band.
    `spread`: the values at an x are different random draws of other fields: their median, min and max."""
    from scipy import stats

    xs = np.unique(x[np.isfinite(x)])
    mid, lo, hi = (np.full(len(xs), np.nan) for _ in range(3))
    for i, v in enumerate(xs):
        at = (x == v) & np.isfinite(y)
        ys = y[at]
        if spread and ys.size:
            mid[i], lo[i], hi[i] = np.median(ys), ys.min(), ys.max()
            continue
        if ys.size > 1:
            half = stats.t.ppf(0.5 + BAND_LEVEL / 2, ys.size - 1) * ys.std(ddof=1) / np.sqrt(ys.size)
            mid[i] = ys.mean()
        elif ys.size == 1:
            mid[i] = ys[0]
            half = stats.norm.ppf(0.5 + BAND_LEVEL / 2) * se[at][0] if se is not None else 0.0
        else:
            continue
        lo[i], hi[i] = mid[i] - half, mid[i] + half
    return xs, mid, lo, hi


def standard_errors(frame: pd.DataFrame, metric: str) -> np.ndarray | None:
    """The standard error a metric's point carries (the metric ``<name>_se``), if any."""
    column = f"{metric}_se"
    return frame[column].to_numpy(float) if metric.startswith("metric:") and column in frame else None


def write_figure(spec: SweepSpec, frame: pd.DataFrame, plan: PlotPlan, path: Path) -> None:
    n = len(plan.metrics)
    ncols = min(n, 3)
    fig, axes = new_figure(ncols=ncols, nrows=math.ceil(n / ncols), width=4.6, height=3.4)
    colors = sequential_colors(max(g.colour for g in plan.groups) + 1)
    x = x_values(spec, frame, plan)
    for ax, metric in zip(axes.flat, plan.metrics):
        y, se = metric_values(frame, metric), standard_errors(frame, metric)
        for g in plan.groups:
            colour, style = colors[g.colour], LINE_STYLES[g.style % len(LINE_STYLES)]
            if plan.scatter:
                ax.plot(x[g.mask], y[g.mask], "o", ms=3, color=colour)
                continue
            xs, mid, lo, hi = summarise(x[g.mask], y[g.mask], None if se is None else se[g.mask],
                                        spread=bool(spec.random))
            ax.plot(xs, mid, marker="o", ls=style, ms=3, color=colour)
            if np.any(hi > lo):
                ax.fill_between(xs, lo, hi, color=colour, alpha=0.25, lw=0)
        ax.set_xlabel(plan.x_label)
        ax.set_ylabel(metric.removeprefix("metric:"))
        if spec.log_x:
            ax.set_xscale("log")
        if metric != "pass fraction" and np.all(y[np.isfinite(y)] > 0) and _spans_decades(y):
            ax.set_yscale("log")
    for ax in list(axes.flat)[n:]:
        ax.set_visible(False)
    _legends(plan, axes, colors)
    band = "" if plan.scatter else band_note(spec, frame, plan)
    rows = f"{frame['point'].nunique()} points, {len(frame)} cells" if spec.plot_cells else f"{len(frame)} points"
    fig.suptitle(f"sweep {spec.name}: {spec.family}, {rows}{band}", fontsize=10)
    save_figure(fig, path)


def band_note(spec: SweepSpec, frame: pd.DataFrame, plan: PlotPlan) -> str:
    """The figure title's words for its bands (none when no metric has one)."""
    if spec.random:
        return " (lines: median over the random samples, band: min to max)"
    kinds = []
    if any(standard_errors(frame, m) is not None for m in plan.metrics):
        kinds.append("±1.96 SE of a Monte Carlo mean")
    if spec.replicates > 1:
        kinds.append(f"Student t over {spec.replicates} replicates (lines: their mean)")
    return f"\nbands: {BAND_LEVEL:.0%} confidence, " + "; ".join(kinds) if kinds else ""


def _legends(plan: PlotPlan, axes, colors) -> None:
    """Colour key (first other field) on the first panel, line-style key (the rest) on the second."""
    from matplotlib.lines import Line2D

    if not plan.others:
        return
    firsts = {g.colour: g.colour_label for g in plan.groups}
    axes.flat[0].legend([Line2D([], [], color=colors[i], marker="o", ms=3) for i in sorted(firsts)],
                        [firsts[i] for i in sorted(firsts)], loc="best", fontsize=7)
    if len(plan.others) > 1 and len(axes.flat) > 1:
        rests = {g.style: g.style_label for g in plan.groups}
        axes.flat[1].legend([Line2D([], [], color="0.3", ls=LINE_STYLES[i % len(LINE_STYLES)]) for i in sorted(rests)],
                            [rests[i] for i in sorted(rests)], loc="best", fontsize=7)


def _spans_decades(y: np.ndarray) -> bool:
    y = y[np.isfinite(y)]
    return y.size > 1 and y.max() / y.min() > 100


# -- recording ---------------------------------------------------------------------------------------------

def x_timeline(spec: SweepSpec, plan: PlotPlan, xs: np.ndarray) -> tuple[str, int]:
    """A sequence timeline for the x axis (rerun's x axis is a timeline): the values themselves
    when they are integers, else the values (log10 of them, for log_x) times the smallest 10^d
    that keeps every distinct value distinct and their spacing to 1 %."""
    if plan.x is None:
        return "point", 0
    base = np.unique(np.log10(xs) if spec.log_x else xs)
    name = f"log10({plan.x})" if spec.log_x else plan.x
    gap = float(np.diff(base).min()) if base.size > 1 else 1.0
    for d in range(0, 7):
        ticks = np.round(base * 10**d)
        if np.all(np.abs(ticks - base * 10**d) <= 0.01 * gap * 10**d) and len(np.unique(ticks)) == base.size:
            return (name, d) if d == 0 else (f"{name} (x{10**d:g})", d)
    return f"{name} (x1e6)", 6


def write_recording(spec: SweepSpec, frame: pd.DataFrame, plan: PlotPlan, summary_md: str, path: Path) -> None:
    x = x_values(spec, frame, plan)
    finite = x[np.isfinite(x)]
    timeline, digits = x_timeline(spec, plan, finite if finite.size else np.zeros(1))
    whole = rrb.TimeAxis(view_range=rrb.TimeRange(start=rrb.TimeRangeBoundary.infinite(),
                                                  end=rrb.TimeRangeBoundary.infinite()))
    legend = rrb.PlotLegend(rrb.Corner2D.RightBottom, visible=1 < len(plan.groups) <= MAX_LEGEND_ENTRIES)
    views = [rrb.TimeSeriesView(origin=f"/metrics/{_entity(m)}", name=f"{m.removeprefix('metric:')} vs {plan.x_label}",
                                axis_x=whole, plot_legend=legend)
             for m in plan.metrics]
    colours = _group_colours(plan)
    blueprint = rrb.Blueprint(
        rrb.Tabs(rrb.Grid(*views, name="metrics"), rrb.TextDocumentView(origin="/sweep", name="sweep")),
        rrb.TimePanel(timeline=timeline, expanded=False, play_state="following"), collapse_panels=True)
    with record.recording(path, application_id="dse-sweep", recording_id=f"sweep-{spec.name}", blueprint=blueprint,
                          properties={"family": spec.family, "points": len(frame), "seed": spec.seed,
                                      "x": plan.x_label, "timeline": timeline}) as rec:
        record.log_markdown(rec, "sweep", summary_md)
        for metric in plan.metrics:
            y = metric_values(frame, metric)
            for g, group in enumerate(plan.groups):
                name, mask, colour = group.name, group.mask, colours[g]
                if plan.scatter:
                    xs, ys = x[mask], y[mask]
                    order = np.argsort(xs, kind="stable")
                    xs, ys = xs[order], ys[order]
                else:
                    xs, ys, _, _ = summarise(x[mask], y[mask], spread=bool(spec.random))
                keep = np.isfinite(xs) & np.isfinite(ys)
                if not keep.any():
                    continue
                ticks = np.round((np.log10(xs[keep]) if spec.log_x and plan.x else xs[keep]) * 10**digits)
                record.send_series(rec, f"metrics/{_entity(metric)}/g{g}", record.sequence_index(timeline, ticks.astype(np.int64)),
                                   ys[keep], names=name, colors=[colour], points=plan.scatter)


def _group_colours(plan: PlotPlan) -> list[tuple[int, int, int]]:
    """As in the figure, one hue per value of the first other grid field (the viewer's palette, which
    reads on its dark background); the combinations of the rest (line styles in the figure) are
    lighter shades of it (the viewer has no line styles)."""
    shades = max(g.style for g in plan.groups) + 1
    out = []
    for g in plan.groups:
        lighten = 0.6 * g.style / max(shades - 1, 1)
        out.append(tuple(int(round((1 - lighten) * c + lighten * 255)) for c in record.color(g.colour)))
    return out


def _entity(metric: str) -> str:
    return "".join(c if c.isalnum() or c in "_-" else "_" for c in metric.removeprefix("metric:"))


def summary_markdown(spec: SweepSpec, frame: pd.DataFrame, claims: pd.DataFrame, failures: dict[str, str]) -> str:
    """The sweep at a glance: what varied, and how often each claim got each verdict."""
    lines = [f"# sweep `{spec.name}`", "", spec.description, "",
             f"- family: `{spec.family}`; {len(frame)} points ({spec.replicates} replicate(s) each); root seed {spec.seed}",
             f"- varied: {', '.join(f'`{f}`' for f in spec.fields) or 'nothing (replicates only)'}",
             f"- fixed overrides: {', '.join(f'`{k}` = {json.dumps(v)}' for k, v in spec.fixed.items()) or 'none'}",
             f"- points with a numerical failure: {int((frame['status'] != 'ok').sum())}"
             if "status" in frame else "", f"- tasks that failed: {len(failures)}" if failures else "", ""]
    if len(claims):
        table = claims.pivot_table(index="claim", columns="verdict", values="point", aggfunc="count", fill_value=0)
        cols = [s for s in STATUS_COUNTS if s in table.columns]
        lines += ["## verdicts per claim (number of points)", "", "| claim | " + " | ".join(cols) + " |",
                  "|---|" + "---|" * len(cols)]
        lines += [f"| `{cid}` | " + " | ".join(str(int(table.loc[cid, c])) for c in cols) + " |" for cid in table.index]
    return "\n".join(line for line in lines if line is not None)


def write_point_tables(spec: SweepSpec, points: Sequence, results: Sequence[dict[str, Any]], directory: Path) -> None:
    """Each table of the points, stacked: `point` and the varied values first, then the table's own
    columns (with their units and definitions), in point order."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    from dse.outputs.tables import read_arrow_file

    names = list(dict.fromkeys(n for r in results for n in r.get("table_files", {})))
    for name in names:
        parts, schema = [], None
        for point, res in zip(points, results):
            path = res.get("table_files", {}).get(name)
            if path is None:
                continue
            t = read_arrow_file(path)
            schema = schema or t.schema
            front = {"point": pa.array([point.index] * t.num_rows, pa.int64())}
            front.update({f: pa.array([json.dumps(cell(point.values[f])) if not isinstance(cell(point.values[f]), str)
                                       else cell(point.values[f])] * t.num_rows, pa.string()) for f in spec.fields})
            parts.append(pa.Table.from_arrays([*front.values(), *t.columns],
                                              schema=pa.schema([pa.field(k, v.type, metadata={
                                                  "unit": "", "definition": "sweep point" if k == "point" else
                                                  f"value of the varied field {k} (JSON)"}) for k, v in front.items()]
                                                               + list(t.schema))))
        if parts:
            with atomic_path(directory / f"{name}.parquet") as tmp:
                pq.write_table(pa.concat_tables(parts, promote_options="permissive"), tmp, compression="zstd")
