"""Rerun recordings of the random-comm-filter family, drawn from the run's tables: one
`<scenario>.rrd` per scenario on the continuous timeline `t` (integer nanoseconds).

Entities: /graph (sensor nodes, communication edges), /events/edge_<i>_<j> (one point per ring
of that edge's clock on a sample path), /truth/x and /nodes/<i>/estimate, /nodes/<i>/error
(sample trials), /nodes/<i>/cov_trace/lam<λ> (tr 𝒫_i, exact tr E[e_ie_iᵀ], Monte Carlo mean
and 95% band, tr P_KB) for every simulated λ, /paths/<p>/node<i> (one clock path: tr P_i(t; τ)
and tr E[e_ie_iᵀ | τ]), /central/kalman_bucy, /bounds/S, /claims/<id>, /report.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from dse.outputs import record as rec_

from .outputs import View

Z95 = 1.959964


def _ns(t: np.ndarray) -> np.ndarray:
    return np.round(np.asarray(t, float) * 1e9).astype(np.int64)


def _lam_tag(lam: float) -> str:
    return f"lam{lam:g}".replace(".", "p")


def write_scenario(v: View, path: Path, claims: list[dict], prov: dict, paper: bool = False) -> None:
    N, n = v.N, v.n
    lams = v.rates
    series, mc = v["series"], v["mc_series"]
    t = np.unique(series["t"].to_numpy())
    idx = rec_.duration_index("t", _ns(t))
    nodes_shown = min(N, 6)
    blueprint = rrb.Blueprint(
        rrb.Tabs(
            rrb.Grid(*[rrb.TimeSeriesView(origin=f"/nodes/{i}/cov_trace/{_lam_tag(lams[0])}",
                                          name=f"node {i + 1}: tr covariance, λ = {lams[0]:g}")
                       for i in range(nodes_shown)], name="mean-square error vs bounds"),
            rrb.Horizontal(rrb.GraphView(origin="/graph", name="sensor network"),
                           rrb.GraphView(origin="/events/graph", name="edge that rang last (one path)"),
                           rrb.TimeSeriesView(origin="/events", name="edge clock rings (one path)"),
                           name="network and events"),
            rrb.Grid(*[rrb.TimeSeriesView(origin=f"/nodes/{i}", contents=[f"/nodes/{i}/estimate/**", "/truth/**"],
                                          name=f"node {i + 1}: estimate vs truth") for i in range(nodes_shown)],
                     name="sample trial"),
            rrb.Grid(*[rrb.TimeSeriesView(origin=f"/nodes/{i}/error", name=f"node {i + 1}: error (sample trials)")
                       for i in range(nodes_shown)], name="errors"),
            rrb.Grid(*[rrb.TimeSeriesView(origin=f"/paths/0/node{i}", name=f"node {i + 1}: one clock path")
                       for i in range(nodes_shown)], name="per-path bound (14)"),
            *[rrb.Grid(*[rrb.TimeSeriesView(origin=f"/nodes/{i}/cov_trace/{_lam_tag(lam)}",
                                            name=f"node {i + 1}, λ = {lam:g}") for i in range(nodes_shown)],
                       name=f"λ = {lam:g}") for lam in lams[1:]],
            rrb.Horizontal(rrb.TextDocumentView(origin="/report", name="claims"),
                           rrb.TextDocumentView(origin="/claims", name="claim detail"), name="claims"),
        ),
        rrb.TimePanel(timeline="t", expanded=False),
        collapse_panels=True,
    )
    grid = mc[mc["simulator"] == "gridded"]
    event = mc[mc["simulator"] == "event"]
    props = {"seed": v.seed, "trials": int(grid["trials"].iloc[0]), "event_trials": int(event["trials"].iloc[0]),
             "rates": str(lams), "alpha": v.design("alpha"), "mode": "edge" if v.design("edge_mode") == 1 else "ordered",
             "n": n, "N": N, "versions": json.dumps(prov.get("versions", {})), "git": prov.get("git", "")}
    gnodes, gedges = v["graph_nodes"], v["graph_edges"]
    pos = gnodes[["x", "y"]].to_numpy()
    clocks = gedges[["i", "j"]].to_numpy()
    undirected = sorted({tuple(sorted(map(int, e))) for e in clocks})
    with rec_.recording(path, application_id="dse-tanwani", recording_id=f"tanwani-{v.name}-seed{v.seed}",
                        blueprint=blueprint, properties=props) as rec:
        rec_.log_graph(rec, "graph", pos, undirected, labels=[f"sensor {i + 1}" for i in range(N)])
        # edge events of the first event-driven sample path
        ev = v["path_events"]
        ev = ev[ev["path"] == 0]
        for k, (i, j) in enumerate(clocks):
            tk = ev.loc[ev["clock"] == k, "t"].to_numpy()
            if tk.size:
                rec_.send_series(rec, f"events/edge_{i + 1}_{j + 1}", rec_.duration_index("t", _ns(tk)),
                                 np.full(tk.size, float(k + 1)), names=f"edge {i + 1}–{j + 1}",
                                 colors=[rec_.color(k)], points=True)
        # the same path as a graph whose edge set is, at every time, the edge that rang last
        if len(ev):
            ids = [str(i) for i in range(N)]
            rec.log("events/graph", rr.GraphNodes(ids, positions=pos * 100.0, labels=[f"sensor {i + 1}" for i in range(N)],
                                                  show_labels=True, radii=12.0), static=True)
            pairs = [(str(i), str(j)) for i, j in ev[["i", "j"]].to_numpy()]
            rec.send_columns("events/graph", indexes=rec_.duration_index("t", _ns(ev["t"].to_numpy())),
                             columns=rr.GraphEdges.columns(edges=pairs).partition([1] * len(pairs)))
        # sample trials of the gridded simulator at the first rate
        sp = v["sample_paths"]
        sp = sp[sp["simulator"] == "gridded"]
        trials = sorted(sp["trial"].unique())
        first = sp[(sp["trial"] == trials[0]) & (sp["node"] == 0)]
        x = first.pivot(index="t", columns="component", values="x").to_numpy()
        rec_.send_series(rec, "truth/x", idx, x, names=[f"x{a + 1} (truth)" for a in range(n)],
                         colors=[(0, 0, 0)] * n, width=2.0)
        for i in range(N):
            at = sp[sp["node"] == i]
            xh = at[at["trial"] == trials[0]].pivot(index="t", columns="component", values="xhat").to_numpy()
            rec_.send_series(rec, f"nodes/{i}/estimate", idx, xh, names=[f"x̂_{i + 1}[{a + 1}]" for a in range(n)])
            for p in trials:
                e = at[at["trial"] == p].pivot(index="t", columns="component", values="error").to_numpy()
                rec_.send_series(rec, f"nodes/{i}/error/trial{p}", idx, e,
                                 names=[f"trial {p}: e_{i + 1}[{a + 1}]" for a in range(n)])
        # mean-square error vs bounds, every simulated λ
        kb = v.by_node(series[series["rate"] == lams[0]], "trP_kb")[:, 0]
        for lam in lams:
            at = series[series["rate"] == lam]
            P, J = v.by_node(at, "trP_bound"), v.by_node(at, "trP_exact")
            g = grid[grid["rate"] == lam]
            m, se = v.by_node(g, "trP_mc"), v.by_node(g, "trP_mc_se")
            for i in range(N):
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
        # one clock path: the per-path bound (14) and the exact per-path covariance
        ps = v["path_series"]
        ps = ps[ps["path"] == 0]
        Pp, Sp = v.by_node(ps, "trP_path"), v.by_node(ps, "trSigma_path")
        mean = v.by_node(series[series["rate"] == lams[0]], "trP_bound")
        for i in range(N):
            rec_.send_series(rec, f"paths/0/node{i}", idx, np.column_stack([Pp[:, i], Sp[:, i], mean[:, i]]),
                             names=["tr P_i(t; τ) (14)", "tr E[e_ie_iᵀ | τ] exact", "tr 𝒫_i(t) (9)"],
                             colors=[(214, 39, 40), (0, 0, 0), (255, 152, 150)])
        counts = {k: sum(c["verdict"] == k for c in claims) for k in ("pass", "fail", "erratum", "not-checkable", "error")}
        table = [c for c in claims if c["id"].endswith(f".{v.name}") or c["id"].count(".") == 2]
        note = "Scenario of this reproduction (the paper has no numerical example). " if paper else ""
        rec_.log_claims(rec, table, f"# {v.title}\n\n{note}All claims of the run: {counts}.", width=24,
                        details=[c for c in claims if c["id"].endswith(f".{v.name}")])
