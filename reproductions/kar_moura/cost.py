"""The cost model of a gossip-kalman run (`dse check`, and the refusal of runs whose
non-streamable part does not fit the memory budget): seconds and peak memory from the
scenario's sizes, without simulating.

Memory. Streamed: the GIKF runs are simulated in RNG units of 1,000 runs, as many per chunk as
the budget allows; a chunk holds every run's N covariances and errors with their temporaries,
and the protocol's draws (the greedy matching sorts E edge priorities per run). Kept whole: what
the claims test run by run (the covariance features of every run and sensor at the record times,
log tr P̂ of every run at the statistic slots for the quantiles, the NEES samples), the
Theorem-8 samples, and the design arrays that grow with the horizon (the centralized filter's
covariances and gains, the class floors, the envelope). Only the kept part can be refused.

Time: per GIKF run, sensor and slot a Riccati step and an error step (their cost per matrix
grows with M and m), per statistic slot an eigen-decomposition of every covariance, the round-off
bounds of the first unit, the Theorem-8 and auxiliary samples per run and slot, the greedy
matching per run, slot and edge, and the design (walk search, tail bounds, the Monte Carlo Ā of a
large greedy graph). The constants are fitted on this machine (see the tests and
`benchmarks/bench_kar_moura.py --estimate`); the estimate is meant within a factor 2.
"""
from __future__ import annotations

import math
from typing import Any

from pipeline.errors import ScenarioError
from pipeline.reproduction import RunOptions
from pipeline.simulate import RNG_UNIT

from .scenario import GossipKalmanScenario, ProtocolSpec

#: seconds per (run · sensor · slot) of the GIKF step, by observation rows m = 1 and m > 1, per M² (fitted)
STEP_S = 2.0e-8
#: seconds per (run · sensor) of an eigen-decomposition at a statistic slot, per M
EIG_S = 6e-8
#: seconds per (run · slot) of a Theorem-8 / auxiliary step, per M²
CHAIN_S = 1.2e-8
#: seconds per (run · slot · edge) of the greedy matching
GREEDY_S = 4e-9
#: seconds per slot of fixed overhead (Python) per chunk of the GIKF, per slot of a Theorem-8 sampler
SLOT_S = 4e-4
#: fixed seconds: imports, design, report, tables, figures and recording per scenario
SCENARIO_S = 3.0
BASE_MIB = 300.0
INTERPRETER_MIB = 200.0


def _n_edges(sc: GossipKalmanScenario) -> int:
    return sc.graph.build().number_of_edges()


def _times(sc: GossipKalmanScenario, slots: int) -> int:
    from .compute import record_times

    return len(record_times(sc, slots))


def _stat_slots(sc: GossipKalmanScenario, slots: int) -> int:
    import estimators.gossip_kalman as gk

    from .compute import STAT_STRIDE, record_times

    return len(gk.decimated_slots(slots, record_times(sc, slots), STAT_STRIDE)[1])


def gikf_bytes_per_run(sc: GossipKalmanScenario, slots: int, spec: ProtocolSpec | None = None) -> float:
    """Bytes of one GIKF run inside a chunk: its covariances, errors and their temporaries, the protocol's
    draws, and its share of what is kept (features, log traces at the statistic slots)."""
    N, M = sc.N, sc.M
    m = max([1] + [c.shape[0] for c in sc.C_types])
    spec = spec or sc.protocol
    draws = {"greedy-matching": 48.0 * _n_edges(sc), "node-initiated": 48.0 * N}.get(spec.kind, 24.0 * N)
    live = 8.0 * N * (12 * M * M + 10 * M + 4 * m + 2 * 49 / 8 + 6)
    return live + draws + kept_bytes_per_run(sc, slots)


def kept_bytes_per_run(sc: GossipKalmanScenario, slots: int) -> float:
    """What every GIKF run leaves until the end of the stage (the per-run samples the claims test)."""
    import estimators.gossip_kalman as gk

    nf = len(gk.FEATURES) + sc.M
    return 8.0 * (_times(sc, slots) * nf * (sc.N + 1) + _stat_slots(sc, slots) * sc.N + 12)


def _kept_mib(sc: GossipKalmanScenario, runs: int, ref_runs: int, slots: int) -> tuple[float, float, float]:
    """(GIKF per-run samples, Theorem-8 samples, design arrays) in MiB, at their peak (joined and sorted)."""
    import estimators.gossip_kalman as gk

    N, M = sc.N, sc.M
    m = max([1] + [c.shape[0] for c in sc.C_types])
    gikf = 3.0 * runs * kept_bytes_per_run(sc, slots) * (2 if sc.comparison is not None else 1)
    nf = len(gk.FEATURES) + M
    ref = 8.0 * ref_runs * (_times(sc, slots) * (nf + 1) + 2 * M * M + 4) * 3
    design = 8.0 * (slots + 1) * (M * N * m + 4 * M * M * 2 + 4) + 8.0 * N * N * 6
    return gikf / 2**20, ref / 2**20, design / 2**20


def scenario_cost(sc: GossipKalmanScenario, opts: RunOptions) -> dict[str, float]:
    from .compute import assumptions, horizon, sizes

    runs, ref_runs, slots = sizes(sc, opts)
    slots = horizon(sc, slots, assumptions(sc))
    N, M = sc.N, sc.M
    m = max([1] + [c.shape[0] for c in sc.C_types])
    budget = opts.chunk_budget_bytes()
    per_run = gikf_bytes_per_run(sc, slots)
    chunk_runs = min(runs, max(1, int(budget // (per_run * RNG_UNIT))) * RNG_UNIT)
    chunks = math.ceil(runs / chunk_runs)
    protocols = 2 if sc.comparison is not None else 1
    step = STEP_S * M * M * (1 if m == 1 else 2.5)
    greedy = GREEDY_S * _n_edges(sc) if sc.protocol.kind == "greedy-matching" else 0.0
    gikf_s = protocols * (runs * slots * (N * step + greedy) + runs * _stat_slots(sc, slots) * N * EIG_S * M
                          + chunks * slots * SLOT_S + min(runs, RNG_UNIT) * slots * N * step * 3)
    aux = 6 if sc.protocol.random else 1
    chain_s = aux * ref_runs * slots * CHAIN_S * M * M * (1 + N * greedy / max(N, 1)) + aux * slots * SLOT_S
    gikf_mib, ref_mib, design_mib = _kept_mib(sc, runs, ref_runs, slots)
    return {"seconds": SCENARIO_S + gikf_s + chain_s, "chunk_mib": chunk_runs * per_run / 2**20,
            "kept_mib": gikf_mib + ref_mib + design_mib, "gikf_mib": gikf_mib, "runs": runs, "ref_runs": ref_runs,
            "slots": slots, "chunks": chunks, "unit_mib": RNG_UNIT * per_run / 2**20}


def estimate(scenarios: list[GossipKalmanScenario], opts: RunOptions) -> dict[str, Any]:
    costs = {sc.name: scenario_cost(sc, opts) for sc in scenarios}
    workers = max(1, min(opts.workers, len(scenarios)))
    seconds = sum(c["seconds"] for c in costs.values()) / workers
    mib = BASE_MIB + max(c["chunk_mib"] + c["kept_mib"] for c in costs.values()) * workers
    parts = [f"{name}: {c['runs']:,} runs × {c['slots']:,} slots in {c['chunks']} chunk(s) of ≤ {c['chunk_mib']:.3g} "
             f"MiB, {c['ref_runs']:,} Theorem-8 runs, kept {c['kept_mib']:.3g} MiB, ≈{c['seconds']:.3g} s"
             for name, c in costs.items()]
    return {"seconds": seconds, "peak_memory_mib": mib, "detail": "; ".join(parts)}


def refuse_beyond_budget(scenarios: list[GossipKalmanScenario], opts: RunOptions) -> None:
    """What cannot be streamed must fit the memory budget, and so must one RNG unit of runs: else one
    ScenarioError naming the field and the estimate, before anything runs."""
    budget = opts.memory_budget_mib
    for sc in scenarios:
        c = scenario_cost(sc, opts)
        if INTERPRETER_MIB + c["unit_mib"] > budget:
            field = "graph.n" if sc.protocol.kind != "greedy-matching" else "protocol.kind"
            raise ScenarioError(field, f"one unit of {RNG_UNIT:,} runs of '{sc.name}' needs about {c['unit_mib']:,.0f} MiB "
                                       f"({sc.N} sensors, {_n_edges(sc):,} edges), more than the memory budget of "
                                       f"{budget:,.0f} MiB (--max-memory)")
        need = INTERPRETER_MIB + c["kept_mib"] + min(c["chunk_mib"], c["unit_mib"])
        if need > budget:
            field = "simulation.runs" if c["gikf_mib"] >= c["kept_mib"] / 2 else "simulation.reference_runs"
            raise ScenarioError(field, f"'{sc.name}' needs about {need:,.0f} MiB ({c['kept_mib']:,.0f} MiB that cannot "
                                       f"be streamed: the per-run samples the law tests use, {c['runs']:,} GIKF and "
                                       f"{c['ref_runs']:,} Theorem-8 runs, and the design arrays over {c['slots']:,} "
                                       f"slots), more than the memory budget of {budget:,.0f} MiB (--max-memory); fewer "
                                       f"runs fit")
