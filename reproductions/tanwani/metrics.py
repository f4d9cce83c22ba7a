"""Summary metrics of a random-comm-filter run, for `dse sweep`.

Per communication rate λ (suffix ``_lam<λ>`` when the scenario has several), from the
gridded Monte Carlo simulation and the moment bounds:

- ``mse_final_mean`` / ``mse_final_max``: tr E[e_i e_iᵀ] at the horizon, mean / max over nodes;
- ``mse_time_avg``: the same averaged over the output grid and the nodes;
- ``bound_final_mean``: the trace of the second-moment bound (ODE (9)) at the horizon, mean over nodes;

and per scenario: ``kb_trP``, the centralized Kalman-Bucy steady-state tr P (the reference),
``abar_abscissa``, the spectral abscissa of the mean error dynamics, and ``crit_bound``,
the critical rate of the bound. Several scenarios (the paper's set) prefix ``<name>.``.
"""
from __future__ import annotations

import numpy as np


def _trace(m: np.ndarray) -> np.ndarray:
    return np.trace(m, axis1=-2, axis2=-1)


def metrics(res) -> dict[str, float]:
    out: dict[str, float] = {}
    many = len(res.scenarios) > 1
    for name, sr in res.scenarios.items():
        pre = f"{name}." if many else ""
        rates = sr.scenario.rates
        for rate in rates:
            suf = "" if len(rates) == 1 else f"_lam{rate:g}"
            mse = sr.grid_moments(rate).trace()[0]  # (T, N): tr E[e_i e_iᵀ] per node
            bound = _trace(sr.bound(rate))  # (T, N)
            out[f"{pre}mse_final_mean{suf}"] = float(mse[-1].mean())
            out[f"{pre}mse_final_max{suf}"] = float(mse[-1].max())
            out[f"{pre}mse_time_avg{suf}"] = float(mse.mean())
            out[f"{pre}bound_final_mean{suf}"] = float(bound[-1].mean())
        out[f"{pre}kb_trP"] = float(np.trace(sr.bounds["P_kb"]))
        out[f"{pre}abar_abscissa"] = float(sr.bounds["abar_abscissa"])
        out[f"{pre}crit_bound"] = float(sr.bounds["crit_bound"])
    return out
