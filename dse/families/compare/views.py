"""Figures and the recording of a compare run, drawn from its tables: `figures/error_vs_communication.png`
(network MSE at the evaluation step against the real numbers each node sends per step, the centralized filter
as the floor), `figures/mse_vs_time.png` (Monte Carlo with its band, exact recursions dashed), `figures/nees.png`
(with the χ² band of a consistent filter) and `<name>.rrd` (every estimator's curves on timeline `k`, the NEES,
the disagreement, the graph and the comparison table, on the recording scaffold with its claims tab). Colours,
markers and labels follow the registry's order (`dse.estimators.network`), then the plug-ins'.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from dse.contract.views import Outputs, View, recording
from dse.outputs.figures import new_figure, plain_log_labels, save_figure
from dse.outputs.palette import color
from dse.simulate.stats import z_for_confidence

BAND = 0.95


def _styles(res) -> tuple[dict, dict, dict]:
    """(colour, marker, label) of every estimator of the run (built-ins in the registry's order, then the
    plug-ins); the reference in black."""
    reg = res.scenario.estimator_specs
    colors = {e: (0, 0, 0) if est.reference else color(i) for i, (e, est) in enumerate(reg.items())}
    markers = {e: "*ovs^D<>p"[i % 9] for i, e in enumerate(reg)}
    return colors, markers, {e: est.title for e, est in reg.items()}


def _rgb(c):
    return tuple(x / 255 for x in c)


def error_vs_communication(res, tables, path: Path) -> None:
    """Left: network MSE against the numbers each node sends per step (symlog), the centralized filter
    as the floor and the frontier of the lowest error for a budget; estimators far off the scale
    (a diverging filter) are drawn on the top edge with their value. Right: the same estimators
    ranked by their MSE relative to the centralized filter, each bar labelled with its budget."""
    colors, markers, labels = _styles(res)
    t = tables["estimators"]
    app = tables["applicability"]
    fig, axes = new_figure(ncols=2, width=7.0, height=5.6)
    ax, bx = axes[0, 0], axes[0, 1]
    central = t[t["estimator"] == "central"]
    floor = float(central["network_mse"].iloc[0]) if len(central) else np.nan
    z = z_for_confidence(BAND)
    rows = t[(t["estimator"] != "central") & np.isfinite(t["network_mse"])]
    vals = rows["network_mse"].to_numpy()
    top = _top(vals, floor)
    for _, r in rows.iterrows():
        est, y = r["estimator"], r["network_mse"]
        c = _rgb(colors[est])
        if y > top:
            ax.plot([r["scalars_per_step"]], [top * 1.15], marker="^", color=c, ms=9, ls="none",
                    label=f"{labels[est]} (off scale: {y:.3g})")
            continue
        err = None if r["exact"] else z * r["network_mse_mc_se"]
        ax.errorbar([r["scalars_per_step"]], [y], yerr=err, fmt=markers[est], color=c, ms=8, capsize=3,
                    label=f"{labels[est]}" + ("" if r["exact"] else " (Monte Carlo)"))
    if np.isfinite(floor):
        ax.axhline(floor, color="k", ls="--", lw=1, label="centralized KF (all measurements at one place)")
    front = _pareto(rows)
    front = front[front[:, 1] <= top] if len(front) else front
    if len(front) > 1:
        ax.step(front[:, 0], front[:, 1], where="post", color="0.5", lw=0.8, ls=":",
                label="lowest error for a communication budget")
    ax.set_xscale("symlog", linthresh=1.0)
    ax.set_yscale("log")
    ax.set_ylim(top=top * 1.35)
    ax.set_xlabel("real numbers sent per node and step")
    ax.set_ylabel(f"network mean-square error at k = {res.scenario.simulation.eval_step}")
    title = f"{res.scenario.name}: error against communication ({res.scenario.links.model} links"
    title += f", σ_c = {res.scenario.links.noise_std:g})" if res.scenario.links.noise_std else ")"
    ax.set_title(title)
    skipped = app[~app["applies"] & (app["reason"] != "not requested (dse.estimators.include)")]
    if len(skipped):
        ax.text(0.01, 0.01, "not applicable: " + ", ".join(skipped["estimator"]), transform=ax.transAxes, fontsize=7,
                va="bottom")
    # below the axes from their left edge (centred, two columns of long labels ran off the figure's left side)
    ax.legend(loc="upper left", bbox_to_anchor=(0.0, -0.16), fontsize=7, ncol=2, borderaxespad=0)
    ranked = rows.sort_values("network_mse")
    ratio = ranked["network_mse"].to_numpy() / floor if np.isfinite(floor) else ranked["network_mse"].to_numpy()
    ypos = np.arange(len(ranked))[::-1]
    bx.barh(ypos, ratio, color=[_rgb(colors[e]) for e in ranked["estimator"]])
    for yv, rv, (_, r) in zip(ypos, ratio, ranked.iterrows()):
        bx.text(rv, yv, f"  {rv:.3g}×, {r['scalars_per_step']:.3g} numbers/step", va="center", fontsize=7)
    bx.set_yticks(ypos, [labels[e] for e in ranked["estimator"]], fontsize=7)
    bx.set_xscale("log")
    bx.axvline(1.0, color="k", ls="--", lw=1)
    bx.set_xlabel("network MSE / centralized KF's")
    bx.set_title("ranked (label: error ratio, communication per node and step)")
    plain_log_labels(fig)   # no mathtext tick labels: matplotlib parses them one by one (about 10 ms each)
    save_figure(fig, path)


def _top(vals: np.ndarray, floor: float) -> float:
    """The top of the error axis: the largest value, leaving out those more than 30 times the median of
    the smaller ones (diverging filters, drawn on the top edge)."""
    v = np.sort(vals[np.isfinite(vals)])
    if len(v) < 3:
        return float(v[-1]) if len(v) else 1.0
    rest = v[:-1]
    while len(rest) > 1 and v[len(rest)] > 30 * np.median(rest):
        v, rest = rest, rest[:-1]
    return float(max(v[-1], floor if np.isfinite(floor) else 0.0))


def _pareto(t) -> np.ndarray:
    """(budget, error) of the estimators no other beats on both, by increasing budget."""
    pts = sorted(zip(t["scalars_per_step"], t["network_mse"]))
    front, best = [], np.inf
    for x, y in pts:
        if y < best:
            front.append((x, y))
            best = y
    return np.array(front)


def _per_estimator(res, tables, height: float):
    """A figure for one curve per estimator of the `series` table: (figure, axes, colours, labels, rows)."""
    colors, _, labels = _styles(res)
    s = tables["series"]
    fig, axes = new_figure(ncols=1, width=10.0, height=height)
    return fig, axes[0, 0], colors, labels, [(est, s[s["estimator"] == est]) for est in labels]


def _finish(fig, ax, path: Path, ylabel: str, title: str) -> None:
    ax.set_yscale("log")
    ax.set_xlabel("step k")
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=7, borderaxespad=0)
    plain_log_labels(fig)
    save_figure(fig, path)


def mse_vs_time(res, tables, path: Path) -> None:
    fig, ax, colors, labels, rows = _per_estimator(res, tables, 5.0)
    z = z_for_confidence(BAND)
    for est, r in rows:
        if not len(r):
            continue
        k, mc, se = r["step"].to_numpy(), r["network_mse_mc"].to_numpy(), r["network_mse_mc_se"].to_numpy()
        if not np.all(np.isfinite(mc)):
            continue
        c = _rgb(colors[est])
        ax.plot(k, mc, color=c, lw=1.2, label=labels[est])
        ax.fill_between(k, np.maximum(mc - z * se, 1e-300), mc + z * se, color=c, alpha=0.2, lw=0)
        ex = r["network_mse_exact"].to_numpy()
        if np.isfinite(ex).any():
            ax.plot(k, ex, color=c, ls="--", lw=1)
    _finish(fig, ax, path, "network mean-square error",
            f"{res.scenario.name}: Monte Carlo (band {BAND:.0%}) and exact (dashed)")


def nees_figure(res, tables, path: Path) -> None:
    fig, ax, colors, labels, rows = _per_estimator(res, tables, 4.5)
    nodes = tables["nodes"]
    lo, hi = float(nodes["nees_lo"].iloc[0]), float(nodes["nees_hi"].iloc[0])
    for est, r in rows:
        if len(r) and np.isfinite(r["nees_mc"]).any():
            ax.plot(r["step"], r["nees_mc"], color=_rgb(colors[est]), label=labels[est])
    ax.axhspan(lo, hi, color="0.8", alpha=0.5, label="χ² band of one consistent node (99%)")
    ax.axhline(res.design.model.n, color="k", lw=0.8)
    _finish(fig, ax, path, "mean NEES (node average)",
            "consistency: NEES with each filter's own covariance (n when consistent)")


def _comparison_markdown(tables) -> str:
    t = tables["estimators"]
    rows = ["| estimator | network MSE | excess over centralized | NEES | messages/step | scalars/step |",
            "|---|---|---|---|---|---|"]
    for _, r in t.iterrows():
        rows.append(f"| {r['label']} | {r['network_mse']:.4g}{'' if r['exact'] else ' (MC)'} | {r['excess']:.4g} | "
                    f"{r['nees']:.3g} | {r['messages_per_step']:.3g} | {r['scalars_per_step']:.3g} |")
    app = tables["applicability"]
    for _, r in app[~app["applies"]].iterrows():
        rows.append(f"| {r['label']} | not applicable: {r['reason']} | | | | |")
    return "\n".join(rows)




def _tabs():
    import rerun.blueprint as rrb

    comparison = rrb.Horizontal(
        rrb.Vertical(
            rrb.TimeSeriesView(origin="/mse", name="network mean-square error: every estimator (dots Monte Carlo, lines "
                               "exact)", contents=["/mse/**"], plot_legend=rrb.PlotLegend(rrb.Corner2D.RightTop)),
            rrb.TimeSeriesView(origin="/nees", name="mean NEES with each filter's own covariance", contents=["/nees/**"],
                               plot_legend=rrb.PlotLegend(visible=False)),
            row_shares=[3, 2]),
        rrb.Vertical(rrb.TextDocumentView(origin="/comparison", name="comparison at the evaluation step"),
                     rrb.GraphView(origin="/graph", name="communication graph"), row_shares=[1, 1]),
        column_shares=[3, 2], name="comparison")
    details = rrb.Grid(
        rrb.TimeSeriesView(origin="/disagreement", name="disagreement between nodes",
                           plot_legend=rrb.PlotLegend(rrb.Corner2D.RightTop)),
        rrb.TimeSeriesView(origin="/excess", name="mean-square distance to the centralized filter",
                           plot_legend=rrb.PlotLegend(visible=False)),
        rrb.TimeSeriesView(origin="/trial", name="trial 0: truth (white) and node 0's estimate of the first state",
                           plot_legend=rrb.PlotLegend(visible=False)),
        name="details")
    return [comparison, details]


def _log_series(rec, s, colors: dict, labels: dict) -> None:
    from dse.outputs import record as rec_

    for est in labels:
        r = s[s["estimator"] == est]
        if not len(r):
            continue
        idx = rec_.sequence_index("k", r["step"].to_numpy())
        col = colors[est]
        rec_.send_series(rec, f"mse/{est}/monte_carlo", idx, r["network_mse_mc"].to_numpy(), names=f"{labels[est]} (MC)",
                         colors=[col], points=True)
        ex = r["network_mse_exact"].to_numpy()
        if np.isfinite(ex).any():
            rec_.send_series(rec, f"mse/{est}/exact", idx, ex, names=f"{labels[est]} (exact)", colors=[col])
        if np.isfinite(r["nees_mc"]).any():
            rec_.send_series(rec, f"nees/{est}", idx, r["nees_mc"].to_numpy(), names=labels[est], colors=[col])
        rec_.send_series(rec, f"disagreement/{est}", idx, r["disagreement_mc"].to_numpy(), names=labels[est],
                         colors=[col])
        if est != "central":
            rec_.send_series(rec, f"excess/{est}", idx, r["excess_mc"].to_numpy(), names=labels[est], colors=[col])


def _log_trial(rec, paths: dict, colors: dict, labels: dict) -> None:
    """Trial 0: the first state and node 0's estimate of it by every estimator."""
    from dse.estimators.network_comparison import TRUE_STATE
    from dse.outputs import record as rec_

    x = paths.get(TRUE_STATE) if paths else None
    if not (x is not None and x.shape[-1] and np.all(np.isfinite(x[:, 0, 0]))):
        return
    idx = rec_.sequence_index("k", np.arange(x.shape[0]))
    rec_.send_series(rec, "trial/truth", idx, x[:, 0, 0], names="x₁(k)", colors=[(230, 230, 230)], width=2.5)
    for est in labels:
        p = paths.get(est)
        if p is not None and np.all(np.isfinite(p[:, 0, 0, 0])):
            rec_.send_series(rec, f"trial/{est}", idx, p[:, 0, 0, 0], names=labels[est], colors=[colors[est]])


def _recording(out: Outputs, path: Path) -> None:
    res, tables = out.results, out.tables
    sc = res.scenario
    colors, _, labels = _styles(res)

    def log(rec):
        from dse.outputs import record as rec_

        edges = res.design.links.topology.edges.tolist()
        rec_.log_graph(rec, "graph", sc.network.positions(), [tuple(e) for e in edges])
        rec_.log_markdown(rec, "comparison", _comparison_markdown(tables))
        _log_series(rec, tables["series"], colors, labels)
        _log_trial(rec, res.paths, colors, labels)

    recording(path, out, recording_id=f"compare-{sc.name}-seed{res.seed}", tabs=_tabs, timeline="k", log=log,
              properties={"links": sc.links.model, "noise_std": sc.links.noise_std},
              summary=out.summary(extra=f"{res.trials:,} trials, {sc.simulation.steps} steps, {sc.N} nodes, "
                                        f"{sc.links.model} links"))


def views(out: Outputs) -> list[View]:
    res, tables = out.results, out.tables
    return [View(f"{res.scenario.name}.rrd", lambda path: _recording(out, path)),
            View("figures/error_vs_communication.png", lambda path: error_vs_communication(res, tables, path)),
            View("figures/mse_vs_time.png", lambda path: mse_vs_time(res, tables, path)),
            View("figures/nees.png", lambda path: nees_figure(res, tables, path))]
