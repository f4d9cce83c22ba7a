"""The gossip-Kalman scenario file, declared once: GIKF on any graph with a random-matching protocol
(or a given matching sequence); our examples E1-E9 and any user scenario (`family = "gossip-kalman"`).

Every key is declared here (type, default, bounds, unit, meaning); docs/scenarios.md is generated
from these declarations. Rules that tie keys of different tables together (matrix sizes against the
state dimension, sensor types against the nodes, matchings against the graph's edges) are the
file's validator, each error naming its key. The validated model is the scenario the stages read:
the matrices, the graph, the sensors and the theorems' hypotheses are its cached properties.
Nodes are 0..N-1.
"""
from __future__ import annotations

from functools import cached_property
from pathlib import Path
from typing import Any, Literal

import numpy as np
from pydantic import model_validator

from dse.errors import ScenarioError
from dse.estimators.gikf_maps import GossipSystem
from dse.estimators.gossip_protocols import (GreedyMatchingGossip, MatchingDistribution, MatchingSequence,
                                             NodeInitiatedGossip, SingleEdgeGossip)
from dse.scenario.declare import (Matrix, Real, ScenarioFile, Section, computed_default, covariance, key, matrix,
                                  name_key, parse)
from dse.scenario.fields import load_toml
from dse.scenario.graphs import GraphSection, GraphSpec, graph_from_section

SCENARIO_DIR = Path(__file__).with_name("scenarios")
PAPER_SCENARIOS = ("e1", "e2", "e3", "e5", "e6", "e6b", "e7", "e8", "e9")
PROTOCOLS = ("single-edge", "node-initiated", "matchings", "greedy-matching", "sequence")
#: sensors of one network: Ā is a dense N x N matrix whose spectrum, powers and walk search the design needs
MAX_NODES = 1000
#: state dimension: every sensor carries an M x M covariance per run
MAX_STATE = 16
#: slots of one run: per-slot statistics are kept at a bounded number of slots, so memory does not grow with it
MAX_SLOTS = 20_000
MAX_RUNS = 1_000_000
MAX_REFERENCE_RUNS = 2_000_000
#: the record times a scenario gets unless it lists its own (those below the horizon, then the horizon)
RECORD_TIMES = (1, 2, 3, 5, 10, 20, 50, 100, 200, 300, 600, 1000)

Pairs = list[list[int]]


class ModelSection(Section):
    """The signal x(t+1) = F x(t) + w(t), w ~ N(0, Q), x(0) ~ N(x0, P0) (eqs (2)-(3))."""

    F: Matrix = key(doc="system matrix F (M x M)", constraint=f"square; M <= {MAX_STATE}")
    Q: Matrix = key(doc="process noise covariance Q (M x M)", unit="state²",
                    constraint="positive definite (S.1: the proofs use Q ≻ 0)")

    @computed_default
    def _identity(data):
        """identity"""
        return np.eye(len(data.get("F") or [])).tolist()

    P0: Matrix = key(_identity, doc="covariance of x(0), the covariance every sensor starts from", unit="state²",
                     constraint="positive semidefinite (a singular P0 is allowed; eigenvalues within the tolerance "
                                "below 0 are set to 0)")

    @computed_default
    def _zeros(data):
        """zeros"""
        return [0.0] * len(data.get("F") or [])

    x0: list[Real] = key(_zeros, doc="prior mean of x(0): every sensor's estimate starts there (the errors do not "
                         "depend on it; the sample runs' states and estimates do)", unit="state", constraint="M entries")


class SensorsSection(Section):
    """Sensor types y_n = C_n x + v_n, v_n ~ N(0, R_n), and which type each node is."""

    C: list[Matrix] = key(doc="observation matrix C_k (m_k x M) of each sensor type k; [] for a node that observes "
                          "nothing (an actuator)", min_length=1, constraint="M columns; at most M rows")
    R: list[Matrix] = key(doc="measurement noise covariance R_k (m_k x m_k) of each sensor type; [] with C = []",
                          unit="measurement²", constraint="one per type; positive definite")
    types: list[int] | None = key(None, doc="the sensor type of each node 0..N-1",
                                  constraint="exactly one of types or pattern; N entries, each a type index")
    pattern: list[int] | None = key(None, doc="sensor types repeated over the nodes in order (e.g. [0, 1] on 200 nodes: "
                                    "0, 1, 0, 1, ...; network-size sweeps)", min_length=1)

    @model_validator(mode="after")
    def _one_of(self):
        if (self.types is None) == (self.pattern is None):
            raise ScenarioError("types", "give exactly one of `types` (one sensor type per node) or `pattern` (sensor "
                                "types repeated over the nodes in order)")
        if len(self.R) != len(self.C):
            raise ScenarioError("R", f"must have one entry per sensor type ({len(self.C)}), got {len(self.R)}")
        return self


class ProtocolSection(Section):
    """How sensors are matched at each slot t ≥ 1 (A(0) = I). Random protocols draw an
    independent matching per slot (the paper's setting); `sequence` replays given matchings."""

    kind: Literal[PROTOCOLS] = key(  # type: ignore[valid-type]
        doc="single-edge: each edge is the only swap of the slot with probability edge_prob (P1); node-initiated: a "
        "uniform node swaps with a uniform neighbour (P2); matchings: a given law over matchings (P3); greedy-matching: "
        "random greedy maximal matching whose chosen links work with probability p_link (P4); sequence: the given "
        "matching of each slot, the same in every run (a replayed protocol or trace)")
    edge_prob: Real | None = key(None, doc="probability that a given edge is the slot's swap (single-edge)", gt=0, le=1,
                                 unit="1/slot", constraint="edge_prob × number of edges <= 1")
    matchings: list[Pairs] | None = key(None, doc="the matchings of the law, each a list of node pairs [u, v] "
                                        "(matchings)", constraint="pairs are graph edges; no node twice in a matching")
    probs: list[Real] | None = key(None, doc="probability of each matching; the rest is 'no communication' "
                                   "(matchings)", constraint="one per matching, each >= 0, sum <= 1")
    p_link: Real | None = key(None, doc="probability that a chosen link works (greedy-matching)", gt=0, le=1)
    sequence: list[Pairs] | None = key(None, doc="the matching of slot 1, 2, ... as lists of node pairs [u, v] ([] = no "
                                       "swap), repeated cyclically beyond its length (sequence)", min_length=1,
                                       constraint=f"at most {MAX_SLOTS} entries; pairs are graph edges; no node twice "
                                                  "in a slot")

    @model_validator(mode="after")
    def _kind_keys(self):
        needs = {"single-edge": {"edge_prob"}, "node-initiated": set(), "matchings": {"matchings", "probs"},
                 "greedy-matching": {"p_link"}, "sequence": {"sequence"}}[self.kind]
        for name in ("edge_prob", "matchings", "probs", "p_link", "sequence"):
            given = getattr(self, name) is not None
            if name in needs and not given:
                raise ScenarioError(name, f"missing (needed for kind '{self.kind}')")
            if given and name not in needs:
                raise ScenarioError(name, f"not a key of kind '{self.kind}'")
        if self.sequence is not None and len(self.sequence) > MAX_SLOTS:
            raise ScenarioError("sequence", f"at most {MAX_SLOTS} slots, got {len(self.sequence)}")
        if self.probs is not None:
            if len(self.probs) != len(self.matchings):
                raise ScenarioError("probs", f"must have one entry per matching ({len(self.matchings)}), got "
                                    f"{len(self.probs)}")
            for i, p in enumerate(self.probs):
                if p < 0:
                    raise ScenarioError(f"probs[{i}]", f"must be >= 0, got {p:g}")
            if sum(self.probs) > 1 + 1e-12:
                raise ScenarioError("probs", f"must sum to <= 1 (the rest is 'no communication'), got {sum(self.probs):.6g}")
        return self

    @property
    def random(self) -> bool:
        """An independent matching per slot (the paper's setting), not a replayed sequence."""
        return self.kind != "sequence"

    @cached_property
    def pairs(self) -> tuple[tuple[tuple[int, int], ...], ...]:
        """The matchings of the law, or the sequence's, as tuples of node pairs (checked against the graph by the file)."""
        raw = self.sequence if self.kind == "sequence" else (self.matchings or ())
        return tuple(tuple((int(u), int(v)) for u, v in mt) for mt in raw)

    def build(self, graph: GraphSpec):
        """The estimator's protocol on `graph` (`dse.estimators.gossip_protocols`)."""
        n, edges = graph.n, _edges(graph)
        if self.kind == "single-edge":
            return SingleEdgeGossip(n, tuple(edges), float(self.edge_prob))
        if self.kind == "node-initiated":
            neighbours: list[list[int]] = [[] for _ in range(n)]
            for u, v in edges:
                neighbours[u].append(v)
                neighbours[v].append(u)
            return NodeInitiatedGossip(tuple(tuple(sorted(nb)) for nb in neighbours))
        if self.kind == "greedy-matching":
            return GreedyMatchingGossip(n, tuple(edges), float(self.p_link))
        if self.kind == "sequence":
            return MatchingSequence.from_matchings(n, self.pairs)
        return MatchingDistribution.from_matchings(n, self.pairs, tuple(float(p) for p in self.probs))


class SimulationSection(Section):
    """Monte Carlo sizes and horizon. Runs are simulated in units of 1,000 (the numbers do not
    depend on the memory budget); per-slot statistics are kept at a bounded set of slots."""

    slots: int = key(300, doc="horizon T (slots simulated)", ge=2, le=MAX_SLOTS, unit="slot")
    runs: int = key(4000, doc="independent GIKF runs", ge=100, le=MAX_RUNS)
    reference_runs: int = key(20_000, doc="independent runs of the Theorem-8 process P̃(t) (the reference law μ_t)",
                              ge=100, le=MAX_REFERENCE_RUNS)

    @computed_default
    def _quick_runs(data):
        """min(runs, 1000)"""
        return min(data["runs"], 1000)

    quick_runs: int = key(_quick_runs, doc="GIKF runs of a quick run", ge=100, le=MAX_RUNS, constraint="<= runs")

    @computed_default
    def _quick_reference_runs(data):
        """min(reference_runs, 4000)"""
        return min(data["reference_runs"], 4000)

    quick_reference_runs: int = key(_quick_reference_runs, doc="Theorem-8 runs of a quick run", ge=100,
                                    le=MAX_REFERENCE_RUNS, constraint="<= reference_runs")

    @computed_default
    def _quick_slots(data):
        """min(slots, 150)"""
        return min(data["slots"], 150)

    quick_slots: int = key(_quick_slots, doc="horizon of a quick run", ge=2, le=MAX_SLOTS, unit="slot",
                           constraint="<= slots")

    @computed_default
    def _record_times(data):
        """1, 2, 3, 5, 10, 20, 50, 100, 200, 300, 600, 1000 below slots, and slots"""
        return [t for t in RECORD_TIMES if t < data["slots"]] + [data["slots"]]

    record_times: list[int] = key(_record_times, doc="slots at which every run's covariance features are kept (the law "
                                  "tests)", unit="slot", constraint="strictly increasing, each in 0..slots; at most 64")
    sample_paths: int = key(3, doc="runs kept whole (traces, errors, matchings, states) for figures and recordings",
                            ge=1, le=20)

    @model_validator(mode="after")
    def _sizes(self):
        for name, cap in (("quick_runs", self.runs), ("quick_reference_runs", self.reference_runs),
                          ("quick_slots", self.slots)):
            if getattr(self, name) > cap:
                raise ScenarioError(name, f"must be <= {cap} ({name.removeprefix('quick_')}), got {getattr(self, name)}")
        rt = self.record_times
        if not rt or len(rt) > 64:
            raise ScenarioError("record_times", f"must have 1 to 64 entries, got {len(rt)}")
        if list(rt) != sorted(set(rt)):
            raise ScenarioError("record_times", "must be strictly increasing")
        for i, t in enumerate(rt):
            if not 0 <= t <= self.slots:
                raise ScenarioError(f"record_times[{i}]", f"must be in 0..{self.slots}, got {t}")
        return self


class ExpectSection(Section):
    """What the scenario's author expects; a wrong expectation makes the assumption checks not
    checkable (the expectation, not the paper, is wrong). A hypothesis declared false here (a negative
    control) is reported as "does not hold (expected)"."""

    c1: bool | None = key(None, doc="C.1 (Ā irreducible and aperiodic) is expected to hold")
    d1: bool | None = key(None, doc="D.1 (a walk of Ā with an invertible Gramian) is expected to hold")
    diverges: bool | None = key(None, doc="some sensor's covariance is expected to diverge: a class of Ā blind to a "
                                "mode |λ| ≥ 1 (the hypothesis undetectable-class) is expected")


class GossipKalmanFile(ScenarioFile):
    """A gossip-kalman scenario file."""

    #: the name seeds the random streams (it is keyed); the description and the expectations change no number
    unkeyed = {"description": True, "expect": True}

    name: str = name_key()
    description: str = key("", doc="one line on what the scenario shows (reports, recordings)", max_length=500)
    model: ModelSection = key(doc="the signal model")
    sensors: SensorsSection = key(doc="the sensors")
    graph: GraphSection = key(doc="the communication graph (a disconnected one is accepted: C.1 then fails and is "
                              "reported)")
    protocol: ProtocolSection = key(doc="the gossip protocol")
    comparison_protocol: ProtocolSection | None = key(None, doc="a second protocol with the same Ā (Remark 9: the laws "
                                                      "depend on the protocol only through Ā)")
    simulation: SimulationSection = key(SimulationSection, doc="Monte Carlo sizes and horizon")
    expect: ExpectSection = key(ExpectSection, doc="the author's expectations")

    @model_validator(mode="after")
    def _across_tables(self):
        """The rules between tables, in the order a reader checks them: the model's matrices against M, the
        sensors against M, the graph's size, the sensor types against the nodes, the protocols against the graph."""
        F = matrix(self.model.F, "model.F")
        M = F.shape[0]
        if F.shape != (M, M):
            raise ScenarioError("model.F", f"must be square, got {F.shape[0]}x{F.shape[1]}")
        if M > MAX_STATE:
            raise ScenarioError("model.F", f"state dimension {M}; this family handles at most {MAX_STATE}")
        covariance(self.model.Q, "model.Q", n=M, definite=True)
        covariance(self.model.P0, "model.P0", n=M)
        if len(self.model.x0) != M:
            raise ScenarioError("model.x0", f"must have {M} entries (state dimension), got {len(self.model.x0)}")
        self._sensor_types(M)
        graph = self.network
        if graph.n > MAX_NODES:
            raise ScenarioError("graph.rows" if graph.kind == "grid" else "graph.n",
                                f"{graph.n} nodes; this family handles at most {MAX_NODES} (Ā is a dense N x N matrix "
                                "whose spectrum, powers and walks the design computes)")
        self._node_types(graph.n)
        _check_protocol(self.protocol, "protocol", graph)
        if self.comparison_protocol is not None:
            _check_protocol(self.comparison_protocol, "comparison_protocol", graph)
            if not (self.protocol.random and self.comparison_protocol.random):
                raise ScenarioError("comparison_protocol.kind", "Remark 9 compares two random protocols; a replayed "
                                    "sequence has no law to compare")
        return self

    def _sensor_types(self, M: int) -> None:
        for k, (c, r) in enumerate(zip(self.sensors.C, self.sensors.R)):
            if len(c) == 0:
                if len(r) != 0:
                    raise ScenarioError(f"sensors.R[{k}]", "must be [] for a sensor type without observations (C = [])")
                continue
            Ck = matrix(c, f"sensors.C[{k}]")
            if Ck.shape[1] != M:
                raise ScenarioError(f"sensors.C[{k}]", f"must have {M} columns (state dimension), got {Ck.shape[1]}")
            if Ck.shape[0] > M:
                raise ScenarioError(f"sensors.C[{k}]", f"at most {M} rows (state dimension), got {Ck.shape[0]}")
            if len(r) == 0:
                raise ScenarioError(f"sensors.R[{k}]", f"must be {Ck.shape[0]}x{Ck.shape[0]} (C[{k}] has "
                                    f"{Ck.shape[0]} rows)")
            covariance(r, f"sensors.R[{k}]", n=Ck.shape[0], definite=True)

    def _node_types(self, n: int) -> None:
        s, n_types = self.sensors, len(self.sensors.C)
        if s.pattern is not None:
            for i, k in enumerate(s.pattern):
                if not 0 <= k < n_types:
                    raise ScenarioError(f"sensors.pattern[{i}]", f"must be a type index in 0..{n_types - 1}, got {k}")
            return
        for i, k in enumerate(s.types):
            if k < 0:
                raise ScenarioError(f"sensors.types[{i}]", f"must be >= 0, got {k}")
            if k >= n_types:
                raise ScenarioError(f"sensors.types[{i}]", f"must be <= {n_types - 1} (a type index), got {k}")
        if len(s.types) != n:
            raise ScenarioError("sensors.types", f"must have one entry per node ({n}), got {len(s.types)}")

    # -- what the stages read ------------------------------------------------------------------------------

    @cached_property
    def network(self) -> GraphSpec:
        """The communication graph (checked: at least 2 nodes; a disconnected graph is accepted)."""
        return graph_from_section(self.graph, "graph", connected=False, min_nodes=2)

    @property
    def N(self) -> int:
        return self.network.n

    @property
    def M(self) -> int:
        return len(self.model.F)

    @cached_property
    def F(self) -> np.ndarray:
        return matrix(self.model.F, "model.F")

    @cached_property
    def Q(self) -> np.ndarray:
        return covariance(self.model.Q, "model.Q", n=self.M, definite=True)

    @cached_property
    def P0(self) -> np.ndarray:
        """P0 within the shared tolerance, projected onto the PSD cone (negative eigenvalues set to 0), so that
        every map sees a true covariance (a −1e-12 eigenvalue of P0 would otherwise show as P̂(1) − Q = −1e-12,
        a violation of Lemma 16 made by the input)."""
        P = covariance(self.model.P0, "model.P0", n=self.M)
        lam, V = np.linalg.eigh(P)
        if lam.min() >= 0:
            return P
        Pp = (V * np.maximum(lam, 0.0)) @ V.T
        return 0.5 * (Pp + Pp.T)

    @cached_property
    def x0(self) -> np.ndarray:
        return np.array(self.model.x0, float)

    @cached_property
    def C_types(self) -> tuple[np.ndarray, ...]:
        """C_k of each sensor type ((0, M) for an actuator)."""
        return tuple(np.zeros((0, self.M)) if len(c) == 0 else matrix(c, f"sensors.C[{k}]")
                     for k, c in enumerate(self.sensors.C))

    @cached_property
    def R_types(self) -> tuple[np.ndarray, ...]:
        return tuple(np.zeros((0, 0)) if len(r) == 0 else covariance(r, f"sensors.R[{k}]", n=len(r), definite=True)
                     for k, r in enumerate(self.sensors.R))

    @cached_property
    def types(self) -> tuple[int, ...]:
        """The sensor type of every node (`types`, or `pattern` repeated over the nodes)."""
        s = self.sensors
        return tuple(s.pattern[i % len(s.pattern)] for i in range(self.N)) if s.pattern is not None else tuple(s.types)

    @cached_property
    def system(self) -> GossipSystem:
        return GossipSystem.build(self.F, self.Q, [self.C_types[k] for k in self.types],
                                  [self.R_types[k] for k in self.types], self.P0)

    @cached_property
    def assumptions(self):
        """The theorems' hypotheses decided from the support of Ā (`assumptions.Assumptions`)."""
        from .assumptions import decide

        return decide(self)


def _edges(graph: GraphSpec) -> list[tuple[int, int]]:
    """The graph's undirected edges (u < v), sorted (from `edge_array`: networkx is imported only for the random kinds)."""
    return [(int(u), int(v)) for u, v in graph.edge_array()]


def _check_protocol(s: ProtocolSection, field: str, graph: GraphSpec) -> None:
    edges = set(_edges(graph))
    if not edges:
        raise ScenarioError(f"{field}.kind", "the graph has no edges: there is nothing to gossip over")
    if s.kind == "single-edge" and s.edge_prob * len(edges) > 1 + 1e-12:
        raise ScenarioError(f"{field}.edge_prob", f"edge_prob × number of edges = {s.edge_prob * len(edges):.6g} "
                            "must be <= 1")
    if s.kind == "node-initiated":
        lonely = sorted(set(range(graph.n)) - {v for e in edges for v in e})
        if lonely:
            raise ScenarioError(field, f"node-initiated gossip needs every node to have a neighbour (node {lonely[0]} "
                                "has none)")
    if s.kind in ("sequence", "matchings"):
        raw = s.sequence if s.kind == "sequence" else s.matchings
        for k, mt in enumerate(raw):
            _check_matching(mt, f"{field}.{s.kind}[{k}]", graph.n, edges)


def _check_matching(pairs: Pairs, field: str, n: int, edges: set[tuple[int, int]]) -> None:
    used: set[int] = set()
    for i, e in enumerate(pairs):
        if len(e) != 2:
            raise ScenarioError(f"{field}[{i}]", "each pair must be [u, v]")
        u, v = e
        for x in (u, v):
            if not 0 <= x < n:
                raise ScenarioError(f"{field}[{i}]", f"node indices must be in 0..{n - 1}, got {e}")
        if (min(u, v), max(u, v)) not in edges:
            raise ScenarioError(f"{field}[{i}]", f"({u}, {v}) is not an edge of the graph")
        if u in used or v in used:
            raise ScenarioError(f"{field}[{i}]", f"node {u if u in used else v} is matched twice (not a matching)")
        used |= {u, v}


def from_dict(data: Any) -> GossipKalmanFile:
    """A validated scenario from a parsed file (without `family`); one ScenarioError naming the field."""
    return parse(GossipKalmanFile, data)


def load_scenario(name: str) -> GossipKalmanFile:
    """One of our example scenarios E1-E9 by name."""
    data = load_toml(SCENARIO_DIR / f"{name}.toml")
    data.pop("family", None)
    return from_dict(data)
