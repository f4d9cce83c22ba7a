"""Rerun recordings of the random-comm-filter family: one `<scenario>.rrd` per scenario on the
continuous timeline `t` (integer nanoseconds).

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

import estimators.gossip_covariance as gc
from pipeline import record as rec_

from .compute import Results, ScenarioResults

Z95 = 1.959964


def _ns(t: np.ndarray) -> np.ndarray:
    return np.round(np.asarray(t, float) * 1e9).astype(np.int64)


def _lam_tag(lam: float) -> str:
    return f"lam{lam:g}".replace(".", "p")


def write_scenario(r: ScenarioResults, res: Results, path: Path, claims: list[dict], prov: dict,
                   paper: bool = False) -> None:
    sc, s, b = r.scenario, r.sys, r.bounds
    N, n = s.N, s.n
    t = sc.output_times
    idx = rec_.duration_index("t", _ns(t))
    lams = sc.rates
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
    props = {"seed": res.seed, "trials": r.trials, "event_trials": r.event_trials, "rates": str(list(lams)),
             "alpha": s.alpha, "mode": s.mode, "gains": sc.gain_rule, "n": n, "N": N,
             "versions": json.dumps(prov.get("versions", {})), "git": prov.get("git", "")}
    with rec_.recording(path, application_id="dse-tanwani", recording_id=f"tanwani-{sc.name}-seed{res.seed}",
                        blueprint=blueprint, properties=props) as rec:
        rec_.log_graph(rec, "graph", sc.graph.positions(), list(s.edges), labels=[f"sensor {i + 1}" for i in range(N)])
        # edge events of the first event-driven sample path
        et, ec = r.event["sample_event_times"][0], r.event["sample_event_clocks"][0]
        for k, (i, j) in enumerate(s.clocks):
            tk = et[(ec == k) & np.isfinite(et)]
            if tk.size:
                rec_.send_series(rec, f"events/edge_{i + 1}_{j + 1}", rec_.duration_index("t", _ns(tk)),
                                 np.full(tk.size, float(k + 1)), names=f"edge {i + 1}–{j + 1}",
                                 colors=[rec_.color(k)], points=True)
        # the same path as a graph whose edge set is, at every time, the edge that rang last
        t_ev = et[(ec >= 0) & np.isfinite(et)]
        if t_ev.size:
            ids = [str(i) for i in range(N)]
            rec.log("events/graph", rr.GraphNodes(ids, positions=np.asarray(sc.graph.positions(), float) * 100.0,
                                                  labels=[f"sensor {i + 1}" for i in range(N)], show_labels=True,
                                                  radii=12.0), static=True)
            pairs = [(str(s.clocks[c][0]), str(s.clocks[c][1])) for c in ec[(ec >= 0) & np.isfinite(et)]]
            rec.send_columns("events/graph", indexes=rec_.duration_index("t", _ns(t_ev)),
                             columns=rr.GraphEdges.columns(edges=pairs).partition([1] * len(pairs)))
        # sample trials of the gridded simulator at the first rate
        z = r.gridded[lams[0]]["sample_z"]                      # (S, T, (N+1)n)
        names = [f"x{a + 1}" for a in range(n)]
        rec_.send_series(rec, "truth/x", idx, z[0, :, :n], names=[f"{nm} (truth)" for nm in names],
                         colors=[(0, 0, 0)] * n, width=2.0)
        for i in range(N):
            e = z[:, :, (i + 1) * n:(i + 2) * n]
            rec_.send_series(rec, f"nodes/{i}/estimate", idx, z[0, :, :n] - e[0],
                             names=[f"x̂_{i + 1}[{a + 1}]" for a in range(n)])
            for p in range(z.shape[0]):
                rec_.send_series(rec, f"nodes/{i}/error/trial{p}", idx, e[p],
                                 names=[f"trial {p}: e_{i + 1}[{a + 1}]" for a in range(n)])
        # mean-square error vs bounds, every simulated λ
        Pkb = np.trace(b["P_kb_t"], axis1=1, axis2=2)
        for lam in lams:
            P = np.trace(r.bound(lam), axis1=2, axis2=3)
            J = None if r.joint(lam) is None else np.trace(gc.diagonal_blocks(r.joint(lam), N, n), axis1=2, axis2=3)
            mc, se = r.grid_moments(lam).trace()
            for i in range(N):
                cols = [P[:, i], J[:, i] if J is not None else np.full(len(t), np.nan), mc[:, i],
                        mc[:, i] - Z95 * se[:, i], mc[:, i] + Z95 * se[:, i], Pkb]
                rec_.send_series(rec, f"nodes/{i}/cov_trace/{_lam_tag(lam)}", idx, np.column_stack(cols),
                                 names=["tr 𝒫_i (bound 9)", "tr E[e_ie_iᵀ] exact", f"MC mean ({r.trials} trials)",
                                        "MC 95% low", "MC 95% high", "tr P_KB (Kalman–Bucy)"],
                                 colors=[(214, 39, 40), (0, 0, 0), (31, 119, 180), (150, 190, 230), (150, 190, 230),
                                         (127, 127, 127)])
        rec_.send_series(rec, "central/kalman_bucy", idx, Pkb, names="tr P_KB(t)", colors=[(127, 127, 127)])
        if "S" in b:
            rec_.send_series(rec, "bounds/S", idx, np.column_stack([np.full(len(t), np.trace(b["S"])),
                                                                   np.full(len(t), np.trace(b["S_true"]))]),
                             names=["tr S (11)", "tr S_true"])
        # one clock path: the per-path bound (14) and the exact per-path covariance
        for i in range(N):
            rec_.send_series(rec, f"paths/0/node{i}", idx,
                             np.column_stack([np.trace(r.event["sample_pbound"][0][:, i], axis1=1, axis2=2),
                                              np.trace(r.event["sample_sigma"][0][:, i], axis1=1, axis2=2),
                                              np.trace(r.bound(lams[0])[:, i], axis1=1, axis2=2)]),
                             names=["tr P_i(t; τ) (14)", "tr E[e_ie_iᵀ | τ] exact", "tr 𝒫_i(t) (9)"],
                             colors=[(214, 39, 40), (0, 0, 0), (255, 152, 150)])
        counts = {v: sum(c["verdict"] == v for c in claims) for v in ("pass", "fail", "erratum", "not-checkable", "error")}
        table = [c for c in claims if c["id"].endswith(f".{sc.name}") or c["id"].count(".") == 2]
        note = "Scenario of this reproduction (the paper has no numerical example). " if paper else ""
        rec_.log_claims(rec, table, f"# {sc.title}\n\n{note}All claims of the run: {counts}.", width=24,
                        details=[c for c in claims if c["id"].endswith(f".{sc.name}")])


def write_recordings(res: Results, out_dir: Path, claims: list[dict], prov: dict, paper: bool = False) -> None:
    for name, r in res.scenarios.items():
        write_scenario(r, res, out_dir / f"{name}.rrd", claims, prov, paper)
