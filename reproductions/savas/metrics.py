"""Summary metrics of a noisy-consensus-filter run, for `dse sweep`.

For each filter (Carli's fixed gain, re-injection) and each (m, σ_c) cell of the scenario:
the exact tr P(k|k-1) of (22) at the evaluation step and its Monte Carlo estimate; and the
centralized Kalman filter's N·P(k|k-1), the lower bound of every distributed filter; each also
per agent (``_per_agent``: divided by N), to compare networks of different sizes. A scenario
with a single cell (the usual sweep point) gets unsuffixed names.
"""
from __future__ import annotations

from .compute import Results
from .outputs import eval_trace_table


def metrics(res: Results) -> dict[str, float]:
    sc = res.scenario
    single = len(sc.sigma_c) == 1 and len(sc.rounds) == 1
    out = {"kf_trP": float(sc.n * res.bounds["kf_prior"][sc.eval_step])}
    out["kf_trP_per_agent"] = out["kf_trP"] / sc.n
    for alg in ("carli", "reinjection"):
        exact, mc, _ = eval_trace_table(res, alg)
        for s, s_c in enumerate(sc.sigma_c):
            for j, m in enumerate(sc.rounds):
                suffix = "" if single else f"_m{m}_sc{s_c:g}"
                out[f"{alg}_trP_exact{suffix}"] = float(exact[s, j])
                out[f"{alg}_trP_mc{suffix}"] = float(mc[s, j])
                out[f"{alg}_trP_exact_per_agent{suffix}"] = float(exact[s, j]) / sc.n
    return out
