"""The evidence behind a claim: the figures, table rows and recording entity a claim's page links to.

A claim does not name its evidence; the run's files do, by convention: a claim evaluated per scenario
carries the scenario's name as one dot-separated part of its id (`kar-moura.lemma16.support.e1`),
and the figures (`tails_vs_bound_e1.png`), recordings (`e1.rrd`) and table rows (`scenario == "e1"`)
of that scenario carry it too. A claim whose source cites a figure (`Fig. 2`) links to the figure of
that number. Every recording logs every claim it holds under `/claims/<claim id>`, and every run's
`claims` table has the claim's own row.
"""
from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

_FIGURE_CITED = re.compile(r"Fig(?:ure|\.)?\s*(\d+)", re.IGNORECASE)


@dataclass
class Evidence:
    figures: list[str] = field(default_factory=list)          # figure file names
    tables: list[tuple[str, str]] = field(default_factory=list)  # (table name, scenario) to filter on
    recording: str | None = None                               # recording file name
    entity: str = ""                                           # the claim's entity in the recording


def _scenario(claim_id: str, known: set[str]) -> str | None:
    """The scenario a claim is about: the last part of its id that names a scenario of the run."""
    for part in reversed(claim_id.split(".")):
        if part in known:
            return part
    return None


def _figures(claim: dict, scenario: str | None, figures: list[Path]) -> list[str]:
    if scenario:
        mine = [f.name for f in figures if f.stem == scenario or f.stem.endswith(f"_{scenario}")]
        if mine:
            return mine
    cited = {f"fig{n}" for n in _FIGURE_CITED.findall(str(claim.get("source", "")))}
    return [f.name for f in figures if f.stem in cited]


def _recording(scenario: str | None, recordings: list[Path]) -> str | None:
    if not recordings:
        return None
    named = [r.name for r in recordings if scenario and r.stem == scenario]
    return named[0] if named else recordings[0].name


def evidence(claim: dict, figures: list[Path], recordings: list[Path], table_scenarios: dict[str, list[str]]) -> Evidence:
    """The figures, table rows and recording entity behind `claim` (a report.json claim row)."""
    known = {r.stem for r in recordings} | {s for values in table_scenarios.values() for s in values}
    scenario = _scenario(str(claim["id"]), known)
    tables = [("claims", "")] if "claims" in table_scenarios else []
    if scenario:
        tables += [(name, scenario) for name, values in table_scenarios.items() if scenario in values]
    return Evidence(figures=_figures(claim, scenario, figures), tables=tables,
                    recording=_recording(scenario, recordings), entity=f"/claims/{claim['id']}")
