"""The Rerun recording of one random-comm-filter scenario, `<scenario>.rrd`, drawn from the run's
tables on the shared recording scaffold, on the continuous timeline `t` (integer nanoseconds).

Entities: /graph (sensor nodes, communication edges), /events/edge_<i>_<j> (one point per ring
of that edge's clock on a sample path), /truth/x and /nodes/<i>/estimate, /nodes/<i>/error
(sample trials), /nodes/<i>/cov_trace/lam<λ> (tr 𝒫_i, exact tr E[e_ie_iᵀ], Monte Carlo mean
and 95% band, tr P_KB) for every simulated λ, /paths/<p>/node<i> (one clock path: tr P_i(t; τ)
and tr E[e_ie_iᵀ | τ]), /central/kalman_bucy, /bounds/S, and the scaffold's /report (the claims).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from dse.contract.views import Outputs, recording
from dse.outputs import record as rec_

from .views import PAPER_NOTE, ScenarioTables

Z95 = 1.959964


def _ns(t: np.ndarray) -> np.ndarray:
    return np.round(np.asarray(t, float) * 1e9).astype(np.int64)


def _lam_tag(lam: float) -> str:
    return f"lam{lam:g}".replace(".", "p")


def _tabs(lams: list[float], N: int) -> list:
    shown = range(min(N, 6))
    grid = lambda views, name: rrb.Grid(*views, name=name)  # noqa: E731
    return [grid([rrb.TimeSeriesView(origin=f"/nodes/{i}/cov_trace/{_lam_tag(lams[0])}",
                                     name=f"node {i}: tr covariance, λ = {lams[0]:g}") for i in shown],
                 "mean-square error vs bounds"),
            rrb.Horizontal(rrb.GraphView(origin="/graph", name="sensor network"),
                           rrb.GraphView(origin="/events/graph", name="edge that rang last (one path)"),
                           rrb.TimeSeriesView(origin="/events", name="edge clock rings (one path)"),
                           name="network and events"),
            grid([rrb.TimeSeriesView(origin=f"/nodes/{i}", contents=[f"/nodes/{i}/estimate/**", "/truth/**"],
                                     name=f"node {i}: estimate vs truth") for i in shown], "sample trial"),
            grid([rrb.TimeSeriesView(origin=f"/nodes/{i}/error", name=f"node {i}: error (sample trials)")
                  for i in shown], "errors"),
            grid([rrb.TimeSeriesView(origin=f"/paths/0/node{i}", name=f"node {i}: one clock path") for i in shown],
                 "per-path bound (14)"),
            *[grid([rrb.TimeSeriesView(origin=f"/nodes/{i}/cov_trace/{_lam_tag(lam)}", name=f"node {i}, λ = {lam:g}")
                    for i in shown], f"λ = {lam:g}") for lam in lams[1:]]]


def _log_network(rec, v: ScenarioTables) -> None:
    """The graph, the rings of the first event-driven sample path, and that path as a graph whose edge set
    is, at every time, the edge that rang last."""
    N = v.N
    pos = v["graph_nodes"][["x", "y"]].to_numpy()
    clocks = v["graph_edges"][["i", "j"]].to_numpy()
    undirected = sorted({tuple(sorted(map(int, e))) for e in clocks})
    rec_.log_graph(rec, "graph", pos, undirected, labels=[f"sensor {i}" for i in range(N)])
    ev = v["path_events"]
    ev = ev[ev["path"] == 0]
    for k, (i, j) in enumerate(clocks):
        tk = ev.loc[ev["clock"] == k, "t"].to_numpy()
        if tk.size:
            rec_.send_series(rec, f"events/edge_{i}_{j}", rec_.duration_index("t", _ns(tk)),
                             np.full(tk.size, float(k + 1)), names=f"edge {i}–{j}", colors=[rec_.color(k)],
                             points=True)
    if len(ev):
        rec.log("events/graph", rr.GraphNodes([str(i) for i in range(N)], positions=pos * 100.0,
                                              labels=[f"sensor {i}" for i in range(N)], show_labels=True,
                                              radii=12.0), static=True)
        pairs = [(str(i), str(j)) for i, j in ev[["i", "j"]].to_numpy()]
        rec.send_columns("events/graph", indexes=rec_.duration_index("t", _ns(ev["t"].to_numpy())),
                         columns=rr.GraphEdges.columns(edges=pairs).partition([1] * len(pairs)))


def _log_trials(rec, v: ScenarioTables, idx) -> None:
    """The sample trials of the gridded simulator at the first rate: truth, estimates and errors."""
    n = v.n
    sp = v["sample_paths"]
    sp = sp[sp["simulator"] == "gridded"]
    trials = sorted(sp["trial"].unique())
    first = sp[(sp["trial"] == trials[0]) & (sp["node"] == 0)]
    x = first.pivot(index="t", columns="component", values="x").to_numpy()
    rec_.send_series(rec, "truth/x", idx, x, names=[f"x{a + 1} (truth)" for a in range(n)], colors=[(0, 0, 0)] * n,
                     width=2.0)
    for i in range(v.N):
        at = sp[sp["node"] == i]
        xh = at[at["trial"] == trials[0]].pivot(index="t", columns="component", values="xhat").to_numpy()
        rec_.send_series(rec, f"nodes/{i}/estimate", idx, xh, names=[f"x̂_{i}[{a + 1}]" for a in range(n)])
        for p in trials:
            e = at[at["trial"] == p].pivot(index="t", columns="component", values="error").to_numpy()
            rec_.send_series(rec, f"nodes/{i}/error/trial{p}", idx, e,
                             names=[f"trial {p}: e_{i}[{a + 1}]" for a in range(n)])


def _log_covariances(rec, v: ScenarioTables, idx, t: np.ndarray) -> None:
    """Mean-square errors against the bounds at every simulated λ, the references, and one clock path."""
    series, mc = v["series"], v["mc_series"]
    grid = mc[mc["simulator"] == "gridded"]
    lams = v.rates
    kb = v.by_node(series[series["rate"] == lams[0]], "trP_kb")[:, 0]
    for lam in lams:
        at = series[series["rate"] == lam]
        P, J = v.by_node(at, "trP_bound"), v.by_node(at, "trP_exact")
        g = grid[grid["rate"] == lam]
        m, se = v.by_node(g, "trP_mc"), v.by_node(g, "trP_mc_se")
        for i in range(v.N):
            cols = [P[:, i], J[:, i], m[:, i], m[:, i] - Z95 * se[:, i], m[:, i] + Z95 * se[:, i], kb]
            rec_.send_series(rec, f"nodes/{i}/cov_trace/{_lam_tag(lam)}", idx, np.column_stack(cols),
                             names=["tr 𝒫_i (bound 9)", "tr E[e_ie_iᵀ] exact", f"MC mean ({int(g['trials'].iloc[0])} "
                                    "trials)", "MC 95% low", "MC 95% high", "tr P_KB (Kalman–Bucy)"],
                             colors=[(214, 39, 40), (0, 0, 0), (31, 119, 180), (150, 190, 230), (150, 190, 230),
                                     (127, 127, 127)])
    rec_.send_series(rec, "central/kalman_bucy", idx, kb, names="tr P_KB(t)", colors=[(127, 127, 127)])
    if np.isfinite(v.design("trS")):
        rec_.send_series(rec, "bounds/S", idx, np.column_stack([np.full(len(t), v.design("trS")),
                                                               np.full(len(t), v.design("trS_true"))]),
                         names=["tr S (11)", "tr S_true"])
    ps = v["path_series"]
    ps = ps[ps["path"] == 0]
    Pp, Sp = v.by_node(ps, "trP_path"), v.by_node(ps, "trSigma_path")
    mean = v.by_node(series[series["rate"] == lams[0]], "trP_bound")
    for i in range(v.N):
        rec_.send_series(rec, f"paths/0/node{i}", idx, np.column_stack([Pp[:, i], Sp[:, i], mean[:, i]]),
                         names=["tr P_i(t; τ) (14)", "tr E[e_ie_iᵀ | τ] exact", "tr 𝒫_i(t) (9)"],
                         colors=[(214, 39, 40), (0, 0, 0), (255, 152, 150)])


def write(out: Outputs, v: ScenarioTables, path: Path) -> None:
    """The scenario's recording; its claims tab lists the scenario's claims and the run's own."""
    t = np.unique(v["series"]["t"].to_numpy())
    idx = rec_.duration_index("t", _ns(t))
    mc = v["mc_series"]

    def log(rec):
        _log_network(rec, v)
        _log_trials(rec, v, idx)
        _log_covariances(rec, v, idx, t)

    several = len(out.reproduction.scenarios) > 1   # a one-scenario run's ids do not name the scenario
    claims = [c for c in out.claims if not several or c["id"].endswith(f".{v.name}") or c["id"].count(".") == 2]
    recording(path, out, recording_id=f"{out.run_prefix}-{v.name}-seed{out.seed}", tabs=lambda: _tabs(v.rates, v.N),
              timeline="t", log=log, claims=claims,
              summary=out.summary(v.title, PAPER_NOTE if out.reproduction.is_paper else ""),
              properties={"event_trials": int(mc.loc[mc["simulator"] == "event", "trials"].iloc[0]),
                          "rates": str(v.rates), "alpha": v.design("alpha"),
                          "mode": "edge" if v.design("edge_mode") == 1 else "ordered", "n": v.n, "N": v.N})
