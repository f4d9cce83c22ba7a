"""The stages of a hybrid-observer run and what they give the claims.

Per scenario: the design (deterministic: `design.design_quantities`, what the hypotheses are
decided on), the model-mismatch demonstration of Section 4 (the paper's reproduction only), the
sampled checks of Lemmas 5 and 6, and one streamed simulation per run (`simulation.simulate_run`,
its bounds evaluated on the fly). Each is a `@stage`: its cache key is derived from the
scenario's key, its other arguments and the source of every module it imports.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from dse.contract.stages import StageResult, stage

from . import simulation
from .design import design_quantities, lemma_samples, model_mismatch
from .monitor import MAXIMA, WORST, Worst
from .scenario import HybridFile, RunSection

#: design arrays that may hold inf or NaN: padding of unequal spectra, c_i of a defective local observer,
#: the vertex-loss placeholders, and r of (22) beyond the float range for many agents (exact as text beside)
DESIGN_NONFINITE = ("local_eigs", "vertex_loss_rho", "c_i", "r_lemma5", "r_printed", "r_lemma5_paper",
                    "r_printed_paper", "one_minus_alpha_log10", "one_minus_alpha_log10_paper")


def run_nonfinite(**_arguments) -> tuple[str, ...]:
    """Every array of a run's result but `simulation.MUST_BE_FINITE` may hold NaN or inf (a quantity
    that does not apply: an interval an agent sat out, a check the run skips)."""
    names = ["A_mixed", "B_mixed", "G_mixed", "A_2", "B_2", "Phi_max", "tau0", "g_t_ns", "g_mean", "g_max",
             "g_central_mean", "ev_sd", "ev_central_sd", "net_sd", "ev_central_mean", "bound51_max", "ratio51_s",
             "net_mean"]
    names += [f"t0_{k}" for k in ("e_pre", "ebar", "x_nominal", "central", "floor", "carried", "carried_sym",
                                  "bound41", "bound51", "x", "xhat", "xc", "err", "cerr", "xnorm", "kf", "z")]
    names += [f"w_{w}_{f}" for w in WORST for f in Worst.FIELDS]
    names += [f"max_{k}" for k in MAXIMA] + [f"trial_{k}" for k in ("fit_rate", "e0", "eb0")]
    return tuple(n for n in names if n not in simulation.MUST_BE_FINITE)


@stage(name="design", allow_nonfinite=DESIGN_NONFINITE)
def design_stage(sc: HybridFile, seed: int, extras: bool) -> dict[str, np.ndarray]:
    """Every design quantity (`extras`: also Section 5's, for the paper's claims)."""
    return design_quantities(sc, seed, extras)


@stage(name="mismatch")
def mismatch_stage(sc: HybridFile, seed: int) -> dict[str, np.ndarray]:
    """Section 4's model-mismatch demonstration (the paper's reproduction)."""
    return model_mismatch(sc, seed)


@stage(name="samples")
def samples_stage(sc: HybridFile, seed: int) -> dict[str, np.ndarray]:
    """The sampled checks of Lemmas 5 and 6."""
    return lemma_samples(sc, seed)


@stage(name="run", unkeyed=("budget_bytes",), allow_nonfinite=run_nonfinite)
def run_stage(sc: HybridFile, design: StageResult, run: str, trials: int, seed: int,
              budget_bytes: float) -> dict[str, np.ndarray]:
    """One run of the scenario (by name): its interval plan, then its trials (`trials` is 1 for a
    run without Monte Carlo) within `budget_bytes` per chunk."""
    return simulation.simulate_run(sc, design, sc.spec(run), trials, seed, budget_bytes)


@dataclass
class Part:
    """One scenario of a run: its label in tables and details ('paper', 'generic', or 'scenario' in
    a user's run), its design quantities (`design`, with the model-mismatch arrays in the paper's
    reproduction) and, once simulated, its lemma samples and its runs' results by name. `example`:
    it is the paper's Section 6 example (in the paper's reproduction)."""

    label: str
    scenario: HybridFile
    design: dict
    stage: StageResult
    example: bool = False
    seed: int = 0
    trials: int = 0
    samples: dict = field(default_factory=dict)
    runs: dict = field(default_factory=dict)

    @property
    def obs(self):
        return self.scenario.observer

    def spec(self, name: str) -> RunSection:
        return self.scenario.spec(name)


@dataclass
class Parts:
    """The scenarios of a run by label: the design stage's output (`dse check`), and with their
    simulations the results the claims are checked on."""

    parts: dict[str, Part]

    def __getitem__(self, label: str) -> Part:
        return self.parts[label]

    def named(self, name: str) -> Part:
        """The part of the scenario of this name (what the claims' per-scenario entries select)."""
        return next(p for p in self.parts.values() if p.scenario.name == name)
