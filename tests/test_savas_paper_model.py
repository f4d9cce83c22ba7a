"""The paper's reference numbers are claims of scope "paper-example": the paper's reproduction
evaluates them, a user's scenario (even one with the paper's content, as a sweep point has) never
does, and the family's structural checks run on any network."""
from __future__ import annotations

import copy
from pathlib import Path
from types import SimpleNamespace

import dse.registry
from dse.families.savas.claims import claims
from dse.families.savas.claims.model import check_Q
from dse.scenario.fields import load_toml

ROOT = Path(__file__).resolve().parents[1]


def _paper_data() -> dict:
    return load_toml(ROOT / "dse" / "families" / "savas" / "paper.toml")


def test_reference_tables_are_paper_example_claims():
    scopes = {c.id: c.scope for c in claims.claims}
    for cid in ("savas.fig1.values", "savas.fig2.values", "savas.fig3.values", "savas.model.Q_example",
                "savas.fig2.zeta_nonmonotone", "savas.fig2.ell_increasing", "savas.thm1.ii.hypothesis"):
        assert scopes[cid] == "paper-example", cid
    assert scopes["savas.thm1.ii"] == scopes["savas.mc.trace"] == "family"


def test_only_the_papers_reproduction_is_a_paper_run():
    assert dse.registry.paper("savas").is_paper
    user = dse.registry.from_dict(_paper_data())
    assert not user.is_paper and user.paper_id == "paper"
    assert "Reconstructions" not in user.notes() and "Reconstructions" in dse.registry.paper("savas").notes()
    # the same claims, by id and order (a user's run names them after itself, the paper's run after the paper)
    run_ids = [c.id for c in dse.registry.paper("savas").claims()]
    assert all(i.startswith("savas.") for i in run_ids) and all(c.id.startswith("paper.") for c in user.claims())
    assert [i.partition(".")[2] for i in run_ids] == [c.id.partition(".")[2] for c in user.claims()]
    assert run_ids == [c.id for c in claims.claims]


def test_structural_Q_check_runs_on_any_network():
    bigger = copy.deepcopy(_paper_data())
    bigger["graph"]["n"] = 5
    verdict = check_Q(SimpleNamespace(scenario=dse.registry.from_dict(bigger).scenario))
    assert verdict.status == "pass" and "second largest" in verdict.detail
