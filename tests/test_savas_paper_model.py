"""The paper's reference numbers apply to the paper's model only: a scenario that keeps the name
"paper" but changes the network (a sweep point) gets the structural checks, not a crash."""
from __future__ import annotations

import copy
from pathlib import Path
from types import SimpleNamespace

from pipeline.scenario import load_toml
from reproductions.savas.claims import _paper_model, check_Q
from reproductions.savas.scenario import NoisyConsensusScenario

ROOT = Path(__file__).resolve().parents[1]


def _res(data: dict) -> SimpleNamespace:
    return SimpleNamespace(scenario=NoisyConsensusScenario.from_dict({k: v for k, v in data.items() if k != "family"}))


def test_paper_model_is_recognised_by_content_not_by_name():
    paper = load_toml(ROOT / "reproductions" / "savas" / "paper.toml")
    assert _paper_model(_res(paper))
    bigger = copy.deepcopy(paper)
    bigger["graph"]["n"] = 5
    assert not _paper_model(_res(bigger))
    noisier = copy.deepcopy(paper)
    noisier["model"]["r"] = 4.0
    assert not _paper_model(_res(noisier))
    verdict = check_Q(_res(bigger))
    assert verdict.status == "pass" and "second largest" in verdict.detail
