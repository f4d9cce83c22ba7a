"""The random-comm-filter claims evaluate their tests' laws with scipy.special, not scipy.stats (0.3 s to
import): the values must be scipy.stats' own, bit for bit, edge cases included (out-of-range arguments,
points outside the support, infinities and nan), or a report would change."""
import numpy as np
import pytest
from scipy import stats

from dse.families.tanwani import claims_common as cc


def same_bits(a, b) -> bool:
    a, b = np.asarray(a, float), np.asarray(b, float)
    return a.shape == b.shape and np.array_equal(a.view(np.int64), b.view(np.int64)) or (
        a.shape == b.shape and bool(np.all((a == b) | (np.isnan(a) & np.isnan(b)))))


EDGES = np.array([-np.inf, -1e300, -50.0, -3.5, -1.0, -0.5, -0.0, 0.0, 1e-300, 0.5, 1.0, 2.0, 3.5, 7.0, 50.0, 1e300,
                  np.inf, np.nan])


@pytest.fixture(scope="module")
def rng():
    return np.random.default_rng(24)


def test_continuous_laws(rng):
    x = np.concatenate([EDGES, rng.standard_normal(400) * 5, rng.exponential(10, 400)])
    for df in (-1.0, 0.0, 0.5, 1.0, 2.0, 7.0, 299.0, 1e6, np.inf, np.nan):
        assert same_bits(cc.t_sf(x, df), stats.t.sf(x, df)), df
        assert same_bits(cc.chi2_cdf(x, df), stats.chi2.cdf(x, df)), df
        assert same_bits(cc.chi2_sf(x, df), stats.chi2.sf(x, df)), df
    dfs = rng.integers(0, 2000, x.size).astype(float)
    assert same_bits(cc.t_sf(x, dfs), stats.t.sf(x, dfs))
    assert same_bits(cc.chi2_cdf(np.abs(x), dfs), stats.chi2.cdf(np.abs(x), dfs))
    assert same_bits(cc.chi2_sf(np.abs(x), dfs), stats.chi2.sf(np.abs(x), dfs))
    assert same_bits(cc.norm_sf(x), stats.norm.sf(x))
    assert same_bits(cc.t_sf(1.5, 3), stats.t.sf(1.5, 3)) and np.ndim(cc.t_sf(1.5, 3)) == 0


def test_discrete_laws(rng):
    k = np.concatenate([EDGES, np.arange(-3, 60, dtype=float), rng.uniform(-2, 80, 300)])
    for mu in (-1.0, 0.0, 1e-3, 0.7, 5.0, 40.0, 1e4, np.inf, np.nan):
        assert same_bits(cc.poisson_cdf(k, mu), stats.poisson.cdf(k, mu)), mu
        assert same_bits(cc.poisson_sf(k, mu), stats.poisson.sf(k, mu)), mu
    for n in (-1.0, 0.0, 1.0, 10.0, 10.5, 50.0, 300.0, np.nan):
        for p in (-0.1, 0.0, 1e-9, 0.3, 0.5, 0.99, 1.0, 1.2, np.nan):
            assert same_bits(cc.binom_cdf(k, n, p), stats.binom.cdf(k, n, p)), (n, p)
            assert same_bits(cc.binom_sf(k, n, p), stats.binom.sf(k, n, p)), (n, p)
    mus, ns, ps = rng.exponential(20, k.size), rng.integers(0, 100, k.size).astype(float), rng.uniform(0, 1, k.size)
    assert same_bits(cc.poisson_cdf(k, mus), stats.poisson.cdf(k, mus))
    assert same_bits(cc.poisson_sf(k - 1, mus), stats.poisson.sf(k - 1, mus))
    assert same_bits(cc.binom_cdf(k, ns, ps), stats.binom.cdf(k, ns, ps))
    assert same_bits(cc.binom_sf(k - 1, ns, ps), stats.binom.sf(k - 1, ns, ps))
