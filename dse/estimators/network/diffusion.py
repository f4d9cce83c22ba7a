"""The diffusion Kalman filter, adapt then combine (Cattivelli & Sayed 2010, Algorithm 1), `information_fusion`:

    P_i = (P̄_i⁻¹ + S_i)⁻¹,   ψ_i = x̄_i + P_i (ȳ_i − S_i x̄_i),   x̂_i = Σ_{l heard} c_{l,i} ψ_l,

the incremental update in its information form, then the combination with the consensus weights. Its
covariance recursion is the Kalman-consensus filter's (the same S_i): when both run, it reuses that one.
Sends two messages of n numbers per link and direction per step (measurement information, then ψ).
"""
from __future__ import annotations

from dse.estimators.network._information import build, design_on, exact, trialwise
from dse.estimators.protocol import Communication, NetworkEstimator

ESTIMATOR = NetworkEstimator(
    name="diffusion", title="diffusion KF, ATC (Cattivelli & Sayed)", rank=70, exact=exact, cost_weight=17,
    design=lambda est: design_on(est, "diffusion"), shares_with="kcf",
    build=lambda est, B, peers: build(est, B, peers, twin="kcf"), joint_moments=True,
    trialwise_covariance=trialwise, communication=lambda links, n: Communication("step", 2, n))
