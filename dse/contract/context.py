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

    def is_stored(self, st: Stage, *args, **kwargs) -> bool:
        """Whether `run` would read this call's result back from the cache (nothing to compute)."""
        return self.cache.has(st.name, st.params(st.bound(args, kwargs)))

    def run_many(self, calls: Sequence[tuple[Stage, tuple, dict]], *, workers: int = 1, desc: str = "",
                 weights: Sequence[float] | None = None, seconds: bool = False,
                 preload: Sequence[str] = ()) -> list[StageResult]:
        """`run` for several (stage, args, kwargs) calls, in `workers` forked processes, the heaviest
        (by `weights`) first; results in the order of `calls`, and the stages the workers ran recorded
        here. Each call stores its own cache entry, so an interrupted run resumes call by call. The run's unit
        executor may ask for fewer processes (`dse.simulate.executor`: none when the units go to a cluster, whose
        stages then compute a few at a time in threads of this process, `stage_threads`).

        Workers are started only for what is left to compute: calls already in the cache are read back here,
        and when `seconds` says the weights are the cost model's estimates in seconds, calls whose work in
        parallel would save less than starting the workers costs (`worth_forking`) run here too. `preload`
        names modules the stages import on first use (a library that takes a second to import): they are
        imported here before the workers fork, once, instead of once per worker. Where the calls run never
        changes their results (each is a seeded stage)."""
        import importlib

        from dse.simulate.units import run_jobs, run_threads

        def job(st: Stage, args: tuple, kwargs: dict):
            def go():
                sub = StageContext(self.cache)
                out = sub.run(st, *args, **kwargs)
                return dict(out), out.key, sub.ran
            return go

        weights = list(weights) if weights is not None else [1.0] * len(calls)
        runner = executor.current()
        workers, threads = runner.stage_workers(workers), runner.stage_threads()
        if (workers > 1 or threads > 1) and len(calls) > 1:
            left = [w for w, (st, args, kwargs) in zip(weights, calls) if not self.is_stored(st, *args, **kwargs)]
            if not worth_forking(left, workers, seconds=seconds):
                workers = 1
            if len(left) <= 1:
                threads = 1
        if workers > 1 and len(calls) > 1:
            for st in {c[0] for c in calls}:     # each stage's code hash once, here, inherited by the forked workers
                code_hash(st.module)
            for name in preload:
                importlib.import_module(name)
        results = []
        jobs = [(w, job(*c)) for w, c in zip(weights, calls)]
        done = run_threads(jobs, threads) if workers <= 1 and threads > 1 else run_jobs(jobs, workers, desc=desc)
        for arrays, key, ran in done:
            self.ran.extend(ran)
            out = StageResult(arrays)
            out.key = key
            results.append(out)
        return results


#: what starting forked workers costs a run beyond its work, in seconds of the reference machine (the cost model's
#: unit): the fork of a process holding numpy, pandas and the scenario, the pool's pipes, the results pickled back
#: (measured about 0.15 s on a loaded 2-core machine three times slower than the reference one)
WORKER_START_S = 0.1


def worth_forking(left: Sequence[float], workers: int, *, seconds: bool) -> bool:
    """Whether running the calls still to compute (their weights `left`) in `workers` processes saves more than the
    workers cost to start. Without estimates in seconds (`seconds` False) any two calls are worth it."""
    if len(left) <= 1:
        return False
    if not seconds:
        return True
    serial = sum(left)
    parallel = max(max(left), serial / min(workers, len(left)))
    return serial - parallel > WORKER_START_S
