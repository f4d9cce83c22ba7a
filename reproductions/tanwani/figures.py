"""The figures of a run (the paper's only figure is a schematic).

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

import estimators.gossip_covariance as gc
from pipeline.figures import new_figure, save_figure

from .compute import Results, ScenarioResults, TOPOLOGIES

Z95 = 1.959964
PAPER_NOTE = "(scenario of this reproduction: the paper has no numerical example)"


def _tr(X):
    return np.trace(X, axis1=-2, axis2=-1)


def _node_axes(N, width=4.2, height=3.0):
    cols = min(N, 3)
    rows = int(math.ceil(N / cols))
    fig, axes = new_figure(ncols=cols, nrows=rows, width=width, height=height)
    return fig, axes.ravel()


def fig1(r: ScenarioResults, path: Path, note: str = "") -> None:
    s = r.sys
    pos = r.scenario.graph.positions()
    fig, axes = new_figure(ncols=2, width=5.2, height=4.0)
    ax = axes[0, 0]
    plant = np.array([pos[:, 0].max() + 1.6, pos[:, 1].mean()])
    for i in range(s.N):
        ax.plot([plant[0], pos[i, 0]], [plant[1], pos[i, 1]], color="0.8", lw=0.8, zorder=0)
    for i, j in s.edges:
        ax.plot(pos[[i, j], 0], pos[[i, j], 1], "k--", lw=1.2)
    ax.scatter(pos[:, 0], pos[:, 1], s=500, c="tab:blue", zorder=3)
    for i in range(s.N):
        ax.text(pos[i, 0], pos[i, 1], f"{i + 1}", color="w", ha="center", va="center", zorder=4)
    ax.scatter([plant[0]], [plant[1]], s=900, marker="s", c="tab:gray", zorder=3)
    ax.text(plant[0], plant[1], "plant", color="w", ha="center", va="center", zorder=4, fontsize=8)
    ax.set_axis_off()
    ax.set_title("sensor units (filters), dashed: random-time communication;\ngrey: measurements y_i", fontsize=9)
    ax = axes[0, 1]
    t, c = r.event["sample_event_times"][0], r.event["sample_event_clocks"][0]
    for k, (i, j) in enumerate(s.clocks):
        tk = t[(c == k) & np.isfinite(t)]
        ax.vlines(tk, k - 0.4, k + 0.4, color=f"C{k % 10}", lw=1)
    ax.set_yticks(range(len(s.clocks)), [f"{i + 1}–{j + 1}" for i, j in s.clocks])
    ax.set_xlabel("t")
    ax.set_ylabel("edge clock")
    ax.set_title(f"Poisson rings of every edge, one path, λ = {r.scenario.main_rate:g}", fontsize=9)
    fig.suptitle(f"Fig. 1 (regenerated): {r.scenario.title}" if note else f"Network and edge events: {r.scenario.title}",
                 fontsize=10)
    save_figure(fig, path)


def fig2(r: ScenarioResults, path: Path, note: str = "") -> None:
    sc, s, b = r.scenario, r.sys, r.bounds
    t = sc.output_times
    lam = sc.main_rate
    fig, axes = _node_axes(s.N)
    P, J = _tr(r.bound(lam)), (None if r.joint(lam) is None else _tr(gc.diagonal_blocks(r.joint(lam), s.N, s.n)))
    mc, se = r.grid_moments(lam).trace()
    emc, ese = r.event_moments().trace()
    for i in range(s.N):
        ax = axes[i]
        ax.plot(t, P[:, i], "C3", lw=1.6, label="tr P̄_i(t), bound (9)")
        if J is not None:
            ax.plot(t, J[:, i], "k", lw=1.2, label="tr E[e_ie_iᵀ] exact (mean covariance ODE)")
        ax.fill_between(t, mc[:, i] - Z95 * se[:, i], mc[:, i] + Z95 * se[:, i], color="C0", alpha=0.3,
                        label=f"gridded MC, {r.trials} trials, 95%")
        ax.errorbar(t[::5], emc[::5, i], yerr=Z95 * ese[::5, i], fmt="o", ms=2.5, color="C2", lw=0.8,
                    label=f"event-driven MC, {int(r.event['n'])} trials")
        ax.plot(t, _tr(b["P_kb_t"]), "C7", lw=1.2, label="tr P_KB(t), Kalman–Bucy")
        if "S" in b:
            ax.axhline(np.trace(b["S"]), color="C3", ls="--", lw=0.9, label="tr S (11)")
            ax.axhline(np.trace(b["S_true"]), color="k", ls=":", lw=0.9, label="tr S_true")
        ax.set_title(f"node {i + 1}", fontsize=9)
        ax.set_xlabel("t")
    for ax in axes[s.N:]:
        ax.set_axis_off()
    axes[0].legend(fontsize=6)
    fig.suptitle(f"Traces at λ = {lam:g}, {sc.title} {note}".strip(), fontsize=9)
    save_figure(fig, path)


def fig3(r: ScenarioResults, path: Path, note: str = "") -> None:
    sc, s = r.scenario, r.sys
    t = sc.output_times
    fig, axes = _node_axes(s.N)
    P, Sg = _tr(r.event["sample_pbound"][0]), _tr(r.event["sample_sigma"][0])
    mean = _tr(r.bound(sc.main_rate))
    et, ec = r.event["sample_event_times"][0], r.event["sample_event_clocks"][0]
    for i in range(s.N):
        ax = axes[i]
        ax.plot(t, P[:, i], "C3", lw=1.2, label="tr P_i(t; τ), eq. (14)")
        ax.plot(t, Sg[:, i], "k", lw=1.2, label="tr E[e_ie_iᵀ | τ](t), exact")
        ax.plot(t, mean[:, i], "C3--", lw=0.9, label="tr P̄_i(t), eq. (9)")
        mine = [tt for tt, cc in zip(et, ec) if cc >= 0 and i in s.clocks[cc][: (2 if s.mode == "edge" else 1)]]
        ax.vlines(mine, 0, 0.05 * np.nanmax(P[:, i]), color="C0", lw=0.6)
        ax.set_title(f"node {i + 1} ({len(mine)} events)", fontsize=9)
        ax.set_xlabel("t")
    for ax in axes[s.N:]:
        ax.set_axis_off()
    axes[0].legend(fontsize=6)
    fig.suptitle(f"Fig. 3: one clock path at λ = {sc.main_rate:g} (output grid {sc.output_step:g}; ticks = events), "
                 f"{sc.name} {note}".strip(), fontsize=9)
    save_figure(fig, path)


def fig4(r: ScenarioResults, path: Path, note: str = "") -> None:
    sc, s = r.scenario, r.sys
    t = sc.output_times
    fig, axes = new_figure(ncols=2, width=5.0, height=3.6)
    from .claims import min_eig

    ax = axes[0, 0]
    for lam in sc.rates:
        if r.joint(lam) is None:
            continue
        g = min_eig(r.bound(lam) - gc.diagonal_blocks(r.joint(lam), s.N, s.n))
        for i in range(s.N):
            ax.plot(t, g[:, i], lw=1, label=f"λ = {lam:g}, node {i + 1}")
    ax.axhline(0, color="k", lw=0.6)
    ax.set_title("min eig(P̄_i(t) − E[e_ie_iᵀ](t)) ≥ 0 (Thm III.1.1)", fontsize=9)
    ax.set_xlabel("t")
    ax.legend(fontsize=6, ncol=2)
    ax = axes[0, 1]
    for p in range(r.event["sample_pbound"].shape[0]):
        g = min_eig(r.event["sample_pbound"][p] - r.event["sample_sigma"][p])
        for i in range(s.N):
            ax.plot(t, g[:, i], lw=0.8, color=f"C{i}", alpha=0.8, label=f"node {i + 1}" if p == 0 else None)
    ax.axhline(0, color="k", lw=0.6)
    ax.set_title(f"min eig(P_i(t; τ) − E[e_ie_iᵀ | τ](t)) ≥ 0 (Prop III.2), {r.event['sample_pbound'].shape[0]} paths",
                 fontsize=9)
    ax.set_xlabel("t")
    ax.legend(fontsize=6)
    fig.suptitle(f"Gaps of the bounds, {sc.name} {note}".strip(), fontsize=9)
    save_figure(fig, path)


def fig5(r: ScenarioResults, path: Path, note: str = "") -> None:
    sc, b, s = r.scenario, r.bounds, r.sys
    fig, axes = new_figure(width=6.8, height=4.6)
    ax = axes[0, 0]
    lams = b["sweep"]
    if "S" not in b:
        ax.text(0.5, 0.5, "Ā not Hurwitz: item 2 does not apply", transform=ax.transAxes, ha="center")
        save_figure(fig, path)
        return
    d = np.linalg.norm(b["sweep_bound"] - b["S"], axis=(2, 3))
    for i in range(s.N):
        ax.loglog(lams, d[:, i], lw=1.2, label=f"‖P̄_{i + 1}^∞ − S‖_F")
    dt = np.linalg.norm(b["sweep_joint"] - b["S_true"], axis=(2, 3)).max(axis=1)
    ax.loglog(lams, dt, "k", lw=1.2, label="max_i ‖E[e_ie_iᵀ]^∞ − S_true‖_F")
    for variant, st in (("faithful", "C3:"), ("tight", "C3-.")):
        ax.loglog(lams, b[f"sweep_explicit_{variant}"], st, lw=1.2, label=f"explicit B_12(λ), {variant} constants")
        ax.axvline(b[f"explicit_{variant}"][-1], color="C3", ls=st[2:], lw=0.6)
    fin = np.isfinite(d[:, 0]) & (d[:, 0] > 0)
    if fin.any():
        l0, d0 = lams[fin][len(lams[fin]) // 2], d[fin][len(lams[fin]) // 2].max()
        ax.loglog(lams[fin], d0 * (lams[fin] / l0) ** -1, color="0.6", lw=0.8, label="slope −1")
        ax.loglog(lams[fin], d0 * (lams[fin] / l0) ** -0.5, color="0.6", ls="--", lw=0.8, label="slope −1/2 (paper)")
    for key, lab in (("crit_bound", "λ_crit (9)"), ("crit_joint", "λ_crit exact")):
        if key in b and np.isfinite(b[key]) and b[key] > 0:
            ax.axvline(float(b[key]), color="k", ls=":", lw=0.8)
            ax.text(float(b[key]), ax.get_ylim()[1] if False else np.nanmax(d) if np.isfinite(np.nanmax(d)) else 1, lab,
                    rotation=90, fontsize=6, va="top")
    ax.set_xlabel("λ")
    ax.set_ylabel("Frobenius distance")
    ax.legend(fontsize=6)
    ax.set_title(f"Practical convergence (12), {sc.name}" + (f"\n{note}" if note else ""), fontsize=9)
    save_figure(fig, path)


def fig6(r: ScenarioResults, path: Path, note: str = "") -> None:
    sc, b, s = r.scenario, r.bounds, r.sys
    fig, axes = new_figure(width=6.8, height=4.4)
    ax = axes[0, 0]
    lams = b["sweep"]
    for i in range(s.N):
        ax.semilogx(lams, _tr(b["sweep_bound"][:, i]), f"C{i}", lw=1.2, label=f"tr P̄_{i + 1}^∞")
        ax.semilogx(lams, _tr(b["sweep_joint"][:, i]), f"C{i}--", lw=1.0, label=f"tr E[e_{i + 1}e_{i + 1}ᵀ]^∞")
    if "S" in b:
        ax.axhline(np.trace(b["S"]), color="C3", ls=":", label="tr S")
        ax.axhline(np.trace(b["S_true"]), color="k", ls=":", label="tr S_true")
    if "P_kb" in b:
        ax.axhline(np.trace(b["P_kb"]), color="C7", lw=0.8, label="tr P_KB")
    finite = _tr(b["sweep_bound"])[np.isfinite(_tr(b["sweep_bound"]))]
    if finite.size:
        ax.set_ylim(0, min(finite.max(), 8 * np.median(finite)) * 1.05)
    ax.set_xlabel("λ")
    ax.set_ylabel("trace")
    ax.legend(fontsize=6, ncol=2)
    ax.set_title(f"Steady-state traces (bound diverges below λ_crit = {float(b['crit_bound']):.4g}), "
                 f"{sc.name}", fontsize=9)
    save_figure(fig, path)


def fig7(r: ScenarioResults, path: Path, note: str = "") -> None:
    sc, b = r.scenario, r.bounds
    fig, axes = new_figure(width=6.4, height=4.0)
    ax = axes[0, 0]
    ax.semilogx(b["sweep"], b["sweep_absc_bound"], "C3", label="abscissa of M_9(λ), eq. (9)")
    ax.semilogx(b["sweep"], b["sweep_absc_joint"], "k", label="abscissa of M_Σ(λ), exact covariance")
    ax.axhline(0, color="0.5", lw=0.6)
    for key in ("crit_bound", "crit_joint"):
        if key in b and np.isfinite(b[key]) and b[key] > 0:
            ax.axvline(float(b[key]), color="k", ls=":", lw=0.8)
    ax.set_xlabel("λ")
    ax.set_ylabel("max Re eig")
    ax.set_ylim(max(-10, np.nanmin(b["sweep_absc_bound"]) * 1.1), None)
    ax.legend(fontsize=7)
    ax.set_title(f"Critical rates, {sc.name}: λ_crit(9) = {float(b['crit_bound']):.5g}, exact = "
                 f"{float(b.get('crit_joint', np.nan)):.5g}", fontsize=9)
    save_figure(fig, path)


def fig_topology(topo: dict, path: Path, note: str = PAPER_NOTE) -> None:
    fig, axes = new_figure(ncols=2, width=5.0, height=4.0)
    lams = topo["lams"]
    for k, name in enumerate(TOPOLOGIES):
        x = lams * float(topo[f"{name}_alpha_fiedler"])
        d, tr = topo[f"{name}_d"], topo[f"{name}_trace_joint"]    # NaN rows: below the critical rate
        axes[0, 0].loglog(x, d.max(axis=1), f"C{k}", label=name)
        axes[0, 1].semilogx(x, tr.mean(axis=1), f"C{k}", label=name)
    axes[0, 0].set_xlabel("λ α σ_2(ℒ)")
    axes[0, 0].set_ylabel("max_i ‖P̄_i^∞ − S‖_F")
    axes[0, 1].set_xlabel("λ α σ_2(ℒ)")
    axes[0, 1].set_ylabel("mean_i tr E[e_ie_iᵀ]^∞")
    axes[0, 0].legend()
    fig.suptitle(f"S4: S2's plant and sensors on four graphs of 4 nodes {note}", fontsize=9)
    save_figure(fig, path)


def write_figures(res: Results, fig_dir: Path, *, main: str, paper: bool = False) -> None:
    note = PAPER_NOTE if paper else ""
    fig1(res.scenarios[main], fig_dir / "fig1_network_events.png", note)
    for name, r in res.scenarios.items():
        fig2(r, fig_dir / f"fig2_traces_{name}.png", note)
        fig3(r, fig_dir / f"fig3_sample_path_{name}.png", note)
        fig4(r, fig_dir / f"fig4_gaps_{name}.png", note)
        fig5(r, fig_dir / f"fig5_rate_{name}.png", note)
        fig6(r, fig_dir / f"fig6_traces_vs_rate_{name}.png", note)
        fig7(r, fig_dir / f"fig7_abscissa_{name}.png", note)
    if res.topology is not None:
        fig_topology(res.topology, fig_dir / "fig_topology.png")
