"""The arena's standard suite: the shipped compare scenarios and generated ones that cover the four link
models, communication noise, weak detectability, an unstable plant and two-row sensors
(`dse.families.compare.generator`), each as a compare scenario dict with the filter's table added.

The suite is declared here once: `dse arena --quick` runs every scenario with its quick trial count and one
seed of each generated edge case; the full suite adds a second seed of each.
"""
from __future__ import annotations

import copy
from dataclasses import dataclass
from typing import Any

#: the shipped compare scenarios (dse/families/compare/scenarios/<name>.toml)
SHIPPED = ("tracking", "noisy_ring", "gossip_weak")
#: the generator's edge cases in the suite: every link model, noise levels, the hard cases
GENERATED = ("reliable_noisy_scalar", "failures", "matchings", "poisson", "poisson_noisy", "weak_detectability",
             "unstable_plant", "two_row_sensors")
#: seeds of the generated scenarios: quick suite, full suite
SEEDS = {True: (0,), False: (0, 1)}


@dataclass(frozen=True)
class Entry:
    """One scenario of the suite: its name, where it comes from, and the scenario dict (without the filter)."""

    name: str
    origin: str
    scenario: dict[str, Any]


def entries(quick: bool) -> list[Entry]:
    """The suite, in the leaderboard's order."""
    from dse import registry
    from dse.scenario.fields import load_toml

    family = registry.family("compare")
    out = []
    for name in SHIPPED:
        path = family.directory() / "scenarios" / f"{name}.toml"
        out.append(Entry(name, f"shipped: {path.name}", load_toml(path)))
    for edge in GENERATED:
        for seed in SEEDS[quick]:
            data = family.generate(seed, edge)
            out.append(Entry(data["name"], f"generated: compare generator, edge {edge}, seed {seed}", data))
    return out


def with_filter(scenario: dict[str, Any], name: str, table: dict[str, Any]) -> dict[str, Any]:
    """The scenario with the filter's table `[estimators.<name>]` (every built-in estimator runs too)."""
    data = copy.deepcopy(scenario)
    estimators = dict(data.get("estimators", {}))
    estimators.pop("include", None)              # every built-in: the leaderboard compares with all of them
    estimators[name] = dict(table)
    data["estimators"] = estimators
    return data
