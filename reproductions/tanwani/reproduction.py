"""The random-communication filtering paper as a `pipeline` reproduction, and the same family
for users' own scenario files (`dse run FILE.toml` with `family = "random-comm-filter"`)."""
from __future__ import annotations

from pathlib import Path
from typing import Any

from pipeline.cache import StageCache
from pipeline.reproduction import RunOptions

from . import claims as claims_mod
from . import compute as compute_mod
from . import outputs
from .scenario import FilterNetworkScenario, paper_scenarios

TITLE = "Tanwani: Suboptimal filtering over sensor networks with random communication (IEEE TAC 2022)"

NOTES = """The paper has no numerical example, no simulation and no table (its Fig. 1 is a schematic): the scenarios
here (S1a-c, S2, S3 and the topology sweep S4) were designed for this reproduction, and their reference numbers
were computed independently. """

FAMILY_NOTES = """Model choices: x(0) ~ N(m0, P0), x̂_i(0) = m0, one Poisson clock per undirected edge with both endpoints
updating from pre-jump values (per ordered pair with `communication.mode = "ordered"`), α = min(1/2, 1/d_max) unless
given, gains = the centralized Kalman–Bucy gain split by columns (L_i = N K_i) unless given. E[e eᵀ] is the second
moment. Derived here, not in the paper: the exact mean joint covariance ODE, the per-path quantities, the second
moments of the P-process over clock paths, the critical rates, the limit S_true, the first-order rate of (9) and
explicit constants for (12). Monte Carlo: an exact event-driven simulator (exact Poisson events, exact Gaussian
transitions between events, exact per-path covariances) and a gridded one (exact flow over h/2, Poisson(λh) rings
per clock per step in alternating clock order, flow over h/2; its own exact mean covariance gives its O(h²) bias).
Statistical verdicts use exact laws (χ² of whitened Gaussian errors given the clocks, Poisson and binomial counts,
Efron's bound for paired symmetric differences) or, for means over random clock paths, Bernstein's inequality with
the exact variance for low means and a Student plus known-variance test for high means. Typos that numbers cannot
show (no claim): (13a) reads '(A − L_iH_i) de_i' (the corrected form is used and checked by
`prop3_2.flow_equality`); the interval in (5); lost minus signs in the problem statement; 'v_i standard' with
covariance V_i; Lemma III.3's garbled text; Ũ† = Ũ."""


class RandomCommReproduction:
    def __init__(self, scenarios: list[FilterNetworkScenario], *, paper: bool):
        self.scenarios = scenarios
        self.is_paper = paper
        self.paper_id = "tanwani" if paper else scenarios[0].name
        self.title = TITLE if paper else f"random-comm-filter scenario '{scenarios[0].name}'"
        self.main = "s2" if paper else scenarios[0].name

    def scenario_ids(self) -> list[str]:
        return [sc.name for sc in self.scenarios]

    def claims(self):
        return claims_mod.catalogue(self.paper_id, self.scenario_ids(), self.main)

    def hypotheses(self):
        return claims_mod.hypotheses(self.paper_id, self.scenario_ids())

    def trials(self, opts: RunOptions) -> int:
        return max(compute_mod.trial_counts(sc, opts)[0] for sc in self.scenarios)

    def compute(self, opts: RunOptions, cache: StageCache):
        return compute_mod.compute(self.scenarios, opts, cache, is_paper=self.is_paper)

    def write_outputs(self, results, out_dir: Path, claims: list[dict], prov: dict) -> None:
        outputs.write_outputs(results, out_dir, claims, prov, main=self.main, paper=self.is_paper)

    def notes(self) -> str:
        return (NOTES + FAMILY_NOTES) if self.is_paper else FAMILY_NOTES


def paper() -> RandomCommReproduction:
    return RandomCommReproduction(paper_scenarios(), paper=True)


def from_dict(data: dict[str, Any]) -> RandomCommReproduction:
    return RandomCommReproduction([FilterNetworkScenario.from_dict(data)], paper=False)
