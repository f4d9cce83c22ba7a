"""One subpackage per paper. The registries below are all the command line needs."""
from __future__ import annotations

import importlib
from typing import Any

from dse.errors import ScenarioError
from dse.scenario.fields import as_str

#: paper id -> module that defines `paper()` returning its Reproduction
PAPERS = {"tanwani": "dse.families.tanwani.reproduction",
          "savas": "dse.families.savas.reproduction",
          "kar-moura": "dse.families.kar_moura.reproduction",
          "wang-liu-morse": "dse.families.wang_liu_morse.reproduction",
          "tran": "dse.families.tran.reproduction"}

#: scenario family (the `family` key of a user's TOML file) -> module with `from_dict(data)`
FAMILIES = {"random-comm-filter": "dse.families.tanwani.reproduction",
            "noisy-consensus-filter": "dse.families.savas.reproduction",
            "gossip-kalman": "dse.families.kar_moura.reproduction",
            "hybrid-observer": "dse.families.wang_liu_morse.reproduction",
            "coestimation": "dse.families.tran.reproduction",
            "compare": "dse.families.compare.reproduction"}

#: a valid scenario file of each family (documentation, and the seed of the input fuzz tests)
FAMILY_EXAMPLES = {"random-comm-filter": "tanwani/example.toml",
                   "noisy-consensus-filter": "savas/paper.toml",
                   "gossip-kalman": "kar_moura/scenarios/e1.toml",
                   "hybrid-observer": "wang_liu_morse/generic.toml",
                   "coestimation": "tran/paper.toml",
                   "compare": "compare/scenarios/tracking.toml"}


#: scenario family -> module with `EDGES` (names of edge cases) and `generate(seed, edge=None) -> dict`:
#: random valid scenarios, small enough for a quick run, for the property tests and the calibration benchmark
FAMILY_GENERATORS = {"random-comm-filter": "dse.families.tanwani.generators",
                     "noisy-consensus-filter": "dse.families.savas.generators",
                     "gossip-kalman": "dse.families.kar_moura.generators",
                     "hybrid-observer": "dse.families.wang_liu_morse.generators",
                     "coestimation": "dse.families.tran.generators",
                     "compare": "dse.families.compare.generators"}


def generator(family: str):
    return importlib.import_module(FAMILY_GENERATORS[family])


def paper(paper_id: str):
    return importlib.import_module(PAPERS[paper_id]).paper()


def family_from_dict(data: dict[str, Any]):
    family = as_str(data.get("family"), "family", FAMILIES) if "family" in data else None
    if family is None:
        if "base" in data or "grid" in data or "random" in data:
            raise ScenarioError("family", "missing: this is a sweep file (it has base, grid or random); run it with "
                                          "`dse sweep`, or check its base scenario")
        raise ScenarioError("family", f"missing (one of {', '.join(FAMILIES)})")
    body = {k: v for k, v in data.items() if k != "family"}
    return importlib.import_module(FAMILIES[family]).from_dict(body)


def family_metrics(family: str, results: Any) -> dict[str, float]:
    """A family's summary metrics of one run (for `dse sweep`): `metrics(results)` of the
    family's `metrics` module next to its reproduction, or none when it has no such module."""
    name = FAMILIES[family].rsplit(".", 1)[0] + ".metrics"
    try:
        module = importlib.import_module(name)
    except ModuleNotFoundError as exc:
        if exc.name != name:
            raise
        return {}
    return module.metrics(results)
