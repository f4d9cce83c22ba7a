"""The Kalman-consensus filter (Olfati-Saber 2007, Table 1; 2009, Algorithm 1), `information_fusion`:

    M_i = (P̄_i⁻¹ + S_i)⁻¹,   x̂_i = x̄_i + M_i (ȳ_i − S_i x̄_i) + γ_i M_i Σ_{j heard} (x̄_j − x̄_i),
    γ_i = ε / (1 + ‖M_i‖_F),  S_i, ȳ_i the information of node i and the neighbours it heard.

Each node sends (u_i, x̄_i), 2n numbers, to its neighbours once per step (U_i is constant and sent once).
Exact moments on reliable links; ε is `weights.kcf_epsilon`.
"""
from __future__ import annotations

from dse.estimators.network._information import build, design_on, exact, trialwise
from dse.estimators.protocol import Communication, NetworkEstimator


def design(est) -> None:
    design_on(est, "kalman-consensus", est.network.scenario.weights.kcf_epsilon)


ESTIMATOR = NetworkEstimator(
    name="kcf", title="Kalman-consensus (Olfati-Saber)", rank=60, design=design, exact=exact, cost_weight=36,
    build=build, joint_moments=True, trialwise_covariance=trialwise,
    communication=lambda links, n: Communication("step", 1, 2 * n))
