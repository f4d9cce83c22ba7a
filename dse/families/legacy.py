"""TEMPORARY: the families not yet ported to `dse.contract.Family`, seen through that contract.

Each old family has a `reproduction` module (`paper()`, `from_dict(data)`, module constants) and a
`generators` module; `legacy_family(...)` makes a `Family` subclass that calls them. A family
ported to the contract replaces its `family.py` and stops using this module; when none does,
this module is deleted.
"""
from __future__ import annotations

import functools
import importlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

from dse.contract.cost import Cost
from dse.contract.family import Computed, Family, Paper
from dse.contract.views import View
from dse.verify.rules import Claim, Hypothesis


@dataclass(frozen=True)
class LegacyScenario:
    legacy: Any        # the old family's reproduction object
    name: str


class _LegacyClaims:
    claims: list = []
    hypotheses: list = []


def legacy_family(family_id: str, package: str, *, paper_id: str | None, example: str) -> type[Family]:
    repro_module = f"{package}.reproduction"

    def mod():
        return importlib.import_module(repro_module)

    class Legacy(Family):
        id = family_id

        @property
        def paper(self):
            return self._paper()

        @functools.lru_cache(maxsize=1)
        def _paper(self):
            if paper_id is None:
                return None
            p = mod().paper()
            return Paper(paper_id, p.title, tuple(p.scenario_ids()))

        @property
        def intro(self):
            return mod().FAMILY_INTRO

        @property
        def scenario_model(self):
            return mod().SCENARIO_MODEL

        @property
        def edges(self):
            return tuple(importlib.import_module(f"{package}.generators").EDGES)

        def scenario_from_dict(self, data):
            obj = mod().from_dict(data)
            return LegacyScenario(obj, obj.paper_id)

        def paper_scenarios(self):
            obj = mod().paper()
            return tuple(LegacyScenario(obj, n) for n in obj.scenario_ids())

        def generate(self, seed, edge=None):
            return importlib.import_module(f"{package}.generators").generate(seed, edge)

        def claims(self):
            return _LegacyClaims()

        def claim_list(self, run):
            return list(run.scenarios[0].legacy.claims())

        def hypothesis_list(self, run):
            return list(run.scenarios[0].legacy.hypotheses())

        def title_of(self, run):
            return run.scenarios[0].legacy.title

        def notes_of(self, run):
            return run.scenarios[0].legacy.notes()

        def design(self, run, opts, ctx):
            return run.scenarios[0].legacy.design(opts)

        def simulate(self, run, opts, ctx, design):
            raise NotImplementedError

        def compute(self, run, opts, ctx):
            legacy = run.scenarios[0].legacy
            results = legacy.compute(opts, ctx.cache)
            design_of = getattr(legacy, "design_of", None)
            return Computed(design_of(results) if design_of is not None else None, results)

        def trials(self, run, opts):
            return run.scenarios[0].legacy.trials(opts)

        def cost(self, run, opts):
            est = run.scenarios[0].legacy.estimate(opts)
            return Cost(est["seconds"], est["peak_memory_mib"], est.get("detail", ""))

        def design_tables(self, run, design):
            return run.scenarios[0].legacy.design_tables(design)

        def tables(self, run, results):
            tables = getattr(run.scenarios[0].legacy, "tables", None)
            return tables(results) if tables is not None else []

        def views(self, outputs):
            legacy = outputs.reproduction.scenarios[0].legacy

            def draw(out_dir: Path):
                legacy.write_outputs(outputs.results, out_dir, outputs.claims, outputs.provenance, tables=outputs.tables)

            return [View("", draw)]

    Legacy.example = example
    Legacy.package = package
    Legacy.directory = lambda self: Path(importlib.import_module(package).__file__).parent
    Legacy.__name__ = Legacy.__qualname__ = f"Legacy_{family_id.replace('-', '_')}"
    return Legacy


# -- what the old reproduction modules share (was dse.engine.driver.FamilyReproduction) -------------------

class FamilyReproduction:
    """What every family's reproduction shares. A family package holds modules `claims` and
    `hypotheses` (each with `catalogue()`) and `tables` (`design_tables(design)`,
    `run_tables(results)`); they are imported on first use, so that `dse list` loads only what it
    prints. A family whose modules differ overrides the method."""

    def _part(self, module: str):
        package = type(self).__module__.rsplit(".", 1)[0]
        return importlib.import_module(f"{package}.{module}")

    def scenario_ids(self) -> list[str]:
        scenarios = getattr(self, "scenarios", None)
        if scenarios is None:
            return [self.scenario.name]
        return [sc.name for sc in (scenarios.values() if isinstance(scenarios, dict) else scenarios)]

    def claims(self) -> Sequence[Claim]:
        return self._part("claims").catalogue()

    def hypotheses(self) -> Sequence[Hypothesis]:
        return self._part("hypotheses").catalogue()

    @staticmethod
    def design_of(results: Any) -> Any:
        return results.design

    def design_tables(self, design: Any):
        return self._part("tables").design_tables(design)

    def tables(self, results: Any):
        return self._part("tables").run_tables(results)

    def table_set(self, results: Any, tables: Any = None):
        """The run's tables as given, or built from the results (outputs drawn without a run's tables)."""
        if tables is None:
            from dse.outputs.tables import Tables

            tables = Tables()
            for table_spec, frame in self.tables(results):
                tables.add(table_spec, frame)
        return tables




def wrap(obj: Any):
    """An old family's reproduction object (tests of families not yet ported build them directly) as a
    `Reproduction`; a `Reproduction` unchanged."""
    from dse.contract.family import Reproduction

    if isinstance(obj, Reproduction):
        return obj
    from dse import registry

    package = type(obj).__module__.rpartition(".")[0]
    fam = next(f for f in registry.families().values() if getattr(f, "package", None) == package)
    names = obj.scenario_ids() if obj.is_paper else [obj.paper_id]
    return Reproduction(fam, is_paper=obj.is_paper, _scenarios=tuple(LegacyScenario(obj, n) for n in names))
