"""Claims and hypotheses declared next to their checks.

A family's claims module makes one `ClaimSet` and registers each check where it is written:

    claims = ClaimSet()

    @claims.hypothesis("{paper}.hyp.{scenario}.alpha", "0 < α ≤ 1/d_max (eq. 3)")
    def alpha_in_range(design, scenario: str) -> Holds: ...

    @claims.claim("{paper}.model.fusion_weights.{scenario}", "eq. (3), (6)", "Π = I − α𝓛 is ...",
                  "identity", hypotheses=("{paper}.hyp.{scenario}.alpha",))
    def check_fusion(results, scenario: str) -> Verdict: ...

    claims.unchecked("savas.nc.convexity", "§VI", "convexity of J is left open", "qualitative",
                     reason="stated as an open question, not a claim")

The ids are templates (claim and hypothesis ids never change: they are what reports and users
refer to):

- ``{paper}`` is the run's id (the paper id in the paper's reproduction, the scenario name in a
  user's run); an id that starts with the family's paper id written literally (``savas.mc.trace``)
  reads it as ``{paper}``, so that a user's claim ids never carry a paper's prefix;
- ``{scenario}`` makes the entry *per scenario*: one claim (or hypothesis) per scenario of the
  run, its check called with the scenario's name (or, when the set declares `select`, with
  `select(results, name)` instead of the results and the name). Consecutive per-scenario
  entries are expanded scenario by scenario (all of the first scenario's, then the next's).
  A run-level claim that rests on a per-scenario hypothesis rests on every scenario's.
  ``{scenario.}``, ``{.scenario}`` and ``{scenario: }`` name the scenario (followed or preceded by
  ``.``, or followed by ``: ``) only when the run has several: the ids of a one-scenario run (a
  user's, whose run id is already the scenario's name) do not repeat its name.
- ``{item}``: with `each=` (a function of the `Where` returning (label, item) pairs), the entry
  is expanded once per item of the scenario (a run of it, say), its check called with the item
  after the scenario's selection and `when` seeing it as `where.item`; consecutive entries with
  the same `each` are expanded item by item.

Gates are declared, not written into the checks: `scope="paper-example"` (evaluated in the
paper's own reproduction only), `when=...` (a predicate on `Where`: the scenario, its roles, the
paper run; `role("full")`, `example("e7")` and `paper_only` are the usual ones) decides whether a
claim exists for a scenario at all, and `hypotheses=` the hypotheses its conclusion rests on (a
claim whose hypotheses do not hold is `not-checkable`, naming them: `dse.verify.rules.evaluate`).
`args=` passes fixed extra arguments, so that one check can back two claims. `requires=` lists
(condition, reason) pairs on the check's arguments: what the scenario must contain for the claim
to be checked at all (two values of m for a trend, a nonzero noise); where a condition is not met
the claim is `not-checkable` with that reason (a function of the arguments, or a text).
"""
from __future__ import annotations

import importlib
import sys
from dataclasses import dataclass, field, replace
from typing import Any, Callable, Iterable, Sequence

from dse.verify.rules import KINDS, SCOPES, Claim, Hypothesis, Verdict, not_checkable


@dataclass(frozen=True)
class Where:
    """Where a claim is being instantiated: the run and one of its scenarios (None for a run-level claim)."""

    run_id: str
    paper: bool
    scenarios: tuple[str, ...]
    scenario: str | None = None
    roles: frozenset[str] = frozenset()
    #: the run itself (`dse.contract.family.Reproduction`), for gates that read the scenarios
    run: Any = field(default=None, compare=False, repr=False)
    #: the item of an `each=` expansion, and its label (what `{item}` becomes)
    item: Any = field(default=None, compare=False, repr=False)
    item_label: str = ""

    @property
    def scenario_object(self) -> Any:
        """The scenario this Where is about (None for the run itself)."""
        if self.run is None or self.scenario is None:
            return None
        return next(sc for sc in self.run.scenarios if sc.name == self.scenario)


Gate = Callable[[Where], bool]


def role(name: str) -> Gate:
    """Present where the scenario has this role (the family's `roles`)."""
    gate = lambda where: name in where.roles  # noqa: E731
    gate.__doc__ = f"scenarios with role {name!r}"
    return gate


def example(*names: str) -> Gate:
    """Present for the paper's own scenarios of these names (in the paper's reproduction only)."""
    gate = lambda where: where.paper and (where.scenario in names or  # noqa: E731
                                          (where.scenario is None and any(n in where.scenarios for n in names)))
    gate.__doc__ = f"the paper's scenario {', '.join(names)}"
    return gate


def paper_only(where: Where) -> bool:
    """Present in the paper's own reproduction only."""
    return where.paper


def _fill_id(template: str, where: Where, scenario: str | None = None) -> str:
    """An id from its template. A family may write its paper's id literally at the start of an id
    (`savas.mc.trace`); in a user's run that prefix is the run's id like `{paper}` (`ring8.mc.trace`), so
    that a user's claim ids never carry a paper's prefix."""
    paper = getattr(getattr(getattr(where.run, "family", None), "paper", None), "id", None)
    if not where.paper and paper and template.startswith(f"{paper}."):
        template = "{paper}" + template[len(paper):]
    return _fill(template, where, scenario)


def _fill(template: str, where: Where, scenario: str | None = None) -> str:
    name = scenario or where.scenario or ""
    several = len(where.scenarios) > 1
    return (template.replace("{paper}", where.run_id).replace("{scenario.}", f"{name}." if several else "")
            .replace("{.scenario}", f".{name}" if several else "")
            .replace("{scenario: }", f"{name}: " if several else "").replace("{scenario}", name)
            .replace("{item}", where.item_label))


def _per_scenario(template: str) -> bool:
    return "{scenario" in template or "{.scenario}" in template


@dataclass(frozen=True)
class ClaimEntry:
    id: str
    source: str
    statement: str
    kind: str
    check: Callable[..., Verdict]
    hypotheses: tuple[str, ...] | Callable[[Where], tuple[str, ...]] = ()
    scope: str = "family"
    when: Gate | None = None
    args: tuple = ()
    requires: tuple[tuple[Callable[..., bool], str | Callable[..., str]], ...] = ()
    each: Callable[[Where], Iterable[tuple[str, Any]]] | None = None
    module: str = ""          # the module that registered it
    confidence_group: str = ""

    @property
    def per_scenario(self) -> bool:
        return _per_scenario(self.id)

    def gated_check(self) -> Callable[..., Verdict]:
        """The check, preceded by the conditions of `requires`."""
        if not self.requires:
            return self.check

        def check(*a):
            for holds, reason in self.requires:
                if not holds(*a):
                    return not_checkable(reason(*a) if callable(reason) else reason)
            return self.check(*a)

        return check


@dataclass(frozen=True)
class HypothesisEntry:
    id: str
    statement: str
    check: Callable[..., Any]
    when: Gate | None = None
    args: tuple = ()
    each: Callable[[Where], Iterable[tuple[str, Any]]] | None = None
    module: str = ""          # the module that registered it
    confidence_group: str = ""

    @property
    def per_scenario(self) -> bool:
        return _per_scenario(self.id)


@dataclass
class ClaimSet:
    """A family's hypotheses and claims, in the order they are reported.

    `select(results, scenario_name)`, when given, is what a per-scenario check receives instead
    of the results and the scenario's name (and likewise a per-scenario hypothesis, with the
    design).

    `modules`, when a set is filled by several modules, names them (dotted) in the order of the report:
    `complete()` imports them, and the report lists their entries module by module, so that the order does
    not depend on which module was imported first (a test or a user importing one check module before the
    others would otherwise reorder a report)."""

    select: Callable[[Any, str], Any] | None = None
    select_design: Callable[[Any, str], Any] | None = None
    claims: list[ClaimEntry] = field(default_factory=list)
    hypotheses: list[HypothesisEntry] = field(default_factory=list)
    modules: tuple[str, ...] = ()

    def complete(self) -> "ClaimSet":
        """Import every module of `modules` (each registers its checks here); returns the set."""
        for name in self.modules:
            importlib.import_module(name)
        return self

    def _ordered(self, entries: list) -> list:
        """`entries` module by module in the order of `modules` (registration order within a module)."""
        if not self.modules:
            return entries
        stray = sorted({e.module for e in entries} - set(self.modules))
        if stray:
            raise ValueError(f"checks registered from modules the ClaimSet does not list: {', '.join(stray)}")
        return sorted(entries, key=lambda e: self.modules.index(e.module))

    # -- registration ----------------------------------------------------------------------------------

    def claim(self, id: str, source: str, statement: str, kind: str, *, hypotheses: Sequence[str] |
              Callable[[Where], tuple[str, ...]] = (), scope: str = "family", when: Gate | None = None,
              args: tuple = (), requires: Sequence[tuple[Callable[..., bool], str | Callable[..., str]]] = (),
              each: Callable[[Where], Iterable[tuple[str, Any]]] | None = None, confidence_group: str = "",
              _module: str = ""):
        """Register the decorated function as the check of a claim (see the module docstring).
        `confidence_group` (a template like the id): statistical claims of one group share a family-wise
        confidence of their own, apart from the report's (a plug-in's claims: adding one changes no other
        claim's confidence)."""
        if kind not in KINDS:
            raise ValueError(f"claim {id}: unknown kind {kind!r}")
        if scope not in SCOPES:
            raise ValueError(f"claim {id}: unknown scope {scope!r}")

        module = _module or sys._getframe(1).f_globals.get("__name__", "")

        def register(fn: Callable[..., Verdict]):
            hyps = hypotheses if callable(hypotheses) else tuple(hypotheses)
            self.claims.append(ClaimEntry(id, source, statement, kind, fn, hyps, scope, when, tuple(args),
                                          tuple(requires), each, module, confidence_group))
            return fn

        return register

    def unchecked(self, id: str, source: str, statement: str, kind: str, *, reason: str, scope: str = "family",
                  when: Gate | None = None) -> None:
        """A claim that no computation can check (an interpretation, an open question): always
        `not-checkable`, with `reason`."""
        self.claim(id, source, statement, kind, scope=scope, when=when,
                   _module=sys._getframe(1).f_globals.get("__name__", ""))(lambda *_a: not_checkable(reason))

    def hypothesis(self, id: str, statement: str, *, when: Gate | None = None, args: tuple = (),
                   each: Callable[[Where], Iterable[tuple[str, Any]]] | None = None):
        """Register the decorated function (design -> Holds) as a hypothesis check."""
        module = sys._getframe(1).f_globals.get("__name__", "")

        def register(fn):
            self.hypotheses.append(HypothesisEntry(id, statement, fn, when, tuple(args), each, module))
            return fn

        return register

    # -- instantiation for one run -----------------------------------------------------------------------

    def hypothesis_list(self, wheres: Sequence[Where]) -> list[Hypothesis]:
        """Every hypothesis of a run, per-scenario ones expanded (`wheres[0]` is the run itself,
        then one `Where` per scenario)."""
        out = []
        for entry, where, name in self._expand(self._ordered(self.hypotheses), wheres):
            out.append(Hypothesis(_fill_id(entry.id, where), _fill(entry.statement, where),
                                  self._bind(entry.check, name, self._args(entry, where), self.select_design)))
        return out

    def claim_list(self, wheres: Sequence[Where]) -> list[Claim]:
        """Every claim of a run, in the order of registration (per-scenario blocks scenario by scenario)."""
        out = []
        for entry, where, name in self._expand(self._ordered(self.claims), wheres):
            refs = entry.hypotheses(where) if callable(entry.hypotheses) else entry.hypotheses
            hyps = []
            for ref in refs:
                if _per_scenario(ref) and name is None:           # a run-level claim: every scenario's
                    hyps += [_fill_id(ref, where, s) for s in where.scenarios]
                else:
                    hyps.append(_fill_id(ref, where))
            out.append(Claim(_fill_id(entry.id, where), entry.source, _fill(entry.statement, where), entry.kind,
                             self._bind(entry.gated_check(), name, self._args(entry, where), self.select),
                             tuple(dict.fromkeys(hyps)),
                             entry.scope, _fill(entry.confidence_group, where)))
        return out

    @staticmethod
    def _expand(entries: Iterable, wheres: Sequence[Where]):
        run, per = wheres[0], list(wheres[1:])
        block: list = []

        def flush():
            for w in per:
                yield from ClaimSet._instances(block, w, w.scenario)
            block.clear()

        for e in entries:
            if e.per_scenario:
                block.append(e)
                continue
            yield from flush()
            yield from ClaimSet._instances([e], run, None)
        yield from flush()

    @staticmethod
    def _instances(entries: list, where: Where, scenario: str | None):
        """The entries present at `where`; consecutive ones with the same `each`, item by item."""
        i = 0
        while i < len(entries):
            j = i + 1
            while entries[i].each is not None and j < len(entries) and entries[j].each is entries[i].each:
                j += 1
            wheres = [where] if entries[i].each is None else \
                [replace(where, item=item, item_label=label) for label, item in entries[i].each(where)]
            for w in wheres:
                yield from ((e, w, scenario) for e in entries[i:j] if e.when is None or e.when(w))
            i = j

    @staticmethod
    def _args(entry, where: Where) -> tuple:
        return ((where.item,) if entry.each is not None else ()) + entry.args

    @staticmethod
    def _bind(fn: Callable, scenario: str | None, args: tuple, select: Callable | None) -> Callable[[Any], Any]:
        if scenario is None:
            return (lambda res: fn(res, *args)) if args else fn
        if select is not None:
            return lambda res: fn(select(res, scenario), *args)
        return lambda res: fn(res, scenario, *args)
