"""Claim and hypothesis ids of a user's run: they start with the user's scenario name, never with a paper's
id, and do not repeat the name (`rcf_disc.hyp.alpha`, not `rcf_disc.hyp.rcf_disc.alpha`); the papers' own
ids do not change."""
from pathlib import Path

import pytest

from dse import registry
from dse.scenario.fields import load_toml

FAMILIES = Path(__file__).resolve().parents[1] / "dse" / "families"
FILES = ["tanwani/example.toml", "savas/paper.toml", "kar_moura/scenarios/e1.toml", "tran/paper.toml",
         "wang_liu_morse/generic.toml", "template/example.toml"]


def user_ids(path: str, name: str = "mine") -> list[str]:
    data = load_toml(FAMILIES / path)
    data["name"] = name
    run = registry.from_dict(data)
    return [h.id for h in run.hypotheses()] + [c.id for c in run.claims()] + \
        [h for c in run.claims() for h in c.hypotheses]


@pytest.mark.parametrize("path", FILES)
def test_a_users_ids_carry_its_name_once_and_no_papers_prefix(path):
    ids = user_ids(path)
    assert ids
    papers = set(registry.papers())
    for cid in ids:
        assert cid.startswith("mine.") and cid.count("mine") == 1, cid
        assert not any(cid.startswith(f"{p}.") or f".{p}." in cid for p in papers), cid


def test_the_random_comm_filter_hypothesis_id_of_the_issue():
    ids = user_ids("tanwani/example.toml", "rcf_disc")
    assert "rcf_disc.hyp.alpha" in ids and "rcf_disc.hyp.rcf_disc.alpha" not in ids


def test_the_papers_ids_keep_the_scenario_names():
    hyps = [h.id for h in registry.paper("tanwani").hypotheses()]
    assert "tanwani.hyp.s1a.alpha" in hyps
    kar = [c.id for c in registry.paper("kar-moura").claims()]
    assert "kar-moura.negative-control.divergence.e5" in kar
