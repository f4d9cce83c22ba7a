"""Every example of README.md runs as written: the scenario file, the Python session, the sweep file and
the invalid-input message. Each fenced block is either run here or listed in NOT_RUN with the reason,
so that a new example cannot go untested unnoticed."""
import ast
import re
from pathlib import Path

import pytest

from dse.cli import main

README = Path(__file__).resolve().parents[1] / "README.md"

#: blocks that are not examples to run here, by their first line, and why
NOT_RUN = {
    "make reproduce": "the make targets: they build the environment and run the whole reproduction and suite",
    "out/<paper>/": "a directory layout, not a command",
    "dse list [PAPER|FAMILY...]": "the command synopsis (placeholders, not a command)",
    "OPENBLAS_NUM_THREADS=1 .venv/bin/dask scheduler": "needs machines of one's own (tests/test_sweep.py runs a "
                                                       "loopback scheduler)",
    "dse/ ": "the package layout, not a command",
}


#: the plug-in example ("Bring your own estimator"): its filter, its scenario and the command running them
PLUGIN_FILE, PLUGIN_SCENARIO, PLUGIN_RUN = "import numpy as np", 'family = "compare"', "PYTHONPATH=. dse run"
#: the example package's leaderboard: its install line (make's set-up runs it) and `dse arena` commands
ARENA = "pip install -e examples/dse-consensus-measurements"


def blocks() -> list[tuple[str, str]]:
    return re.findall(r"^```(\w*)\n(.*?)^```", README.read_text(), re.S | re.M)


def block(lang: str, first: str) -> str:
    found = [body for kind, body in blocks() if kind == lang and body.startswith(first)]
    assert len(found) == 1, f"README.md: expected one {lang} block starting with {first!r}"
    return found[0]


def scenario_file() -> str:
    return block("toml", 'family = "noisy-consensus-filter"')


def test_every_block_is_run_here_or_said_why_not():
    run_here = {("toml", 'family = "noisy-consensus-filter"'), ("toml", 'name = "my-sweep"'), ("python", "import dse"),
                ("python", PLUGIN_FILE), ("toml", PLUGIN_SCENARIO), ("", PLUGIN_RUN), ("", ARENA)}
    for kind, body in blocks():
        if any((kind, body.startswith(first)) == (k, True) for k, first in run_here):
            continue
        assert kind == "" and any(body.startswith(first) for first in NOT_RUN), \
            f"README.md block not covered by tests/test_readme_examples.py: {body.splitlines()[0]!r}"


@pytest.fixture
def readme_dir(tmp_path, monkeypatch):
    """A directory holding the README's scenario as ring8.toml (its `name`), the working directory."""
    (tmp_path / "ring8.toml").write_text(scenario_file())
    monkeypatch.chdir(tmp_path)
    return tmp_path


def test_scenario_checks_and_its_invalid_variant_gives_the_quoted_line(readme_dir, capsys):
    assert main(["check", "ring8.toml"]) == 0
    assert "valid scenario 'ring8'" in capsys.readouterr().out
    quoted = re.search(r"\(`(dse: error: model\.r: [^`]*)`\)", " ".join(README.read_text().split())).group(1)
    (readme_dir / "bad.toml").write_text(scenario_file().replace("r = 25.0", "r = -1.0"))
    assert main(["check", "bad.toml"]) == 2
    assert capsys.readouterr().err.strip() == quoted


def test_python_session_runs_and_its_counts_comment_is_what_it_gives(readme_dir):
    code = block("python", "import dse")
    namespace: dict = {}
    exec(compile(code, "README.md", "exec"), namespace)      # noqa: S102 - the README's own example
    shown = re.search(r"run\.counts\s+# (\{.*\})", code).group(1).replace(", ...}", "}")
    assert ast.literal_eval(shown).items() <= namespace["run"].counts.items()
    assert (readme_dir / "out" / "run" / "ring8" / "report.json").is_file()


def test_sweep_file_runs_and_draws_the_metrics_it_names(readme_dir, capsys):
    text = block("toml", 'name = "my-sweep"')
    (readme_dir / "my-sweep.toml").write_text(text)
    assert main(["sweep", "my-sweep.toml", "--scheduler", "inline", "--out", "out"]) == 0
    captured = capsys.readouterr()
    assert "plot.metrics" not in captured.err and "8 points (8 run" in captured.out
    import pandas as pd

    results = pd.read_parquet(readme_dir / "out" / "sweep" / "my-sweep" / "results.parquet")
    for metric in re.search(r"^metrics = (\[.*\])", text, re.M).group(1).strip("[]").replace('"', "").split(", "):
        assert results[f"metric:{metric}"].notna().all()
    assert (readme_dir / "out" / "sweep" / "my-sweep" / "sweep.png").stat().st_size > 0


def test_plugin_filter_runs_in_its_scenario_as_shown(tmp_path, monkeypatch, capsys):
    """The README's filter file and compare scenario, run by its command: the plug-in runs, sends what it
    declares, and its claims hold (orthogonality to the centralized error, the centralized lower bound)."""
    import json
    import sys

    (tmp_path / "my_filter.py").write_text(block("python", PLUGIN_FILE))
    (tmp_path / "ring_mine.toml").write_text(block("toml", PLUGIN_SCENARIO))
    monkeypatch.chdir(tmp_path)
    monkeypatch.syspath_prepend(str(tmp_path))                   # what PYTHONPATH=. does
    monkeypatch.delitem(sys.modules, "my_filter", raising=False)
    command = block("", PLUGIN_RUN).split("#")[0].split()
    assert command[:3] == ["PYTHONPATH=.", "dse", "run"]
    assert main(command[2:]) == 0, capsys.readouterr().err
    report = json.loads((tmp_path / "out" / "run" / "ring_mine" / "report.json").read_text())
    verdicts = {c["id"]: c["verdict"] for c in report["claims"] if c["id"].startswith("compare.plugin.mine.")}
    assert verdicts["compare.plugin.mine.orthogonality"] == "pass", verdicts
    assert verdicts["compare.plugin.mine.lower_bound"] == "pass", verdicts
    import pandas as pd

    table = pd.read_parquet(tmp_path / "out" / "run" / "ring_mine" / "tables" / "estimators.parquet")
    assert table.set_index("estimator").loc["mine", "scalars_per_step"] == 2.0     # n = 1 number to 2 neighbours


def test_example_package_arena_commands_run_as_shown(tmp_path, monkeypatch, capsys):
    """The README's arena block: the package its first line installs is installed (make's set-up), `--keys`
    prints its parameter, and `dse arena cm --quick` writes the leaderboard, on a suite cut to two small
    generated scenarios and in process (the standard suite takes about a minute; tests/test_arena.py tests the
    command itself)."""
    from importlib.metadata import entry_points

    from dse import registry
    from dse.arena import suite

    lines = [line.split("#")[0].split() for line in block("", ARENA).splitlines()]
    assert lines[0] == ["pip", "install", "-e", "examples/dse-consensus-measurements"]
    assert "cm" in {ep.name for ep in entry_points(group="dse.estimators")}, "make's set-up installs the example"
    compare = registry.family("compare")
    picked = [suite.Entry(f"s{i}", "test", compare.generate(seed, edge))
              for i, (seed, edge) in enumerate([(0, "matchings"), (1, "reliable_noisy_scalar")])]
    monkeypatch.setattr(suite, "entries", lambda quick: picked)
    monkeypatch.chdir(tmp_path)
    commands = lines[1:]
    assert [c[:3] for c in commands] == [["dse", "arena", "cm"]] * 2
    assert main(commands[0][1:]) == 0 and "rounds (int | None" in capsys.readouterr().out
    assert main(commands[1][1:] + ["--scheduler", "inline"]) == 0, capsys.readouterr().err
    import pandas as pd

    board = pd.read_csv(tmp_path / "out" / "arena" / "cm" / "tables" / "leaderboard.csv")
    mine = board[board.estimator == "cm"]
    assert len(mine) == 2 and not mine.filter(like="verdict_").isin(["fail", "error"]).any().any()
    assert (mine.verdict_orthogonality == "pass").all()
