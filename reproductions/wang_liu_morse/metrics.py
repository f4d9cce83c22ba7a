"""Summary metrics of a hybrid-observer run, for `dse sweep`.

Per simulated run (``<run>.``, e.g. ``sync.``): the largest and the median estimation error
‖x̂_i − x‖ over agents and trials at the end of the run, and the ratio of the largest error
at the end to the largest at the start (the contraction the design achieves). Per design:
ρ of (17), the event count q of (22) and of (27), and σ (the mixing bound). Several scenarios
(the paper's set) prefix ``<scenario>.``.
"""
from __future__ import annotations

import numpy as np

DESIGN_SCALARS = ("rho", "q_thm22", "q27", "q_minimal", "sigma")


def _one(res) -> dict[str, float]:
    out = {k: float(res.design[k]) for k in DESIGN_SCALARS if k in res.design}
    for name, arrays in res.runs.items():
        err = np.asarray(arrays["err"], float)  # (T, trials, agents)
        out[f"{name}.err_final_max"] = float(err[-1].max())
        out[f"{name}.err_final_median"] = float(np.median(err[-1]))
        start = float(err[0].max())
        out[f"{name}.err_ratio"] = float(err[-1].max() / start) if start > 0 else float("nan")
    return out


def metrics(res) -> dict[str, float]:
    parts = res.parts
    if len(parts) == 1:
        return _one(next(iter(parts.values())))
    return {f"{key}.{k}": v for key, part in parts.items() for k, v in _one(part).items()}
