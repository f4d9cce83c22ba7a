"""The gossip-kalman stages' cache keys are derived from their code: editing a module a stage imports,
directly or transitively, changes the stage's key; editing a module it does not import (a claims
module, another family) does not; and no stage imports a claims module."""
from __future__ import annotations

import pytest

from dse.contract import stages
from dse.contract.stages import StageResult, code_closure
from dse.families.kar_moura.bounds import bound_checks, bounds
from dse.families.kar_moura.eq74 import eq74
from dse.families.kar_moura.gikf import gikf
from dse.families.kar_moura.scenario import load_scenario
from dse.families.kar_moura.theorem8 import aux, pullback_divergent, theorem8

STAGES = (bounds, bound_checks, gikf, theorem8, aux, pullback_divergent, eq74)
PACKAGE = "dse.families.kar_moura"


def _clear():
    for f in (stages.direct_imports, stages.code_closure, stages.code_hash):
        f.cache_clear()


@pytest.fixture
def edit(monkeypatch, tmp_path):
    """edit(module): the module's source as the key sees it gains a line (a copy; the tree is untouched)."""
    original = stages.module_file

    def apply(module: str) -> None:
        path = original(module)
        copy = tmp_path / f"{module}.py"
        copy.write_text(path.read_text() + "\n# an edit\n")
        monkeypatch.setattr(stages, "module_file", lambda name: copy if name == module else original(name))
        _clear()

    _clear()
    yield apply
    monkeypatch.undo()
    _clear()


def _gikf_key() -> dict:
    sc, upstream = load_scenario("e1"), StageResult()
    upstream.key = "bounds-0"
    return gikf.params(gikf.bound((sc, upstream, 0, 1000, 40, "protocol", 2.0**20, 1.0), {}))


def test_editing_an_imported_module_changes_the_key(edit):
    before = _gikf_key()
    assert before == _gikf_key()                              # deterministic
    edit("dse.estimators.gikf_maps")                          # imported through dse.estimators.gikf_monte_carlo
    after = _gikf_key()
    assert after["code"] != before["code"] and after["inputs"] == before["inputs"]


@pytest.mark.parametrize("module", ["dse.families.kar_moura.claims_theorems", "dse.families.tanwani.scenario",
                                    "dse.families.kar_moura.views"])
def test_editing_an_unrelated_module_keeps_the_key(edit, module):
    before = _gikf_key()
    edit(module)
    assert _gikf_key() == before


def test_the_budget_is_not_part_of_the_key():
    a, b = _gikf_key(), _gikf_key()
    sc, upstream = load_scenario("e1"), StageResult()
    upstream.key = "bounds-0"
    c = gikf.params(gikf.bound((sc, upstream, 0, 1000, 40, "protocol", 1.0, 99.0), {}))
    assert a == b == c


@pytest.mark.parametrize("st", STAGES, ids=[s.name for s in STAGES])
def test_no_stage_imports_a_claims_module(st):
    closure = code_closure(st.module)
    assert f"{PACKAGE}.scenario" in closure
    claims = {m for m in closure if m.startswith(f"{PACKAGE}.") and m.rpartition(".")[2] in
              ("claims", "hypotheses", "checking", "stats", "tables", "views", "cost", "family")
              or m.startswith(f"{PACKAGE}.claims_")}
    assert not claims, claims


@pytest.mark.parametrize("edge", ["stable-f", "c1-fail-oblique", "actuators"])
def test_centralized_reference_and_class_floors_start_from_the_declared_prior(edge):
    """The centralized filter's prior covariances P_c(t) and each class floor, on a generated scenario with a prior
    mean x0 ≠ 0 and a non-identity P0, against filterpy's KalmanFilter started from the declared P0 (an
    independent implementation; the prior mean does not enter a covariance)."""
    import numpy as np
    import scipy.linalg
    from filterpy.kalman import KalmanFilter

    from dse import registry
    from dse.families.kar_moura.generator import generate

    data = generate(3, edge)
    P0 = np.array(data["model"]["P0"])
    assert np.any(np.array(data["model"]["x0"]) != 0) and not np.allclose(P0, np.eye(len(P0)))
    sc = registry.from_dict(data).scenarios[0]
    T = 12
    b = bounds.__wrapped__(sc, T)
    sys_ = sc.system

    def filterpy_priors(C, R):
        kf = KalmanFilter(dim_x=sc.M, dim_z=C.shape[0])
        kf.F, kf.Q, kf.H, kf.R, kf.P = sc.F, sc.Q, C, R, P0.copy()
        out = []
        for _ in range(T + 1):
            out.append(kf.P.copy())
            kf.update(np.zeros(C.shape[0]))
            kf.predict()
        return np.array(out)

    ref = filterpy_priors(sys_.C_all, sys_.R_all)
    assert np.allclose(b["P_central"], ref, rtol=0, atol=1e-12 * np.abs(ref).max())
    for c, cls in enumerate(sc.assumptions.classes):
        idx = list(cls)
        floor = filterpy_priors(sys_.C[idx].reshape(-1, sc.M), scipy.linalg.block_diag(*sys_.R[idx]))
        assert np.allclose(b["P_floor"][:, c], floor, rtol=0, atol=1e-12 * np.abs(floor).max())
