"""Stages of the compare family: the design (the estimators' gain searches), the exact moments, the
centralized filter against filterpy, the Monte Carlo of every estimator on common random numbers (streamed in
RNG units, folded in unit order), and Kar & Moura's token chain. The estimators' declarations are stage
arguments: each is keyed by its name and the code of its module.

Random streams (`dse.simulate.seeding`): ``plant`` (x(0), w, v), ``links`` (the link draws), ``noise``
(communication noise), ``gossip`` (the swap matchings' priorities and the random node q of the token law) and
``token`` (an independent copy of the communication driving the token chain). A trial's numbers depend only
on the seed and its index, never on the memory chunk or on how the estimators are split over workers.
"""
from __future__ import annotations

import functools
import time
from dataclasses import dataclass, field

import numpy as np

from dse.contract.stages import StageContext, StageResult, stage
from dse.estimators.network_comparison import PER_TRIAL_SUMS, STATS, Setup, record_steps, simulate_units
from dse.simulate.seeding import block_seeds, stream_seed
from dse.simulate.units import RNG_UNIT, UnitStreams, run_jobs, units_per_chunk

from .design import Design, design_of
from .scenario import CompareFile

STREAMS = ("plant", "links", "noise", "gossip")
#: the exact moments kept per estimator (`protocol.DesignedEstimator.exact_moments`)
MOMENTS = ("blocks", "mse", "disagreement", "own_cov")


def token_times(sc: CompareFile) -> tuple[int, ...]:
    K = sc.simulation.steps
    return tuple(sorted({max(1, K // 4), max(1, K // 2), K - 1}))


def recorded(sc: CompareFile) -> tuple[int, ...]:
    s = sc.simulation
    return record_steps(s.steps, extra=(s.eval_step, s.steps // 2) + token_times(sc))


def tuned_numbers(result: StageResult) -> dict[str, float]:
    return dict(zip(result["names"].tolist(), result["values"].tolist()))


def rebuilt(sc: CompareFile, quick: bool, tuned: StageResult, estimators) -> Design:
    return design_of(sc, quick, tuned_numbers(tuned), estimators)


# -- the design -------------------------------------------------------------------------------------------

@stage(name="design", allow_nonfinite=("values",))
def tune(sc: CompareFile, quick: bool, estimators: tuple) -> dict[str, np.ndarray]:
    """The numbers the estimators' designs searched for, by name (an unstable gain's steady state is inf)."""
    tuned = design_of(sc, quick, {}, estimators).tuned
    return {"names": np.array(list(tuned), dtype=str), "values": np.array([float(v) for v in tuned.values()])}


def design(sc: CompareFile, quick: bool, ctx: StageContext, estimators: tuple) -> Design:
    tuned = ctx.run(tune, sc, quick, estimators)
    d = rebuilt(sc, quick, tuned, estimators)
    d.tuning_stage = tuned
    return d


# -- exact moments and the reference ----------------------------------------------------------------------

@stage(allow_nonfinite=lambda estimators, **_: tuple(f"{e.name}__{k}" for e in estimators for k in MOMENTS))
def exact_moments(sc: CompareFile, quick: bool, tuned: StageResult, estimators: tuple) -> dict[str, np.ndarray]:
    """'<estimator>__<moment>' of every running estimator whose exact moments are computed."""
    d = rebuilt(sc, quick, tuned, estimators)
    out = {}
    with np.errstate(over="ignore", invalid="ignore"):     # a mean-square unstable filter's moments may overflow
        for name, est in d.running.items():
            if est.exact:
                ex = est.exact_moments()
                out.update({f"{name}__{k}": ex[k] for k in MOMENTS if k in ex})
    return out


@stage(name="reference")
def filterpy_reference(sc: CompareFile) -> dict[str, np.ndarray]:
    """The centralized filter against filterpy's KalmanFilter on three simulated trials of the first 50
    steps: the largest differences of the estimates and covariances, and the inputs' scale."""
    from filterpy.kalman import KalmanFilter

    from dse.estimators.network.central import CentralizedKalman
    from dse.estimators.network_step import StepContext

    m, K = sc.model, min(sc.simulation.steps, 50)
    rng = np.random.default_rng(12345)
    B = 3
    x = m.x0[:, None] + np.linalg.cholesky(m.P0) @ rng.standard_normal((m.n, B))
    lam, V = np.linalg.eigh(m.Q)
    Lq = V * np.sqrt(np.maximum(lam, 0))
    c = CentralizedKalman(m, K, B)
    kfs = []
    for b in range(B):
        kf = KalmanFilter(dim_x=m.n, dim_z=m.N * m.m)
        kf.F, kf.H, kf.Q, kf.R = m.F, m.H_all, m.Q, m.R_all
        kf.P, kf.x = m.P0.copy(), m.x0.copy()
        kfs.append(kf)
    dx = dP = sx = sP = 0.0
    for k in range(K):
        y = np.einsum("imn,nb->imb", m.H, x) + np.einsum("iab,ibc->iac", m.R_chol, rng.standard_normal((m.N, m.m, B)))
        est = c.step(StepContext(k, y, None))[0]
        for b, kf in enumerate(kfs):
            kf.update(y[:, :, b].reshape(-1))
            dx = max(dx, float(np.abs(est[:, b] - kf.x).max()))
            dP = max(dP, float(np.abs(c.P_post[k] - kf.P).max()))
            sx = max(sx, float(np.abs(kf.x).max()))
            sP = max(sP, float(np.abs(kf.P).max()))
            kf.predict()
        x = m.F @ x + Lq @ rng.standard_normal((m.n, B))
    cond = float(np.linalg.cond(m.H_all @ m.P0 @ m.H_all.T + m.R_all))
    return {"dx": np.array(dx), "dP": np.array(dP), "sx": np.array(sx), "sP": np.array(sP), "steps": np.array(K),
            "cond": np.array(cond)}


# -- the Monte Carlo ----------------------------------------------------------------------------------------

def bytes_per_trial(d: Design, chosen: dict) -> float:
    """Memory of one trial in a chunk: estimates, covariances per node where they depend on the
    trial, and the temporaries of one step (about eight arrays of the largest size)."""
    N, n = d.model.N, d.model.n
    per = sum(N * n + (3 * N * n * n if est.trialwise_covariance() else 0) for est in chosen.values())
    events = d.links.max_events * 2 * n if not d.links.synchronous else 0
    return 8.0 * (8 * per + N * n * 4 + d.topology.E * 4 + events)


def estimator_groups(d: Design, workers: int) -> list[list[str]]:
    """The running estimators split into at most `workers` groups of similar cost (`cost_weight`, longest
    first), each with the reference (of the distance statistics); an estimator that reuses another's
    recursion (`shares_with`) stays with it."""
    running = d.running
    head = [name for name, est in running.items() if est.spec.reference]
    names = [name for name in running if name not in head]
    if workers <= 1 or len(names) < 2:
        return [list(running)]
    units: list[list[str]] = []
    for name in names:
        home = next((u for u in units if running[name].spec.shares_with in u), None)
        home.append(name) if home is not None else units.append([name])

    def weight(unit):
        return sum(running[e].spec.cost_weight for e in unit)

    units.sort(key=lambda u: -weight(u))
    groups: list[list[str]] = [[] for _ in range(min(workers, len(units)))]
    load = [0.0] * len(groups)
    for u in units:
        g = int(np.argmin(load))
        groups[g] += u
        load[g] += weight(u)
    return [head + [e for e in running if e in g] for g in groups if g]


def _mc_nonfinite(estimators, **_) -> tuple[str, ...]:
    names = [e.name for e in estimators]
    return (tuple(f"path__{e}" for e in names) + ("path__x",) + tuple(f"{e}__{s}" for e in names for s in STATS +
            PER_TRIAL_SUMS) + tuple(f"token__{e}" for e in names))


@stage(unkeyed=("workers", "budget_bytes"), allow_nonfinite=_mc_nonfinite)
def monte_carlo(sc: CompareFile, quick: bool, tuned: StageResult, exact: StageResult, seed: int, trials: int,
                estimators: tuple, workers: int, budget_bytes: float) -> dict[str, np.ndarray]:
    """Every running estimator on `trials` trials: '<estimator>__<sum>' (`network_comparison`), the token
    law 'token__<estimator>', the sample paths 'path__<estimator>' and the recorded 'steps'. With several
    workers the estimators are split into groups simulated in parallel processes; every group draws the
    same random numbers (the streams depend only on the seed and the unit), so the results are those of one
    process."""
    d = rebuilt(sc, quick, tuned, estimators)
    exact_cov = {name: exact[f"{name}__blocks"] for name, est in d.running.items()
                 if est.spec.joint_moments and f"{name}__blocks" in exact}
    groups = estimator_groups(d, workers)
    jobs = [(sum(d.running[e].spec.cost_weight for e in g), functools.partial(
        _simulate_group, d, exact_cov, seed, trials, budget_bytes, g)) for g in groups]
    with np.errstate(over="ignore", invalid="ignore"):     # a diverging filter's errors may overflow
        parts = run_jobs(jobs, workers=len(groups))       # forked: the declarations are inherited, not pickled
    mc, token, paths = {}, {}, {}
    for p in parts:
        mc.update({e: v for e, v in p["mc"].items() if e not in mc})
        token.update(p["token"])
        paths.update({e: v for e, v in p["paths"].items() if e not in paths})
    arrays = {f"{e}__{k}": v for e in d.running if e in mc for k, v in mc[e].items()}
    arrays.update({f"token__{e}": v for e, v in token.items()})
    arrays.update({f"path__{e}": v for e, v in paths.items()})
    arrays["steps"] = parts[0]["steps"]
    return arrays


def _simulate_group(d: Design, exact_cov: dict, seed: int, trials: int, budget_bytes: float,
                    names: list[str]) -> dict:
    """The estimators `names` on every trial, chunk by chunk of RNG units, folded in unit order."""
    sc = d.scenario
    chosen = {e: est for e, est in d.running.items() if e in names}
    setup = Setup(d.model, d.links, sc.simulation.steps, chosen,
                  exact_cov={e: v for e, v in exact_cov.items() if e in chosen},
                  token_times=token_times(sc) if any(est.spec.swaps for est in chosen.values()) else (),
                  n_paths=sc.simulation.paths, record_steps=recorded(sc))
    n_units = -(-trials // RNG_UNIT)
    sizes = [min(RNG_UNIT, trials - u * RNG_UNIT) for u in range(n_units)]
    seeds = {s: block_seeds(stream_seed(seed, "compare", s), n_units) for s in STREAMS}
    per_chunk = units_per_chunk(bytes_per_trial(d, chosen), budget_bytes)
    sums: dict[str, dict[str, list]] = {}
    token: dict[str, list] = {}
    paths = None
    cpu0 = time.process_time()
    for start in range(0, n_units, per_chunk):
        stop = min(start + per_chunk, n_units)
        out = simulate_units(setup, *(UnitStreams(seeds[s][start:stop], sizes[start:stop]) for s in STREAMS))
        for est, stats in out["sums"].items():
            for name, arr in stats.items():
                sums.setdefault(est, {}).setdefault(name, []).append(arr)
        for est, arr in out["token"].items():
            token.setdefault(est, []).append(arr)
        paths = out["paths"] if paths is None else paths
    mc = {est: {name: np.concatenate(parts).sum(axis=0) for name, parts in stats.items()} for est, stats in sums.items()}
    return {"mc": mc, "token": {e: np.concatenate(v, axis=1) for e, v in token.items()}, "paths": paths,
            "steps": out["steps"], "cpu_s": time.process_time() - cpu0}


@stage(unkeyed=("budget_bytes",), allow_nonfinite=("chain",))
def token_chain(sc: CompareFile, seed: int, trials: int, budget_bytes: float) -> dict[str, np.ndarray]:
    """(len(token_times), trials): tr P̃(t) of Kar & Moura's token chain (20) at the token times, driven
    by an independent copy of the communication (stream ``token``)."""
    from dse.estimators.gossip_swap_kalman import TokenSampler

    m, lm = sc.model, sc.link_model
    times = token_times(sc)
    n_units = -(-trials // RNG_UNIT)
    sizes = [min(RNG_UNIT, trials - u * RNG_UNIT) for u in range(n_units)]
    seeds = {s: block_seeds(stream_seed(seed, "compare-token", s), n_units) for s in ("links", "gossip")}
    per_chunk = units_per_chunk(8.0 * (m.n ** 2 * 6 + lm.topology.E * 4 + m.N * 4), budget_bytes)
    parts = []
    for start in range(0, n_units, per_chunk):
        stop = min(start + per_chunk, n_units)
        links = UnitStreams(seeds["links"][start:stop], sizes[start:stop])
        gossip = UnitStreams(seeds["gossip"][start:stop], sizes[start:stop])
        B = sum(sizes[start:stop])
        tok = TokenSampler(m, lm, B, gossip.integers(0, m.N))
        out = np.zeros((len(times), B))
        for k in range(sc.simulation.steps):
            if k in times:
                out[times.index(k)] = np.trace(tok.P, axis1=0, axis2=1)
            step = lm.draw(links)
            prio = gossip.random((lm.topology.E,)).T if (lm.synchronous and lm.kind != "matchings") else None
            tok.step(step, prio)
        parts.append(out)
    return {"chain": np.concatenate(parts, axis=1)}


# -- the results the claims and tables read ---------------------------------------------------------------

@dataclass
class Results:
    scenario: CompareFile
    design: Design
    seed: int
    trials: int
    quick: bool
    steps: np.ndarray                                   # recorded steps
    exact: dict[str, dict[str, np.ndarray]] = field(default_factory=dict)
    mc: dict[str, dict[str, np.ndarray]] = field(default_factory=dict)   # folded sums per estimator
    token: dict[str, np.ndarray] = field(default_factory=dict)
    paths: dict[str, np.ndarray] = field(default_factory=dict)
    reference: dict[str, np.ndarray] = field(default_factory=dict)

    @property
    def eval_index(self) -> int:
        return int(np.searchsorted(self.steps, self.scenario.simulation.eval_step))

    def check_indices(self) -> list[int]:
        """Recorded steps at which the claims compare: the middle of the horizon and the evaluation step."""
        s = self.scenario.simulation
        return sorted(int(np.searchsorted(self.steps, k)) for k in {s.eval_step, s.steps // 2}
                      if k in set(self.steps.tolist()))


def simulate(sc: CompareFile, d: Design, seed: int, trials: int, quick: bool, workers: int, budget_bytes: float,
             ctx: StageContext) -> Results:
    """Every stage after the design, gathered for the claims and the tables."""
    keyed = (sc, quick, d.tuning_stage)
    exact = ctx.run(exact_moments, *keyed, d.specs)
    mc = ctx.run(monte_carlo, *keyed, exact, seed, trials, d.specs, workers, budget_bytes)
    res = Results(sc, d, seed, trials, quick, mc["steps"])
    if "central" in d.running:
        res.reference = dict(ctx.run(filterpy_reference, sc))
    for key, value in exact.items():
        est, name = key.split("__", 1)
        res.exact.setdefault(est, {})[name] = value
    for key, value in mc.items():
        head, _, name = key.partition("__")
        if head == "token":
            res.token[name] = value
        elif head == "path":
            res.paths[name] = value
        elif name:
            res.mc.setdefault(head, {})[name] = value
    if res.token:                       # a filter that swaps states ran: the law of its random node's covariance
        res.token["chain"] = ctx.run(token_chain, sc, seed, trials, budget_bytes)["chain"]
    return res
