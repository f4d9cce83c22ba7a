"""Small scenarios a user might write first, one per family: each family's generator at its smallest edge case
(two nodes or two agents where it has one; gossip-kalman's periodic ring), seed 0. Generated when used, so that
they follow the generator's keys; `make bench` times `dse run --quick` on each (target 2 s) and the tests check
that `dse check` and `dse run` share their design (tests/test_check_shares_design.py)."""
from __future__ import annotations

from pathlib import Path

#: family id -> the generator's edge case used as the family's small scenario
SMALL_EDGES = {"coestimation": "two_nodes", "compare": "two_nodes", "gossip-kalman": "periodic",
               "hybrid-observer": "two_agents", "noisy-consensus-filter": "two_agents",
               "random-comm-filter": "two-nodes", "template": "two_nodes"}
SEED = 0


def small_scenario(family_id: str) -> dict:
    """The small scenario of a family, as a parsed scenario file."""
    from dse import registry

    return registry.families()[family_id].generate(SEED, SMALL_EDGES[family_id])


def write_small_scenarios(directory: Path) -> dict[str, Path]:
    """Every registered family's small scenario written to `directory` as <family id>.toml; family id -> path."""
    from dse import registry

    from .common import toml_text

    out = {}
    for family_id in registry.families():
        path = Path(directory) / f"{family_id}.toml"
        path.write_text(toml_text(small_scenario(family_id)))
        out[family_id] = path
    return out
