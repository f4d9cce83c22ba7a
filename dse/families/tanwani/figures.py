"""The figures of a run (the paper's only figure is a schematic), drawn from the run's tables.

fig1_network_events.png   F1: sensor network (+ plant) and the edge-event raster of one clock path
fig2_traces_<s>.png       F2: tr P̄_i(t), exact tr E[e_ie_iᵀ](t), Monte Carlo with 95% band, tr P_KB(t), tr S, tr S_true
fig3_sample_path_<s>.png  F3: one clock path: tr P_i(t; τ) (eq. 14), tr E[e_ie_iᵀ | τ](t), tr P̄_i(t)
fig4_gaps_<s>.png         F4: smallest eigenvalues of P̄_i − E[e_ie_iᵀ] and of P_i(t; τ) − E[e_ie_iᵀ | τ]
fig5_rate_<s>.png         F5: ‖P̄_i^∞(λ) − S‖_F, explicit B_12(λ), slopes −1 and −1/2, ‖E[e_ie_iᵀ]^∞ − S_true‖_F
fig6_traces_vs_rate_<s>.png  F6: steady-state traces against λ
fig7_abscissa_<s>.png     F7: spectral abscissae of the generators of (9) and of the exact covariance against λ
fig_topology.png          S4: topology sweep (paper only)
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from dse.outputs.figures import new_figure, plain_log_labels, save_figure, set_margins

from .views import PAPER_NOTE, ScenarioTables

Z95 = 1.959964


def _save(fig, path: Path, **margins) -> None:
    """Fixed margins (inches) instead of tight_layout's extra measuring draw; log-axis labels without mathtext."""
    set_margins(fig, **margins)
    plain_log_labels(fig)
    save_figure(fig, path, tight=False)


def _node_axes(N, width=4.2, height=3.0):
    cols = min(N, 3)
    rows = int(math.ceil(N / cols))
    fig, axes = new_figure(ncols=cols, nrows=rows, width=width, height=height)
    return fig, axes.ravel()


def _main_series(v: ScenarioTables):
    s = v["series"]
    return s[s["rate"] == v.main_rate]


def fig1(v: ScenarioTables, path: Path, note: str = "") -> None:
    nodes, edges = v["graph_nodes"], v["graph_edges"]
    pos = nodes[["x", "y"]].to_numpy()
    N = len(pos)
    fig, axes = new_figure(ncols=2, width=5.2, height=4.0)
    ax = axes[0, 0]
    plant = np.array([pos[:, 0].max() + 1.6, pos[:, 1].mean()])
    for i in range(N):
        ax.plot([plant[0], pos[i, 0]], [plant[1], pos[i, 1]], color="0.8", lw=0.8, zorder=0)
    for i, j in {tuple(sorted(e)) for e in edges[["i", "j"]].to_numpy().tolist()}:
        ax.plot(pos[[i, j], 0], pos[[i, j], 1], "k--", lw=1.2)
    ax.scatter(pos[:, 0], pos[:, 1], s=500, c="tab:blue", zorder=3)
    for i in range(N):
        ax.text(pos[i, 0], pos[i, 1], f"{i}", color="w", ha="center", va="center", zorder=4)
    ax.scatter([plant[0]], [plant[1]], s=900, marker="s", c="tab:gray", zorder=3)
    ax.text(plant[0], plant[1], "plant", color="w", ha="center", va="center", zorder=4, fontsize=8)
    ax.set_axis_off()
    ax.set_title("sensor units (filters), dashed: random-time communication;\ngrey: measurements y_i", fontsize=9)
    ax = axes[0, 1]
    ev = v["path_events"]
    ev = ev[ev["path"] == 0]
    for k, (i, j) in enumerate(edges[["i", "j"]].to_numpy()):
        ax.vlines(ev.loc[ev["clock"] == k, "t"].to_numpy(), k - 0.4, k + 0.4, color=f"C{k % 10}", lw=1)
    ax.set_yticks(range(len(edges)), [f"{i}–{j}" for i, j in edges[["i", "j"]].to_numpy()])
    ax.set_xlabel("t")
    ax.set_ylabel("edge clock")
    ax.set_title(f"Poisson rings of every edge, one path, λ = {v.main_rate:g}", fontsize=9)
    fig.suptitle(f"Fig. 1 (regenerated): {v.title}" if note else f"Network and edge events: {v.title}", fontsize=10)
    _save(fig, path, left=0.25, top=0.85, wspace=0.8)


def fig2(v: ScenarioTables, path: Path, note: str = "") -> None:
    N, lam = v.N, v.main_rate
    fig, axes = _node_axes(N)
    s = _main_series(v)
    t = np.unique(s["t"].to_numpy())
    P, J, kb = v.by_node(s, "trP_bound"), v.by_node(s, "trP_exact"), v.by_node(s, "trP_kb")[:, 0]
    mc = v["mc_series"]
    grid = mc[(mc["simulator"] == "gridded") & (mc["rate"] == lam)]
    event = mc[mc["simulator"] == "event"]
    g, gse = v.by_node(grid, "trP_mc"), v.by_node(grid, "trP_mc_se")
    e, ese = v.by_node(event, "trP_mc"), v.by_node(event, "trP_mc_se")
    trS, trSt = v.design("trS"), v.design("trS_true")
    for i in range(N):
        ax = axes[i]
        ax.plot(t, P[:, i], "C3", lw=1.6, label="tr P̄_i(t), bound (9)")
        if np.isfinite(J[:, i]).any():
            ax.plot(t, J[:, i], "k", lw=1.2, label="tr E[e_ie_iᵀ] exact (mean covariance ODE)")
        ax.fill_between(t, g[:, i] - Z95 * gse[:, i], g[:, i] + Z95 * gse[:, i], color="C0", alpha=0.3,
                        label=f"gridded MC, {int(grid['trials'].iloc[0])} trials, 95%")
        step = max(1, len(t) // 20)
        ax.errorbar(t[::step], e[::step, i], yerr=Z95 * ese[::step, i], fmt="o", ms=2.5, color="C2", lw=0.8,
                    label=f"event-driven MC, {int(event['trials'].iloc[0])} trials")
        ax.plot(t, kb, "C7", lw=1.2, label="tr P_KB(t), Kalman–Bucy")
        if np.isfinite(trS):
            ax.axhline(trS, color="C3", ls="--", lw=0.9, label="tr S (11)")
            ax.axhline(trSt, color="k", ls=":", lw=0.9, label="tr S_true")
        ax.set_title(f"node {i}", fontsize=9)
        ax.set_xlabel("t")
    for ax in axes[N:]:
        ax.set_axis_off()
    axes[0].legend(fontsize=6)
    fig.suptitle(f"Traces at λ = {lam:g}, {v.title} {note}".strip(), fontsize=9)
    _save(fig, path, left=0.45, top=0.55, wspace=0.45, hspace=0.8)


def fig3(v: ScenarioTables, path: Path, note: str = "") -> None:
    N = v.N
    fig, axes = _node_axes(N)
    ps = v["path_series"]
    ps = ps[ps["path"] == 0]
    t = np.unique(ps["t"].to_numpy())
    P, Sg = v.by_node(ps, "trP_path"), v.by_node(ps, "trSigma_path")
    mean = v.by_node(_main_series(v), "trP_bound")
    for i in range(N):
        ax = axes[i]
        ax.plot(t, P[:, i], "C3", lw=1.2, label="tr P_i(t; τ), eq. (14)")
        ax.plot(t, Sg[:, i], "k", lw=1.2, label="tr E[e_ie_iᵀ | τ](t), exact")
        ax.plot(t, mean[:, i], "C3--", lw=0.9, label="tr P̄_i(t), eq. (9)")
        mine = v.node_events(0, i)
        ax.vlines(mine, 0, 0.05 * np.nanmax(P[:, i]), color="C0", lw=0.6)
        ax.set_title(f"node {i} ({len(mine)} events)", fontsize=9)
        ax.set_xlabel("t")
    for ax in axes[N:]:
        ax.set_axis_off()
    axes[0].legend(fontsize=6)
    fig.suptitle(f"Fig. 3: one clock path at λ = {v.main_rate:g} (output grid {v.design('output_step'):g}; ticks = events), "
                 f"{v.name} {note}".strip(), fontsize=9)
    _save(fig, path, left=0.45, top=0.55, wspace=0.45, hspace=0.8)


def fig4(v: ScenarioTables, path: Path, note: str = "") -> None:
    N = v.N
    fig, axes = new_figure(ncols=2, width=5.0, height=3.6)
    ax = axes[0, 0]
    s = v["series"]
    for lam in v.rates:
        at = s[s["rate"] == lam]
        g = v.by_node(at, "gap_bound_exact")
        if not np.isfinite(g).any():
            continue
        t = np.unique(at["t"].to_numpy())
        for i in range(N):
            ax.plot(t, g[:, i], lw=1, label=f"λ = {lam:g}, node {i}")
    ax.axhline(0, color="k", lw=0.6)
    ax.set_title("min eig(P̄_i(t) − E[e_ie_iᵀ](t)) ≥ 0 (Thm III.1.1)", fontsize=9)
    ax.set_xlabel("t")
    ax.legend(fontsize=6, ncol=2)
    ax = axes[0, 1]
    ps = v["path_series"]
    paths = sorted(ps["path"].unique())
    for p in paths:
        at = ps[ps["path"] == p]
        g = v.by_node(at, "gap_path")
        t = np.unique(at["t"].to_numpy())
        for i in range(N):
            ax.plot(t, g[:, i], lw=0.8, color=f"C{i}", alpha=0.8, label=f"node {i}" if p == 0 else None)
    ax.axhline(0, color="k", lw=0.6)
    ax.set_title(f"min eig(P_i(t; τ) − E[e_ie_iᵀ | τ](t)) ≥ 0 (Prop III.2), {len(paths)} paths", fontsize=9)
    ax.set_xlabel("t")
    ax.legend(fontsize=6)
    fig.suptitle(f"Gaps of the bounds, {v.name} {note}".strip(), fontsize=9)
    _save(fig, path, left=0.6, top=0.6, wspace=0.7)


def fig5(v: ScenarioTables, path: Path, note: str = "") -> None:
    fig, axes = new_figure(width=6.8, height=4.6)
    ax = axes[0, 0]
    if v.design("abar_hurwitz") != 1:
        ax.text(0.5, 0.5, "Ā not Hurwitz: item 2 does not apply", transform=ax.transAxes, ha="center")
        _save(fig, path)
        return
    sw, nodes = v["sweep"], v["sweep_nodes"]
    lams = sw["rate"].to_numpy()
    d = v.by_node(nodes, "dev_bound", index="rate")
    for i in range(v.N):
        ax.loglog(lams, d[:, i], lw=1.2, label=f"‖P̄_{i}^∞ − S‖_F")
    ax.loglog(lams, sw["dev_exact"].to_numpy(), "k", lw=1.2, label="max_i ‖E[e_ie_iᵀ]^∞ − S_true‖_F")
    for variant, st in (("faithful", "C3:"), ("tight", "C3-.")):
        ax.loglog(lams, sw[f"B12_{variant}"].to_numpy(), st, lw=1.2, label=f"explicit B_12(λ), {variant} constants")
        ax.axvline(v.design(f"explicit_{variant}.threshold"), color="C3", ls=st[2:], lw=0.6)
    fin = np.isfinite(d[:, 0]) & (d[:, 0] > 0)
    if fin.any():
        l0, d0 = lams[fin][len(lams[fin]) // 2], d[fin][len(lams[fin]) // 2].max()
        ax.loglog(lams[fin], d0 * (lams[fin] / l0) ** -1, color="0.6", lw=0.8, label="slope −1")
        ax.loglog(lams[fin], d0 * (lams[fin] / l0) ** -0.5, color="0.6", ls="--", lw=0.8, label="slope −1/2 (paper)")
    top = np.nanmax(d) if np.isfinite(np.nanmax(d)) else 1.0
    for key, lab in (("crit_bound", "λ_crit (9)"), ("crit_joint", "λ_crit exact")):
        c = v.design(key)
        if np.isfinite(c) and c > 0:
            ax.axvline(c, color="k", ls=":", lw=0.8)
            ax.text(c, top, lab, rotation=90, fontsize=6, va="top")
    ax.set_xlabel("λ")
    ax.set_ylabel("Frobenius distance")
    ax.legend(fontsize=6)
    ax.set_title(f"Practical convergence (12), {v.name}" + (f"\n{note}" if note else ""), fontsize=9)
    _save(fig, path, left=0.75, top=0.5)


def fig6(v: ScenarioTables, path: Path, note: str = "") -> None:
    fig, axes = new_figure(width=6.8, height=4.4)
    ax = axes[0, 0]
    nodes = v["sweep_nodes"]
    lams = np.unique(nodes["rate"].to_numpy())
    P, J = v.by_node(nodes, "trP_bound", index="rate"), v.by_node(nodes, "trP_exact", index="rate")
    for i in range(v.N):
        ax.semilogx(lams, P[:, i], f"C{i}", lw=1.2, label=f"tr P̄_{i}^∞")
        ax.semilogx(lams, J[:, i], f"C{i}--", lw=1.0, label=f"tr E[e_{i}e_{i}ᵀ]^∞")
    if np.isfinite(v.design("trS")):
        ax.axhline(v.design("trS"), color="C3", ls=":", label="tr S")
        ax.axhline(v.design("trS_true"), color="k", ls=":", label="tr S_true")
    if np.isfinite(v.design("trP_kb")):
        ax.axhline(v.design("trP_kb"), color="C7", lw=0.8, label="tr P_KB")
    finite = P[np.isfinite(P)]
    if finite.size:
        ax.set_ylim(0, min(finite.max(), 8 * np.median(finite)) * 1.05)
    ax.set_xlabel("λ")
    ax.set_ylabel("trace")
    ax.legend(fontsize=6, ncol=2)
    ax.set_title(f"Steady-state traces (bound diverges below λ_crit = {v.design('crit_bound'):.4g}), {v.name}", fontsize=9)
    _save(fig, path, left=0.6)


def fig7(v: ScenarioTables, path: Path, note: str = "") -> None:
    fig, axes = new_figure(width=6.4, height=4.0)
    ax = axes[0, 0]
    sw = v["sweep"]
    ax.semilogx(sw["rate"], sw["abscissa_bound"], "C3", label="abscissa of M_9(λ), eq. (9)")
    ax.semilogx(sw["rate"], sw["abscissa_exact"], "k", label="abscissa of M_Σ(λ), exact covariance")
    ax.axhline(0, color="0.5", lw=0.6)
    for key in ("crit_bound", "crit_joint"):
        c = v.design(key)
        if np.isfinite(c) and c > 0:
            ax.axvline(c, color="k", ls=":", lw=0.8)
    ax.set_xlabel("λ")
    ax.set_ylabel("max Re eig")
    ax.set_ylim(max(-10, np.nanmin(sw["abscissa_bound"]) * 1.1), None)
    ax.legend(fontsize=7)
    ax.set_title(f"Critical rates, {v.name}: λ_crit(9) = {v.design('crit_bound'):.5g}, exact = "
                 f"{v.design('crit_joint'):.5g}", fontsize=9)
    _save(fig, path, left=0.6)


def fig_topology(tables, path: Path, note: str = PAPER_NOTE) -> None:
    fig, axes = new_figure(ncols=2, width=5.0, height=4.0)
    topo, graphs = tables["topology"], tables["topology_graphs"].set_index("graph")
    for k, name in enumerate(graphs.index):
        at = topo[topo["graph"] == name]
        d = at.pivot(index="rate", columns="node", values="dev_bound")     # NaN rows: below the critical rate
        tr = at.pivot(index="rate", columns="node", values="trP_exact")
        x = d.index.to_numpy() * float(graphs.loc[name, "alpha_fiedler"])
        axes[0, 0].loglog(x, d.to_numpy().max(axis=1), f"C{k}", label=name)
        axes[0, 1].semilogx(x, tr.to_numpy().mean(axis=1), f"C{k}", label=name)
    axes[0, 0].set_xlabel("λ α σ_2(ℒ)")
    axes[0, 0].set_ylabel("max_i ‖P̄_i^∞ − S‖_F")
    axes[0, 1].set_xlabel("λ α σ_2(ℒ)")
    axes[0, 1].set_ylabel("mean_i tr E[e_ie_iᵀ]^∞")
    axes[0, 0].legend()
    fig.suptitle(f"S4: S2's plant and sensors on four graphs of 4 nodes {note}", fontsize=9)
    _save(fig, path, left=0.75, top=0.45, wspace=0.85)


#: the figures drawn for every scenario: (file stem, function)
PER_SCENARIO = (("fig2_traces", fig2), ("fig3_sample_path", fig3), ("fig4_gaps", fig4), ("fig5_rate", fig5),
                ("fig6_traces_vs_rate", fig6), ("fig7_abscissa", fig7))
