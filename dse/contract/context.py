"""Where a run's stages are computed: the stage cache, and the record of what ran.

Kept apart from `dse.contract.stages` (the declaration of a stage and its key): how a stage is run
(cached, in a forked worker) does not change what it computes, so it is not part of any stage's code.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Sequence

from dse.contract.stages import Stage, StageResult


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

        def compute():
            computed.append(True)
            return st.fn(**arguments)

        arrays = self.cache.get_or_compute(st.name, params, compute, scenario=scenario,
                                           allow_nonfinite=st.nonfinite_allowed(arguments))
        self.ran.append({"name": st.name, "key": key, "cached": not computed})
        out = StageResult(arrays)
        out.key = key
        return out

    def run_many(self, calls: Sequence[tuple[Stage, tuple, dict]], *, workers: int = 1, desc: str = "",
                 weights: Sequence[float] | None = None) -> list[StageResult]:
        """`run` for several (stage, args, kwargs) calls, in `workers` forked processes, the heaviest
        (by `weights`) first; results in the order of `calls`, and the stages the workers ran recorded
        here. Each call stores its own cache entry, so an interrupted run resumes call by call."""
        from dse.simulate.units import run_jobs

        def job(st: Stage, args: tuple, kwargs: dict):
            def go():
                sub = StageContext(self.cache)
                out = sub.run(st, *args, **kwargs)
                return dict(out), out.key, sub.ran
            return go

        weights = list(weights) if weights is not None else [1.0] * len(calls)
        results = []
        for arrays, key, ran in run_jobs([(w, job(*c)) for w, c in zip(weights, calls)], workers, desc=desc):
            self.ran.extend(ran)
            out = StageResult(arrays)
            out.key = key
            results.append(out)
        return results
