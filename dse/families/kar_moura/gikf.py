"""The GIKF Monte Carlo stage: independent runs of the gossip interactive Kalman filter (eq (12) for the
covariances, the error recursion for the estimates) under the scenario's protocol or its comparison
protocol, in RNG units of 1,000 runs, with the statistics the claims and tables read computed by the
accumulators of `dse.estimators.gikf_monte_carlo` beside the filter step.
"""
from __future__ import annotations

import numpy as np

from dse.contract.stages import stage
from dse.engine.cache import check_finite
from dse.estimators.gikf_monte_carlo import finish_gikf, fold_gikf, gikf_units, standard_accumulators
from dse.simulate.seeding import stream_seed
from dse.simulate.units import run_units

from .bounds import J_GRID
from .results import record_times
from .scenario import GossipKalmanFile

#: tail statistics, quantiles and Loewner margins are evaluated at every STAT_STRIDE-th slot
STAT_STRIDE = 5
#: NaN marks slots not evaluated (stride) in 'margins' and 'slack' and, after a float overflow (a divergence,
#: reported by the claims with its slot), the unreached slots; the sample runs' states grow with an unstable F
PARTIAL = ("margins", "slack", "feat_q", "feat_n", "quantiles", "path_trace", "path_err", "path_err_c", "nees_q",
           "nees_c", "path_state", "nees", "nees_run", "final_sum", "final_sq")
#: what may be non-finite when no covariance overflowed
UNEVALUATED = ("margins", "slack", "nees_q", "nees_c", "path_state")


def nees_slots(slots: int) -> list[int]:
    """The slots at which the per-run NEES is kept for the exact χ² tests: the first (where a wrong start shows
    most), a third and two thirds of the horizon, and the last."""
    return sorted({1, max(1, slots // 3), max(1, (2 * slots) // 3), slots})


@stage(unkeyed=("budget_bytes", "bytes_per_run"), allow_nonfinite=PARTIAL)
def gikf(sc: GossipKalmanFile, bounds: dict, seed: int, runs: int, slots: int, which: str, budget_bytes: float,
         bytes_per_run: float) -> dict[str, np.ndarray]:
    """The GIKF runs under `which` ("protocol" or "comparison"), as many units per chunk as `budget_bytes`
    allows (`bytes_per_run`: the cost model's): every statistic is made per unit and folded in unit order, so
    the numbers do not depend on the budget; the chunks are portable (they go to the run's unit executor).
    The first unit carries the Loewner margins (with their round-off bounds) and the sample runs."""
    spec = sc.protocol if which == "protocol" else sc.comparison_protocol
    protocol = spec.build(sc.network)
    sys_, b = sc.system, bounds

    def chunk(streams):
        first = streams.first_unit == 0
        acc = standard_accumulators(sys_, slots, record_times=record_times(sc, slots), P_central=b["P_central"],
                                    envelope=b["envelope"], envelope_log=b["envelope_log"],
                                    envelope_err=b["envelope_err"], j_grid=J_GRID, n_paths=sc.simulation.sample_paths,
                                    check=first, paths=first, nees_window=(max(1, min(20, slots // 3)), min(60, slots)),
                                    stat_stride=STAT_STRIDE, P_floor=b["P_floor"], floor_index=b["class_of"],
                                    floor_err=b["P_floor_err"], nees_slots=nees_slots(slots), x0=sc.x0)
        return gikf_units(sys_, protocol, list(zip(streams.generators, streams.sizes)), slots,
                          K_central=b["K_central"], accumulators=acc)

    out = finish_gikf(run_units(chunk, fold_gikf, runs, stream_seed(seed, sc.name, "gikf", which),
                                bytes_per_trial=bytes_per_run, budget_bytes=budget_bytes, portable=True))
    if int(out["overflow"]) < 0:
        check_finite({k: v for k, v in out.items() if k not in UNEVALUATED}, stage="gikf", scenario=sc.name)
    return out
