"""Resources: the bounds of --trials, --workers, --max-memory and --max-time (CLI and API), the refusal of
a run estimated too long, and `dse check`'s own budget (its design work bounded, announced past a second).
No test here depends on the machine's speed: work is bounded by CPU time (ITIMER_PROF) or counted."""
from __future__ import annotations

import contextlib
import math
import signal
from pathlib import Path

import pytest

import dse.estimators.constant_gain_fusion as cgf
from dse import api, cli
from dse.contract.cost import allowing, parse_duration
from dse.contract.options import DEFAULT_MAX_TIME_S, RunOptions, declared_bounds, machine_cpus, machine_memory_mib
from dse.engine.progress import note_if_slow
from dse.estimators.network import registry
from dse.errors import ScenarioError
from dse.families.compare.cost import design_seconds, tuning_solves

ROOT = Path(__file__).resolve().parents[1]
SAVAS = ROOT / "dse" / "families" / "savas" / "paper.toml"


class CpuBudgetExceeded(Exception):
    pass


@contextlib.contextmanager
def cpu_limit(seconds: float):
    """Fail the block once it has used `seconds` of CPU time (this process; not wall time)."""
    def over(signum, frame):
        raise CpuBudgetExceeded(f"used more than {seconds} s of CPU")

    previous = signal.signal(signal.SIGPROF, over)
    signal.setitimer(signal.ITIMER_PROF, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_PROF, 0)
        signal.signal(signal.SIGPROF, previous)


def compare_rgg(n: int, radius: float, **links) -> dict:
    """A compare scenario on a random geometric graph: 2-state plant, two sensor types, link failures."""
    return {"family": "compare", "name": f"rgg{n}",
            "plant": {"F": [[1.0, 0.1], [0.0, 0.98]], "Q": [[0.01, 0.0], [0.0, 0.05]], "P0": [[1.0, 0.0], [0.0, 1.0]]},
            "sensors": {"types": [{"H": [[1.0, 0.0]], "R": [[0.5]]}, {"H": [[0.0, 1.0]], "R": [[0.5]]}]},
            "graph": {"kind": "random_geometric", "n": n, "radius": radius, "seed": 1},
            "links": {"model": "failures", "p_fail": 0.3, "noise_std": 0.1, **links}}


def run_cli(capsys, *argv: str) -> tuple[int, str, str]:
    code = cli.main(list(argv))
    out = capsys.readouterr()
    return code, out.out, out.err


# -- item 1: dse check within its own budget --------------------------------------------------------------

def test_check_refuses_a_design_beyond_its_budget_before_computing_it():
    """The issue's 200-node compare scenario kept `dse check` busy for minutes (gain searches): now refused in
    one line naming graph.n, after a fraction of a second of CPU."""
    with cpu_limit(10.0), pytest.raises(ScenarioError) as err:
        api.check(compare_rgg(200, 0.17))
    assert err.value.field == "graph.n"
    assert "--max-design-time" in err.value.reason and "dse run" in err.value.reason


def test_check_refusal_on_the_command_line_is_one_line_exit_2(capsys, tmp_path):
    f = tmp_path / "rgg200.toml"
    f.write_text(_toml(compare_rgg(200, 0.17)))
    with cpu_limit(10.0):
        code, out, err = run_cli(capsys, "check", str(f), "--out", str(tmp_path / "out"))
    assert code == 2 and out == "" and err.count("\n") == 1 and err.startswith("dse: error: graph.n: ")


def test_compare_cost_model_counts_the_steady_states_the_design_computes(monkeypatch):
    """The design estimate is built on the number of steady states the gain searches solve: counted here
    against the design itself (quick and full searches, one and two rounds)."""
    calls = []
    real = cgf.steady_state
    monkeypatch.setattr(cgf, "steady_state", lambda *a, **k: calls.append(1) or real(*a, **k))
    for quick, links in ((True, {}), (False, {}), (True, {"rounds": 2})):
        repro = api.load(compare_rgg(6, 0.9, **links))
        calls.clear()
        api.check(repro, quick=quick)
        running = {n for n in repro.scenario.estimator_names if not registry()[n].applies(repro.scenario.link_model)}
        assert len(calls) == tuning_solves(repro.scenario, quick, running), (quick, links)


def test_compare_design_estimate_grows_with_the_graph_as_the_searches_do():
    """Per steady state on random links, the edge patterns cost N²·E·n²: the 200-node design is estimated
    hundreds of times the 20-node one (what made the issue's check run for minutes)."""
    small, large = (api.load(compare_rgg(n, r)).scenario for n, r in ((20, 0.5), (200, 0.17)))
    assert design_seconds(large, False) > 100 * design_seconds(small, False)
    assert design_seconds(small, True) < design_seconds(small, False)


def test_a_slow_block_is_announced_once_and_a_fast_one_not(capsys):
    with note_if_slow(0.0, "dse check: computing the design") as note:
        assert note.noted.wait(30)
    with note_if_slow(3600.0, "never shown") as quiet:
        pass
    assert not quiet.noted.is_set()
    err = capsys.readouterr().err
    assert err.count("computing the design") == 1 and "never shown" not in err


# -- item 3: the options within the scenario's and the machine's bounds ------------------------------------

def test_trials_option_gets_the_declared_bounds_of_the_trials_key(capsys, tmp_path):
    assert declared_bounds(api.load(SAVAS).family.scenario_model, "monte_carlo.trials") == (100, 100_000_000)
    for command, out_flag in (("run", ["--out", str(tmp_path / "out")]), ("check", ["--out", str(tmp_path / "out")])):
        with cpu_limit(20.0):
            code, out, err = run_cli(capsys, command, str(SAVAS), "--trials", "1e12", *out_flag)
        assert code == 2 and err.count("\n") == 1, (command, err)
        assert err.startswith("dse: error: --trials: ") and "100,000,000" in err and "monte_carlo.trials" in err
    with pytest.raises(ScenarioError) as e:
        api.run(SAVAS, trials=10**12)
    assert e.value.field == "--trials"
    with pytest.raises(ScenarioError) as e:
        api.run(SAVAS, trials=50)                          # below the key's lower bound too
    assert e.value.field == "--trials" and "[100," in e.value.reason


def test_every_family_names_a_declared_trials_key():
    from dse import registry as families

    for fid, fam in families.families().items():
        lo, hi = declared_bounds(fam.scenario_model, fam.trials_key)
        assert lo is not None and hi is not None and lo <= hi, fid


def test_a_run_estimated_beyond_the_time_limit_is_refused_before_it_starts():
    """1e8 trials of the savas paper scenario are within the key's bounds but take hours: refused with the
    limit and the flag that lifts it, before any stage (CPU-bounded)."""
    repro = api.load(SAVAS)
    with cpu_limit(20.0), pytest.raises(ScenarioError) as e:
        api.execute(repro, RunOptions(trials=100_000_000, max_time_s=600.0))
    assert e.value.field == "--trials" and "--max-time" in e.value.reason and "10 minutes" in e.value.reason
    assert RunOptions().time_limit_s == DEFAULT_MAX_TIME_S == 86400.0


def test_check_reports_the_refusal_run_would_give(capsys, tmp_path):
    with cpu_limit(30.0):
        code, out, err = run_cli(capsys, "check", str(SAVAS), "--trials", "1e8", "--max-time", "10m", "--out",
                                 str(tmp_path / "out"))
    assert code == 2 and "estimate:" in out
    assert err.strip().splitlines()[-1].startswith("dse: error: `dse run` would refuse this run: --trials: ")


def test_workers_and_memory_beyond_the_machine_are_refused(capsys):
    too_many = max(machine_cpus(), 2) + 1
    code, _, err = run_cli(capsys, "check", str(SAVAS), "--workers", str(too_many))
    assert code == 2 and err.startswith("dse: error: --workers: at most ") and err.count("\n") == 1
    code, _, err = run_cli(capsys, "check", str(SAVAS), "--max-memory", "1T" if machine_memory_mib() < 2**20 else "1000T")
    assert code == 2 and err.startswith("dse: error: --max-memory: at most this machine's memory")
    with pytest.raises(ScenarioError) as e:
        api.run(SAVAS, workers=too_many)
    assert e.value.field == "--workers"


def test_check_accepts_the_run_budgets(capsys, tmp_path):
    code, out, err = run_cli(capsys, "check", str(SAVAS), "--quick", "--max-memory", "2G", "--max-time", "1h", "--out",
                             str(tmp_path / "out"))
    assert code == 0 and "estimate:" in out


def test_durations():
    assert parse_duration("90") == 90 and parse_duration("30m") == 1800 and parse_duration("2d") == 172800
    assert parse_duration("inf") == math.inf
    for bad in ("0", "-1h", "nan", "soon", ""):
        with pytest.raises(ValueError):
            parse_duration(bad)
    assert parse_duration(allowing(4.15e7)) > 4.15e7 and allowing(4.15e7).endswith("d")


def _toml(data: dict) -> str:
    """Scenario dicts as TOML: top-level keys on one line each, tables inline."""
    import json

    def value(v):
        if isinstance(v, dict):
            return "{" + ", ".join(f"{k} = {value(x)}" for k, x in v.items()) + "}"
        if isinstance(v, (list, tuple)):
            return "[" + ", ".join(value(x) for x in v) + "]"
        return json.dumps(v)

    return "\n".join(f"{k} = {value(v)}" for k, v in data.items()) + "\n"


# -- item 4: the estimates include what a user waits for -----------------------------------------------------

def test_compare_estimate_includes_start_up_and_outputs():
    """A small compare run was estimated at 0.27 s (its Monte Carlo only) for 7-12 s measured: the interpreter,
    the imports, the design, the figures and recordings are now part of the estimate."""
    from dse.families.compare.cost import OUTPUTS_S, STARTUP_S

    est = api.check(ROOT / "dse" / "families" / "compare" / "scenarios" / "noisy_ring.toml", quick=True).estimate
    assert est["seconds"] >= STARTUP_S + OUTPUTS_S >= 2.0


def test_api_run_takes_the_time_limit():
    with cpu_limit(20.0), pytest.raises(ScenarioError) as e:
        api.run(SAVAS, trials=100_000_000, max_time_s=60.0)
    assert e.value.field == "--trials" and "more than the 60 s --max-time allows" in e.value.reason
