"""Figures (PNG) and Rerun recordings of the hybrid-observer family, drawn from the run's tables.

One recording per (system, run): ``<part>_<run>.rrd`` on the continuous timeline ``t``
(integer nanoseconds): the true state and each agent's estimate (trial 0), the error of each
agent at the stored samples and before/after every reset at the event times, trial 0's
estimator iterates at their iteration times (first stored intervals), statistics over trials,
the bound curves, the switching graph (source sets of the first stored intervals) and the
claims. Errors are also recorded as log10(max(error, 1e-300)): an exact zero never breaks a
log scale.
"""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pandas as pd
import rerun as rr
import rerun.blueprint as rrb

from dse.outputs import record as rec_
from dse.outputs.figures import draw_all, new_figure, plain_log_labels, save_figure, set_margins

from . import bounds
from . import claims as cl

TINY = 1e-300
AGENT_COLORS = [(31, 119, 180), (255, 127, 14), (44, 160, 44), (214, 39, 40), (148, 103, 189), (140, 86, 75),
                (227, 119, 194), (127, 127, 127)]


def _col(i: int) -> tuple[int, int, int]:
    return AGENT_COLORS[i % len(AGENT_COLORS)]


def _mpl(i: int):
    return tuple(c / 255 for c in _col(i))


def log10_safe(v: np.ndarray) -> np.ndarray:
    return np.log10(np.maximum(np.asarray(v, float), TINY))


class TableView:
    """The run's tables, each split once into its rows per scenario (and run) on first use:
    figures and recordings select the same rows many times, and a boolean mask over the
    580,000 rows of `state_series` costs about as much as splitting the whole table."""

    def __init__(self, tables):
        self.tables = tables
        self._parts: dict[tuple[str, bool], dict] = {}

    def __getitem__(self, name: str) -> pd.DataFrame:
        return self.tables[name]

    def rows(self, name: str, scenario: str, run: str | None = None) -> pd.DataFrame:
        """The rows of one table for a scenario (and a run), in table order."""
        key = (name, run is not None)
        if key not in self._parts:
            by = ["scenario", "run"] if run is not None else ["scenario"]
            self._parts[key] = dict(iter(self.tables[name].groupby(by, sort=False)))
        return self._parts[key].get((scenario, run) if run is not None else (scenario,), self.tables[name].iloc[:0])


def _pivot(frame: pd.DataFrame, column: str, index: str = "t", by: str = "node") -> tuple[np.ndarray, np.ndarray]:
    """(index values, matrix index x by) of a tidy frame; a frame already in (index, by) order
    (as the tables are written) is reshaped without pandas' pivot."""
    idx, keys, vals = frame[index].to_numpy(float), frame[by].to_numpy(), frame[column].to_numpy(float)
    labels = np.unique(keys)
    k = len(labels)
    if k and len(vals) % k == 0:
        first = idx[::k]
        if (np.array_equal(keys, np.tile(labels, len(vals) // k)) and np.all(np.diff(first) > 0)
                and np.array_equal(idx.reshape(-1, k), np.repeat(first[:, None], k, axis=1))):
            return first, vals.reshape(-1, k)
    p = frame.pivot(index=index, columns=by, values=column).sort_index()
    return p.index.to_numpy(float), p.to_numpy(float)


# -- figures --------------------------------------------------------------------------------------

def _save(fig, path: Path, **margins) -> None:
    """Fixed margins (inches) instead of tight_layout's extra measuring draw; log-axis labels
    without mathtext."""
    set_margins(fig, **margins)
    plain_log_labels(fig)
    save_figure(fig, path, tight=False)


def _trace_figure(tables, scenario: str, run: str, m: int, title: str, path: Path, agents=(0,), component: int = 2,
                  shade: tuple[float, float] | None = None) -> None:
    st = tables.rows("state_series", scenario, run)
    st = st[st["component"] == component + 1]
    truth = st[st["source"] == "truth"]
    fig, axes = new_figure(ncols=2, width=5.6)
    ax = axes[0, 0]
    ax.plot(truth["t"], truth["value"], "k-", lw=2, label=f"x^({component + 1})")
    for i in agents:
        est = st[(st["source"] == "agent") & (st["node"] == i + 1)]
        ax.plot(est["t"], est["value"], "--", color=_mpl(i), lw=1.3, label=f"x_{i + 1}^({component + 1})")
    ax.set_xlabel("t")
    ax.set_title(title, fontsize=9)
    ax.legend()
    ax = axes[0, 1]
    t, err = _pivot(tables.rows("node_series", scenario, run), "error_trial0")
    for i in range(m):
        ax.semilogy(t, np.maximum(err[:, i], TINY), color=_mpl(i), lw=1, label=f"||e_{i + 1}(t)||")
    net = tables.rows("network_series", scenario, run)
    if np.isfinite(net["kalman_trial0"]).any():
        ax.semilogy(net["t"], np.maximum(net["kalman_trial0"], TINY), "k:", lw=1, label="centralized KF (filterpy)")
    else:
        ax.semilogy(net["t"], np.maximum(net["central_trial0"], TINY), "k:", lw=1, label="centralized observer")
    if shade:
        for a in axes[0]:
            a.axvspan(*shade, color="0.85", zorder=0)
    ax.set_xlabel("t")
    ax.set_title("estimation errors (log scale)", fontsize=9)
    ax.legend(ncol=2)
    _save(fig, path)


def _fig1(path: Path) -> None:
    """Fig. 1 with illustrative values: Δ = 1, β = 0.3, ε = 0.1."""
    rng = np.random.default_rng(0)
    Delta, beta, eps = 1.0, 0.3, 0.1
    fig, axes = new_figure(width=7.0, height=2.8)
    ax = axes[0, 0]
    for row, name in ((1, "agent i"), (0, "agent j")):
        tau = np.arange(5) * Delta + rng.uniform(-eps, eps, 5)
        ax.vlines(tau, row - 0.3, row + 0.3, color="k")
        for k, tk in enumerate(tau):
            ax.text(tk, row + 0.35, f"τ({k})", ha="center", fontsize=7)
        if row == 0:
            ax.plot(tau[:-1] + beta, np.full(4, row), "v", color="tab:red", label="j broadcasts z_j(k-1) at τ_j(k-1)+β")
        else:
            for k in range(4):
                ax.plot([tau[k], tau[k + 1]], [row - 0.15] * 2, color="tab:blue", lw=3, alpha=0.4)
        ax.text(-0.6, row, name, va="center")
    ax.set_yticks([])
    ax.set_xlim(-0.8, 4.6)
    ax.set_xlabel("time (Δ = 1, β = 0.3, ε = 0.1)")
    ax.set_title("Fig. 1: j's broadcast falls inside i's reception interval [τ_i(k-1), τ_i(k)) under (10)", fontsize=9)
    ax.legend(loc="lower right")
    _save(fig, path, left=0.2, right=0.2)


def _graph_figure(tables, scenario: str, path: Path) -> None:
    props = tables.rows("graph_properties", scenario)
    arcs = tables.rows("graphs", scenario)
    m = int(tables.rows("agents", scenario)["node"].max())
    fig, axes = new_figure(ncols=len(props), width=3.4, height=3.4)
    ang = np.pi / 2 - 2 * np.pi * np.arange(m) / m
    pos = np.column_stack([np.cos(ang), np.sin(ang)])
    for ax, (_, g) in zip(axes[0], props.iterrows()):
        for _, a in arcs[arcs["graph"] == g["graph"]].iterrows():          # arc j -> i
            i, j = int(a["receiver"]) - 1, int(a["sender"]) - 1
            ax.annotate("", xy=pos[i] * 0.85 + pos[j] * 0.15, xytext=pos[j] * 0.85 + pos[i] * 0.15,
                        arrowprops=dict(arrowstyle="->", color="0.3", lw=1.2))
        for i in range(m):
            ax.scatter(*pos[i], s=500, color=_mpl(i), zorder=3)
            ax.text(*pos[i], str(i + 1), ha="center", va="center", color="w", zorder=4)
        ax.set_title(g["name"] + ("" if g["strongly_connected"] else " (not strongly connected)"), fontsize=9)
        ax.set_xlim(-1.4, 1.4)
        ax.set_ylim(-1.4, 1.4)
        ax.set_aspect("equal")
        ax.axis("off")
    _save(fig, path, left=0.1, right=0.1, bottom=0.1, wspace=0.2)


def _bounds_figure(res, tables, scenario: str, path: Path) -> None:
    """Theorem 1 on a run inside its hypotheses: |e(s)| over trials vs (51); the continuous bound
    as printed and corrected on the idealised run (trial 0)."""
    r = res[scenario]
    fig, axes = new_figure(ncols=2, width=5.6)
    sync = next((s for s in r.scenario.runs if s.timing == "sync" and cl.in_theorem1(r, s) and not s.ideal), None)
    if sync is None:
        sync = next((s for s in r.scenario.runs if s.timing == "sync" and bounds.is_theorem_run(s)), None)
    ax = axes[0, 0]
    if sync is not None:
        ev = tables.rows("events", scenario, sync.name)
        ev = ev[ev["s"] >= 1]
        ts = ev["s"].to_numpy() * r.scenario.T
        ax.semilogy(ts, np.maximum(ev["error_max"], TINY), "o-", ms=3, label=f"max over {int(ev['trials'].iloc[0])} "
                                                                             "trials |e(s)|")
        ax.semilogy(ts, np.maximum(ev["error_mean"], TINY), ".-", ms=3, label="mean |e(s)|")
        ax.semilogy(ts, ev["bound51_max"], "k--", label="bound (51), largest over trials")
        ax.semilogy(ts, np.exp(-r.scenario.lam * ts) * float(ev["error_max"].iloc[0]), "k:", lw=1,
                    label=f"e^(-λt), λ = {r.scenario.lam}")
        ax.set_title(f"{scenario}/{sync.name}: event-sampled error vs (51), q = {sync.q}", fontsize=9)
        ax.legend()
    ax.set_xlabel("t = sT")
    ideal = next((s for s in r.scenario.runs if s.ideal and bounds.is_theorem_run(s)), None)
    ax = axes[0, 1]
    if ideal is not None:
        net = tables.rows("network_series", scenario, ideal.name)
        T = r.scenario.T
        sel = net["t"].to_numpy() <= 3 * T
        t, err = net["t"].to_numpy()[sel], net["error_trial0"].to_numpy()[sel]
        ax.plot(t, err / net["bound_printed_trial0"].to_numpy()[sel], color="tab:red",
                label="||e(t)|| / printed bound e^(||A||T-λt)(...)")
        ax.plot(t, err / net["bound_corrected_trial0"].to_numpy()[sel], color="k",
                label="||e(t)|| / corrected bound (× e^(λT))")
        nd = tables.rows("nodes", scenario, ideal.name)
        pre = nd.groupby("s")["error_before_reset"].max()
        pre = pre[(pre.index >= 1) & (pre.index * T <= 3 * T)]
        pts = pre.index.to_numpy() * T
        printed_at = np.interp(pts, net["t"], net["bound_printed_trial0"])
        ax.plot(pts, pre.to_numpy() / printed_at, "v", color="tab:red", ms=6, label="left limits e(sT⁻) / printed")
        ax.axhline(1.0, color="0.4", ls="--", lw=1)
        ax.set_title(f"{scenario}/{ideal.name} (ē(0) = 0): continuous-time bound ratio, trial 0", fontsize=9)
        ax.set_xlabel("t")
        ax.legend(fontsize=7)
    _save(fig, path)


def _decay_figure(res, tables, path: Path) -> None:
    fig, axes = new_figure()
    ax = axes[0, 0]
    for idx, (name, r) in enumerate(res.parts.items()):
        sync = next((s for s in r.scenario.runs if s.timing == "sync" and not s.ideal and bounds.is_theorem_run(s)), None)
        if sync is None:
            continue
        ev = tables.rows("events", name, sync.name)
        t, e, fl = ev["t"].to_numpy(), ev["error_trial0"].to_numpy(), ev["floor_trial0"].to_numpy()
        rate, first, stop = cl.fit_rate(t, e, fl)
        c = _mpl(idx)
        ax.semilogy(t, np.maximum(e, TINY), "o", ms=3, color=c, label=f"{name}/{sync.name}: max_i||e_i(t_is)||")
        ax.semilogy(t, fl, ":", color=c, lw=1, label=f"{name}: round-off allowance")
        if not math.isnan(rate):
            tt = t[first:stop]
            c0 = np.exp(np.polyfit(tt, np.log(e[first:stop]), 1)[1])
            ax.semilogy(tt, c0 * np.exp(-rate * tt), "-", color=c, lw=1.5, label=f"{name}: fit, rate {rate:.3f} "
                                                                               f"(λ = {r.scenario.lam})")
    ax.set_xlabel("t")
    ax.set_title("decay rate fits stop where round-off starts", fontsize=9)
    ax.legend(fontsize=7)
    _save(fig, path)


def _anorm_figure(res, tables, path: Path) -> None:
    import matplotlib.pyplot as plt

    parts = list(res.parts.items())
    fig, axes = new_figure(ncols=len(parts), width=5.4)
    cmap = plt.get_cmap("tab20")
    for ax, (name, r) in zip(axes[0], parts):
        k = 0
        for s in r.scenario.runs:
            iv = tables.rows("intervals", name, s.name)
            key = "A_2" if s.rule == "symmetric" else "A_mixed"
            v = iv[key].to_numpy()
            if np.all(np.isnan(v)) or s.noise:
                continue
            ax.semilogy(iv["s"], np.maximum(v, TINY), marker=".", ms=3, lw=1, color=cmap(k % 20),
                        ls="-" if k < 10 else "--", label=f"{s.name} ({'||·||₂' if key == 'A_2' else '|·|'}, q = {s.q})")
            k += 1
        ax.axhline(math.exp(-r.scenario.lam * r.scenario.T), ls="--", lw=1.2, color="k", label="e^(-λT)")
        ax.set_xlabel("event interval s")
        ax.set_title(f"{name}: |A(s)| per interval, Lemma 4 (44) and (54)", fontsize=9)
        ax.legend(fontsize=6, ncol=2)
    _save(fig, path)


def figure_jobs(res, tables, out_dir: Path, paper: bool) -> list:
    figs = out_dir / "figures"
    jobs = []
    if paper:
        m = res["paper"].scenario.m
        lv = res["paper"].spec("fig5_leave_join").leave
        jobs += [lambda: _fig1(figs / "fig1_timing.png"),
                 lambda: _graph_figure(tables, "paper", figs / "fig2_graphs.png"),
                 lambda: _trace_figure(tables, "paper", "fig3_noise", m, "Fig. 3: x' = Ax + b cos(10t); graphs 2a/2b "
                                       "alternate", figs / "fig3.png"),
                 lambda: _trace_figure(tables, "paper", "fig4_offset", m, "Fig. 4: agent 4's events 0.2T early "
                                       "(index-aligned exchange)", figs / "fig4.png", agents=(0, 3)),
                 lambda: _trace_figure(tables, "paper", "fig5_leave_join", m, "Fig. 5: agent 4 leaves at t = 5, "
                                       "re-joins at t = 7 (graph 2a)", figs / "fig5.png", agents=(0, 3),
                                       shade=(lv.at, lv.rejoin))]
        jobs += [lambda name=name: _bounds_figure(res, tables, name, figs / f"theorem1_bounds_{name}.png")
                 for name in res.parts]
    else:
        for name, r in res.parts.items():
            jobs += [lambda name=name: _graph_figure(tables, name, figs / "graphs.png"),
                     lambda name=name: _bounds_figure(res, tables, name, figs / "theorem1_bounds.png")]
            for s in r.scenario.runs:
                shade = (s.leave.at, s.leave.rejoin) if s.leave else None
                jobs.append(lambda name=name, s=s, shade=shade, r=r: _trace_figure(
                    tables, name, s.name, r.scenario.m, f"run {s.name}", figs / f"run_{s.name}.png", shade=shade,
                    component=min(2, r.scenario.n - 1)))
    jobs += [lambda: _decay_figure(res, tables, figs / "decay_rates.png"),
             lambda: _anorm_figure(res, tables, figs / "A_norms.png")]
    return jobs


# -- recordings -------------------------------------------------------------------------------------

def _ns(t) -> np.ndarray:
    return np.round(np.asarray(t, float) * 1e9).astype(np.int64)


def write_run_recording(res, tables, scenario: str, run_name: str, path: Path, claims: list[dict], prov: dict,
                        summary: str) -> None:
    r = res[scenario]
    sc = r.scenario
    spec = r.spec(run_name)
    m, n = sc.m, sc.n
    blueprint = rrb.Blueprint(
        rrb.Tabs(
            rrb.Horizontal(
                rrb.Grid(*[rrb.TimeSeriesView(origin=f"/nodes/{i + 1}", name=f"agent {i + 1}: estimate vs truth",
                                              contents=[f"/nodes/{i + 1}/estimate/**", "/truth/**"])
                           for i in range(min(m, 6))]),
                rrb.Vertical(rrb.TimeSeriesView(origin="/", name="log10 errors, bounds",
                                                contents=[f"/nodes/{i + 1}/log10_error/**" for i in range(m)]
                                                + ["/bounds/log10/**", "/central/log10/**", "/mc/log10/**"]),
                             rrb.GraphView(origin="/graph", name="neighbour graph N(t)"), row_shares=[2, 1]),
                column_shares=[3, 2], name="estimates"),
            rrb.Grid(*[rrb.TimeSeriesView(origin=f"/nodes/{i + 1}", name=f"agent {i + 1}: errors at resets",
                                          contents=[f"/nodes/{i + 1}/log10_error/**", f"/nodes/{i + 1}/reset/**"])
                       for i in range(min(m, 6))], name="resets"),
            rrb.Grid(*[rrb.TimeSeriesView(origin=f"/nodes/{i + 1}/iterates", name=f"agent {i + 1}: log10 ||z_is(k) - x(t_i(s-1))||")
                       for i in range(min(m, 6))], name="iterates"),
            rrb.TimeSeriesView(origin="/bounds", name="|A(s)|, bounds", contents=["/bounds/**"]),
            rrb.Horizontal(rrb.TextDocumentView(origin="/report", name="claims"),
                           rrb.TextDocumentView(origin="/claims", name="claim detail"), name="claims"),
        ),
        rrb.TimePanel(timeline="t", expanded=False),
        collapse_panels=True,
    )
    ev = tables.rows("events", scenario, run_name)
    props = {"seed": r.seed, "trials": int(ev["trials"].iloc[0]), "system": sc.name, "run": run_name, "q": float(spec.q),
             "T": sc.T, "timing": spec.timing, "switching": spec.switching, "rule": spec.rule,
             "versions": json.dumps(prov.get("versions", {})), "git": prov.get("git", "")}
    with rec_.recording(path, application_id="dse-wang-liu-morse", recording_id=f"wlm-{sc.name}-{run_name}-seed{r.seed}",
                        blueprint=blueprint, properties=props) as rec:
        st = tables.rows("state_series", scenario, run_name)
        truth = st[st["source"] == "truth"]
        ts, x = _pivot(truth, "value", by="component")
        idx = rec_.duration_index("t", _ns(ts))
        rec_.send_series(rec, "truth/x", idx, x, names=[f"x^({c + 1})" for c in range(n)], colors=[(0, 0, 0)] * n,
                         width=2.0)
        series = tables.rows("node_series", scenario, run_name)
        tn, err = _pivot(series, "error_trial0")
        _, emean = _pivot(series, "error_mean")
        _, emax = _pivot(series, "error_max")
        nidx = rec_.duration_index("t", _ns(tn))
        nodes = tables.rows("nodes", scenario, run_name)
        its = tables.rows("iterates", scenario, run_name)
        estimates = dict(iter(st[st["source"] == "agent"].groupby("node", sort=False)))
        nodes_of, its_of = dict(iter(nodes.groupby("node", sort=False))), dict(iter(its.groupby("node", sort=False)))
        # series sharing their times are columns of one entity (a fixed cost per entity dominates short series)
        rec_.send_series(rec, "nodes/error", nidx, err, names=[f"||e_{i + 1}(t)||" for i in range(m)],
                         colors=[_col(i) for i in range(m)])
        for i in range(m):
            lab = f"agent {i + 1}"
            te, xe = _pivot(estimates[i + 1], "value", by="component")
            rec_.send_series(rec, f"nodes/{i + 1}/estimate", rec_.duration_index("t", _ns(te)), xe,
                             names=[f"{lab} x_{i + 1}^({c + 1})" for c in range(n)], colors=[_col(i)] * n)
            rec_.send_series(rec, f"nodes/{i + 1}/log10_error", nidx, log10_safe(err[:, i]),
                             names=f"log10 ||e_{i + 1}(t)||", colors=[_col(i)])
            nd = nodes_of[i + 1]
            rec_.send_series(rec, f"nodes/{i + 1}/reset", rec_.duration_index("t", _ns(nd["t"])),
                             np.column_stack([log10_safe(nd["error_before_reset"]), log10_safe(nd["error_trial0"])]),
                             names=[f"log10 ||e_{i + 1}(t_is⁻)|| (before reset)",
                                    f"log10 ||e_{i + 1}(t_is)|| (after reset)"],
                             colors=[(120, 120, 120), _col(i)], points=True)
            it = its_of.get(i + 1, its.iloc[:0]).sort_values("t", kind="stable")
            if len(it):
                rec_.send_series(rec, f"nodes/{i + 1}/iterates", rec_.duration_index("t", _ns(it["t"])),
                                 log10_safe(it["error"]), names=f"agent {i + 1} log10 ||π_is(k)||", colors=[_col(i)],
                                 points=True)
        resets = nodes.sort_values(["t", "node"], kind="stable")
        rec.send_columns("events/reset", indexes=rec_.duration_index("t", _ns(resets["t"])),
                         columns=rr.TextLog.columns(text=[f"agent {int(i)}: event s = {int(s)}"
                                                          for i, s in zip(resets["node"], resets["s"])]))
        net = tables.rows("network_series", scenario, run_name)
        gidx = rec_.duration_index("t", _ns(net["t"]))
        rec_.send_series(rec, "central/error", gidx, net["central_trial0"].to_numpy(),
                         names="centralized observer ||x_c - x||", colors=[(0, 0, 0)])
        kalman = np.isfinite(net["kalman_trial0"]).any()
        rec_.send_series(rec, "central/log10", gidx,
                         np.column_stack([log10_safe(net["central_trial0"])]
                                         + ([log10_safe(net["kalman_trial0"])] if kalman else [])),
                         names=["log10 centralized observer error"]
                         + (["log10 centralized Kalman filter error (filterpy)"] if kalman else []),
                         colors=[(90, 90, 90), (0, 0, 0)][:1 + kalman])
        trials = int(ev["trials"].iloc[0])
        if trials > 1:
            rec_.send_series(rec, "mc/log10/max_error", nidx,
                             np.column_stack([log10_safe(emean.max(axis=1)), log10_safe(emax.max(axis=1))]),
                             names=[f"max_i of the mean over {trials} trials of ||e_i||", "largest over trials and agents"],
                             colors=[(100, 100, 200), (200, 100, 100)])
        if bounds.is_theorem_run(spec):
            b = ev[ev["s"] >= 1]
            rec_.send_series(rec, "bounds/log10/eq51", rec_.duration_index("t", _ns(b["t"])),
                             log10_safe(b["bound51_trial0"]), names="bound (51), trial 0", colors=[(0, 0, 0)],
                             points=True)
            if np.isfinite(net["bound_printed_trial0"]).any():
                rec_.send_series(rec, "bounds/log10/continuous", gidx,
                                 np.column_stack([log10_safe(net["bound_printed_trial0"]),
                                                  log10_safe(net["bound_corrected_trial0"])]),
                                 names=["printed continuous bound", "corrected continuous bound (× e^(λT))"],
                                 colors=[(214, 39, 40), (0, 0, 0)], width=1.0)
        iv = tables.rows("intervals", scenario, run_name)
        key = "A_2" if spec.rule == "symmetric" else "A_mixed"
        vals = iv[key].to_numpy()
        ok = ~np.isnan(vals)
        t_end = nodes_of[1].set_index("s")["t"]
        if ok.any():
            times = t_end.reindex(iv["s"].to_numpy()[ok]).to_numpy()
            rec_.send_series(rec, "bounds/A_norm", rec_.duration_index("t", _ns(times)),
                             np.column_stack([log10_safe(vals[ok]), np.full(ok.sum(), -sc.lam * sc.T / math.log(10))]),
                             names=[f"log10 {'||A(s)||₂' if key == 'A_2' else '|A(s)|'}", "log10 e^(-λT)"],
                             colors=[(31, 119, 180), (0, 0, 0)], points=False)
        # the switching graph: nodes fixed, edges per iteration of the first stored intervals, where they change
        ang = np.pi / 2 - 2 * np.pi * np.arange(m) / m
        rec.log("graph", rr.GraphNodes([str(i + 1) for i in range(m)], positions=np.column_stack([np.cos(ang), np.sin(ang)]) * 100,
                                       labels=[f"agent {i + 1}" for i in range(m)], colors=[_col(i) for i in range(m)],
                                       radii=12.0, show_labels=True), static=True)
        src = tables.rows("source_sets", scenario, run_name)
        src = src[src["used"]]
        times, edges = [], []
        if len(src):
            s_, k_ = src["s"].to_numpy(), src["k"].to_numpy()
            i_, j_ = src["receiver"].to_numpy() - 1, src["sender"].to_numpy() - 1
            slot = (s_ - 1) * spec.q + (k_ - 1)                           # iteration k of interval s, in time order
            masks = np.zeros((int(slot.max()) + 1, m, m), dtype=bool)
            masks[slot, i_, j_] = True
            change = np.r_[True, (masks[1:] != masks[:-1]).any(axis=(1, 2))]
            start = t_end.to_dict()
            labels = np.array([str(i + 1) for i in range(m)])
            for g in np.nonzero(change)[0]:
                s, k = divmod(int(g), spec.q)
                times.append(int(round((start[s] + k * spec.Delta) * 1e9)))
                ii, jj = np.nonzero(masks[g])
                edges.append(np.column_stack([labels[jj], labels[ii]]))        # (sender, receiver) pairs
        if times:
            sizes = [len(es) for es in edges]
            rec.send_columns("graph", indexes=rec_.duration_index("t", np.array(times)),
                             columns=rr.GraphEdges.columns(edges=np.concatenate(edges),
                                                           graph_type=[rr.GraphType.Directed] * sum(sizes)
                                                           ).partition(sizes))
        rec_.log_claims(rec, claims, summary, width=30)


#: the tables figures and recordings select per run, split before the workers fork (each would split its own)
SPLIT = ("state_series", "node_series", "network_series", "nodes", "events", "intervals", "iterates", "source_sets")


def write_outputs(res, tables, out_dir: Path, claims: list[dict], prov: dict, *, paper: bool) -> None:
    """The figures and one recording per (system, run), drawn together in forked workers."""
    view = TableView(tables)
    for name in SPLIT:
        view.rows(name, "", "")
    counts = {s: sum(c["verdict"] == s for c in claims) for s in ("pass", "fail", "erratum", "not-checkable", "error")}
    summary = (f"# hybrid observer: {counts['pass']} pass, {counts['fail']} fail, {counts['erratum']} erratum, "
               f"{counts['not-checkable']} not checkable, {counts['error']} error")
    recordings = [lambda name=name, s=s: write_run_recording(
        res, view, name, s.name, out_dir / (f"{name}_{s.name}.rrd" if paper else f"{s.name}.rrd"), claims, prov, summary)
        for name, r in res.parts.items() for s in r.scenario.runs]
    draw_all(figure_jobs(res, view, out_dir, paper) + recordings, workers=int(prov.get("workers", 1) or 1))
