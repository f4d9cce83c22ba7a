"""A valid scenario whose numbers float64 cannot hold ends in one line and exit 3, never a traceback
or exit 1 (which means --strict or verify found a fail)."""
import pickle
import warnings

import numpy as np
import pytest

from dse.cli import main
from dse.errors import NumericalError, NumericalLimit
from dse.estimators import consensus_covariance as cc

RING5 = """family = "noisy-consensus-filter"
name = "ring5-huge-r"
[graph]
kind = "ring"
n = 5
[model]
q = 1.0
r = 1e40
[sweep]
"""


def ring_weights(n: int) -> np.ndarray:
    Q = np.zeros((n, n))
    for i in range(n):
        Q[i, i] = Q[i, (i + 1) % n] = Q[i, (i - 1) % n] = 1 / 3
    return Q


def test_noisy_consensus_with_r_1e40_is_a_one_line_exit_3(tmp_path, capsys):
    path = tmp_path / "ring5.toml"
    path.write_text(RING5)
    with warnings.catch_warnings():
        warnings.simplefilter("error")          # and no raw numpy warning on the way
        assert main(["check", str(path), "--quick", "--out", str(tmp_path / "out")]) == 3
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("dse: numerical failure: beyond float64: no steady-state covariance")


def test_gain_below_the_rounding_unit_is_a_numerical_limit_not_a_value_error():
    kwargs = dict(ell=1e-20, m=1, sigma_c=0.0, q=1.0, r=1e40, reinjection=False)
    with pytest.raises(NumericalLimit, match="below the rounding unit"):
        cc.asymptotic_covariance_summary(ring_weights(5), **kwargs)
    with pytest.raises(NumericalLimit):
        cc.asymptotic_covariance_lyapunov(ring_weights(5), **kwargs)
    # the transient still exists: with (1-ell)^2 rounding to 1 each step adds b (the limit of the closed form)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        P = cc.predictive_covariance_at_steps(ring_weights(5), steps=[0, 1, 10], sigma0=1.0, **kwargs)
    assert np.all(np.isfinite(P.trace)) and np.all(np.diff(P.trace) > 0)


def test_numerical_limit_is_a_numerical_error_that_survives_pickling():
    exc = pickle.loads(pickle.dumps(NumericalLimit("the gain rounds away")))
    assert isinstance(exc, NumericalError) and str(exc) == "beyond float64: the gain rounds away"


COMPARE_HUGE_F = """family = "compare"
name = "huge-f"
[plant]
F = [[1e10, 0.0], [0.0, 1.01]]
Q = [[0.05, 0.0], [0.0, 0.05]]
[sensors]
types = [{ H = [[1.0, 0.0]], R = [[1.0]] }, { H = [[0.0, 1.0]], R = [[1.0]] }]
[graph]
kind = "line"
n = 4
[links]
model = "matchings"
[simulation]
steps = 20
trials = 200
quick_trials = 100
"""


def test_a_matrix_singular_at_working_precision_is_a_one_line_exit_3(tmp_path, capsys):
    # F = 1e10 is inside the documented magnitudes; the centralized filter's innovation covariance
    # HPHᵀ + R (P ~ 1e20) is singular in float64: numpy's LinAlgError traceback, exit 1, before
    path = tmp_path / "huge.toml"
    path.write_text(COMPARE_HUGE_F)
    assert main(["run", str(path), "--quick", "--no-figures", "--out", str(tmp_path / "out")]) == 3
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "stage 'exact_moments', scenario 'huge-f': Singular matrix in kalman_covariances" in err


def test_only_numerical_linear_algebra_errors_become_numerical_limits():
    from dse.contract.context import beyond_float64

    singular = np.linalg.LinAlgError("Singular matrix")
    assert isinstance(beyond_float64(singular, "design", "s"), NumericalLimit)
    shape = np.linalg.LinAlgError("Last 2 dimensions of the array must be square")
    assert beyond_float64(shape, "design", "s") is shape          # a defect of ours stays a traceback
