"""The figures (PNG) of a hybrid-observer run, drawn from its tables: the paper's Figs. 1-5 (in
its reproduction) or the graphs and one trace per run (a user's), Theorem 1's bounds, the decay
rate fits and |A(s)| per interval. Errors are drawn as max(error, 1e-300): an exact zero never
breaks a log scale."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pandas as pd

from dse.contract.views import View
from dse.outputs.figures import new_figure, plain_log_labels, save_figure, set_margins

from .simulation import is_theorem_run
from .claims.common import fit_rate, in_theorem1

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
    shown = r.scenario.name                 # the scenario's own name (a user's run labels its part 'scenario')
    ideal = next((s for s in r.scenario.runs if s.ideal and is_theorem_run(s)), None)
    fig, axes = new_figure(ncols=2 if ideal is not None else 1, width=5.6)   # no empty panel without an ideal run
    sync = next((s for s in r.scenario.runs if s.timing == "sync" and in_theorem1(r, s) and not s.ideal), None)
    if sync is None:
        sync = next((s for s in r.scenario.runs if s.timing == "sync" and is_theorem_run(s)), None)
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
        ax.set_title(f"{shown}/{sync.name}: event-sampled error vs (51), q = {sync.q}", fontsize=9)
        ax.legend()
    ax.set_xlabel("t = sT")
    if ideal is not None:
        ax = axes[0, 1]
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
        ax.set_title(f"{shown}/{ideal.name} (ē(0) = 0): continuous-time bound ratio, trial 0", fontsize=9)
        ax.set_xlabel("t")
        ax.legend(fontsize=7)
    _save(fig, path)


def _decay_figure(res, tables, path: Path) -> None:
    fig, axes = new_figure()
    ax = axes[0, 0]
    for idx, (name, r) in enumerate(res.parts.items()):
        sync = next((s for s in r.scenario.runs if s.timing == "sync" and not s.ideal and is_theorem_run(s)), None)
        if sync is None:
            continue
        ev = tables.rows("events", name, sync.name)
        t, e, fl = ev["t"].to_numpy(), ev["error_trial0"].to_numpy(), ev["floor_trial0"].to_numpy()
        rate, first, stop = fit_rate(t, e, fl)
        c = _mpl(idx)
        ax.semilogy(t, np.maximum(e, TINY), "o", ms=3, color=c,
                    label=f"{r.scenario.name}/{sync.name}: max_i||e_i(t_is)||")
        ax.semilogy(t, fl, ":", color=c, lw=1, label=f"{r.scenario.name}: round-off allowance")
        if not math.isnan(rate):
            tt = t[first:stop]
            c0 = np.exp(np.polyfit(tt, np.log(e[first:stop]), 1)[1])
            ax.semilogy(tt, c0 * np.exp(-rate * tt), "-", color=c, lw=1.5, label=f"{r.scenario.name}: fit, rate {rate:.3f} "
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


def figure_views(res, tables, paper: bool) -> list[View]:
    """The paper's Figs. 1-5 and Theorem 1's bounds per system, or a user's graphs, bounds and one
    trace per run; then the decay-rate fits and |A(s)| per interval."""
    if paper:
        m = res["paper"].scenario.m
        lv = res["paper"].spec("fig5_leave_join").leave
        views = [View("fig1_timing.png", _fig1),
                 View("fig2_graphs.png", lambda path: _graph_figure(tables, "paper", path)),
                 View("fig3.png", lambda path: _trace_figure(tables, "paper", "fig3_noise", m, "Fig. 3: x' = Ax + "
                                                             "b cos(10t); graphs 2a/2b alternate", path)),
                 View("fig4.png", lambda path: _trace_figure(tables, "paper", "fig4_offset", m, "Fig. 4: agent 4's "
                                                             "events 0.2T early (index-aligned exchange)", path,
                                                             agents=(0, 3))),
                 View("fig5.png", lambda path: _trace_figure(tables, "paper", "fig5_leave_join", m, "Fig. 5: agent 4 "
                                                             "leaves at t = 5, re-joins at t = 7 (graph 2a)", path,
                                                             agents=(0, 3), shade=(lv.at, lv.rejoin)))]
        views += [View(f"theorem1_bounds_{name}.png", lambda path, name=name: _bounds_figure(res, tables, name, path))
                  for name in res.parts]
    else:
        views = []
        for name, r in res.parts.items():
            views += [View("graphs.png", lambda path, name=name: _graph_figure(tables, name, path)),
                      View("theorem1_bounds.png", lambda path, name=name: _bounds_figure(res, tables, name, path))]
            views += [View(f"run_{s.name}.png", lambda path, name=name, s=s, r=r: _trace_figure(
                tables, name, s.name, r.scenario.m, f"run {s.name}", path, component=min(2, r.scenario.n - 1),
                shade=(s.leave.at, s.leave.rejoin) if s.leave else None)) for s in r.scenario.runs]
    views += [View("decay_rates.png", lambda path: _decay_figure(res, tables, path)),
              View("A_norms.png", lambda path: _anorm_figure(res, tables, path))]
    return [View(f"figures/{v.file}", v.draw) for v in views]
