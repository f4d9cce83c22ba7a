"""The noisy-consensus-filter scenario family (scalar random walk, N agents, doubly
stochastic Q): the paper's example and any user scenario of the same kind."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from pipeline.errors import ScenarioError
from pipeline.graphs import GraphSpec, consensus_matrix_from_dict
from pipeline.scenario import (scenario_root, as_float, as_float_tuple, as_int, as_int_tuple, as_str, load_toml,
                               reject_unknown, section)

GAIN_CHOICES = ("optimal-corrected", "optimal-printed", "fixed")
SECTIONS = ("name", "graph", "consensus", "model", "sweep", "carli", "reinjection", "gains", "monte_carlo")


@dataclass(frozen=True)
class NoisyConsensusScenario:
    name: str
    graph: GraphSpec
    Q: np.ndarray
    q: float
    r: float
    sigma0: float
    x0_mean: float
    rounds: tuple[int, ...]
    sigma_c: tuple[float, ...]
    n_steps: int
    eval_step: int
    carli_ell: float
    reinjection_gains: str
    fixed_ell: float
    fixed_zeta: float
    rounds_max: int
    grid: tuple[int, int]
    trials: int
    quick_trials: int
    sample_paths: int

    @property
    def n(self) -> int:
        return self.graph.n

    @property
    def symmetric(self) -> bool:
        return bool(np.allclose(self.Q, self.Q.T, atol=1e-12))

    def key(self) -> dict[str, Any]:
        """Everything that determines the numbers (for the stage cache)."""
        d = {f: getattr(self, f) for f in self.__dataclass_fields__ if f not in ("name", "quick_trials", "trials")}
        d["Q"] = self.Q.tolist()
        return d

    @classmethod
    def from_dict(cls, data: Any) -> "NoisyConsensusScenario":
        data, name = scenario_root(data, allowed=SECTIONS, required=("graph", "model", "sweep"))
        graph = GraphSpec.from_dict(data["graph"], "graph")
        Q = consensus_matrix_from_dict(data.get("consensus", {"weights": "metropolis"}), "consensus", graph.build())

        model = section(data["model"], "model")
        reject_unknown(model, ("q", "r", "sigma0", "x0_mean"), "model")
        for key in ("q", "r"):
            if key not in model:
                raise ScenarioError(f"model.{key}", "missing")
        q = as_float(model["q"], "model.q", low=0.0, low_open=True)
        r = as_float(model["r"], "model.r", low=0.0, low_open=True)
        sigma0 = as_float(model.get("sigma0", 1.0), "model.sigma0", low=0.0)
        x0_mean = as_float(model.get("x0_mean", 0.0), "model.x0_mean")

        sweep = section(data["sweep"], "sweep")
        reject_unknown(sweep, ("rounds", "sigma_c", "n_steps", "eval_step"), "sweep")
        rounds = as_int_tuple(sweep.get("rounds", [0, 1, 2, 3, 4, 5]), "sweep.rounds", low=0, high=1000)
        if len(set(rounds)) != len(rounds) or list(rounds) != sorted(rounds):
            raise ScenarioError("sweep.rounds", "must be strictly increasing")
        sigma_c = as_float_tuple(sweep.get("sigma_c", [0.0, 1.0]), "sweep.sigma_c", low=0.0)
        if list(sigma_c) != sorted(set(sigma_c)):
            raise ScenarioError("sweep.sigma_c", "must be strictly increasing")
        n_steps = as_int(sweep.get("n_steps", 10), "sweep.n_steps", low=1, high=100_000)
        eval_step = as_int(sweep.get("eval_step", min(4, n_steps - 1)), "sweep.eval_step", low=0)
        if eval_step >= n_steps:
            raise ScenarioError("sweep.eval_step", f"must be < n_steps = {n_steps}, got {eval_step}")

        carli = section(data.get("carli", {}), "carli")
        reject_unknown(carli, ("ell",), "carli")
        carli_ell = as_float(carli.get("ell", 0.25), "carli.ell", low=0.0, high=1.0, low_open=True)

        rein = section(data.get("reinjection", {}), "reinjection")
        reject_unknown(rein, ("gains", "ell", "zeta"), "reinjection")
        gains = as_str(rein.get("gains", "optimal-corrected"), "reinjection.gains", GAIN_CHOICES)
        if gains == "fixed":
            for key in ("ell", "zeta"):
                if key not in rein:
                    raise ScenarioError(f"reinjection.{key}", "missing (needed for gains = 'fixed')")
        elif "ell" in rein or "zeta" in rein:
            raise ScenarioError("reinjection.ell" if "ell" in rein else "reinjection.zeta",
                                "only allowed with gains = 'fixed'")
        fixed_ell = as_float(rein.get("ell", 0.25), "reinjection.ell", low=0.0, high=1.0, low_open=True)
        fixed_zeta = as_float(rein.get("zeta", 0.0), "reinjection.zeta", low=0.0, high=1.0)
        if gains == "optimal-printed" and not np.allclose(Q, Q.T, atol=1e-12):
            raise ScenarioError("reinjection.gains", "optimal gains use eq. (16), which needs a symmetric Q")
        if gains == "optimal-corrected" and not np.allclose(Q, Q.T, atol=1e-12):
            raise ScenarioError("reinjection.gains", "optimal gains use eq. (16), which needs a symmetric Q; use 'fixed'")

        opt = section(data.get("gains", {}), "gains")
        reject_unknown(opt, ("rounds_max", "grid"), "gains")
        rounds_max = as_int(opt.get("rounds_max", max(rounds)), "gains.rounds_max", low=max(rounds), high=1000)
        grid = as_int_tuple(opt.get("grid", [400, 401]), "gains.grid", low=11, high=5000)
        if len(grid) != 2:
            raise ScenarioError("gains.grid", "must be [n_ell, n_zeta]")

        mc = section(data.get("monte_carlo", {}), "monte_carlo")
        reject_unknown(mc, ("trials", "quick_trials", "sample_paths"), "monte_carlo")
        trials = as_int(mc.get("trials", 200_000), "monte_carlo.trials", low=100, high=100_000_000)
        quick_trials = as_int(mc.get("quick_trials", min(trials, 20_000)), "monte_carlo.quick_trials", low=100)
        sample_paths = as_int(mc.get("sample_paths", 3), "monte_carlo.sample_paths", low=0, high=50)
        return cls(name, graph, Q, q, r, sigma0, x0_mean, rounds, sigma_c, n_steps, eval_step, carli_ell, gains,
                   fixed_ell, fixed_zeta, rounds_max, (grid[0], grid[1]), trials, quick_trials, sample_paths)


def paper_scenario() -> NoisyConsensusScenario:
    data = load_toml(Path(__file__).with_name("paper.toml"))
    data.pop("family")
    return NoisyConsensusScenario.from_dict(data)
