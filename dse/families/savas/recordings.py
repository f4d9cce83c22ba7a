"""The Rerun recordings of a noisy-consensus-filter run, drawn from its tables on the shared scaffold
(`dse.contract.views.recording`: the claims tab, the properties, the /report header).

Two recordings per scenario, because a time-series view plots against one timeline:
``<name>.rrd`` on timeline ``k`` (sample trials, Monte Carlo aggregates against the exact
recursion and the centralized bound, the graph) and ``<name>_figures.rrd`` on timeline ``m``
(Figs. 1-3: metric and optimal gains against the number of rounds).
"""
from __future__ import annotations

import numpy as np

from dse.contract.views import Outputs, View, recording
from dse.simulate.stats import z_for_confidence

from .figures import BAND_CONFIDENCE, cell_rows, eval_trace_table, fig_label, gain_table, kf_eval, showcase

# rerun (dse.outputs.record) is imported by the functions that draw, in a forked worker
COLORS = {"carli": (214, 39, 40), "reinjection": (31, 119, 180)}


def _properties(sc) -> dict:
    return {"q": sc.model.q, "r": sc.model.r, "sigma0": sc.model.sigma0, "x0_mean": sc.model.x0_mean,
            "carli_ell": sc.carli.ell, "gains": sc.reinjection.gains, "graph": sc.network.kind, "n": sc.n}


def _q_matrix(tables, n: int) -> np.ndarray:
    q = tables["consensus_matrix"]
    Q = np.zeros((n, n))
    Q[q["row"].to_numpy(), q["col"].to_numpy()] = q["value"].to_numpy()
    return Q


def _trials_tabs(n: int):
    import rerun.blueprint as rrb

    return [
        rrb.Horizontal(
            rrb.Vertical(rrb.TimeSeriesView(origin="/mc", name="tr P(k|k-1): Monte Carlo vs exact vs centralized",
                                            contents=["/mc/**", "/bounds/**", "/central/**"],
                                            plot_legend=rrb.PlotLegend(rrb.Corner2D.RightBottom)),
                         rrb.GraphView(origin="/graph", name="communication graph"), row_shares=[2, 1]),
            rrb.Vertical(*[rrb.TimeSeriesView(origin=f"/nodes/{i}", name=f"agent {i}: estimates (red Carli, blue "
                                              "re-injection) and truth", contents=[f"/nodes/{i}/estimate/**", "/truth/**"],
                                              plot_legend=rrb.PlotLegend(visible=False)) for i in range(min(n, 4))]),
            column_shares=[3, 2], name="Monte Carlo and trials"),
        rrb.Grid(*[rrb.TimeSeriesView(origin=f"/nodes/{i}/error", name=f"agent {i}: error x(k) − x̂ᵢ(k|k-1)",
                                      plot_legend=rrb.PlotLegend(visible=False)) for i in range(min(n, 9))],
                 name="errors"),
        rrb.Grid(*[rrb.TimeSeriesView(origin=f"/nodes/{i}/consensus", name=f"agent {i}: consensus iterates (timeline "
                                      "'round')", plot_legend=rrb.PlotLegend(rrb.Corner2D.LeftTop)) for i in range(min(n, 9))],
                 name="consensus rounds")]


def _log_sample_paths(rec, tables, sc, alg: str, m: int, s_c: float, first: bool) -> None:
    """The sample trials of one cell: estimates and errors per agent, the truth, the consensus iterates of trial 0."""
    from dse.outputs import record

    p = cell_rows(tables["sample_paths"], sc, alg, m, s_c)
    if not len(p):
        return
    n, col = sc.n, COLORS[alg]
    n_paths, ks = int(p["trial"].max()) + 1, np.sort(p["k"].unique())
    pidx = record.sequence_index("k", ks)
    grid = lambda col_: p.pivot_table(index="k", columns=["trial", "node"], values=col_).to_numpy().reshape(len(ks), n_paths, n)
    x, xhat = grid("x")[:, :, 0], grid("xhat_pred")
    if first:  # both filters share the random draws at equal m (monte_carlo.group_streams)
        record.send_series(rec, "truth/x", pidx, x, names=[f"x(k), trial {q}" for q in range(n_paths)],
                           colors=[(230, 230, 230)] * n_paths, width=2.5)
    r = cell_rows(tables["consensus_rounds"], sc, alg, m, s_c)
    rounds_idx = record.sequence_index("round", np.arange(len(ks) * (m + 1)))
    for i in range(n):
        record.send_series(rec, f"nodes/{i}/estimate/{alg}", pidx, xhat[:, :, i],
                           names=[f"{alg} x̂(k|k-1), trial {q}" for q in range(n_paths)], colors=[col] * n_paths)
        record.send_series(rec, f"nodes/{i}/error/{alg}", pidx, x - xhat[:, :, i],
                           names=[f"{alg}, trial {q}" for q in range(n_paths)], colors=[col] * n_paths, width=1.0)
        zi = r[r["node"] == i].sort_values(["k", "round"])["z"].to_numpy()
        record.send_series(rec, f"nodes/{i}/consensus/{alg}", rounds_idx, zi,
                           names=f"{alg} z(k+h/m|k), trial 0", colors=[col], points=True)


def _trials_recording(out: Outputs, path) -> None:
    from dse.outputs import record

    sc, tables = out.results.scenario, out.tables
    m, s_c = showcase(sc)
    z = z_for_confidence(BAND_CONFIDENCE)

    def log(rec):
        record.log_graph(rec, "graph", sc.network.positions(), list(sc.network.build().edges()),
                         labels=[f"agent {i}" for i in range(sc.n)])
        record.log_tensor(rec, "graph/Q", _q_matrix(tables, sc.n))
        for a, alg in enumerate(("carli", "reinjection")):
            col, t = COLORS[alg], cell_rows(tables["trace_series"], sc, alg, m, s_c)
            idx = record.sequence_index("k", t["k"].to_numpy())
            mc, se = t["trP_mc"].to_numpy(), t["trP_mc_se"].to_numpy()
            label = f"{alg} m={m} σ_c={s_c:g}"
            record.send_series(rec, f"mc/{alg}/trace", idx, mc, names=f"{label}: Monte Carlo", colors=[col], points=True)
            record.send_series(rec, f"mc/{alg}/band", idx, np.column_stack([mc - z * se, mc + z * se]),
                               names=[f"{label}: MC {BAND_CONFIDENCE:.0%} low", f"{label}: MC {BAND_CONFIDENCE:.0%} high"],
                               colors=[col, col], width=0.5)
            record.send_series(rec, f"bounds/{alg}/trace", idx, t["trP_exact"].to_numpy(), names=f"{label}: exact (22)",
                               colors=[col])
            if a == 0:
                record.send_series(rec, "central/kf_trace", idx, t["kf_trP"].to_numpy(),
                                   names="N · P_KF(k|k-1) (centralized KF)", colors=[(0, 0, 0)])
            if "sample_paths" in tables:
                _log_sample_paths(rec, tables, sc, alg, m, s_c, a == 0)

    recording(path, out, recording_id=f"{out.run_prefix}-{sc.name}-seed{out.results.seed}",
              tabs=lambda: _trials_tabs(sc.n), timeline="k", log=log, properties=_properties(sc),
              summary=out.summary(sc.name, f"{out.results.trials:,} trials per cell"))


def _figures_tabs(sc, paper: bool, has_gains: bool):
    import rerun.blueprint as rrb

    metric = f"tr P({sc.sweep.eval_step}|{sc.sweep.eval_step - 1})"
    views = [rrb.TimeSeriesView(origin="/fig1", name=f"{fig_label(paper, 1)}Carli's filter, {metric} vs m (lines exact, "
                                "dots Monte Carlo)", plot_legend=rrb.PlotLegend(rrb.Corner2D.LeftTop)),
             rrb.TimeSeriesView(origin="/fig3", name=f"{fig_label(paper, 3)}re-injection filter, {metric} vs m (σ_c: dark "
                                "0 → yellow max)", plot_legend=rrb.PlotLegend(visible=False))]
    if has_gains:
        hidden = rrb.PlotLegend(visible=False)
        views += [rrb.TimeSeriesView(origin="/fig2/ell", name=f"{fig_label(paper, 2)}optimal ℓ* vs m (lines corrected "
                                     "(16), dots printed)", plot_legend=hidden),
                  rrb.TimeSeriesView(origin="/fig2/zeta", name=f"{fig_label(paper, 2)}optimal ζ* vs m", plot_legend=hidden),
                  rrb.TimeSeriesView(origin="/fig2/J", name="optimal cost J* vs m", plot_legend=hidden)]
    return [rrb.Grid(*views, name="figures")]


def _figures_recording(out: Outputs, path) -> None:
    from dse.outputs import record
    from dse.outputs.figures import sequential_colors

    sc, tables = out.results.scenario, out.tables
    sigma_c = sc.sweep.sigma_c
    has_gains = "gains" in tables and len(tables["gains"]) > 0
    cols = [tuple(int(255 * x) for x in c[:3]) for c in sequential_colors(len(sigma_c), "plasma")]
    names = [f"σ_c = {s:g}" for s in sigma_c]

    def log(rec):
        idx = record.sequence_index("m", sc.sweep.rounds)
        for fig, alg in (("fig1", "carli"), ("fig3", "reinjection")):
            exact, mc, se = eval_trace_table(tables, sc, alg)
            record.send_series(rec, f"{fig}/exact", idx, exact.T, names=[f"{n} exact" for n in names], colors=cols)
            record.send_series(rec, f"{fig}/monte_carlo", idx, mc.T, names=[f"{n} Monte Carlo" for n in names],
                               colors=cols, points=True)
            record.send_series(rec, f"{fig}/centralized_kf", idx, np.full(len(sc.sweep.rounds), kf_eval(tables)),
                               names="centralized KF (lower bound)", colors=[(0, 0, 0)])
        if has_gains:
            midx = record.sequence_index("m", np.arange(sc.rounds_max + 1))
            for key in ("ell", "zeta", "J"):
                record.send_series(rec, f"fig2/{key}/corrected", midx, gain_table(tables, sc, "corrected", key).T,
                                   names=[f"{n} corrected (16)" for n in names], colors=cols)
                record.send_series(rec, f"fig2/{key}/printed", midx, gain_table(tables, sc, "printed", key).T,
                                   names=[f"{n} printed (16)" for n in names], colors=cols, points=True)

    recording(path, out, recording_id=f"{out.run_prefix}-{sc.name}-figures-seed{out.results.seed}",
              tabs=lambda: _figures_tabs(sc, out.reproduction.is_paper, has_gains), timeline="m", log=log,
              properties=_properties(sc),
              summary=out.summary(sc.name, f"{out.results.trials:,} trials per cell"))


def views(out: Outputs) -> list[View]:
    name = out.results.scenario.name
    return [View(f"{name}.rrd", lambda path: _trials_recording(out, path)),
            View(f"{name}_figures.rrd", lambda path: _figures_recording(out, path))]
