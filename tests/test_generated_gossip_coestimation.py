"""Generated scenarios of the families listed for this file in `tests/generated_runs.py` (`SPLIT_FAMILIES`):
every claim on random valid scenarios, biased towards the edge cases (see tests/test_generated_scenarios.py)."""
from __future__ import annotations

import pytest

from generated_runs import cases, check_generated


@pytest.mark.parametrize("family,seed,edge", cases(("gossip-kalman", "coestimation")))
def test_generated_scenario_has_no_fail_and_no_error(family, seed, edge, tmp_path):
    check_generated(family, seed, edge, tmp_path)
