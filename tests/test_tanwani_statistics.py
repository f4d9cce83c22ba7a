"""The tests behind the statistical claims of the random-comm-filter family keep their level on
heavy-tailed samples, and the errata's reference generator is the one of (9)."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from dse.families.tanwani.claims_common import path_mean_pvalues
from dse.families.tanwani.claims_references import erratum_states, generator_by_definition, generator_formula
from dse.families.tanwani.scenario import load_scenario

REPS = 4000


def _rare(rng, n):
    """Nonnegative, a 1% component 50 times larger: most samples of 300 miss it or see a few."""
    x = rng.exponential(1.0, (REPS, n)) + 50.0 * (rng.random((REPS, n)) < 0.01)
    return x, 1.5, 1.0 + 0.01 * 0.99 * 50.0 ** 2


def _rare_low(rng, n):
    """Nonnegative and left-skewed: usually 10, rarely (1%) 0."""
    x = 10.0 * (rng.random((REPS, n)) >= 0.01)
    return x, 9.9, 100 * 0.01 * 0.99


def _lognormal(rng, n):
    return rng.lognormal(0.0, 1.0, (REPS, n)), np.exp(0.5), (np.exp(1.0) - 1) * np.exp(1.0)


@pytest.mark.parametrize("law", [_rare, _rare_low, _lognormal])
@pytest.mark.parametrize("n", [50, 300])
def test_path_mean_test_keeps_its_level(law, n):
    """The plain z-test rejects these at many times its level; ours at most at its level (with
    the binomial allowance of REPS replications)."""
    x, mu, var = law(np.random.default_rng(n), n)
    p = path_mean_pvalues(x.sum(1), np.square(x).sum(1), n, mu, var)
    for level in (0.01, 0.05):
        rate = float(np.mean(p <= level))
        assert rate <= level + 3 * np.sqrt(level / REPS), (law.__name__, n, level, rate)


def test_path_mean_test_has_power():
    rng = np.random.default_rng(1)
    x = rng.exponential(1.0, (200, 300))
    p = path_mean_pvalues(x.sum(1), np.square(x).sum(1), 300, 1.3, 1.0)       # the true mean is 1
    assert np.mean(p <= 0.01) > 0.9


def test_efron_bound_for_paired_heavy_tails():
    """Σd/√Σd² for sign-symmetric d (differences of two samples of the same Pareto law): the
    two-sided bound 2exp(−x²/2) is conservative at every sample size."""
    rng = np.random.default_rng(2)
    for n in (20, 300):
        d = rng.pareto(1.5, (REPS, n)) - rng.pareto(1.5, (REPS, n))
        S, Q = d.sum(1), np.square(d).sum(1)
        p = np.minimum(1.0, 2 * np.exp(-S ** 2 / (2 * Q)))
        assert np.mean(p <= 0.05) <= 0.05


@pytest.mark.parametrize("name", ["s2", "s3"])
def test_generator_from_its_definition_is_that_of_9(name):
    sc = load_scenario(name)
    s = sc.gossip
    r = SimpleNamespace(sys=s, scenario=sc, bound=lambda lam: np.broadcast_to(s.P0, (2, s.N, s.n, s.n)))
    Q = erratum_states(r)
    ref, tol = generator_by_definition(r, Q)
    coupling = sum(s.jump(c) - np.eye(s.N) for c in range(len(s.clocks)))
    corrected = generator_formula(r, Q, coupling)
    assert np.abs(corrected - ref).max() <= tol < 1e-5 * np.abs(ref).max()
    printed = generator_formula(r, Q, s.alpha * s.laplacian)
    assert np.abs(printed - ref).max() > 1e3 * tol
