"""Summary metrics of a gossip-kalman (GIKF) run, for `dse sweep`.

From the sensors' conditional error covariances P_n(t) at the last recorded slot, over all
runs and sensors: the median and the 90 % quantile of log tr P (quantiles, not means: the
invariant law μ can have an infinite mean); the centralized filter's steady-state log tr P
(the reference every sensor's P dominates); the second largest eigenvalue modulus of the
mean adjacency Ā (how fast gossip mixes) and the assumption checks C.1 and D.1 as 0/1.
Several scenarios (the paper's set) prefix ``<scenario>.``.
"""
from __future__ import annotations

import numpy as np

import estimators.gossip_kalman as gk

LOG_TRACE = gk.FEATURES.index("log_trace")


def _one(sr) -> dict[str, float]:
    log_tr = np.asarray(sr.gikf["feat_n"], float)[-1, LOG_TRACE]  # (runs, sensors) at the last recorded slot
    finite = log_tr[np.isfinite(log_tr)]
    return {"median_log_trP": float(np.median(finite)) if finite.size else float("inf"),
            "q90_log_trP": float(np.quantile(finite, 0.9)) if finite.size else float("inf"),
            "nonfinite_fraction": float(1.0 - finite.size / log_tr.size),
            "central_log_trP": (float(np.log(np.trace(sr.bounds["P_central_inf"]))) if "P_central_inf" in sr.bounds
                                else float("nan")),  # no limit where (F, C_all) is not detectable
            "slem": float(sr.bounds["slem"]), "c1": float(sr.c1), "d1": float(sr.d1)}


def metrics(res) -> dict[str, float]:
    if len(res.scenarios) == 1:
        return _one(next(iter(res.scenarios.values())))
    return {f"{name}.{k}": v for name, sr in res.scenarios.items() for k, v in _one(sr).items()}
