"""dse: distributed state estimation, reproduced. The Python entry point (see `dse.api`).

    import dse
    run = dse.run("my_scenario.toml", trials=5000)      # or a dict, or dse.paper("savas")
    run.counts, run.hypotheses, run.claims, run.tables["nodes"]
    run.write("out/run/mine")                          # files only when asked
    dse.check("my_scenario.toml").estimate             # validate and estimate, no simulation

The names below are loaded on first use, so that `import dse.estimators.kalman` (or the
command line, which limits BLAS threads before numpy loads) does not import the whole
pipeline.
"""
from __future__ import annotations

import importlib
import os

#: Rerun's Rust side logs write failures (a full disk) as coloured lines on stderr, and reads
#: RUST_LOG once, when `rerun` is first imported: off unless the user set it. A recording that
#: could not be written is an error of ours instead (dse.outputs.record.recording), one line.
RUST_LOG_SET_HERE = "RUST_LOG" not in os.environ
os.environ.setdefault("RUST_LOG", "off")

_EXPORTS = {"Check": "dse.api", "Run": "dse.api", "check": "dse.api", "execute": "dse.api", "load": "dse.api",
            "paper": "dse.api", "run": "dse.api", "ScenarioError": "dse.errors", "UsageError": "dse.errors",
            "OutputError": "dse.errors", "NumericalError": "dse.errors", "NumericalLimit": "dse.errors",
            "RunOptions": "dse.engine.driver"}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str):
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'dse' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_EXPORTS))
