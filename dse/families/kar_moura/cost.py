"""The cost model of a gossip-kalman run (`dse check`, and the driver's refusal of runs whose
non-streamable part does not fit the memory budget): seconds and peak memory from the
scenario's sizes, without simulating.

Memory. Streamed: the GIKF runs are simulated in RNG units of 1,000 runs, as many per chunk as
the budget allows; a chunk holds every run's N covariances and errors with their temporaries,
and the protocol's draws (the greedy matching sorts E edge priorities per run). Kept whole: what
the claims test run by run (the covariance features of every run and sensor at the record times,
log tr P̂ of every run at the statistic slots for the quantiles, the NEES samples), the
Theorem-8 samples, and the design arrays that grow with the horizon (the centralized filter's
covariances and gains, the class floors, the envelope). Only the kept part can be refused.

Time: per GIKF run, sensor and slot a Riccati step, an error step and their statistics (a + b·M²),
per slot a fixed overhead per chunk; per Theorem-8 run and slot a step (a + b·M²) and per slot a
fixed overhead per chain; the auxiliary samples (where C.1 and D.1 hold) about 3.1 Theorem-8 runs
and eight more chains; the greedy matching per draw and edge (in the GIKF, in protocol-driven chains
and in the Monte Carlo Ā of the design, ABAR_DRAW_S); the lifted chain's dense solve (the `bound_checks` stage,
beside the Monte Carlo: not in the design's estimate `dse check` shows); the claims, tables, figures and recording
per scenario and sensor. Fitted on this machine against whole runs (CPU time of `dse run`, estimate
/ measured): E1 1.01 (4,000 runs × 300 slots, 20,000 Theorem-8 runs), E1 quick 1.03, E2 quick 1.02,
E9 quick 1.43 (greedy, 30 nodes, M = 6; 1.33 with the faster greedy sampler and GREEDY_S scaled to it), a 200-node greedy ring 1.11, E1 over 2,000 slots 0.91, the
paper quick 1.3 and default 1.17; peak memory 0.8-1.15. The estimate is meant within a factor 1.5
(2 for small runs, where the fixed costs dominate).
"""
from __future__ import annotations

import math

from dse.contract.cost import Cost
from dse.contract.options import INTERPRETER_MIB, RunOptions
from dse.estimators.gikf_maps import FEATURES
from dse.estimators.gikf_monte_carlo import decimated_slots
from dse.simulate.units import RNG_UNIT

from .assumptions import ABAR_DRAWS, horizon
from .gikf import STAT_STRIDE
from .results import record_times, sizes
from .scenario import GossipKalmanFile, ProtocolSection

#: fitted seconds (this machine, one process): per GIKF (run · sensor · slot) a + b·M² (Riccati and error steps,
#: statistics), per Theorem-8 (run · slot) a + b·M², per (draw · edge) of the greedy matching
GIKF_S = (3e-8, 8.5e-8)
CHAIN_S = (2.5e-7, 4.5e-8)
#: (fitted at 1.3e-7 with the earlier sampler, whose draws cost 3.8 µs against 3.0 µs now on E9's 118 edges: scaled)
GREEDY_S = 1.0e-7
#: per (draw · edge) of the Monte Carlo Ā of the design (ABAR_DRAWS draws in chunks of up to 50,000: E9's 118 edges
#: 0.73 s of CPU)
ABAR_DRAW_S = 3.1e-8
#: fixed seconds per slot: of a GIKF chunk, and of one chain (the Theorem-8 run; the auxiliary samples are AUX_CHAINS)
GIKF_SLOT_S = 6e-4
CHAIN_STEP_S = 2e-4
AUX_CHAINS = 8
#: the auxiliary samples (run where C.1 and D.1 hold) cost about AUX_FACTOR Theorem-8 runs, plus pull-backs b·M²
AUX_FACTOR = 3.1
PULLBACK_S = 0.03
#: seconds per slot and M² of the eq74 sequences (2 tokens × 500 paths × up to 7 restarts): E1 0.5 s at 120 slots
EQ74_S_PER_STEP = 1e-3
#: the lifted window chain's dense stationary solve, per state³; the centralized filter's solve per slot and (N m)³;
#: dense products of N x N matrices (the token chain's total variation, Ā's spectrum) per flop
LIFTED_S = 2e-9
CENTRAL_S = 2e-11
DENSE_S = 2e-10
#: fixed: interpreter and imports; claims, tables, figures and the recording, per scenario and per sensor (the
#: small runs of `make bench`, section `estimates`: `dse run --quick` of e5-e8 and generated scenarios, 2.8-4.6 s of
#: CPU, were estimated 1.3-1.85x with 3.5 s of imports)
IMPORT_S = 2.5
OUTPUT_S = 1.5
OUTPUT_NODE_S = 0.02
BASE_MIB = 300.0


def _n_edges(sc: GossipKalmanFile) -> int:
    return len(sc.network.edge_array())


def gikf_bytes_per_run(sc: GossipKalmanFile, slots: int, spec: ProtocolSection | None = None) -> float:
    """Bytes of one GIKF run inside a chunk: its covariances, errors and their temporaries, the protocol's
    draws, and its share of what is kept (features, log traces at the statistic slots)."""
    N, M = sc.N, sc.M
    m = max([1] + [c.shape[0] for c in sc.C_types])
    spec = spec or sc.protocol
    draws = {"greedy-matching": 48.0 * _n_edges(sc), "node-initiated": 48.0 * N}.get(spec.kind, 24.0 * N)
    live = 8.0 * N * (12 * M * M + 10 * M + 4 * m + 2 * 49 / 8 + 6)
    return live + draws + kept_bytes_per_run(sc, slots)


def kept_bytes_per_run(sc: GossipKalmanFile, slots: int) -> float:
    """What every GIKF run leaves until the end of the stage (the per-run samples the claims test)."""
    nf = len(FEATURES) + sc.M
    times = record_times(sc, slots)
    n_stat = len(decimated_slots(slots, times, STAT_STRIDE)[1])
    return 8.0 * (len(times) * nf * (sc.N + 1) + n_stat * sc.N + 12)


def _kept_mib(sc: GossipKalmanFile, runs: int, ref_runs: int, slots: int) -> tuple[float, float, float]:
    """(GIKF per-run samples, Theorem-8 samples, design arrays) in MiB, at their peak (the per-unit parts and
    their join)."""
    N, M = sc.N, sc.M
    m = max([1] + [c.shape[0] for c in sc.C_types])
    gikf = 2.0 * runs * kept_bytes_per_run(sc, slots) * (2 if sc.comparison_protocol is not None else 1)
    nf = len(FEATURES) + M
    ref = 8.0 * ref_runs * (len(record_times(sc, slots)) * (nf + 1) + 2 * M * M + 4) * 2
    design = 8.0 * (slots + 1) * (M * N * m + 4 * M * M * 2 + 4) + 8.0 * N * N * 6
    if sc.protocol.kind == "greedy-matching" and _n_edges(sc) > 40:     # the Monte Carlo Ā, in 64 MiB chunks
        design += 2**26
    return gikf / 2**20, ref / 2**20, design / 2**20


def _lifted_states(sc: GossipKalmanFile) -> float:
    """Ā-walks of the witness length (the states of the lifted chain), approximated from the mean degree."""
    w = sc.assumptions.d1.search.witness
    if w is None:
        return 0.0
    degree = 2.0 * _n_edges(sc) / sc.N + 1
    states = sc.N * degree ** (len(w) - 1)
    return states if states <= 5000 else 0.0


def scenario_cost(sc: GossipKalmanFile, opts: RunOptions) -> dict[str, float]:
    """Estimated seconds and MiB of one scenario's stages."""
    runs, ref_runs, slots = sizes(sc, opts)
    slots = horizon(sc, slots)
    N, M = sc.N, sc.M
    per_run = gikf_bytes_per_run(sc, slots)
    chunk_runs = min(runs, max(1, int(opts.chunk_budget_bytes() // (per_run * RNG_UNIT))) * RNG_UNIT)
    chunks = math.ceil(runs / chunk_runs)
    E = _n_edges(sc)
    greedy = GREEDY_S * E if sc.protocol.kind == "greedy-matching" else 0.0
    protocols = 2 if sc.comparison_protocol is not None else 1
    gikf_s = protocols * (runs * slots * (N * (GIKF_S[0] + GIKF_S[1] * M * M) + greedy) + chunks * slots * GIKF_SLOT_S)
    exact = sc.protocol.kind != "greedy-matching" or E <= 40
    step = CHAIN_S[0] + CHAIN_S[1] * M * M + (0.0 if exact else greedy)
    ref_s = ref_runs * slots * step + slots * CHAIN_STEP_S
    aux_s = (AUX_FACTOR * ref_s + PULLBACK_S * M * M + AUX_CHAINS * slots * CHAIN_STEP_S) if sc.assumptions.theorem else 0.0
    m_all = sum(sc.C_types[k].shape[0] for k in sc.types)
    design_s = (0.1 + (0.0 if exact else ABAR_DRAWS * ABAR_DRAW_S * E) + slots * m_all ** 3 * CENTRAL_S
                + 200 * min(N, 64) * N * N * DENSE_S + 3 * N ** 3 * DENSE_S * 5)
    checks_s = LIFTED_S * _lifted_states(sc) ** 3 if exact else 0.0      # the `bound_checks` stage, beside the Monte Carlo
    gikf_mib, ref_mib, design_mib = _kept_mib(sc, runs, ref_runs, slots)
    return {"seconds": design_s + checks_s + gikf_s + ref_s + aux_s + OUTPUT_S + OUTPUT_NODE_S * N, "design_s": design_s,
            "checks_s": checks_s, "gikf_s": gikf_s, "chain_s": ref_s + aux_s, "ref_s": ref_s, "aux_s": aux_s,
            "pullback_s": PULLBACK_S * M * M,
            "eq74_s": EQ74_S_PER_STEP * min(slots, 120) * M ** 2, "chunk_mib": chunk_runs * per_run / 2**20,
            "kept_mib": gikf_mib + ref_mib + design_mib, "gikf_mib": gikf_mib, "runs": runs, "ref_runs": ref_runs,
            "slots": slots, "chunks": chunks, "unit_mib": RNG_UNIT * per_run / 2**20}


def estimate(scenarios: list[GossipKalmanFile], opts: RunOptions) -> Cost:
    """The run's cost, with what the driver's refusal reads: the first scenario whose one unit of runs does not
    fit beside the interpreter is sized by its graph (or by its greedy protocol's edges), the first whose kept
    samples and smallest chunk do not fit by its runs (or Theorem-8 runs, when they keep more); else the
    largest kept part and smallest chunk of any scenario."""
    costs = {sc.name: scenario_cost(sc, opts) for sc in scenarios}
    workers = max(1, min(opts.workers, len(scenarios)))
    seconds = IMPORT_S + sum(c["seconds"] for c in costs.values()) / workers
    mib = BASE_MIB + max(c["chunk_mib"] + c["kept_mib"] for c in costs.values()) * workers
    parts = [f"{name}: design ≈{c['design_s']:.2g} s; {c['runs']:,} GIKF runs × {c['slots']:,} slots ≈{c['gikf_s']:.3g} s "
             f"in {c['chunks']} chunk(s) of ≤ {c['chunk_mib']:.3g} MiB; {c['ref_runs']:,} Theorem-8 runs and the "
             f"auxiliary samples ≈{c['chain_s']:.3g} s; kept {c['kept_mib']:.3g} MiB"
             for name, c in costs.items()]
    room = opts.memory_budget_mib - INTERPRETER_MIB
    sized = {}
    for sc in scenarios:
        c = costs[sc.name]
        if c["unit_mib"] > room:
            sized = dict(kept_mib=c["kept_mib"], unit_mib=c["unit_mib"],
                         sized_by="graph.n" if sc.protocol.kind != "greedy-matching" else "protocol.kind",
                         unit_what=f"unit of {RNG_UNIT:,} runs of '{sc.name}' ({sc.N} sensors, {_n_edges(sc):,} edges)")
            break
        if c["kept_mib"] + min(c["chunk_mib"], c["unit_mib"]) > room:
            sized = dict(kept_mib=c["kept_mib"], unit_mib=min(c["chunk_mib"], c["unit_mib"]),
                         sized_by="simulation.runs" if c["gikf_mib"] >= c["kept_mib"] / 2 else "simulation.reference_runs",
                         unit_what=f"chunk of runs of '{sc.name}'")
            break
    if not sized:
        c = max(costs.values(), key=lambda c: c["kept_mib"] + min(c["chunk_mib"], c["unit_mib"]))
        sized = dict(kept_mib=c["kept_mib"], unit_mib=min(c["chunk_mib"], c["unit_mib"]), sized_by="simulation.runs")
    design_s = sum(c["design_s"] for c in costs.values()) / workers
    return Cost(seconds, mib, "; ".join(parts), design_s=design_s, chunk_mib=max(c["chunk_mib"] for c in costs.values()),
                kept_what="per-run samples of the law tests, Theorem-8 samples and design arrays", **sized,
                stages={"designs": sum(c["design_s"] for c in costs.values()),
                        "monte_carlo": sum(c["gikf_s"] + c["chain_s"] for c in costs.values())})
