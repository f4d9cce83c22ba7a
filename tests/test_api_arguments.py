"""The Python API checks its arguments like the command line: one line, as a documented exception."""
import inspect
from pathlib import Path

import pytest

import dse
from dse import api
from dse.cli import build_parser
from dse.errors import ScenarioError, UsageError

TEMPLATE = Path(api.__file__).parent / "families" / "template" / "example.toml"

BAD_OPTIONS = [
    ({"trials": -3}, "trials: must be >= 1, got -3"),
    ({"trials": 2.5}, "trials: must be a whole number, got 2.5"),
    ({"trials": 10**13}, "trials: must be at most 1e+12"),
    ({"seed": -1}, "seed: must be >= 0, got -1"),
    ({"seed": "1"}, "seed: must be a whole number, got '1'"),
    ({"workers": 0}, "workers: must be >= 1, got 0"),
    ({"workers": True}, "workers: must be a whole number, got True"),
    ({"quick": "yes"}, "quick: must be True or False, got 'yes'"),
    ({"max_memory": "lots"}, "max_memory: must be a size of at least 256 MiB"),
    ({"max_memory": 10}, "max_memory: must be a size of at least 256 MiB"),
]


@pytest.mark.parametrize("function", [dse.run, dse.check])
@pytest.mark.parametrize("kwargs,message", BAD_OPTIONS, ids=[m.split(":")[0] + str(k) for k, m in BAD_OPTIONS])
def test_bad_options_are_one_line_usage_errors(function, kwargs, message):
    with pytest.raises(UsageError) as info:
        function(TEMPLATE, **kwargs)
    assert str(info.value).startswith(message) and "\n" not in str(info.value)


@pytest.mark.parametrize("call", [
    lambda: dse.check(123), lambda: dse.run(None), lambda: dse.load(3.5), lambda: dse.load(dse.paper("savas")),
    lambda: dse.paper(5), lambda: dse.run(TEMPLATE, quick=True, cache_dir=7),
    lambda: dse.execute("savas", dse.RunOptions()),
])
def test_bad_sources_and_paths_are_usage_errors(call):
    with pytest.raises(UsageError):
        call()


def test_usage_error_is_a_scenario_error_and_unknown_input_stays_one_too(tmp_path):
    assert issubclass(UsageError, ScenarioError)
    with pytest.raises(ScenarioError, match="unknown paper nope"):
        dse.paper("nope")
    with pytest.raises(ScenarioError, match="cannot read file"):
        dse.check(tmp_path / "missing.toml")


def test_defaults_match_the_command_line_and_max_memory_is_accepted():
    cli_run = build_parser().parse_args(["run", "x.toml"])
    cli_check = build_parser().parse_args(["check", "x.toml"])
    for function in (dse.run, dse.check):
        params = inspect.signature(function).parameters
        assert params["workers"].default == cli_run.workers == cli_check.workers
        assert params["seed"].default == cli_run.seed
        assert "max_memory" in params
    assert dse.check(TEMPLATE, quick=True, max_memory="1G").options.max_memory_mib == 1024.0
    assert dse.check(TEMPLATE, quick=True, max_memory=300).options.max_memory_mib == 300.0


@pytest.mark.parametrize("function", [dse.run, dse.check, dse.load, dse.paper, dse.execute, api.Run.write])
def test_every_parameter_is_documented(function):
    doc = inspect.getdoc(function)
    names = [p for p in inspect.signature(function).parameters if p != "self"]
    if function is dse.check:   # the parameters it shares with run are documented there
        assert "those of `run`" in doc
        names = [p for p in names if p not in inspect.signature(dse.run).parameters]
    for name in names:
        assert f"{name}:" in doc, f"{function.__qualname__}: parameter {name} is not documented"
