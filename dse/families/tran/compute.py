"""Stages of the coestimation family, each cached: the design (`design.py`: seed-free, then the noise
and exact fixed-role law of the seed), the deterministic runs (coestimation with time-varying and
fixed roles, each also at half the step; the comparison architecture), the stochastic Monte Carlo
(time-varying roles, fixed roles, fixed roles at half the step) and the centralized Kalman reference.

Runs stream over time: the integrator evaluates the input CHUNK_STEPS steps at a time and keeps
only the recorded samples (`simulation.record_dt`). The Monte Carlo streams over trials in RNG
units of 1,000 (`dse.simulate.units.run_units`, as many units at a time as the memory budget
allows) and keeps, per recorded time, the moments of V = zᵀPz over the trials (merged unit by
unit), the per-trial late-window mean of ‖z‖, the projections on the exact law's principal
directions at the check times, the final-time moments of every node's error, and the first
`stochastic.runs` trials whole. Results do not depend on the budget.
"""
from __future__ import annotations

import sys
from dataclasses import dataclass, field
from typing import Any

import numpy as np

import dse.estimators.input_state_coestimation as ce
import dse.estimators.observer_network_simulation as sim
import dse.estimators.sinusoid_sup  # noqa: F401  (imported for the code fingerprint)
from dse.engine.cache import StageCache, code_fingerprint
from dse.engine.progress import counter
from dse.engine.driver import RunOptions
from dse.simulate.seeding import stream_seed
from dse.simulate.units import run_jobs, run_units
from dse.simulate.stats import Moments

from .central_reference import central_deterministic, central_stochastic
from .design import (DESIGN_MAY_BE_NAN, LAW_MAY_BE_NAN, Design, coestimation, design_core, design_parts, fixed_law,
                     gains, input_signal, merge_design, step_operators, t_stochastic)
from .scenario import CoestimationScenario

CODE_MODULES = ("dse.estimators.common_lyapunov", "dse.estimators.input_state_coestimation", "dse.estimators.lyapunov_bounds",
                "dse.estimators.observer_network_simulation", "dse.estimators.exponential_integrators",
                "dse.estimators.sinusoid_sup", "dse.estimators.kalman_bucy", "dse.simulate.stats", "dse.simulate.units",
                "dse.families.tran.compute", "dse.families.tran.design", "dse.families.tran.central_reference",
                "dse.families.tran.scenario")
# a diverging run (an unstable error system: the hypotheses do not hold) is kept with its non-finite values
RUN_MAY_BE_NAN = ("x", "w", "e", "g", "V_mean", "V_m2", "V_max", "late_mean", "late_m2", "proj_mean", "proj_m2",
                  "final_mean", "final_m2", "final_sq_mean", "final_sq_m2", "xerr_mean", "werr_mean", "kept_x",
                  "kept_e", "kept_g", "EV", "mean_proj_h", "mean_proj_half", "mean_final", "det_s", "det_all_s", "sde_s")
#: deterministic and stochastic runs (the stochastic runs' names are SDE_RUNS)
SDE_RUNS = ("sde_roles", "sde_fixed", "sde_fixed_half")


@dataclass
class Results:
    scenario: CoestimationScenario
    seed: int
    trials: int
    quick: bool
    design: Design
    runs: dict[str, dict[str, np.ndarray]] = field(default_factory=dict)

    @property
    def P(self) -> np.ndarray:
        return self.design.P

    def signal(self) -> sim.SinusoidalInput:
        return input_signal(self.scenario)


def trial_count(sc: CoestimationScenario, opts: RunOptions) -> int:
    return opts.trials if opts.trials is not None else (sc.quick_trials if opts.quick else sc.trials)


def code() -> str:
    return code_fingerprint(CODE_MODULES)


# -- the design -----------------------------------------------------------------------------------

def design(sc: CoestimationScenario, quick: bool, seed: int, cache: StageCache | None = None, *,
           paper: bool = False, workers: int = 1) -> Design:
    """The design of the scenario for these options (through the stage cache when given); its independent parts
    in `workers` forked processes."""
    core, parts, law = design_stages(sc, quick, seed, cache, paper=paper)
    done = dict(zip(parts, run_jobs(list(parts.values()), workers, desc=f"{sc.name}: design")))
    return Design(sc, quick, seed, merge_design(core, done), law)


def design_stages(sc: CoestimationScenario, quick: bool, seed: int, cache: StageCache | None = None, *,
                  paper: bool = False) -> tuple[dict, dict[str, tuple], dict]:
    """(the design's core, its parts as (weight, job) — each a cached stage of its own —, the law of the seed)."""
    base = {"scenario": sc.key(), "code": code(), "quick": quick}

    def stage(name, key, fn, nan):
        return fn() if cache is None else cache.get_or_compute(name, key, fn, scenario=sc.name, allow_nonfinite=nan)
    core = stage("design", base, lambda: design_core(sc), DESIGN_MAY_BE_NAN)
    parts = {name: (w, lambda name=name, job=job: stage(f"design-{name}", base, job, DESIGN_MAY_BE_NAN))
             for name, (w, job) in design_parts(sc, quick, paper, core).items()}
    law = stage("law", {**base, "seed": seed}, lambda: fixed_law(sc, core, seed, quick), LAW_MAY_BE_NAN)
    return core, parts, law


# -- deterministic runs ---------------------------------------------------------------------------

def comparison(sc: CoestimationScenario, P_b_types: np.ndarray) -> ce.NetworkObserver:
    G = gains(sc)
    sig_b = np.array([sc.types[t].comparison_sigma for t in sc.node_type])
    P_b = np.stack([P_b_types[t] for t in sc.node_type])
    return ce.estimation_network(sc.A, sc.B, G["C"], G["L"], G["J"], G["K"], sig_b, P_b, sc.lap,
                                 sc.comparison_alpha, sc.gamma)


def role_law(sc: CoestimationScenario, fixed: bool):
    if fixed:
        return sim.FixedRoles(np.asarray(sc.fixed_active, float))
    if sc.role_mode == "fixed":
        return sim.FixedRoles(np.asarray(sc.roles_active, float))
    return sim.ProximityRoles(sc.positions, sc.radius, sc.beta, sc.position_states)


def _steps_bar(sc: CoestimationScenario, t_end: float, h: float, desc: str):
    return counter(int(round(t_end / h)), desc=f"{sc.name}: {desc}", unit="step")


def run_deterministic(sc: CoestimationScenario, net: ce.NetworkObserver, roles, h: float,
                      desc: str = "deterministic run") -> dict[str, np.ndarray]:
    every = int(round(sc.record_dt / h))
    with _steps_bar(sc, sc.t_end, h, desc) as bar:
        tr = sim.simulate(net, roles, input_signal(sc), sc.x0, sc.e0, t_end=sc.t_end, h=h, record_every=every,
                          allow_nonfinite=True, progress=lambda k: bar.update(k - bar.n))
    return {"t": tr.t, "w": tr.w, "x": tr.x[0], "e": tr.e[0], "g": tr.g[0]}


def deterministic_jobs(sc: CoestimationScenario, d: Design) -> dict[str, Any]:
    """The deterministic runs: name -> job. The `_half` twins are the step-halving check; with a stochastic
    step of its own, the fixed-role noise-free run at that step (and its half) is the exact mean of the SDE."""
    P = d.P
    tv, fx = role_law(sc, fixed=False), role_law(sc, fixed=True)
    jobs = {
        "coest": lambda: run_deterministic(sc, coestimation(sc, P), tv, sc.step, "coestimation"),
        "coest_half": lambda: run_deterministic(sc, coestimation(sc, P), tv, sc.step / 2, "coestimation, h/2"),
        "fixed": lambda: run_deterministic(sc, coestimation(sc, P), fx, sc.step, "fixed roles"),
        "fixed_half": lambda: run_deterministic(sc, coestimation(sc, P), fx, sc.step / 2, "fixed roles, h/2"),
    }
    if np.all(np.isfinite(d["P_comparison"])):
        jobs["comparison"] = lambda: run_deterministic(sc, comparison(sc, d["P_comparison"]), tv, sc.step, "comparison")
    if sc.sde_step != sc.step:
        jobs["fixed_sde"] = lambda: run_deterministic(sc, coestimation(sc, P), fx, sc.sde_step, "fixed roles, SDE step")
        jobs["fixed_sde_half"] = lambda: run_deterministic(sc, coestimation(sc, P), fx, sc.sde_step / 2,
                                                           "fixed roles, SDE step / 2")
    return jobs


def integration_error(runs: dict, run: str) -> dict[str, float]:
    """The step-halving estimate of a run: 2·max|Δ| between the run at h and at h/2 on the recorded samples
    (a first-order Richardson estimate, conservative for the second-order scheme and for role switches), the
    scale of the run, and the first time at which either is not finite (nan if none)."""
    a, b = runs[run], runs[f"{run}_half"]
    bad = ~np.isfinite(a["e"]).all(axis=(1, 2)) | ~np.isfinite(b["e"]).all(axis=(1, 2))
    if bad.any():
        return {"error": float("nan"), "scale": float("nan"), "t_bad": float(a["t"][np.argmax(bad)])}
    return {"error": 2.0 * float(np.abs(a["e"] - b["e"]).max()),
            "scale": max(1.0, float(np.abs(a["x"]).max()), float(np.abs(a["w"]).max()), float(np.abs(a["e"]).max())),
            "t_bad": float("nan")}


# -- stochastic runs ---------------------------------------------------------------------------------

def sde_bytes_per_trial(sc: CoestimationScenario, n_noise: int) -> int:
    """Memory of one trial in a chunk: the state, the integrator's and the reduction's temporaries, the
    noise draws and the per-trial accumulators."""
    D = sc.n + sc.N * sc.q
    return 8 * (12 * D + 3 * n_noise + 4 * sc.N + 8)


def _unit_moments(values: np.ndarray, edges: np.ndarray, outer: bool = False) -> list[Moments]:
    return [Moments.of(values[a:b], outer) for a, b in zip(edges[:-1], edges[1:])]


def run_stochastic(sc: CoestimationScenario, d: Design, *, fixed: bool, trials: int, seed: int, t_end: float,
                   keep: int, h: float, probes: dict[int, np.ndarray] | None = None,
                   budget_bytes: float = 2.0**27) -> dict[str, np.ndarray]:
    """All trials in RNG units of 1,000, as many units per chunk as `budget_bytes` allows; per recorded time
    the moments of V over the trials, the per-trial late-window mean of ‖z‖, the projections on `probes`
    ({record index: directions (k, Nq)}), the final-time moments of every node's error, mean node errors; the
    first `keep` trials whole."""
    P = d.P
    net = coestimation(sc, P)
    noise = d.noise
    prepared = step_operators(sc, P, noise, h)
    every = int(round(sc.record_dt / h))
    n_rec = int(round(t_end / sc.record_dt)) + 1
    t = np.arange(n_rec) * sc.record_dt
    late = t >= min(sc.tail_start, t[-1] / 2)
    Pbig = ce.block_diag(list(P))
    probes = probes or {}
    kept: dict[str, list] = {"x": [], "e": [], "g": []}
    done = [0]
    roles, signal = role_law(sc, fixed), input_signal(sc)
    bar = counter(int(round(t_end / h)) * trials, desc=f"{sc.name}: {'fixed' if fixed else 'time-varying'} roles, "
                  f"Monte Carlo at h = {h:g}", unit="trial-step")

    def chunk(streams):
        R, edges = streams.n, np.cumsum([0, *streams.sizes])
        U = len(streams.sizes)
        starts = edges[:-1]
        # per unit and recorded time: mean and M2 of V, sums of the mean node errors ‖x̃_i‖ and ‖w̃_i‖
        acc = {"V_mean": np.zeros((U, n_rec)), "V_m2": np.zeros((U, n_rec)), "V_max": np.full(U, -np.inf),
               "err_sums": np.zeros((U, 2, n_rec)), "late": np.zeros(R), "proj": {}, "final": None}
        sizes = np.asarray(streams.sizes, float)

        def reduce(t_now, x, w, e, g):
            k = int(round(t_now / sc.record_dt))
            z = ce.errors_from_estimates(x, w, e, sc.n)
            zf = z.reshape(R, -1)
            V = np.einsum("ri,ri->r", zf @ Pbig, zf)
            mean = np.add.reduceat(V, starts) / sizes
            acc["V_mean"][:, k] = mean
            acc["V_m2"][:, k] = np.add.reduceat(np.square(V - np.repeat(mean, streams.sizes)), starts)
            acc["V_max"] = np.maximum(acc["V_max"], np.maximum.reduceat(V, starts))
            sq = np.square(z)
            acc["err_sums"][:, 0, k] = np.add.reduceat(np.sqrt(sq[..., :sc.n].sum(-1)).mean(-1), starts)
            acc["err_sums"][:, 1, k] = np.add.reduceat(np.sqrt(sq[..., sc.n:].sum(-1)).mean(-1), starts)
            if late[k]:
                acc["late"] += np.sqrt(sq.reshape(R, -1).sum(-1))
            if k in probes:
                acc["proj"][k] = _unit_moments(zf @ probes[k].T, edges)
            if k == n_rec - 1:
                acc["final"] = (_unit_moments(z, edges, outer=True), _unit_moments(sq.sum(-1), edges))
            return None

        k_keep = max(0, min(keep - done[0], R))
        last = [0]

        def advanced(steps_done):
            bar.update(R * (steps_done - last[0]))
            last[0] = steps_done
        tr = sim.simulate(net, roles, signal, sc.x0, sc.e0, t_end=t_end, h=h, record_every=every, n_trials=R,
                          noise=noise, rng=streams, keep=k_keep, reducer=reduce, prepared=prepared, allow_nonfinite=True,
                          progress=advanced)
        for name in ("x", "e", "g"):
            if k_keep:
                kept[name].append(getattr(tr, name))
        done[0] += R
        late_mean = acc["late"] / max(int(late.sum()), 1)
        final, final_sq = acc["final"]
        parts = []
        for u, (a, b) in enumerate(zip(edges[:-1], edges[1:])):
            m = int(b - a)
            parts.append({"V": Moments(m, acc["V_mean"][u], acc["V_m2"][u]), "V_max": float(acc["V_max"][u]),
                          "err_sums": acc["err_sums"][u], "late": Moments.of(late_mean[a:b]),
                          "proj": {k: v[u] for k, v in acc["proj"].items()},
                          "final": final[u], "final_sq": final_sq[u]})
        return parts

    def fold(total, part):
        if total is None:
            return part
        return {"V": total["V"].merge(part["V"]), "V_max": max(total["V_max"], part["V_max"]),
                "err_sums": total["err_sums"] + part["err_sums"], "late": total["late"].merge(part["late"]),
                "proj": {k: total["proj"][k].merge(part["proj"][k]) for k in total["proj"]},
                "final": total["final"].merge(part["final"]), "final_sq": total["final_sq"].merge(part["final_sq"])}

    label = ("fixed" if fixed else "roles", h)
    n_noise = 0 if prepared.factors is None else len(prepared.factors)
    with bar:
        acc = run_units(chunk, fold, trials, stream_seed(seed, "tran", "sde", label),
                        bytes_per_trial=sde_bytes_per_trial(sc, n_noise), budget_bytes=budget_bytes)
    order = sorted(acc["proj"])
    out = {"t": t, "w": signal(t), "trials": np.array(acc["V"].count), "V_mean": acc["V"].mean, "V_m2": acc["V"].m2,
           "V_max": np.array(acc["V_max"]), "late_mean": np.array(acc["late"].mean), "late_m2": np.array(acc["late"].m2),
           "late_start": np.array(t[late][0]), "xerr_mean": acc["err_sums"][0] / trials,
           "werr_mean": acc["err_sums"][1] / trials,
           "final_mean": acc["final"].mean, "final_m2": acc["final"].m2, "final_sq_mean": acc["final_sq"].mean,
           "final_sq_m2": acc["final_sq"].m2, "probe_index": np.array(order, dtype=int)}
    if order:
        out["proj_mean"] = np.stack([acc["proj"][k].mean for k in order])
        out["proj_m2"] = np.stack([acc["proj"][k].m2 for k in order])
    for name in ("x", "e", "g"):
        out[f"kept_{name}"] = np.concatenate(kept[name]) if kept[name] else np.zeros((0,))
    return out


def fixed_means(sc: CoestimationScenario, d: Design, runs: dict) -> dict[str, np.ndarray]:
    """The exact mean part of the fixed-role law: the noise-free run at the stochastic step is the SDE's exact
    mean m(t), so E{V(t)} = m(t)ᵀPm(t) + tr(PΣ(t)) at every record time of the stochastic horizon; the means
    u_jᵀm of the projections at the check times, at h and h/2; m at the end of the horizon per node."""
    law = d.law
    names = {"h": "fixed" if sc.sde_step == sc.step else "fixed_sde",
             "half": "fixed_half" if sc.sde_step == sc.step else "fixed_sde_half"}
    n_law = len(law["tr_PSigma"])
    zf = {k: ce.errors_from_estimates(runs[r]["x"][:n_law], runs[r]["w"][:n_law], runs[r]["e"][:n_law], sc.n)
          for k, r in names.items()}
    Pbig = ce.block_diag(list(d.P))
    flat = {k: z.reshape(len(z), -1) for k, z in zf.items()}
    idx = law["probe_index"]
    return {"t": runs[names["h"]]["t"][:n_law],
            "EV": np.einsum("ti,ij,tj->t", flat["h"], Pbig, flat["h"]) + law["tr_PSigma"],
            **{f"mean_proj_{k}": np.einsum("ckd,cd->ck", law["probe_dirs"], z[idx]) for k, z in flat.items()},
            "mean_final": zf["h"][-1]}


def _announce(sc: CoestimationScenario, opts: RunOptions) -> None:
    """A long run says so before it starts (with its estimated time and memory)."""
    from .cost import LONG_RUN_S, estimate, human_seconds

    c = estimate(sc, opts)
    if c.seconds > LONG_RUN_S:
        print(f"{sc.name}: estimated {human_seconds(c.seconds)} and {c.peak_mib:,.0f} MiB peak memory ({c.detail})",
              file=sys.stderr)


def compute(sc: CoestimationScenario, opts: RunOptions, cache: StageCache, *, paper: bool = True) -> Results:
    from . import cost

    cost.refuse_if_too_large(sc, opts)
    _announce(sc, opts)
    trials = trial_count(sc, opts)
    core, parts, law = design_stages(sc, opts.quick, opts.seed, cache, paper=paper)
    d = Design(sc, opts.quick, opts.seed, core, law)      # the runs need the core only; the parts join their pool
    res = Results(sc, opts.seed, trials, opts.quick, d)
    base = {"scenario": sc.key(), "code": code()}
    t_sde = t_stochastic(sc, opts.quick)
    t_half = min(t_sde, sc.quick_t_end)
    law = d.law
    probes = {"sde_fixed": {int(k): u for k, u in zip(law["probe_index"], law["probe_dirs"])},
              "sde_fixed_half": {int(k): u for k, u in zip(law["probe_index"], law["probe_dirs"])
                                 if k * sc.record_dt <= t_half + 1e-9}}
    sde_key = {**base, "seed": opts.seed, "trials": trials}
    budget = opts.chunk_budget_bytes()

    def stage(name, key, fn):
        return lambda: cache.get_or_compute(name, key, fn, scenario=sc.name, allow_nonfinite=RUN_MAY_BE_NAN)

    def then(first, name, key, fn):
        """The stage `first`, then a stage computed from its result, in one job: (first's result, the second's)."""
        def job():
            out = first()
            return out, cache.get_or_compute(name, key, lambda: fn(out), scenario=sc.name, allow_nonfinite=RUN_MAY_BE_NAN)
        return job

    def sde_job(name, fixed, h, t_end):
        return (cost.sde_seconds(sc, trials, t_end / h, fixed, budget),
                stage(name, {**sde_key, "t_end": t_end, "h": h},
                      lambda: run_stochastic(sc, d, fixed=fixed, trials=trials, seed=opts.seed, t_end=t_end, keep=sc.runs,
                                             h=h, probes=probes.get(name), budget_bytes=budget)))
    det = deterministic_jobs(sc, d)
    jobs = {name: (cost.deterministic_seconds(sc, name), stage(f"det-{name}", base, job)) for name, job in det.items()}
    jobs.update(sde_roles=sde_job("sde_roles", False, sc.sde_step, t_sde),
                sde_fixed=sde_job("sde_fixed", True, sc.sde_step, t_sde),
                sde_fixed_half=sde_job("sde_fixed_half", True, sc.sde_step / 2, t_half))
    # the centralized Kalman filter follows the run it filters, in the same job
    kf_steps = sc.t_end / sc.kf_dt
    w, job = jobs["coest"]
    jobs["coest"] = (w + 2 * kf_steps * cost.KF_STEP_S, then(job, "central-det", base, lambda run: central_deterministic(sc, run)))
    w, job = jobs["sde_roles"]
    jobs["sde_roles"] = (w + t_sde / sc.kf_dt * cost.KF_STEP_S,
                         then(job, "central-sde", {**base, "seed": opts.seed, "t_end": t_sde},
                              lambda run: central_stochastic(sc, run, d.noise)))
    jobs.update({f"design-{name}": job for name, job in parts.items()})
    # every run and the design's parts at once: the lighter jobs fill in around the Monte Carlo
    done = dict(zip(jobs, run_jobs(list(jobs.values()), opts.workers, desc=f"{sc.name}: runs and Monte Carlo")))
    d.arrays = merge_design(core, {name: done.pop(f"design-{name}") for name in parts})
    (done["coest"], central_det), (done["sde_roles"], central_sde) = done["coest"], done["sde_roles"]
    res.runs.update(done)
    d.integration = {run: integration_error(res.runs, run) for run in ("coest", "fixed")}
    res.runs["exact_fixed"] = fixed_means(sc, d, res.runs)
    res.runs["central"] = {**central_det, **central_sde}
    return res
