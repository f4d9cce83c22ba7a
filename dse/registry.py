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
def families() -> dict[str, Any]:
    """family id -> Family instance, by id."""
    out: dict[str, Any] = {}
    for ep in sorted(entry_points(group=GROUP), key=lambda e: e.name):
        try:
            cls = ep.load()
            if getattr(cls, "id", None) != ep.name:
                raise ValueError(f"the entry point names family {ep.name}, the class declares {getattr(cls, 'id', None)!r}")
            out[ep.name] = cls()
        except Exception as exc:   # one broken plugin does not take the others down
            print(f"dse: family {ep.name} ({ep.value}) could not be loaded and is skipped: {type(exc).__name__}: {exc}",
                  file=sys.stderr)
    if not out:
        raise RuntimeError(f"no scenario family is registered (entry point group {GROUP}): is dse installed?")
    return out


def papers() -> dict[str, Any]:
    """paper id -> the family that reproduces it."""
    return dict(sorted((f.paper.id, f) for f in families().values() if f.paper is not None))


def family(family_id: str):
    try:
        return families()[family_id]
    except KeyError:
        raise ScenarioError("family", f"unknown family {family_id!r} (one of {', '.join(families())})") from None


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

    known = families()
    if "family" not in data:
        if "base" in data or "grid" in data or "random" in data:
            raise ScenarioError("family", "missing: this is a sweep file (it has base, grid or random); run it with "
                                          "`dse sweep`, or check its base scenario")
        raise ScenarioError("family", f"missing (one of {', '.join(known)})")
    fam = known[as_str(data.get("family"), "family", known)]
    body = {k: v for k, v in data.items() if k != "family"}
    return Reproduction(fam, is_paper=False, _scenarios=(fam.scenario_from_dict(body),))

