"""Issue 26, the hybrid observer with 6 to 8 agents: the q's of (22), (21)+(19), the minimal one and
(27) as exact integers (against an independent computation in exact rational arithmetic), α^p of
the runs from the safe end of ρ's bracket (1 for p = 0), and σ of (26) reported as not enumerated
with its reason; end to end on a 7-agent scenario of the issue's class (ρ = 0 up to round-off)."""
from __future__ import annotations

import copy
import math
from fractions import Fraction

import numpy as np
import pytest

import dse.estimators.jointly_observable_design as jd
from dse import api
from dse.families.wang_liu_morse.design import alpha_power


def bracket(num: Fraction, series_terms, tail) -> tuple[Fraction, Fraction]:
    """[num / (S + tail), num / S] for a positive series S with the given tail bound."""
    S = sum(series_terms)
    return num / (S + tail), num / S


def exact_rounding(num: Fraction, lo: Fraction, hi: Fraction) -> tuple[int, int]:
    """ceil and floor of a number known to lie in [lo, hi] (the test needs them decided)."""
    assert math.ceil(lo) == math.ceil(hi) and math.floor(lo) == math.floor(hi), "bracket straddles an integer"
    return math.ceil(lo), math.floor(lo)


def rational_q22(rho: float, m: int, norm_A: float, lam: float, T: float) -> tuple[int, int, int]:
    """(q of (22), of (21)+(19), minimal) with the floats' exact rational values and -ln(1 - u) by its
    series u + u²/2 + ... with a proven tail."""
    N = (m - 1) ** 2 + 1
    u = Fraction(m - 1) * (1 - Fraction(rho)) / Fraction(m) ** ((m - 1) ** 2)
    num = (Fraction(lam) + Fraction(norm_A)) * Fraction(T)
    k = 8
    lo, hi = bracket(num, [u ** j / j for j in range(1, k + 1)], u ** (k + 1) / ((k + 1) * (1 - u)))
    c, f = exact_rounding(num, lo, hi)
    return N * c + 1, N * (c + 1), N * (f + 1)


def rational_q27(sigma: float, norm_A: float, lam: float, T: float) -> tuple[int, int]:
    """(q of (27), minimal) with ln(1/σ) = 2 atanh(z), z = (1 - σ)/(1 + σ), by its series with a tail."""
    s = Fraction(sigma)
    z = (1 - s) / (1 + s)
    num = (Fraction(lam) + Fraction(norm_A)) * Fraction(T)
    k = 60
    terms = [2 * z ** (2 * j + 1) / (2 * j + 1) for j in range(k)]
    lo, hi = bracket(num, terms, 2 * z ** (2 * k + 1) / ((2 * k + 1) * (1 - z * z)))
    c, f = exact_rounding(num, lo, hi)
    return c + 1, f + 1


@pytest.mark.parametrize("rho, m, norm_A, lam, T", [
    (0.1234567891234567, 6, 2.718281828459045, 0.7, 0.37),     # q ≈ 2e20: the float path was off by ~470
    (1e-3, 6, 1.2345678901234567, 0.9, 0.3),
    (0.1234567891234567, 8, 2.718281828459045, 0.7, 0.37),     # q ≈ 1e44
    (1e-300, 7, 1.0000000000000002, 0.1, 0.3),
    (0.3, 5, 3.3, 1.1, 0.77), (0.8507, 3, 1.7, 0.5, 1.0), (0.0, 16, 2.0, 1.0, 1.0)])
def test_q22_q21_minimal_are_exact_integers(rho, m, norm_A, lam, T):
    sq = jd.sufficient_q(rho, m, norm_A, lam, T)
    assert (sq.q_thm22, sq.q_thm21, sq.q_minimal) == rational_q22(rho, m, norm_A, lam, T)
    assert jd.exact_int(jd.exact_text(sq.q_thm22)) == sq.q_thm22


@pytest.mark.parametrize("sigma, norm_A, lam, T", [(0.929855, 2.0135501568, 2.0, 1.0), (0.999999999, 1.3, 0.7, 0.9),
                                                   (0.1, 0.5, 0.2, 0.3), (0.5, 1.0, 1.0, 0.6931471805599453)])
def test_q27_is_exact(sigma, norm_A, lam, T):
    assert (jd.q_symmetric(sigma, norm_A, lam, T), jd.q_symmetric_minimal(sigma, norm_A, lam, T)) == \
        rational_q27(sigma, norm_A, lam, T)


def test_alpha_power_uses_the_safe_end_and_is_one_for_p_zero():
    exact = {"rho_exact": np.array(True), "alpha_lemma5": np.array(0.9), "alpha_lemma5_upper": np.array(0.9)}
    bracketed = {"rho_exact": np.array(False), "alpha_lemma5": np.array(0.8), "alpha_lemma5_upper": np.array(0.95)}
    unbounded = {"rho_exact": np.array(False), "alpha_lemma5": np.array(0.8)}
    assert alpha_power(exact, 2) == pytest.approx(0.81)
    assert alpha_power(bracketed, 2) == pytest.approx(0.95 ** 2)          # the upper end of ρ: the larger α
    assert alpha_power(unbounded, 3) == 1.0                               # |P(S⊗I)| <= 1 for every step
    assert alpha_power(unbounded, 0) == alpha_power(bracketed, 0) == 1.0


def modal_scenario(m: int = 7, n: int = 4, seed: int = 11) -> dict:
    """An oscillatory system in an orthonormal modal basis (ρ = 0 up to round-off) whose agents each
    observe one or two of the rotation blocks; a directed ring; q below N (p = 0)."""
    rng = np.random.default_rng(seed)
    Qm, _ = np.linalg.qr(rng.standard_normal((n, n)))
    J = np.zeros((n, n))
    for b in range(n // 2):
        w = 0.6 + 0.5 * b
        J[2 * b:2 * b + 2, 2 * b:2 * b + 2] = [[-0.05, w], [-w, -0.05]]
    A = Qm @ J @ Qm.T
    C = []
    for i in range(m):
        b = i % (n // 2)
        C.append((rng.standard_normal((1, 2)) @ Qm.T[2 * b:2 * b + 2]).tolist())
    ring = [[(i - 1) % m + 1] for i in range(m)]
    return {"family": "hybrid-observer", "name": "seven",
            "system": {"A": A.tolist(), "C": C},
            "design": {"T": 0.5, "q": 3, "lambda": 0.3, "lambda_bar": 0.6},
            "graphs": {"neighbors": [ring]},
            "initial": {"x0": [1.0] * n, "xhat0": [[0.0] * n] * m},
            "monte_carlo": {"trials": 2, "quick_trials": 2}, "sampling": {"step": 0.05},
            "runs": [{"name": "ideal", "ideal": True, "intervals": 3, "monte_carlo": False}]}


def test_seven_agents_rho_exact_alpha_p_one_and_sigma_reason():
    """Before: ρ bracketed in [~1e-16, 1] (the search stopped), α^p NaN although p = 0, σ missing
    without a word. Now: ρ exact (the method said), α^p = 1, σ not enumerated with its reason."""
    chk = api.check(copy.deepcopy(modal_scenario()))
    design = chk.tables["design"].set_index("quantity")
    assert design.loc["rho_exact", "value"] == 1.0 and design.loc["rho_upper", "value"] < 1e-11
    assert design.loc["rho_method", "exact"].startswith("exhaustive search")
    assert design.loc["rho_distinct", "value"] == 2
    runs = chk.tables["runs"].set_index("run")
    assert runs.loc["ideal", "p"] == 0 and runs.loc["ideal", "alpha_p"] == 1.0
    assert "sigma" not in design.index
    reason = design.loc["sigma_not_enumerated", "exact"]
    assert "connected graph" in reason and design.loc["sigma_not_enumerated", "value"] > 1e4


def test_seven_agents_idealized_attenuation_is_checked():
    """Before: α^p NaN made the comparison (20) of the idealised run not checkable (and the monitor
    skipped it); with p = 0 it is checked against α^0 = 1."""
    run = api.run(copy.deepcopy(modal_scenario()), seed=1)
    claims = run.claims.set_index("id")
    row = claims.loc[[i for i in claims.index if i.endswith("sec2.idealized_attenuation")][0]]
    assert row["verdict"] == "pass", row["detail"]
    assert "p = floor(q/N) = 0" in row["detail"]
