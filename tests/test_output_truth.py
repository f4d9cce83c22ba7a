"""Outputs tell the truth: a run memo never hides damaged stage entries, `dse verify` finds edited
files and tables and says exactly what it checked and what to run, and a refused command (exit 2
or 3) leaves no lock, no cache and no directory behind. In process (`dse.cli.main`), one worker."""
from __future__ import annotations

import errno
import json
import os
import shlex
import threading
from pathlib import Path

import pandas as pd
import pytest

from dse import cli
from dse.engine import cache, outlock
from test_cli import GOOD

FAST = ["--quick", "--no-figures", "--workers", "1"]


@pytest.fixture
def scenario(tmp_path, monkeypatch):
    """ring5 of test_cli, in a fresh directory, with a fixed code fingerprint (memos stay valid
    whatever else changes in the tree while the test runs)."""
    monkeypatch.setattr(cache, "project_fingerprint", lambda: "fixed-code")
    monkeypatch.setenv("DSE_PROGRESS", "0")
    monkeypatch.chdir(tmp_path)
    (tmp_path / "s.toml").write_text(GOOD)
    return tmp_path


def dse(capsys, *argv) -> tuple[int, str, str]:
    code = cli.main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def report(path: Path) -> dict:
    return json.loads((path / "run/ring5/report.json").read_text())


def listing(root: Path) -> dict[str, bytes | None]:
    """Every path under `root` with the bytes of files (None for directories)."""
    return {str(p.relative_to(root)): (p.read_bytes() if p.is_file() else None) for p in sorted(root.rglob("*"))}


# -- 5: the run memo and damaged stage entries; verify's advice; --fresh ----------------------------------

def test_a_damaged_or_missing_stage_entry_makes_the_run_memo_stale(scenario, capsys):
    assert dse(capsys, "run", "s.toml", "--out", "o", *FAST)[0] == 0
    assert dse(capsys, "run", "s.toml", "--out", "o", *FAST)[0] == 0
    assert report(scenario / "o")["provenance"]["memo"] is True
    entries = sorted((scenario / "o/.cache/ring5").glob("monte_carlo-*.npz"))
    entries[0].write_bytes(b"garbage")                 # damaged
    entries[1].unlink()                                # gone
    code, _, err = dse(capsys, "run", "s.toml", "--out", "o", *FAST)
    assert code == 0 and "computing the run again" in err, err
    prov = report(scenario / "o")["provenance"]
    assert prov["memo"] is False
    recomputed = {s["key"] for s in prov["stages"] if not s["cached"]}
    assert recomputed == {entries[0].stem, entries[1].stem}


def test_verify_names_damaged_entries_and_the_command_that_recomputes_them(scenario, capsys):
    assert dse(capsys, "run", "s.toml", "--out", "o", *FAST)[0] == 0
    before = report(scenario / "o")["claims"]
    for entry in (scenario / "o/.cache/ring5").glob("monte_carlo-*.npz"):
        entry.write_bytes(b"garbage")
    code, out, err = dse(capsys, "verify", "o")
    assert code == 1 and "recomputing" not in err and "damaged" in err, err
    command = err.split("`")[1]                         # the exact command verify names
    argv = shlex.split(command)
    assert argv[:2] == ["dse", "run"] and Path(argv[2]) == (scenario / "s.toml").resolve() and "--quick" in argv
    assert dse(capsys, *argv[1:], "--no-figures", "--workers", "1")[0] == 0   # not answered from the memo
    code, out, err = dse(capsys, "verify", "o")
    assert code == 0 and "verified: no differences" in out, out + err
    assert report(scenario / "o")["claims"] == before


def test_verify_without_the_cache_says_so_and_notes_a_changed_scenario_file(scenario, capsys):
    import shutil

    assert dse(capsys, "run", "s.toml", "--out", "o", *FAST)[0] == 0
    shutil.rmtree(scenario / "o/.cache")
    (scenario / "s.toml").write_text(GOOD.replace("q = 0.5", "q = 0.6"))
    code, _, err = dse(capsys, "verify", "o")
    assert code == 1 and "lacks a stage" in err and "s.toml changed or is gone since the run" in err, err
    assert len(err.strip().splitlines()) == 1


def test_fresh_ignores_the_memo_and_the_stage_cache(scenario, capsys):
    assert dse(capsys, "run", "s.toml", "--out", "o", *FAST)[0] == 0
    first = report(scenario / "o")
    assert dse(capsys, "run", "s.toml", "--out", "o", *FAST, "--fresh")[0] == 0
    again = report(scenario / "o")
    assert again["provenance"]["memo"] is False and not any(s["cached"] for s in again["provenance"]["stages"])
    assert again["claims"] == first["claims"]
    assert "--fresh" in cli.build_parser()._subparsers._group_actions[0].choices["run"].format_help()


# -- 6: verify finds edited outputs and says what it checked ---------------------------------------------------

def test_verify_fails_on_edited_tables_and_report_and_names_each_file(scenario, capsys):
    assert dse(capsys, "run", "s.toml", "--out", "o", *FAST)[0] == 0
    d = scenario / "o/run/ring5"
    nodes = pd.read_parquet(d / "tables/nodes.parquet")
    nodes.loc[0, "P_steady"] = 999.0
    nodes.to_parquet(d / "tables/nodes.parquet")
    csv = (d / "tables/claims.csv").read_text()
    (d / "tables/claims.csv").write_text(csv.replace(",pass,", ",fail,", 1))
    (d / "report.md").write_text("# everything passes\n")
    for flags in ((), ("--strict",)):
        code, out, _ = dse(capsys, "verify", "o", *flags)
        assert code == 1, out
        differs = [ln for ln in out.splitlines() if "differs:" in ln]
        for name in ("tables/nodes.parquet: edited", "tables/claims.csv: edited", "report.md: edited",
                     "tables/nodes.parquet row 0 column P_steady: 999.0 written"):
            assert sum(name in ln for ln in differs) == 1, (name, out)
        assert "NOT verified" in out and "files" in out and "tables" in out and "claims" in out


def test_verify_says_what_it_checked(scenario, capsys):
    assert dse(capsys, "run", "s.toml", "--out", "o", *FAST)[0] == 0
    code, out, _ = dse(capsys, "verify", "o")
    files = len([p for p in (scenario / "o/run/ring5").rglob("*") if p.is_file()]) - 1   # all but run.json
    assert code == 0 and f"files: {files} checked" in out and "compared with tables/*.parquet exactly" in out, out
    (scenario / "o/run/ring5/extra.txt").write_text("x")
    code, out, _ = dse(capsys, "verify", "o")
    assert code == 1 and "extra.txt: not written by the run" in out


def test_verify_finds_an_edited_sweep_file(scenario, capsys):
    (scenario / "sw.toml").write_text('name = "sw"\nbase = "s.toml"\nquick = true\n[grid]\n"model.q" = [0.5, 1.0]\n')
    assert dse(capsys, "sweep", "sw.toml", "--out", "o", "--scheduler", "inline")[0] == 0
    assert dse(capsys, "verify", "o/sweep/sw")[0] == 0
    claims = pd.read_parquet(scenario / "o/sweep/sw/claims.parquet")
    claims.loc[0, "verdict"] = "fail" if claims.loc[0, "verdict"] != "fail" else "pass"
    claims.to_parquet(scenario / "o/sweep/sw/claims.parquet")
    code, out, _ = dse(capsys, "verify", "o/sweep/sw")
    assert code == 1 and "claims.parquet: edited" in out, out


# -- 8: a refused command leaves nothing behind ------------------------------------------------------------------

def test_the_lock_file_is_removed_after_a_run(scenario, capsys):
    assert dse(capsys, "run", "s.toml", "--out", "o", *FAST)[0] == 0
    assert not (scenario / "o" / ".dse.lock").exists()


def test_a_sweep_with_an_invalid_point_leaves_no_output_directory(scenario, capsys):
    (scenario / "sw.toml").write_text('name = "sw"\nbase = "s.toml"\nquick = true\n[grid]\n"model.q" = [0.5, -1.0]\n')
    code, _, err = dse(capsys, "sweep", "sw.toml", "--out", "new", "--scheduler", "inline")
    assert code == 2 and "model.q" in err
    assert not (scenario / "new").exists()


def test_a_sweep_without_workers_leaves_no_output_directory(scenario, capsys, monkeypatch):
    from dse.errors import ScenarioError
    from dse.sweeps import run as sweep_run

    def no_worker(tasks, scheduler, *rest):   # what a scheduler no worker joins ends in (tests/test_faults.py)
        raise ScenarioError("--scheduler", f"no worker joined the Dask scheduler at {scheduler} within 3 s")

    monkeypatch.setattr(sweep_run, "_execute_dask", no_worker)
    (scenario / "sw.toml").write_text('name = "sw"\nbase = "s.toml"\nquick = true\n[grid]\n"model.q" = [0.5, 1.0]\n')
    code, _, err = dse(capsys, "sweep", "sw.toml", "--out", "new/deeper", "--scheduler", "tcp://127.0.0.1:1")
    assert code == 2 and "no worker" in err
    assert not (scenario / "new").exists()


def _full_disk_after(monkeypatch, module, name: str, allowed: int) -> None:
    """`module.name` (a writer) succeeds `allowed` times, then fails as on a full disk."""
    real, calls = getattr(module, name), []

    def writer(*args, **kwargs):
        calls.append(1)
        if len(calls) > allowed:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return real(*args, **kwargs)

    monkeypatch.setattr(module, name, writer)


def _full_disk_at_the_probe(monkeypatch) -> None:
    """The write probe of the output directory is half written, then the disk is full."""
    real = Path.write_bytes

    def write_bytes(self, data):
        if self.name != ".dse-write-probe":
            return real(self, data)
        real(self, data[: len(data) // 2])
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(Path, "write_bytes", write_bytes)


@pytest.mark.parametrize("where", ["probe", "stage cache", "tables"])
def test_a_full_disk_leaves_a_new_out_absent_and_an_old_one_as_it_was(scenario, capsys, monkeypatch, where):
    from dse.outputs import tables

    assert dse(capsys, "run", "s.toml", "--out", "old", *FAST, "--seed", "1")[0] == 0
    before = listing(scenario / "old")
    if where == "probe":
        _full_disk_at_the_probe(monkeypatch)
    elif where == "stage cache":
        _full_disk_after(monkeypatch, cache, "atomic_write_bytes", 3)
    else:
        _full_disk_after(monkeypatch, tables, "_write_parquet", 2)
    for out in ("new", "old"):
        code, _, err = dse(capsys, "run", "s.toml", "--out", out, *FAST, "--seed", "7")
        assert code == 2 and "No space left" in err, err
    assert not (scenario / "new").exists()
    assert listing(scenario / "old") == before


def test_a_refused_run_keeps_what_others_put_in_an_existing_out(scenario, capsys, monkeypatch):
    assert dse(capsys, "run", "s.toml", "--out", "old", *FAST, "--seed", "1")[0] == 0
    before = listing(scenario / "old")
    real = cache.atomic_write_bytes

    def disk_full_while_someone_writes(*args, **kwargs):
        (scenario / "old" / "notes.txt").write_text("mine")      # not dse's: kept
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(cache, "atomic_write_bytes", disk_full_while_someone_writes)
    assert dse(capsys, "run", "s.toml", "--out", "old", *FAST, "--seed", "7")[0] == 2
    monkeypatch.setattr(cache, "atomic_write_bytes", real)
    assert listing(scenario / "old") == {**before, "notes.txt": b"mine"}


def test_a_numerical_failure_leaves_a_new_out_absent(scenario, capsys, monkeypatch):
    from dse.errors import NumericalError

    def diverge(*args, **kwargs):
        raise NumericalError("monte_carlo", "ring5", "array 'x' at index (3,)")

    real = cache.StageCache.save
    saved = []

    def save_then_diverge(self, stage, params, arrays):   # a few entries stored, then a NaN
        saved.append(stage)
        if len(saved) > 2:
            diverge()
        return real(self, stage, params, arrays)

    monkeypatch.setattr(cache.StageCache, "save", save_then_diverge)
    code, _, err = dse(capsys, "run", "s.toml", "--out", "new", *FAST)
    assert code == 3, err
    assert not (scenario / "new").exists()


def test_a_run_that_waited_for_a_removed_lock_file_holds_the_current_one(tmp_path, monkeypatch):
    """The lock file is removed on release; a run that was waiting on the removed file takes the lock
    on a new one, so that a third run still waits (never two holders)."""
    import fcntl

    waiting, inside, leave = threading.Event(), threading.Event(), threading.Event()

    def announce(*args, **kwargs):
        waiting.set()

    monkeypatch.setattr(outlock, "print", announce, raising=False)

    def second():
        with outlock.output_lock(tmp_path / "o"):
            inside.set()
            leave.wait(30)

    with outlock.output_lock(tmp_path / "o"):
        t = threading.Thread(target=second)
        t.start()
        assert waiting.wait(30)
    assert inside.wait(30)
    with open(tmp_path / "o" / ".dse.lock", "a+") as third:
        with pytest.raises(BlockingIOError):
            fcntl.flock(third, fcntl.LOCK_EX | fcntl.LOCK_NB)
    leave.set()
    t.join(30)
    assert not (tmp_path / "o" / ".dse.lock").exists()
