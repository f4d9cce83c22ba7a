"""Summary metrics of a coestimation run, for `dse sweep`.

Per deterministic run (``<run>.``: coest, fixed, comparison, ...): the largest estimation
error ‖(x̃_i, w̃_i)‖ over nodes at the end of the horizon, its RMS over the last tenth of the
horizon, and the largest adaptive gain at the end. Per design: the smallest margin of the
LMIs (38)-(39), and the ultimate bound of (18) with its ingredients (μ, q̄) for the single
common P.
"""
from __future__ import annotations

import numpy as np

DESIGN_SCALARS = ("bound18_single", "mu_single", "qbar_single", "lamP_max", "lamP_min")


def metrics(res) -> dict[str, float]:
    out = {k: float(res.design[k]) for k in DESIGN_SCALARS if k in res.design}
    if "lmi_margin" in res.design:
        out["lmi_margin_min"] = float(np.min(res.design["lmi_margin"]))
    for name, arrays in res.runs.items():
        if "e" not in arrays:
            continue
        norm = np.linalg.norm(np.asarray(arrays["e"], float), axis=-1)  # (T, nodes)
        tail = norm[-max(1, len(norm) // 10):]
        out[f"{name}.err_final_max"] = float(norm[-1].max())
        out[f"{name}.err_tail_rms"] = float(np.sqrt(np.mean(tail ** 2)))
        if "g" in arrays:
            out[f"{name}.gain_final_max"] = float(np.max(arrays["g"][-1]))
    return out
