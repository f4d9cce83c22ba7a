"""The estimators of the compare arena: every module of this package declares one, as its module-level
`ESTIMATOR` (a `dse.estimators.protocol.NetworkEstimator`); modules whose names start with "_" hold what
several declarations share. The registry finds them by scanning the package, so adding an estimator is
adding a module (and its test), with no registration line. `register` adds one declared elsewhere (a
test's; third-party packages will come through an entry point group).

The compare harness, design, cost model, claims, tables, generator and the scenario's `[estimators]`
keys all read `registry()`.
"""
from __future__ import annotations

import dataclasses
import functools
import importlib
import pkgutil
from typing import Annotated

from pydantic import AfterValidator

from dse.estimators.protocol import NetworkEstimator

_REGISTERED: dict[str, NetworkEstimator] = {}


@functools.lru_cache(maxsize=1)
def builtin() -> tuple[NetworkEstimator, ...]:
    """The declarations of this package's modules (each tagged with its module, for the stage keys)."""
    found = []
    for info in pkgutil.iter_modules(__path__):
        if info.name.startswith("_"):
            continue
        module = importlib.import_module(f"{__name__}.{info.name}")
        found.append(dataclasses.replace(module.ESTIMATOR, module=module.__name__))
    return tuple(found)


def registry() -> dict[str, NetworkEstimator]:
    """name -> declaration, in the order of the tables (by rank)."""
    every = list(builtin()) + list(_REGISTERED.values())
    names = [e.name for e in every]
    if len(set(names)) != len(names):
        raise ValueError(f"two estimators share a name: {sorted(n for n in names if names.count(n) > 1)}")
    return {e.name: e for e in sorted(every, key=lambda e: e.rank)}


def register(estimator: NetworkEstimator) -> NetworkEstimator:
    """Add an estimator declared outside this package (until `unregister`)."""
    if estimator.name in registry():
        raise ValueError(f"an estimator named {estimator.name!r} is already registered")
    _REGISTERED[estimator.name] = estimator
    return estimator


def unregister(name: str) -> None:
    _REGISTERED.pop(name, None)


def _registered(name: str) -> str:
    if name not in registry():
        raise ValueError(f"must be one of {', '.join(registry())}; got {name!r}")
    return name


#: the name of a registered estimator in a scenario file, checked against the registry when the file is read
EstimatorName = Annotated[str, AfterValidator(_registered)]
