"""The views of a coestimation run: figures (PNG) and the Rerun recording.

Figures 2-11 of the paper (Fig. 2 reconstructed) for the paper's example, the same views with
plain names and titles for users' scenarios, plus roles, bounds and Monte Carlo figures. One
recording `<scenario>.rrd` on timeline `t` (duration), on the shared recording scaffold: the graph
at fixed positions with each node's role g_i(t) as colour and size, the target and each node's
estimate in the plane, states and inputs against truth, errors against the bounds, the stochastic
Monte Carlo against (46) and the exact moments, the LMI results (and the scaffold's claims tab).
Trajectories are the recorded runs the tables hold; bounds, moments and the LMI results are read
from the tables.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from dse.contract.views import Outputs, View, recording
from dse.outputs.figures import new_figure, plain_log_labels, save_figure, sequential_colors, set_margins
from dse.outputs.tables import Tables
from dse.simulate.stats import z_for_confidence

from .runs import Results

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


def _node_colors(N: int):
    return sequential_colors(N, "tab20") if N <= 20 else sequential_colors(N, "viridis")


def _rgb(c) -> tuple[int, int, int]:
    return tuple(int(255 * x) for x in c[:3])


def _ns(t) -> np.ndarray:
    """Times (s) as integer nanoseconds (the recording's duration index)."""
    return np.round(np.asarray(t) * 1e9).astype(np.int64)


def graph_edges(net) -> list[tuple[int, int]]:
    """The graph's edges in the order of networkx's `build().edges()` (the order the figures draw them and the
    recording lists them), without importing networkx (0.07 s in each drawing worker) where that order is known:
    an explicit list's edges as (smaller, larger) node, stably sorted by the smaller; a line's, a ring's and a
    complete graph's sorted (`edge_array`). tests/test_tran_reference.py compares them with networkx's."""
    if net.kind == "edges":
        return sorted(((min(u, v), max(u, v)) for u, v in net.edges), key=lambda e: e[0])
    if net.kind in ("line", "complete") or (net.kind == "ring" and net.n >= 3):
        return [(int(u), int(v)) for u, v in net.edge_array()]
    return [(int(u), int(v)) for u, v in net.build().edges()]


def bound_values(tables: Tables) -> dict[tuple[str, str], float]:
    b = tables["bounds"]
    return {(q, v): float(x) for q, v, x in zip(b["quantity"], b["variant"], b["value"])}


class Drawing:
    """What the figures and the recording of one run share: its recorded runs (t, x, w, e, g), their error
    norms, the tables, the layout (positions, colours, state labels) and the paper's names or plain ones."""

    def __init__(self, res: Results, tables: Tables, paper: bool):
        self.res, self.tables, self.paper, self.sc = res, tables, paper, res.scenario
        n = self.sc.n
        self.labels = list(PAPER_STATE_LABELS) if paper and n == 4 else [f"x{k + 1}" for k in range(n)]
        self.cols = _node_colors(self.sc.N)

    def run(self, name: str) -> dict[str, np.ndarray] | None:
        """A noise-free run (coest, fixed, comparison) or stored stochastic trial `stochastic_<k>`."""
        if not name.startswith("stochastic"):
            return self.res.runs.get(name)
        s, k = self.res.runs["sde_roles"], int(name.split("_")[1])
        return {"t": s["t"], "x": s["kept_x"][k], "w": s["w"], "e": s["kept_e"][k], "g": s["kept_g"][k]} \
            if k < len(s["kept_x"]) else None

    def stochastic_runs(self) -> list[dict]:
        return [self.run(f"stochastic_{k}") for k in range(len(self.res.runs["sde_roles"]["kept_x"]))]

    def errors(self, name: str) -> dict[str, np.ndarray]:
        """Per node ‖x̃_i‖, ‖w̃_i‖ (T, N); the network's mean of each, ‖z‖ and V = zᵀPz (T,) (the `errors` table)."""
        z, n = self.res.errors(name), self.sc.n
        nx, nw = np.linalg.norm(z[..., :n], axis=-1), np.linalg.norm(z[..., n:], axis=-1)
        return {"norm_x": nx, "norm_w": nw, "net_x": nx.mean(1), "net_w": nw.mean(1),
                "norm_z": np.linalg.norm(z.reshape(len(z), -1), axis=1),
                "V": np.einsum("tni,nij,tnj->tn", z, self.res.P, z).sum(1)}

    def where(self, key: str) -> tuple[str, str]:
        """(file under figures/, title) of a figure."""
        pf, pt, uf, ut = FIGURES[key]
        return (pf, pt) if self.paper else (uf, ut)


# -- figures ----------------------------------------------------------------------------------

def _save(fig, path: Path, **margins) -> None:
    """Fixed margins (inches) instead of tight_layout's extra measuring draw; log-axis labels without mathtext."""
    set_margins(fig, **margins)
    plain_log_labels(fig)
    save_figure(fig, path, tight=False)


def _legend_below(fig, ax, fontsize: float = 6, max_columns: int = 13) -> float:
    """The legend of `ax` centred at the bottom of the figure, clear of the data (a legend placed "best" tests
    every vertex of every line); returns the bottom margin (inches) the axes then need."""
    handles, labels = ax.get_legend_handles_labels()
    ncol = max(1, min(len(labels), max_columns))
    rows = -(-len(labels) // ncol)
    fig.legend(handles, labels, loc="lower center", ncol=ncol, fontsize=fontsize, frameon=False)
    return 0.6 + rows * 1.5 * fontsize / 72


def _series_figure(dr: Drawing, run: dict, title: str, path: Path, components: list[int], band=None) -> None:
    """Each node's estimate of the given components of (x, w) against the truth (dashed), optionally with the
    min/max envelope of the true state over the stored stochastic runs."""
    sc, n = dr.sc, dr.sc.n
    ncols = 2 if len(components) > 1 and components[0] < n else max(1, len(components))
    fig, axes = new_figure(ncols=ncols, nrows=int(np.ceil(len(components) / ncols)), width=5.2,
                           height=3.2 if components[0] < n else 3.4)
    for a, k in enumerate(components):
        ax = axes.flat[a]
        if band is not None:
            ax.fill_between(run["t"], band[0][:, k], band[1][:, k], color="tab:orange", alpha=0.45, lw=0.6,
                            edgecolor="tab:orange", zorder=5, label=f"true state, min/max over {band[2]} runs")
        for i in range(sc.N):
            ax.plot(run["t"], run["e"][:, i, k], color=dr.cols[i], lw=0.8, label=f"node {i + 1}" if a == 0 else None)
        ax.plot(run["t"], run["x"][:, k] if k < n else run["w"][:, k - n], "k--", lw=1.4, label="true" if a == 0 else None)
        ax.set_xlabel("t (s)")
        ax.set_ylabel(dr.labels[k] if k < n else f"w{k - n + 1}")
    for ax in axes.flat[len(components):]:
        ax.set_visible(False)
    fig.suptitle(title, fontsize=9)
    _save(fig, path, top=0.45, bottom=_legend_below(fig, axes.flat[0]))


def _network_figure(dr: Drawing, run: dict, title: str, path: Path, graph: bool) -> None:
    """The nodes in the plane (marker size and opacity: the fraction of time active; sensing discs with proximity
    roles) and the target's path; `graph`: Fig. 2's layout, else each node's position estimate (Figs. 5, 8)."""
    import matplotlib.patches as mpatches

    sc, g = dr.sc, run["g"]
    pos, (a, b) = sc.nodes.positions, sc.roles.position_states
    fig, axes = new_figure(width=6.4, height=5.4)
    ax = axes[0, 0]
    for u, v in graph_edges(sc.network):
        ax.plot(pos[[u, v], 0], pos[[u, v], 1], color="0.75", lw=0.8, zorder=1)
    active_frac = g.mean(0)
    for i in range(sc.N):
        if sc.roles.mode == "proximity":
            ax.add_patch(mpatches.Circle(pos[i], sc.roles.radius, fill=False, color="0.85", lw=0.5, zorder=0))
        ax.scatter(*pos[i], s=60 + 200 * active_frac[i], marker="o" if sc.type_of[i] == 0 else "s",
                   c=[[0.85, 0.2, 0.1, 0.3 + 0.7 * active_frac[i]]], edgecolors="k", zorder=3)
        tag = " AN" if not graph and np.any(g[:, i] > 0.5) else ""
        ax.annotate(f"{i + 1}{tag}", pos[i], xytext=(5, 5), textcoords="offset points", fontsize=7)
        if not graph:
            ax.plot(run["e"][:, i, a], run["e"][:, i, b], color=dr.cols[i], lw=0.8)
    ax.plot(run["x"][:, a], run["x"][:, b], "k--", lw=1 if graph else 1.6,
            label="target path (deterministic run)" if graph else "true trajectory")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel(dr.labels[a])
    ax.set_ylabel(dr.labels[b])
    ax.legend(fontsize=7, loc="lower left")
    if graph:
        ax.set_title(f"{title}\nmarker size and opacity = fraction of time active in the deterministic run\n"
                     f"circles = {sc.types[0].name}, squares = other types", fontsize=8)
    else:
        ax.set_title(title, fontsize=9)
    _save(fig, path, **({"top": 0.65} if graph else {}))


def _roles_figure(dr: Drawing, path: Path) -> None:
    run = dr.run("coest")
    fig, axes = new_figure(nrows=2, width=9, height=2.6)
    for i in range(dr.sc.N):
        axes[0, 0].plot(run["t"], run["g"][:, i], color=dr.cols[i], lw=1, label=f"node {i + 1}")
    axes[0, 0].set_ylabel("g_i(t)")
    axes[1, 0].plot(run["t"], (run["g"] > 0.5).sum(1), "k-")
    axes[1, 0].set_ylabel("# active (g > 1/2)")
    axes[1, 0].set_xlabel("t (s)")
    _save(fig, path, hspace=0.55, top=0.2, bottom=_legend_below(fig, axes[0, 0], max_columns=14))


def _bounds_figure(dr: Drawing, path: Path) -> None:
    b = bound_values(dr.tables)
    fig, axes = new_figure(ncols=2, width=5.4, height=4)
    for ax, run, label, bounds in (
            (axes[0, 0], "coest", "time-varying roles",
             [("(18), single ε", b[("bound18", "single")]), ("(18), per-node ε_i", b[("bound18", "pernode")]),
              ("(18), certified ε_i", b[("bound18", "certified")]), ("(18), vertex q*", b[("bound18", "qstar")])]),
            (axes[0, 1], "fixed", "fixed roles (Thm 2.1)", [("(18), Q̄ = Q + 2αL⊗I", b[("bound18", "fixed")])])):
        ax.semilogy(dr.run(run)["t"], dr.errors(run)["norm_z"], "k-", label="‖z(t)‖")
        for (name, val), col in zip(bounds, sequential_colors(len(bounds), "plasma")):
            if np.isfinite(val):
                ax.axhline(val, color=col, ls="--", label=f"{name} = {val:.3g}")
        ax.set_xlabel("t (s)")
        ax.set_title(label, fontsize=9)
        ax.legend(fontsize=7, loc="center right")
    _save(fig, path)


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
        ax.legend(fontsize=7, loc="center right")
    _save(fig, path, left=0.8)


def figure_views(dr: Drawing) -> list[View]:
    """One view per figure (the paper's figure names and titles in its reproduction, plain ones otherwise)."""
    sc = dr.sc
    states, inputs = list(range(sc.n)), list(range(sc.n, sc.q))

    def fig(key, draw):
        name, title = dr.where(key)
        return View(f"figures/{name}.png", lambda path: draw(title, path))

    co, cp, runs = dr.run("coest"), dr.run("comparison"), dr.stochastic_runs()
    out = [fig("graph", lambda title, path: _network_figure(dr, co, title, path, graph=True)),
           fig("states", lambda title, path: _series_figure(dr, co, title, path, states)),
           fig("inputs", lambda title, path: _series_figure(dr, co, title, path, inputs)),
           fig("plane", lambda title, path: _network_figure(dr, co, title, path, graph=False)),
           View("figures/roles.png", lambda path: _roles_figure(dr, path)),
           View("figures/bounds.png", lambda path: _bounds_figure(dr, path)),
           View("figures/mean_square.png", lambda path: _mc_figure(dr.tables, path))]
    if cp is not None:
        out += [fig("comp_states", lambda title, path: _series_figure(dr, cp, title, path, states)),
                fig("comp_inputs", lambda title, path: _series_figure(dr, cp, title, path, inputs)),
                fig("comp_plane", lambda title, path: _network_figure(dr, cp, title, path, graph=False))]
    if runs:
        xs = np.stack([r["x"] for r in runs])
        band = (xs.min(0), xs.max(0), len(runs))
        plane = list(sc.roles.position_states)
        others = [k for k in states if k not in plane] or plane[:1]
        out += [fig("sde_pos", lambda title, path: _series_figure(dr, runs[0], title, path, plane, band)),
                fig("sde_other", lambda title, path: _series_figure(dr, runs[0], title, path, others, band)),
                fig("sde_inputs", lambda title, path: _series_figure(dr, runs[0], title, path, inputs))]
    return out


# -- recording --------------------------------------------------------------------------------

def _md_table(header: list[str], rows) -> list[str]:
    return ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)] + ["| " + " | ".join(r) + " |" for r in rows]


def lmi_markdown(tables: Tables) -> str:
    """The LMIs (28)-(29) per node type, the comparison LMIs (38)-(39) and the bounds, as a text document."""
    nt, b, cells, spectra = tables["node_types"], bound_values(tables), tables["s_cells"].set_index("cell"), tables["spectra"]
    opt = lambda x: "" if np.isnan(x) else f"{x:.4g}"  # noqa: E731
    lines = ["# LMI results", "", "## (28)-(29): coestimation, per node type", ""] + _md_table(
        ["type", "ε", "Clarabel status", "normalised margin t*", "verified max eig at P*", "given P: max eig g=0", "g=1"],
        [(r.type, f"{r.eps:g}", r.lmi_status, f"{r.lmi_margin:.4g}", f"{r.lmi_verified:.4g}", opt(r.given_max_eig_g0),
          opt(r.given_max_eig_g1)) for r in nt.itertuples()])
    lines += ["", "## (38)-(39): the comparison architecture", ""]
    if (nt["comparison_status_at_sigma"] != "").any():   # at the coestimation σ: the paper's example only
        lines += _md_table(["type", "σ (coestimation)", "status", "t*", "smallest feasible σ", "σ_b used", "status", "t*"],
                           [(r.type, f"{r.sigma:g}", r.comparison_status_at_sigma, f"{r.comparison_margin_at_sigma:.4g}",
                             f"{r.comparison_sigma_min:.4g}", f"{r.comparison_sigma:g}", r.comparison_status,
                             f"{r.comparison_margin:.4g}") for r in nt.itertuples()])
    else:
        lines += _md_table(["type", "σ_b used", "status", "t*"], [(r.type, f"{r.comparison_sigma:g}", r.comparison_status,
                                                                   f"{r.comparison_margin:.4g}") for r in nt.itertuples()])
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


def _tabs(dr: Drawing) -> list:
    """The recording's own tabs (the scaffold adds the claims)."""
    import rerun.blueprint as rrb

    n, p, labels = dr.sc.n, dr.sc.p, dr.labels
    figs_est, figs_comp = (" (Figs. 3-4)", " (Figs. 6-7)") if dr.paper else ("", "")
    return [
        rrb.Horizontal(rrb.Vertical(rrb.GraphView(origin="/graph", name="graph: node size/colour = role g_i(t)"),
                                    rrb.TimeSeriesView(origin="/roles", name="roles g_i(t)"), row_shares=[3, 2]),
                       rrb.Spatial2DView(origin="/plane", name="target (black) and node estimates in the plane"),
                       column_shares=[2, 3], name="network"),
        rrb.Grid(*[rrb.TimeSeriesView(origin=f"/states/x{k + 1}", name=f"{labels[k]}: nodes vs truth") for k in range(n)],
                 *[rrb.TimeSeriesView(origin=f"/states/w{k + 1}", name=f"w{k + 1}: nodes vs truth") for k in range(p)],
                 grid_columns=2, name=f"estimates{figs_est}"),
        rrb.Grid(*[rrb.TimeSeriesView(origin=f"/comparison/x{k + 1}", name=f"comparison arch.: {labels[k]}")
                   for k in range(n)], grid_columns=2, name=f"comparison{figs_comp}"),
        rrb.Grid(rrb.TimeSeriesView(origin="/bounds/roles", name="‖z(t)‖ vs (18) variants (log)"),
                 rrb.TimeSeriesView(origin="/bounds/fixed", name="fixed roles: ‖z‖ vs (18)"),
                 rrb.TimeSeriesView(origin="/mc", name="E{z^T P z}: Monte Carlo, exact, (46)"),
                 rrb.TimeSeriesView(origin="/errors", name="mean node errors: coestimation, comparison, central KF"),
                 name="errors and bounds"),
        rrb.TextDocumentView(origin="/lmi", name="LMI results")]


def _log_network(rec, dr: Drawing) -> None:
    """The graph with each node's role g_i(t) as colour and size, the target and the estimates in the plane."""
    import rerun as rr

    from dse.outputs import record

    sc, co = dr.sc, dr.run("coest")
    N, (a, b), pos = sc.N, sc.roles.position_states, sc.nodes.positions
    cols = [_rgb(c) for c in dr.cols]
    stride = max(1, int(round(FRAME_DT / sc.simulation.record_dt)), -(-len(co["t"]) // MAX_FRAMES))
    frames = np.arange(0, len(co["t"]), stride)
    rec.log("graph", rr.GraphEdges([(str(u), str(v)) for u, v in graph_edges(sc.network)],
                                   graph_type=rr.GraphType.Undirected), static=True)
    rec.log("graph", rr.GraphNodes.from_fields(show_labels=True), static=True)
    rec.log("plane/target_path", rr.LineStrips2D([record.as_float32(co["x"][:, [a, b]])], colors=[(0, 0, 0)],
                                                 radii=0.02), static=True)
    if sc.roles.mode == "proximity":
        circ = np.linspace(0, 2 * np.pi, 60)
        discs = [record.as_float32(pos[i] + sc.roles.radius * np.c_[np.cos(circ), np.sin(circ)]) for i in range(N)]
        rec.log("plane/sensing_discs", rr.LineStrips2D(discs, colors=[(200, 200, 200)], radii=0.01), static=True)
    # one column send per entity for all frames (N nodes per frame)
    F, g = len(frames), co["g"][frames]
    node_cols = np.stack([60 + 195 * g, 120 * (1 - g), 200 * (1 - g)], axis=-1).astype(np.uint8).reshape(F * N, 3)
    fidx, per_frame = record.duration_index("t", _ns(co["t"])[frames]), [N] * F
    names = np.array([str(i + 1) for i in range(N)])
    rec.send_columns("graph", indexes=fidx, columns=rr.GraphNodes.columns(
        node_ids=np.tile(np.array([str(i) for i in range(N)]), F), positions=np.tile(record.display_positions(pos), (F, 1)),
        colors=node_cols, radii=(8 + 14 * g).ravel(),
        labels=np.char.add(np.tile(names, F), np.where(g > 0.5, "·A", "").ravel())).partition(per_frame))
    rec.send_columns("plane/nodes", indexes=fidx, columns=rr.Points2D.columns(
        positions=record.as_float32(np.tile(pos, (F, 1))), colors=node_cols, radii=(0.08 + 0.17 * g).ravel(),
        labels=np.tile(names, F)).partition(per_frame))
    rec.send_columns("plane/target", indexes=fidx, columns=rr.Points2D.columns(
        positions=record.as_float32(co["x"][frames][:, [a, b]]), colors=np.zeros((F, 3), np.uint8), radii=np.full(F, 0.12)))
    rec.send_columns("plane/estimates", indexes=fidx, columns=rr.Points2D.columns(
        positions=record.as_float32(co["e"][frames][:, :, [a, b]].reshape(F * N, 2)), colors=np.tile(np.array(cols, np.uint8), (F, 1)),
        radii=np.full(F * N, 0.07)).partition(per_frame))
    idx = record.duration_index("t", _ns(co["t"]))
    record.send_series(rec, "roles", idx, co["g"], names=[f"g_{i + 1}" for i in range(N)], colors=cols)
    record.send_series(rec, "roles/n_active", idx, (co["g"] > 0.5).sum(1), names="# active", colors=[(0, 0, 0)], width=2)


def _log_estimates(rec, dr: Drawing) -> None:
    """Truth and per-node estimates (by state, and by node), the comparison architecture's and the central KF's."""
    from dse.outputs import record

    sc, co, cp = dr.sc, dr.run("coest"), dr.run("comparison")
    n, p, N = sc.n, sc.p, sc.N
    idx = record.duration_index("t", _ns(co["t"]))
    cols, names, black = [_rgb(c) for c in dr.cols], [f"node {i + 1}" for i in range(N)], [(0, 0, 0)]
    for k, (path, series, truth) in enumerate([(f"x{k + 1}", co["e"][:, :, k], co["x"][:, k]) for k in range(n)] +
                                              [(f"w{k + 1}", co["e"][:, :, n + k], co["w"][:, k]) for k in range(p)]):
        record.send_series(rec, f"states/{path}/nodes", idx, series, names=names, colors=cols, width=1)
        record.send_series(rec, f"states/{path}/truth", idx, truth, names="true", colors=black, width=2.5)
        record.send_series(rec, f"truth/{path}", idx, truth, names=path, colors=black)
    err = dr.errors("coest")
    for i in range(N):
        record.send_series(rec, f"nodes/{i}/estimate", idx, co["e"][:, i],
                           names=[f"x̂{k + 1}" for k in range(n)] + [f"ŵ{k + 1}" for k in range(p)])
        record.send_series(rec, f"nodes/{i}/error", idx, np.c_[err["norm_x"][:, i], err["norm_w"][:, i]],
                           names=["‖x̃_i‖", "‖w̃_i‖"])
    if cp is not None:
        for k in range(n):
            record.send_series(rec, f"comparison/x{k + 1}/nodes", idx, cp["e"][:, :, k], names=names, colors=cols, width=1)
            record.send_series(rec, f"comparison/x{k + 1}/truth", idx, cp["x"][:, k], names="true", colors=black,
                               width=2.5)
        ec = dr.errors("comparison")
        record.send_series(rec, "errors/comparison", idx, np.c_[ec["net_x"], ec["net_w"]],
                           names=["comparison mean ‖x̃‖", "comparison mean ‖w̃‖"], colors=[(214, 39, 40), (255, 152, 150)])
    record.send_series(rec, "errors/coestimation", idx, np.c_[err["net_x"], err["net_w"]],
                       names=["coestimation mean ‖x̃‖", "coestimation mean ‖w̃‖"], colors=[(31, 119, 180), (174, 199, 232)])
    c = dr.tables["central"]
    c = c[c["run"] == "deterministic"].sort_values(["t", "component"])
    kt = np.unique(c["t"].to_numpy())
    kidx = record.duration_index("t", _ns(kt))
    est, truth = c["estimate"].to_numpy().reshape(len(kt), -1), c["truth"].to_numpy().reshape(len(kt), -1)
    record.send_series(rec, "central/estimate", kidx, est, names=[f"KF x̂{k + 1}" for k in range(n)] +
                       [f"KF ŵ{k + 1}" for k in range(p)])
    record.send_series(rec, "errors/central_kf", kidx, np.c_[np.linalg.norm(est[:, :n] - truth[:, :n], axis=1),
                                                             np.linalg.norm(est[:, n:] - truth[:, n:], axis=1)],
                       names=["central KF ‖x̃‖", "central KF ‖w̃‖"], colors=[(0, 0, 0), (127, 127, 127)])


def _log_bounds(rec, dr: Drawing) -> None:
    """‖z(t)‖ against the variants of (18); the Monte Carlo E{V} against (46) and the exact moments; the LMIs."""
    from dse.outputs import record

    bv, err = bound_values(dr.tables), dr.errors("coest")
    idx = record.duration_index("t", _ns(dr.run("coest")["t"]))
    nz = err["norm_z"]
    record.send_series(rec, "bounds/roles/norm_z", idx, nz, names="‖z(t)‖", colors=[(0, 0, 0)], width=2)
    for name in ("single", "pernode", "certified", "qstar"):
        if np.isfinite(bv[("bound18", name)]):
            record.send_series(rec, f"bounds/roles/bound18_{name}", idx, np.full(len(nz), bv[("bound18", name)]),
                               names=f"(18) {name}")
    nzf = dr.errors("fixed")["norm_z"]
    record.send_series(rec, "bounds/fixed/norm_z", idx, nzf, names="‖z(t)‖", colors=[(0, 0, 0)], width=2)
    record.send_series(rec, "bounds/fixed/bound18", idx, np.full(len(nzf), bv[("bound18", "fixed")]), names="(18)")
    record.send_series(rec, "bounds/roles/V", idx, err["V"], names="V = zᵀPz", colors=[(44, 160, 44)])
    mc, zc95 = dr.tables["mc_series"], z_for_confidence(0.95)
    for run in ("sde_fixed", "sde_roles"):
        r = mc[mc["run"] == run].sort_values("t")
        sidx = record.duration_index("t", _ns(r["t"].to_numpy()))
        m, se = r["V_mean"].to_numpy(), r["V_se"].to_numpy()
        record.send_series(rec, f"mc/{run}/mean_V", sidx, np.c_[m, m - zc95 * se, m + zc95 * se],
                           names=[f"{run}: mean V", f"{run}: 95% low", f"{run}: 95% high"])
        record.send_series(rec, f"mc/{run}/bound46", sidx, r["bound46"].to_numpy(), names=f"{run}: (46)")
        if run == "sde_fixed":
            record.send_series(rec, "mc/sde_fixed/exact", sidx, r["exact_EV"].to_numpy(),
                               names="fixed roles: exact E{V}", colors=[(0, 0, 0)])
    record.log_markdown(rec, "lmi", lmi_markdown(dr.tables))


def views(out: Outputs) -> list[View]:
    """The recording and the figures (drawn in forked workers)."""
    dr = Drawing(out.results, out.tables, out.reproduction.is_paper)
    sc = dr.sc

    def draw_recording(path: Path) -> None:
        def log(rec):
            _log_network(rec, dr)
            _log_estimates(rec, dr)
            _log_bounds(rec, dr)
        roles = {"beta": sc.roles.beta, "radius": sc.roles.radius} if sc.roles.mode == "proximity" else {}
        recording(path, out, recording_id=f"{out.run_prefix}-{sc.name}-seed{out.seed}", timeline="t",
                  tabs=lambda: _tabs(dr), log=log,
                  properties={"alpha": sc.coupling.alpha, **roles, "N": sc.N, "P_mode": sc.coupling.P})

    return [View(f"{sc.name}.rrd", draw_recording)] + figure_views(dr)
