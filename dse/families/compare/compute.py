"""Stages of the compare family: design (gain tuning cached), exact moments, Monte Carlo with common
random numbers (streamed in RNG units, folded in unit order), and Kar & Moura's token chain.

Random streams (`dse.simulate.seeding`): ``plant`` (x(0), w, v), ``links`` (the link draws), ``noise``
(communication noise), ``gossip`` (the GIKF's matching priorities and its random sensor q) and
``token`` (an independent copy of the communication driving the token chain). A trial's numbers
depend only on the seed and its index, never on the memory chunk.
"""
from __future__ import annotations

import functools
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from dse.estimators.constant_gain_fusion import FusionFilter
from dse.estimators.constant_gain_fusion import exact_moments as fusion_exact
from dse.estimators.gossip_swap_kalman import TokenSampler
from dse.estimators.information_fusion import InformationFilter
from dse.estimators.information_fusion import exact_moments as information_exact
from dse.estimators.network_comparison import STATS, Setup, record_steps, simulate_units
from dse.engine.cache import StageCache, code_fingerprint
from dse.engine.driver import RunOptions
from dse.simulate.seeding import block_seeds, stream_seed
from dse.simulate.units import RNG_UNIT, UnitStreams, units_per_chunk

from .design import Design, design, tuned_arrays
from .scenario import CompareScenario

CODE_MODULES = ("dse.estimators.constant_gain_fusion", "dse.estimators.information_fusion", "dse.estimators.gossip_swap_kalman",
                "dse.estimators.network_comparison", "dse.estimators.link_models", "dse.estimators.network_mixing",
                "dse.estimators.small_matrix", "dse.estimators.joint_moments", "dse.estimators.sensor_network",
                "dse.estimators.kalman", "dse.families.compare.design", "dse.families.compare.compute")
STREAMS = ("plant", "links", "noise", "gossip")
#: the per-trial sums beside `STATS` (a diverging filter may make any of them infinite: a result, not a failure)
PER_TRIAL_SUMS = ("dis", "dis2", "dis_node", "net", "net2", "msgs", "scalars")


@dataclass
class Results:
    scenario: CompareScenario
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
        return int(np.searchsorted(self.steps, self.scenario.eval_step))

    def check_indices(self) -> list[int]:
        """Recorded steps at which the claims compare: the middle of the horizon and the evaluation step."""
        k = {self.scenario.eval_step, self.scenario.steps // 2}
        return sorted(int(np.searchsorted(self.steps, s)) for s in k if s in set(self.steps.tolist()))


def trial_count(sc: CompareScenario, opts: RunOptions) -> int:
    return opts.trials if opts.trials is not None else (sc.quick_trials if opts.quick else sc.trials)


def token_times(sc: CompareScenario) -> tuple[int, ...]:
    K = sc.steps
    return tuple(sorted({max(1, K // 4), max(1, K // 2), K - 1}))


def recorded(sc: CompareScenario) -> tuple[int, ...]:
    return record_steps(sc.steps, extra=(sc.eval_step, sc.steps // 2) + token_times(sc))


def compute_design(sc: CompareScenario, opts: RunOptions, cache: StageCache | None = None) -> Design:
    if cache is None:
        return design(sc, opts.quick)
    params = {"scenario": sc.key(), "quick": opts.quick, "code": code_fingerprint(CODE_MODULES)}
    holder: dict[str, Design] = {}

    def run():
        holder["d"] = design(sc, opts.quick)
        return tuned_arrays(holder["d"])

    arrays = cache.get_or_compute("design", params, run, scenario=sc.name,
                                  allow_nonfinite=tuple(f"{e}_{s}" for e in ("carli", "reinjection", "pairwise")
                                                        for s in ("steady", "rho", "scale")) + ("carli_scale",
                                                        "reinjection_scale", "carli_local_steady"))
    if "d" in holder:
        return holder["d"]
    return design(sc, opts.quick, tuned={k: float(v) for k, v in arrays.items()})


def compute_exact(d: Design) -> dict[str, np.ndarray]:
    """Exact moments of every estimator that has them, flattened as '<id>__<name>' arrays."""
    sc, m, K = d.scenario, d.model, d.scenario.steps
    out: dict[str, np.ndarray] = {}
    if d.status["central"][0]:
        cov = m.central_covariances(K)
        out["central__blocks"] = cov.P_post[:, None]
        out["central__mse"] = np.trace(cov.P_post, axis1=1, axis2=2)[:, None]
        out.update(_filterpy_reference(d))
    if d.status["local"][0]:
        covs = m.local_covariances(K)
        blocks = np.stack([c.P_post for c in covs], axis=1)
        out["local__blocks"] = blocks
        out["local__mse"] = np.einsum("kiaa->ki", blocks)
    for est, kind in d.estimators.items():
        if not d.exact.get(est, (False, ""))[0] or est in ("central", "local"):
            continue
        ex = fusion_exact(kind, K) if isinstance(kind, FusionFilter) else information_exact(kind, K)
        for name in ("blocks", "mse", "disagreement") + (("own_cov",) if "own_cov" in ex else ()):
            out[f"{est}__{name}"] = ex[name]
    return out


def _filterpy_reference(d: Design) -> dict[str, np.ndarray]:
    """The centralized filter against filterpy's KalmanFilter on three simulated trials: the largest
    relative differences of the estimates, covariances and gains, and the inputs' scale."""
    from filterpy.kalman import KalmanFilter

    from dse.estimators.network_comparison import _Central
    from dse.estimators.network_step import StepContext

    m, K = d.model, min(d.scenario.steps, 50)
    rng = np.random.default_rng(12345)
    B = 3
    x = m.x0[:, None] + np.linalg.cholesky(m.P0) @ rng.standard_normal((m.n, B))
    lam, V = np.linalg.eigh(m.Q)
    Lq = V * np.sqrt(np.maximum(lam, 0))
    c = _Central(m, K, B)
    kfs = []
    for b in range(B):
        kf = KalmanFilter(dim_x=m.n, dim_z=m.N * m.m)
        kf.F, kf.H, kf.Q, kf.R = m.F, m.H_all, m.Q, m.R_all
        kf.P, kf.x = m.P0.copy(), m.x0.copy()
        kfs.append(kf)
    dx = dP = 0.0
    sx = sP = 0.0
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
    return {"reference__dx": np.array(dx), "reference__dP": np.array(dP), "reference__sx": np.array(sx),
            "reference__sP": np.array(sP), "reference__steps": np.array(K), "reference__cond": np.array(cond)}


def bytes_per_trial(d: Design, estimators: dict | None = None) -> float:
    """Memory of one trial in a chunk: estimates, covariances per node where they depend on the
    trial, and the temporaries of one step (about eight arrays of the largest size)."""
    m = d.model
    N, n = m.N, m.n
    per = 0
    for est, kind in (d.estimators if estimators is None else estimators).items():
        per += N * n
        if kind == "gossip" or (isinstance(kind, InformationFilter) and d.links.random):
            per += 3 * N * n * n
    events = d.links.max_events * 2 * n if not d.links.synchronous else 0
    return 8.0 * (8 * per + N * n * 4 + d.topology.E * 4 + events)


#: relative cost per step of an estimator (CPU, 50 nodes, 4 states, random links), for splitting them over workers
COST_WEIGHT = {"central": 0.5, "local": 1, "gikf": 18, "carli": 5, "reinjection": 5, "pairwise": 5, "kcf": 36,
               "diffusion": 17, "ci": 37}


def estimator_groups(d: Design, workers: int) -> list[list[str]]:
    """The estimators split into at most `workers` groups of similar cost (longest first), each with
    the centralized filter (the reference of the distance statistics); the diffusion filter stays with
    the Kalman-consensus filter, whose covariance recursion it shares."""
    names = [e for e in d.estimators if e != "central"]
    if workers <= 1 or len(names) < 2:
        return [list(d.estimators)]
    units = []
    if "kcf" in names and "diffusion" in names:
        units.append(["kcf", "diffusion"])
    units += [[e] for e in names if not (e in ("kcf", "diffusion") and "kcf" in names and "diffusion" in names)]
    units.sort(key=lambda u: -sum(COST_WEIGHT.get(e, 5) for e in u))
    groups: list[list[str]] = [[] for _ in range(min(workers, len(units)))]
    load = [0.0] * len(groups)
    for u in units:
        g = int(np.argmin(load))
        groups[g] += u
        load[g] += sum(COST_WEIGHT.get(e, 5) for e in u)
    head = ["central"] if "central" in d.estimators else []
    return [head + [e for e in d.estimators if e in g] for g in groups if g]


def simulate(d: Design, opts: RunOptions, trials: int) -> dict[str, Any]:
    """Every estimator on `trials` trials, chunk by chunk of RNG units, folded in unit order. With
    several workers the estimators are split into groups simulated in parallel processes; every group
    draws the same random numbers (the streams depend only on the seed and the unit), so the results
    are those of one process."""
    from dse.simulate.units import parallel_map

    groups = estimator_groups(d, opts.workers)
    parts = parallel_map(functools.partial(_simulate_group, d, opts, trials), groups, workers=len(groups))
    out = parts[0]
    out["group_cpu_s"] = [p["cpu_s"] for p in parts]
    for p in parts[1:]:
        out["mc"].update({e: v for e, v in p["mc"].items() if e not in out["mc"]})
        out["token"].update(p["token"])
        out["paths"].update({e: v for e, v in p["paths"].items() if e not in out["paths"]})
        out["seconds"].update({e: v for e, v in p["seconds"].items() if e not in out["seconds"]})
    order = list(d.estimators)
    out["mc"] = {e: out["mc"][e] for e in order if e in out["mc"]}
    return out


def _simulate_group(d: Design, opts: RunOptions, trials: int, names: list[str]) -> dict[str, Any]:
    import time

    cpu0 = time.process_time()
    sc = d.scenario
    chosen = {e: k for e, k in d.estimators.items() if e in names}
    setup = Setup(d.model, d.links, sc.steps, chosen, exact_cov={e: v for e, v in _exact_cov(d).items() if e in chosen},
                  token_times=token_times(sc) if "gikf" in chosen else (), n_paths=sc.paths,
                  record_steps=recorded(sc))
    n_units = -(-trials // RNG_UNIT)
    sizes = [min(RNG_UNIT, trials - u * RNG_UNIT) for u in range(n_units)]
    seeds = {s: block_seeds(stream_seed(opts.seed, "compare", s), n_units) for s in STREAMS}
    per_chunk = units_per_chunk(bytes_per_trial(d, chosen), opts.chunk_budget_bytes())
    sums: dict[str, dict[str, list]] = {}
    token: dict[str, list] = {}
    paths = None
    seconds: dict[str, float] = {}
    for start in range(0, n_units, per_chunk):
        stop = min(start + per_chunk, n_units)
        streams = [UnitStreams(seeds[s][start:stop], sizes[start:stop]) for s in STREAMS]
        out = simulate_units(setup, *streams)
        for est, stats in out["sums"].items():
            for name, arr in stats.items():
                sums.setdefault(est, {}).setdefault(name, []).append(arr)
        for est, arr in out["token"].items():
            token.setdefault(est, []).append(arr)
        if paths is None:
            paths = out["paths"]
        steps = out["steps"]
        for est, t in out["seconds"].items():
            seconds[est] = seconds.get(est, 0.0) + t
    mc = {est: {name: np.concatenate(parts).sum(axis=0) for name, parts in stats.items()} for est, stats in sums.items()}
    return {"mc": mc, "token": {e: np.concatenate(v, axis=1) for e, v in token.items()}, "paths": paths,
            "steps": steps, "seconds": seconds, "cpu_s": time.process_time() - cpu0}


def _exact_cov(d: Design) -> dict[str, np.ndarray]:
    return d.__dict__.get("_exact_blocks", {})


def token_chain(d: Design, opts: RunOptions, trials: int) -> np.ndarray:
    """(len(token_times), trials): tr P̃(t) of Kar & Moura's token chain (20) at the token times, driven
    by an independent copy of the communication (stream ``token``)."""
    sc = d.scenario
    times = token_times(sc)
    n_units = -(-trials // RNG_UNIT)
    sizes = [min(RNG_UNIT, trials - u * RNG_UNIT) for u in range(n_units)]
    seeds = {s: block_seeds(stream_seed(opts.seed, "compare-token", s), n_units) for s in ("links", "gossip")}
    per_chunk = units_per_chunk(8.0 * (d.model.n ** 2 * 6 + d.topology.E * 4 + d.model.N * 4), opts.chunk_budget_bytes())
    parts = []
    for start in range(0, n_units, per_chunk):
        stop = min(start + per_chunk, n_units)
        links = UnitStreams(seeds["links"][start:stop], sizes[start:stop])
        gossip = UnitStreams(seeds["gossip"][start:stop], sizes[start:stop])
        B = sum(sizes[start:stop])
        tok = TokenSampler(d.model, d.links, B, gossip.integers(0, d.model.N))
        out = np.zeros((len(times), B))
        for k in range(sc.steps):
            if k in times:
                out[times.index(k)] = np.trace(tok.P, axis1=0, axis2=1)
            step = d.links.draw(links)
            prio = gossip.random((d.topology.E,)).T if (d.links.synchronous and d.links.kind != "matchings") else None
            tok.step(step, prio)
        parts.append(out)
    return np.concatenate(parts, axis=1)


def compute(sc: CompareScenario, opts: RunOptions, cache: StageCache) -> Results:
    trials = trial_count(sc, opts)
    d = compute_design(sc, opts, cache)
    code = code_fingerprint(CODE_MODULES)
    base = {"scenario": sc.key(), "quick": opts.quick, "code": code}
    def run_exact():
        with np.errstate(over="ignore", invalid="ignore"):     # a mean-square unstable filter's moments may overflow
            return compute_exact(d)

    exact = cache.get_or_compute("exact", base, run_exact, scenario=sc.name,
                                 allow_nonfinite=tuple(f"{e}__{k}" for e in d.estimators
                                                       for k in ("blocks", "mse", "disagreement", "own_cov")))
    d.__dict__["_exact_blocks"] = {k.split("__")[0]: v for k, v in exact.items()
                                   if k.endswith("__blocks") and k.split("__")[0] not in ("central", "local")
                                   and d.status[k.split("__")[0]][0]}
    mc_key = {**base, "seed": opts.seed, "trials": trials}

    def run_mc():
        with np.errstate(over="ignore", invalid="ignore"):     # a diverging filter's errors may overflow
            out = simulate(d, opts, trials)
        arrays = {f"{e}__{k}": v for e, stats in out["mc"].items() for k, v in stats.items()}
        arrays.update({f"token__{e}": v for e, v in out["token"].items()})
        arrays.update({f"path__{e}": v for e, v in out["paths"].items()})
        arrays["steps"] = out["steps"]
        return arrays

    mc_arrays = cache.get_or_compute("mc", mc_key, run_mc, scenario=sc.name,
                                     allow_nonfinite=tuple(f"path__{e}" for e in d.estimators) + ("path__x",) +
                                     tuple(f"{e}__{s}" for e in d.estimators for s in STATS + PER_TRIAL_SUMS)
                                     + tuple(f"token__{e}" for e in d.estimators))
    res = Results(sc, d, opts.seed, trials, opts.quick, mc_arrays["steps"])
    for key, value in exact.items():
        est, name = key.split("__", 1)
        (res.reference if est == "reference" else res.exact.setdefault(est, {}))[name] = value
    for key, value in mc_arrays.items():
        if key == "steps":
            continue
        head, name = key.split("__", 1)
        if head == "token":
            res.token[name] = value
        elif head == "path":
            res.paths[name] = value
        else:
            res.mc.setdefault(head, {})[name] = value
    if "gikf" in d.estimators:
        tok = cache.get_or_compute("token", {**mc_key, "stage": "token"},
                                   lambda: {"chain": token_chain(d, opts, trials)}, scenario=sc.name,
                                   allow_nonfinite=("chain",))
        res.token["chain"] = tok["chain"]
    return res
