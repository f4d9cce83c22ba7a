"""Figures (PNG) and the Rerun recording of the coestimation family, drawn from the run's tables.

Figures 2-11 of the paper (Fig. 2 reconstructed) for the paper's example, the same views with
plain names and titles for users' scenarios, plus roles, bounds and Monte Carlo figures. One
recording `<scenario>.rrd` on timeline `t` (duration): the graph at fixed positions with each
node's role g_i(t) as colour and size, the target and each node's estimate in the plane, states
and inputs against truth, errors against the bounds, the stochastic Monte Carlo against (46) and
the exact moments, the LMI results and the claims. Every number comes from the tables
(`tables.py`); the scenario gives only the layout (graph, positions, names).
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

import pandas as pd

from pipeline import record as rec_
from pipeline.figures import new_figure, save_figure, sequential_colors
from pipeline.stats import z_for_confidence
from pipeline.tables import Tables

from .compute import Results

PAPER_STATE_LABELS = ("x₁ (x position)", "x₂ (x velocity)", "x₃ (y position)", "x₄ (y velocity)")
FRAME_DT = 0.1  # seconds between recorded network/plane frames ...
MAX_FRAMES = 2000  # ... and at most this many of them (long horizons are thinned)
# (paper file, paper title, user file, user title) of each figure
FIGURES = {
    "graph": ("fig2", "Fig. 2 (reconstructed): communication graph and sensing discs", "graph",
              "communication graph and sensing discs"),
    "states": ("fig3", "Fig. 3: coestimation (22)-(23), x̂_i(t); dashed: true x(t)", "states",
               "coestimation (22)-(23), x̂_i(t); dashed: true x(t)"),
    "inputs": ("fig4", "Fig. 4: coestimation, ŵ_i(t); dashed: true w(t)", "inputs",
               "coestimation, ŵ_i(t); dashed: true w(t)"),
    "plane": ("fig5", "Fig. 5: coestimation, position estimates; AN = active nodes", "plane",
              "coestimation, position estimates; AN = active nodes"),
    "comp_states": ("fig6", "Fig. 6: estimation architecture (36)-(37), x̂_i(t)", "comparison_states",
                    "estimation architecture (36)-(37), x̂_i(t)"),
    "comp_inputs": ("fig7", "Fig. 7: estimation architecture (36)-(37), ŵ_i(t)", "comparison_inputs",
                    "estimation architecture (36)-(37), ŵ_i(t)"),
    "comp_plane": ("fig8", "Fig. 8: estimation architecture, position estimates", "comparison_plane",
                   "estimation architecture, position estimates"),
    "sde_pos": ("fig9", "Fig. 9: Ex. 5.2 (stochastic), run 0; shaded: true-state envelope over the runs",
                "stochastic_positions", "stochastic run 0, position states; shaded: true-state envelope over the runs"),
    "sde_other": ("fig10", "Fig. 10: Ex. 5.2, run 0, the other states; shaded: envelope over the runs",
                  "stochastic_states", "stochastic run 0, the other states; shaded: envelope over the runs"),
    "sde_inputs": ("fig11", "Fig. 11: Ex. 5.2, run 0, ŵ_i(t); dashed: true w(t)", "stochastic_inputs",
                   "stochastic run 0, ŵ_i(t); dashed: true w(t)"),
}


def _figure(key: str, paper: bool) -> tuple[str, str]:
    pf, pt, uf, ut = FIGURES[key]
    return (pf, pt) if paper else (uf, ut)


def state_labels(res: Results, paper: bool) -> list[str]:
    n = res.scenario.n
    return list(PAPER_STATE_LABELS) if paper and n == 4 else [f"x{k + 1}" for k in range(n)]


def _node_colors(N: int):
    return sequential_colors(N, "tab20") if N <= 20 else sequential_colors(N, "viridis")


# -- reading the tables -------------------------------------------------------------------------

def trajectory(tables: Tables, run: str) -> dict[str, np.ndarray] | None:
    """A run's samples from the tables: t (T,), x (T, n), w (T, p), e (T, N, n+p), g (T, N); None if absent.
    Noise-free runs share the truth ("deterministic") and the roles of the scenario's run ("coest")."""
    est = tables["estimates"]
    est = est[est["run"] == run]
    if est.empty:
        return None
    stochastic = run.startswith("stochastic")
    truth = tables["truth"]
    truth = truth[truth["run"] == (run if stochastic else "deterministic")].sort_values(["t", "component"])
    roles = tables["roles"]
    roles = roles[roles["run"] == (run if stochastic else "coest")].sort_values(["t", "node"])
    est = est.sort_values(["t", "node", "component"])
    t = np.unique(est["t"].to_numpy())
    T, N, q = len(t), int(est["node"].max()) + 1, int(est["component"].max()) + 1
    xw = truth["value"].to_numpy().reshape(T, q)
    return {"t": t, "xw": xw, "e": est["value"].to_numpy().reshape(T, N, q),
            "g": roles["g"].to_numpy().reshape(T, N) if run != "fixed" else None}


def run_arrays(res: Results, tables: Tables, run: str) -> dict[str, np.ndarray] | None:
    """`trajectory` split into x and w with the scenario's n, and the fixed roles for the fixed run."""
    tr = trajectory(tables, run)
    if tr is None:
        return None
    n = res.scenario.n
    g = tr["g"] if tr["g"] is not None else np.broadcast_to(np.asarray(res.scenario.fixed_active), tr["e"].shape[:2])
    return {"t": tr["t"], "x": tr["xw"][:, :n], "w": tr["xw"][:, n:], "e": tr["e"], "g": g}


def bound_values(tables: Tables) -> dict[tuple[str, str], float]:
    b = tables["bounds"]
    return {(q, v): float(x) for q, v, x in zip(b["quantity"], b["variant"], b["value"])}


def network_errors(tables: Tables, run: str) -> pd.DataFrame:
    e = tables["errors"]
    return e[(e["run"] == run) & e["node"].isna()].sort_values("t")


# -- figures ----------------------------------------------------------------------------------

def _states_figure(res: Results, run: dict, title: str, path: Path, labels: list[str], states=None, band=None) -> None:
    sc = res.scenario
    states = list(range(sc.n)) if states is None else states
    cols = _node_colors(sc.N)
    ncols = 2 if len(states) > 1 else 1
    nrows = int(np.ceil(len(states) / ncols))
    fig, axes = new_figure(ncols=ncols, nrows=nrows, width=5.2, height=3.2)
    for a, k in enumerate(states):
        ax = axes.flat[a]
        if band is not None:
            ax.fill_between(run["t"], band[0][:, k], band[1][:, k], color="tab:orange", alpha=0.45, lw=0.6,
                            edgecolor="tab:orange", zorder=5, label=f"true state, min/max over {band[2]} runs")
        for i in range(sc.N):
            ax.plot(run["t"], run["e"][:, i, k], color=cols[i], lw=0.8, label=f"node {i + 1}" if a == 0 else None)
        ax.plot(run["t"], run["x"][:, k], "k--", lw=1.4, label="true" if a == 0 else None)
        ax.set_xlabel("t (s)")
        ax.set_ylabel(labels[k])
    for ax in axes.flat[len(states):]:
        ax.set_visible(False)
    axes.flat[0].legend(ncol=5, fontsize=5, loc="best", framealpha=0.6)
    fig.suptitle(title, fontsize=9)
    save_figure(fig, path)


def _inputs_figure(res: Results, run: dict, title: str, path: Path) -> None:
    sc = res.scenario
    cols = _node_colors(sc.N)
    fig, axes = new_figure(ncols=sc.p, width=5.2, height=3.4)
    for k in range(sc.p):
        ax = axes[0, k]
        for i in range(sc.N):
            ax.plot(run["t"], run["e"][:, i, sc.n + k], color=cols[i], lw=0.8, label=f"node {i + 1}" if k == 0 else None)
        ax.plot(run["t"], run["w"][:, k], "k--", lw=1.4, label="true" if k == 0 else None)
        ax.set_xlabel("t (s)")
        ax.set_ylabel(f"w{k + 1}")
    axes[0, 0].legend(ncol=4, fontsize=6)
    fig.suptitle(title, fontsize=9)
    save_figure(fig, path)


def _plane_figure(res: Results, run: dict, title: str, path: Path, labels: list[str]) -> None:
    sc = res.scenario
    a, b = sc.position_states
    cols = _node_colors(sc.N)
    fig, axes = new_figure(width=6.4, height=5.4)
    ax = axes[0, 0]
    _draw_network(ax, res, run["g"])
    for i in range(sc.N):
        ax.plot(run["e"][:, i, a], run["e"][:, i, b], color=cols[i], lw=0.8)
    ax.plot(run["x"][:, a], run["x"][:, b], "k--", lw=1.6, label="true trajectory")
    ax.set_xlabel(labels[a])
    ax.set_ylabel(labels[b])
    ax.set_aspect("equal", adjustable="datalim")
    ax.legend(fontsize=7, loc="lower left")
    ax.set_title(title, fontsize=9)
    save_figure(fig, path)


def _draw_network(ax, res: Results, g: np.ndarray | None = None, tag_active: bool = True) -> None:
    import matplotlib.patches as mpatches

    sc = res.scenario
    pos = sc.positions
    for u, v in sc.graph.build().edges():
        ax.plot(pos[[u, v], 0], pos[[u, v], 1], color="0.75", lw=0.8, zorder=1)
    active_frac = g.mean(0) if g is not None else np.zeros(sc.N)
    for i in range(sc.N):
        if sc.role_mode == "proximity":
            ax.add_patch(mpatches.Circle(pos[i], sc.radius, fill=False, color="0.85", lw=0.5, zorder=0))
        marker = "o" if sc.node_type[i] == 0 else "s"
        ax.scatter(*pos[i], s=60 + 200 * active_frac[i], marker=marker, c=[[0.85, 0.2, 0.1, 0.3 + 0.7 * active_frac[i]]],
                   edgecolors="k", zorder=3)
        tag = " AN" if tag_active and g is not None and np.any(g[:, i] > 0.5) else ""
        ax.annotate(f"{i + 1}{tag}", pos[i], xytext=(5, 5), textcoords="offset points", fontsize=7)


def _graph_figure(res: Results, run: dict, path: Path, title: str, labels: list[str]) -> None:
    sc = res.scenario
    fig, axes = new_figure(width=6.4, height=5.4)
    ax = axes[0, 0]
    _draw_network(ax, res, run["g"], tag_active=False)
    a, b = sc.position_states
    ax.plot(run["x"][:, a], run["x"][:, b], "k--", lw=1, label="target path (deterministic run)")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel(labels[a])
    ax.set_ylabel(labels[b])
    ax.set_title(f"{title}\nmarker size and opacity = fraction of time active in the deterministic run; "
                 f"circles = {sc.types[0].name}, squares = other types", fontsize=8)
    ax.legend(fontsize=7)
    save_figure(fig, path)


def _roles_figure(res: Results, run: dict, path: Path) -> None:
    sc = res.scenario
    cols = _node_colors(sc.N)
    fig, axes = new_figure(nrows=2, width=9, height=2.6)
    for i in range(sc.N):
        axes[0, 0].plot(run["t"], run["g"][:, i], color=cols[i], lw=1, label=f"node {i + 1}")
    axes[0, 0].set_ylabel("g_i(t)")
    axes[0, 0].legend(ncol=6, fontsize=6)
    axes[1, 0].plot(run["t"], (run["g"] > 0.5).sum(1), "k-")
    axes[1, 0].set_ylabel("# active (g > 1/2)")
    axes[1, 0].set_xlabel("t (s)")
    save_figure(fig, path)


def _bounds_figure(tables: Tables, path: Path) -> None:
    b = bound_values(tables)
    fig, axes = new_figure(ncols=2, width=5.4, height=4)
    for ax, run, label, bounds in (
            (axes[0, 0], "coest", "time-varying roles",
             [("(18), single ε", b[("bound18", "single")]), ("(18), per-node ε_i", b[("bound18", "pernode")]),
              ("(18), certified ε_i", b[("bound18", "certified")]), ("(18), vertex q*", b[("bound18", "qstar")])]),
            (axes[0, 1], "fixed", "fixed roles (Thm 2.1)", [("(18), Q̄ = Q + 2αL⊗I", b[("bound18", "fixed")])])):
        e = network_errors(tables, run)
        ax.semilogy(e["t"], e["norm_z"], "k-", label="‖z(t)‖")
        for (name, val), col in zip(bounds, sequential_colors(len(bounds), "plasma")):
            if np.isfinite(val):
                ax.axhline(val, color=col, ls="--", label=f"{name} = {val:.3g}")
        ax.set_xlabel("t (s)")
        ax.set_title(label, fontsize=9)
        ax.legend(fontsize=7)
    save_figure(fig, path)


def _mc_figure(tables: Tables, path: Path) -> None:
    fig, axes = new_figure(ncols=2, width=5.4, height=4)
    z = z_for_confidence(0.95)
    mc = tables["mc_series"]
    for ax, run, fixed in ((axes[0, 0], "sde_fixed", True), (axes[0, 1], "sde_roles", False)):
        r = mc[mc["run"] == run].sort_values("t")
        t, m, se = r["t"].to_numpy(), r["V_mean"].to_numpy(), r["V_se"].to_numpy()
        ax.semilogy(t, m, "b-", label=f"Monte Carlo mean ({int(r['trials'].iloc[0])} trials)")
        ax.fill_between(t, np.maximum(m - z * se, 1e-3), m + z * se, color="b", alpha=0.25, label="95% CI")
        if fixed:
            ax.semilogy(t, r["exact_EV"], "k--", lw=1, label="exact moments")
        ax.semilogy(t, r["bound46"], "r:", label="bound (46)")
        ax.set_xlabel("t (s)")
        ax.set_ylabel("E{zᵀPz}")
        ax.set_title("fixed roles" if fixed else "time-varying roles", fontsize=9)
        ax.legend(fontsize=7)
    save_figure(fig, path)


def _stochastic_runs(res: Results, tables: Tables) -> list[dict]:
    runs, k = [], 0
    while (r := run_arrays(res, tables, f"stochastic_{k}")) is not None:
        runs.append(r)
        k += 1
    return runs


def write_figures(res: Results, tables: Tables, out_dir: Path, paper: bool = True) -> None:
    figs = out_dir / "figures"
    sc = res.scenario
    co = run_arrays(res, tables, "coest")
    labels = state_labels(res, paper)

    def where(key):
        name, title = _figure(key, paper)
        return title, figs / f"{name}.png"

    _graph_figure(res, co, where("graph")[1], where("graph")[0], labels)
    _states_figure(res, co, *where("states"), labels)
    _inputs_figure(res, co, *where("inputs"))
    _plane_figure(res, co, *where("plane"), labels)
    cp = run_arrays(res, tables, "comparison")
    if cp is not None:
        _states_figure(res, cp, *where("comp_states"), labels)
        _inputs_figure(res, cp, *where("comp_inputs"))
        _plane_figure(res, cp, *where("comp_plane"), labels)
    runs = _stochastic_runs(res, tables)
    if runs:
        xs = np.stack([r["x"] for r in runs])
        band = (xs.min(0), xs.max(0), len(runs))
        a, b = sc.position_states
        others = [k for k in range(sc.n) if k not in (a, b)]
        _states_figure(res, runs[0], *where("sde_pos"), labels, states=[a, b], band=band)
        _states_figure(res, runs[0], *where("sde_other"), labels, states=others or [a], band=band)
        _inputs_figure(res, runs[0], *where("sde_inputs"))
    _roles_figure(res, co, figs / "roles.png")
    _bounds_figure(tables, figs / "bounds.png")
    _mc_figure(tables, figs / "mean_square.png")


# -- recording --------------------------------------------------------------------------------

def _rgb(c) -> tuple[int, int, int]:
    return tuple(int(255 * x) for x in c[:3])


def lmi_markdown(tables: Tables) -> str:
    nt, b = tables["node_types"], bound_values(tables)
    cells = tables["s_cells"].set_index("cell")
    spectra = tables["spectra"]
    lines = ["# LMI results", "", "## (28)-(29): coestimation, per node type", "",
             "| type | ε | Clarabel status | normalised margin t* | verified max eig at P* | given P: max eig g=0 | g=1 |",
             "|---|---|---|---|---|---|---|"]
    for r in nt.itertuples():
        lines.append(f"| {r.type} | {r.eps:g} | {r.lmi_status} | {r.lmi_margin:.4g} | {r.lmi_verified:.4g} | "
                     f"{'' if np.isnan(r.given_max_eig_g0) else f'{r.given_max_eig_g0:.4g}'} | "
                     f"{'' if np.isnan(r.given_max_eig_g1) else f'{r.given_max_eig_g1:.4g}'} |")
    lines += ["", "## (38)-(39): the comparison architecture", ""]
    if (nt["comparison_status_at_sigma"] != "").any():   # at the coestimation σ: the paper's example only
        lines += ["| type | σ (coestimation) | status | t* | smallest feasible σ | σ_b used | status | t* |",
                  "|---|---|---|---|---|---|---|---|"]
        for r in nt.itertuples():
            lines.append(f"| {r.type} | {r.sigma:g} | {r.comparison_status_at_sigma} | {r.comparison_margin_at_sigma:.4g} | "
                         f"{r.comparison_sigma_min:.4g} | {r.comparison_sigma:g} | {r.comparison_status} | "
                         f"{r.comparison_margin:.4g} |")
    else:
        lines += ["| type | σ_b used | status | t* |", "|---|---|---|---|"]
        for r in nt.itertuples():
            lines.append(f"| {r.type} | {r.comparison_sigma:g} | {r.comparison_status} | {r.comparison_margin:.4g} |")
    smin = [float(spectra[spectra["matrix"] == f"S_{c}"]["real"].min()) for c in ("all_passive", "all_active")]
    lines += ["", "## Bounds", "", f"- w̄ = {b[('wbar', '')]:.6g} (sup‖w‖ = {b[('w_sup', '')]:.6g}, sup‖ẇ‖ = "
              f"{b[('wdot_sup', '')]:.6g}); φ̄ = {b[('phibar', 'paper')]:.6g} (tight {b[('phibar', 'tight')]:.6g})",
              f"- λ_min(P) = {b[('lamP_min', '')]:.5g}, λ_max(P) = {b[('lamP_max', '')]:.5g}",
              f"- (18) single ε: {b[('bound18', 'single')]:.4g}; per-node ε_i: {b[('bound18', 'pernode')]:.4g}; "
              f"certified: {b[('bound18', 'certified')]:.4g}; vertex q* ({b[('qbar_min', 'qstar')]:.4g}): "
              f"{b[('bound18', 'qstar')]:.4g}",
              f"- fixed roles: λ_min(Q̄) = {b[('qbar_min', 'fixed')]:.4g}, (18) = {b[('bound18', 'fixed')]:.4g}",
              f"- max Re λ(S) at g ≡ 0 / g ≡ 1: {cells.loc['all_passive', 'max_real']:.4g} / "
              f"{cells.loc['all_active', 'max_real']:.4g}; min Re λ: {np.round(smin, 1).tolist()}"]
    return "\n".join(lines)


def write_recording(res: Results, tables: Tables, path: Path, claims: list[dict], prov: dict, paper: bool = True) -> None:
    sc = res.scenario
    n, p, N = sc.n, sc.p, sc.N
    co = run_arrays(res, tables, "coest")
    bv = bound_values(tables)
    t_ns = np.round(co["t"] * 1e9).astype(np.int64)
    idx = rec_.duration_index("t", t_ns)
    cols = [_rgb(c) for c in _node_colors(N)]
    a, b = sc.position_states
    labels = state_labels(res, paper)
    figs_est, figs_comp = (" (Figs. 3-4)", " (Figs. 6-7)") if paper else ("", "")
    blueprint = rrb.Blueprint(
        rrb.Tabs(
            rrb.Horizontal(
                rrb.Vertical(rrb.GraphView(origin="/graph", name="graph: node size/colour = role g_i(t)"),
                             rrb.TimeSeriesView(origin="/roles", name="roles g_i(t)"), row_shares=[3, 2]),
                rrb.Spatial2DView(origin="/plane", name="target (black) and node estimates in the plane"),
                column_shares=[2, 3], name="network"),
            rrb.Grid(*[rrb.TimeSeriesView(origin=f"/states/x{k + 1}", name=f"{labels[k]}: nodes vs truth")
                       for k in range(n)],
                     *[rrb.TimeSeriesView(origin=f"/states/w{k + 1}", name=f"w{k + 1}: nodes vs truth") for k in range(p)],
                     grid_columns=2, name=f"estimates{figs_est}"),
            rrb.Grid(*[rrb.TimeSeriesView(origin=f"/comparison/x{k + 1}", name=f"comparison arch.: {labels[k]}")
                       for k in range(n)], grid_columns=2, name=f"comparison{figs_comp}"),
            rrb.Grid(rrb.TimeSeriesView(origin="/bounds/roles", name="‖z(t)‖ vs (18) variants (log)"),
                     rrb.TimeSeriesView(origin="/bounds/fixed", name="fixed roles: ‖z‖ vs (18)"),
                     rrb.TimeSeriesView(origin="/mc", name="E{z^T P z}: Monte Carlo, exact, (46)"),
                     rrb.TimeSeriesView(origin="/errors", name="mean node errors: coestimation, comparison, central KF"),
                     name="errors and bounds"),
            rrb.Horizontal(rrb.TextDocumentView(origin="/lmi", name="LMI results"),
                           rrb.TextDocumentView(origin="/report", name="claims"),
                           rrb.TextDocumentView(origin="/claims", name="claim detail"), name="LMIs and claims"),
        ),
        rrb.TimePanel(timeline="t", expanded=False),
        collapse_panels=True,
    )
    props = {"seed": res.seed, "trials": res.trials, "alpha": sc.alpha, "beta": sc.beta, "radius": sc.radius,
             "N": N, "P_mode": sc.P_mode, "versions": json.dumps(prov.get("versions", {})), "git": prov.get("git", "")}
    with rec_.recording(path, application_id="dse-tran", recording_id=f"tran-{sc.name}-seed{res.seed}",
                        blueprint=blueprint, properties=props) as rec:
        # graph: static edges, per-frame node colours/sizes from g_i(t)
        stride = max(1, int(round(FRAME_DT / sc.record_dt)), -(-len(co["t"]) // MAX_FRAMES))
        frames = np.arange(0, len(co["t"]), stride)
        ids = [str(i) for i in range(N)]
        rec.log("graph", rr.GraphEdges([(str(u), str(v)) for u, v in sc.graph.build().edges()],
                                       graph_type=rr.GraphType.Undirected), static=True)
        rec.log("plane/target_path", rr.LineStrips2D([co["x"][:, [a, b]]], colors=[(0, 0, 0)], radii=0.02), static=True)
        if sc.role_mode == "proximity":
            circ = np.linspace(0, 2 * np.pi, 60)
            rec.log("plane/sensing_discs", rr.LineStrips2D([sc.positions[i] + sc.radius * np.c_[np.cos(circ), np.sin(circ)]
                                                             for i in range(N)], colors=[(200, 200, 200)], radii=0.01),
                    static=True)
        for k in frames:
            g = co["g"][k]
            rec.set_time("t", duration=np.timedelta64(int(t_ns[k]), "ns"))
            node_cols = [(int(60 + 195 * gi), int(120 * (1 - gi)), int(200 * (1 - gi))) for gi in g]
            rec.log("graph", rr.GraphNodes(ids, positions=rec_.display_positions(sc.positions), colors=node_cols, radii=(8 + 14 * g).tolist(),
                                           labels=[f"{i + 1}{'·A' if g[i] > 0.5 else ''}" for i in range(N)],
                                           show_labels=True))
            rec.log("plane/nodes", rr.Points2D(sc.positions, colors=node_cols, radii=(0.08 + 0.17 * g).tolist(),
                                               labels=[str(i + 1) for i in range(N)]))
            rec.log("plane/target", rr.Points2D(co["x"][k:k + 1, [a, b]], colors=[(0, 0, 0)], radii=0.12))
            rec.log("plane/estimates", rr.Points2D(co["e"][k, :, [a, b]].T, colors=cols, radii=0.07))
        rec_.send_series(rec, "roles", idx, co["g"], names=[f"g_{i + 1}" for i in range(N)], colors=cols)
        rec_.send_series(rec, "roles/n_active", idx, (co["g"] > 0.5).sum(1), names="# active", colors=[(0, 0, 0)], width=2)
        # truth and per-node estimates (by state, and by node)
        names = [f"node {i + 1}" for i in range(N)]
        for k in range(n):
            rec_.send_series(rec, f"states/x{k + 1}/nodes", idx, co["e"][:, :, k], names=names, colors=cols, width=1)
            rec_.send_series(rec, f"states/x{k + 1}/truth", idx, co["x"][:, k], names="true", colors=[(0, 0, 0)], width=2.5)
            rec_.send_series(rec, f"truth/x{k + 1}", idx, co["x"][:, k], names=f"x{k + 1}", colors=[(0, 0, 0)])
        for k in range(p):
            rec_.send_series(rec, f"states/w{k + 1}/nodes", idx, co["e"][:, :, n + k], names=names, colors=cols, width=1)
            rec_.send_series(rec, f"states/w{k + 1}/truth", idx, co["w"][:, k], names="true", colors=[(0, 0, 0)], width=2.5)
            rec_.send_series(rec, f"truth/w{k + 1}", idx, co["w"][:, k], names=f"w{k + 1}", colors=[(0, 0, 0)])
        err = tables["errors"]
        for i in range(N):
            rec_.send_series(rec, f"nodes/{i}/estimate", idx, co["e"][:, i],
                             names=[f"x̂{k + 1}" for k in range(n)] + [f"ŵ{k + 1}" for k in range(p)])
            ei = err[(err["run"] == "coest") & (err["node"] == i)].sort_values("t")
            rec_.send_series(rec, f"nodes/{i}/error", idx, ei[["norm_x", "norm_w"]].to_numpy(), names=["‖x̃_i‖", "‖w̃_i‖"])
        cp = run_arrays(res, tables, "comparison")
        if cp is not None:
            for k in range(n):
                rec_.send_series(rec, f"comparison/x{k + 1}/nodes", idx, cp["e"][:, :, k], names=names, colors=cols, width=1)
                rec_.send_series(rec, f"comparison/x{k + 1}/truth", idx, cp["x"][:, k], names="true", colors=[(0, 0, 0)],
                                 width=2.5)
            rec_.send_series(rec, "errors/comparison", idx, network_errors(tables, "comparison")[["norm_x", "norm_w"]].to_numpy(),
                             names=["comparison mean ‖x̃‖", "comparison mean ‖w̃‖"], colors=[(214, 39, 40), (255, 152, 150)])
        net = network_errors(tables, "coest")
        rec_.send_series(rec, "errors/coestimation", idx, net[["norm_x", "norm_w"]].to_numpy(),
                         names=["coestimation mean ‖x̃‖", "coestimation mean ‖w̃‖"], colors=[(31, 119, 180), (174, 199, 232)])
        c = tables["central"]
        c = c[c["run"] == "deterministic"].sort_values(["t", "component"])
        kt = np.unique(c["t"].to_numpy())
        kidx = rec_.duration_index("t", np.round(kt * 1e9).astype(np.int64))
        est, truth = c["estimate"].to_numpy().reshape(len(kt), -1), c["truth"].to_numpy().reshape(len(kt), -1)
        rec_.send_series(rec, "central/estimate", kidx, est, names=[f"KF x̂{k + 1}" for k in range(n)] +
                         [f"KF ŵ{k + 1}" for k in range(p)])
        rec_.send_series(rec, "errors/central_kf", kidx, np.c_[np.linalg.norm(est[:, :n] - truth[:, :n], axis=1),
                                                                np.linalg.norm(est[:, n:] - truth[:, n:], axis=1)],
                         names=["central KF ‖x̃‖", "central KF ‖w̃‖"], colors=[(0, 0, 0), (127, 127, 127)])
        # bounds
        nz = net["norm_z"].to_numpy()
        rec_.send_series(rec, "bounds/roles/norm_z", idx, nz, names="‖z(t)‖", colors=[(0, 0, 0)], width=2)
        for name in ("single", "pernode", "certified", "qstar"):
            val = bv[("bound18", name)]
            if np.isfinite(val):
                rec_.send_series(rec, f"bounds/roles/bound18_{name}", idx, np.full(len(nz), val), names=f"(18) {name}")
        nzf = network_errors(tables, "fixed")["norm_z"].to_numpy()
        rec_.send_series(rec, "bounds/fixed/norm_z", idx, nzf, names="‖z(t)‖", colors=[(0, 0, 0)], width=2)
        rec_.send_series(rec, "bounds/fixed/bound18", idx, np.full(len(nzf), bv[("bound18", "fixed")]), names="(18)")
        rec_.send_series(rec, "bounds/roles/V", idx, net["V"].to_numpy(), names="V = zᵀPz", colors=[(44, 160, 44)])
        # Monte Carlo
        mc = tables["mc_series"]
        zc95 = z_for_confidence(0.95)
        for run in ("sde_fixed", "sde_roles"):
            r = mc[mc["run"] == run].sort_values("t")
            sidx = rec_.duration_index("t", np.round(r["t"].to_numpy() * 1e9).astype(np.int64))
            m, se = r["V_mean"].to_numpy(), r["V_se"].to_numpy()
            rec_.send_series(rec, f"mc/{run}/mean_V", sidx, np.c_[m, m - zc95 * se, m + zc95 * se],
                             names=[f"{run}: mean V", f"{run}: 95% low", f"{run}: 95% high"])
            rec_.send_series(rec, f"mc/{run}/bound46", sidx, r["bound46"].to_numpy(), names=f"{run}: (46)")
            if run == "sde_fixed":
                rec_.send_series(rec, "mc/sde_fixed/exact", sidx, r["exact_EV"].to_numpy(), names="fixed roles: exact E{V}",
                                 colors=[(0, 0, 0)])
        rec_.log_markdown(rec, "lmi", lmi_markdown(tables))
        counts = {s: sum(c["verdict"] == s for c in claims) for s in ("pass", "fail", "erratum", "not-checkable", "error")}
        rec_.log_claims(rec, claims, f"# {sc.name}: {counts}")


def write_outputs(res: Results, tables: Tables, out_dir: Path, claims: list[dict], prov: dict, paper: bool = True) -> None:
    write_figures(res, tables, out_dir, paper)
    write_recording(res, tables, out_dir / f"{res.scenario.name}.rrd", claims, prov, paper)
