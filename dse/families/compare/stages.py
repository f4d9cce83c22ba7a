"""Stages of the compare family: the design (the estimators' gain searches), the exact moments, the
centralized filter against filterpy, the Monte Carlo of every estimator on common random numbers (streamed in
RNG units, folded in unit order), and Kar & Moura's token chain (run in that order by `results.simulate`).
The estimators' declarations are stage arguments: each is keyed by its name and the code of its module.

Random streams (`dse.simulate.seeding`), under ``compare``: ``plant`` (x(0), w, v), ``links`` (the link
draws), ``noise`` (communication noise), ``gossip`` (the swap matchings' priorities and the random node q of
the token law); under ``compare-token``: an independent copy of the communication driving the token chain.
A trial's numbers depend only on the seed and its index, never on the memory chunk, on how the
estimators are split over workers, or on where the units ran (with one worker, or ``--scheduler inline``,
``local`` or a cluster's address, the Monte Carlo's units go to the run's unit executor).
"""
from __future__ import annotations

import numpy as np

from dse.contract.stages import StageResult, stage
from dse.estimators.network_comparison import PER_TRIAL_SUMS, STATS, Setup, record_steps, unit_chunks
from dse.estimators.network_comparison import simulate as simulate_trials
from dse.simulate import executor

from .design import Design, design_of
from .scenario import CompareFile

#: the exact moments kept per estimator (`protocol.DesignedEstimator.exact_moments`)
MOMENTS = ("blocks", "mse", "disagreement", "own_cov")


def token_times(sc: CompareFile) -> tuple[int, ...]:
    K = sc.simulation.steps
    return tuple(sorted({max(1, K // 4), max(1, K // 2), K - 1}))


#: the first steps, recorded and checked by the claims that compare the simulation with exact laws
EARLY_STEPS = (0, 1)


def recorded(sc: CompareFile) -> tuple[int, ...]:
    s = sc.simulation
    return record_steps(s.steps, extra=EARLY_STEPS + (s.eval_step, s.steps // 2) + token_times(sc))


def rebuilt(sc: CompareFile, quick: bool, tuned: StageResult, estimators) -> Design:
    """The design from the design stage's numbers (no search)."""
    return design_of(sc, quick, dict(zip(tuned["names"].tolist(), tuned["values"].tolist())), estimators)


@stage(name="design", allow_nonfinite=("values",))
def tune(sc: CompareFile, quick: bool, estimators: tuple) -> dict[str, np.ndarray]:
    """The numbers the estimators' designs searched for, by name (an unstable gain's steady state is inf)."""
    tuned = design_of(sc, quick, {}, estimators).network.tuned
    return {"names": np.array(list(tuned), dtype=str), "values": np.array([float(v) for v in tuned.values()])}


@stage(allow_nonfinite=lambda estimators, **_: tuple(f"{e.name}__{k}" for e in estimators for k in MOMENTS))
def exact_moments(sc: CompareFile, quick: bool, tuned: StageResult, estimators: tuple) -> dict[str, np.ndarray]:
    """'<estimator>__<moment>' of every running estimator whose exact moments are computed."""
    from dse.plugin.harness import PluginFault

    d = rebuilt(sc, quick, tuned, estimators)
    out = {}
    with np.errstate(over="ignore", invalid="ignore"):     # a mean-square unstable filter's moments may overflow
        for name, est in d.running.items():
            if est.exact:
                try:
                    ex = est.exact_moments()
                except PluginFault as fault:               # a plug-in's matrices: its fault, reported, not ours
                    out[f"fault__{name}"] = np.array(str(fault))
                    continue
                out.update({f"{name}__{k}": ex[k] for k in MOMENTS if k in ex})
    return out


@stage(name="reference")
def filterpy_reference(sc: CompareFile) -> dict[str, np.ndarray]:
    """The centralized filter against filterpy's KalmanFilter (`central.filterpy_differences`)."""
    from dse.estimators.network.central import filterpy_differences

    return filterpy_differences(sc.model, min(sc.simulation.steps, 50))


# -- the Monte Carlo ----------------------------------------------------------------------------------------

def _mc_nonfinite(estimators, **_) -> tuple[str, ...]:
    names = [e.name for e in estimators]
    return (tuple(f"path__{e}" for e in names) + ("path__x",) + tuple(f"{e}__{s}" for e in names for s in STATS +
            PER_TRIAL_SUMS) + tuple(f"token__{e}" for e in names))


@stage(unkeyed=("workers", "budget_bytes"), allow_nonfinite=_mc_nonfinite)
def monte_carlo(sc: CompareFile, quick: bool, tuned: StageResult, exact: StageResult, seed: int, trials: int,
                estimators: tuple, workers: int, budget_bytes: float) -> dict[str, np.ndarray]:
    """Every running estimator on `trials` trials (`network_comparison.simulate`, the estimators split over
    `workers` forked processes, or with one worker, the units on the run's unit executor): '<estimator>__<sum>',
    the token law 'token__<estimator>', the sample paths 'path__<estimator>', what a failed plug-in did
    'fault__<estimator>' and the recorded 'steps'. The joint-moment filters' exact covariances give the NEES of
    their exact law."""
    from .cost import time_limits

    d = rebuilt(sc, quick, tuned, estimators)
    d.network.shared.update(trials=trials, time_limits=time_limits(sc, trials))     # for the plug-ins' pace
    exact_cov = {name: exact[f"{name}__blocks"] for name, est in d.running.items()
                 if est.spec.joint_moments and f"{name}__blocks" in exact}
    setup = Setup(d.model, d.links, sc.simulation.steps, d.running, exact_cov=exact_cov, token_times=token_times(sc),
                  n_paths=sc.simulation.paths, record_steps=recorded(sc))
    with np.errstate(over="ignore", invalid="ignore"):     # a diverging filter's errors may overflow
        out = simulate_trials(setup, seed, trials, budget_bytes, executor.current().stage_workers(workers),
                              label="compare")
    arrays = {f"{e}__{k}": v for e, sums in out["mc"].items() for k, v in sums.items()}
    arrays.update({f"token__{e}": v for e, v in out["token"].items()})
    arrays.update({f"path__{e}": v for e, v in out["paths"].items()})
    arrays.update({f"fault__{e}": np.array(what) for e, what in out["faults"].items()})
    arrays["steps"] = out["steps"]
    return arrays


@stage(unkeyed=("budget_bytes",), allow_nonfinite=("chain",))
def token_chain(sc: CompareFile, seed: int, trials: int, budget_bytes: float) -> dict[str, np.ndarray]:
    """(len(token_times), trials): tr P̃(t) of Kar & Moura's token chain (20) at the token times, driven
    by an independent copy of the communication (streams ``compare-token``)."""
    from dse.estimators.gossip_swap_kalman import token_chain_traces

    m, lm = sc.model, sc.link_model
    chunks = unit_chunks(seed, "compare-token", ("links", "gossip"), trials,
                         8.0 * (m.n ** 2 * 6 + lm.topology.E * 4 + m.N * 4), budget_bytes)
    return {"chain": np.concatenate([token_chain_traces(m, lm, sc.simulation.steps, token_times(sc), links, gossip)
                                     for links, gossip in chunks], axis=1)}
