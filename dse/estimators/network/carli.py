"""Carli, Chiuso, Schenato & Zampieri's two-stage consensus filter (2008), as written by Savas, Srivastava &
Leonard (2017), (7)-(9), in vector form (`constant_gain_fusion`, rule "consensus"):

    x̂_i(k|k) = x̄_i + ℓ G_i (y_i − H_i x̄_i),   then `links.rounds` rounds z ← W z (+ σ_c u) from z = x̂(k|k),

the fused estimate is z and x̄_i ← F z_i. ℓ (`gains.carli_scale`) minimises the exact steady-state network
MSE when "optimal", as Carli et al. tune their gain. Synchronous rounds only. Sends n numbers per working
link, round and direction.
"""
from __future__ import annotations

from dse.estimators.network._constant_gain import (base_gains, build, communication, exact, finish, fusion_filter,
                                                   search_grid, synchronous_only)
from dse.estimators.protocol import NetworkEstimator


def tuned_scale(net) -> float:
    """ℓ: `gains.carli_scale`, or (optimal) the scale of least exact steady-state network MSE."""
    if "carli_scale" not in net.tuned:
        setting = net.scenario.gains.carli_scale
        if setting == "optimal":
            from dse.estimators.constant_gain_fusion import tune_scale

            grid, iters = search_grid(net)
            net.tuned["carli_scale"], _ = tune_scale(fusion_filter(net, "consensus", 1.0, tuning=True),
                                                     base_gains(net)[0], grid=grid, iters=iters)
        else:
            net.tuned["carli_scale"] = float(setting)
    return net.tuned["carli_scale"]


def design(est) -> None:
    """The tuned filter, and the steady state of the same gains without fusion (ζ = 1 of the re-injection
    filter): whether communication helps it (`compare.hyp.carli_noise_dominated`)."""
    from dse.estimators.constant_gain_fusion import steady_state

    net = est.network
    G, why = base_gains(net)
    if G is None:
        est.reason = why
        return
    scale = tuned_scale(net)
    finish(est, "consensus", scale)
    if est.applies and "carli_local_steady" not in net.tuned:
        quiet = fusion_filter(net, "reinjection", scale, 1.0, tuning=True)
        net.tuned["carli_local_steady"] = steady_state(quiet, radius=False)["network"]


ESTIMATOR = NetworkEstimator(
    name="carli", title="two-stage consensus (Carli et al.)", rank=30, applies=synchronous_only, design=design,
    build=build, exact=exact, communication=communication, joint_moments=True)
