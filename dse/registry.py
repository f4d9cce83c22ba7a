"""The registry of scenario families: every entry point of the `dse.families` group.

(`dse.families` is the package of this project's families; the registry is a module of its own so
that a family's stages, which live in that package, do not depend on the registry's code.)

This package's families are declared in pyproject.toml (`[project.entry-points."dse.families"]`,
one line per family: `<family id> = "<module>:<Family subclass>"`); an installed package adds a
family the same way in its own metadata. The command line, the Python API, the generated
scenario reference, sweeps and benchmarks all read this registry and nothing else.
"""
from __future__ import annotations

import functools
import sys
from importlib.metadata import entry_points
from typing import Any

from dse.errors import ScenarioError

GROUP = "dse.families"


@functools.lru_cache(maxsize=1)
def _entry_points() -> dict[str, Any]:
    """family id -> its entry point, by id (nothing is imported yet)."""
    found = {ep.name: ep for ep in sorted(entry_points(group=GROUP), key=lambda e: e.name)}
    if not found:
        raise RuntimeError(f"no scenario family is registered (entry point group {GROUP}): is dse installed?")
    return found


@functools.lru_cache(maxsize=None)
def _load(family_id: str) -> Any:
    """The Family of one entry point, imported on first use; None (with one line on stderr) when it cannot be
    loaded: one broken plugin does not take the others down."""
    ep = _entry_points()[family_id]
    try:
        cls = ep.load()
        if getattr(cls, "id", None) != ep.name:
            raise ValueError(f"the entry point names family {ep.name}, the class declares {getattr(cls, 'id', None)!r}")
        return cls()
    except Exception as exc:
        print(f"dse: family {ep.name} ({ep.value}) could not be loaded and is skipped: {type(exc).__name__}: {exc}",
              file=sys.stderr)
        return None


def families() -> dict[str, Any]:
    """family id -> Family instance, by id (every family is imported)."""
    return {name: fam for name in _entry_points() if (fam := _load(name)) is not None}


def cache_clear() -> None:
    """Forget what was found (tests that register a family)."""
    _entry_points.cache_clear()
    _load.cache_clear()


def papers() -> dict[str, Any]:
    """paper id -> the family that reproduces it."""
    return dict(sorted((f.paper.id, f) for f in families().values() if f.paper is not None))


def family(family_id: str):
    """One family, importing only it."""
    fam = _load(family_id) if family_id in _entry_points() else None
    if fam is None:
        raise ScenarioError("family", f"unknown family {family_id!r} (one of {', '.join(families())})")
    return fam


def paper(paper_id: str):
    """The paper's own reproduction."""
    from dse.contract.family import Reproduction

    found = papers().get(paper_id)
    if found is None:
        raise ScenarioError("PAPER", f"unknown paper {paper_id} (known: {', '.join(papers())})")
    return Reproduction(found, is_paper=True)


def from_dict(data: dict[str, Any]):
    """A user's scenario (a parsed file with its `family` key) as a run of its family."""
    from dse.contract.family import Reproduction
    from dse.scenario.fields import as_str

    known = _entry_points()
    if "family" not in data:
        if {"base", "scenario", "grid", "random"} & set(data):
            raise ScenarioError("family", "missing: this is a sweep file (it has base, grid or random); run it with "
                                          "`dse sweep`, or check its base scenario")
        raise ScenarioError("family", f"missing (one of {', '.join(known)})")
    fam = family(as_str(data.get("family"), "family", known))
    body = {k: v for k, v in data.items() if k != "family"}
    return Reproduction(fam, is_paper=False, _scenarios=(fam.scenario_from_dict(body),))

