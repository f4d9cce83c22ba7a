"""The hybrid-observer reproduction end to end: the paper in quick mode (verdicts, figures,
recordings read back), a user's scenario with design quantities checked against independent
computations, and scenario validation (one ScenarioError naming the field)."""
from __future__ import annotations

import copy
import json
import math
import re
import subprocess
import sys
import tomllib
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import scipy.linalg as sla

from dse.outputs import record
from dse.errors import ScenarioError
import dse.registry
from dse.contract.options import RunOptions
from dse.contract.context import StageContext
from dse.engine.cache import StageCache
from dse.engine.driver import evaluate_claims, reverify, run

RERUN = Path(sys.executable).parent / "rerun"


def from_dict(data: dict):
    """A user's run of a scenario file's body (without its `family` key)."""
    return dse.registry.from_dict({"family": "hybrid-observer", **data})


def paper():
    return dse.registry.paper("wang-liu-morse")
PKG = Path(__file__).resolve().parent.parent / "dse" / "families" / "wang_liu_morse"

USER = """
name = "two_agents"
[system]
A = [[-0.2, 0.3], [0.0, 0.1]]
C = [[[1.0, -1.0]], [[0.0, 1.0]]]
[design]
T = 0.5
q = "theory"
lambda = 0.8
lambda_bar = 1.2
[graphs]
neighbors = [[[2], [1]]]
[initial]
x0 = [1.0, -2.0]
xhat0 = [[0.0, 0.0], [0.5, 0.5]]
[monte_carlo]
trials = 8
quick_trials = 8
[[runs]]
name = "sync"
intervals = 40
monte_carlo = true
[[runs]]
name = "ideal"
ideal = true
intervals = 6
monte_carlo = true
[[runs]]
name = "async"
timing = "async"
epsilon = [0.001, 0.002]
beta = 0.004
Delta = 0.04
intervals = 40
monte_carlo = true
reference_run = "sync"
"""


@pytest.fixture(scope="module")
def paper_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("wlm")
    summary = run(paper(), out, RunOptions(quick=True, workers=2))
    return out / "wang-liu-morse", summary


def _verdicts(d: Path) -> dict[str, dict]:
    return {c["id"]: c for c in json.loads((d / "report.json").read_text())["claims"]}


def test_paper_verdicts(paper_run):
    d, summary = paper_run
    v = _verdicts(d)
    P = "wang-liu-morse."
    for claim in ("eq41.error_recursion", "thm1.event_bound", "thm1.rate", "thm2.async_equals_sync", "lemma4.eq44",
                  "lemma2.source_sets", "lemma3.source_sets", "eq17.rho", "eq26.sigma", "sec6.rate", "sec6.eq44_q50",
                  "sec3.symmetric_case", "lemma8.eq62", "sec4.eq63", "sec6.fig5_leave_join", "sec6.reduced_models",
                  "sec2.local_design", "reference.centralized"):
        assert v[P + claim]["verdict"] == "pass", (claim, v[P + claim]["detail"][:500])
    for claim in ("thm1.continuous_bound", "eq61.offset_recursion", "sec6.local_rates", "eq18.alpha"):
        row = v[P + claim]
        assert row["verdict"] == "erratum" and row["printed"] is not None and row["corrected"] is not None, claim
    assert v[P + "thm1.continuous_bound"]["printed"] > 1 >= v[P + "thm1.continuous_bound"]["corrected"]
    assert v[P + "eq41.error_recursion"]["measured"] < 1e-13
    # the example's q = 50 misses (22) and (27): hypotheses of the theorems that the example does not meet
    # (reported first, with the required q), not claims; the theorem claims are checked on the generic system
    assert P + "sec6.q_eq22" not in v and P + "sec6.q_eq27" not in v
    hyps = {h["id"]: h for h in json.loads((d / "report.json").read_text())["hypotheses"]}
    q22, q27 = hyps[P + "hyp.paper.q_eq22"], hyps[P + "hyp.paper.q_eq27"]
    assert q22["holds"] is False and q22["value"] == 50 and q22["threshold"] == 3_419_701        # λ = 1.9
    assert "3,507,081" in q22["detail"] and "471" in q22["detail"]                                # λ = 2; α as printed
    assert q27["holds"] is False and q27["threshold"] == 55 and "q >= 57" in q27["detail"]
    assert hyps[P + "hyp.generic.q_eq22"]["holds"] is True and hyps[P + "hyp.paper.symmetric.q_eq27"]["holds"] is True
    assert not any(h["error"] for h in hyps.values())
    assert "[generic/sync]" in v[P + "thm1.event_bound"]["detail"]
    assert "hyp.paper.q_eq22 does not hold" in v[P + "thm1.event_bound"]["detail"]          # the paper's cells left out
    for claim in ("sec6.rate", "sec6.fig3_noise", "sec4.key_point_mismatch", "remarks.not_tight", "sec6.eq44_q50"):
        assert v[P + claim]["scope"] == "paper-example", claim
    assert v[P + "thm1.rate"]["scope"] == "family"
    assert summary["fail"] == 0 and summary["erratum"] == 4 and summary.get("error", 0) == 0


def test_paper_outputs(paper_run):
    d, _ = paper_run
    for fig in ("fig1_timing", "fig2_graphs", "fig3", "fig4", "fig5", "theorem1_bounds_paper", "theorem1_bounds_generic",
                "decay_rates", "A_norms"):
        assert (d / "figures" / f"{fig}.png").stat().st_size > 10_000, fig
    design = pd.read_parquet(d / "tables" / "design.parquet")

    def value(scenario, quantity, lam=None, column="value"):
        sel = (design["scenario"] == scenario) & (design["quantity"] == quantity)
        sel &= design["lam"].isna() if lam is None else design["lam"] == lam
        (v,) = design.loc[sel, column]
        return v

    assert value("paper", "q_thm22", 2.0, "exact") == "3507081"                          # the printed λ = 2
    assert value("paper", "q_thm21_printed_alpha", 2.0, "exact") == str(10 * (math.ceil(46.127) + 1))
    assert value("paper", "q27", 2.0) == 57 and value("paper", "sigma") == pytest.approx(0.929855, abs=1e-6)
    assert value("generic", "rho_exact") == 1.0
    rrd = d / "paper_sync.rrd"
    for f in (rrd, d / "paper_fig5_leave_join.rrd", d / "generic_async.rrd"):
        proc = subprocess.run([str(RERUN), "rrd", "verify", str(f)], capture_output=True, text=True, timeout=120)
        assert proc.returncode == 0, proc.stderr
    sc = record.read_scalars(rrd, "t")
    t, err = sc["/nodes/error"]                                  # one column per agent
    assert t.dtype.kind == "m" and np.array_equal(t.astype(np.int64)[:3], [0, 10_000_000, 20_000_000])
    assert err.shape == (len(t), 4)
    np.testing.assert_array_equal(sc["/nodes/1/log10_error"][1][:, 0], np.log10(np.maximum(err[:, 0], 1e-300)))
    ti, it = sc["/nodes/2/iterates"]
    assert len(ti) == 25 * 51                                    # S intervals × (q + 1) iterates
    _, reset = sc["/nodes/3/reset"]                              # before and after each reset
    assert (reset[1:, 0] != reset[1:, 1]).all()                  # the discontinuity at each reset
    kinds = record.blueprint_view_kinds(rrd)
    assert "TimeSeries" in kinds and "Graph" in kinds and "TextDocument" in kinds


def test_user_scenario_against_independent_design(tmp_path):
    data = tomllib.loads(USER)
    repro = from_dict(copy.deepcopy(data))
    summary = run(repro, tmp_path, RunOptions(seed=5, workers=2))
    d = tmp_path / "two_agents"
    v = _verdicts(d)
    for claim in ("eq41.error_recursion", "thm1.event_bound", "thm2.async_equals_sync", "lemma4.eq44", "thm1.rate",
                  "eq17.rho", "lemma3.source_sets"):
        assert v["two_agents." + claim]["verdict"] == "pass", claim
    assert not any(k.startswith("two_agents.sec6") for k in v)            # the paper's example claims are absent
    hyps = {h["id"]: h for h in json.loads((d / "report.json").read_text())["hypotheses"]}
    assert hyps["two_agents.hyp.q_eq22"]["holds"] is True and hyps["two_agents.hyp.async.eq10"]["holds"] is True
    assert "two_agents.hyp.q_eq22" in v["two_agents.thm1.event_bound"]["hypotheses"]
    report = (d / "report.md").read_text()
    for text in ("q = 50", "Fig. ", "graph 2a", "Section 6"):
        assert text not in report, text
    assert not re.search(r"\bspecs?\b", report, re.IGNORECASE)       # no citation of notes outside the repository
    design = pd.read_parquet(d / "tables" / "design.parquet").set_index("quantity")
    design = {q: design.loc[q, "value"] for q in design.index}
    q_runs = pd.read_parquet(d / "tables" / "runs.parquet").set_index("run")["q"]
    # independent: for m = 2, ρ = ||P_1 P_2|| = cos of the angle between the unobservable lines
    A = np.array(data["system"]["A"])
    C1, C2 = (np.array(c, float) for c in data["system"]["C"])
    k1 = sla.null_space(np.vstack([C1, C1 @ A]))                          # ker O_i (unobservable lines)
    k2 = sla.null_space(np.vstack([C2, C2 @ A]))
    rho = abs(float(k1[:, 0] @ k2[:, 0]))
    assert design["rho"] == pytest.approx(rho, rel=1e-12)
    alpha = (1 + rho) / 2
    r = (0.8 + np.linalg.norm(A, 2)) * 0.5 / math.log(1 / alpha)
    assert design["q_thm22"] == 2 * math.ceil(r) + 1 == q_runs["sync"]
    assert design["alpha_lemma5"] == pytest.approx(alpha, rel=1e-12) == design["alpha_printed"]
    assert summary["fail"] == 0
    rows, diffs = reverify(from_dict(copy.deepcopy(data)), tmp_path, d)   # claims again, from the cache only
    assert diffs == [] and len(rows) == len(v)
    for f in ("sync.rrd", "ideal.rrd", "async.rrd"):
        proc = subprocess.run([str(RERUN), "rrd", "verify", str(d / f)], capture_output=True, text=True, timeout=120)
        assert proc.returncode == 0, proc.stderr


BAD = [
    (lambda s: s["system"].update(C=[[[1.0, -1.0]], [[2.0, -2.0]]]), "system.C: (C, A) is not jointly observable"),
    (lambda s: s["system"].update(C=[[[1.0, -1.0]], [[0.0, 0.0]]]), "system.C[1]: is zero"),
    (lambda s: s["graphs"].update(neighbors=[[[2], [2]]]), "graphs.neighbors[0][1]: lists agent 2 as its own"),
    (lambda s: s["graphs"].update(neighbors=[[[2, 2], [1]]]), "graphs.neighbors[0][0]: repeats a neighbour"),
    (lambda s: s["graphs"].update(neighbors=[[[2], [3]]]), "graphs.neighbors[0][1]: agent labels are 1..2, got 3"),
    (lambda s: s["system"].update(C=[[[1.0, -1.0]]]), "system.C: needs at least 2 agents"),
    (lambda s: s["design"].update(q="many"), "design.q: must be an integer or one of"),
    (lambda s: s.update(name="bad name"), "name: must match"),
    (lambda s: s["design"].update(**{"lambda": 1.5}), "design.lambda: must be < lambda_bar"),
    (lambda s: s["design"].update(poles=[[-0.5], [-2.0]]), "design.lambda_bar: agent 1's local observer"),
    (lambda s: s["design"].update(qq=3), "design.qq: unknown key"),
    (lambda s: s["system"].update(A=[[1.0, 2.0, 3.0], [0.0, 1.0, 0.0]]), "system.A: must be square"),
    (lambda s: s["runs"][2].update(Delta=0.3), "runs[2].Delta: q Δ + ε"),
    (lambda s: s["runs"][0].update(timing="offset", offsets=[0.0, -0.6]), "runs[0].offsets: the spread"),
    (lambda s: s["runs"][0].update(leave={"agent": 2, "at": 1.2, "rejoin": 2.0}), "runs[0].leave.at: must be an event time"),
    (lambda s: s["runs"][2].update(reference_run="nope"), "runs[2].reference_run: must name an earlier run"),
    (lambda s: s["initial"].update(x0=[1.0]), "initial.x0: must have n = 2 entries"),
]


@pytest.mark.parametrize("mutate, message", BAD, ids=[m for _, m in BAD])
def test_bad_scenarios(mutate, message):
    data = tomllib.loads(USER)
    mutate(data)
    with pytest.raises(ScenarioError) as exc:
        from_dict(data)
    assert message in str(exc.value), str(exc.value)


def test_paper_theory_q_is_refused_with_its_value():
    data = tomllib.loads((PKG / "paper.toml").read_text())
    data.pop("family")
    data["design"]["q"] = "theory"
    with pytest.raises(ScenarioError, match=r"design.q: the theory q is \d+"):
        from_dict(data)


def test_cli_rejects_a_bad_file_with_one_line(tmp_path):
    """`dse run FILE.toml`: exit 2, one line naming the field."""
    data = USER.replace("C = [[[1.0, -1.0]], [[0.0, 1.0]]]", "C = [[[1.0, -1.0]], [[2.0, -2.0]]]")
    (tmp_path / "s.toml").write_text('family = "hybrid-observer"\n' + data)
    code = "import sys; from dse.cli import main; sys.exit(main(sys.argv[1:]))"
    root = Path(__file__).resolve().parent.parent
    proc = subprocess.run([sys.executable, "-c", code, "run", "s.toml", "--out", "out"], cwd=tmp_path, capture_output=True,
                          text=True, timeout=300, env={"PYTHONPATH": str(root), "PATH": "/usr/bin:/bin", "DSE_PROGRESS": "0"})
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 2 and len(lines) == 1 and "system.C: (C, A) is not jointly observable" in lines[0]
    assert not (tmp_path / "out").exists()


def test_q_below_the_bound_makes_the_theorems_not_checkable(tmp_path):
    """A q one below (22): Theorem 1's conclusions are not checked (not-checkable, naming the hypothesis);
    the identities still are. A run with its own q below the bound is left out of the claims by name."""
    data = tomllib.loads(USER)
    probe = from_dict(copy.deepcopy(data))
    q22 = probe.scenario.q_design
    data["design"]["q"] = q22 - 1
    for r in data["runs"]:
        r["intervals"] = min(r["intervals"], 10)
    data["runs"].append({"name": "enough", "q": q22, "intervals": 10})
    repro = from_dict(data)
    ev = evaluate_claims(repro, repro.compute(RunOptions(seed=1, quick=True), StageContext(StageCache(tmp_path))))
    v = {r["id"]: r for r in ev.claims}
    hyps = {h["id"]: h for h in ev.hypotheses}
    assert hyps["two_agents.hyp.q_eq22"]["holds"] is False
    assert hyps["two_agents.hyp.enough.q_eq22"]["holds"] is True
    assert not any(r["verdict"] in ("fail", "error") for r in ev.claims)
    # the design q governs every run but one: the claim gates the cells itself and checks 'enough'
    ev_bound = v["two_agents.thm1.event_bound"]
    assert ev_bound["verdict"] == "pass" and "[scenario/enough]" in ev_bound["detail"]
    assert "two_agents.hyp.q_eq22 does not hold" in ev_bound["detail"]
    assert v["two_agents.eq41.error_recursion"]["verdict"] == "pass"
