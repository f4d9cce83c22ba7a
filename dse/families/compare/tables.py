"""Every number of a compare run as documented tidy tables (first column `scenario`), one row per estimator
of the registry (`dse.estimators.network`) where a table has one."""
from __future__ import annotations

import numpy as np
import pandas as pd

from dse.estimators.network import registry
from dse.estimators.network_comparison import NEES_BAND, ks_test, nees_band
from dse.outputs.tables import spec

from .design import Design
from .stages import token_times

_S = ("scenario", "", "scenario name")
_E = ("estimator", "", "estimator id: " + ", ".join(registry()) + ", or a plug-in filter's name")

APPLICABILITY = spec("applicability", "estimator", [
    _S, _E, ("label", "", "what the estimator is"), ("applies", "", "true when it runs on this scenario"),
    ("reason", "", "why it does not apply (empty when it does)"),
    ("exact", "", "true when its exact mean second moments are computed (else Monte Carlo only)"),
    ("exact_reason", "", "why there are no exact moments"),
    ("gain_scale", "1", "ℓ multiplying the base gains (constant-gain filters)"),
    ("zeta", "1", "ζ of the re-injection filter (13)"),
    ("mean_square_radius", "1", "spectral radius of the exact mean second-moment step (constant-gain filters; < 1: "
                                "the mean-square error converges)"),
    ("steady_mse", "state²", "exact steady-state network MSE (node average of tr E[e eᵀ]; constant-gain filters)")],
    "Which estimator applies to the link model, and the constant gains it uses.")

GAINS = spec("gains", "entry of a constant-gain filter's gain at a node", [
    _S, _E, ("node", "", "node"), ("row", "", "state index"), ("col", "", "measurement row"),
    ("value", "1", "gain entry ℓ·G_i")])

WEIGHTS = spec("edge_weights", "edge of the graph", [
    _S, ("u", "", "first node"), ("v", "", "second node"),
    ("consensus_weight", "1", "q_uv of the consensus and combination rounds"),
    ("pairwise_weight", "1", "α of the pairwise averaging (6)")])

DETECT = spec("detectability", "node", [
    _S, ("node", "", "node"), ("sensor_type", "", "index into sensors.types"),
    ("locally_detectable", "", "(F, H_i) detectable: the node's own Kalman filter has a bounded error")])

ESTIMATOR_TABLE = spec("estimators", "estimator at the evaluation step", [
    _S, _E, ("label", "", "what the estimator is"), ("step", "", "evaluation step k"),
    ("network_mse", "state²", "node average of E‖x − x̂_i‖²: exact when `exact`, else the Monte Carlo mean"),
    ("exact", "", "network_mse and excess are exact"),
    ("network_mse_mc", "state²", "Monte Carlo node average of ‖x − x̂_i‖²"),
    ("network_mse_mc_se", "state²", "its standard error"),
    ("excess", "state²", "network_mse minus the centralized filter's (= mean-square distance to it)"),
    ("excess_mc", "state²", "Monte Carlo node average of ‖x̂_i − x̂_c‖²"),
    ("excess_mc_se", "state²", "the node average of the nodes' standard errors (an upper bound of its standard error)"),
    ("nees", "1", "Monte Carlo node average of the NEES e_iᵀ P_i⁻¹ e_i with the estimator's own covariance (n when "
                  "consistent); empty when it has none"),
    ("disagreement", "state²", "mean over trials of (1/N) Σ_i ‖x̂_i − mean_j x̂_j‖²"),
    ("messages_per_step", "1", "messages sent per node and step (one message: one node to one neighbour), mean over "
                               "nodes, trials and steps"),
    ("scalars_per_step", "1", "real numbers sent per node and step")],
    "The comparison: error against communication, one row per estimator that runs.")

NODES = spec("nodes", "estimator and node at the evaluation step", [
    _S, _E, ("node", "Int64", "node (empty for the centralized filter)"), ("step", "", "evaluation step k"),
    ("mse_mc", "state²", "Monte Carlo mean of ‖x(k) − x̂_i(k)‖²"), ("mse_mc_se", "state²", "its standard error"),
    ("mse_exact", "state²", "exact E‖x(k) − x̂_i(k)‖² (mean over link patterns); empty without exact moments"),
    ("excess_exact", "state²", "mse_exact minus the centralized filter's exact MSE"),
    ("excess_mc", "state²", "Monte Carlo mean of ‖x̂_i − x̂_c‖², the excess over the centralized filter"),
    ("excess_mc_se", "state²", "its standard error"),
    ("nees_mc", "1", "Monte Carlo mean NEES with the estimator's own covariance"),
    ("nees_lo", "1", f"lower end of the {NEES_BAND:.0%} χ² band of the mean NEES of a consistent filter"),
    ("nees_hi", "1", "upper end of that band"),
    ("disagreement_mc", "state²", "Monte Carlo mean of ‖x̂_i − mean_j x̂_j‖², the node's distance from the network "
                                  "average estimate"),
    ("messages_per_step", "1", "messages sent by the node per step"),
    ("scalars_per_step", "1", "real numbers sent by the node per step")])

SERIES = spec("series", "estimator and recorded step", [
    _S, _E, ("step", "", "time step k"),
    ("network_mse_mc", "state²", "Monte Carlo node average of ‖x − x̂_i‖²"), ("network_mse_mc_se", "state²", "its standard error"),
    ("network_mse_exact", "state²", "exact node average (empty without exact moments)"),
    ("excess_mc", "state²", "node average of the mean ‖x̂_i − x̂_c‖²"),
    ("nees_mc", "1", "node average of the mean NEES with the estimator's own covariance"),
    ("disagreement_mc", "state²", "mean of (1/N) Σ_i ‖x̂_i − mean_j x̂_j‖²"),
    ("disagreement_exact", "state²", "its exact value from the joint recursion of the nodes' errors "
     "(empty without exact moments, or when N n > simulation.exact_max_dimension)")])

TOKEN = spec("token_law", "step of the GIKF token-law comparison", [
    _S, ("step", "", "time step k"), ("trials", "", "trials in each sample"),
    ("median_random_sensor", "state²", "median of tr P̂_q(k), q a uniformly random sensor"),
    ("median_token_chain", "state²", "median of tr P̃(k) of the token chain (20)"),
    ("ks_statistic", "1", "two-sample Kolmogorov-Smirnov distance"), ("p_value", "1", "its p-value")])

METRICS = spec("metrics", "metric of an estimator (network-wide when node is empty)", [
    _S, ("metric", "", "<estimator>.<quantity>: network_mse, excess, nees, disagreement, messages_per_step, "
                       "scalars_per_step, steady_mse"),
    ("node", "", "node (empty: network-wide)"), _E, ("value", "as the quantity", "the value at the evaluation step")])


FAULTS = spec("faults", "plug-in filter that failed", [
    _S, _E, ("what", "", "what it did (one line); its results are left out, the other estimators' numbers are the "
                         "same as without it")],
    "Plug-in filters (dse.plugin) that broke the protocol: raised, returned NaN or a wrong shape, wrote into their "
    "inputs, sent more than they declared, were too slow, or declared matrices that are not theirs.")


def applicability_rows(d: Design) -> list[dict]:
    return [{"scenario": d.scenario.name, "estimator": name, "label": est.spec.title, "applies": est.applies,
             "reason": est.reason, "exact": est.exact, "exact_reason": est.exact_reason if est.applies else "",
             "gain_scale": est.tuning.get("scale", np.nan), "zeta": est.tuning.get("zeta", np.nan),
             "mean_square_radius": est.tuning.get("rho", np.nan), "steady_mse": est.tuning.get("steady_mse", np.nan)}
            for name, est in d.estimators.items()]


def design_tables(d: Design) -> list:
    sc = d.scenario
    out = [(APPLICABILITY, pd.DataFrame(applicability_rows(d), columns=APPLICABILITY.column_names))]
    g = [{"scenario": sc.name, "estimator": name, "node": i, "row": a, "col": b, "value": est.gains[i, a, b]}
         for name, est in d.running.items() if est.gains is not None
         for i, a in np.ndindex(est.gains.shape[:2]) for b in range(d.model.rows[i])]
    out.append((GAINS, pd.DataFrame(g, columns=GAINS.column_names)))
    edges = d.links.topology.edges
    out.append((WEIGHTS, pd.DataFrame({"scenario": sc.name, "u": edges[:, 0], "v": edges[:, 1],
                                       "consensus_weight": d.network.weights, "pairwise_weight": sc.alpha},
                                      columns=WEIGHTS.column_names)))
    out.append((DETECT, pd.DataFrame({"scenario": sc.name, "node": np.arange(sc.N), "sensor_type": list(sc.assign),
                                      "locally_detectable": d.numbers["local_detectable"]}, columns=DETECT.column_names)))
    return out


def _estimator_rows(res, est: str, reference_exact) -> tuple[dict, list, list, list]:
    """The estimator's row of `estimators`, its rows of `nodes` and `series`, and its `metrics`."""
    sc, i, k = res.scenario, res.eval_index, res.scenario.simulation.eval_step
    ref = res.is_reference(est)
    st = res.stats(est)
    W = st.mse.shape[1]
    ex = res.exact_at(est)
    exact = ex is not None
    mse_mc = st.mse[i]
    net_mc, net_se = float(st.network[i]), float(st.network_se[i])
    network = float(ex[i].mean()) if exact else net_mc
    excess = (network - float(reference_exact[k])) if (exact and reference_exact is not None) else \
        (float(st.excess[i].mean()) if st.excess is not None else 0.0 if ref else np.nan)
    exc_mc = float(st.excess[i].mean()) if st.excess is not None else (0.0 if ref else np.nan)
    exc_se = float(np.mean(st.excess_se[i])) if st.excess_se is not None else 0.0
    nees = float(st.nees[i].mean()) if st.nees is not None else np.nan
    msgs, scal = float(st.messages.mean()), float(st.scalars.mean())
    row = {"scenario": sc.name, "estimator": est, "label": res.design.estimators[est].spec.title, "step": k,
           "network_mse": network, "exact": exact, "network_mse_mc": net_mc, "network_mse_mc_se": net_se,
           "excess": excess, "excess_mc": exc_mc, "excess_mc_se": exc_se, "nees": nees,
           "disagreement": float(st.disagreement[i]), "messages_per_step": msgs, "scalars_per_step": scal}
    lo, hi = nees_band(res.trials, res.design.model.n)
    nodes = [{"scenario": sc.name, "estimator": est, "node": (pd.NA if ref else node), "step": k,
              "mse_mc": mse_mc[node], "mse_mc_se": st.mse_se[i, node], "mse_exact": ex[i, node] if exact else np.nan,
              "excess_exact": (ex[i, node] - reference_exact[k]) if (exact and reference_exact is not None) else np.nan,
              "excess_mc": st.excess[i, node] if st.excess is not None else (0.0 if ref else np.nan),
              "excess_mc_se": st.excess_se[i, node] if st.excess_se is not None else 0.0,
              "nees_mc": st.nees[i, node] if st.nees is not None else np.nan, "nees_lo": lo, "nees_hi": hi,
              "disagreement_mc": st.disagreement_node[i, node],
              "messages_per_step": st.messages[node] if not ref else 0.0,
              "scalars_per_step": st.scalars[node] if not ref else 0.0} for node in range(W)]
    dis_ex = res.exact_at(est, "disagreement")
    series = [{"scenario": sc.name, "estimator": est, "step": int(step), "network_mse_mc": st.network[j],
               "network_mse_mc_se": st.network_se[j], "network_mse_exact": ex[j].mean() if exact else np.nan,
               "excess_mc": st.excess[j].mean() if st.excess is not None else (0.0 if ref else np.nan),
               "nees_mc": st.nees[j].mean() if st.nees is not None else np.nan,
               "disagreement_mc": st.disagreement[j], "disagreement_exact": dis_ex[j] if dis_ex is not None else np.nan}
              for j, step in enumerate(res.steps)]
    vals = {"network_mse": network, "excess": excess, "nees": nees, "disagreement": float(st.disagreement[i]),
            "messages_per_step": msgs, "scalars_per_step": scal}
    if est in res.design.gains:
        vals["steady_mse"] = res.design.gains[est]["steady_mse"]
    metrics = [{"scenario": sc.name, "metric": f"{est}.{q}", "node": pd.NA, "estimator": est, "value": v}
               for q, v in vals.items()]
    metrics += [{"scenario": sc.name, "metric": f"{est}.mse", "node": node, "estimator": est,
                 "value": float(ex[i, node] if exact else mse_mc[node])} for node in range(W if not ref else 0)]
    return row, nodes, series, metrics


def _token_rows(res) -> list[dict]:
    """The law of the GIKF's random-sensor covariance against the token chain's, at the token times."""
    rows = []
    for t, (x, y) in enumerate(zip(res.token["gikf"], res.token["chain"])):
        r = ks_test(x, y)
        rows.append({"scenario": res.scenario.name, "step": token_times(res.scenario)[t], "trials": x.size,
                     "median_random_sensor": float(np.median(x)), "median_token_chain": float(np.median(y)),
                     "ks_statistic": float(r.statistic), "p_value": float(r.pvalue)})
    return rows


def run_tables(res) -> list:
    out = design_tables(res.design)
    reference = next((name for name in res.mc if res.is_reference(name)), None)
    reference_exact = res.exact[reference]["mse"][:, 0] if reference in res.exact else None
    est_rows, node_rows, series_rows, metric_rows = [], [], [], []
    for est in res.mc:
        row, nodes, series, metrics = _estimator_rows(res, est, reference_exact)
        est_rows.append(row)
        node_rows += nodes
        series_rows += series
        metric_rows += metrics
    out.append((ESTIMATOR_TABLE, pd.DataFrame(est_rows, columns=ESTIMATOR_TABLE.column_names)))
    out.append((NODES, pd.DataFrame(node_rows, columns=NODES.column_names).astype({"node": "Int64"})))
    out.append((SERIES, pd.DataFrame(series_rows, columns=SERIES.column_names)))
    if "gikf" in res.token and "chain" in res.token:
        out.append((TOKEN, pd.DataFrame(_token_rows(res), columns=TOKEN.column_names)))
    out.append((METRICS, pd.DataFrame(metric_rows, columns=METRICS.column_names).astype({"node": "Int64"})))
    out.append((FAULTS, pd.DataFrame([{"scenario": res.scenario.name, "estimator": e, "what": what}
                                      for e, what in res.faults.items()], columns=FAULTS.column_names)))
    return out
