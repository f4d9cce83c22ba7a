"""The arena's views: summary.md, the frontier figure and the recording (`outputs` module doc)."""
from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from dse.outputs import record as rec_
from dse.outputs.figures import new_figure, save_figure

#: the filter under test is drawn in this colour (RGB 0..255; in no palette the built-ins use), the built-ins in
#: the palette's
HIGHLIGHT = (255, 190, 0)
#: the recording's plane: x = log10(1 + numbers sent) and y = −log10(MSE ratio), times this (the viewer's y points down)
PLANE_SCALE = 100.0
COLUMNS = 4


def _fmt(x: Any, digits: int = 4) -> str:
    if isinstance(x, (float, np.floating)):
        return "" if not np.isfinite(x) else f"{x:.{digits}g}"
    return str(x)


def _table_md(frame: pd.DataFrame, columns: list[str]) -> str:
    lines = ["| " + " | ".join(columns) + " |", "|" + "---|" * len(columns)]
    lines += ["| " + " | ".join(_fmt(v) for v in row) + " |" for row in frame[columns].itertuples(index=False)]
    return "\n".join(lines)


def markdown(name: str, table: dict[str, Any], board: pd.DataFrame, summary: pd.DataFrame, failures: dict[str, str],
             *, quick: bool, seed: int) -> str:
    """summary.md: the filter, the suite, the summary per estimator, the filter's rows and its faults."""
    mine = board[board["estimator"] == name]
    out = [f"# Arena: `{name}`", "",
           f"The filter `{name}` ({', '.join(f'{k} = {v!r}' for k, v in table.items()) or 'installed, defaults'}) "
           f"against every built-in estimator on {board['scenario'].nunique()} scenarios "
           f"({'quick suite' if quick else 'full suite'}, seed {seed}). MSE ratios are to the centralized Kalman "
           "filter (1 is optimal); the frontier holds the estimators no other beats in both error and numbers "
           "sent. Tables: tables/leaderboard.csv (every scenario and estimator), tables/summary.csv.", "",
           "## Summary", "", _table_md(summary, ["estimator", "scenarios", "mse_ratio_geomean",
                                                 "scalars_per_step_mean", "on_frontier", "diverged", "fails", "faults"]),
           "", f"## `{name}` on each scenario", "",
           _table_md(mine, ["scenario", "mse_ratio", "scalars_per_step", "nees", "frontier", "verdict_orthogonality",
                            "verdict_lower_bound", "verdict_nees", "verdict_exact_moments"])]
    faults = [r for r in mine.itertuples() if r.fault]
    if faults:
        out += ["", "## Faults", ""] + [f"- {r.scenario}: {r.fault}" for r in faults]
    if failures:
        out += ["", "## Scenarios that failed to run", ""] + [f"- {k}: {v}" for k, v in failures.items()]
    return "\n".join(out) + "\n"


def _colours(board: pd.DataFrame, name: str) -> dict[str, tuple[int, int, int]]:
    names = [e for e in dict.fromkeys(board["estimator"]) if e != name]
    out = {e: ((0, 0, 0) if e == "central" else rec_.color(i)) for i, e in enumerate(names)}
    out[name] = HIGHLIGHT
    return out


def frontier_figure(name: str, board: pd.DataFrame, path: Path) -> None:
    """One panel per scenario: MSE ratio to the centralized filter (log) against the numbers each node sends
    per step (symlog), every estimator a marker, the filter a large gold star, the frontier a step line."""
    scenarios = list(dict.fromkeys(board["scenario"]))
    cols = min(COLUMNS, len(scenarios))
    rows = -(-len(scenarios) // cols)
    fig, axes = new_figure(ncols=cols, nrows=rows, width=3.6, height=3.0)
    colours = _colours(board, name)
    for k, sc in enumerate(scenarios):
        ax = axes[k // cols, k % cols]
        g = board[(board["scenario"] == sc) & board["ran"] & ~board["diverged"]]
        for r in g.itertuples():
            mine = r.estimator == name
            ax.scatter(r.scalars_per_step, r.mse_ratio, s=130 if mine else 28, marker="*" if mine else "o",
                       color=np.array(colours[r.estimator]) / 255, zorder=3 if mine else 2,
                       edgecolors="black" if mine else "none", linewidths=0.6, label=r.estimator)
        front = g[g["frontier"]].sort_values("scalars_per_step")
        if len(front):
            ax.step(front["scalars_per_step"], front["mse_ratio"], where="post", color="0.4", lw=1, ls="--", zorder=1)
        ax.set_xscale("symlog", linthresh=1.0)
        ax.set_yscale("log")
        ax.set_title(sc, fontsize=8)
        ax.tick_params(which="both", labelsize=7)
        if k % cols == 0:
            ax.set_ylabel("MSE / centralized MSE", fontsize=7)
        if k // cols == rows - 1:
            ax.set_xlabel("numbers sent per node and step", fontsize=7)
    for k in range(len(scenarios), rows * cols):
        axes[k // cols, k % cols].axis("off")
    handles = {e: axes[0, 0].scatter([], [], marker="*" if e == name else "o", s=80 if e == name else 20,
                                     color=np.array(c) / 255) for e, c in colours.items()}
    fig.legend(list(handles.values()), list(handles), loc="lower center", ncol=min(6, len(handles)), fontsize=7,
               frameon=False)
    fig.suptitle(f"Arena: {name} (gold star) against the built-in estimators; dashed: the frontier", fontsize=9)
    fig.subplots_adjust(bottom=0.12 + 0.02 * (len(handles) // 6), top=0.92, hspace=0.45, wspace=0.3)
    save_figure(fig, path, tight=False)


def _plane(g: pd.DataFrame) -> np.ndarray:
    """(k, 2) positions in the recording's plane (PLANE_SCALE)."""
    return np.column_stack([np.log10(1.0 + g["scalars_per_step"].to_numpy(float)),
                            -np.log10(g["mse_ratio"].to_numpy(float))]) * PLANE_SCALE


def staircase(xy: np.ndarray) -> np.ndarray:
    """The frontier through points sorted by x as a staircase: from each point across to the next one's x, then
    to the next point (as the figure's `step(where="post")`)."""
    out = [xy[0]]
    for a, b in zip(xy[:-1], xy[1:]):
        out += [np.array([b[0], a[1]]), b]
    return np.array(out)


def recording(name: str, board: pd.DataFrame, text: str, path: Path, *, seed: int) -> None:
    """arena.rrd, opening on the frontier plane of the first scenario (the `scenario` timeline steps through the
    suite): every estimator a labelled point at (log10(1 + numbers sent per node and step), −log10(MSE ratio)),
    the filter large and gold, the frontier a line; then the MSE ratios and numbers sent along the suite, the
    summary and the list of scenarios."""
    import rerun as rr
    import rerun.blueprint as rrb

    scenarios = list(dict.fromkeys(board["scenario"]))
    colours = _colours(board, name)
    ran = board[board["ran"] & ~board["diverged"]]
    whole = rrb.TimeAxis(view_range=rrb.TimeRange(start=rrb.TimeRangeBoundary.infinite(),
                                                  end=rrb.TimeRangeBoundary.infinite()))
    blueprint = rrb.Blueprint(
        rrb.Tabs(rrb.Horizontal(rrb.Spatial2DView(origin="/frontier", name="error (up) against numbers sent (right)"),
                                rrb.TextDocumentView(origin="/axes", name="how to read it"), column_shares=[4, 1],
                                name="frontier"),
                 rrb.Vertical(rrb.TimeSeriesView(origin="/log10_mse_ratio", name="log10(MSE / centralized MSE), per "
                                                 "scenario", axis_x=whole),
                              rrb.TimeSeriesView(origin="/scalars", name="numbers sent per node and step",
                                                 axis_x=whole), name="along the suite"),
                 rrb.TextDocumentView(origin="/summary", name="summary"),
                 rrb.TextDocumentView(origin="/scenarios", name="scenarios")),
        rrb.TimePanel(timeline="scenario", expanded=True), collapse_panels=True)
    with rec_.recording(path, application_id="dse-arena", recording_id=f"arena-{name}-seed{seed}", blueprint=blueprint,
                        properties={"filter": name, "scenarios": len(scenarios), "seed": seed}) as rec:
        rec_.log_markdown(rec, "summary", text)
        rec_.log_markdown(rec, "scenarios", "\n".join(f"{i}. {s}" for i, s in enumerate(scenarios)))
        rec_.log_markdown(rec, "axes", f"One scenario at a time (the `scenario` timeline). Right: log10(1 + numbers "
                                       f"sent per node and step) × {PLANE_SCALE:g}; up: −log10(MSE / centralized "
                                       f"MSE) × {PLANE_SCALE:g}, so the centralized filter is at the bottom (height 0) "
                                       f"and every other estimator higher by its excess error. `{name}`: the large gold point; the line: the "
                                       "frontier (no network estimator has both less error and sends no more).")
        for i, sc in enumerate(scenarios):
            rec.set_time("scenario", sequence=i)
            g = ran[ran["scenario"] == sc]
            mine = (g["estimator"] == name).to_numpy()
            rec.log("frontier/estimators", rr.Points2D(rec_.as_float32(_plane(g)), labels=g["estimator"].tolist(),
                                                       colors=[rec_.on_dark(colours[e]) for e in g["estimator"]],
                                                       radii=[rr.components.Radius.ui_points(9.0 if m else 5.0)
                                                              for m in mine], show_labels=True))
            front = g[g["frontier"]].sort_values("scalars_per_step")
            if len(front):
                rec.log("frontier/line", rr.LineStrips2D([rec_.as_float32(staircase(_plane(front)))],
                                                         colors=[(160, 160, 160)]))
            else:
                rec.log("frontier/line", rr.Clear(recursive=False))
        for est, g in board[board["ran"]].groupby("estimator", sort=False):
            idx = rec_.sequence_index("scenario", [scenarios.index(s) for s in g["scenario"]])
            with np.errstate(divide="ignore", invalid="ignore"):
                ratio = np.log10(g["mse_ratio"].to_numpy(float))
            rec_.send_series(rec, f"log10_mse_ratio/{est}", idx, ratio, names=est, colors=[colours[est]], points=True)
            rec_.send_series(rec, f"scalars/{est}", idx, g["scalars_per_step"].to_numpy(float), names=est,
                             colors=[colours[est]], points=True)
