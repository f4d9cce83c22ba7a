"""The contract between the pipeline and a scenario family (one paper's, or compare).

A family is a subclass of `Family` that declares what it is (the class attributes) and
implements the abstract methods; the driver calls nothing else. A run is a `Reproduction`:
the family, the scenarios it runs (the paper's own, or one scenario file of a user's) and
whether it is the paper's reproduction (claims of scope "paper-example" are evaluated then
only). The registry (`dse.families`) finds families by the `dse.families` entry point group,
so an installed package can add one.

    scenario file ──scenario_from_dict──▶ Reproduction ──design──▶ design ──hypotheses──▶ (dse check)
                                               │                      │
                                               └──────simulate────────┴──▶ results ──claims──▶ verdicts
                                                                                  └──tables──▶ tables ──views──▶ figures, recordings

Each stage of `design` and `simulate` is a declared `dse.contract.stages.Stage` run through the
`StageContext` it is given (cache keys derived from its inputs and its code). `cost` is an
estimate made before anything runs; the driver refuses a run that cannot fit its memory budget.
"""
from __future__ import annotations

import importlib
import inspect
from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar, Iterable, Sequence

from dse.contract.claims import ClaimSet, Where
from dse.contract.cost import Cost
from dse.contract.options import RunOptions
from dse.contract.context import StageContext


class Declared:
    """A shipped scenario as the expansion of its run's claims reads it, declared so that listing them
    (`dse list`) reads no file and builds no scenario: its name, its roles in the run (what `Family.roles`
    gives the parsed file) and the properties the claims' gates read (`when`, `each`, hypotheses chosen per
    scenario), under the scenario model's own attribute names; a nested part (a run of the scenario, say) is
    a `Declared` too. Reading a property that is not declared raises, naming it; tests compare every
    declaration, and the listing made from it, with the parsed file."""

    __slots__ = ("name", "roles", "_properties")

    def __init__(self, name: str, *, roles: Iterable[str] = (), **properties: Any):
        self.name = name
        self.roles = frozenset(roles)
        self._properties = properties

    def properties(self) -> dict[str, Any]:
        """The declared properties, by attribute name."""
        return dict(self._properties)

    def __getattr__(self, key: str) -> Any:
        if key.startswith("_"):          # not a scenario property (copy, pickle and hasattr probe these)
            raise AttributeError(key)
        try:
            return self._properties[key]
        except KeyError:
            raise AttributeError(f"the declared scenario {self.name!r} has no property {key!r}: a claim's gate "
                                 "reads it, so its declaration (Paper.declared or Family.example_declared) must "
                                 "give it") from None

    def __repr__(self) -> str:
        parts = [repr(self.name)] + ([f"roles={sorted(self.roles)}"] if self.roles else []) + \
            [f"{k}={v!r}" for k, v in self._properties.items()]
        return f"Declared({', '.join(parts)})"


@dataclass(frozen=True)
class Paper:
    """The paper a family reproduces: its id (`dse reproduce ID`), title, the ids of its own
    scenarios (listed without reading their files), the notes of its reproduction (the values
    the paper leaves out and what we chose) and, for the scenarios whose roles or properties its
    claims' gates read, their declarations (`Declared`; the others are their names alone)."""

    id: str
    title: str
    scenario_ids: tuple[str, ...]
    notes: str = ""
    declared: tuple[Declared, ...] = ()

    def __post_init__(self):
        unknown = [d.name for d in self.declared if d.name not in self.scenario_ids]
        if unknown:
            raise ValueError(f"paper {self.id}: declared scenarios {', '.join(unknown)} are not among its "
                             f"scenario ids {', '.join(self.scenario_ids)}")

    def declared_scenarios(self) -> tuple[Declared, ...]:
        """One declaration per scenario id, in order (a scenario not declared: its name alone)."""
        given = {d.name: d for d in self.declared}
        return tuple(given.get(name, Declared(name)) for name in self.scenario_ids)


class Family(ABC):
    """A scenario family. Subclasses declare the class attributes and implement every abstract
    method; `docs/design.md` ("Adding a paper") walks through the template family."""

    #: the `family` key of a scenario file
    id: ClassVar[str]
    #: the paper reproduced, or None (a family of its own, like compare)
    paper: ClassVar[Paper | None] = None
    #: what a scenario of the family is and which tables a run writes (docs/scenarios.md, `dse list`)
    intro: ClassVar[str]
    #: model choices and how the verdicts are reached: the notes of every run's report
    notes: ClassVar[str] = ""
    #: the declared scenario file (a `dse.scenario.declare.Section`; docs/scenarios.md is generated from it)
    scenario_model: ClassVar[type]
    #: a valid scenario file of the family, relative to the family's package directory
    example: ClassVar[str]
    #: the names of the generator's edge cases (`generate(seed, edge)`)
    edges: ClassVar[tuple[str, ...]] = ()
    #: the title of a user's run: "<family> scenario '<name>'" and this
    run_title: ClassVar[str] = ""
    #: the dotted scenario key that `--trials` (RunOptions.trials) stands for: the option gets its declared bounds
    trials_key: ClassVar[str] = ""
    #: a family without a paper: its example as a user's run of it reads it (`Declared`: the file's name, and
    #: what the claims' gates read), so that `dse list` shows its claims without reading the file
    example_declared: ClassVar[Declared | None] = None
    #: modules that what follows the Monte Carlo imports (claims' libraries, a late reference stage's oracle),
    #: imported while the Monte Carlo's forked workers run (`dse.simulate.units.idle_work`), on a core they may
    #: leave idle, instead of between them and the claims; ".name" is a module of the family's own package
    idle_imports: ClassVar[tuple[str, ...]] = ()

    # -- scenarios ---------------------------------------------------------------------------------------

    def scenario_from_dict(self, data: dict[str, Any]) -> Any:
        """A validated scenario from a parsed file without its `family` key (ScenarioError naming the field):
        the scenario model's instance, validated by its declaration."""
        from dse.scenario.declare import parse

        return parse(self.scenario_model, data)

    def __init_subclass__(cls, **kwargs):
        super().__init_subclass__(**kwargs)
        if cls.paper is not None and cls.paper_scenarios is Family.paper_scenarios:
            raise TypeError(f"{cls.__name__} declares the paper {cls.paper.id!r} but not its paper_scenarios()")
        if cls.paper is None and hasattr(cls, "example") and cls.example_declared is None:
            raise TypeError(f"{cls.__name__} declares no paper and its example {cls.example!r} but not "
                            "example_declared (what `dse list` shows)")

    def paper_scenarios(self) -> Sequence[Any]:
        """The paper's own scenarios, in the order of `paper.scenario_ids`: a family that declares a paper
        defines them (checked when its class is defined); a family without a paper has none."""
        return ()

    def roles(self, scenario: Any, paper: bool) -> frozenset[str]:
        """Roles of a scenario in a run, read by the claims' `role(...)` gates (none by default)."""
        return frozenset()

    @abstractmethod
    def generate(self, seed: int, edge: str | None = None) -> dict[str, Any]:
        """A random valid scenario file (as a dict with `family`), small enough for a quick run;
        `edge` one of `edges`. Deterministic in (seed, edge)."""

    def external_code(self, scenario: Any) -> str:
        """A hash of code outside the project that the scenario runs (a plug-in filter's), "" when none: run
        memos, sweep points and arena scenarios are keyed by it beside the project's own code."""
        return ""

    # -- stages ------------------------------------------------------------------------------------------

    @abstractmethod
    def claims(self) -> ClaimSet:
        """The family's hypotheses and claims (its claims module's `ClaimSet`, imported on first use)."""

    @abstractmethod
    def design(self, run: "Reproduction", opts: RunOptions, ctx: StageContext) -> Any:
        """The deterministic design stage: what the hypotheses are evaluated on (`dse check`)."""

    @abstractmethod
    def simulate(self, run: "Reproduction", opts: RunOptions, ctx: StageContext, design: Any) -> Any:
        """Monte Carlo and bounds on top of the design: what the claims are evaluated on."""

    @abstractmethod
    def trials(self, run: "Reproduction", opts: RunOptions) -> int:
        """Monte Carlo trials per cell of the run (provenance)."""

    @abstractmethod
    def cost(self, run: "Reproduction", opts: RunOptions) -> Cost:
        """The run's estimated time and memory, from the scenario's sizes, before anything runs."""

    # -- outputs -----------------------------------------------------------------------------------------

    def design_tables(self, run: "Reproduction", design: Any) -> Iterable[tuple[Any, Any]]:
        """(TableSpec, DataFrame) of every design quantity (also written by `dse check`): by default the
        family's `tables.design_tables(design)`."""
        return self.module("tables").design_tables(design)

    def tables(self, run: "Reproduction", results: Any) -> Iterable[tuple[Any, Any]]:
        """(TableSpec, DataFrame) of every number the run computed (design tables included): by default the
        family's `tables.run_tables(results)`."""
        return self.module("tables").run_tables(results)

    def views(self, outputs: Any) -> list[Any]:
        """The run's figures and recordings (`dse.contract.views.View`), drawn from `outputs`: by default the
        family's `views.views(outputs)`."""
        return self.module("views").views(outputs)

    # -- what the driver reads (defined here once) -------------------------------------------------------

    def claim_list(self, run: "Reproduction") -> list:
        """The run's claims, expanded from the family's ClaimSet."""
        return self.claims().claim_list(self.wheres(run))

    def hypothesis_list(self, run: "Reproduction") -> list:
        """The run's hypotheses, expanded from the family's ClaimSet."""
        return self.claims().hypothesis_list(self.wheres(run))

    def wheres(self, run: "Reproduction") -> list[Where]:
        """The run itself, then each of its scenarios (with its roles), for the claims' expansion."""
        ids = tuple(run.scenario_ids())
        out = [Where(run.paper_id, run.is_paper, ids, run=run)]
        entries = self.claims().claims + self.claims().hypotheses
        if not any(e.per_scenario or e.when is not None for e in entries):
            return out
        if run._scenarios is None and not any(e.when is not None or e.each is not None
                                              or callable(getattr(e, "hypotheses", ())) for e in entries):
            # nothing reads a scenario's roles or items: the paper's files are not parsed for the ids
            return out + [Where(run.paper_id, run.is_paper, ids, name, run=run) for name in ids]
        return out + [Where(run.paper_id, run.is_paper, ids, sc.name, self.roles_of(sc, run.is_paper), run=run)
                      for sc in run.scenarios]

    def roles_of(self, scenario: Any, paper: bool) -> frozenset[str]:
        """The roles of a scenario in a run: declared (`Declared`), or given by `roles`."""
        return scenario.roles if isinstance(scenario, Declared) else self.roles(scenario, paper)

    def listing(self) -> "Reproduction":
        """What `dse list` shows: the paper's reproduction, or a user's run of the example, on the declared
        scenarios (`Paper.declared`, `example_declared`), so that its hypotheses and claims are expanded
        without reading a file or building a scenario. For listing only: an `each=` item is a declaration
        there, not the scenario's part, so its checks are not for running."""
        if self.paper is not None:
            return Reproduction(self, True, self.paper.declared_scenarios())
        return Reproduction(self, False, (self.example_declared,))

    def compute(self, run: "Reproduction", opts: RunOptions, ctx: StageContext) -> "Computed":
        """The design, then the simulation on top of it."""
        design = self.design(run, opts, ctx)
        return Computed(design, self.simulate(run, opts, ctx, design))

    def title_of(self, run: "Reproduction") -> str:
        if run.is_paper:
            return self.paper.title
        return f"{self.id} scenario '{run.paper_id}'" + (f": {self.run_title}" if self.run_title else "")

    def notes_of(self, run: "Reproduction") -> str:
        if run.is_paper and self.paper.notes:
            return "\n\n".join(n for n in (self.paper.notes, self.notes) if n)
        return self.notes

    def directory(self) -> Path:
        """The family's package directory (its scenario files live there)."""
        return Path(inspect.getfile(type(self))).parent

    def example_file(self) -> Path:
        return self.directory() / self.example

    def module(self, name: str):
        """A module of the family's package, imported on first use (so that `dse list` loads only what it prints)."""
        return importlib.import_module(f"{type(self).__module__.rpartition('.')[0]}.{name}")

    def import_idle_imports(self) -> None:
        """Import `idle_imports` (a head start only: a module that fails to import here fails where it is used)."""
        for name in self.idle_imports:
            self.module(name[1:]) if name.startswith(".") else importlib.import_module(name)


@dataclass(frozen=True)
class Computed:
    """A run's design (hypotheses) and results (claims, tables)."""

    design: Any
    results: Any


@dataclass
class Reproduction:
    """One run of a family: the paper's reproduction (`scenarios` None: read from the paper's
    files when first needed) or a user's scenario."""

    family: Family
    is_paper: bool
    _scenarios: tuple | None = None
    _claims: list | None = field(default=None, repr=False)
    _hypotheses: list | None = field(default=None, repr=False)

    @property
    def scenarios(self) -> tuple:
        if self._scenarios is None:
            self._scenarios = tuple(self.family.paper_scenarios())
        return self._scenarios

    @property
    def scenario(self) -> Any:
        """The scenario of a one-scenario run."""
        return self.scenarios[0]

    def external_code(self) -> str:
        """The hash of code outside the project that the run's scenarios run (`Family.external_code`)."""
        return "".join(self.family.external_code(sc) for sc in self.scenarios) if not self.is_paper else ""

    def scenario_ids(self) -> list[str]:
        if self.is_paper and self._scenarios is None:
            return list(self.family.paper.scenario_ids)
        return [sc.name for sc in self.scenarios]

    @property
    def paper_id(self) -> str:
        """The run's id: the paper's, or the user's scenario name (the output directory, claim ids)."""
        return self.family.paper.id if self.is_paper else self.scenarios[0].name

    @property
    def title(self) -> str:
        return self.family.title_of(self)

    def notes(self) -> str:
        return self.family.notes_of(self)

    # -- claims ------------------------------------------------------------------------------------------

    def claims(self) -> list:
        if self._claims is None:
            self._claims = self.family.claim_list(self)
        return self._claims

    def hypotheses(self) -> list:
        if self._hypotheses is None:
            self._hypotheses = self.family.hypothesis_list(self)
        return self._hypotheses

    # -- stages ------------------------------------------------------------------------------------------

    def design(self, opts: RunOptions, ctx: StageContext) -> Any:
        return self.family.design(self, opts, ctx)

    def compute(self, opts: RunOptions, ctx: StageContext) -> Computed:
        from dse.simulate.units import idle_work

        with idle_work(self.family.import_idle_imports):
            return self.family.compute(self, opts, ctx)

    def trials(self, opts: RunOptions) -> int:
        return self.family.trials(self, opts)

    def cost(self, opts: RunOptions) -> Cost:
        return self.family.cost(self, opts)

    def design_tables(self, design: Any) -> list:
        """The family's design tables, built without numpy warnings (see `tables`)."""
        with _quiet_floats():
            return list(self.family.design_tables(self, design))

    def tables(self, results: Any) -> list:
        """The family's tables, built with numpy's floating-point warnings off: they are numbers derived
        from stage results that were checked finite (or declared non-finite results), and a column that
        overflows (the square of a diverging error, say) holds inf or NaN, a result, not a warning."""
        with _quiet_floats():
            return list(self.family.tables(self, results))

    def views(self, outputs: Any) -> list:
        return self.family.views(outputs)


def _quiet_floats():
    import numpy as np

    return np.errstate(over="ignore", invalid="ignore", divide="ignore")
