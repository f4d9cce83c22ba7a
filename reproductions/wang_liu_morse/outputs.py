"""Figures (PNG), design quantities (JSON) and Rerun recordings of the hybrid-observer family.

One recording per (system, run): ``<part>_<run>.rrd`` on the continuous timeline ``t``
(integer nanoseconds): the true state and each agent's estimate (trial 0), the error of each
agent on the sample grid (right-continuous) and before/after every reset at the event
times, the parameter-estimator iterates within each event interval at their iteration
times, Monte Carlo aggregates over trials, the bound curves, the switching graph and the
claims. Errors are also recorded as log10(max(error, 1e-300)): an exact zero never breaks
a log scale.
"""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from pipeline import record as rec_
from pipeline.atomic import atomic_write_text
from pipeline.figures import new_figure, save_figure

from . import claims as cl
from .compute import MultiResults, Results

TINY = 1e-300
AGENT_COLORS = [(31, 119, 180), (255, 127, 14), (44, 160, 44), (214, 39, 40), (148, 103, 189), (140, 86, 75),
                (227, 119, 194), (127, 127, 127)]


def _col(i: int) -> tuple[int, int, int]:
    return AGENT_COLORS[i % len(AGENT_COLORS)]


def _mpl(i: int):
    return tuple(c / 255 for c in _col(i))


def log10_safe(v: np.ndarray) -> np.ndarray:
    return np.log10(np.maximum(np.asarray(v, float), TINY))


# -- figures --------------------------------------------------------------------------------------

def _trace_figure(r: Results, run_name: str, title: str, path: Path, agents=(0,), component: int = 2,
                  shade: tuple[float, float] | None = None) -> None:
    run = r.run(run_name)
    t = run.t_ns / 1e9
    fig, axes = new_figure(ncols=2, width=5.6)
    ax = axes[0, 0]
    ax.plot(t, run.x0[:, component], "k-", lw=2, label=f"x^({component + 1})")
    for i in agents:
        ax.plot(t, run.xhat0[:, i, component], "--", color=_mpl(i), lw=1.3, label=f"x_{i + 1}^({component + 1})")
    ax.set_xlabel("t")
    ax.set_title(title, fontsize=9)
    ax.legend()
    ax = axes[0, 1]
    for i in range(r.scenario.m):
        ax.semilogy(t, np.maximum(run.err[:, 0, i], TINY), color=_mpl(i), lw=1, label=f"||e_{i + 1}(t)||")
    if run_name in r.runs and "kf_err" in r.runs[run_name]:
        ax.semilogy(t, np.maximum(r.runs[run_name]["kf_err"], TINY), "k:", lw=1, label="centralized KF (filterpy)")
    else:
        ax.semilogy(t, np.maximum(run.central_err[:, 0], TINY), "k:", lw=1, label="centralized observer")
    if shade:
        for a in axes[0]:
            a.axvspan(*shade, color="0.85", zorder=0)
    ax.set_xlabel("t")
    ax.set_title("estimation errors (log scale)", fontsize=9)
    ax.legend(ncol=2)
    save_figure(fig, path)


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
    save_figure(fig, path)


def _graph_figure(r: Results, path: Path) -> None:
    G = r.scenario.graphs
    m = r.scenario.m
    fig, axes = new_figure(ncols=len(G), width=3.4, height=3.4)
    ang = np.pi / 2 - 2 * np.pi * np.arange(m) / m
    pos = np.column_stack([np.cos(ang), np.sin(ang)])
    for g, ax in enumerate(axes[0]):
        for i in range(m):
            for j in range(m):
                if i != j and G[g][i, j]:            # arc j -> i
                    ax.annotate("", xy=pos[i] * 0.85 + pos[j] * 0.15, xytext=pos[j] * 0.85 + pos[i] * 0.15,
                                arrowprops=dict(arrowstyle="->", color="0.3", lw=1.2))
        for i in range(m):
            ax.scatter(*pos[i], s=500, color=_mpl(i), zorder=3)
            ax.text(*pos[i], str(i + 1), ha="center", va="center", color="w", zorder=4)
        ax.set_title(r.scenario.graph_names[g], fontsize=9)
        ax.set_xlim(-1.4, 1.4)
        ax.set_ylim(-1.4, 1.4)
        ax.set_aspect("equal")
        ax.axis("off")
    save_figure(fig, path)


def _bounds_figure(r: Results, path: Path) -> None:
    """Theorem 1 on a run inside its hypotheses: |e(s)| over trials vs (51); the continuous bound
    as printed and corrected on the idealised run."""
    fig, axes = new_figure(ncols=2, width=5.6)
    sync = next((s for s in r.scenario.runs if s.timing == "sync" and cl.in_theorem1(r, s) and not s.ideal), None)
    if sync is None:
        sync = next(s for s in r.scenario.runs if s.timing == "sync")
    lhs, rhs = cl.event_bound(r, sync.name)
    ts = np.arange(1, lhs.shape[0] + 1) * r.scenario.T
    ax = axes[0, 0]
    ax.semilogy(ts, np.maximum(lhs.max(axis=1), TINY), "o-", ms=3, label=f"max over {lhs.shape[1]} trials |e(s)|")
    ax.semilogy(ts, np.maximum(np.median(lhs, axis=1), TINY), ".-", ms=3, label="median |e(s)|")
    ax.semilogy(ts, rhs.max(axis=1), "k--", label="bound (51), largest over trials")
    ax.semilogy(ts, np.exp(-r.scenario.lam * ts) * lhs[0].max(), "k:", lw=1, label=f"e^(-λt), λ = {r.scenario.lam}")
    ax.set_xlabel("t = sT")
    ax.set_title(f"{r.scenario.name}/{sync.name}: event-sampled error vs (51), q = {sync.q}", fontsize=9)
    ax.legend()
    ideal = next((s for s in r.scenario.runs if s.ideal), None)
    ax = axes[0, 1]
    if ideal is not None:
        run = r.run(ideal.name)
        k = cl.constants(r, ideal)
        e, eb, _, _ = cl.event_norms(r, ideal.name)
        t = run.t_ns / 1e9
        lam, T, nA = r.scenario.lam, r.scenario.T, k["norm_A"]
        K0s = e[0] + k["d"] * eb[0]
        ratio = run.err.max(axis=-1) / (np.exp(nA * T - lam * t)[:, None] * K0s[None])
        b = int(np.argmax(ratio.max(axis=0)))                       # the trial closest to breaking the printed bound
        K0 = K0s[b]
        sel = t <= 3 * T
        printed = np.exp(nA * T - lam * t) * K0
        err = run.err[:, b].max(axis=-1)
        ax.plot(t[sel], err[sel] / printed[sel], color="tab:red", label="||e(t)|| / printed bound e^(||A||T-λt)(...)")
        ax.plot(t[sel], err[sel] / (printed[sel] * np.exp(lam * T)), color="k",
                label="||e(t)|| / corrected bound (× e^(λT))")
        pre = np.linalg.norm(run.e_pre[1:, b], axis=-1).max(axis=-1)
        ts = np.arange(1, len(pre) + 1) * T
        keep = ts <= 3 * T
        pb = np.exp(nA * T - lam * ts) * K0
        ax.plot(ts[keep], pre[keep] / pb[keep], "v", color="tab:red", ms=6, label="left limits e(sT⁻) / printed")
        ax.axhline(1.0, color="0.4", ls="--", lw=1)
        ax.set_title(f"{r.scenario.name}/{ideal.name} (ē(0) = 0): continuous-time bound ratio, trial {b}", fontsize=9)
        ax.set_xlabel("t")
        ax.legend(fontsize=7)
    save_figure(fig, path)


def _decay_figure(res: MultiResults, path: Path) -> None:
    fig, axes = new_figure()
    ax = axes[0, 0]
    for idx, (name, r) in enumerate(res.parts.items()):
        sync = next((s for s in r.scenario.runs if s.timing == "sync" and not s.ideal and not s.noise
                     and s.leave is None), None)
        if sync is None:
            continue
        e, _, _, _ = cl.event_norms(r, sync.name)
        fl = cl.roundoff_floor(r, sync.name)
        t = r.run(sync.name).event_ns[0] / 1e9
        rate, first, stop = cl.fit_rate(t, e[:, 0], fl[:, 0])
        c = _mpl(idx)
        ax.semilogy(t, np.maximum(e[:, 0], TINY), "o", ms=3, color=c, label=f"{name}/{sync.name}: max_i||e_i(t_is)||")
        ax.semilogy(t, fl[:, 0], ":", color=c, lw=1, label=f"{name}: round-off allowance")
        if not math.isnan(rate):
            tt = t[first:stop]
            c0 = np.exp(np.polyfit(tt, np.log(e[first:stop, 0]), 1)[1])
            ax.semilogy(tt, c0 * np.exp(-rate * tt), "-", color=c, lw=1.5, label=f"{name}: fit, rate {rate:.3f} "
                                                                               f"(λ = {r.scenario.lam})")
    ax.set_xlabel("t")
    ax.set_title("decay rate fits stop where round-off starts", fontsize=9)
    ax.legend(fontsize=7)
    save_figure(fig, path)


def _anorm_figure(res: MultiResults, path: Path) -> None:
    import matplotlib.pyplot as plt

    parts = list(res.parts.items())
    fig, axes = new_figure(ncols=len(parts), width=5.4)
    cmap = plt.get_cmap("tab20")
    for ax, (name, r) in zip(axes[0], parts):
        k = 0
        for s in r.scenario.runs:
            a = r.runs[s.name]
            key = "A_2" if s.rule == "symmetric" else "A_mixed"
            v = a[key]
            if np.all(np.isnan(v)) or s.noise:
                continue
            ax.semilogy(np.arange(1, len(v) + 1), np.maximum(v, TINY), marker=".", ms=3, lw=1, color=cmap(k % 20),
                        ls="-" if k < 10 else "--", label=f"{s.name} ({'||·||₂' if key == 'A_2' else '|·|'}, q = {s.q})")
            k += 1
        ax.axhline(math.exp(-r.scenario.lam * r.scenario.T), ls="--", lw=1.2, color="k", label="e^(-λT)")
        ax.set_xlabel("event interval s")
        ax.set_title(f"{name}: |A(s)| per interval, Lemma 4 (44) and (54)", fontsize=9)
        ax.legend(fontsize=6, ncol=2)
    save_figure(fig, path)


def write_figures(res: MultiResults, out_dir: Path, paper: bool) -> None:
    figs = out_dir / "figures"
    if paper:
        r = res["paper"]
        _fig1(figs / "fig1_timing.png")
        _graph_figure(r, figs / "fig2_graphs.png")
        _trace_figure(r, "fig3_noise", "Fig. 3: x' = Ax + b cos(10t); graphs 2a/2b alternate", figs / "fig3.png")
        _trace_figure(r, "fig4_offset", "Fig. 4: agent 4's events 0.2T early (index-aligned exchange)",
                      figs / "fig4.png", agents=(0, 3))
        lv = r.spec("fig5_leave_join").leave
        _trace_figure(r, "fig5_leave_join", "Fig. 5: agent 4 leaves at t = 5, re-joins at t = 7 (graph 2a)",
                      figs / "fig5.png", agents=(0, 3), shade=(lv.at, lv.rejoin))
        for name, rr_ in res.parts.items():
            _bounds_figure(rr_, figs / f"theorem1_bounds_{name}.png")
    else:
        for name, rr_ in res.parts.items():
            _graph_figure(rr_, figs / "graphs.png")
            _bounds_figure(rr_, figs / "theorem1_bounds.png")
            for s in rr_.scenario.runs:
                shade = (s.leave.at, s.leave.rejoin) if s.leave else None
                _trace_figure(rr_, s.name, f"run {s.name}", figs / f"run_{s.name}.png", shade=shade,
                              component=min(2, rr_.scenario.n - 1))
    _decay_figure(res, figs / "decay_rates.png")
    _anorm_figure(res, figs / "A_norms.png")


# -- design quantities ------------------------------------------------------------------------------

def design_summary(r: Results) -> dict:
    dz = r.design
    out = {}
    for k, v in dz.items():
        v = np.asarray(v)
        if v.dtype.kind == "U":
            out[k] = int(str(v)) if str(v).isdigit() else str(v)
        elif v.size == 1:
            out[k] = v.item()
        elif v.size <= 64:
            out[k] = v.tolist()
    out["m"], out["n"], out["T"], out["lambda"], out["lambda_bar"] = (r.scenario.m, r.scenario.n, r.scenario.T,
                                                                      r.scenario.lam, r.scenario.lam_bar)
    out["q_runs"] = {s.name: s.q for s in r.scenario.runs}
    out["K"] = [k.tolist() for k in r.obs.K]
    out["L"] = [L.tolist() for L in r.obs.L]
    return out


# -- recordings -------------------------------------------------------------------------------------

def _edges(N: np.ndarray) -> list[tuple[str, str]]:
    m = len(N)
    return [(str(j + 1), str(i + 1)) for i in range(m) for j in range(m) if i != j and N[i, j]]


def write_run_recording(r: Results, run_name: str, path: Path, claims: list[dict], prov: dict, summary: str) -> None:
    sc = r.scenario
    spec = r.spec(run_name)
    run = r.run(run_name)
    a = r.runs[run_name]
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
    props = {"seed": r.seed, "trials": int(run.err.shape[1]), "system": sc.name, "run": run_name, "q": float(spec.q),
             "T": sc.T, "timing": spec.timing, "switching": spec.switching, "rule": spec.rule,
             "versions": json.dumps(prov.get("versions", {})), "git": prov.get("git", "")}
    with rec_.recording(path, application_id="dse-wang-liu-morse", recording_id=f"wlm-{sc.name}-{run_name}-seed{r.seed}",
                        blueprint=blueprint, properties=props) as rec:
        idx = rec_.duration_index("t", run.t_ns)
        names = [f"x^({c + 1})" for c in range(n)]
        rec_.send_series(rec, "truth/x", idx, run.x0, names=names, colors=[(0, 0, 0)] * n, width=2.0)
        for i in range(m):
            lab = f"agent {i + 1}"
            rec_.send_series(rec, f"nodes/{i + 1}/estimate", idx, run.xhat0[:, i],
                             names=[f"{lab} x_{i + 1}^({c + 1})" for c in range(n)], colors=[_col(i)] * n)
            rec_.send_series(rec, f"nodes/{i + 1}/error", idx, run.err[:, 0, i], names=f"||e_{i + 1}(t)||", colors=[_col(i)])
            rec_.send_series(rec, f"nodes/{i + 1}/log10_error", idx, log10_safe(run.err[:, 0, i]),
                             names=f"log10 ||e_{i + 1}(t)||", colors=[_col(i)])
            ev = rec_.duration_index("t", run.event_ns[i])
            rec_.send_series(rec, f"nodes/{i + 1}/reset/before", ev, log10_safe(np.linalg.norm(run.e_pre[:, 0, i], axis=-1)),
                             names=f"log10 ||e_{i + 1}(t_is⁻)|| (before reset)", colors=[(120, 120, 120)], points=True)
            rec_.send_series(rec, f"nodes/{i + 1}/reset/after", ev, log10_safe(np.linalg.norm(run.e_post[:, 0, i], axis=-1)),
                             names=f"log10 ||e_{i + 1}(t_is)|| (after reset)", colors=[_col(i)], points=True)
            # iterates at their iteration times τ_is(k) = t_i(s-1) + kΔ + δ_is(k)
            S, q1 = run.z0.shape[0], run.z0.shape[1]
            delta = a["jitter"][:, i, :] if "jitter" in a else np.zeros((S, q1))
            tau = run.event_ns[i, :S, None] + np.round((np.arange(q1)[None, :] * spec.Delta + delta) * 1e9).astype(np.int64)
            pi = np.linalg.norm(run.z0[:, :, i] - run.x_event[:S, 0, i][:, None, :], axis=-1)
            order = np.argsort(tau.ravel(), kind="stable")
            rec_.send_series(rec, f"nodes/{i + 1}/iterates", rec_.duration_index("t", tau.ravel()[order]),
                             log10_safe(pi.ravel()[order]), names=f"agent {i + 1} log10 ||π_is(k)||", colors=[_col(i)],
                             points=True)
        rec_.send_series(rec, "central/error", idx, run.central_err[:, 0], names="centralized observer ||x_c - x||",
                         colors=[(0, 0, 0)])
        rec_.send_series(rec, "central/log10/error", idx, log10_safe(run.central_err[:, 0]),
                         names="log10 centralized observer error", colors=[(90, 90, 90)])
        if "kf_err" in a:
            rec_.send_series(rec, "central/log10/kalman", idx, log10_safe(a["kf_err"]),
                             names="log10 centralized Kalman filter error (filterpy)", colors=[(0, 0, 0)])
        if run.err.shape[1] > 1:
            mx = run.err.max(axis=-1)
            rec_.send_series(rec, "mc/log10/max_error", idx,
                             np.column_stack([log10_safe(np.median(mx, axis=1)), log10_safe(mx.max(axis=1))]),
                             names=[f"median over {mx.shape[1]} trials of max_i ||e_i||", "largest over trials"],
                             colors=[(100, 100, 200), (200, 100, 100)])
        # bounds
        ev0 = rec_.duration_index("t", run.event_ns[0, 1:])
        if spec.rule == "mean" and not spec.noise and spec.leave is None:
            lhs, rhs = cl.event_bound(r, run_name)
            rec_.send_series(rec, "bounds/log10/eq51", ev0, log10_safe(rhs[:, 0]), names="bound (51), trial 0",
                             colors=[(0, 0, 0)], points=True)
            k = cl.constants(r, spec)
            e, eb, _, _ = cl.event_norms(r, run_name)
            K0 = e[0, 0] + k["d"] * eb[0, 0]
            t = run.t_ns / 1e9
            rec_.send_series(rec, "bounds/log10/continuous", idx,
                             np.column_stack([log10_safe(np.exp(k["norm_A"] * sc.T - sc.lam * t) * K0),
                                              log10_safe(np.exp((k["norm_A"] + sc.lam) * sc.T - sc.lam * t) * K0)]),
                             names=["printed continuous bound", "corrected continuous bound (× e^(λT))"],
                             colors=[(214, 39, 40), (0, 0, 0)], width=1.0)
        key = "A_2" if spec.rule == "symmetric" else "A_mixed"
        vals = a[key]
        ok = ~np.isnan(vals)
        if ok.any():
            rec_.send_series(rec, "bounds/A_norm", rec_.duration_index("t", run.event_ns[0, 1:][ok]),
                             np.column_stack([log10_safe(vals[ok]), np.full(ok.sum(), -sc.lam * sc.T / math.log(10))]),
                             names=[f"log10 {'||A(s)||₂' if key == 'A_2' else '|A(s)|'}", "log10 e^(-λT)"],
                             colors=[(31, 119, 180), (0, 0, 0)], points=False)
        # the switching graph: nodes fixed, edges per iteration sample (Lemma 2's nominal graph)
        ang = np.pi / 2 - 2 * np.pi * np.arange(m) / m
        rec.log("graph", rr.GraphNodes([str(i + 1) for i in range(m)], positions=np.column_stack([np.cos(ang), np.sin(ang)]) * 100,
                                       labels=[f"agent {i + 1}" for i in range(m)], colors=[_col(i) for i in range(m)],
                                       radii=12.0, show_labels=True), static=True)
        S = run.sources.shape[0]
        times, edges = [], []
        last = None
        for s in range(S):
            for kk in range(run.sources.shape[1]):
                e_ = _edges(run.sources[s, kk])
                if e_ != last:
                    times.append(int(run.event_ns[0, s] + round(kk * spec.Delta * 1e9)))
                    edges.append(e_)
                    last = e_
        rec.send_columns("graph", indexes=rec_.duration_index("t", np.array(times)),
                         columns=rr.GraphEdges.columns(edges=[e for es in edges for e in es],
                                                       graph_type=[rr.GraphType.Directed] * sum(len(es) for es in edges)
                                                       ).partition([len(es) for es in edges]))
        for i in range(m):
            ev = rec_.duration_index("t", run.event_ns[i])
            rec.send_columns(f"events/reset/{i + 1}", indexes=ev,
                             columns=rr.TextLog.columns(text=[f"agent {i + 1}: event s = {s}" for s in range(len(run.event_ns[i]))]))
        rec_.log_claims(rec, claims, summary, width=30)


def write_outputs(res: MultiResults, out_dir: Path, claims: list[dict], prov: dict, *, paper: bool) -> None:
    write_figures(res, out_dir, paper)
    atomic_write_text(out_dir / "design.json", json.dumps({k: design_summary(r) for k, r in res.parts.items()},
                                                          indent=1, default=str))
    counts = {s: sum(c["verdict"] == s for c in claims) for s in ("pass", "fail", "erratum", "not-checkable", "error")}
    summary = (f"# hybrid observer: {counts['pass']} pass, {counts['fail']} fail, {counts['erratum']} erratum, "
               f"{counts['not-checkable']} not checkable, {counts['error']} error")
    for name, r in res.parts.items():
        for s in r.scenario.runs:
            fname = f"{name}_{s.name}.rrd" if paper else f"{s.name}.rrd"
            write_run_recording(r, s.name, out_dir / fname, claims, prov, summary)
