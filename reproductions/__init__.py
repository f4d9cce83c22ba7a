"""One subpackage per paper. The registries below are all the command line needs."""
from __future__ import annotations

import importlib
from typing import Any

from pipeline.errors import ScenarioError
from pipeline.scenario import as_str

#: paper id -> module that defines `paper()` returning its Reproduction
PAPERS = {"tanwani": "reproductions.tanwani.reproduction",
          "savas": "reproductions.savas.reproduction",
          "kar-moura": "reproductions.kar_moura.reproduction",
          "wang-liu-morse": "reproductions.wang_liu_morse.reproduction",
          "tran": "reproductions.tran.reproduction"}

#: scenario family (the `family` key of a user's TOML file) -> module with `from_dict(data)`
FAMILIES = {"random-comm-filter": "reproductions.tanwani.reproduction",
            "noisy-consensus-filter": "reproductions.savas.reproduction",
            "gossip-kalman": "reproductions.kar_moura.reproduction",
            "hybrid-observer": "reproductions.wang_liu_morse.reproduction",
            "coestimation": "reproductions.tran.reproduction",
            "compare": "reproductions.compare.reproduction"}

#: a valid scenario file of each family (documentation, and the seed of the input fuzz tests)
FAMILY_EXAMPLES = {"random-comm-filter": "tanwani/example.toml",
                   "noisy-consensus-filter": "savas/paper.toml",
                   "gossip-kalman": "kar_moura/scenarios/e1.toml",
                   "hybrid-observer": "wang_liu_morse/generic.toml",
                   "coestimation": "tran/paper.toml",
                   "compare": "compare/scenarios/tracking.toml"}


#: scenario family -> module with `EDGES` (names of edge cases) and `generate(seed, edge=None) -> dict`:
#: random valid scenarios, small enough for a quick run, for the property tests and the calibration benchmark
FAMILY_GENERATORS = {"random-comm-filter": "reproductions.tanwani.generators",
                     "noisy-consensus-filter": "reproductions.savas.generators",
                     "gossip-kalman": "reproductions.kar_moura.generators",
                     "hybrid-observer": "reproductions.wang_liu_morse.generators",
                     "coestimation": "reproductions.tran.generators",
                     "compare": "reproductions.compare.generators"}


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
