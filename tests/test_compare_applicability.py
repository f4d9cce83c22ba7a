"""One applicability rule for the constant-gain filters of `compare`: mean-square stability of the error
recursion with the gains they would run with (a computed steady state; spectral radius < 1 on reliable
links), the same for Carli's, the
re-injection and the pairwise filters (an unstable plant once had re-injection gains of radius 2.6 counted
as applicable)."""
import numpy as np

from dse import api

UNSTABLE = {"family": "compare", "name": "unstable",
            "plant": {"F": [[2.0]], "Q": [[1.0]], "P0": [[1.0]]},
            "sensors": {"types": [{"H": [[1.0]], "R": [[25.0]]}, {"H": [[1.0]], "R": [[1e4]]}]},
            "graph": {"kind": "ring", "n": 8},
            "links": {"model": "reliable", "rounds": 1, "noise_std": 1.0},
            "estimators": {"include": ["carli", "reinjection", "pairwise"]},
            "simulation": {"steps": 40, "trials": 4000, "quick_trials": 1000}}
CONSTANT_GAIN = ["carli", "reinjection", "pairwise"]


def test_a_constant_gain_filter_applies_exactly_when_its_recursion_is_mean_square_stable():
    chk = api.check(UNSTABLE, quick=True)
    table = chk.tables["applicability"].set_index("estimator").loc[CONSTANT_GAIN]
    rho, steady = table["mean_square_radius"].to_numpy(float), table["steady_mse"].to_numpy(float)
    assert np.isfinite(rho).all() and ((rho < 1) == np.isfinite(steady)).all()
    assert (table["applies"].to_numpy(bool) == np.isfinite(steady)).all(), table[["applies", "steady_mse", "reason"]]
    unstable = table[~np.isfinite(steady)]
    assert len(unstable) and unstable["reason"].str.contains("no steady state, spectral radius").all()
    assert table.loc["carli", "applies"] and not table.loc["reinjection", "applies"]   # the case
    stable = {h["id"]: h for h in chk.hypotheses}["compare.hyp.mean_square_stable"]
    assert stable["holds"] is False and stable["value"] >= 1
