"""`dse list FAMILY` lists the hypotheses and claims of every registered family, with or without a paper."""
import pytest

from dse import registry
from dse.cli import main


@pytest.mark.parametrize("family_id", list(registry.families()))
def test_list_family_prints_its_hypotheses_and_claims(capsys, family_id):
    assert main(["list", family_id]) == 0
    out = capsys.readouterr().out
    lines = out.splitlines()
    assert lines and family_id in lines[0]
    claims = [line for line in lines[2:] if line.startswith("  ") and not line.startswith("  hypothesis ")]
    assert len(claims) >= 1, out


def test_list_without_arguments_includes_families_without_a_paper(capsys):
    assert main(["list"]) == 0
    out = capsys.readouterr().out
    for family_id, family in registry.families().items():
        if family.paper is None:
            assert f"\n{family_id} (a family without a paper" in out


def test_only_the_program_freezes_its_objects_for_exit(capsys, monkeypatch):
    """`main` called from Python (here, with arguments) leaves the garbage collector as it was; the program
    (`dse`, no arguments given to `main`) exempts what is alive at its end from the collector's exit passes."""
    import gc
    import sys

    before = gc.get_freeze_count()
    assert main(["list"]) == 0
    assert gc.get_freeze_count() == before
    monkeypatch.setattr(sys, "argv", ["dse", "list"])
    try:
        assert main() == 0
        assert gc.get_freeze_count() > before
    finally:
        gc.unfreeze()
    capsys.readouterr()
