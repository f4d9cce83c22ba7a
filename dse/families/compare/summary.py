"""Estimates from the folded Monte Carlo sums and the exact moments, per estimator, node and step.

Every Monte Carlo mean comes with its standard error (the sample standard deviation over trials
divided by √trials); a NEES mean with its χ² band: if the estimator's covariance is the covariance
of its Gaussian error, the sum of B independent NEES values is χ²(B n), so the mean lies in
[χ²_{Bn}(α/2), χ²_{Bn}(1 − α/2)] / B with probability 1 − α.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

NEES_BAND = 0.99


@dataclass
class Stats:
    """(S, W) arrays at the recorded steps (W = N nodes, 1 for the centralized filter)."""

    mse: np.ndarray
    mse_se: np.ndarray
    excess: np.ndarray | None
    excess_se: np.ndarray | None
    cross: np.ndarray | None
    cross_se: np.ndarray | None
    nees: np.ndarray | None
    nees_se: np.ndarray | None
    disagreement: np.ndarray           # (S,)
    disagreement_se: np.ndarray
    disagreement_node: np.ndarray      # (S, W) mean of ‖x̂_i − mean_j x̂_j‖²
    network: np.ndarray                # (S,) node average of the MSE
    network_se: np.ndarray
    messages: np.ndarray               # (N,) per node and step
    scalars: np.ndarray


def _mean_se(s1, s2, B):
    with np.errstate(invalid="ignore", over="ignore"):      # a diverging filter's sums may be infinite
        mean = s1 / B
        var = np.maximum(s2 / B - mean * mean, 0.0)
        return mean, np.sqrt(var * B / max(B - 1, 1) / B)


def stats(res, est: str) -> Stats:
    s = res.mc[est]
    B, K = res.trials, res.scenario.steps
    mse, mse_se = _mean_se(s["sq"], s["sq2"], B)
    excess = excess_se = cross = cross_se = None
    if "dist" in s and est != "central":
        excess, excess_se = _mean_se(s["dist"], s["dist2"], B)
        cross, cross_se = _mean_se(s["cross"], s["cross2"], B)
    nees = nees_se = None
    if np.any(s["nees"] != 0):
        nees, nees_se = _mean_se(s["nees"], s["nees2"], B)
    dis, dis_se = _mean_se(s["dis"], s["dis2"], B)
    net, net_se = _mean_se(s["net"], s["net2"], B)
    return Stats(mse, mse_se, excess, excess_se, cross, cross_se, nees, nees_se, dis, dis_se, s["dis_node"] / B,
                 net, net_se,
                 s["msgs"] / (B * K), s["scalars"] / (B * K))


def nees_band(trials: int, n: int, level: float = NEES_BAND) -> tuple[float, float]:
    from scipy.stats import chi2

    a = (1 - level) / 2
    return float(chi2.ppf(a, trials * n) / trials), float(chi2.ppf(1 - a, trials * n) / trials)


def exact_mse(res, est: str) -> np.ndarray | None:
    """(K, W) exact mean-square error per node, or None."""
    ex = res.exact.get(est)
    return None if ex is None else ex["mse"]


def exact_at(res, est: str) -> np.ndarray | None:
    """(S, W) exact mean-square error at the recorded steps."""
    m = exact_mse(res, est)
    return None if m is None else m[res.steps]


def central_exact_at(res) -> np.ndarray:
    return res.exact["central"]["mse"][res.steps][:, 0]


def best_mse(res, est: str) -> tuple[np.ndarray, bool]:
    """(S, W) MSE: exact when the estimator has exact moments, else the Monte Carlo mean."""
    ex = exact_at(res, est)
    return (ex, True) if ex is not None else (stats(res, est).mse, False)


def exact_disagreement_at(res, est: str) -> np.ndarray | None:
    ex = res.exact.get(est)
    if ex is None or "disagreement" not in ex:
        return None
    return ex["disagreement"][res.steps]
