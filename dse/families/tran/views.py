"""The views of a coestimation run: figures (PNG) and the Rerun recording, drawn from the run's tables.

Figures 2-11 of the paper (Fig. 2 reconstructed) for the paper's example, the same views with
plain names and titles for users' scenarios, plus roles, bounds and Monte Carlo figures. One
recording `<scenario>.rrd` on timeline `t` (duration), on the shared recording scaffold: the graph
at fixed positions with each node's role g_i(t) as colour and size, the target and each node's
estimate in the plane, states and inputs against truth, errors against the bounds, the stochastic
Monte Carlo against (46) and the exact moments, the LMI results (and the scaffold's claims tab).
Every number comes from the tables (`tables.py`); the scenario gives only the layout (graph,
positions, names).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from dse.contract.views import Outputs, View, recording
from dse.outputs.figures import new_figure, plain_log_labels, save_figure, sequential_colors, set_margins
from dse.simulate.stats import z_for_confidence
from dse.outputs.tables import Tables

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


def _figure(key: str, paper: bool) -> tuple[str, str]:
    pf, pt, uf, ut = FIGURES[key]
    return (pf, pt) if paper else (uf, ut)


def state_labels(res: Results, paper: bool) -> list[str]:
    n = res.scenario.n
    return list(PAPER_STATE_LABELS) if paper and n == 4 else [f"x{k + 1}" for k in range(n)]


def _node_colors(N: int):
    return sequential_colors(N, "tab20") if N <= 20 else sequential_colors(N, "viridis")


# -- reading the tables -------------------------------------------------------------------------

def _segments(frame: pd.DataFrame, column: str) -> dict[str, slice] | None:
    """{value: its rows} of a table whose rows of each `column` value are contiguous (as the tables are
    written); None when they are not."""
    codes, labels = pd.factorize(frame[column], sort=False)
    if not len(codes):
        return {}
    starts = np.r_[0, np.flatnonzero(np.diff(codes)) + 1]
    stops = np.r_[starts[1:], len(codes)]
    first = codes[starts]
    if len(np.unique(first)) != len(first):
        return None
    return {str(labels[c]): slice(int(a), int(b)) for c, a, b in zip(first, starts, stops)}


def _grid(frame: pd.DataFrame, keys: tuple[str, ...], value: str) -> tuple[np.ndarray, np.ndarray]:
    """(t (T,), values (T, *sizes)) of a tidy frame with one row per (t, *keys), keys 0-based integers. Rows
    in (t, *keys) order, as the tables are written, are reshaped directly; others are sorted first."""
    def parts(f):
        return f["t"].to_numpy(float), [f[k].to_numpy(dtype=np.int64) for k in keys]
    t, ks = parts(frame)
    sizes = tuple(int(k.max()) + 1 for k in ks)
    per = int(np.prod(sizes))
    T = len(t) // per
    if T * per != len(t) or not _in_order(t, ks, sizes, T, per):
        frame = frame.sort_values(["t", *keys])
        t, ks = parts(frame)
    return t[::per], frame[value].to_numpy(float).reshape((T, *sizes))


def _in_order(t, ks, sizes, T: int, per: int) -> bool:
    grid = np.indices(sizes).reshape(len(sizes), per)
    tt = t.reshape(T, per)
    return (all(np.array_equal(k.reshape(T, per), np.broadcast_to(g, (T, per))) for k, g in zip(ks, grid))
            and bool(np.all(tt == tt[:, :1])) and bool(np.all(np.diff(tt[:, 0]) > 0)))


class RunView:
    """The trajectories of the tables as arrays, per run, each table split once: figures and the recording
    read the same runs many times (a boolean mask over the 1.6 million rows of `estimates` costs as much as
    splitting it). Built before the figure workers fork, so that they share it."""

    def __init__(self, res: Results, tables: Tables):
        self.res, self.tables = res, tables
        self._split = {name: _segments(tables[name], "run") for name in ("estimates", "truth", "roles")}
        self._runs: dict[str, dict | None] = {}

    def _rows(self, name: str, run: str) -> pd.DataFrame:
        frame, parts = self.tables[name], self._split[name]
        if parts is None:
            return frame[frame["run"] == run]
        return frame.iloc[parts[run]] if run in parts else frame.iloc[:0]

    def run(self, run: str) -> dict[str, np.ndarray] | None:
        """A run's samples: t (T,), x (T, n), w (T, p), e (T, N, q), g (T, N); None if absent. Noise-free runs
        share the truth ("deterministic") and the roles of the scenario's run ("coest"); the fixed run has the
        scenario's fixed roles."""
        if run not in self._runs:
            self._runs[run] = self._read(run)
        return self._runs[run]

    def _read(self, run: str) -> dict[str, np.ndarray] | None:
        est = self._rows("estimates", run)
        if est.empty:
            return None
        sc = self.res.scenario
        stochastic = run.startswith("stochastic")
        t, e = _grid(est, ("node", "component"), "value")
        xw = _grid(self._rows("truth", run if stochastic else "deterministic"), ("component",), "value")[1]
        if run == "fixed":
            g = np.broadcast_to(np.asarray(sc.fixed_roles.active, float), e.shape[:2])
        else:
            g = _grid(self._rows("roles", run if stochastic else "coest"), ("node",), "g")[1]
        return {"t": t, "x": xw[:, :sc.n], "w": xw[:, sc.n:], "e": e, "g": g}

    def stochastic_runs(self) -> list[dict]:
        runs, k = [], 0
        while (r := self.run(f"stochastic_{k}")) is not None:
            runs.append(r)
            k += 1
        return runs


    def errors(self, run: str) -> tuple[pd.DataFrame, dict[str, np.ndarray]]:
        """The `errors` rows of a run: the network's (by time) and, per node, norm_x and norm_w as (T, N)."""
        if "errors" not in self._split:
            self._split["errors"] = _segments(self.tables["errors"], "run")
        rows = self._rows("errors", run)
        net = rows["node"].isna().to_numpy()
        whole = rows[net]
        if not np.all(np.diff(whole["t"].to_numpy(float)) > 0):
            whole = whole.sort_values("t")
        per = rows[~net]
        return whole, {c: _grid(per, ("node",), c)[1] for c in ("norm_x", "norm_w")}


def bound_values(tables: Tables) -> dict[tuple[str, str], float]:
    b = tables["bounds"]
    return {(q, v): float(x) for q, v, x in zip(b["quantity"], b["variant"], b["value"])}


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
    fig.suptitle(title, fontsize=9)
    _save(fig, path, top=0.45, bottom=_legend_below(fig, axes.flat[0]))


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
    fig.suptitle(title, fontsize=9)
    _save(fig, path, top=0.45, bottom=_legend_below(fig, axes[0, 0]))


def _plane_figure(res: Results, run: dict, title: str, path: Path, labels: list[str]) -> None:
    sc = res.scenario
    a, b = sc.roles.position_states
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
    _save(fig, path)


def _draw_network(ax, res: Results, g: np.ndarray | None = None, tag_active: bool = True) -> None:
    import matplotlib.patches as mpatches

    sc = res.scenario
    pos = sc.nodes.positions
    for u, v in sc.network.build().edges():
        ax.plot(pos[[u, v], 0], pos[[u, v], 1], color="0.75", lw=0.8, zorder=1)
    active_frac = g.mean(0) if g is not None else np.zeros(sc.N)
    for i in range(sc.N):
        if sc.roles.mode == "proximity":
            ax.add_patch(mpatches.Circle(pos[i], sc.roles.radius, fill=False, color="0.85", lw=0.5, zorder=0))
        marker = "o" if sc.type_of[i] == 0 else "s"
        ax.scatter(*pos[i], s=60 + 200 * active_frac[i], marker=marker, c=[[0.85, 0.2, 0.1, 0.3 + 0.7 * active_frac[i]]],
                   edgecolors="k", zorder=3)
        tag = " AN" if tag_active and g is not None and np.any(g[:, i] > 0.5) else ""
        ax.annotate(f"{i + 1}{tag}", pos[i], xytext=(5, 5), textcoords="offset points", fontsize=7)


def _graph_figure(res: Results, run: dict, path: Path, title: str, labels: list[str]) -> None:
    sc = res.scenario
    fig, axes = new_figure(width=6.4, height=5.4)
    ax = axes[0, 0]
    _draw_network(ax, res, run["g"], tag_active=False)
    a, b = sc.roles.position_states
    ax.plot(run["x"][:, a], run["x"][:, b], "k--", lw=1, label="target path (deterministic run)")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel(labels[a])
    ax.set_ylabel(labels[b])
    ax.set_title(f"{title}\nmarker size and opacity = fraction of time active in the deterministic run\n"
                 f"circles = {sc.types[0].name}, squares = other types", fontsize=8)
    ax.legend(fontsize=7, loc="lower left")
    _save(fig, path, top=0.65)


def _roles_figure(res: Results, run: dict, path: Path) -> None:
    sc = res.scenario
    cols = _node_colors(sc.N)
    fig, axes = new_figure(nrows=2, width=9, height=2.6)
    for i in range(sc.N):
        axes[0, 0].plot(run["t"], run["g"][:, i], color=cols[i], lw=1, label=f"node {i + 1}")
    axes[0, 0].set_ylabel("g_i(t)")
    axes[1, 0].plot(run["t"], (run["g"] > 0.5).sum(1), "k-")
    axes[1, 0].set_ylabel("# active (g > 1/2)")
    axes[1, 0].set_xlabel("t (s)")
    _save(fig, path, hspace=0.55, top=0.2, bottom=_legend_below(fig, axes[0, 0], max_columns=14))


def _bounds_figure(view: RunView, path: Path) -> None:
    b = bound_values(view.tables)
    fig, axes = new_figure(ncols=2, width=5.4, height=4)
    for ax, run, label, bounds in (
            (axes[0, 0], "coest", "time-varying roles",
             [("(18), single ε", b[("bound18", "single")]), ("(18), per-node ε_i", b[("bound18", "pernode")]),
              ("(18), certified ε_i", b[("bound18", "certified")]), ("(18), vertex q*", b[("bound18", "qstar")])]),
            (axes[0, 1], "fixed", "fixed roles (Thm 2.1)", [("(18), Q̄ = Q + 2αL⊗I", b[("bound18", "fixed")])])):
        e = view.errors(run)[0]
        ax.semilogy(e["t"], e["norm_z"], "k-", label="‖z(t)‖")
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


def figure_views(view: RunView, paper: bool) -> list[View]:
    """One view per figure (the paper's figure names and titles in its reproduction, plain ones otherwise)."""
    res, sc = view.res, view.res.scenario
    labels = state_labels(res, paper)

    def fig(key, draw):
        name, title = _figure(key, paper)
        return View(f"figures/{name}.png", lambda path: draw(title, path))

    co, cp, runs = view.run("coest"), view.run("comparison"), view.stochastic_runs()
    out = [fig("graph", lambda title, path: _graph_figure(res, co, path, title, labels)),
           fig("states", lambda title, path: _states_figure(res, co, title, path, labels)),
           fig("inputs", lambda title, path: _inputs_figure(res, co, title, path)),
           fig("plane", lambda title, path: _plane_figure(res, co, title, path, labels)),
           View("figures/roles.png", lambda path: _roles_figure(res, co, path)),
           View("figures/bounds.png", lambda path: _bounds_figure(view, path)),
           View("figures/mean_square.png", lambda path: _mc_figure(view.tables, path))]
    if cp is not None:
        out += [fig("comp_states", lambda title, path: _states_figure(res, cp, title, path, labels)),
                fig("comp_inputs", lambda title, path: _inputs_figure(res, cp, title, path)),
                fig("comp_plane", lambda title, path: _plane_figure(res, cp, title, path, labels))]
    if runs:
        xs = np.stack([r["x"] for r in runs])
        band = (xs.min(0), xs.max(0), len(runs))
        a, b = sc.roles.position_states
        others = [k for k in range(sc.n) if k not in (a, b)] or [a]
        out += [fig("sde_pos", lambda title, path: _states_figure(res, runs[0], title, path, labels, [a, b], band)),
                fig("sde_other", lambda title, path: _states_figure(res, runs[0], title, path, labels, others, band)),
                fig("sde_inputs", lambda title, path: _inputs_figure(res, runs[0], title, path))]
    return out


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


def _tabs(n: int, p: int, labels: list[str], paper: bool) -> list:
    """The recording's own tabs (the scaffold adds the claims)."""
    import rerun.blueprint as rrb

    figs_est, figs_comp = (" (Figs. 3-4)", " (Figs. 6-7)") if paper else ("", "")
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


def _ns(t) -> np.ndarray:
    """Times (s) as integer nanoseconds (the recording's duration index)."""
    return np.round(np.asarray(t) * 1e9).astype(np.int64)


def _log_network(rec, view: RunView) -> None:
    """The graph with each node's role g_i(t) as colour and size, the target and the estimates in the plane."""
    import rerun as rr

    from dse.outputs import record

    sc, co = view.res.scenario, view.run("coest")
    N, (a, b), pos = sc.N, sc.roles.position_states, sc.nodes.positions
    cols = [_rgb(c) for c in _node_colors(N)]
    stride = max(1, int(round(FRAME_DT / sc.simulation.record_dt)), -(-len(co["t"]) // MAX_FRAMES))
    frames = np.arange(0, len(co["t"]), stride)
    rec.log("graph", rr.GraphEdges([(str(u), str(v)) for u, v in sc.network.build().edges()],
                                   graph_type=rr.GraphType.Undirected), static=True)
    rec.log("graph", rr.GraphNodes.from_fields(show_labels=True), static=True)
    rec.log("plane/target_path", rr.LineStrips2D([co["x"][:, [a, b]]], colors=[(0, 0, 0)], radii=0.02), static=True)
    if sc.roles.mode == "proximity":
        circ = np.linspace(0, 2 * np.pi, 60)
        rec.log("plane/sensing_discs", rr.LineStrips2D([pos[i] + sc.roles.radius * np.c_[np.cos(circ), np.sin(circ)]
                                                         for i in range(N)], colors=[(200, 200, 200)], radii=0.01),
                static=True)
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
        positions=np.tile(pos, (F, 1)), colors=node_cols, radii=(0.08 + 0.17 * g).ravel(),
        labels=np.tile(names, F)).partition(per_frame))
    rec.send_columns("plane/target", indexes=fidx, columns=rr.Points2D.columns(
        positions=co["x"][frames][:, [a, b]], colors=np.zeros((F, 3), np.uint8), radii=np.full(F, 0.12)))
    rec.send_columns("plane/estimates", indexes=fidx, columns=rr.Points2D.columns(
        positions=co["e"][frames][:, :, [a, b]].reshape(F * N, 2), colors=np.tile(np.array(cols, np.uint8), (F, 1)),
        radii=np.full(F * N, 0.07)).partition(per_frame))
    idx = record.duration_index("t", _ns(co["t"]))
    record.send_series(rec, "roles", idx, co["g"], names=[f"g_{i + 1}" for i in range(N)], colors=cols)
    record.send_series(rec, "roles/n_active", idx, (co["g"] > 0.5).sum(1), names="# active", colors=[(0, 0, 0)], width=2)


def _log_estimates(rec, view: RunView) -> None:
    """Truth and per-node estimates (by state, and by node), the comparison architecture's and the central KF's."""
    from dse.outputs import record

    sc, co, cp = view.res.scenario, view.run("coest"), view.run("comparison")
    n, p, N = sc.n, sc.p, sc.N
    idx = record.duration_index("t", _ns(co["t"]))
    cols, names, black = [_rgb(c) for c in _node_colors(N)], [f"node {i + 1}" for i in range(N)], [(0, 0, 0)]
    for k, (path, series, truth) in enumerate([(f"x{k + 1}", co["e"][:, :, k], co["x"][:, k]) for k in range(n)] +
                                              [(f"w{k + 1}", co["e"][:, :, n + k], co["w"][:, k]) for k in range(p)]):
        record.send_series(rec, f"states/{path}/nodes", idx, series, names=names, colors=cols, width=1)
        record.send_series(rec, f"states/{path}/truth", idx, truth, names="true", colors=black, width=2.5)
        record.send_series(rec, f"truth/{path}", idx, truth, names=path, colors=black)
    net, per_node = view.errors("coest")
    for i in range(N):
        record.send_series(rec, f"nodes/{i}/estimate", idx, co["e"][:, i],
                           names=[f"x̂{k + 1}" for k in range(n)] + [f"ŵ{k + 1}" for k in range(p)])
        record.send_series(rec, f"nodes/{i}/error", idx, np.c_[per_node["norm_x"][:, i], per_node["norm_w"][:, i]],
                           names=["‖x̃_i‖", "‖w̃_i‖"])
    if cp is not None:
        for k in range(n):
            record.send_series(rec, f"comparison/x{k + 1}/nodes", idx, cp["e"][:, :, k], names=names, colors=cols, width=1)
            record.send_series(rec, f"comparison/x{k + 1}/truth", idx, cp["x"][:, k], names="true", colors=black,
                               width=2.5)
        record.send_series(rec, "errors/comparison", idx, view.errors("comparison")[0][["norm_x", "norm_w"]].to_numpy(),
                           names=["comparison mean ‖x̃‖", "comparison mean ‖w̃‖"], colors=[(214, 39, 40), (255, 152, 150)])
    record.send_series(rec, "errors/coestimation", idx, net[["norm_x", "norm_w"]].to_numpy(),
                       names=["coestimation mean ‖x̃‖", "coestimation mean ‖w̃‖"], colors=[(31, 119, 180), (174, 199, 232)])
    c = view.tables["central"]
    c = c[c["run"] == "deterministic"].sort_values(["t", "component"])
    kt = np.unique(c["t"].to_numpy())
    kidx = record.duration_index("t", _ns(kt))
    est, truth = c["estimate"].to_numpy().reshape(len(kt), -1), c["truth"].to_numpy().reshape(len(kt), -1)
    record.send_series(rec, "central/estimate", kidx, est, names=[f"KF x̂{k + 1}" for k in range(n)] +
                       [f"KF ŵ{k + 1}" for k in range(p)])
    record.send_series(rec, "errors/central_kf", kidx, np.c_[np.linalg.norm(est[:, :n] - truth[:, :n], axis=1),
                                                             np.linalg.norm(est[:, n:] - truth[:, n:], axis=1)],
                       names=["central KF ‖x̃‖", "central KF ‖w̃‖"], colors=[(0, 0, 0), (127, 127, 127)])


def _log_bounds(rec, view: RunView) -> None:
    """‖z(t)‖ against the variants of (18); the Monte Carlo E{V} against (46) and the exact moments; the LMIs."""
    from dse.outputs import record

    bv, net = bound_values(view.tables), view.errors("coest")[0]
    idx = record.duration_index("t", _ns(view.run("coest")["t"]))
    nz = net["norm_z"].to_numpy()
    record.send_series(rec, "bounds/roles/norm_z", idx, nz, names="‖z(t)‖", colors=[(0, 0, 0)], width=2)
    for name in ("single", "pernode", "certified", "qstar"):
        if np.isfinite(bv[("bound18", name)]):
            record.send_series(rec, f"bounds/roles/bound18_{name}", idx, np.full(len(nz), bv[("bound18", name)]),
                               names=f"(18) {name}")
    nzf = view.errors("fixed")[0]["norm_z"].to_numpy()
    record.send_series(rec, "bounds/fixed/norm_z", idx, nzf, names="‖z(t)‖", colors=[(0, 0, 0)], width=2)
    record.send_series(rec, "bounds/fixed/bound18", idx, np.full(len(nzf), bv[("bound18", "fixed")]), names="(18)")
    record.send_series(rec, "bounds/roles/V", idx, net["V"].to_numpy(), names="V = zᵀPz", colors=[(44, 160, 44)])
    mc, zc95 = view.tables["mc_series"], z_for_confidence(0.95)
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
    record.log_markdown(rec, "lmi", lmi_markdown(view.tables))


def _recording(out: Outputs, view: RunView, path: Path, paper: bool) -> None:
    sc = view.res.scenario
    labels = state_labels(view.res, paper)

    def log(rec):
        _log_network(rec, view)
        _log_estimates(rec, view)
        _log_bounds(rec, view)

    recording(path, out, recording_id=f"tran-{sc.name}-seed{out.seed}", application_id="dse-tran", timeline="t",
              tabs=lambda: _tabs(sc.n, sc.p, labels, paper), log=log,
              properties={"alpha": sc.coupling.alpha, "beta": sc.roles.beta, "radius": sc.roles.radius, "N": sc.N,
                          "P_mode": sc.coupling.P})


def views(out: Outputs) -> list[View]:
    """The figures and the recording, drawn (in forked workers) from one view of the tables, split before the
    workers fork."""
    res, paper = out.results, out.reproduction.is_paper
    view = RunView(res, out.tables)
    view.stochastic_runs()
    for run in ("coest", "comparison", "fixed"):
        if view.run(run) is not None:
            view.errors(run)
    name = res.scenario.name
    return [View(f"{name}.rrd", lambda path: _recording(out, view, path, paper))] + figure_views(view, paper)
