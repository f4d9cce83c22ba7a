"""The command line's help, version and the sweep's run options; one-line messages for a file given to the
wrong command, a sweep's missing base and an output root that is a file (issue 21)."""
from __future__ import annotations

import json
from pathlib import Path

import pytest

from dse import registry
from dse.cli import build_parser, main
from dse.sweeps import run as sweep_run
from dse.sweeps import spec as sweep_spec
from dse.sweeps.spec import parse_sweep

ROOT = Path(__file__).resolve().parents[1]
SCENARIO = ROOT / "dse" / "families" / "tanwani" / "example.toml"


def help_of(*argv: str, capsys) -> str:
    with pytest.raises(SystemExit) as stop:
        main([*argv, "--help"])
    assert stop.value.code == 0
    return capsys.readouterr().out


def test_version(capsys):
    with pytest.raises(SystemExit) as stop:
        main(["--version"])
    assert stop.value.code == 0 and capsys.readouterr().out.startswith("dse ")


def test_reproduce_help_lists_every_paper_with_its_title(capsys):
    text = help_of("reproduce", capsys=capsys)
    for pid, fam in registry.papers().items():
        assert pid in text and fam.paper.title[:40] in text


@pytest.mark.parametrize("command", ["run", "check"])
def test_file_and_quick_are_explained(command, capsys):
    text = " ".join(help_of(command, capsys=capsys).split())
    assert "a scenario file (TOML)" in text and "for tests" not in text
    if command == "run":
        assert "fewer Monte Carlo trials" in text


def test_sweep_on_a_scenario_file_says_so(tmp_path, capsys):
    assert main(["sweep", str(SCENARIO), "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert "is a scenario file" in err and "dse run" in err and len(err.strip().splitlines()) == 1


def test_run_on_a_sweep_file_says_so(tmp_path, capsys):
    sweep = tmp_path / "s.toml"
    sweep.write_text(f'name = "x"\n[scenario]\nfamily = "random-comm-filter"\n')
    assert main(["run", str(sweep), "--out", str(tmp_path / "o")]) == 2
    assert "this is a sweep file" in capsys.readouterr().err


def test_a_missing_base_names_the_field_and_the_resolved_path(tmp_path, capsys):
    sweep = tmp_path / "sub" / "s.toml"
    sweep.parent.mkdir()
    sweep.write_text('name = "x"\nbase = "../nope.toml"\n[grid]\n"graph.n" = [3]\n')
    assert main(["sweep", str(sweep), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("dse: error: base: '../nope.toml'") and str(tmp_path / "nope.toml") in err


def test_out_that_is_a_file_says_so(tmp_path, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    assert main(["run", str(SCENARIO), "--out", str(blocker)]) == 2
    assert f"--out {blocker} is a file, not a directory" in capsys.readouterr().err
    assert main(["run", str(SCENARIO), "--out", str(blocker / "below")]) == 2
    assert f"{blocker} is a file, not a directory" in capsys.readouterr().err


def test_sweep_options_apply_to_every_point_and_to_the_recorded_source():
    spec = parse_sweep({"name": "x", "base": str(SCENARIO), "seed": 3, "grid": {"communication.rates": [[1.0]]}},
                       base_dir=ROOT)
    changed = sweep_spec.with_options(spec, seed=7, trials=123, quick=True)
    assert (changed.seed, changed.trials, changed.quick) == (7, 123, True)
    assert {k: changed.source[k] for k in ("seed", "trials", "quick")} == {"seed": 7, "trials": 123, "quick": True}
    assert [p.seed for p in changed.points()] != [p.seed for p in spec.points()]
    assert sweep_spec.with_options(spec) is spec


def test_sweep_flags_reach_the_sweep_and_strict_fails_on_a_failed_claim(tmp_path, monkeypatch, capsys):
    seen = {}

    def fake_run_sweep(spec, out_root, **kw):
        seen["spec"] = spec
        return {"name": spec.name, "points": 1, "ran": 1, "reused": 0, "failed": 0, "numerical_errors": 0,
                "claims_failed": 2, "wall_s": 0.0, "out_dir": out_root}

    monkeypatch.setattr(sweep_run, "run_sweep", fake_run_sweep)
    sweep = tmp_path / "s.toml"
    sweep.write_text(f'name = "x"\nbase = "{SCENARIO}"\n[grid]\n"communication.rates" = [[1.0]]\n')
    args = ["sweep", str(sweep), "--out", str(tmp_path / "o"), "--seed", "5", "--trials", "300", "--quick"]
    assert main(args) == 0
    assert (seen["spec"].seed, seen["spec"].trials, seen["spec"].quick) == (5, 300, True)
    assert main([*args, "--strict"]) == 1
    assert "fail or error" in capsys.readouterr().out


def test_help_of_sweep_documents_the_run_options(capsys):
    text = help_of("sweep", capsys=capsys)
    for flag in ("--seed", "--trials", "--quick", "--strict"):
        assert flag in text
    assert build_parser().parse_args(["sweep", "f.toml"]).seed is None
