"""`dse check` and `dse run` share the design: with one stage cache, both compute the same design stages under the
same keys, so a run after a check reads the check's design back, and a check after a run computes nothing.
Every registered family whose design is a stage (the template's is a plain function, computed anew each time), on a
small generated scenario (`--quick`)."""
from __future__ import annotations

import pytest

from benchmarks.small_scenarios import SMALL_EDGES, small_scenario
from dse import api, registry
from dse.cli import main


def _small(family_id: str) -> dict:
    return small_scenario(family_id)


def test_every_family_has_a_small_scenario():
    assert set(registry.families()) <= set(SMALL_EDGES)


@pytest.mark.parametrize("family_id", sorted(set(registry.families()) - {"template"}))
def test_a_run_after_a_check_reads_the_checks_design(family_id, tmp_path):
    data = _small(family_id)
    checked = api.check(data, quick=True, cache_dir=tmp_path)
    assert checked.stages and not any(s["cached"] for s in checked.stages)
    ran = {s["key"]: s["cached"] for s in api.run(data, quick=True, cache_dir=tmp_path).provenance["stages"]}
    assert all(ran.get(s["key"]) is True for s in checked.stages), (checked.stages, ran)


@pytest.mark.parametrize("family_id", ["noisy-consensus-filter", "gossip-kalman"])
def test_a_check_after_a_run_computes_nothing(family_id, tmp_path):
    data = _small(family_id)
    api.run(data, quick=True, cache_dir=tmp_path)
    checked = api.check(data, quick=True, cache_dir=tmp_path)
    assert checked.stages and all(s["cached"] for s in checked.stages)


def test_the_command_line_check_stores_the_design_under_the_output_root(tmp_path, capsys):
    from benchmarks.common import toml_text

    path = tmp_path / "small.toml"
    path.write_text(toml_text(_small("noisy-consensus-filter")))
    out = tmp_path / "out"
    assert main(["check", str(path), "--out", str(out)]) == 0
    assert "computed and stored in the stage cache" in capsys.readouterr().out
    assert any((out / ".cache").rglob("*.npz"))
    assert main(["check", str(path), "--out", str(out)]) == 0
    assert "read back from the stage cache" in capsys.readouterr().out


def test_a_check_whose_output_root_cannot_be_used_keeps_the_design_in_memory(tmp_path, capsys):
    from benchmarks.common import toml_text

    path = tmp_path / "small.toml"
    path.write_text(toml_text(_small("noisy-consensus-filter")))
    blocker = tmp_path / "a-file"
    blocker.write_text("")
    assert main(["check", str(path), "--out", str(blocker / "out")]) == 0
    captured = capsys.readouterr()
    assert "is not usable" in captured.err and "kept in memory" in captured.err and captured.err.count("\n") == 1
    assert "valid scenario" in captured.out and "stage cache" not in captured.out


@pytest.mark.parametrize("family_id", sorted(registry.families()))
def test_the_design_text_read_back_is_the_one_rendered_from_the_tables(family_id, tmp_path):
    """`dse check` prints the design tables from the text an earlier check stored beside the design: the same text
    as rendered from the tables, under a key that follows the scenario and the options."""
    from dse.api import render_design_tables

    data = _small(family_id)
    first = api.check(data, quick=True, cache_dir=tmp_path)
    stored = first.design_text(tmp_path)
    assert list(tmp_path.glob("check-text-*.txt"))
    again = api.check(data, quick=True, cache_dir=tmp_path)
    assert "tables" not in again.__dict__          # not built: the text is read back
    assert again.design_text(tmp_path) == stored == render_design_tables(again.tables)
    other_seed = api.check(data, quick=True, seed=1, cache_dir=tmp_path)
    assert other_seed._text_key() != first._text_key()


def test_an_edit_of_the_familys_code_changes_the_design_texts_key(tmp_path, monkeypatch):
    """The key of the stored text follows every module of the family's package (a table's code lives there) and
    the modules they import."""
    from dse.contract import stages

    data = _small("noisy-consensus-filter")
    checked = api.check(data, quick=True, cache_dir=tmp_path)
    before = checked._text_key()
    real = stages.module_file

    def edited(name):
        path = real(name)
        if name == "dse.families.savas.tables":
            copy = tmp_path / "tables.py"
            copy.write_bytes(path.read_bytes() + b"\n# an edit\n")
            return copy
        return path

    monkeypatch.setattr(stages, "module_file", edited)
    for f in (stages.direct_imports, stages.code_closure, stages.code_hash):
        f.cache_clear()
    try:
        assert checked._text_key() != before
    finally:
        for f in (stages.direct_imports, stages.code_closure, stages.code_hash):
            f.cache_clear()
