"""The figures (PNG) of a noisy-consensus-filter run, drawn from its tables: Figs. 1 and 3 (the metric
tr P(k_eval|k_eval−1) of each filter against m, exact and Monte Carlo), Fig. 2 (the optimal gains and
costs) and the trace over k of one cell. The helpers that read the tables serve the recordings too.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from dse.contract.views import Outputs, View
from dse.simulate.stats import z_for_confidence

# matplotlib (dse.outputs.figures) is imported by the functions that draw: the figures and the recordings
# are drawn in forked workers, each importing only what it draws with.

BAND_CONFIDENCE = 0.95


def eval_trace_table(tables, sc, alg: str):
    """Exact and Monte Carlo tr P(k_eval) with its SE, arrays (S, M) over σ_c × m."""
    sw = sc.sweep
    cells = tables["cells"]
    cells = cells[(cells["alg"] == alg) & (cells["n_steps"] == sw.n_steps)]
    ts = tables["trace_series"]
    ts = ts[(ts["alg"] == alg) & (ts["n_steps"] == sw.n_steps) & (ts["k"] == sw.eval_step)]
    exact = cells.pivot(index="sigma_c", columns="m", values="trP_eval").loc[list(sw.sigma_c), list(sw.rounds)]
    mc = ts.pivot(index="sigma_c", columns="m", values="trP_mc").loc[list(sw.sigma_c), list(sw.rounds)]
    se = ts.pivot(index="sigma_c", columns="m", values="trP_mc_se").loc[list(sw.sigma_c), list(sw.rounds)]
    return exact.to_numpy(), mc.to_numpy(), se.to_numpy()


def kf_eval(tables) -> float:
    return float(tables["cells"]["kf_trP_eval"].iloc[0])


def showcase(sc):
    """The cell shown in the per-trial views: m = 2 (or the largest ≤ 2 > 0), σ_c closest to 1."""
    m = max([m for m in sc.sweep.rounds if 0 < m <= 2] or [sc.sweep.rounds[-1]])
    s_c = min(sc.sweep.sigma_c, key=lambda s: abs(s - 1.0))
    return m, s_c


def cell_rows(frame: pd.DataFrame, sc, alg: str, m: int, s_c: float) -> pd.DataFrame:
    return frame[(frame["alg"] == alg) & (frame["m"] == m) & (frame["sigma_c"] == s_c)
                 & (frame["n_steps"] == sc.sweep.n_steps)]


def gain_table(tables, sc, objective: str, key: str) -> np.ndarray:
    """One column of the optimal-gain tables, (σ_c, m = 0..rounds_max)."""
    g = tables["gains"]
    g = g[(g["objective"] == objective) & (g["m"] <= sc.rounds_max)]
    return g.pivot(index="sigma_c", columns="m", values=key).loc[list(sc.sweep.sigma_c)].to_numpy()


def fig_label(paper: bool, number: int) -> str:
    """'Fig. N: ' in the paper's reproduction only (a user's scenario is not the paper's figure)."""
    return f"Fig. {number}: " if paper else ""


def _metric_figure(tables, sc, trials: int, alg: str, title: str, path: Path) -> None:
    from dse.outputs.figures import new_figure, save_figure, sequential_colors, set_margins

    sw = sc.sweep
    exact, mc, se = eval_trace_table(tables, sc, alg)
    z = z_for_confidence(BAND_CONFIDENCE)
    fig, axes = new_figure(width=8.0)
    ax = axes[0, 0]
    for s, (s_c, col) in enumerate(zip(sw.sigma_c, sequential_colors(len(sw.sigma_c), "plasma"))):
        ax.plot(sw.rounds, exact[s], "-", color=col, lw=1.4, label=f"σ_c = {s_c:g}")
        ax.errorbar(sw.rounds, mc[s], yerr=z * se[s], fmt="o", color=col, ms=3.5, capsize=2)
    ax.axhline(kf_eval(tables), color="k", ls=":", lw=1, label="centralized KF (lower bound)")
    ax.set_xlabel("consensus rounds m")
    ax.set_ylabel(f"Σᵢ var(x̃ᵢ({sw.eval_step}|{sw.eval_step - 1}))")
    ax.set_title(f"{title}\nlines: exact recursion; markers: {trials:,} Monte Carlo runs ± {BAND_CONFIDENCE:.0%} CI",
                 fontsize=9)
    ax.set_xticks(sw.rounds)
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0)
    set_margins(fig, left=0.8, right=2.7, top=0.6, bottom=0.55)   # the legend right of the axes
    save_figure(fig, path, tight=False)


def _gains_figure(tables, sc, path: Path) -> None:
    from dse.outputs.figures import new_figure, save_figure, sequential_colors, set_margins

    ms = np.arange(sc.rounds_max + 1)
    fig, axes = new_figure(ncols=3, width=4.6)
    cols = sequential_colors(len(sc.sweep.sigma_c), "plasma")
    for ax, key in zip(axes[0], ("ell", "zeta", "J")):
        corrected, printed = gain_table(tables, sc, "corrected", key), gain_table(tables, sc, "printed", key)
        for s, s_c in enumerate(sc.sweep.sigma_c):
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


def _trace_over_k_figure(tables, sc, path: Path) -> None:
    from dse.outputs.figures import new_figure, save_figure, set_margins

    m, s_c = showcase(sc)
    fig, axes = new_figure()
    ax = axes[0, 0]
    z = z_for_confidence(BAND_CONFIDENCE)
    ts = tables["trace_series"]
    for alg, col in (("carli", "tab:red"), ("reinjection", "tab:blue")):
        t = cell_rows(ts, sc, alg, m, s_c)
        ax.plot(t["k"], t["trP_exact"], "-", color=col, label=f"{alg}: exact (22)")
        ax.fill_between(t["k"], t["trP_mc"] - z * t["trP_mc_se"], t["trP_mc"] + z * t["trP_mc_se"], color=col, alpha=0.25,
                        label=f"{alg}: Monte Carlo {BAND_CONFIDENCE:.0%} band")
    ax.plot(t["k"], t["kf_trP"], "k:", label="N · centralized KF")
    if sc.sweep.n_steps > 1000:
        ax.set_xscale("symlog", linthresh=10)
    ax.set_xlabel("k")
    ax.set_ylabel("tr P(k|k−1)")
    ax.set_title(f"m = {m}, σ_c = {s_c:g}", fontsize=9)
    ax.legend()
    set_margins(fig, left=0.75, right=0.15, top=0.35, bottom=0.55)
    save_figure(fig, path, tight=False)


def views(out: Outputs) -> list[View]:
    """figures/fig1.png, fig2.png (with gain tables), fig3.png and trace_over_k.png."""
    sc, tables, paper, trials = out.results.scenario, out.tables, out.reproduction.is_paper, out.results.trials
    found = [View("figures/fig1.png", lambda p: _metric_figure(
        tables, sc, trials, "carli", f"{fig_label(paper, 1)}two-stage filter (7)+(9) under communication noise, "
        f"ℓ = {sc.carli.ell:g}", p))]
    if "gains" in tables and len(tables["gains"]):
        found.append(View("figures/fig2.png", lambda p: _gains_figure(tables, sc, p)))
    found.append(View("figures/fig3.png", lambda p: _metric_figure(
        tables, sc, trials, "reinjection", f"{fig_label(paper, 3)}re-injection filter (11)-(13), "
        f"{sc.reinjection.gains} gains", p)))
    found.append(View("figures/trace_over_k.png", lambda p: _trace_over_k_figure(tables, sc, p)))
    return found
