"""The deterministic design of a compare scenario: the model, the link model, every estimator that
applies (or why not), the constant gains (tuned where asked), mean-square stability, steady
states, and the quantities the hypotheses are decided by (detectability, the GIKF's mean
communication). No Monte Carlo: `dse check` computes it alone.

Which estimator applies to which link model (the design note of the family):

| estimator | reliable | failures | matchings | poisson | exact moments |
|---|---|---|---|---|---|
| centralized KF, local KFs | yes | yes | yes | yes | always |
| GIKF | random maximal matching of the graph | of the working links | the model's | exchanges in order | given the swap path |
| Carli, re-injection | yes | yes | yes | no: synchronous rounds | reliable, failures |
| pairwise averaging | yes | yes | yes | yes | reliable, failures, poisson |
| Kalman-consensus, diffusion, CI | yes | yes | yes | yes | reliable |

Constant-gain filters also need base gains: the split rule needs the centralized filter's
stabilising Riccati solution (collective detectability and stabilisability).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from dse.estimators.constant_gain_fusion import FusionFilter, steady_state, tune_reinjection, tune_scale
from dse.estimators.information_fusion import InformationFilter
from dse.estimators.link_models import LinkModel, Topology, greedy_matching
from dse.estimators.sensor_network import SensorNetworkModel, detectable, observable, split_gains

from .scenario import ESTIMATORS, LABELS, CompareScenario

FUSION = ("carli", "reinjection", "pairwise")
INFORMATION = {"kcf": "kalman-consensus", "diffusion": "diffusion", "ci": "information-consensus"}
#: exact Poisson-exchange moments compose the one-exchange map up to the truncated count: skip beyond this cost
POISSON_EXACT_BUDGET = 3e10


@dataclass
class Design:
    scenario: CompareScenario
    model: SensorNetworkModel
    topology: Topology
    links: LinkModel
    weights: np.ndarray
    estimators: dict[str, Any] = field(default_factory=dict)       # id -> kind for the simulation
    status: dict[str, tuple[bool, str]] = field(default_factory=dict)   # id -> (applies, reason)
    exact: dict[str, tuple[bool, str]] = field(default_factory=dict)    # id -> (exact moments, reason)
    gains: dict[str, dict[str, float]] = field(default_factory=dict)    # id -> scale, zeta, rho, steady
    base_gains: np.ndarray | None = None
    base_error: str = ""
    numbers: dict[str, Any] = field(default_factory=dict)               # hypothesis numbers


def build_model(sc: CompareScenario) -> SensorNetworkModel:
    H = [sc.H_types[t] for t in sc.assign]
    R = [sc.R_types[t] for t in sc.assign]
    return SensorNetworkModel.build(sc.F, sc.Q, H, R, sc.P0, sc.x0)


def build_links(sc: CompareScenario) -> LinkModel:
    topo = Topology.from_edges(sc.N, list(sc.graph.build().edges()))
    return LinkModel(topo, sc.link_model, rounds=sc.rounds, p_fail=sc.p_fail, rate=sc.rate, noise_std=sc.noise_std)


def edge_weights(sc: CompareScenario, topo: Topology) -> np.ndarray:
    return topo.metropolis_weights() if sc.weights_kind == "metropolis" else np.full(topo.E, sc.eps)


def base_gains(sc: CompareScenario, model: SensorNetworkModel) -> tuple[np.ndarray | None, str]:
    if sc.gain_base == "given":
        G = np.zeros((model.N, model.n, model.m))
        for i, t in enumerate(sc.assign):
            K = sc.given_gains[t]
            G[i, :, :K.shape[1]] = K
        return G, ""
    try:
        G = split_gains(model)
    except (np.linalg.LinAlgError, ValueError) as exc:
        return None, f"the split gains need the centralized filter's stabilising Riccati solution ({exc})"
    if not np.all(np.isfinite(G)):
        return None, "the split gains need the centralized filter's stabilising Riccati solution (not finite)"
    return G, ""


def design(sc: CompareScenario, quick: bool, tuned: dict[str, float] | None = None) -> Design:
    """The design; `tuned` (from the stage cache) skips the gain searches."""
    model = build_model(sc)
    links = build_links(sc)
    topo = links.topology
    w = edge_weights(sc, topo)
    d = Design(sc, model, topo, links, w)
    G, err = base_gains(sc, model)
    d.base_gains, d.base_error = G, err
    Nn = model.N * model.n
    too_big = Nn > sc.exact_max_dimension
    big_reason = (f"the joint recursion is (N n)² = {Nn}² entries per step, beyond simulation.exact_max_dimension = "
                  f"{sc.exact_max_dimension} (Monte Carlo only)")
    for est in ESTIMATORS:
        if est not in sc.include:
            d.status[est] = (False, "not requested (dse.estimators.include)")
            continue
        d.status[est] = (True, "")
        if est in ("central", "local"):
            d.estimators[est] = est
            d.exact[est] = (True, "")
        elif est == "gikf":
            d.estimators[est] = "gossip"
            d.exact[est] = (False, "its covariance is exact given the swap path (the NEES law checks it trial by "
                                   "trial); the mean over swap paths has no closed form (Monte Carlo)")
        elif est in FUSION:
            if est != "pairwise" and not links.synchronous:
                d.status[est] = (False, "its consensus rounds are synchronous; Poisson-clocked links exchange one "
                                        "pair at a time (the asynchronous pairwise version is Tanwani's filter)")
                continue
            if G is None:
                d.status[est] = (False, err)
                continue
            d.estimators[est] = None      # filled after tuning
        else:
            f = InformationFilter(model, links, INFORMATION[est], w, sc.kcf_epsilon)
            d.estimators[est] = f
            ok, why = f.exact_available
            d.exact[est] = (ok and not too_big, why if not ok else big_reason if too_big else "")
    _tune(d, quick, tuned)
    _hypothesis_numbers(d)
    return d


def _fusion(d: Design, rule: str, scale: float, zeta: float = 1.0, *, tuning: bool = False) -> FusionFilter:
    w = np.full(d.topology.E, d.scenario.alpha) if rule == "pairwise" else d.weights
    links = d.numbers.get("tuning_links", d.links) if tuning else d.links
    return FusionFilter(d.model, links, scale * d.base_gains, w, rule, zeta)


def _tuning_links(d: Design) -> LinkModel:
    """The links the steady states are computed on: the scenario's own, except for random matchings,
    whose dependent edges have no closed-form mean recursion: there, independent link failures with
    the same mean activity (the probability that an edge is in the matching and works, estimated from
    20,000 matchings drawn with a fixed seed)."""
    lm = d.links
    if lm.kind != "matchings":
        return lm
    rng = np.random.default_rng(0)
    chosen = greedy_matching(lm.topology, rng.random((lm.topology.E, 20_000)))
    activity = float(chosen.mean()) * (1.0 - lm.p_fail)
    d.numbers["matching_activity"] = activity
    return LinkModel(lm.topology, "failures", rounds=lm.rounds, p_fail=1.0 - activity, noise_std=lm.noise_std)


def _tune(d: Design, quick: bool, tuned: dict[str, float] | None) -> None:
    sc = d.scenario
    tuned = dict(tuned or {})
    d.numbers["tuning_links"] = _tuning_links(d)
    grid, iters = (7, 6) if quick else (17, 18)
    plan = [e for e in FUSION if e in d.estimators and d.estimators[e] is None]
    if "carli" in plan or "reinjection" in plan:
        if "carli_scale" not in tuned:
            if sc.carli_scale == "optimal":
                tuned["carli_scale"], _ = tune_scale(_fusion(d, "consensus", 1.0, tuning=True), d.base_gains, grid=grid,
                                                   iters=iters)
            else:
                tuned["carli_scale"] = float(sc.carli_scale)
    if "reinjection" in plan and "reinjection_scale" not in tuned:
        ell0 = tuned["carli_scale"] if sc.reinjection_scale == "optimal" else float(sc.reinjection_scale)
        if not np.isfinite(ell0):
            ell0 = 1.0
        f = _fusion(d, "reinjection", 1.0, tuning=True)
        if sc.reinjection_scale == "optimal" and sc.reinjection_zeta == "optimal":
            tuned["reinjection_scale"], tuned["reinjection_zeta"], _ = tune_reinjection(
                f, d.base_gains, ell0=ell0, sweeps=1 if quick else 2, zeta_grid=5 if quick else 11, iters=iters)
        elif sc.reinjection_zeta == "optimal":
            zs = np.linspace(0, 1, 11)
            vals = [steady_state(f.with_gains(ell0 * d.base_gains, z), radius=False)["network"] for z in zs]
            tuned["reinjection_scale"], tuned["reinjection_zeta"] = ell0, float(zs[int(np.argmin(vals))])
        elif sc.reinjection_scale == "optimal":
            zeta = float(sc.reinjection_zeta)
            ell, _ = tune_scale(_fusion(d, "reinjection", 1.0, zeta, tuning=True), d.base_gains, grid=grid,
                                iters=iters)
            tuned["reinjection_scale"], tuned["reinjection_zeta"] = ell, zeta
        else:
            tuned["reinjection_scale"], tuned["reinjection_zeta"] = ell0, float(sc.reinjection_zeta)
    specs = {"carli": ("consensus", "carli_scale", None), "reinjection": ("reinjection", "reinjection_scale",
                                                                          "reinjection_zeta"),
             "pairwise": ("pairwise", None, None)}
    for est in plan:
        rule, skey, zkey = specs[est]
        scale = tuned[skey] if skey else sc.pairwise_scale
        zeta = tuned[zkey] if zkey else 1.0
        if not np.isfinite(scale):
            d.status[est] = (False, "no gain scale makes its mean-square error recursion stable")
            d.estimators.pop(est)
            continue
        f = _fusion(d, rule, scale, zeta)
        d.estimators[est] = f
        key = f"{est}_steady"
        if key not in tuned:
            ss = steady_state(_fusion(d, rule, scale, zeta, tuning=True))
            tuned[key], tuned[f"{est}_rho"] = ss["network"], ss["rho"]
        d.gains[est] = {"scale": float(scale), "zeta": float(zeta), "rho": float(tuned[f"{est}_rho"]),
                        "steady_mse": float(tuned[key]), "surrogate": d.links.kind == "matchings"}
        ok, why = f.exact_available
        Nn = d.model.N * d.model.n
        if ok and Nn > sc.exact_max_dimension:
            ok, why = False, (f"the joint recursion is (N n)² = {Nn}² entries per step, beyond "
                              f"simulation.exact_max_dimension = {sc.exact_max_dimension} (Monte Carlo only)")
        if ok and not d.links.synchronous:
            cost = d.links.max_events * sc.steps * (Nn ** 2) * d.model.N
            if cost > POISSON_EXACT_BUDGET:
                ok, why = False, (f"the mean over Poisson exchanges composes the one-exchange map up to "
                                  f"{d.links.max_events} times per step; ≈{cost:.2g} operations over the horizon "
                                  "(Monte Carlo only)")
        d.exact[est] = (ok, why)
    if "carli" in d.estimators:
        quiet = _fusion(d, "reinjection", tuned["carli_scale"], 1.0, tuning=True)     # the same gains, no fusion
        if "carli_local_steady" not in tuned:
            tuned["carli_local_steady"] = steady_state(quiet, radius=False)["network"]
    d.numbers["tuned"] = tuned


def tuned_arrays(d: Design) -> dict[str, np.ndarray]:
    return {k: np.array(float(v)) for k, v in d.numbers["tuned"].items()}


def steady_is_exact(d: Design) -> bool:
    """The steady states are the scenario's own (not the matching surrogate's)."""
    return d.links.kind != "matchings"


# -- hypotheses' numbers ----------------------------------------------------------------------------------

def _stabilizable(F: np.ndarray, Q: np.ndarray) -> bool:
    lam, V = np.linalg.eigh(0.5 * (Q + Q.T))
    half = V * np.sqrt(np.maximum(lam, 0))
    return detectable(F.T, half.T)


def _self_loop_witness(topo: Topology, links: LinkModel) -> tuple[bool | None, str]:
    """Can a node keep its state in a step (a diagonal entry of the GIKF's mean permutation)?"""
    if links.kind == "poisson":
        return True, "with positive probability no link of a node rings in a step"
    if links.kind in ("failures", "matchings") and links.p_fail > 0:
        return True, "with positive probability every link of a node fails"
    rng = np.random.default_rng(0)
    for _ in range(200):      # a maximal matching that leaves some node unmatched (greedy from random orders)
        chosen = greedy_matching(topo, rng.random((topo.E, 1)))[:, 0]
        covered = (topo.node_edges[:, chosen]).any(axis=1)
        if not covered.all():
            return True, f"the maximal matching {topo.edges[chosen].tolist()} leaves node {int(np.argmin(covered))} alone"
    return None, "no maximal matching leaving a node unmatched was found in 200 random orders"


def _hypothesis_numbers(d: Design) -> None:
    m, topo, links = d.model, d.topology, d.links
    num = d.numbers
    num["local_detectable"] = m.locally_detectable()
    num["collective_detectable"] = m.collectively_detectable()
    num["collective_observable"] = observable(m.F, m.H_all)
    num["stabilizable"] = _stabilizable(m.F, m.Q)
    # C.1: the token moves along edges of the graph (every edge can be swapped over) and stays put with
    # positive probability when the link model allows it; irreducible iff the graph is connected (it is).
    loops, why = _self_loop_witness(topo, links)
    bip = topo.is_bipartite()
    num["c1"] = True if (not bip or loops) else (None if loops is None else False)
    num["c1_detail"] = ("the graph is connected (irreducible) and " +
                        ("has an odd cycle (aperiodic)" if not bip else f"bipartite; self-loops: {why}"))
    num["self_loops"] = loops
    # D.1: a covering walk (depth-first, with backtracking), staying n steps at each node when self-loops
    # are possible, repeated n times; its Gramian Σ F^{iT} H_{w_i}ᵀ H_{w_i} F^i.
    walk = _covering_walk(topo, stay=m.n if loops else 1) * m.n
    Gram = np.zeros((m.n, m.n))
    Fi = np.eye(m.n)
    for node in walk:
        Hf = m.H[node] @ Fi
        Gram += Hf.T @ Hf
        Fi = m.F @ Fi
        if np.abs(Fi).max() > 1e150:
            break
    ev = np.linalg.eigvalsh(0.5 * (Gram + Gram.T))
    ratio = ev[0] / max(ev[-1], 1e-300)
    num["d1_ratio"] = float(ratio)
    num["d1_walk_length"] = len(walk)
    if ratio > 1e-10:
        num["d1"] = True
    elif not num["collective_observable"]:
        num["d1"] = False
    else:
        num["d1"] = None


def _covering_walk(topo: Topology, stay: int) -> list[int]:
    nb = topo.neighbours()
    seen, walk = set(), []

    def visit(i):
        seen.add(i)
        walk.extend([i] * stay)
        for j in sorted(nb[i]):
            if j not in seen:
                visit(j)
                walk.append(i)

    visit(0)
    return walk


def applicability_rows(d: Design) -> list[dict[str, Any]]:
    rows = []
    for est in ESTIMATORS:
        ok, why = d.status[est]
        ex, exwhy = d.exact.get(est, (False, ""))
        g = d.gains.get(est, {})
        rows.append({"estimator": est, "label": LABELS[est], "applies": ok, "reason": why,
                     "exact": bool(ok and ex), "exact_reason": exwhy if ok else "",
                     "gain_scale": g.get("scale", np.nan), "zeta": g.get("zeta", np.nan),
                     "mean_square_radius": g.get("rho", np.nan), "steady_mse": g.get("steady_mse", np.nan)})
    return rows
