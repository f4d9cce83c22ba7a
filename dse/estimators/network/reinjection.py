"""Savas, Srivastava & Leonard's re-injection filter (2017), (11)-(13), in vector form (`constant_gain_fusion`,
rule "reinjection"): after the local correction x̂(k|k), `links.rounds` rounds z ← W z + x̂(k|k) (+ σ_c u)
from z = x̂(k|k), and the fused estimate ζ x̂(k|k) + (1 − ζ) z / (m + 1).

(ℓ, ζ) are tuned jointly for the exact steady state when both are "optimal" (Savas et al. §V-B: coordinate
search from ζ = 1, the same local filters without fusion, so never worse than not communicating); either one
alone when the other is given. Synchronous rounds only; sends n numbers per working link, round and direction.
"""
from __future__ import annotations

import numpy as np

from dse.estimators.network._constant_gain import (base_gains, build, communication, exact, finish, fusion_filter,
                                                   search_grid, synchronous_only)
from dse.estimators.network.carli import tuned_scale as carli_scale
from dse.estimators.protocol import NetworkEstimator


def _search(net, G: np.ndarray) -> tuple[float, float]:
    """(ℓ, ζ) from `gains.reinjection_scale` and `gains.reinjection_zeta` (numbers, or optimal); an optimal
    scale starts from Carli's."""
    from dse.estimators.constant_gain_fusion import steady_state, tune_reinjection, tune_scale

    g = net.scenario.gains
    grid, iters = search_grid(net)
    ell0 = carli_scale(net) if g.reinjection_scale == "optimal" else float(g.reinjection_scale)
    if not np.isfinite(ell0):
        ell0 = 1.0
    f = fusion_filter(net, "reinjection", 1.0, tuning=True)
    if g.reinjection_scale == "optimal" and g.reinjection_zeta == "optimal":
        ell, zeta, _ = tune_reinjection(f, G, ell0=ell0, sweeps=1 if net.quick else 2,
                                        zeta_grid=5 if net.quick else 11, iters=iters)
        return ell, zeta
    if g.reinjection_zeta == "optimal":
        zs = np.linspace(0, 1, 11)
        vals = [steady_state(f.with_gains(ell0 * G, z), radius=False)["network"] for z in zs]
        return ell0, float(zs[int(np.argmin(vals))])
    if g.reinjection_scale == "optimal":
        zeta = float(g.reinjection_zeta)
        ell, _ = tune_scale(fusion_filter(net, "reinjection", 1.0, zeta, tuning=True), G, grid=grid, iters=iters)
        return ell, zeta
    return ell0, float(g.reinjection_zeta)


def design(est) -> None:
    net = est.network
    G, why = base_gains(net)
    if G is None:
        est.reason = why
        return
    if "reinjection_scale" not in net.tuned:
        net.tuned["reinjection_scale"], net.tuned["reinjection_zeta"] = _search(net, G)
    finish(est, "reinjection", net.tuned["reinjection_scale"], net.tuned["reinjection_zeta"])


ESTIMATOR = NetworkEstimator(
    name="reinjection", title="re-injection (Savas et al.)", rank=40, applies=synchronous_only, design=design,
    build=build, exact=exact, communication=communication, joint_moments=True)
