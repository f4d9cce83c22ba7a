"""A plug-in filter's code keys what it computes: editing any file of its package makes the stage cache, the run
memo and the arena's stored scenarios recompute (they are keyed by the project's code otherwise)."""
from __future__ import annotations

import importlib
import sys
import textwrap

import numpy as np

from dse import registry
from dse.api import execute, run_key
from dse.contract.options import RunOptions

FILTER = '''
import numpy as np
from dse.plugin import NetworkFilter
from .helper import SCALE


class Scaled(NetworkFilter):
    """x̂ = SCALE · ŷ-free prior mean, a filter whose numbers change with its helper module."""

    def __init__(self, problem, params, trials):
        super().__init__(problem, params, trials)
        self.x = np.broadcast_to(problem.x0[None, :, None], (problem.N, problem.n, trials)).copy()

    def step(self, k, y, network):
        self.x = np.matmul(self.problem.F, self.x) * SCALE
        return self.x
'''


def _package(root, scale: float):
    pkg = root / "keyed_plugin"
    pkg.mkdir(exist_ok=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "filter.py").write_text(textwrap.dedent(FILTER))
    (pkg / "helper.py").write_text(f"SCALE = {scale!r}\n")


def _scenario():
    data = registry.family("compare").generate(0, "failures")
    data["estimators"] = {"include": ["local"], "scaled": {"factory": "keyed_plugin.filter:Scaled"}}
    return data


def test_editing_a_helper_module_of_a_plugin_changes_its_keys_and_numbers(tmp_path, monkeypatch):
    monkeypatch.syspath_prepend(str(tmp_path))
    # no bytecode for the package: its two versions of helper.py have the same size and are written within a second,
    # so a .pyc of the first (written when bytecode is allowed, as `make test` allows it) would pass for the second
    monkeypatch.setattr(sys, "dont_write_bytecode", True)
    _package(tmp_path, 1.0)
    opts = RunOptions(seed=0, quick=True, workers=1)
    data = _scenario()
    first = execute(registry.from_dict(data), opts, cache_dir=tmp_path / "cache", source=data)
    key1 = run_key(registry.from_dict(data), opts, data)
    for name in ("keyed_plugin.filter", "keyed_plugin.helper", "keyed_plugin"):
        sys.modules.pop(name, None)
    _package(tmp_path, 0.5)
    importlib.invalidate_caches()
    second = execute(registry.from_dict(data), opts, cache_dir=tmp_path / "cache", source=data)
    assert run_key(registry.from_dict(data), opts, data) != key1
    assert not second.provenance["memo"]
    a, b = (r.tables["estimators"].set_index("estimator").loc["scaled", "network_mse_mc"] for r in (first, second))
    assert a != b and np.isfinite(a) and np.isfinite(b)
    same = (r.tables["estimators"].set_index("estimator").loc["local", "network_mse_mc"] for r in (first, second))
    assert len(set(same)) == 1
