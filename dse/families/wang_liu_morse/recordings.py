"""The Rerun recordings of a hybrid-observer run, on the shared recording scaffold, and the run's
views (figures and recordings).

One recording per (system, run): ``<part>_<run>.rrd`` (a user's run: ``<run>.rrd``) on the
continuous timeline ``t`` (integer nanoseconds): the true state and each agent's estimate (trial
0), the error of each agent at the stored samples and before/after every reset at the event
times, trial 0's estimator iterates at their iteration times (first stored intervals),
statistics over trials, the bound curves, the switching graph (source sets of the first stored
intervals), and the claims. Errors are also recorded as log10(max(error, 1e-300)).
"""
from __future__ import annotations

import math

import numpy as np

from dse.contract.views import Outputs, View, recording

from .figures import TableView, _col, _pivot, figure_views, log10_safe
from .simulation import is_theorem_run

#: the tables figures and recordings select per run, split before the workers fork (each would split its own)
SPLIT = ("state_series", "node_series", "network_series", "nodes", "events", "intervals", "iterates", "source_sets")


def _ns(t) -> np.ndarray:
    return np.round(np.asarray(t, float) * 1e9).astype(np.int64)


def _tabs(m: int):
    import rerun.blueprint as rrb

    agents = range(min(m, 6))
    return [rrb.Horizontal(
                rrb.Grid(*[rrb.TimeSeriesView(origin=f"/nodes/{i + 1}", name=f"agent {i + 1}: estimate vs truth",
                                              contents=[f"/nodes/{i + 1}/estimate/**", "/truth/**"]) for i in agents]),
                rrb.Vertical(rrb.TimeSeriesView(origin="/", name="log10 errors, bounds",
                                                contents=[f"/nodes/{i + 1}/log10_error/**" for i in range(m)]
                                                + ["/bounds/log10/**", "/central/log10/**", "/mc/log10/**"]),
                             rrb.GraphView(origin="/graph", name="neighbour graph N(t)"), row_shares=[2, 1]),
                column_shares=[3, 2], name="estimates"),
            rrb.Grid(*[rrb.TimeSeriesView(origin=f"/nodes/{i + 1}", name=f"agent {i + 1}: errors at resets",
                                          contents=[f"/nodes/{i + 1}/log10_error/**", f"/nodes/{i + 1}/reset/**"])
                       for i in agents], name="resets"),
            rrb.Grid(*[rrb.TimeSeriesView(origin=f"/nodes/{i + 1}/iterates",
                                          name=f"agent {i + 1}: log10 ||z_is(k) - x(t_i(s-1))||") for i in agents],
                     name="iterates"),
            rrb.TimeSeriesView(origin="/bounds", name="|A(s)|, bounds", contents=["/bounds/**"])]


def _log_agents(rec, tables, scenario: str, run_name: str, m: int, n: int) -> None:
    """The truth and each agent's estimate, its error (log10 too), its errors at the resets and its iterates."""
    from dse.outputs import record

    st = tables.rows("state_series", scenario, run_name)
    ts, x = _pivot(st[st["source"] == "truth"], "value", by="component")
    record.send_series(rec, "truth/x", record.duration_index("t", _ns(ts)), x, names=[f"x^({c + 1})" for c in range(n)],
                       colors=[(0, 0, 0)] * n, width=2.0)
    tn, err = _pivot(tables.rows("node_series", scenario, run_name), "error_trial0")
    nidx = record.duration_index("t", _ns(tn))
    its = tables.rows("iterates", scenario, run_name)
    estimates = dict(iter(st[st["source"] == "agent"].groupby("node", sort=False)))
    nodes_of = dict(iter(tables.rows("nodes", scenario, run_name).groupby("node", sort=False)))
    its_of = dict(iter(its.groupby("node", sort=False)))
    # series sharing their times are columns of one entity (a fixed cost per entity dominates short series)
    record.send_series(rec, "nodes/error", nidx, err, names=[f"||e_{i + 1}(t)||" for i in range(m)],
                       colors=[_col(i) for i in range(m)])
    for i in range(m):
        te, xe = _pivot(estimates[i + 1], "value", by="component")
        record.send_series(rec, f"nodes/{i + 1}/estimate", record.duration_index("t", _ns(te)), xe,
                           names=[f"agent {i + 1} x_{i + 1}^({c + 1})" for c in range(n)], colors=[_col(i)] * n)
        record.send_series(rec, f"nodes/{i + 1}/log10_error", nidx, log10_safe(err[:, i]),
                           names=f"log10 ||e_{i + 1}(t)||", colors=[_col(i)])
        nd = nodes_of[i + 1]
        record.send_series(rec, f"nodes/{i + 1}/reset", record.duration_index("t", _ns(nd["t"])),
                           np.column_stack([log10_safe(nd["error_before_reset"]), log10_safe(nd["error_trial0"])]),
                           names=[f"log10 ||e_{i + 1}(t_is⁻)|| (before reset)", f"log10 ||e_{i + 1}(t_is)|| (after reset)"],
                           colors=[(120, 120, 120), _col(i)], points=True)
        it = its_of.get(i + 1, its.iloc[:0]).sort_values("t", kind="stable")
        if len(it):
            record.send_series(rec, f"nodes/{i + 1}/iterates", record.duration_index("t", _ns(it["t"])),
                               log10_safe(it["error"]), names=f"agent {i + 1} log10 ||π_is(k)||", colors=[_col(i)],
                               points=True)


def _log_network(rec, tables, scenario: str, run_name: str, spec, lam_T: float) -> None:
    """The resets, the centralized reference, the statistics over trials, the bounds and |A(s)|."""
    import rerun as rr

    from dse.outputs import record

    nodes = tables.rows("nodes", scenario, run_name)
    resets = nodes.sort_values(["t", "node"], kind="stable")
    rec.send_columns("events/reset", indexes=record.duration_index("t", _ns(resets["t"])),
                     columns=rr.TextLog.columns(text=[f"agent {int(i)}: event s = {int(s)}"
                                                      for i, s in zip(resets["node"], resets["s"])]))
    net = tables.rows("network_series", scenario, run_name)
    gidx = record.duration_index("t", _ns(net["t"]))
    record.send_series(rec, "central/error", gidx, net["central_trial0"].to_numpy(),
                       names="centralized observer ||x_c - x||", colors=[(0, 0, 0)])
    kalman = np.isfinite(net["kalman_trial0"]).any()
    record.send_series(rec, "central/log10", gidx, np.column_stack([log10_safe(net["central_trial0"])]
                                                                   + ([log10_safe(net["kalman_trial0"])] if kalman else [])),
                       names=["log10 centralized observer error"]
                       + (["log10 centralized Kalman filter error (filterpy)"] if kalman else []),
                       colors=[(90, 90, 90), (0, 0, 0)][:1 + kalman])
    series = tables.rows("node_series", scenario, run_name)
    tn, emean = _pivot(series, "error_mean")
    _, emax = _pivot(series, "error_max")
    ev = tables.rows("events", scenario, run_name)
    trials = int(ev["trials"].iloc[0])
    if trials > 1:
        record.send_series(rec, "mc/log10/max_error", record.duration_index("t", _ns(tn)),
                           np.column_stack([log10_safe(emean.max(axis=1)), log10_safe(emax.max(axis=1))]),
                           names=[f"max_i of the mean over {trials} trials of ||e_i||", "largest over trials and agents"],
                           colors=[(100, 100, 200), (200, 100, 100)])
    if is_theorem_run(spec):
        b = ev[ev["s"] >= 1]
        record.send_series(rec, "bounds/log10/eq51", record.duration_index("t", _ns(b["t"])),
                           log10_safe(b["bound51_trial0"]), names="bound (51), trial 0", colors=[(0, 0, 0)], points=True)
        if np.isfinite(net["bound_printed_trial0"]).any():
            record.send_series(rec, "bounds/log10/continuous", gidx,
                               np.column_stack([log10_safe(net["bound_printed_trial0"]),
                                                log10_safe(net["bound_corrected_trial0"])]),
                               names=["printed continuous bound", "corrected continuous bound (× e^(λT))"],
                               colors=[(214, 39, 40), (0, 0, 0)], width=1.0)
    iv = tables.rows("intervals", scenario, run_name)
    key = "A_2" if spec.rule == "symmetric" else "A_mixed"
    vals = iv[key].to_numpy()
    ok = ~np.isnan(vals)
    if ok.any():
        times = nodes[nodes["node"] == 1].set_index("s")["t"].reindex(iv["s"].to_numpy()[ok]).to_numpy()
        record.send_series(rec, "bounds/A_norm", record.duration_index("t", _ns(times)),
                           np.column_stack([log10_safe(vals[ok]), np.full(ok.sum(), -lam_T / math.log(10))]),
                           names=[f"log10 {'||A(s)||₂' if key == 'A_2' else '|A(s)|'}", "log10 e^(-λT)"],
                           colors=[(31, 119, 180), (0, 0, 0)], points=False)


def _log_graph(rec, tables, scenario: str, run_name: str, spec, m: int) -> None:
    """The switching graph: nodes fixed, edges per iteration of the first stored intervals, where they change."""
    import rerun as rr

    from dse.outputs import record

    ang = np.pi / 2 - 2 * np.pi * np.arange(m) / m
    rec.log("graph", rr.GraphNodes([str(i + 1) for i in range(m)], positions=np.column_stack([np.cos(ang), np.sin(ang)])
                                   * 100, labels=[f"agent {i + 1}" for i in range(m)],
                                   colors=[_col(i) for i in range(m)], radii=12.0, show_labels=True), static=True)
    src = tables.rows("source_sets", scenario, run_name)
    src = src[src["used"]]
    if not len(src):
        return
    nodes = tables.rows("nodes", scenario, run_name)
    start = nodes[nodes["node"] == 1].set_index("s")["t"].to_dict()
    slot = (src["s"].to_numpy() - 1) * spec.q + (src["k"].to_numpy() - 1)       # iteration k of interval s, in order
    masks = np.zeros((int(slot.max()) + 1, m, m), dtype=bool)
    masks[slot, src["receiver"].to_numpy() - 1, src["sender"].to_numpy() - 1] = True
    change = np.r_[True, (masks[1:] != masks[:-1]).any(axis=(1, 2))]
    labels = np.array([str(i + 1) for i in range(m)])
    times, edges = [], []
    for g in np.nonzero(change)[0]:
        s, k = divmod(int(g), spec.q)
        times.append(int(round((start[s] + k * spec.Delta) * 1e9)))
        ii, jj = np.nonzero(masks[g])
        edges.append(np.column_stack([labels[jj], labels[ii]]))                 # (sender, receiver) pairs
    sizes = [len(es) for es in edges]
    rec.send_columns("graph", indexes=record.duration_index("t", np.array(times)),
                     columns=rr.GraphEdges.columns(edges=np.concatenate(edges),
                                                   graph_type=[rr.GraphType.Directed] * sum(sizes)).partition(sizes))


def run_recording(out: Outputs, tables, scenario: str, run_name: str, path) -> None:
    """The recording of one run of one system."""
    r = out.results[scenario]
    sc, spec = r.scenario, r.spec(run_name)

    def log(rec):
        _log_agents(rec, tables, scenario, run_name, sc.m, sc.n)
        _log_network(rec, tables, scenario, run_name, spec, sc.lam * sc.T)
        _log_graph(rec, tables, scenario, run_name, spec, sc.m)

    ev = tables.rows("events", scenario, run_name)
    recording(path, out, recording_id=f"{out.run_prefix}-{sc.name}-{run_name}-seed{r.seed}", tabs=lambda: _tabs(sc.m),
              timeline="t", log=log,
              properties={"system": sc.name, "run": run_name, "run_trials": int(ev["trials"].iloc[0]),
                          "q": float(spec.q), "T": sc.T, "timing": spec.timing, "switching": spec.switching,
                          "rule": spec.rule})


def views(out: Outputs) -> list[View]:
    """The figures, and one recording per (system, run), drawn from the run's tables."""
    tables = TableView(out.tables)
    for name in SPLIT:
        tables.rows(name, "", "")
    paper = out.reproduction.is_paper
    recordings = [View(f"{label}_{s.name}.rrd" if paper else f"{s.name}.rrd",
                       lambda path, label=label, s=s: run_recording(out, tables, label, s.name, path))
                  for label, part in out.results.parts.items() for s in part.scenario.runs]
    return figure_views(out.results, tables, paper) + recordings
