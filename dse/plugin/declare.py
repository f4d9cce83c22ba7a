"""From a researcher's `NetworkFilter` class to an estimator of the compare arena.

Two ways in: an installed package that declares its filter in the entry point group ``dse.estimators``
(``name = "package.module:Class"``), or a compare scenario's table ``[estimators.<name>]`` with
``factory = "package.module:Class"``. Either way the table's other keys are the filter's parameters,
validated by its own `Parameters` model, and `estimator` turns the class into the same declaration
(`protocol.NetworkEstimator`) every built-in has: the harness (`harness.PluginRun`) runs it, the claims
check it, the tables and the figures show it.
"""
from __future__ import annotations

import hashlib
import importlib
import inspect
from dataclasses import dataclass
from typing import Any

import numpy as np
from pydantic import BaseModel, ConfigDict, ValidationError

from dse.errors import ScenarioError
from dse.estimators.protocol import SILENT, Communication, NetworkEstimator
from dse.scenario.declare import Real, Section, key

from .interface import Messages, NetworkFilter, Problem

#: plug-in filters come after the built-ins in tables and figures
RANK = 1000.0
#: the entry point group of installed filters
GROUP = "dse.estimators"
#: the link models a filter runs on unless it declares `link_models`
ALL_LINKS = ("reliable", "failures", "matchings", "poisson")
#: a filter's CPU time limit by default: this many times the family's cost model's estimate for it (put in
#: `Network.shared["time_limits"]` by the family), and at least MIN_LIMIT_S
LIMIT_FACTOR = 10.0
MIN_LIMIT_S = 60.0
#: what a plug-in filter sends is counted from its exchanges; one that does not override `sends` sends nothing
#: (it may not call `exchange`), and nothing is counted
SENT = Communication("sent")


def sends_nothing(cls: type[NetworkFilter]) -> bool:
    """Whether the class keeps `NetworkFilter.sends` (None: it may not exchange anything)."""
    return getattr(cls.sends, "__func__", None) is NetworkFilter.sends.__func__


class PluginTable(Section):
    """A plug-in filter, `[estimators.<name>]` (<name>: its id in tables and figures): the class from `factory`
    or, without it, the filter installed under <name> (entry point group `dse.estimators`); every other key of
    the table is one of the filter's parameters, validated by its own `Parameters` model (`dse arena NAME
    --keys` lists them)."""

    model_config = ConfigDict(extra="allow", strict=True, frozen=True, arbitrary_types_allowed=True)

    factory: str | None = key(None, doc="the filter's class, a dse.plugin.NetworkFilter; none: the filter installed "
                              "under the table's name", constraint="'package.module:Class'")
    time_limit: Real | None = key(None, doc="CPU seconds the filter may take over the run: it is stopped, with one "
                                  f"line, once its pace projects past them; none: {LIMIT_FACTOR:g} times the cost "
                                  f"model's estimate for it, at least {MIN_LIMIT_S:g} s", unit="s", gt=0)

    @property
    def parameters(self) -> dict[str, Any]:
        """The filter's own keys (everything but `factory` and `time_limit`)."""
        return dict(self.model_extra or {})


#: names the compare stages use for arrays of their own (`token__<e>`, `path__<e>`, `fault__<e>` and `steps` beside
#: every estimator's `<e>__<sum>`): a filter named so would overwrite them or be read as them
RESERVED_NAMES = ("token", "path", "fault", "steps")


def from_table(name: str, table: PluginTable, order: int) -> NetworkEstimator:
    """The declaration of table `[estimators.<name>]` (ScenarioErrors name the key)."""
    if name in RESERVED_NAMES:
        raise ScenarioError(f"estimators.{name}", f"{name!r} is reserved (the names {', '.join(RESERVED_NAMES)} "
                                                  "label the simulation's own arrays); give the plug-in another name")
    if "__" in name:
        raise ScenarioError(f"estimators.{name}", "a plug-in's name has no '__' (it separates a filter's name from "
                                                  "its arrays' in the stage results)")
    cls = load_class(name, table.factory)
    return estimator(name, cls, parameters(name, cls, table.parameters), table.time_limit, order)


def installed() -> dict[str, Any]:
    """name -> entry point of every filter installed in the group ``dse.estimators``."""
    from importlib.metadata import entry_points

    return {ep.name: ep for ep in entry_points(group=GROUP)}


def load_class(name: str, factory: str | None) -> type[NetworkFilter]:
    """The filter class of table ``[estimators.<name>]``: its `factory` ("package.module:Class"), or the
    filter installed under `name`; a ScenarioError naming the key otherwise."""
    where = f"estimators.{name}.factory" if factory else f"estimators.{name}"
    if factory:
        module, _, attr = factory.partition(":")
        if not module or not attr:
            raise ScenarioError(where, f"must be 'package.module:Class', got {factory!r}")
        try:
            obj = importlib.import_module(module)
            for part in attr.split("."):
                obj = getattr(obj, part)
        except Exception as exc:                        # noqa: BLE001 (whatever the import raised, in one line)
            raise ScenarioError(where, f"cannot load {factory!r}: {type(exc).__name__}: {exc}") from None
    else:
        eps = installed()
        if name not in eps:
            raise ScenarioError(where, f"no filter named {name!r} is installed (entry point group {GROUP}: "
                                       f"{', '.join(sorted(eps)) or 'none'}); give its factory = 'package.module:Class'")
        try:
            obj = eps[name].load()
        except Exception as exc:                        # noqa: BLE001
            raise ScenarioError(where, f"the installed filter {eps[name].value!r} cannot be loaded: "
                                       f"{type(exc).__name__}: {exc}") from None
    check_class(obj, where)
    return obj


def check_class(cls: Any, where: str) -> None:
    """The declaration rules of a filter class (`interface.NetworkFilter`), each a ScenarioError at `where`."""
    if not (isinstance(cls, type) and issubclass(cls, NetworkFilter)):
        raise ScenarioError(where, f"{cls!r} is not a subclass of dse.plugin.NetworkFilter")
    if inspect.isabstract(cls):
        raise ScenarioError(where, f"{cls.__name__} does not implement step(k, y, network)")
    if cls.equivariant and not callable(getattr(cls, "shift", None)):
        raise ScenarioError(where, f"{cls.__name__} declares equivariant = True but has no shift(delta)")
    if cls.linear and not callable(getattr(cls, "matrices", None)):
        raise ScenarioError(where, f"{cls.__name__} declares linear = True but has no matrices(k)")
    if cls.covariance_law not in (None, "conditional", "bound"):
        raise ScenarioError(where, f"{cls.__name__}.covariance_law must be None, 'conditional' or 'bound', "
                                   f"got {cls.covariance_law!r}")
    if not (isinstance(cls.Parameters, type) and issubclass(cls.Parameters, BaseModel)):
        raise ScenarioError(where, f"{cls.__name__}.Parameters must be a pydantic model")
    bad = [m for m in getattr(cls, "link_models", ALL_LINKS) if m not in ALL_LINKS]
    if bad:
        raise ScenarioError(where, f"{cls.__name__}.link_models: unknown link model {bad[0]!r}")


def parameters(name: str, cls: type[NetworkFilter], values: dict[str, Any]) -> BaseModel:
    """The filter's parameters from its table, validated by its own schema."""
    try:
        return cls.Parameters.model_validate(values)
    except ValidationError as exc:
        err = exc.errors()[0]
        path = ".".join(str(p) for p in err["loc"])
        raise ScenarioError(f"estimators.{name}" + (f".{path}" if path else ""),
                            err["msg"] if err["type"] != "extra_forbidden"
                            else f"unknown key (the parameters of {cls.__name__}: "
                                 f"{', '.join(cls.Parameters.model_fields) or 'none'})") from None


def problem_of(model, links, weights: np.ndarray, steps: int) -> Problem:
    """What a filter is built for (`interface.Problem`), from the arena's model, link model and weights."""
    from .harness import Wiring, read_only

    w = Wiring(links.topology)
    q = np.where(w.valid, weights[np.where(w.valid, w.edge_of, 0)], 0.0)
    arrays = [read_only(np.array(a, float)) for a in (model.F, model.Q, model.P0, model.x0, model.H, model.R)]
    return Problem(*arrays, neighbours=read_only(w.neighbours), weights=read_only(q),
                   degrees=read_only(np.asarray(links.topology.degrees)), edges=read_only(links.topology.edges),
                   link_model=links.kind, rounds=links.rounds, noise_std=float(links.noise_std), steps=steps)


def code_of(cls: type) -> str:
    """What the filter's code contributes to the stage keys and run memos: every Python file of the package
    its class is defined in (a filter's helpers change its numbers too; a module outside any package: its own
    file), and the harness's code."""
    import sys
    from pathlib import Path

    from dse.estimators.protocol import source_hash

    module = sys.modules[cls.__module__]
    h = hashlib.sha256(source_hash(__name__).encode())
    path = Path(inspect.getfile(module))
    files = sorted(path.parent.rglob("*.py")) if "." in cls.__module__ else [path]
    for f in files:
        h.update(str(f.relative_to(path.parent)).encode())
        h.update(f.read_bytes())
    return h.hexdigest()[:16]


@dataclass(eq=False)
class PluginConfig:
    """A plug-in filter designed for one scenario: its class, parameters, problem and messages."""

    cls: type[NetworkFilter]
    params: BaseModel
    problem: Problem
    messages: Messages | None
    #: the inverse of the last covariance its batches reported (`harness.LastInverse`): the sub-batches of a step
    #: report the same one
    inverse: Any = None


def estimator(name: str, cls: type[NetworkFilter], params: BaseModel, time_limit: float | None,
              order: int = 0) -> NetworkEstimator:
    """The arena's declaration of a plug-in filter (module doc)."""
    from . import exact

    def design(est) -> None:
        net = est.network
        problem = problem_of(net.model, net.links, net.weights, net.steps)
        try:
            messages = cls.sends(problem, params)
        except Exception as exc:                        # noqa: BLE001
            raise ScenarioError(f"estimators.{name}", f"{cls.__name__}.sends raised {type(exc).__name__}: {exc}") from None
        if messages is not None and not isinstance(messages, Messages):
            raise ScenarioError(f"estimators.{name}", f"{cls.__name__}.sends must return Messages or None")
        from .harness import LastInverse

        est.config = PluginConfig(cls, params, problem, messages, LastInverse())
        est.exact_reason = exact.reason(est)

    def build(est, B: int, peers):
        from .harness import PluginRun

        cfg, net = est.config, est.network
        total = int(net.shared.get("trials", B))
        limit = time_limit if time_limit is not None else net.shared.get("time_limits", {}).get(name, MIN_LIMIT_S)
        return PluginRun(name, cls, cfg.problem, cfg.params, net.links, cfg.messages, B, total, limit, cfg.inverse)

    def applies(links) -> str:
        allowed = getattr(cls, "link_models", ALL_LINKS)
        return "" if links.kind in allowed else (f"it declares the link models {', '.join(allowed)}; the scenario's "
                                                 f"is {links.kind}")

    return NetworkEstimator(
        name=name, title=cls.title or cls.__name__, rank=RANK + order, build=build, applies=applies, design=design,
        exact=exact.moments if cls.linear else None, communication=lambda links, n: SILENT if sends_nothing(cls) else SENT,
        cost_weight=float(cls.cost_weight),
        trialwise_covariance=lambda links: bool(cls.per_trial_matrices or (cls.covariance_law and links.random)),
        joint_moments=bool(cls.linear),
        covariance_law=cls.covariance_law, plugin=True, true_coordinates=not cls.equivariant, module=cls.__module__, code=code_of(cls))
