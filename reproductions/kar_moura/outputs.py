"""Figures (PNG) and Rerun recordings of the gossip-Kalman family.

One recording per scenario, ``<scenario>.rrd``, on the sequence timeline ``k`` (the slot):
the graph with the active matching of a sample run at each slot, per-sensor tr P̂ and
estimation error of the sample runs, quantiles over runs of log₁₀ tr P̂ per sensor (quantiles,
not means: μ can have an infinite mean), the Theorem-8 quantiles at the record times, the
centralized reference, the Lyapunov envelope and the claims.
"""
from __future__ import annotations

import functools
import json
from pathlib import Path

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

import estimators.gossip_kalman as gk
from pipeline import record as rec_
from pipeline.figures import new_figure, save_figure, sequential_colors
from pipeline.simulate import parallel_map

from .compute import J_GRID, Results, ScenarioResults

FI = {name: i for i, name in enumerate(gk.FEATURES)}
LOG10 = np.log(10.0)


def _log10_trace(arr: np.ndarray) -> np.ndarray:
    return arr[FI["log_trace"]] / LOG10


def _ecdf(ax, x, **kw):
    x = np.sort(x[np.isfinite(x)])
    ax.step(x, np.arange(1, len(x) + 1) / len(x), where="post", **kw)


# -- figures -------------------------------------------------------------------------------------------

def fig_random_sensor(r: ScenarioResults, path: Path) -> None:
    """Left: ECDFs of log tr P̂ at a random sensor (solid) and of the Theorem-8 process at the same t
    (dashed). Right: KS distance of the random sensor at t to μ_T (the limit sample) and to μ_t, with
    the 95% noise floor."""
    from scipy import stats

    g, ref = r.gikf, r.reference
    times = [int(t) for t in g["times"] if t >= 1]
    show = times if len(times) <= 6 else [times[i] for i in np.linspace(0, len(times) - 1, 6).astype(int)]
    cols = sequential_colors(len(show))
    fig, axes = new_figure(ncols=2, width=5.4)
    ax = axes[0, 0]
    for t, col in zip(show, cols):
        i = list(g["times"]).index(t)
        _ecdf(ax, _log10_trace(g["feat_q"][i]), color=col, lw=1.6, label=f"t = {t}")
        _ecdf(ax, _log10_trace(ref["features"][i]), color=col, lw=1.0, ls="--")
    ax.set_xlabel("log₁₀ tr P̂")
    ax.set_ylabel("empirical CDF")
    ax.set_title(f"{r.name}: random sensor q ({r.runs} runs, solid)\nvs Theorem-8 process μ_t ({r.reference_runs} runs, dashed)",
                 fontsize=9)
    ax.legend(ncol=1)
    ax = axes[0, 1]
    mu_T = _log10_trace(ref["features"][-1])
    d_T, d_t = [], []
    for t in times:
        i = list(g["times"]).index(t)
        x = _log10_trace(g["feat_q"][i])
        d_T.append(stats.ks_2samp(x, mu_T, method="asymp").statistic)
        d_t.append(stats.ks_2samp(x, _log10_trace(ref["features"][i]), method="asymp").statistic)
    n, m = r.runs, ref["features"].shape[-1]
    ax.semilogx(times, d_T, "o-", label="KS(random sensor at t, μ_T)")
    ax.semilogx(times, d_t, "s--", label="KS(random sensor at t, μ_t): exact identity")
    ax.axhline(1.36 * np.sqrt((n + m) / (n * m)), color="k", ls=":", label="95% noise floor")
    ax.set_xlabel("slot t")
    ax.set_ylabel("KS distance")
    ax.set_title("convergence to μ and the finite-t identity", fontsize=9)
    ax.legend()
    save_figure(fig, path)


def fig_per_sensor(r: ScenarioResults, path: Path) -> None:
    g, ref = r.gikf, r.reference
    i = len(g["times"]) - 1
    T = int(g["times"][-1])
    N = r.scenario.N
    fig, axes = new_figure()
    ax = axes[0, 0]
    cols = sequential_colors(min(N, 12), "tab10")
    for n in range(min(N, 12)):
        _ecdf(ax, _log10_trace(g["feat_n"][i])[:, n], color=cols[n], lw=1.0, label=f"sensor {n} (type {r.scenario.types[n]})")
    _ecdf(ax, _log10_trace(ref["features"][-1]), color="k", lw=2.2, label="μ_T (Theorem-8 process)")
    ax.set_xlabel("log₁₀ tr P̂_n(T)")
    ax.set_ylabel("empirical CDF")
    ax.set_title(f"{r.name}: per-sensor laws at T = {T}; their mixture is μ (weak consensus)", fontsize=9)
    ax.legend(ncol=2, fontsize=7)
    save_figure(fig, path)


def fig_tails(r: ScenarioResults, path: Path) -> None:
    g, ref, b = r.gikf, r.reference, r.bounds
    fig, axes = new_figure()
    ax = axes[0, 0]
    lam = np.exp(ref["features"][-1][FI["log_lam_max"]])
    emp = np.array([(lam > J).mean() for J in J_GRID])
    ax.loglog(J_GRID, np.where(emp > 0, emp, np.nan), "k-", lw=2, label=f"μ̂: P(‖P̃(T)‖ > J), {len(lam)} runs")
    ex = g["exceed"].astype(float)
    rows = [t for t in range(1, ex.shape[0]) if ex[t, 0, 0] >= 0]
    S = ex[rows].max(axis=0) / r.runs
    for n in range(r.scenario.N):
        ax.loglog(J_GRID, np.where(S[n] > 0, S[n], np.nan), lw=0.8, alpha=0.6, color="tab:blue",
                  label="sensors: sup_t P(‖P̂_n(t)‖ ≥ J)" if n == 0 else None)
    ax.loglog(J_GRID, np.minimum(1, r.scenario.N * emp), "b:", label="N μ̂ bound (27)")
    if "beta_single" in b and np.isfinite(b["beta_single"]).any():
        ax.loglog(J_GRID, b["beta_single"], "r--", label="Lemma 15 β(J), single witness")
        if np.isfinite(b["beta_multi"]).any():
            ax.loglog(J_GRID, b["beta_multi"], "m--", label="Lemma 15 β(J), all witness windows")
    elif "beta_single" in b:
        ax.text(0.02, 0.02, "Lemma 15 β(J) not drawn: Ā is a Monte Carlo estimate (greedy matching)",
                transform=ax.transAxes, fontsize=7)
    ax.set_xlabel("J")
    ax.set_ylabel("tail probability")
    ax.set_ylim(1e-5, 1.5)
    ax.set_title(f"{r.name}: stochastic boundedness — empirical tails vs bounds", fontsize=9)
    ax.legend(fontsize=7)
    save_figure(fig, path)


def fig_sample_paths(r: ScenarioResults, path: Path) -> None:
    g, b = r.gikf, r.bounds
    tr = g["path_trace"][0]
    T = tr.shape[0]
    fig, axes = new_figure(height=4.6)
    ax = axes[0, 0]
    cols = sequential_colors(r.scenario.N, "tab10" if r.scenario.N <= 10 else "viridis")
    for n in range(r.scenario.N):
        ax.semilogy(np.arange(T), tr[:, n], lw=0.9, color=cols[n], label=f"sensor {n}")
    ax.semilogy(np.arange(T), np.trace(b["P_central"][:T], axis1=1, axis2=2), "k--", lw=1.5, label="centralized P_c(t)")
    ax.set_xlabel("slot t")
    ax.set_ylabel("tr P̂_n(t)")
    ax.set_title(f"{r.name}: one GIKF run, trace of every sensor's covariance", fontsize=9)
    ax.legend(ncol=3, fontsize=6)
    save_figure(fig, path)


def fig_quantiles(r: ScenarioResults, path: Path) -> None:
    g, b = r.gikf, r.bounds
    q = g["quantiles"] / LOG10
    T = q.shape[0]
    t = np.arange(T)
    fig, axes = new_figure(height=4.6)
    ax = axes[0, 0]
    cols = sequential_colors(r.scenario.N, "tab10" if r.scenario.N <= 10 else "viridis")
    for n in range(r.scenario.N):
        ax.plot(t, q[:, n, gk.QUANTILES.index(0.5)], color=cols[n], lw=1.2, label=f"sensor {n} median")
        ax.plot(t, q[:, n, gk.QUANTILES.index(0.99)], color=cols[n], lw=0.7, ls=":")
    ref_q = np.quantile(r.reference["features"][:, FI["log_trace"]] / LOG10, [0.5, 0.99], axis=1)
    ax.plot(r.reference["times"], ref_q[0], "ko-", ms=3, label="μ_t median (Theorem 8)")
    ax.plot(r.reference["times"], ref_q[1], "ks:", ms=3, label="μ_t q0.99")
    rate = b["divergence_rate"]
    if (rate > 0).any():
        n = int(np.argmax(rate))
        t0 = T // 2
        y0 = q[t0, n, gk.QUANTILES.index(0.5)]
        ax.plot(t[t0:], y0 + (t[t0:] - t0) * rate[n] / LOG10, "r--", lw=2, label=f"predicted slope 2 log|λ| = {rate[n]:.3f}/slot")
    ax.set_xlabel("slot t")
    ax.set_ylabel("log₁₀ tr P̂_n(t): quantiles over runs")
    ax.set_title(f"{r.name}: median (solid) and q0.99 (dotted) over {r.runs} runs", fontsize=9)
    ax.legend(ncol=3, fontsize=6)
    save_figure(fig, path)


def fig_matchings(r: ScenarioResults, path: Path) -> None:
    g = r.gikf
    partners = g["path_partners"][0]
    T = min(partners.shape[0] - 1, 120)
    edges = sorted({(min(u, v), max(u, v)) for u, v in r.scenario.graph.build().edges()})
    if len(edges) <= 40:
        grid = np.zeros((len(edges), T))
        for t in range(T):
            for k, (u, v) in enumerate(edges):
                grid[k, t] = partners[t, u] == v
        labels, ylabel = [f"{u}–{v}" for u, v in edges], "edge"
    else:  # many edges (E9): one row per node, shaded when the node is matched
        grid = (partners[:T] != np.arange(partners.shape[1])).T.astype(float)
        labels, ylabel = [str(n) for n in range(partners.shape[1])], "node (shaded: matched)"
    fig, axes = new_figure(width=8, height=max(2.5, 0.22 * len(labels) + 1))
    ax = axes[0, 0]
    ax.imshow(grid, aspect="auto", cmap="Greys", interpolation="nearest")
    ax.set_yticks(range(len(labels)))
    ax.set_yticklabels(labels, fontsize=6)
    ax.set_xlabel("slot t")
    ax.set_ylabel(ylabel)
    ax.grid(False)
    ax.set_title(f"{r.name}: active matching A(t) of sample run 0 ({r.scenario.protocol.kind}; A(0) = I)", fontsize=9)
    save_figure(fig, path)


def write_figures(r: ScenarioResults, figs: Path) -> None:
    n = r.name
    fig_sample_paths(r, figs / f"sample_paths_trace_{n}.png")
    fig_quantiles(r, figs / f"quantiles_over_runs_{n}.png")
    fig_matchings(r, figs / f"matchings_{n}.png")
    fig_random_sensor(r, figs / f"laws_random_sensor_vs_mu_{n}.png")
    if not (r.bounds["divergence_rate"] > 0).any():
        fig_per_sensor(r, figs / f"laws_per_sensor_{n}.png")
        fig_tails(r, figs / f"tails_vs_bound_{n}.png")


# -- recordings ----------------------------------------------------------------------------------------

def write_recording(r: ScenarioResults, path: Path, claims: list[dict], prov: dict, paper_id: str) -> None:
    sc, g, b = r.scenario, r.gikf, r.bounds
    N, M = sc.N, sc.M
    n_show = min(N, 12)
    blueprint = rrb.Blueprint(
        rrb.Tabs(
            rrb.Horizontal(
                rrb.Vertical(rrb.GraphView(origin="/graph", name="active matching A(t) (sample run 0)"),
                             rrb.GraphView(origin="/links", name="allowed links (graph)"),
                             rrb.TextDocumentView(origin="/report", name="claims"), row_shares=[3, 2, 2]),
                rrb.Vertical(rrb.TimeSeriesView(origin="/nodes", name="tr P̂_n(t), sample run 0, every sensor",
                                                contents=[f"/nodes/{n}/cov_trace/**" for n in range(N)] + ["/central/cov_trace"]),
                             rrb.TimeSeriesView(origin="/mc", name="log10 tr P̂: median over runs per sensor, μ_t quantiles",
                                                contents=["/mc/median/**", "/mc/mu/**"]), row_shares=[1, 1]),
                column_shares=[2, 3], name="overview"),
            rrb.Grid(*[rrb.TimeSeriesView(origin=f"/mc/quantiles/{n}", name=f"sensor {n}: log10 tr P̂ quantiles over runs",
                                          contents=[f"/mc/quantiles/{n}/**", "/mc/mu/**"]) for n in range(n_show)],
                     name="quantiles over runs"),
            rrb.Grid(*[rrb.TimeSeriesView(origin=f"/nodes/{n}/error", name=f"sensor {n}: estimation error (run 0)",
                                          contents=[f"/nodes/{n}/error/**", "/central/error/**"]) for n in range(n_show)],
                     name="errors"),
            rrb.Horizontal(rrb.TextDocumentView(origin="/report", name="claims"),
                           rrb.TextDocumentView(origin="/claims", name="claim detail"), name="claims"),
        ),
        rrb.TimePanel(timeline="k", expanded=False),
        collapse_panels=True,
    )
    props = {"seed": r.seed, "runs": r.runs, "reference_runs": r.reference_runs, "slots": r.slots, "N": N, "M": M,
             "protocol": sc.protocol.kind, "graph": sc.graph.kind, "versions": json.dumps(prov.get("versions", {})),
             "git": prov.get("git", "")}
    with rec_.recording(path, application_id=f"dse-{paper_id}", recording_id=f"{paper_id}-{sc.name}-seed{r.seed}",
                        blueprint=blueprint, properties=props) as rec:
        T1 = g["path_trace"].shape[1]
        idx = rec_.sequence_index("k", np.arange(T1))
        pos = sc.graph.positions()
        edges = sorted({(min(u, v), max(u, v)) for u, v in sc.graph.build().edges()})
        ids = [str(n) for n in range(N)]
        labels = [f"s{n} (type {sc.types[n]})" for n in range(N)]
        colors = [rec_.color(t) for t in sc.types]
        # nodes static, the active matching per slot (static edges would override the per-slot ones)
        rec.log("graph", rr.GraphNodes(ids, positions=rec_.display_positions(pos), labels=labels, colors=colors, radii=12.0,
                                       show_labels=True), static=True)
        rec_.log_graph(rec, "links", pos, edges, labels=labels, colors=colors)
        partners = g["path_partners"][0][:T1]
        per_step = [[(str(n), str(int(p))) for n, p in enumerate(row) if p > n] for row in partners]
        flat = [e for es in per_step for e in es]
        if flat:
            rec.send_columns("graph", indexes=idx,
                             columns=rr.GraphEdges.columns(edges=flat).partition([len(es) for es in per_step]))
        rec_.send_series(rec, "events/matching_size", idx, np.array([len(es) for es in per_step], float),
                         names="edges in A(t), run 0", points=True)
        n_paths = g["path_trace"].shape[0]
        for n in range(N):
            rec_.send_series(rec, f"nodes/{n}/cov_trace", idx, g["path_trace"][:, :, n].T,
                             names=[f"sensor {n} run {p}" for p in range(n_paths)], colors=[rec_.color(n)] * n_paths)
            rec_.send_series(rec, f"nodes/{n}/error", idx, g["path_err"][0, :, n, :],
                             names=[f"sensor {n}: e_{j + 1}" for j in range(M)], colors=[rec_.color(j) for j in range(M)])
            qs = g["quantiles"][:, n, :] / LOG10
            rec_.send_series(rec, f"mc/quantiles/{n}", idx, qs, names=[f"q{q:g}" for q in gk.QUANTILES],
                             colors=[rec_.color(n)] * len(gk.QUANTILES), width=1.0)
            rec_.send_series(rec, f"mc/median/{n}", idx, qs[:, gk.QUANTILES.index(0.5)], names=f"sensor {n} median",
                             colors=[rec_.color(n)])
        rec_.send_series(rec, "central/cov_trace", idx, np.trace(b["P_central"][:T1], axis1=1, axis2=2),
                         names="centralized tr P_c(t)", colors=[(0, 0, 0)], width=2.5)
        rec_.send_series(rec, "central/error", idx, g["path_err_c"][0], names=[f"centralized e_{j + 1}" for j in range(M)],
                         colors=[(0, 0, 0)] * M, width=2.0)
        rec_.send_series(rec, "bounds/envelope_log10_trace", idx, np.log10(np.trace(b["envelope"][:T1], axis1=1, axis2=2)),
                         names="log10 tr f_0^t(P0) (Lyapunov envelope)", colors=[(120, 120, 120)])
        ref_t = r.reference["times"]
        ref_q = np.quantile(r.reference["features"][:, FI["log_trace"]] / LOG10, list(gk.QUANTILES), axis=1).T
        rec_.send_series(rec, "mc/mu", rec_.sequence_index("k", ref_t), ref_q,
                         names=[f"μ_t q{q:g} (Theorem 8)" for q in gk.QUANTILES], colors=[(0, 0, 0)] * len(gk.QUANTILES),
                         points=True)
        rec_.log_tensor(rec, "graph/Abar", b["Abar"])
        own = [c for c in claims if c["id"].endswith(f".{sc.name}")]
        counts = {s: sum(c["verdict"] == s for c in own) for s in ("pass", "fail", "erratum", "not-checkable", "error")}
        summary = (f"# {sc.name}: {counts['pass']} pass, {counts['fail']} fail, {counts['erratum']} erratum, "
                   f"{counts['not-checkable']} not checkable, {counts['error']} errors\n\n{sc.description}\n\nseed {r.seed}, "
                   f"{r.runs:,} GIKF runs, "
                   f"{r.reference_runs:,} Theorem-8 runs, {r.slots} slots")
        table = [c for c in own if c["id"].endswith(f".{sc.name}") or c["id"].count(".") == 2]
        rec_.log_claims(rec, table, summary, details=own)


def _write_scenario(r: ScenarioResults, out_dir: Path, claims: list[dict], prov: dict, paper_id: str) -> None:
    write_figures(r, out_dir / "figures")
    write_recording(r, out_dir / f"{r.name}.rrd", claims, prov, paper_id)


def write_outputs(res: Results, out_dir: Path, claims: list[dict], prov: dict, paper_id: str, workers: int = 1) -> None:
    work = functools.partial(_write_scenario, out_dir=out_dir, claims=claims, prov=prov, paper_id=paper_id)
    parallel_map(work, list(res.scenarios.values()), workers=workers, desc="figures and recordings")
