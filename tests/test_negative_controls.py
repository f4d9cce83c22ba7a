"""A hypothesis a scenario declares it breaks (a negative control: gossip-kalman's `[expect]`) is shown as
"does not hold (expected)" by `dse check` and in report.md, never as a failure."""
from pathlib import Path

from dse.cli import main

E5 = Path(__file__).resolve().parents[1] / "dse" / "families" / "kar_moura" / "scenarios" / "e5.toml"
WORDS = {True: "yes", False: "no", None: "undecided"}


def test_check_says_a_negative_controls_hypothesis_does_not_hold_as_expected(capsys, tmp_path):
    assert main(["check", str(E5), "--quick", "--out", str(tmp_path / "out")]) == 0
    out = capsys.readouterr().out
    hypotheses = out.split("hypotheses:")[1].split("design quantities:")[0]
    assert "FAILS" not in hypotheses
    assert "does not hold (expected) e5.hyp.d1:" in hypotheses      # e5 declares d1 = false
    assert "holds         e5.hyp.c1:" in hypotheses                  # and c1 = true


def test_the_status_words():
    from dse.outputs.report import hypothesis_status

    assert hypothesis_status({"holds": False, "expected": False}, WORDS) == "does not hold (expected)"
    assert hypothesis_status({"holds": True, "expected": False}, WORDS) == "holds (expected not to)"
    assert hypothesis_status({"holds": False, "expected": True}, WORDS) == "no"
    assert hypothesis_status({"holds": False}, WORDS) == "no"
    assert hypothesis_status({"holds": None, "expected": False}, WORDS) == "undecided"
