"""The template family's tables, figure and recording. Figures and recordings are drawn from the
tables (the numeric source of truth a user reads)."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from dse.contract.views import Outputs, View, recording
from dse.outputs.tables import spec

from .stages import Design, Results

SPECTRUM = spec("spectrum", "eigenvalue of W", [("k", "1", "index, increasing order"),
                                                ("eigenvalue", "1", "eigenvalue λ_k of the consensus weights W")])
MSE = spec("mse", "consensus round and node", [
    ("round", "1", "consensus round t"), ("node", "1", "node i"),
    ("exact", "θ²", "r (W^{2t})_ii: the exact mean-square error"),
    ("monte_carlo", "θ²", "mean of e_i(t)² over the trials"),
    ("se", "θ²", "standard error of the Monte Carlo mean, √(2/n)·exact (Gaussian errors)")])


def design_tables(design: Design):
    yield SPECTRUM, pd.DataFrame({"k": np.arange(len(design.eigenvalues)), "eigenvalue": design.eigenvalues})


def run_tables(res: Results):
    yield from design_tables(res.design)
    T, N = res.design.mse.shape
    yield MSE, pd.DataFrame({"round": np.repeat(np.arange(T), N), "node": np.tile(np.arange(N), T),
                             "exact": res.design.mse.ravel(), "monte_carlo": res.mse.ravel(),
                             "se": np.sqrt(2.0 / res.trials) * res.design.mse.ravel()})


def _figure(out: Outputs, path: Path) -> None:
    from dse.outputs.figures import new_figure, plain_log_labels, save_figure

    sc, mse = out.results.design.scenario, out.tables["mse"]
    fig, axes = new_figure()
    ax = axes[0, 0]
    for i, rows in mse.groupby("node"):
        line, = ax.plot(rows["round"], rows["exact"], "-", lw=1.2, label=f"node {i}" if i < 8 else None)
        ax.plot(rows["round"], rows["monte_carlo"], "o", ms=3, color=line.get_color())
    ax.axhline(sc.model.r / sc.n, color="k", ls=":", lw=1, label="r/N (centralized)")
    ax.set_yscale("log")
    ax.set_xlabel("consensus round t")
    ax.set_ylabel("mean-square error of node i")
    ax.set_title(f"lines: exact r(W^2t)_ii; dots: {out.trials:,} Monte Carlo trials", fontsize=9)
    ax.legend(ncol=2)
    plain_log_labels(fig)   # no mathtext tick labels: matplotlib parses them one by one (about 10 ms each)
    save_figure(fig, path)


def _recording(out: Outputs, path: Path) -> None:
    import rerun.blueprint as rrb

    from dse.outputs import record

    sc, mse = out.results.design.scenario, out.tables["mse"]

    def tabs():
        return [rrb.Horizontal(rrb.TimeSeriesView(origin="/", name="mean-square error per node: exact (lines), "
                                                  "Monte Carlo (dots)", contents=["/nodes/**", "/central/**"]),
                               rrb.GraphView(origin="/graph", name="communication graph"), column_shares=[3, 1],
                               name="consensus")]

    def log(rec):
        record.log_graph(rec, "graph", sc.network.positions(), [tuple(e) for e in sc.network.edge_array()])
        for i, rows in mse.groupby("node"):
            index = record.sequence_index("round", rows["round"].to_numpy())
            color = [record.color(int(i))]
            record.send_series(rec, f"nodes/{i}/exact", index, rows["exact"].to_numpy(), names=f"node {i}: exact",
                               colors=color)
            record.send_series(rec, f"nodes/{i}/monte_carlo", index, rows["monte_carlo"].to_numpy(),
                               names=f"node {i}: Monte Carlo", colors=color, points=True)
        rounds = np.arange(sc.model.rounds + 1)
        record.send_series(rec, "central/r_over_N", record.sequence_index("round", rounds),
                           np.full(len(rounds), sc.model.r / sc.n), names="r/N (centralized)", colors=[(0, 0, 0)])

    recording(path, out, recording_id=f"template-{sc.name}-seed{out.seed}", tabs=tabs, timeline="round", log=log,
              properties={"r": sc.model.r, "rounds": sc.model.rounds, "graph": sc.graph.kind, "n": sc.n})


def views(out: Outputs) -> list[View]:
    name = out.results.design.scenario.name
    return [View("figures/mse.png", lambda path: _figure(out, path)),
            View(f"{name}.rrd", lambda path: _recording(out, path))]
