"""Every claim on random valid scenarios of every family, biased towards the edge cases.

A theorem's claims may be `pass`, `erratum` or `not-checkable` on a valid scenario; a
`fail` would be a counterexample to a paper (which the generated scenarios are not meant
to contain: they satisfy the family's validation, and a claim whose hypotheses fail must
say so) and an `error` is a defect of ours. Each family's generator lists its edge cases
(`EDGES`); every edge case runs once, plus a few unbiased draws.
"""
from __future__ import annotations

from pathlib import Path

import pytest

from dse import registry
from dse.contract.context import StageContext
from dse.contract.options import RunOptions
from dse.engine.cache import StageCache
from dse.engine.driver import evaluate_claims
from generated_runs import SPLIT_FAMILIES, cases, check_generated, unsplit_families


@pytest.mark.parametrize("family,seed,edge", cases(unsplit_families()))
def test_generated_scenario_has_no_fail_and_no_error(family, seed, edge, tmp_path):
    check_generated(family, seed, edge, tmp_path)


def test_the_split_files_exist_and_name_registered_families():
    """The families run by the other generated-scenario files are registered, and those files exist."""
    for name, families in SPLIT_FAMILIES.items():
        assert (Path(__file__).parent / name).is_file(), name
        assert set(families) <= set(registry.families()), families


def test_every_family_has_a_generator():
    for family in registry.families().values():
        assert family.edges and len(set(family.edges)) == len(family.edges)
        a, b = family.generate(3, None), family.generate(3, None)
        assert a == b, "a generator must be a function of its seed"


@pytest.mark.parametrize("seed, m, blocks", [(0, 7, 2), (1, 8, 2)])
def test_hybrid_observer_many_agents_rho_near_zero(seed, m, blocks, tmp_path):
    """6-8 agents of an oscillatory system (ρ = 0 up to round-off): ρ is exact, every run's
    α^p finite, no claim fails or errs (7 and 8 agents here: with 6, σ of (26) over 26,704 graphs
    takes seconds; 6 agents' ρ is in tests/test_wang_liu_morse_rho.py)."""
    from dse.families.wang_liu_morse.generator import generate_many_agents

    data = generate_many_agents(seed, m, blocks)
    assert len(data["system"]["C"]) == m
    repro = registry.from_dict(data)
    computed = repro.compute(RunOptions(seed=seed, quick=True, workers=1), StageContext(StageCache(tmp_path / "cache")))
    design = computed.design["scenario"].design
    assert bool(design["rho_exact"]) and float(design["rho_upper"]) < 1e-11
    ev = evaluate_claims(repro, computed)
    bad = [f"{r['id']}: {r['verdict']}: {str(r.get('detail'))[:400]}" for r in ev.claims if r["verdict"] in ("fail", "error")]
    bad += [f"hypothesis {h['id']}: {h['error'][:400]}" for h in ev.hypotheses if h["error"]]
    assert not bad, f"many agents seed={seed}:\n" + "\n".join(bad)
    ideal = [r for r in ev.claims if r["id"].endswith("sec2.idealized_attenuation")]
    assert ideal and ideal[0]["verdict"] == "pass"


#: keys a generator keeps at one value on purpose: trial counts and horizons chosen for the time of `make test`,
#: values only the paper's reproduction reads, and values a rule excludes (a comparison protocol must be random);
#: compare's plug-in tables name code outside the package (tests/test_plugin_*.py add them to generated scenarios)
KEPT_FIXED = {
    "compare": {"simulation.trials", "simulation.quick_trials", "estimators.<name>.factory",
                "estimators.<name>.time_limit"},
    "gossip-kalman": {"simulation.slots", "simulation.runs", "simulation.reference_runs", "simulation.quick_runs",
                      "simulation.quick_reference_runs", "simulation.quick_slots", "simulation.record_times",
                      "simulation.sample_paths", "comparison_protocol.sequence"},
    "hybrid-observer": {"monte_carlo.trials", "monte_carlo.quick_trials", "paper_values.lambda",
                        "paper_values.lambda_bar"},
    "random-comm-filter": {"simulation.trials", "simulation.event_trials", "simulation.quick_trials",
                           "simulation.quick_event_trials", "simulation.sample_trials"},
    "template": {"monte_carlo.trials"},
}
#: unbiased draws per family in the key audit, and the seeds of every edge case
AUDIT_DRAWS, AUDIT_EDGE_SEEDS = 20, (0, 1, 2)


def _declared_keys(model) -> list[str]:
    from dse.scenario.declare import reference_rows

    return [f"{path}.{row['key']}" if path else row["key"] for path, rows, _ in reference_rows(model) for row in rows]


def _values(node, parts: list[str]) -> list[str]:
    """The values a dotted key path takes in a scenario dict ('<default>' where it is not given); `a[]` walks a
    list of tables, `<name>` every table of a table of tables."""
    import json

    if not parts:
        return [json.dumps(node, sort_keys=True)]
    head, rest = parts[0], parts[1:]
    if head == "<name>":
        return [v for sub in node.values() for v in _values(sub, rest)] if isinstance(node, dict) else ["<default>"]
    key = head[:-2] if head.endswith("[]") else head
    if not isinstance(node, dict) or key not in node:
        return ["<default>"]
    if head.endswith("[]"):
        return [v for item in node[key] for v in _values(item, rest)] or ["<default>"]
    return _values(node[key], rest)


@pytest.mark.parametrize("family", sorted(registry.families()))
def test_every_generator_varies_every_declared_key(family):
    """Each declared key takes at least two values over the generator's draws (the default counts as one): a key
    left at its default is a part of the model no property test exercises (a non-zero prior mean was such a key,
    and with it a wrong start of the compare simulation). The keys kept fixed on purpose are listed above."""
    fam = registry.family(family)
    scenarios = [fam.generate(seed, None) for seed in range(AUDIT_DRAWS)]
    scenarios += [fam.generate(seed, e) for e in fam.edges for seed in AUDIT_EDGE_SEEDS]
    fixed = [k for k in _declared_keys(fam.scenario_model) if k not in KEPT_FIXED.get(family, set())
             and len({v for d in scenarios for v in _values(d, k.split("."))}) < 2]
    assert not fixed, f"{family}: the generator never varies {fixed}"


def test_random_graph_tables_are_valid_connected_and_of_every_kind():
    """`dse.scenario.graphs.random_graph_table`, which every generator draws graphs with."""
    import math

    import numpy as np

    from dse.scenario.graphs import GRAPH_KINDS, graph, random_graph_table

    rng, kinds = np.random.default_rng(5), set()
    for lo, hi in ((2, 2), (2, 7), (3, 12), (5, 5)):
        for _ in range(150):
            table = random_graph_table(rng, lo, hi)
            spec = graph(table, min_nodes=2)                   # valid and connected, or this raises
            kinds.add(table["kind"])
            # a ring has at least 3 nodes; a grid rounds n_min up to whole rows (at most rows − 1 beyond n_max)
            top = {"ring": max(hi, 3), "grid": hi + math.isqrt(hi) - 1}.get(table["kind"], hi)
            assert lo <= spec.n <= top, table
    assert kinds == set(GRAPH_KINDS)
