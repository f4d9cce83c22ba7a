"""The reference numbers of the reproduction's own scenarios apply only to those scenarios: a
scenario that keeps such a name but changes the system (as a sweep point does) gets
`not-checkable`, not a crash."""
from __future__ import annotations

import copy
from pathlib import Path
from types import SimpleNamespace

import pytest

from dse.scenario.fields import load_toml
from dse.families.tanwani.claims_references import reference_differences
from dse.families.tanwani.scenario import scenario_from_dict

SCENARIOS = Path(__file__).resolve().parents[1] / "dse" / "families" / "tanwani" / "scenarios"


def _results(data: dict) -> SimpleNamespace:
    return SimpleNamespace(scenario=scenario_from_dict({k: v for k, v in data.items() if k != "family"}))


@pytest.mark.parametrize("name", ["s1a", "s1b", "s1c", "s2", "s3"])
def test_shipped_scenarios_match_themselves(name):
    assert reference_differences(_results(load_toml(SCENARIOS / f"{name}.toml")), name) == ([], True)


def test_changed_system_or_clock_is_detected():
    s2 = load_toml(SCENARIOS / "s2.toml")
    changed = copy.deepcopy(s2)
    changed["communication"]["alpha"] = 0.3
    changed["graph"]["kind"] = "line"
    assert reference_differences(_results(changed), "s2") == (["edges", "alpha"], True)
    slower = copy.deepcopy(s2)
    slower["communication"]["rates"] = [0.5]
    assert reference_differences(_results(slower), "s2") == ([], False)
