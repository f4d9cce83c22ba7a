"""Figures (PNG) and Rerun recordings of the gossip-Kalman family, drawn from the run's tables.

One recording per scenario, ``<scenario>.rrd``, on the sequence timeline ``k`` (the slot):
the graph with the active matching of a sample run at each slot, per-sensor tr P̂ and
estimation error of the sample runs, quantiles over runs of log₁₀ tr P̂ per sensor (quantiles,
not means: μ can have an infinite mean), the Theorem-8 quantiles at the record times, the
centralized reference, the Lyapunov envelope and the claims.
"""
from __future__ import annotations

import functools
from pathlib import Path

import numpy as np
import pandas as pd

from dse.contract.views import Outputs, View, recording
from dse.estimators.gikf_monte_carlo import QUANTILES
from dse.outputs.figures import new_figure, plain_log_labels, save_figure, sequential_colors, set_margins

from .scenario import GossipKalmanFile

LOG10 = np.log(10.0)


#: the tables figures and recordings read (split by scenario once, before the drawing workers fork)
VIEW_TABLES = ("design", "sensors", "abar", "reference_series", "tail_bounds", "sample_paths", "matchings", "quantiles",
               "laws", "ks", "tails")


class ScenarioTables:
    """One scenario's rows of every table (figures and recordings read only these)."""

    def __init__(self, frames: dict[str, pd.DataFrame], sc: GossipKalmanFile, runs: int, reference_runs: int,
                 slots: int, seed: int):
        self.sc, self.name, self.runs, self.reference_runs, self.slots, self.seed = (sc, sc.name, runs, reference_runs,
                                                                                     slots, seed)
        self._frames = frames

    def __getitem__(self, table: str) -> pd.DataFrame:
        return self._frames.get(table, pd.DataFrame())

    def design(self, quantity: str) -> float:
        d = self["design"]
        return float(d.loc[d["quantity"] == quantity, "value"].iloc[0])

    def reference(self, series: str, cls: int | None = None) -> pd.DataFrame:
        f = self["reference_series"]
        f = f[f["series"] == series]
        return f if cls is None else f[f["class"] == cls]


def split_tables(res, tables) -> list[ScenarioTables]:
    """The rows of every scenario of the run, each table split by scenario once (the rows of a scenario in table order)."""
    frames: dict[str, dict[str, pd.DataFrame]] = {name: {} for name in res.scenarios}
    for table in VIEW_TABLES:
        if table in tables:
            for name, f in tables[table].groupby("scenario", sort=False):
                if name in frames:
                    frames[name][table] = f
    return [ScenarioTables(frames[r.name], r.scenario, r.runs, r.reference_runs, r.slots, r.seed)
            for r in res.scenarios.values()]


def _ecdf_from_quantiles(ax, frame: pd.DataFrame, **kw) -> None:
    """Plot a law from its quantile function (levels 0..1 in steps of 0.01) as a CDF."""
    if len(frame):
        ax.plot(frame["log_trace"].to_numpy() / LOG10, frame["probability"].to_numpy(), drawstyle="steps-post", **kw)


# -- figures -------------------------------------------------------------------------------------------

def _title(ax, text: str) -> None:
    """A title at the top of the axes (y given: matplotlib then skips its search for tick labels above the axes,
    a measurement of every tick label at each draw)."""
    ax.set_title(text, fontsize=9, y=1.0)


def _save(fig, path: Path, **margins) -> None:
    """Fixed margins in inches (no tight_layout: it measures every text in an extra draw) and log-axis labels
    without mathtext (parsed label by label)."""
    set_margins(fig, **margins)
    plain_log_labels(fig)
    save_figure(fig, path, tight=False)


def fig_random_sensor(v: ScenarioTables, path: Path) -> None:
    """Left: the laws of log tr P̂ at a random sensor (solid) and of the Theorem-8 process at the same t
    (dashed). Right: KS distance of the random sensor at t to μ_T (the limit sample) and to μ_t, with
    the 95% noise floor."""
    laws, ks = v["laws"], v["ks"]
    times = sorted(int(t) for t in laws.loc[laws["law"] == "random_sensor", "t"].unique() if t >= 1)
    show = times if len(times) <= 6 else [times[i] for i in np.linspace(0, len(times) - 1, 6).astype(int)]
    cols = sequential_colors(len(show))
    fig, axes = new_figure(ncols=2, width=5.4)
    ax = axes[0, 0]
    for t, col in zip(show, cols):
        at = laws[laws["t"] == t]
        _ecdf_from_quantiles(ax, at[at["law"] == "random_sensor"], color=col, lw=1.6, label=f"t = {t}")
        _ecdf_from_quantiles(ax, at[at["law"] == "theorem8"], color=col, lw=1.0, ls="--")
    ax.set_xlabel("log₁₀ tr P̂")
    ax.set_ylabel("CDF")
    _title(ax, f"{v.name}: random sensor q ({v.runs} runs, solid)\nvs Theorem-8 process μ_t ({v.reference_runs} runs, "
                 "dashed)")
    ax.legend(ncol=1)
    ax = axes[0, 1]
    ax.semilogx(ks["t"], ks["ks_to_mu_T"], "o-", label="KS(random sensor at t, μ_T)")
    ax.semilogx(ks["t"], ks["ks_to_mu_t"], "s--", label="KS(random sensor at t, μ_t): exact identity")
    if len(ks):
        ax.axhline(float(ks["noise_floor_95"].iloc[0]), color="k", ls=":", label="95% noise floor")
    ax.set_xlabel("slot t")
    ax.set_ylabel("KS distance")
    _title(ax, "convergence to μ and the finite-t identity")
    ax.legend()
    _save(fig, path, top=0.6)


def fig_per_sensor(v: ScenarioTables, path: Path) -> None:
    laws = v["laws"]
    T = int(laws["t"].max())
    fig, axes = new_figure()
    ax = axes[0, 0]
    N = v.sc.N
    cols = sequential_colors(min(N, 12), "tab10")
    sensor = laws[laws["law"] == "sensor"]
    for n in range(min(N, 12)):
        _ecdf_from_quantiles(ax, sensor[sensor["node"] == n], color=cols[n], lw=1.0,
                             label=f"sensor {n} (type {v.sc.types[n]})")
    _ecdf_from_quantiles(ax, laws[(laws["law"] == "theorem8") & (laws["t"] == T)], color="k", lw=2.2,
                         label="μ_T (Theorem-8 process)")
    ax.set_xlabel("log₁₀ tr P̂_n(T)")
    ax.set_ylabel("CDF")
    _title(ax, f"{v.name}: per-sensor laws at T = {T}; their mixture is μ (weak consensus)")
    ax.legend(ncol=2, fontsize=7)
    _save(fig, path)


def fig_tails(v: ScenarioTables, path: Path) -> None:
    tails, bounds = v["tails"], v["tail_bounds"]
    fig, axes = new_figure()
    ax = axes[0, 0]
    first = tails[tails["node"] == 0]
    J, mu = first["J"].to_numpy(), first["mu_tail"].to_numpy()
    ax.loglog(J, np.where(mu > 0, mu, np.nan), "k-", lw=2, label=f"μ̂: P(‖P̃(T)‖ > J), {v.reference_runs} runs")
    for n, f in tails.groupby("node"):
        S = f["sup_t_tail"].to_numpy()
        ax.loglog(f["J"], np.where(S > 0, S, np.nan), lw=0.8, alpha=0.6, color="tab:blue",
                  label="sensors: sup_t P(‖P̂_n(t)‖ ≥ J)" if n == 0 else None)
    ax.loglog(J, first["N_mu_bound"], "b:", label="N μ̂ bound (27)")
    if len(bounds) and np.isfinite(bounds["beta_single"]).any():
        ax.loglog(bounds["J"], bounds["beta_single"], "r--", label="Lemma 15 β(J), single witness")
        if np.isfinite(bounds["beta_multi"]).any():
            ax.loglog(bounds["J"], bounds["beta_multi"], "m--", label="Lemma 15 β(J), all witness windows")
    elif len(bounds):
        ax.text(0.02, 0.02, "Lemma 15 β(J) not drawn: Ā is a Monte Carlo estimate (greedy matching)",
                transform=ax.transAxes, fontsize=7)
    ax.set_xlabel("J")
    ax.set_ylabel("tail probability")
    ax.set_ylim(1e-5, 1.5)
    _title(ax, f"{v.name}: stochastic boundedness — empirical tails vs bounds")
    ax.legend(fontsize=7)
    _save(fig, path)


def fig_sample_paths(v: ScenarioTables, path: Path) -> None:
    paths = v["sample_paths"]
    run0 = paths[(paths["run"] == 0) & (paths["component"] == 0)]
    N = v.sc.N
    fig, axes = new_figure(height=4.6)
    ax = axes[0, 0]
    cols = sequential_colors(N, "tab10" if N <= 10 else "viridis")
    for n, f in run0[run0["node"].notna()].groupby("node"):
        ax.semilogy(f["t"], f["trace"], lw=0.9, color=cols[int(n)], label=f"sensor {n}")
    central = v.reference("central")
    ax.semilogy(central["t"], central["trace"], "k--", lw=1.5, label="centralized P_c(t)")
    ax.set_xlabel("slot t")
    ax.set_ylabel("tr P̂_n(t)")
    _title(ax, f"{v.name}: one GIKF run, trace of every sensor's covariance")
    ax.legend(ncol=3, fontsize=6)
    _save(fig, path)


def fig_quantiles(v: ScenarioTables, path: Path) -> None:
    q = v["quantiles"]
    q = q[q["protocol"] == "protocol"]
    N = v.sc.N
    fig, axes = new_figure(height=4.6)
    ax = axes[0, 0]
    cols = sequential_colors(N, "tab10" if N <= 10 else "viridis")
    for (n, p), f in q[q["probability"].isin([0.5, 0.99])].groupby(["node", "probability"]):
        ax.plot(f["t"], f["log_trace"] / LOG10, color=cols[int(n)], lw=1.2 if p == 0.5 else 0.7,
                ls="-" if p == 0.5 else ":", label=f"sensor {n} median" if p == 0.5 else None)
    laws = v["laws"]
    mu = laws[laws["law"] == "theorem8"]
    for p, style, label in ((0.5, "ko-", "μ_t median (Theorem 8)"), (0.99, "ks:", "μ_t q0.99")):
        f = mu[np.isclose(mu["probability"], p)]
        ax.plot(f["t"], f["log_trace"] / LOG10, style, ms=3, label=label)
    sensors = v["sensors"]
    rate = sensors["divergence_rate"].to_numpy()
    if (rate > 0).any():
        n = int(np.argmax(rate))
        med = q[(q["node"] == n) & (q["probability"] == 0.5)]
        t, y = med["t"].to_numpy(), med["log_trace"].to_numpy() / LOG10
        k = len(t) // 2
        ax.plot(t[k:], y[k] + (t[k:] - t[k]) * rate[n] / LOG10, "r--", lw=2,
                label=f"predicted slope 2 log|λ| = {rate[n]:.3f}/slot")
    ax.set_xlabel("slot t")
    ax.set_ylabel("log₁₀ tr P̂_n(t): quantiles over runs")
    _title(ax, f"{v.name}: median (solid) and q0.99 (dotted) over {v.runs} runs")
    ax.legend(ncol=3, fontsize=6)
    _save(fig, path)


def fig_matchings(v: ScenarioTables, path: Path) -> None:
    m = v["matchings"]
    m = m[m["run"] == 0]
    N = v.sc.N
    T = min(int(m["t"].max()), 120)
    partners = m[m["t"] < T].sort_values(["t", "node"])["partner"].to_numpy().reshape(T, N)
    edges = _edges(v.sc)
    if len(edges) <= 40:
        grid = np.zeros((len(edges), T))
        for k, (u, w) in enumerate(edges):
            grid[k] = partners[:, u] == w
        labels, ylabel = [f"{u}–{w}" for u, w in edges], "edge"
    else:  # many edges (E9): one row per node, shaded when the node is matched
        grid = (partners != np.arange(N)).T.astype(float)
        labels, ylabel = [str(n) for n in range(N)], "node (shaded: matched)"
    fig, axes = new_figure(width=8, height=max(2.5, 0.22 * len(labels) + 1))
    ax = axes[0, 0]
    ax.imshow(grid, aspect="auto", cmap="Greys", interpolation="nearest")
    ax.set_yticks(range(len(labels)))
    ax.set_yticklabels(labels, fontsize=6)
    ax.set_xlabel("slot t")
    ax.set_ylabel(ylabel)
    ax.grid(False)
    _title(ax, f"{v.name}: active matching A(t) of sample run 0 ({v.sc.protocol.kind}; A(0) = I)")
    _save(fig, path, left=0.8)


def figures(v: ScenarioTables) -> list[View]:
    """The figures of a scenario (the laws per sensor and the tails only where no class diverges)."""
    drawn = [(fig_sample_paths, "sample_paths_trace"), (fig_quantiles, "quantiles_over_runs"), (fig_matchings, "matchings"),
             (fig_random_sensor, "laws_random_sensor_vs_mu")]
    if not (v["sensors"]["divergence_rate"] > 0).any():
        drawn += [(fig_per_sensor, "laws_per_sensor"), (fig_tails, "tails_vs_bound")]
    return [View(f"figures/{stem}_{v.name}.png", functools.partial(fig, v)) for fig, stem in drawn]


# -- recordings ----------------------------------------------------------------------------------------

def _groups(frame: pd.DataFrame, keys: list[str]):
    """Rows of `frame` by the values of `keys` (each group in table order; an absent key gives no rows), split once
    instead of one boolean mask per series."""
    groups = {k: g for k, g in frame.groupby(keys, sort=False)}
    empty = frame.iloc[:0]
    return lambda *key: groups.get(key, empty)


def _series(frame: pd.DataFrame, index: np.ndarray, value: str) -> np.ndarray:
    """A column of a frame sorted by t, on the slots `index` (NaN where the frame has no row)."""
    out = np.full(len(index), np.nan)
    pos = np.searchsorted(index, frame["t"].to_numpy())
    out[pos] = frame[value].to_numpy()
    return out


#: the overview's legends are shown up to this many sensors (each has a curve per sample run)
MAX_LEGEND_SENSORS = 3


def _tabs(v: ScenarioTables):
    import rerun.blueprint as rrb

    N, n_show = v.sc.N, min(v.sc.N, 12)
    # one curve per sensor and sample run (and per quantile): with more than a few sensors the legend would
    # cover the plot; the colours are the sensors', and hovering a curve names it
    legend = rrb.PlotLegend(rrb.Corner2D.RightTop, visible=N <= MAX_LEGEND_SENSORS)
    return [rrb.Horizontal(
                rrb.Vertical(rrb.GraphView(origin="/graph", name="active matching A(t) (sample run 0)"),
                             rrb.GraphView(origin="/links", name="allowed links (graph)"), row_shares=[3, 2]),
                rrb.Vertical(rrb.TimeSeriesView(origin="/nodes", name="tr P̂_n(t), sample run 0, every sensor",
                                                contents=[f"/nodes/{n}/cov_trace/**" for n in range(N)]
                                                + ["/central/cov_trace"], plot_legend=legend),
                             rrb.TimeSeriesView(origin="/mc", name="log10 tr P̂: median over runs per sensor, μ_t "
                                                                    "quantiles", contents=["/mc/median/**", "/mc/mu/**"],
                                                plot_legend=legend),
                             row_shares=[1, 1]),
                column_shares=[2, 3], name="overview"),
            rrb.Grid(*[rrb.TimeSeriesView(origin=f"/mc/quantiles/{n}", name=f"sensor {n}: log10 tr P̂ quantiles over runs",
                                          contents=[f"/mc/quantiles/{n}/**", "/mc/mu/**"]) for n in range(n_show)],
                     name="quantiles over runs"),
            rrb.Grid(*[rrb.TimeSeriesView(origin=f"/nodes/{n}/error", name=f"sensor {n}: estimation error (run 0)",
                                          contents=[f"/nodes/{n}/error/**", "/central/error/**"]) for n in range(n_show)],
                     name="errors")]


def _log_matchings(rec, v: ScenarioTables) -> None:
    """The graph, its allowed links, and the active matching of sample run 0 at every slot."""
    import rerun as rr

    from dse.outputs import record

    sc, N = v.sc, v.sc.N
    pos = sc.network.positions()
    edges = _edges(sc)
    ids = [str(n) for n in range(N)]
    labels = [f"s{n} (type {sc.types[n]})" for n in range(N)]
    colors = [record.color(t) for t in sc.types]
    # nodes static, the active matching per slot (static edges would override the per-slot ones)
    rec.log("graph", rr.GraphNodes(ids, positions=record.display_positions(pos), labels=labels, colors=colors,
                                   radii=12.0, show_labels=True), static=True)
    record.log_graph(rec, "links", pos, edges, labels=labels, colors=colors)
    m = v["matchings"]
    m = m[m["run"] == 0].sort_values(["t", "node"])
    n_match = int(m["t"].max()) + 1
    partners = m["partner"].to_numpy().reshape(n_match, N)
    per_step = [[(str(n), str(int(p))) for n, p in enumerate(row) if p > n] for row in partners]
    flat = [e for es in per_step for e in es]
    match_idx = record.sequence_index("k", np.arange(n_match))
    if flat:
        rec.send_columns("graph", indexes=match_idx,
                         columns=rr.GraphEdges.columns(edges=flat).partition([len(es) for es in per_step]))
    record.send_series(rec, "events/matching_size", match_idx, np.array([len(es) for es in per_step], float),
                       names="edges in A(t), run 0", points=True)
    record.log_tensor(rec, "graph/Abar", v["abar"].sort_values(["row", "col"])["value"].to_numpy().reshape(N, N))


def _log_runs(rec, v: ScenarioTables) -> None:
    """The sample runs (traces and errors of every sensor and of the centralized filter), the quantiles over runs
    of every sensor, the Theorem-8 quantiles at the record times and the Lyapunov envelope."""
    from dse.outputs import record

    N, M = v.sc.N, v.sc.M
    paths = v["sample_paths"]
    slots = np.sort(paths["t"].unique())
    idx = record.sequence_index("k", slots)
    runs = sorted(paths["run"].unique())
    sensor = _groups(paths[paths["node"].notna()], ["node", "run", "component"])
    for n in range(N):
        tr = np.column_stack([_series(sensor(n, k, 0), slots, "trace") for k in runs])
        record.send_series(rec, f"nodes/{n}/cov_trace", idx, tr, names=[f"sensor {n} run {k}" for k in runs],
                           colors=[record.color(n)] * len(runs))
        err = np.column_stack([_series(sensor(n, 0, j), slots, "error") for j in range(M)])
        record.send_series(rec, f"nodes/{n}/error", idx, err, names=[f"sensor {n}: e_{j + 1}" for j in range(M)],
                           colors=[record.color(j) for j in range(M)])
    q = v["quantiles"]
    q = q[q["protocol"] == "protocol"]
    q_slots = np.sort(q["t"].unique())
    q_idx = record.sequence_index("k", q_slots)
    quantile = _groups(q, ["node", "probability"])
    for n in range(N):
        qs = np.column_stack([_series(quantile(n, p), q_slots, "log_trace") / LOG10 for p in QUANTILES])
        record.send_series(rec, f"mc/quantiles/{n}", q_idx, qs, names=[f"q{p:g}" for p in QUANTILES],
                           colors=[record.color(n)] * len(QUANTILES), width=1.0)
        record.send_series(rec, f"mc/median/{n}", q_idx, qs[:, QUANTILES.index(0.5)], names=f"sensor {n} median",
                           colors=[record.color(n)])
    central = v.reference("central")
    central = central[central["t"].isin(slots)]
    record.send_series(rec, "central/cov_trace", idx, _series(central, slots, "trace"), names="centralized tr P_c(t)",
                       colors=[(0, 0, 0)], width=2.5)
    cen = paths[paths["node"].isna() & (paths["run"] == 0)]
    record.send_series(rec, "central/error", idx,
                       np.column_stack([_series(cen[cen["component"] == j], slots, "error") for j in range(M)]),
                       names=[f"centralized e_{j + 1}" for j in range(M)], colors=[(0, 0, 0)] * M, width=2.0)
    env = v.reference("envelope")
    env = env[env["t"].isin(slots)]
    record.send_series(rec, "bounds/envelope_log10_trace", idx, _series(env, slots, "log_trace") / LOG10,
                       names="log10 tr f_0^t(P0) (Lyapunov envelope)", colors=[(120, 120, 120)])
    mu = v["laws"][v["laws"]["law"] == "theorem8"]
    mu_t = np.sort(mu["t"].unique())
    ref_q = np.column_stack([_series(mu[np.isclose(mu["probability"], p)], mu_t, "log_trace") / LOG10
                             for p in QUANTILES])
    record.send_series(rec, "mc/mu", record.sequence_index("k", mu_t), ref_q,
                       names=[f"μ_t q{p:g} (Theorem 8)" for p in QUANTILES], colors=[(0, 0, 0)] * len(QUANTILES),
                       points=True)


def write_recording(v: ScenarioTables, path: Path, out: Outputs) -> None:
    """One scenario's recording on the shared scaffold (its claims: those whose id ends with its name, or every
    claim of a one-scenario run)."""
    from dse.outputs.report import counts_line, verdict_counts

    sc, repro = v.sc, out.reproduction
    several = len(repro.scenarios) > 1   # a one-scenario run's ids do not name the scenario: every claim is its own
    own = [c for c in out.claims if not several or c["id"].endswith(f".{sc.name}")]
    summary = (f"# {sc.name}: {counts_line(verdict_counts(own))}\n\n{sc.description}\n\nseed {v.seed}, {v.runs:,} GIKF "
               f"runs, {v.reference_runs:,} Theorem-8 runs, {v.slots} slots")

    def log(rec):
        _log_matchings(rec, v)
        _log_runs(rec, v)

    recording(path, out, recording_id=f"{out.run_prefix}-{sc.name}-seed{v.seed}", tabs=lambda: _tabs(v), timeline="k", log=log,
              properties={"runs": v.runs, "reference_runs": v.reference_runs, "slots": v.slots, "N": sc.N, "M": sc.M,
                          "protocol": sc.protocol.kind, "graph": sc.network.kind}, summary=summary, claims=own)


def views(out: Outputs) -> list[View]:
    """Every scenario's recording and figures, drawn from the tables split by scenario once."""
    found = []
    for v in split_tables(out.results, out.tables):
        found.append(View(f"{v.name}.rrd", functools.partial(write_recording, v, out=out)))
        found += figures(v)
    return found


def _edges(sc) -> list[tuple[int, int]]:
    """The graph's edges (u < v), sorted: from `edge_array`, which needs networkx only for the random kinds (the
    drawing workers then do not import it, about 0.07 s each)."""
    return sorted({(int(u), int(w)) for u, w in sc.network.edge_array()})
