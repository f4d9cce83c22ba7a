"""Figures (PNG) and Rerun recordings of the noisy-consensus-filter family, drawn from the run's tables.

Two recordings per scenario, because a time-series view plots against one timeline:
``<name>.rrd`` on timeline ``k`` (sample trials, Monte Carlo aggregates against the exact
recursion and the centralized bound, the graph, the claims) and ``<name>_figures.rrd`` on
timeline ``m`` (Figs. 1-3: metric and optimal gains against the number of rounds).
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd

from dse.simulate.stats import z_for_confidence
from dse.outputs.tables import Tables

from .compute import Results

# matplotlib (dse.outputs.figures) and rerun (dse.outputs.record) are imported by the functions that draw: the
# figures and the recordings are drawn in forked workers, each importing only what it draws with.

BAND_CONFIDENCE = 0.95


def eval_trace_table(tables: Tables, sc, alg: str):
    """Exact and Monte Carlo tr P(k_eval) with its SE, arrays (S, M) over σ_c × m."""
    cells = tables["cells"]
    cells = cells[(cells["alg"] == alg) & (cells["n_steps"] == sc.n_steps)]
    ts = tables["trace_series"]
    ts = ts[(ts["alg"] == alg) & (ts["n_steps"] == sc.n_steps) & (ts["k"] == sc.eval_step)]
    exact = cells.pivot(index="sigma_c", columns="m", values="trP_eval").loc[list(sc.sigma_c), list(sc.rounds)]
    mc = ts.pivot(index="sigma_c", columns="m", values="trP_mc").loc[list(sc.sigma_c), list(sc.rounds)]
    se = ts.pivot(index="sigma_c", columns="m", values="trP_mc_se").loc[list(sc.sigma_c), list(sc.rounds)]
    return exact.to_numpy(), mc.to_numpy(), se.to_numpy()


def _kf_eval(tables: Tables) -> float:
    return float(tables["cells"]["kf_trP_eval"].iloc[0])


def showcase(sc):
    """The cell shown in the per-trial views: m = 2 (or the largest ≤ 2 > 0), σ_c closest to 1."""
    m = max([m for m in sc.rounds if 0 < m <= 2] or [sc.rounds[-1]])
    s_c = min(sc.sigma_c, key=lambda s: abs(s - 1.0))
    return m, s_c


def _cell_rows(frame: pd.DataFrame, sc, alg: str, m: int, s_c: float) -> pd.DataFrame:
    return frame[(frame["alg"] == alg) & (frame["m"] == m) & (frame["sigma_c"] == s_c) & (frame["n_steps"] == sc.n_steps)]


# -- figures --------------------------------------------------------------------------------------

def _metric_figure(tables: Tables, sc, trials: int, alg: str, title: str, path: Path) -> None:
    from dse.outputs.figures import new_figure, save_figure, sequential_colors, set_margins

    exact, mc, se = eval_trace_table(tables, sc, alg)
    z = z_for_confidence(BAND_CONFIDENCE)
    fig, axes = new_figure(width=8.0)
    ax = axes[0, 0]
    for s, (s_c, col) in enumerate(zip(sc.sigma_c, sequential_colors(len(sc.sigma_c), "plasma"))):
        ax.plot(sc.rounds, exact[s], "-", color=col, lw=1.4, label=f"σ_c = {s_c:g}")
        ax.errorbar(sc.rounds, mc[s], yerr=z * se[s], fmt="o", color=col, ms=3.5, capsize=2)
    ax.axhline(_kf_eval(tables), color="k", ls=":", lw=1, label="centralized KF (lower bound)")
    ax.set_xlabel("consensus rounds m")
    ax.set_ylabel(f"Σᵢ var(x̃ᵢ({sc.eval_step}|{sc.eval_step - 1}))")
    ax.set_title(f"{title}\nlines: exact recursion; markers: {trials:,} Monte Carlo runs ± {BAND_CONFIDENCE:.0%} CI",
                 fontsize=9)
    ax.set_xticks(sc.rounds)
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0)
    set_margins(fig, left=0.8, right=2.7, top=0.6, bottom=0.55)   # the legend right of the axes
    save_figure(fig, path, tight=False)


def _gains(tables: Tables, sc, objective: str, key: str) -> np.ndarray:
    g = tables["gains"]
    g = g[(g["objective"] == objective) & (g["m"] <= sc.rounds_max)]
    return g.pivot(index="sigma_c", columns="m", values=key).loc[list(sc.sigma_c)].to_numpy()


def _gains_figure(tables: Tables, sc, path: Path) -> None:
    from dse.outputs.figures import new_figure, save_figure, sequential_colors, set_margins

    ms = np.arange(sc.rounds_max + 1)
    fig, axes = new_figure(ncols=3, width=4.6)
    cols = sequential_colors(len(sc.sigma_c), "plasma")
    for ax, key in zip(axes[0], ("ell", "zeta", "J")):
        corrected, printed = _gains(tables, sc, "corrected", key), _gains(tables, sc, "printed", key)
        for s, s_c in enumerate(sc.sigma_c):
            ax.plot(ms, corrected[s], "-o", ms=2.5, color=cols[s], label=f"σ_c = {s_c:g}")
            if key != "J":
                ax.plot(ms[1:], printed[s, 1:], "--", lw=1, color=cols[s])
    for ax, lab in zip(axes[0], ("optimal ℓ*", "optimal ζ*", "J* = tr P∞")):
        ax.set_xlabel("consensus rounds m")
        ax.xaxis.get_major_locator().set_params(integer=True)
        ax.set_ylabel(lab)
    axes[0, 2].axhline(float(tables["cells"]["kf_trP_steady"].iloc[0]), color="k", ls=":", lw=1,
                       label="N P_c⁻ (centralized)")
    axes[0, 0].set_title("solid: corrected (16); dashed: (16) as printed", fontsize=9)
    axes[0, 2].legend(ncol=1)
    set_margins(fig, left=0.75, right=0.15, top=0.35, bottom=0.55, wspace=0.85)
    save_figure(fig, path, tight=False)


def _trace_over_k_figure(tables: Tables, sc, path: Path) -> None:
    from dse.outputs.figures import new_figure, save_figure, set_margins

    m, s_c = showcase(sc)
    fig, axes = new_figure()
    ax = axes[0, 0]
    z = z_for_confidence(BAND_CONFIDENCE)
    ts = tables["trace_series"]
    for alg, col in (("carli", "tab:red"), ("reinjection", "tab:blue")):
        t = _cell_rows(ts, sc, alg, m, s_c)
        ax.plot(t["k"], t["trP_exact"], "-", color=col, label=f"{alg}: exact (22)")
        ax.fill_between(t["k"], t["trP_mc"] - z * t["trP_mc_se"], t["trP_mc"] + z * t["trP_mc_se"], color=col, alpha=0.25,
                        label=f"{alg}: Monte Carlo {BAND_CONFIDENCE:.0%} band")
    ax.plot(t["k"], t["kf_trP"], "k:", label="N · centralized KF")
    if sc.n_steps > 1000:
        ax.set_xscale("symlog", linthresh=10)
    ax.set_xlabel("k")
    ax.set_ylabel("tr P(k|k−1)")
    ax.set_title(f"m = {m}, σ_c = {s_c:g}", fontsize=9)
    ax.legend()
    set_margins(fig, left=0.75, right=0.15, top=0.35, bottom=0.55)
    save_figure(fig, path, tight=False)


def _fig(paper: bool, number: int) -> str:
    """'Fig. N: ' in the paper's reproduction only (a user's scenario is not the paper's figure)."""
    return f"Fig. {number}: " if paper else ""


def write_figures(res: Results, tables: Tables, out_dir: Path, paper: bool = False) -> None:
    sc = res.scenario
    figs = out_dir / "figures"
    _metric_figure(tables, sc, res.trials, "carli", f"{_fig(paper, 1)}two-stage filter (7)+(9) under communication "
                   f"noise, ℓ = {sc.carli_ell:g}", figs / "fig1.png")
    if "gains" in tables and len(tables["gains"]):
        _gains_figure(tables, sc, figs / "fig2.png")
    _metric_figure(tables, sc, res.trials, "reinjection", f"{_fig(paper, 3)}re-injection filter (11)-(13), "
                   f"{sc.reinjection_gains} gains", figs / "fig3.png")
    _trace_over_k_figure(tables, sc, figs / "trace_over_k.png")


# -- recordings -----------------------------------------------------------------------------------

def _properties(res: Results, prov: dict) -> dict:
    sc = res.scenario
    return {"seed": res.seed, "trials": res.trials, "q": sc.q, "r": sc.r, "sigma0": sc.sigma0, "x0_mean": sc.x0_mean,
            "carli_ell": sc.carli_ell, "gains": sc.reinjection_gains, "graph": sc.graph.kind, "n": sc.n,
            "versions": json.dumps(prov.get("versions", {})), "git": prov.get("git", "")}


def _q_matrix(tables: Tables, n: int) -> np.ndarray:
    q = tables["consensus_matrix"]
    Q = np.zeros((n, n))
    Q[q["row"].to_numpy(), q["col"].to_numpy()] = q["value"].to_numpy()
    return Q


def write_trials_recording(res: Results, tables: Tables, path: Path, claims: list[dict], prov: dict, summary: str) -> None:
    import rerun.blueprint as rrb

    from dse.outputs import record as rec_

    sc = res.scenario
    m, s_c = showcase(sc)
    n = sc.n
    blueprint = rrb.Blueprint(
        rrb.Tabs(
            rrb.Horizontal(
                rrb.Vertical(rrb.TimeSeriesView(origin="/mc", name="tr P(k|k-1): Monte Carlo vs exact vs centralized",
                                                contents=["/mc/**", "/bounds/**", "/central/**"],
                                                plot_legend=rrb.PlotLegend(rrb.Corner2D.RightBottom)),
                             rrb.GraphView(origin="/graph", name="communication graph"), row_shares=[2, 1]),
                rrb.Vertical(*[rrb.TimeSeriesView(origin=f"/nodes/{i}", name=f"agent {i}: estimates (red Carli, blue re-injection) and truth",
                                                  contents=[f"/nodes/{i}/estimate/**", "/truth/**"],
                                                  plot_legend=rrb.PlotLegend(visible=False)) for i in range(min(n, 4))]),
                column_shares=[3, 2], name="Monte Carlo and trials"),
            rrb.Grid(*[rrb.TimeSeriesView(origin=f"/nodes/{i}/error", name=f"agent {i}: error x(k) − x̂ᵢ(k|k-1)",
                                          plot_legend=rrb.PlotLegend(visible=False)) for i in range(min(n, 9))],
                     name="errors"),
            rrb.Grid(*[rrb.TimeSeriesView(origin=f"/nodes/{i}/consensus", name=f"agent {i}: consensus iterates (timeline 'round')",
                                          plot_legend=rrb.PlotLegend(rrb.Corner2D.LeftTop)) for i in range(min(n, 9))],
                     name="consensus rounds"),
            rrb.Horizontal(rrb.TextDocumentView(origin="/report", name="claims"),
                           rrb.TextDocumentView(origin="/claims", name="claim detail"), name="claims"),
        ),
        rrb.TimePanel(timeline="k", expanded=False),
        collapse_panels=True,
    )
    ts = tables["trace_series"]
    paths = tables["sample_paths"] if "sample_paths" in tables else None
    rounds = tables["consensus_rounds"] if "consensus_rounds" in tables else None
    z = z_for_confidence(BAND_CONFIDENCE)
    with rec_.recording(path, application_id="dse-savas", recording_id=f"savas-{sc.name}-seed{res.seed}",
                        blueprint=blueprint, properties=_properties(res, prov)) as rec:
        rec_.log_graph(rec, "graph", sc.graph.positions(), list(sc.graph.build().edges()),
                       labels=[f"agent {i}" for i in range(n)])
        rec_.log_tensor(rec, "graph/Q", _q_matrix(tables, n))
        for a, (alg, col) in enumerate((("carli", (214, 39, 40)), ("reinjection", (31, 119, 180)))):
            t = _cell_rows(ts, sc, alg, m, s_c)
            idx = rec_.sequence_index("k", t["k"].to_numpy())
            mc, se = t["trP_mc"].to_numpy(), t["trP_mc_se"].to_numpy()
            label = f"{alg} m={m} σ_c={s_c:g}"
            rec_.send_series(rec, f"mc/{alg}/trace", idx, mc, names=f"{label}: Monte Carlo", colors=[col], points=True)
            rec_.send_series(rec, f"mc/{alg}/band", idx, np.column_stack([mc - z * se, mc + z * se]),
                             names=[f"{label}: MC {BAND_CONFIDENCE:.0%} low", f"{label}: MC {BAND_CONFIDENCE:.0%} high"],
                             colors=[col, col], width=0.5)
            rec_.send_series(rec, f"bounds/{alg}/trace", idx, t["trP_exact"].to_numpy(), names=f"{label}: exact (22)",
                             colors=[col])
            if a == 0:
                rec_.send_series(rec, "central/kf_trace", idx, t["kf_trP"].to_numpy(),
                                 names="N · P_KF(k|k-1) (centralized KF)", colors=[(0, 0, 0)])
            if paths is None:
                continue
            p = _cell_rows(paths, sc, alg, m, s_c)
            if not len(p):
                continue
            n_paths, ks = int(p["trial"].max()) + 1, np.sort(p["k"].unique())
            pidx = rec_.sequence_index("k", ks)
            grid = lambda col_: p.pivot_table(index="k", columns=["trial", "node"], values=col_).to_numpy().reshape(len(ks), n_paths, n)
            x, xhat = grid("x")[:, :, 0], grid("xhat_pred")
            if a == 0:  # both filters share the random draws at equal m (compute.simulate_group)
                rec_.send_series(rec, "truth/x", pidx, x, names=[f"x(k), trial {q}" for q in range(n_paths)],
                                 colors=[(230, 230, 230)] * n_paths, width=2.5)
            r = _cell_rows(rounds, sc, alg, m, s_c)
            rounds_idx = rec_.sequence_index("round", np.arange(len(ks) * (m + 1)))
            for i in range(n):
                rec_.send_series(rec, f"nodes/{i}/estimate/{alg}", pidx, xhat[:, :, i],
                                 names=[f"{alg} x̂(k|k-1), trial {q}" for q in range(n_paths)], colors=[col] * n_paths)
                rec_.send_series(rec, f"nodes/{i}/error/{alg}", pidx, x - xhat[:, :, i],
                                 names=[f"{alg}, trial {q}" for q in range(n_paths)], colors=[col] * n_paths, width=1.0)
                zi = r[r["node"] == i].sort_values(["k", "round"])["z"].to_numpy()
                rec_.send_series(rec, f"nodes/{i}/consensus/{alg}", rounds_idx, zi,
                                 names=f"{alg} z(k+h/m|k), trial 0", colors=[col], points=True)
        rec_.log_claims(rec, claims, summary)


def write_figures_recording(res: Results, tables: Tables, path: Path, claims: list[dict], prov: dict, summary: str,
                            paper: bool = False) -> None:
    import rerun.blueprint as rrb

    from dse.outputs import record as rec_
    from dse.outputs.figures import sequential_colors

    sc = res.scenario
    metric = f"tr P({sc.eval_step}|{sc.eval_step - 1})"
    has_gains = "gains" in tables and len(tables["gains"]) > 0
    views = [rrb.TimeSeriesView(origin="/fig1", name=f"{_fig(paper, 1)}Carli's filter, {metric} vs m (lines exact, dots "
                                "Monte Carlo)", plot_legend=rrb.PlotLegend(rrb.Corner2D.LeftTop)),
             rrb.TimeSeriesView(origin="/fig3", name=f"{_fig(paper, 3)}re-injection filter, {metric} vs m (σ_c: dark 0 → "
                                "yellow max)", plot_legend=rrb.PlotLegend(visible=False))]
    if has_gains:
        hidden = rrb.PlotLegend(visible=False)
        views += [rrb.TimeSeriesView(origin="/fig2/ell", name=f"{_fig(paper, 2)}optimal ℓ* vs m (lines corrected (16), dots "
                                     "printed)", plot_legend=hidden),
                  rrb.TimeSeriesView(origin="/fig2/zeta", name=f"{_fig(paper, 2)}optimal ζ* vs m", plot_legend=hidden),
                  rrb.TimeSeriesView(origin="/fig2/J", name="optimal cost J* vs m", plot_legend=hidden)]
    blueprint = rrb.Blueprint(
        rrb.Tabs(rrb.Grid(*views, name="figures"),
                 rrb.Horizontal(rrb.TextDocumentView(origin="/report", name="claims"),
                                rrb.TextDocumentView(origin="/claims", name="claim detail"), name="claims")),
        rrb.TimePanel(timeline="m", expanded=False),
        collapse_panels=True,
    )
    cols = [tuple(int(255 * x) for x in c[:3]) for c in sequential_colors(len(sc.sigma_c), "plasma")]
    names = [f"σ_c = {s:g}" for s in sc.sigma_c]
    with rec_.recording(path, application_id="dse-savas", recording_id=f"savas-{sc.name}-figures-seed{res.seed}",
                        blueprint=blueprint, properties=_properties(res, prov)) as rec:
        idx = rec_.sequence_index("m", sc.rounds)
        for fig, alg in (("fig1", "carli"), ("fig3", "reinjection")):
            exact, mc, se = eval_trace_table(tables, sc, alg)
            rec_.send_series(rec, f"{fig}/exact", idx, exact.T, names=[f"{n} exact" for n in names], colors=cols)
            rec_.send_series(rec, f"{fig}/monte_carlo", idx, mc.T, names=[f"{n} Monte Carlo" for n in names], colors=cols, points=True)
            rec_.send_series(rec, f"{fig}/centralized_kf", idx, np.full(len(sc.rounds), _kf_eval(tables)),
                             names="centralized KF (lower bound)", colors=[(0, 0, 0)])
        if has_gains:
            midx = rec_.sequence_index("m", np.arange(sc.rounds_max + 1))
            for key in ("ell", "zeta", "J"):
                rec_.send_series(rec, f"fig2/{key}/corrected", midx, _gains(tables, sc, "corrected", key).T,
                                 names=[f"{n} corrected (16)" for n in names], colors=cols)
                rec_.send_series(rec, f"fig2/{key}/printed", midx, _gains(tables, sc, "printed", key).T,
                                 names=[f"{n} printed (16)" for n in names], colors=cols, points=True)
        rec_.log_claims(rec, claims, summary)


def write_outputs(res: Results, tables: Tables, out_dir: Path, claims: list[dict], prov: dict, paper: bool = False) -> None:
    """The figures and the two recordings, drawn in two forked workers when the run has them (the
    figures in one, the recordings in the other: each imports its library once)."""
    from dse.outputs.figures import draw_all

    counts = {s: sum(c["verdict"] == s for c in claims) for s in ("pass", "fail", "erratum", "not-checkable", "error")}
    summary = (f"# {res.scenario.name}: {counts['pass']} pass, {counts['fail']} fail, {counts['erratum']} erratum, "
               f"{counts['not-checkable']} not checkable, {counts['error']} error\n\nseed {res.seed}, "
               f"{res.trials:,} trials per cell")
    name = res.scenario.name

    def recordings():
        write_trials_recording(res, tables, out_dir / f"{name}.rrd", claims, prov, summary)
        write_figures_recording(res, tables, out_dir / f"{name}_figures.rrd", claims, prov, summary, paper)

    draw_all([lambda: write_figures(res, tables, out_dir, paper), recordings], workers=int(prov.get("workers", 1) or 1))
