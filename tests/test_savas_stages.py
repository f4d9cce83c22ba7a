"""The noisy-consensus-filter stages: cache keys derived from their arguments and from the source of
every module they import (an edit to a module a stage imports, even transitively, changes its key;
an edit elsewhere does not), no stage importing a claims module, and a rerun read back from the cache."""
from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

import dse.registry
from dse.contract import stages
from dse.contract.options import RunOptions
from dse.contract.context import StageContext
from dse.contract.stages import code_closure
from dse.engine.cache import StageCache
from dse.families.savas import design, monte_carlo

ROOT = Path(__file__).resolve().parents[1]
STAGE_MODULES = ("dse.families.savas.design", "dse.families.savas.monte_carlo")
SMALL = {"family": "noisy-consensus-filter", "name": "keys", "graph": {"kind": "line", "n": 3},
         "consensus": {"weights": "laplacian", "eps": 0.4}, "model": {"q": 1.0, "r": 25.0},
         "sweep": {"rounds": [0, 1], "sigma_c": [0.0, 1.0], "n_steps": 6},
         "gains": {"grid": [21, 21]}, "monte_carlo": {"trials": 200, "sample_paths": 1}}


def _forget_code():
    """Forget the import graph and the source hashes read so far (they are cached per process)."""
    for f in (stages.direct_imports, stages.code_closure, stages.code_hash):
        f.cache_clear()


@pytest.fixture
def tree(tmp_path, monkeypatch):
    """A copy of the package's source, which the key derivation reads instead of the real one."""
    copy = tmp_path / "dse"
    shutil.copytree(ROOT / "dse", copy, ignore=shutil.ignore_patterns("__pycache__"))
    monkeypatch.setattr(stages, "_project_root", lambda: copy)
    _forget_code()
    yield copy
    monkeypatch.undo()
    _forget_code()


def _keys(sc) -> tuple[str, str]:
    """The code part of the keys of the design stage and of a Monte Carlo group."""
    _forget_code()
    d = design.design_arrays.params({"sc": sc, "grid": (21, 21)})
    mc = monte_carlo.simulate_group.params({"sc": sc, "seed": 0, "trials": 200, "steps": np.arange(6), "cells": ()})
    return d["code"], mc["code"]


def _edit(path: Path) -> None:
    path.write_text(path.read_text() + "\n# edited\n")


@pytest.mark.parametrize("module, changes", [
    ("estimators/gain_tuning.py", (True, False)),          # imported by the design stage
    ("estimators/consensus_trace.py", (True, False)),      # ... through design.py and gain_tuning.py
    ("estimators/consensus_covariance.py", (True, True)),  # ... by both, the simulator through consensus_filter
    ("estimators/consensus_filter.py", (False, True)),     # the simulator: the Monte Carlo only
    ("families/savas/scenario.py", (True, True)),          # the scenario both read
    ("families/savas/cells.py", (True, True)),             # ... and the cells
    ("families/savas/claims/theorem1.py", (False, False)),  # a claims module: no stage runs it
    ("families/savas/figures.py", (False, False)),
    ("outputs/record.py", (False, False)),
])
def test_an_edit_changes_the_keys_of_the_stages_that_import_it_and_no_other(tree, module, changes):
    sc = dse.registry.from_dict(SMALL).scenario
    before = _keys(sc)
    _edit(tree / module)
    after = _keys(sc)
    assert tuple(a != b for a, b in zip(before, after)) == changes


def test_no_stage_imports_a_claims_module():
    for name in STAGE_MODULES:
        closure = code_closure(name)
        assert not [m for m in closure if m.startswith("dse.families.savas.claims")], name
        assert "dse.estimators.consensus_filter" in closure or name.endswith("design")


def test_keys_follow_the_arguments_not_the_budget():
    sc = dse.registry.from_dict(SMALL).scenario
    other = dse.registry.from_dict({**SMALL, "name": "renamed", "monte_carlo": {"trials": 5000, "sample_paths": 1}}).scenario
    base = {"sc": sc, "seed": 0, "trials": 200, "steps": np.arange(6), "cells": (), "budget_bytes": 1.0}
    key = monte_carlo.simulate_group.params
    assert key(base) == key({**base, "sc": other, "budget_bytes": 2.0**30})     # name, trial counts, budget: unkeyed
    assert key(base) != key({**base, "seed": 1}) and key(base) != key({**base, "trials": 300})
    changed = dse.registry.from_dict({**SMALL, "model": {"q": 1.5, "r": 25.0}}).scenario
    assert design.design_arrays.params({"sc": sc, "grid": (21, 21)}) != design.design_arrays.params({"sc": changed,
                                                                                                    "grid": (21, 21)})


def test_a_second_run_reads_every_stage_back(tmp_path):
    run = dse.registry.from_dict(SMALL)
    opts = RunOptions(seed=1, quick=True)
    first, second = StageContext(StageCache(tmp_path)), StageContext(StageCache(tmp_path))
    a, b = run.compute(opts, first), run.compute(opts, second)
    names = [s["name"] for s in first.ran]
    assert names[0] == "design" and names.count("monte_carlo") == 5   # (algorithm, m) groups and the long run
    assert not any(s["cached"] for s in first.ran) and all(s["cached"] for s in second.ran)
    assert [s["key"] for s in first.ran] == [s["key"] for s in second.ran]
    for label, arrays in a.results.mc.items():
        for k, v in arrays.items():
            np.testing.assert_array_equal(v, b.results.mc[label][k], err_msg=f"{label} {k}")
