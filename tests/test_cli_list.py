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
