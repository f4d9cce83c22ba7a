"""What the three constant-gain filters (carli, reinjection, pairwise) share: node i corrects its prediction
with ℓ·G_i (`constant_gain_fusion`), G_i the base gain and ℓ the filter's scale, then fuses.

Base gains (`[gains] base`): Tanwani's split (7), G_i = N K_i, the centralized steady-state Kalman gain cut
by each node's columns (it needs the stabilising Riccati solution), or given per sensor type. Scales are
tuned on the exact steady state of the mean second-moment recursion; with random matchings, whose edges are
dependent, that recursion has no closed form here and the steady states are computed on independent link
failures of the same mean activity (the `surrogate` of the applicability table).
"""
from __future__ import annotations

import numpy as np

from dse.estimators.protocol import Communication

#: exact Poisson-exchange moments compose the one-exchange map up to the truncated count: skip beyond this cost
POISSON_EXACT_BUDGET = 3e10
#: samples of random matchings behind the surrogate's mean link activity (fixed seed)
MATCHING_SAMPLES = 20_000


def synchronous_only(links) -> str:
    if links.synchronous:
        return ""
    return ("its consensus rounds are synchronous; Poisson-clocked links exchange one pair at a time (the "
            "asynchronous pairwise version is Tanwani's filter)")


def communication(links, n: int) -> Communication:
    """n numbers per working link, round (or exchange) and direction."""
    return Communication("rounds", 1, n)


def base_gains(net) -> tuple[np.ndarray | None, str]:
    """(N, n, m) base gains G_i, or None and why they do not exist (computed once per design)."""
    if "base_gains" not in net.shared:
        net.shared["base_gains"] = _base_gains(net.scenario, net.model)
    return net.shared["base_gains"]


def _base_gains(sc, model) -> tuple[np.ndarray | None, str]:
    from dse.estimators.sensor_network import split_gains

    if sc.gains.base == "given":
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


def tuning_links(net):
    """The links the steady states are computed on: the scenario's own, except for random matchings: there,
    independent link failures with the same mean activity (the probability that an edge is in the matching
    and works, estimated from MATCHING_SAMPLES matchings drawn with a fixed seed)."""
    from dse.estimators.link_models import LinkModel, greedy_matching

    lm = net.links
    if lm.kind != "matchings":
        return lm
    if "tuning_links" not in net.shared:
        chosen = greedy_matching(lm.topology, np.random.default_rng(0).random((lm.topology.E, MATCHING_SAMPLES)))
        activity = float(chosen.mean()) * (1.0 - lm.p_fail)
        net.shared["tuning_links"] = LinkModel(lm.topology, "failures", rounds=lm.rounds, p_fail=1.0 - activity,
                                               noise_std=lm.noise_std)
    return net.shared["tuning_links"]


def fusion_filter(net, rule: str, scale: float, zeta: float = 1.0, *, tuning: bool = False):
    """The `FusionFilter` with gains scale·G (pairwise: Tanwani's weight α on every link), on the scenario's
    links or (`tuning`) on those the steady states are computed on."""
    from dse.estimators.constant_gain_fusion import FusionFilter

    weights = np.full(net.links.topology.E, net.scenario.alpha) if rule == "pairwise" else net.weights
    return FusionFilter(net.model, tuning_links(net) if tuning else net.links, scale * base_gains(net)[0], weights,
                        rule, zeta)


def search_grid(net) -> tuple[int, int]:
    """(log-grid points, golden-section iterations) of a scale search: coarser in quick runs."""
    return (7, 6) if net.quick else (17, 18)


def finish(est, rule: str, scale: float, zeta: float = 1.0) -> None:
    """Design `est` as the filter `rule` with gains scale·G: its exact steady state, its gains, and whether its
    exact moments are computed. The one applicability rule of the constant-gain filters: the mean-square error
    recursion with the gains it runs with (given, or tuned) must be stable, i.e. have a steady state, computed
    on the links the steady states are computed on (`steady_state`: ρ < 1 exactly on reliable links, a
    certified positive solution on random ones, where the estimate of ρ can read 1 + 1e-16); otherwise (or when
    no scale was found) it is not applicable, with ρ in the reason (the `applicability` table keeps ρ, the
    scale and ζ)."""
    from dse.estimators.constant_gain_fusion import steady_state

    net = est.network
    if not np.isfinite(scale):
        est.reason = "no gain scale makes its mean-square error recursion stable"
        return
    f = fusion_filter(net, rule, scale, zeta)
    steady, rho = f"{est.name}_steady", f"{est.name}_rho"
    if steady not in net.tuned:
        ss = steady_state(fusion_filter(net, rule, scale, zeta, tuning=True))
        net.tuned[steady], net.tuned[rho] = ss["network"], ss["rho"]
    est.tuning = {"scale": float(scale), "zeta": float(zeta), "rho": float(net.tuned[rho]),
                  "steady_mse": float(net.tuned[steady]), "surrogate": net.links.kind == "matchings"}
    if not np.isfinite(net.tuned[steady]):
        est.reason = (f"its mean-square error recursion is unstable with the gains it would run with (ℓ = {scale:.4g}"
                      + (f", ζ = {zeta:.4g}" if rule == "reinjection" else "")
                      + f"): no steady state, spectral radius {net.tuned[rho]:.4g}")
        return
    est.config, est.gains = f, f.gains
    est.exact_reason = _exact_reason(f, net)


def _exact_reason(f, net) -> str:
    ok, why = f.exact_available
    if not ok:
        return why
    if net.joint_size_reason():
        return net.joint_size_reason()
    lm, Nn = net.links, net.model.N * net.model.n
    cost = lm.max_events * net.steps * (Nn ** 2) * net.model.N
    if not lm.synchronous and cost > POISSON_EXACT_BUDGET:
        return (f"the mean over Poisson exchanges composes the one-exchange map up to {lm.max_events} times per step; "
                f"≈{cost:.2g} operations over the horizon (Monte Carlo only)")
    return ""


def build(est, B: int, peers):
    from dse.estimators.constant_gain_fusion import FusionRun

    return FusionRun(est.config, B)


def exact(est, n_steps: int) -> dict[str, np.ndarray]:
    from dse.estimators.constant_gain_fusion import exact_moments

    return exact_moments(est.config, n_steps)
