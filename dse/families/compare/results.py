"""The results the claims and tables read, and the run of the stages (`stages`) that produce them."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from dse.contract.context import StageContext
from dse.contract.stages import StageResult
from dse.estimators.network_comparison import Stats, stats

from .design import Design
from .scenario import CompareFile
from .stages import EARLY_STEPS, exact_moments, filterpy_reference, monte_carlo, rebuilt, token_chain, tune


def design(sc: CompareFile, quick: bool, ctx: StageContext, estimators: tuple) -> Design:
    tuned = ctx.run(tune, sc, quick, estimators)
    d = rebuilt(sc, quick, tuned, estimators)
    d.tuning_stage = tuned
    return d


@dataclass
class Results:
    scenario: CompareFile
    design: Design
    seed: int
    trials: int
    steps: np.ndarray                                   # recorded steps
    exact: dict[str, dict[str, np.ndarray]] = field(default_factory=dict)
    mc: dict[str, dict[str, np.ndarray]] = field(default_factory=dict)   # folded sums per estimator
    token: dict[str, np.ndarray] = field(default_factory=dict)
    paths: dict[str, np.ndarray] = field(default_factory=dict)
    reference: dict[str, np.ndarray] = field(default_factory=dict)
    faults: dict[str, str] = field(default_factory=dict)          # plug-in filter -> what it did wrong

    def stats(self, est: str) -> Stats:
        """Means and standard errors of an estimator's Monte Carlo sums."""
        return stats(self.mc[est], self.trials, self.scenario.simulation.steps, self.is_reference(est))

    def is_reference(self, est: str) -> bool:
        return self.design.estimators[est].spec.reference

    def exact_at(self, est: str, moment: str = "mse") -> np.ndarray | None:
        """An exact moment ((S, W) mean-square error, (S,) disagreement) at the recorded steps, or None."""
        ex = self.exact.get(est, {})
        return ex[moment][self.steps] if moment in ex else None

    @property
    def eval_index(self) -> int:
        return int(np.searchsorted(self.steps, self.scenario.simulation.eval_step))

    def check_indices(self) -> list[int]:
        """Recorded steps at which the claims compare: the first two (where a wrong start or a wrong first
        prediction shows most), the middle of the horizon and the evaluation step."""
        s = self.scenario.simulation
        return sorted(int(np.searchsorted(self.steps, k)) for k in set(EARLY_STEPS) | {s.eval_step, s.steps // 2}
                      if k in set(self.steps.tolist()))


def _nested(arrays: StageResult) -> dict[str, dict[str, np.ndarray]]:
    """'<head>__<name>' arrays as {head: {name: array}} (arrays without a head left out)."""
    out: dict[str, dict[str, np.ndarray]] = {}
    for key, value in arrays.items():
        head, _, name = key.partition("__")
        if name:
            out.setdefault(head, {})[name] = value
    return out


def simulate(sc: CompareFile, d: Design, seed: int, trials: int, quick: bool, workers: int, budget_bytes: float,
             ctx: StageContext) -> Results:
    """Every stage after the design, gathered for the claims and the tables."""
    keyed = (sc, quick, d.tuning_stage)
    exact = ctx.run(exact_moments, *keyed, d.specs)
    mc = ctx.run(monte_carlo, *keyed, exact, seed, trials, d.specs, workers, budget_bytes)
    sums, moments = _nested(mc), _nested(exact)
    faults = {**{e: str(v) for e, v in moments.pop("fault", {}).items()},
              **{e: str(v) for e, v in sums.pop("fault", {}).items()}}
    res = Results(sc, d, seed, trials, mc["steps"], moments, token=sums.pop("token", {}),
                  paths=sums.pop("path", {}), mc=sums, faults=faults)
    if "central" in d.running:
        res.reference = dict(ctx.run(filterpy_reference, sc))
    if res.token:                       # a filter that swaps states ran: the law of its random node's covariance
        res.token["chain"] = ctx.run(token_chain, sc, seed, trials, budget_bytes)["chain"]
    return res
