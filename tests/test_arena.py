"""`dse arena`: a plug-in filter against every built-in estimator over a suite of compare scenarios. The suite is
cut to two small generated scenarios here (the standard one runs in `make reproduce` and the README)."""
from __future__ import annotations

import subprocess

import pandas as pd
import pytest

from dse.arena import suite
from dse.arena.run import run_arena


@pytest.fixture
def small_suite(monkeypatch):
    from dse import registry

    fam = registry.family("compare")
    picked = [suite.Entry(f"s{i}", "test", fam.generate(seed, edge)) for i, (seed, edge) in
              enumerate([(0, "failures"), (1, "reliable_noisy_scalar")])]
    monkeypatch.setattr(suite, "entries", lambda quick: picked)
    return picked


def _board(out, name):
    return pd.read_csv(out / "arena" / name / "tables" / "leaderboard.csv")


def test_the_twin_of_a_builtin_scores_as_the_builtin_and_workers_do_not_change_a_bit(small_suite, tmp_path):
    kw = dict(factory="tests.plugins.twins:LocalTwin", quick=True, log=lambda m: None)
    a = run_arena("twin", out_root=tmp_path / "a", scheduler="inline", **kw)
    b = run_arena("twin", out_root=tmp_path / "b", scheduler="local", workers=2, **kw)
    assert a["scheduler"] == "inline" and b["scheduler"] == "local"
    for table in ("leaderboard.csv", "summary.csv"):
        assert (tmp_path / "a/arena/twin/tables" / table).read_bytes() == \
            (tmp_path / "b/arena/twin/tables" / table).read_bytes()
    board = _board(tmp_path / "a", "twin")
    for sc, g in board.groupby("scenario"):
        twin, local = g[g.estimator == "twin"].iloc[0], g[g.estimator == "local"].iloc[0]
        assert twin.mse_ratio == local.mse_ratio and twin.scalars_per_step == local.scalars_per_step == 0.0
        assert twin.plugin and not local.plugin
        assert twin.verdict_orthogonality == "pass" and twin.verdict_lower_bound == "pass", sc
    for f in ("frontier.png", "arena.rrd", "summary.md", "scenarios/s0.toml"):
        assert (tmp_path / "a/arena/twin" / f).is_file()
    # a stored suite is reused, not recomputed
    again = run_arena("twin", out_root=tmp_path / "a", scheduler="inline", **kw)
    assert again["reused"] == 2


def test_a_biased_filter_gets_fail_and_a_raising_one_is_left_out_in_one_line(small_suite, tmp_path):
    r = run_arena("shrunk", factory="tests.plugins.twins:ShrunkLocal", out_root=tmp_path, quick=True,
                  scheduler="inline", log=lambda m: None)
    board = _board(tmp_path, "shrunk")
    mine = board[board.estimator == "shrunk"]
    assert (mine.verdict_orthogonality == "fail").all() and r["fails"] >= 2
    builtin = board[board.estimator == "local"]
    assert (builtin.verdict_orthogonality == "pass").all()      # a plug-in's failure is not the built-ins'

    r = run_arena("bad", factory="tests.plugins.bad:RaisesInStep", out_root=tmp_path, quick=True,
                  scheduler="inline", log=lambda m: None)
    board = _board(tmp_path, "bad")
    mine = board[board.estimator == "bad"]
    assert len(mine) == 2 and not mine.ran.any() and mine.mse_ratio.isna().all()
    assert all("estimator 'bad' failed at step 3: raised RuntimeError: boom" in f for f in mine.fault) and len(r["faults"]) == 2 and r["ran"] == 0
    assert (board[board.estimator == "local"].ran).all()       # the others ran, with their numbers

    # matrices that are not its own: its exact moments are left out, it still ran and has numbers
    run_arena("lying", factory="tests.plugins.bad:NotUnbiased", out_root=tmp_path, quick=True, scheduler="inline",
              log=lambda m: None)
    mine = _board(tmp_path, "lying").query("estimator == 'lying'")
    reliable = mine[mine.scenario == "s1"]                       # the exact moments exist on reliable links only
    assert mine.ran.all() and mine.mse_ratio.notna().all() and "not unbiased" in reliable.fault.iloc[0]


def test_cli_keys_bad_factory_and_params(tmp_path, capsys):
    """`dse arena` by the command's entry point in this process (`cli.main`, what `python -m dse.cli` exits with;
    a fresh interpreter per command would only repeat the imports)."""
    from dse import cli

    def dse(*args):
        capsys.readouterr()
        code = cli.main(["arena", *args, "--out", str(tmp_path)])   # an exception escaping main fails the test too
        out, err = capsys.readouterr()
        return subprocess.CompletedProcess(args, code, out, err)

    r = dse("twin", "--factory", "tests.plugins.twins:LocalTwin", "--keys")
    assert r.returncode == 0 and "no parameters" in r.stdout
    r = dse("x", "--factory", "tests.plugins.nowhere:Filter")
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and "estimators.x.factory" in r.stderr
    r = dse("x", "--factory", "tests.plugins.twins:LocalTwin", "--param", "gain=2")
    assert r.returncode == 2 and "estimators.x.gain" in r.stderr and r.stderr.count("\n") == 1
    r = dse("nothing_installed_here")
    assert r.returncode == 2 and "no filter named 'nothing_installed_here' is installed" in r.stderr
