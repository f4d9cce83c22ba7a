"""The random-comm-filter scenario family: a continuous-time plant, N sensor nodes with
constant-gain filters, a connected graph whose edges carry Poisson clocks of rate λ.

TOML layout (every key is validated; unknown keys are errors):

    family = "random-comm-filter"
    name = "my-network"
    [system]            A, B (lists of rows); optional P0 (default I), m0 (default 0)
    [[sensors]]         one table per node: H (p_i × n), V (p_i × p_i, ≻ 0), optional L (n × p_i)
    [graph]             pipeline.graphs.GraphSpec (kind = ring/line/complete/grid/edges/...)
    [communication]     alpha (default min(1/2, 1/d_max)), mode = "edge" | "ordered",
                        rates = [λ, …] (simulated), sweep = [λ_min, λ_max, points] (steady states)
    [gains]             rule = "kalman-bucy-split" (default) | "given" (then every sensor has L)
    [simulation]        horizon, output_step, grid_step, trials, event_trials, quick_trials,
                        quick_event_trials, sample_trials
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from estimators.gossip_filter import MODES, GossipSystem, kalman_bucy_split_gains
from pipeline.errors import ScenarioError
from pipeline.graphs import GraphSpec
from pipeline.scenario import (scenario_root, as_float, as_float_tuple, as_int, as_list, as_matrix, as_str, load_toml, reject_unknown,
                               section)

SECTIONS = ("name", "title", "system", "sensors", "graph", "communication", "gains", "simulation")
GAIN_RULES = ("kalman-bucy-split", "given")
MAX_STATE = 8
MAX_JOINT = 40


@dataclass(frozen=True)
class FilterNetworkScenario:
    name: str
    title: str
    graph: GraphSpec
    system: GossipSystem
    gain_rule: str
    rates: tuple[float, ...]
    sweep: tuple[float, float, int]
    horizon: float
    output_step: float
    grid_step: float
    trials: int
    event_trials: int
    quick_trials: int
    quick_event_trials: int
    sample_trials: int

    @property
    def main_rate(self) -> float:
        return self.rates[0]

    @property
    def n_outputs(self) -> int:
        return int(round(self.horizon / self.output_step))

    @property
    def output_times(self) -> np.ndarray:
        return np.arange(self.n_outputs + 1) * self.output_step

    def key(self) -> dict[str, Any]:
        s = self.system
        return {"A": s.A, "B": s.B, "H": list(s.H), "V": list(s.V), "L": list(s.L), "edges": s.edges,
                "alpha": s.alpha, "mode": s.mode, "P0": s.P0, "m0": s.m0, "rates": self.rates, "sweep": self.sweep,
                "horizon": self.horizon, "output_step": self.output_step, "grid_step": self.grid_step}

    @classmethod
    def from_dict(cls, data: Any) -> "FilterNetworkScenario":
        data, name = scenario_root(data, allowed=SECTIONS, required=("system", "sensors", "graph"))
        title = as_str(data.get("title", name), "title")

        sysd = section(data["system"], "system")
        reject_unknown(sysd, ("A", "B", "P0", "m0"), "system")
        for key in ("A", "B"):
            if key not in sysd:
                raise ScenarioError(f"system.{key}", "missing")
        A = as_matrix(sysd["A"], "system.A")
        n = A.shape[0]
        if A.shape[1] != n:
            raise ScenarioError("system.A", f"must be square, got {A.shape[0]}x{A.shape[1]}")
        if n > MAX_STATE:
            raise ScenarioError("system.A", f"state dimension {n} > {MAX_STATE} is not supported")
        B = as_matrix(sysd["B"], "system.B")
        if B.shape[0] != n:
            raise ScenarioError("system.B", f"must have {n} rows (the state dimension), got {B.shape[0]}")
        P0 = as_matrix(sysd.get("P0", np.eye(n).tolist()), "system.P0", shape=(n, n), psd=True)
        m0 = np.array(as_float_tuple(sysd.get("m0", [0.0] * n), "system.m0"))
        if m0.shape != (n,):
            raise ScenarioError("system.m0", f"must have {n} entries, got {m0.size}")

        graph = GraphSpec.from_dict(data["graph"], "graph")
        G = graph.build()
        N = graph.n
        if N < 2:
            raise ScenarioError("graph", "needs at least 2 nodes")
        if N * n > MAX_JOINT:
            raise ScenarioError("graph", f"N·n = {N * n} > {MAX_JOINT}: the exact joint covariance would be too large")
        edges = tuple(sorted((min(u, v), max(u, v)) for u, v in G.edges()))

        gains = section(data.get("gains", {}), "gains")
        reject_unknown(gains, ("rule",), "gains")
        rule = as_str(gains.get("rule", "kalman-bucy-split"), "gains.rule", GAIN_RULES)

        sensors = as_list(data["sensors"], "sensors")
        if len(sensors) != N:
            raise ScenarioError("sensors", f"must list one sensor per graph node ({N}), got {len(sensors)}")
        H, V, L = [], [], []
        for i, s in enumerate(sensors):
            f = f"sensors[{i}]"
            s = section(s, f)
            reject_unknown(s, ("H", "V", "L"), f)
            for key in ("H", "V"):
                if key not in s:
                    raise ScenarioError(f"{f}.{key}", "missing")
            Hi = as_matrix(s["H"], f"{f}.H")
            if Hi.shape[1] != n:
                raise ScenarioError(f"{f}.H", f"must have {n} columns, got {Hi.shape[1]}")
            p = Hi.shape[0]
            Vi = as_matrix(s["V"], f"{f}.V", shape=(p, p), symmetric=True)
            if np.linalg.eigvalsh(Vi).min() <= 1e-12 * max(1.0, np.abs(Vi).max()):
                raise ScenarioError(f"{f}.V", "must be positive definite")
            if rule == "given":
                if "L" not in s:
                    raise ScenarioError(f"{f}.L", "missing (needed for gains.rule = 'given')")
                L.append(as_matrix(s["L"], f"{f}.L", shape=(n, p)))
            elif "L" in s:
                raise ScenarioError(f"{f}.L", "only allowed with gains.rule = 'given'")
            H.append(Hi)
            V.append(Vi)
        if rule == "kalman-bucy-split":
            try:
                L, _ = kalman_bucy_split_gains(A, B, H, V)
            except (np.linalg.LinAlgError, ValueError) as exc:
                raise ScenarioError("gains.rule", f"the Kalman–Bucy Riccati equation has no stabilising solution "
                                                  f"((A, H) not detectable or (A, B) not stabilisable?): {exc}") from None
            if not np.all(np.isfinite(np.concatenate([l.ravel() for l in L]))):
                raise ScenarioError("gains.rule", "the Kalman–Bucy Riccati solution is not finite")

        comm = section(data.get("communication", {}), "communication")
        reject_unknown(comm, ("alpha", "mode", "rates", "sweep"), "communication")
        dmax = max(d for _, d in G.degree())
        alpha = as_float(comm.get("alpha", min(0.5, 1.0 / dmax)), "communication.alpha", low=0.0, low_open=True,
                         high=1.0 / dmax)
        mode = as_str(comm.get("mode", "edge"), "communication.mode", MODES)
        rates = as_float_tuple(comm.get("rates", [2.0]), "communication.rates", low=0.0, low_open=True, high=1e4)
        if len(rates) > 4:
            raise ScenarioError("communication.rates", "at most 4 simulated rates")
        sw = as_list(comm.get("sweep", [0.1, 1e4, 40]), "communication.sweep")
        if len(sw) != 3:
            raise ScenarioError("communication.sweep", "must be [lambda_min, lambda_max, points]")
        lo = as_float(sw[0], "communication.sweep[0]", low=0.0, low_open=True)
        hi = as_float(sw[1], "communication.sweep[1]", low=lo, low_open=True, high=1e9)
        pts = as_int(sw[2], "communication.sweep[2]", low=5, high=400)

        sim = section(data.get("simulation", {}), "simulation")
        reject_unknown(sim, ("horizon", "output_step", "grid_step", "trials", "event_trials", "quick_trials",
                             "quick_event_trials", "sample_trials"), "simulation")
        horizon = as_float(sim.get("horizon", 10.0), "simulation.horizon", low=0.0, low_open=True, high=1e3)
        output_step = as_float(sim.get("output_step", 0.1), "simulation.output_step", low=0.0, low_open=True,
                               high=horizon)
        n_out = horizon / output_step
        if abs(n_out - round(n_out)) > 1e-9 * n_out or round(n_out) > 2000:
            raise ScenarioError("simulation.output_step", "must divide the horizon into at most 2000 steps")
        grid_step = as_float(sim.get("grid_step", 0.01), "simulation.grid_step", low=0.0, low_open=True,
                             high=output_step)
        per = output_step / grid_step
        if abs(per - round(per)) > 1e-9 * per:
            raise ScenarioError("simulation.grid_step", "must divide simulation.output_step")
        if round(horizon / grid_step) > 200_000:
            raise ScenarioError("simulation.grid_step", "more than 200,000 steps")
        if max(rates) * grid_step * dmax > 0.5:
            raise ScenarioError("simulation.grid_step", f"λ·h·d_max = {max(rates) * grid_step * dmax:.3g} must be "
                                                        "≤ 0.5 for the gridded simulator (make the step smaller)")
        trials = as_int(sim.get("trials", 10_000), "simulation.trials", low=100, high=10_000_000)
        event_trials = as_int(sim.get("event_trials", 2_000), "simulation.event_trials", low=50, high=1_000_000)
        quick_trials = as_int(sim.get("quick_trials", min(trials, 2_000)), "simulation.quick_trials", low=100)
        quick_event = as_int(sim.get("quick_event_trials", min(event_trials, 300)), "simulation.quick_event_trials",
                             low=50)
        sample_trials = as_int(sim.get("sample_trials", 3), "simulation.sample_trials", low=1, high=20)

        system = GossipSystem(A, B, tuple(H), tuple(V), tuple(np.asarray(l, float) for l in L), edges, alpha, mode,
                              P0, m0)
        return cls(name, title, graph, system, rule, rates, (lo, hi, pts), horizon, output_step, grid_step, trials,
                   event_trials, quick_trials, quick_event, sample_trials)


SCENARIO_DIR = Path(__file__).with_name("scenarios")
PAPER_SCENARIOS = ("s1a", "s1b", "s1c", "s2", "s3")


def load_scenario(name: str) -> FilterNetworkScenario:
    data = load_toml(SCENARIO_DIR / f"{name}.toml")
    data.pop("family", None)
    return FilterNetworkScenario.from_dict(data)


def paper_scenarios() -> list[FilterNetworkScenario]:
    return [load_scenario(n) for n in PAPER_SCENARIOS]


def with_graph(sc: FilterNetworkScenario, graph: GraphSpec, name: str) -> GossipSystem:
    """The same plant and sensors on another graph (α = min(1/2, 1/d_max)), for the topology sweep."""
    G = graph.build()
    dmax = max(d for _, d in G.degree())
    edges = tuple(sorted((min(u, v), max(u, v)) for u, v in G.edges()))
    s = sc.system
    return GossipSystem(s.A, s.B, s.H, s.V, s.L, edges, min(0.5, 1.0 / dmax), s.mode, s.P0, s.m0)

