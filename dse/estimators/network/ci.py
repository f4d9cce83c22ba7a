"""Consensus on information (Battistelli & Chisci 2014), `information_fusion`: information pairs
(Ω_i, q_i = Ω_i x̂_i), corrected locally (Ω_i ← Ω̄_i + U_i, q_i ← q̄_i + u_i), averaged over `links.rounds`
consensus rounds (Ω_i, q_i) ← Σ_j π_ij (Ω_j, q_j) (pairwise at each Poisson exchange), then predicted.
A convex combination of information pairs is a covariance intersection: with noiseless links
E[e_i e_iᵀ] ⪯ Ω_i⁻¹ (the `compare.ci.conservative.*` claims). Sends the pair, n + n(n+1)/2 numbers, per
link, round and direction.
"""
from __future__ import annotations

from dse.estimators.network._information import build, design_on, exact, trialwise
from dse.estimators.protocol import Communication, NetworkEstimator

ESTIMATOR = NetworkEstimator(
    name="ci", title="consensus on information (Battistelli & Chisci)", rank=80, exact=exact, cost_weight=37,
    design=lambda est: design_on(est, "information-consensus"), per_exchange=True, joint_moments=True,
    build=build, trialwise_covariance=trialwise,
    communication=lambda links, n: Communication("rounds", 1, n + n * (n + 1) // 2))
