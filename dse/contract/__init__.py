"""The one contract between the pipeline, the scenario families and their stages.

- `Family` (family.py): what a family declares (id, paper, intro, notes, scenario model,
  example, edge cases, and the shipped scenarios `dse list` expands on as `Declared`) and implements (scenario_from_dict, paper_scenarios, generate, claims,
  design, simulate, trials, cost, design_tables, tables, views). A run is a `Reproduction`.
- `stage` (stages.py): a cached computation whose key is derived from its arguments and the
  source of every module it imports; run through a `StageContext`.
- `ClaimSet` (claims.py): hypotheses and claims registered next to their checks, with declared
  gates (scope, per-scenario expansion, roles, hypotheses).
- `Cost` (cost.py): the estimated time and memory of a run; the driver refuses what cannot fit.
- `View`, `Outputs`, `recording` (views.py): figures and recordings, and the recording scaffold.
- `RunOptions` (options.py): seed, trials, quick, workers, memory budget.

Estimators for the compare arena implement `dse.estimators.protocol.BatchedFilter`.
"""
import importlib

# names loaded on first use: a stage module that imports `dse.contract.stages` does not load (nor
# depend on, for its cache key) the claims, views or family modules
_EXPORTS = {"ClaimSet": "claims", "Where": "claims", "example": "claims", "paper_only": "claims", "role": "claims",
            "Cost": "cost", "Computed": "family", "Declared": "family", "Family": "family", "Paper": "family", "Reproduction": "family",
            "RunOptions": "options", "Stage": "stages", "StageContext": "context", "StageResult": "stages", "stage": "stages",
            "Outputs": "views", "View": "views", "recording": "views"}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str):
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'dse.contract' has no attribute {name!r}")
    return getattr(importlib.import_module(f"dse.contract.{module}"), name)
