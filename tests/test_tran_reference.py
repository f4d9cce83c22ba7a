"""The coestimation run's centralized Kalman filter (`reference.run_kalman`) computes filterpy's
KalmanFilter.predict and .update without importing filterpy (and with it scipy.stats): filterpy is the
oracle here, run step for step on the same inputs, and the estimates must be the same bits, with the
deterministic run's fictitious noise and with the stochastic run's sampled measurement noise."""
from __future__ import annotations

import subprocess
import sys
from types import SimpleNamespace

import numpy as np
import pytest
from filterpy.kalman import KalmanFilter

from dse import registry
from dse.families.tran import reference


def _filterpy_predict(s, P, F, Q):
    kf = KalmanFilter(dim_x=len(s), dim_z=1)
    kf.x, kf.P, kf.F, kf.Q = s, P, F, Q
    kf.predict()
    return kf.x, kf.P


def _filterpy_update(s, P, z, R, H):
    kf = KalmanFilter(dim_x=len(s), dim_z=len(z))
    kf.x, kf.P = s, P
    kf.update(z, R=R, H=H)
    return kf.x, kf.P


@pytest.fixture(scope="module")
def scenario():
    fam = registry.families()["coestimation"]
    return registry.from_dict(fam.generate(3, "two_nodes")).scenario


@pytest.mark.parametrize("noisy", [False, True])
def test_run_kalman_is_filterpy_bit_for_bit(scenario, noisy, monkeypatch):
    sc, rng = scenario, np.random.default_rng(7)
    steps = 60
    t = np.arange(steps) * sc.reference.dt
    x = rng.normal(size=(steps, sc.n))
    g = (rng.random((steps, sc.N)) > 0.4).astype(float)   # sensors switching on and off, some steps with none
    g[5] = 0.0
    noise = SimpleNamespace(process=rng.normal(size=(sc.n, 1)), measurement=rng.normal(size=(sc.N, sc.m, 1))) \
        if noisy else None
    ours = reference.run_kalman(sc, t, x, g, noise=noise, rng=np.random.default_rng(1) if noisy else None)
    monkeypatch.setattr(reference, "_predict", _filterpy_predict)
    monkeypatch.setattr(reference, "_update", _filterpy_update)
    oracle = reference.run_kalman(sc, t, x, g, noise=noise, rng=np.random.default_rng(1) if noisy else None)
    assert np.isfinite(ours["s"]).all()
    assert ours["s"].tobytes() == oracle["s"].tobytes()


def test_the_run_does_not_import_filterpy():
    """A coestimation run (computed, checked and tabulated) imports neither filterpy nor scipy.stats (a third
    of a second of a small run)."""
    code = ("import sys, dse; from dse import registry; fam = registry.families()['coestimation']; "
            "dse.run(fam.generate(0, 'two_nodes'), quick=True, workers=1); "
            "print(sorted(m for m in ('filterpy', 'scipy.stats') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip().splitlines()[-1] == "[]"


def test_graph_edges_in_networkx_order():
    """The views' edge list (figures, recording) is networkx's, in networkx's order, without building the graph."""
    from dse.families.tran.views import graph_edges
    from dse.scenario.graphs import GraphSpec

    rng = np.random.default_rng(0)
    specs = [GraphSpec(kind=k, n=n) for k in ("line", "ring", "complete") for n in range(2, 9)]
    specs += [GraphSpec(kind="grid", n=12, rows=3, cols=4), GraphSpec(kind="random_geometric", n=10, radius=0.5, seed=1)]
    for n in range(3, 9):
        pairs = [(u, v) for u in range(n) for v in range(u + 1, n)]
        for _ in range(30):
            chosen = rng.permutation(len(pairs))[:rng.integers(1, len(pairs) + 1)]
            edges = tuple(pairs[i][::-1] if rng.random() < 0.5 else pairs[i] for i in chosen)
            specs.append(GraphSpec(kind="edges", n=n, edges=edges))
    for spec in specs:
        assert graph_edges(spec) == [(int(u), int(v)) for u, v in spec.build().edges()], spec
