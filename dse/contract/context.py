"""Where a run's stages are computed: the stage cache, and the record of what ran.

Kept apart from `dse.contract.stages` (the declaration of a stage and its key): how a stage is run
(cached, in a forked worker) does not change what it computes, so it is not part of any stage's code.
"""
from __future__ import annotations

import traceback
from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np

from dse.contract.stages import Stage, StageResult, code_hash
from dse.errors import NumericalLimit
from dse.simulate import checkpoints, executor  # executor: registers how portable Monte Carlo runs (run_units)

#: what LAPACK says when a matrix is singular, indefinite or ill-conditioned at working precision
#: (other LinAlgErrors, such as a non-square argument, are defects and propagate as they are)
NUMERICAL_LINALG = ("singular", "not positive definite", "did not converge")


def beyond_float64(exc: Exception, stage: str, scenario: str) -> Exception:
    """A LinAlgError of a valid scenario's stage as a NumericalLimit naming the stage, the scenario and
    the function of ours that failed (a matrix singular to working precision, an SVD of overflowed
    entries: numbers too far apart, such as a plant that multiplies by 1e10 each step); any other
    exception unchanged."""
    if not any(word in str(exc).lower() for word in NUMERICAL_LINALG):
        return exc
    ours = [f for f in traceback.extract_tb(exc.__traceback__) if "/dse/" in f.filename.replace("\\", "/")]
    where = f" in {ours[-1].name} ({ours[-1].filename.rsplit('/dse/', 1)[-1]}:{ours[-1].lineno})" if ours else ""
    return NumericalLimit(f"stage '{stage}', scenario '{scenario}': {exc}{where}: the linear algebra fails at "
                          "working precision (the scenario's numbers are too far apart to compute with)")


@dataclass
class StageContext:
    """Where a run's stages are computed: the stage cache and the record of what ran."""

    cache: Any                                     # dse.engine.cache.StageCache (or MemoryCache)
    ran: list[dict[str, Any]] = field(default_factory=list)

    def run(self, st: Stage, *args, **kwargs) -> StageResult:
        """The stage's result for these arguments: from the cache, or computed and stored."""
        arguments = st.bound(args, kwargs)
        params = st.params(arguments)
        key = self.cache.key(st.name, params)
        scenario = next((str(getattr(v, "name", "")) for v in arguments.values() if callable(getattr(v, "key", None))
                         and not isinstance(v, StageResult)), "")
        computed = []
        units_dir = self.cache.units_dir(key)

        def compute():
            computed.append(True)
            try:
                # an overflow or a NaN inside a stage is not printed: the stage's arrays are checked
                # finite when stored (NumericalError naming the array) unless it declares them allowed;
                # its finished Monte Carlo units are kept in `units_dir` until its entry is stored
                with np.errstate(over="ignore", invalid="ignore", divide="ignore"), \
                        checkpoints.stage_scope(units_dir, fresh=self.cache.fresh):
                    return st.fn(**arguments)
            except np.linalg.LinAlgError as exc:
                raise beyond_float64(exc, st.name, scenario) from exc

        arrays = self.cache.get_or_compute(st.name, params, compute, scenario=scenario,
                                           allow_nonfinite=st.nonfinite_allowed(arguments))
        if computed:
            checkpoints.finish_stage(units_dir)
        self.ran.append({"name": st.name, "key": key, "cached": not computed})
        out = StageResult(arrays)
        out.key = key
        return out

    def run_many(self, calls: Sequence[tuple[Stage, tuple, dict]], *, workers: int = 1, desc: str = "",
                 weights: Sequence[float] | None = None) -> list[StageResult]:
        """`run` for several (stage, args, kwargs) calls, in `workers` forked processes, the heaviest
        (by `weights`) first; results in the order of `calls`, and the stages the workers ran recorded
        here. Each call stores its own cache entry, so an interrupted run resumes call by call. The run's unit
        executor may ask for fewer processes (`dse.simulate.executor`: none when the units go to a cluster)."""
        from dse.simulate.units import run_jobs

        def job(st: Stage, args: tuple, kwargs: dict):
            def go():
                sub = StageContext(self.cache)
                out = sub.run(st, *args, **kwargs)
                return dict(out), out.key, sub.ran
            return go

        weights = list(weights) if weights is not None else [1.0] * len(calls)
        if workers > 1 and len(calls) > 1:
            for st in {c[0] for c in calls}:     # each stage's code hash once, here, inherited by the forked workers
                code_hash(st.module)
        results = []
        jobs = [(w, job(*c)) for w, c in zip(weights, calls)]
        for arrays, key, ran in run_jobs(jobs, executor.current().stage_workers(workers), desc=desc):
            self.ran.extend(ran)
            out = StageResult(arrays)
            out.key = key
            results.append(out)
        return results
