"""The paper's reference numbers are claims of scope "paper-example": the paper's reproduction
evaluates them, a user's scenario (even one with the paper's content, as a sweep point has) never
does, and the family's structural checks run on any network."""
from __future__ import annotations

import copy
from pathlib import Path
from types import SimpleNamespace

from dse.scenario.fields import load_toml
from dse.families.savas.claims import catalogue, check_Q
from dse.families.savas.reproduction import from_dict, paper
from dse.families.savas.scenario import NoisyConsensusScenario

ROOT = Path(__file__).resolve().parents[1]


def _paper_data() -> dict:
    return {k: v for k, v in load_toml(ROOT / "dse" / "families" / "savas" / "paper.toml").items() if k != "family"}


def test_reference_tables_are_paper_example_claims():
    scopes = {c.id: c.scope for c in catalogue()}
    for cid in ("savas.fig1.values", "savas.fig2.values", "savas.fig3.values", "savas.model.Q_example",
                "savas.fig2.zeta_nonmonotone", "savas.fig2.ell_increasing", "savas.thm1.ii.hypothesis"):
        assert scopes[cid] == "paper-example", cid
    assert scopes["savas.thm1.ii"] == scopes["savas.mc.trace"] == "family"


def test_only_the_papers_reproduction_is_a_paper_run():
    assert paper().is_paper
    assert not from_dict(_paper_data()).is_paper
    assert "Reconstructions" not in from_dict(_paper_data()).notes()


def test_structural_Q_check_runs_on_any_network():
    bigger = copy.deepcopy(_paper_data())
    bigger["graph"]["n"] = 5
    verdict = check_Q(SimpleNamespace(scenario=NoisyConsensusScenario.from_dict(bigger)))
    assert verdict.status == "pass" and "second largest" in verdict.detail
