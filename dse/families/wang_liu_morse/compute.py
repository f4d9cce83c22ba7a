"""Stages of the hybrid-observer family, through the stage cache: the design (deterministic,
`design.py`), the sampled checks of Lemmas 5 and 6, and one streamed simulation per run
(`bounds.py`: the interval plan, then the trials in RNG units within the memory budget)."""
from __future__ import annotations

import functools
from dataclasses import dataclass, field
from typing import Any

import numpy as np

import dse.estimators.hybrid_observer as ho
from dse.engine.cache import StageCache, code_fingerprint
from dse.engine.driver import RunOptions
from dse.simulate.units import parallel_map

from . import bounds
from .design import Design, MultiDesign, design_quantities, lemma_samples, model_mismatch, observer_design
from .scenario import HybridScenario, RunSpec

CODE_MODULES = ("dse.estimators.hybrid_observer", "dse.estimators.jointly_observable_design",
                "dse.families.wang_liu_morse.bounds", "dse.families.wang_liu_morse.design",
                "dse.families.wang_liu_morse.compute", "dse.families.wang_liu_morse.scenario")


@dataclass
class Results:
    scenario: HybridScenario
    seed: int
    trials: int
    quick: bool
    design: dict
    samples: dict
    runs: dict = field(default_factory=dict)
    is_paper: bool = False

    def spec(self, name: str) -> RunSpec:
        return next(r for r in self.scenario.runs if r.name == name)

    @property
    def obs(self) -> ho.ObserverDesign:
        if "_obs" not in self.__dict__:
            self.__dict__["_obs"] = observer_design(self.scenario)
        return self.__dict__["_obs"]


@dataclass
class MultiResults:
    """The paper reproduction checks two systems: the paper's example and a generic one."""

    parts: dict

    def __getitem__(self, key: str) -> Results:
        return self.parts[key]

    def design(self) -> MultiDesign:
        return MultiDesign({k: Design(r.scenario, r.design) for k, r in self.parts.items()})


def trial_count(sc: HybridScenario, opts: RunOptions) -> int:
    return opts.trials if opts.trials is not None else (sc.quick_trials if opts.quick else sc.trials)


def _base(sc: HybridScenario) -> dict[str, Any]:
    return {"scenario": sc.key(), "code": code_fingerprint(CODE_MODULES)}


#: design arrays that may hold inf or NaN: padding of unequal spectra, c_i of a defective local observer,
#: the vertex-loss placeholders, and r of (22) beyond the float range for many agents (exact as text beside)
DESIGN_NONFINITE = ("local_eigs", "vertex_loss_rho", "c_i", "r_lemma5", "r_printed", "r_lemma5_paper",
                    "r_printed_paper", "one_minus_alpha_log10", "one_minus_alpha_log10_paper")


def design_stage(sc: HybridScenario, seed: int, cache: StageCache, extras: bool = False) -> dict:
    """`extras`: the design quantities only the paper's own claims use (see `design_quantities`),
    but Section 4's model-mismatch demonstration (a task of its own in `compute_all`)."""
    return cache.get_or_compute("design", {**_base(sc), "seed": seed, "extras": extras, "mismatch": False},
                                lambda: design_quantities(sc, seed, extras, mismatch=False), scenario=sc.name,
                                allow_nonfinite=DESIGN_NONFINITE)


def _cached_run(cache: StageCache, base: dict, sc: HybridScenario, design: dict, seed: int, trials: int,
                budget: float, run: RunSpec) -> dict[str, np.ndarray]:
    def work():
        return bounds.simulate_run(sc, design, run, trials, seed, budget)

    return cache.get_or_compute("run", {**base, "run": run.key(), "seed": seed, "trials": trials if run.mc else 1},
                                  work, scenario=f"{sc.name}/{run.name}",
                                  allow_nonfinite=tuple(k for k in _result_keys() if k not in bounds.MUST_BE_FINITE))


def _result_keys() -> list[str]:
    """Every array name a run's result may hold (all but MUST_BE_FINITE may hold NaN or inf)."""
    names = ["A_mixed", "B_mixed", "G_mixed", "A_2", "B_2", "Phi_max", "tau0", "g_t_ns", "g_mean", "g_max",
             "g_central_mean", "ev_sd", "ev_central_sd", "net_sd", "ev_central_mean", "bound51_max", "ratio51_s",
             "net_mean"]
    names += [f"t0_{k}" for k in ("e_pre", "ebar", "x_nominal", "central", "floor", "carried", "carried_sym",
                                  "bound41", "bound51", "x", "xhat", "xc", "err", "cerr", "xnorm", "kf", "z")]
    names += [f"w_{w}_{f}" for w in bounds.WORST for f in bounds.Worst.FIELDS]
    names += [f"max_{k}" for k in bounds.MAXIMA] + [f"trial_{k}" for k in ("fit_rate", "e0", "eb0")]
    return names


def _samples(cache: StageCache, sc: HybridScenario, seed: int) -> dict[str, np.ndarray]:
    return cache.get_or_compute("samples", {**_base(sc), "seed": seed}, lambda: lemma_samples(sc, seed),
                                scenario=sc.name)


def _task(cache: StageCache, scenarios: dict, designs: dict, seed: int, trials: dict, budget: float,
          task: tuple[str, RunSpec | str]) -> dict[str, np.ndarray]:
    """One task of `compute_all`: a scenario's sampled Lemma 5/6 checks ("samples"), its model-mismatch
    demonstration ("mismatch") or one of its runs."""
    key, what = task
    sc = scenarios[key]
    if what == "samples":
        return _samples(cache, sc, seed)
    if what == "mismatch":
        return cache.get_or_compute("mismatch", {**_base(sc), "seed": seed}, lambda: model_mismatch(sc, seed),
                                    scenario=sc.name)
    return _cached_run(cache, _base(sc), sc, designs[key], seed, trials[key], budget, what)


def compute_all(scenarios: dict[str, HybridScenario], opts: RunOptions, cache: StageCache, *,
                extras: bool = False) -> MultiResults:
    """Every scenario's design, then its sampled lemma checks and its runs as one set of tasks over
    the workers, the longest first (by the cost model) so that the workers finish together."""
    from .cost import MISMATCH_S, run_cost, sample_seconds

    designs = {k: design_stage(sc, opts.seed, cache, extras) for k, sc in scenarios.items()}
    trials = {k: trial_count(sc, opts) for k, sc in scenarios.items()}
    budget = opts.chunk_budget_bytes()
    tasks, costs = [], []
    for k, sc in scenarios.items():
        n_i = [int(v) for v in designs[k]["n_i"]]
        tasks += [(k, "samples")] + ([(k, "mismatch")] if extras else [])
        costs += [sample_seconds(sc)] + ([MISMATCH_S] if extras else [])
        for run in sc.runs:
            tasks.append((k, run))
            costs.append(run_cost(sc, run, trials[k], n_i, budget)["seconds"])
    order = sorted(range(len(tasks)), key=lambda i: -costs[i])
    outs = parallel_map(functools.partial(_task, cache, scenarios, designs, opts.seed, trials, budget),
                        [tasks[i] for i in order], workers=opts.workers,
                        desc=f"hybrid observer: {sum(len(sc.runs) for sc in scenarios.values())} runs, lemma samples")
    done = {(tasks[i][0], getattr(tasks[i][1], "name", tasks[i][1])): out for i, out in zip(order, outs)}
    return MultiResults({k: Results(sc, opts.seed, trials[k], opts.quick, {**designs[k], **done.get((k, "mismatch"), {})},
                                    done[(k, "samples")], {r.name: done[(k, r.name)] for r in sc.runs}, k == "paper")
                         for k, sc in scenarios.items()})
