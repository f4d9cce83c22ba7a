"""The gossip-Kalman scenario family (GIKF on any graph with a random-matching protocol):
our examples E1-E9 and any user scenario of the same kind (`family = "gossip-kalman"`)."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from estimators.gossip_kalman import GossipSystem, GreedyMatchingGossip, MatchingDistribution, NodeInitiatedGossip
from pipeline.errors import ScenarioError
from pipeline.graphs import GraphSpec
from pipeline.scenario import (scenario_root, as_float, as_int, as_int_tuple, as_list, as_matrix, as_str, join, load_toml,
                               reject_unknown, section)

SCENARIO_DIR = Path(__file__).with_name("scenarios")
PAPER_SCENARIOS = ("e1", "e2", "e3", "e5", "e6", "e6b", "e7", "e8", "e9")
PROTOCOLS = ("single-edge", "node-initiated", "matchings", "greedy-matching")
SECTIONS = ("name", "description", "model", "sensors", "graph", "protocol", "comparison_protocol", "simulation", "expect")


@dataclass(frozen=True)
class ProtocolSpec:
    """[protocol] (and [comparison_protocol]) of a scenario file; `kind` is one of

    * "single-edge" (edge_prob): each graph edge is the only swap of the slot with probability
      edge_prob (edge_prob × number of edges ≤ 1), protocol P1;
    * "node-initiated": a uniform node wakes up and swaps with a uniform neighbour, protocol P2;
    * "matchings" (matchings, probs): a user-given distribution over matchings, the rest of the
      probability is "no communication" (protocol P3 is a case);
    * "greedy-matching" (p_link ∈ (0, 1]): random greedy maximal matching, each chosen link then
      works with probability p_link, protocol P4. Ā is exact on small graphs (≤ 40 edges), otherwise a
      Monte Carlo estimate, and the Theorem-8 chains are driven by the protocol itself (S3).
    """

    kind: str
    edge_prob: float = 0.0
    matchings: tuple[tuple[tuple[int, int], ...], ...] = ()
    probs: tuple[float, ...] = ()
    p_link: float = 1.0

    def build(self, graph: GraphSpec):
        n = graph.n
        edges = sorted((min(u, v), max(u, v)) for u, v in graph.build().edges())
        if self.kind == "single-edge":
            return MatchingDistribution.single_edge(n, edges, [self.edge_prob] * len(edges))
        if self.kind == "node-initiated":
            G = graph.build()
            return NodeInitiatedGossip(tuple(tuple(sorted(G.neighbors(i))) for i in range(n)))
        if self.kind == "greedy-matching":
            return GreedyMatchingGossip(n, tuple(edges), self.p_link)
        return MatchingDistribution.from_matchings(n, self.matchings, self.probs)

    @classmethod
    def from_dict(cls, data: Any, field: str, graph: GraphSpec) -> "ProtocolSpec":
        data = section(data, field)
        kind = as_str(data.get("kind"), join(field, "kind"), PROTOCOLS) if "kind" in data else None
        if kind is None:
            raise ScenarioError(join(field, "kind"), f"missing (one of {', '.join(PROTOCOLS)})")
        edges = {(min(u, v), max(u, v)) for u, v in graph.build().edges()}
        if not edges:
            raise ScenarioError(join(field, "kind"), "the graph has no edges: there is nothing to gossip over")
        if kind == "single-edge":
            reject_unknown(data, ("kind", "edge_prob"), field)
            if "edge_prob" not in data:
                raise ScenarioError(join(field, "edge_prob"), "missing (probability of each edge per slot)")
            p = as_float(data["edge_prob"], join(field, "edge_prob"), low=0.0, low_open=True, high=1.0)
            if p * len(edges) > 1 + 1e-12:
                raise ScenarioError(join(field, "edge_prob"), f"edge_prob × number of edges = {p * len(edges):.6g} must be <= 1")
            return cls(kind, edge_prob=p)
        if kind == "node-initiated":
            reject_unknown(data, ("kind",), field)
            G = graph.build()
            lonely = [i for i in range(graph.n) if G.degree(i) == 0]
            if lonely:
                raise ScenarioError(field, f"node-initiated gossip needs every node to have a neighbour (node {lonely[0]} has none)")
            return cls(kind)
        if kind == "greedy-matching":
            reject_unknown(data, ("kind", "p_link"), field)
            if "p_link" not in data:
                raise ScenarioError(join(field, "p_link"), "missing (probability that a chosen link works)")
            p = as_float(data["p_link"], join(field, "p_link"), low=0.0, low_open=True, high=1.0)
            return cls(kind, p_link=p)
        reject_unknown(data, ("kind", "matchings", "probs"), field)
        for key in ("matchings", "probs"):
            if key not in data:
                raise ScenarioError(join(field, key), "missing")
        raw = as_list(data["matchings"], join(field, "matchings"))
        matchings = []
        for k, mt in enumerate(raw):
            f = join(field, f"matchings[{k}]")
            pairs, used = [], set()
            for i, e in enumerate(as_list(mt, f, min_len=0)):
                if not (isinstance(e, list) and len(e) == 2):
                    raise ScenarioError(f"{f}[{i}]", "each pair must be [u, v]")
                u, v = (as_int(x, f"{f}[{i}]", low=0, high=graph.n - 1) for x in e)
                if (min(u, v), max(u, v)) not in edges:
                    raise ScenarioError(f"{f}[{i}]", f"({u}, {v}) is not an edge of the graph")
                if u in used or v in used:
                    raise ScenarioError(f"{f}[{i}]", f"node {u if u in used else v} is matched twice (not a matching)")
                used |= {u, v}
                pairs.append((u, v))
            matchings.append(tuple(pairs))
        probs = tuple(as_float(p, join(field, f"probs[{i}]"), low=0.0) for i, p in enumerate(as_list(data["probs"], join(field, "probs"))))
        if len(probs) != len(matchings):
            raise ScenarioError(join(field, "probs"), f"must have one entry per matching ({len(matchings)}), got {len(probs)}")
        if sum(probs) > 1 + 1e-12:
            raise ScenarioError(join(field, "probs"), f"must sum to <= 1 (the rest is 'no communication'), got {sum(probs):.6g}")
        return cls(kind, matchings=tuple(matchings), probs=probs)


@dataclass(frozen=True)
class GossipKalmanScenario:
    name: str
    description: str
    F: np.ndarray
    Q: np.ndarray
    P0: np.ndarray
    types: tuple[int, ...]
    C_types: tuple[np.ndarray, ...]
    R_types: tuple[np.ndarray, ...]
    graph: GraphSpec
    protocol: ProtocolSpec
    comparison: ProtocolSpec | None
    slots: int
    runs: int
    reference_runs: int
    quick_runs: int
    quick_reference_runs: int
    quick_slots: int
    record_times: tuple[int, ...]
    sample_paths: int
    expect: dict

    @property
    def N(self) -> int:
        return self.graph.n

    @property
    def M(self) -> int:
        return self.F.shape[0]

    def system(self) -> GossipSystem:
        return GossipSystem.build(self.F, self.Q, [self.C_types[k] for k in self.types],
                                  [self.R_types[k] for k in self.types], self.P0)

    def key(self) -> dict[str, Any]:
        d = {f: getattr(self, f) for f in self.__dataclass_fields__ if f not in ("name", "description")}
        for f in ("F", "Q", "P0"):
            d[f] = getattr(self, f).tolist()
        d["C_types"] = [c.tolist() for c in self.C_types]
        d["R_types"] = [r.tolist() for r in self.R_types]
        return d

    @classmethod
    def from_dict(cls, data: Any) -> "GossipKalmanScenario":
        data, name = scenario_root(data, allowed=SECTIONS, required=("model", "sensors", "graph", "protocol"))
        description = as_str(data.get("description", ""), "description")

        model = section(data["model"], "model")
        reject_unknown(model, ("F", "Q", "P0"), "model")
        if "F" not in model:
            raise ScenarioError("model.F", "missing")
        F = as_matrix(model["F"], "model.F")
        M = F.shape[0]
        if F.shape != (M, M):
            raise ScenarioError("model.F", f"must be square, got {F.shape[0]}x{F.shape[1]}")
        if "Q" not in model:
            raise ScenarioError("model.Q", "missing")
        Q = as_matrix(model["Q"], "model.Q", shape=(M, M), psd=True)
        if np.linalg.eigvalsh(Q).min() <= 1e-12 * max(1.0, np.abs(Q).max()):
            raise ScenarioError("model.Q", "must be positive definite (the theorems' proofs use Q ≻ 0)")
        P0 = as_matrix(model.get("P0", np.eye(M).tolist()), "model.P0", shape=(M, M), psd=True)

        sensors = section(data["sensors"], "sensors")
        reject_unknown(sensors, ("types", "pattern", "C", "R"), "sensors")
        if ("types" in sensors) == ("pattern" in sensors):
            raise ScenarioError("sensors.types", "give exactly one of `types` (one sensor type per node) or `pattern` "
                                "(sensor types repeated over the nodes in order)")
        for key in ("C", "R"):
            if key not in sensors:
                raise ScenarioError(f"sensors.{key}", "missing")
        C_raw = as_list(sensors["C"], "sensors.C")
        R_raw = as_list(sensors["R"], "sensors.R")
        if len(R_raw) != len(C_raw):
            raise ScenarioError("sensors.R", f"must have one entry per sensor type ({len(C_raw)}), got {len(R_raw)}")
        C_types, R_types = [], []
        for k, (c, r) in enumerate(zip(C_raw, R_raw)):
            if isinstance(c, list) and len(c) == 0:
                C_types.append(np.zeros((0, M)))
                if not (isinstance(r, list) and len(r) == 0):
                    raise ScenarioError(f"sensors.R[{k}]", "must be [] for a sensor type without observations (C = [])")
                R_types.append(np.zeros((0, 0)))
                continue
            Ck = as_matrix(c, f"sensors.C[{k}]")
            if Ck.shape[1] != M:
                raise ScenarioError(f"sensors.C[{k}]", f"must have {M} columns (state dimension), got {Ck.shape[1]}")
            Rk = as_matrix(r, f"sensors.R[{k}]", shape=(Ck.shape[0], Ck.shape[0]), psd=True)
            if np.linalg.eigvalsh(Rk).min() <= 1e-12 * max(1.0, np.abs(Rk).max()):
                raise ScenarioError(f"sensors.R[{k}]", "must be positive definite")
            C_types.append(Ck)
            R_types.append(Rk)

        graph = GraphSpec.from_dict(data["graph"], "graph", require_connected=False)
        if "pattern" in sensors:  # e.g. [0, 1] on 200 nodes: types 0, 1, 0, 1, ... (network-size sweeps)
            pattern = as_int_tuple(sensors["pattern"], "sensors.pattern", low=0, high=len(C_types) - 1)
            types = tuple(pattern[i % len(pattern)] for i in range(graph.n))
        else:
            types = as_int_tuple(sensors["types"], "sensors.types", low=0, high=len(C_types) - 1)
        if len(types) != graph.n:
            raise ScenarioError("sensors.types", f"must have one entry per node ({graph.n}), got {len(types)}")
        protocol = ProtocolSpec.from_dict(data["protocol"], "protocol", graph)
        comparison = (ProtocolSpec.from_dict(data["comparison_protocol"], "comparison_protocol", graph)
                      if "comparison_protocol" in data else None)

        sim = section(data.get("simulation", {}), "simulation")
        reject_unknown(sim, ("slots", "runs", "reference_runs", "quick_runs", "quick_reference_runs", "quick_slots",
                             "record_times", "sample_paths"), "simulation")
        slots = as_int(sim.get("slots", 300), "simulation.slots", low=2, high=20_000)
        runs = as_int(sim.get("runs", 4000), "simulation.runs", low=100, high=1_000_000)
        reference_runs = as_int(sim.get("reference_runs", 20_000), "simulation.reference_runs", low=100, high=2_000_000)
        quick_runs = as_int(sim.get("quick_runs", min(runs, 1000)), "simulation.quick_runs", low=100, high=runs)
        quick_reference_runs = as_int(sim.get("quick_reference_runs", min(reference_runs, 4000)),
                                      "simulation.quick_reference_runs", low=100, high=reference_runs)
        quick_slots = as_int(sim.get("quick_slots", min(slots, 150)), "simulation.quick_slots", low=2, high=slots)
        default_times = [t for t in (1, 2, 3, 5, 10, 20, 50, 100, 200, 300, 600, 1000) if t < slots] + [slots]
        record_times = as_int_tuple(sim.get("record_times", default_times), "simulation.record_times", low=0, high=slots)
        if list(record_times) != sorted(set(record_times)):
            raise ScenarioError("simulation.record_times", "must be strictly increasing")
        sample_paths = as_int(sim.get("sample_paths", 3), "simulation.sample_paths", low=1, high=20)

        expect = section(data.get("expect", {}), "expect")
        reject_unknown(expect, ("c1", "d1", "diverges"), "expect")
        for key, v in expect.items():
            if not isinstance(v, bool):
                raise ScenarioError(f"expect.{key}", f"must be true or false, got {type(v).__name__}")
        return cls(name, description, F, Q, P0, types, tuple(C_types), tuple(R_types), graph, protocol, comparison,
                   slots, runs, reference_runs, quick_runs, quick_reference_runs, quick_slots, record_times,
                   sample_paths, dict(expect))


def load_scenario(name: str) -> GossipKalmanScenario:
    data = load_toml(SCENARIO_DIR / f"{name}.toml")
    data.pop("family", None)
    return GossipKalmanScenario.from_dict(data)


def paper_scenarios() -> list[GossipKalmanScenario]:
    return [load_scenario(n) for n in PAPER_SCENARIOS]
