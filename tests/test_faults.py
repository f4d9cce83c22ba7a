"""Faults injected into `dse`: signals at random moments, a full disk, damaged and tampered files,
a scheduler with no workers, odd input files. Each must end in one line and a documented exit
code, never a traceback, and leave no half-written output."""
from __future__ import annotations

import json
import os
import random
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from test_cli import GOOD, dse_here, sigint_as_from_a_terminal

DSE = [sys.executable, "-m", "dse.cli"]
ROOT = Path(__file__).resolve().parent.parent
ENV = {"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin", "DSE_PROGRESS": "0"}


def dse(*args, cwd, timeout=600):
    return subprocess.run([*DSE, *args], cwd=cwd, capture_output=True, text=True, timeout=timeout, env=ENV)


def one_line(err: str) -> bool:
    lines = [ln for ln in err.strip().splitlines() if ln.strip()]
    return len(lines) >= 1 and "Traceback" not in err and lines[-1].startswith("dse")


def complete_outputs(out: Path) -> None:
    """Whatever is at a final path is complete: JSON parses, no temporary or staging leftovers."""
    for path in out.rglob("*.json"):
        if ".cache" not in path.parts:
            json.loads(path.read_text())
    leftovers = [p for p in out.rglob(".*") if ".staging-" in p.name or ".old-" in p.name]
    assert not leftovers, leftovers


@pytest.fixture(scope="module")
def scenario(tmp_path_factory):
    d = tmp_path_factory.mktemp("faults")
    (d / "s.toml").write_text(GOOD.replace("trials = 4000", "trials = 400000"))
    return d


@pytest.fixture(scope="module")
def quick_out(tmp_path_factory):
    """`dse run s.toml --out o --quick` of GOOD, run once (in process: the faults are in what it leaves): the tests
    that damage a finished run's files start from a copy of it (the same files a run of their own would write,
    without computing them again)."""
    d = tmp_path_factory.mktemp("quick")
    (d / "s.toml").write_text(GOOD)
    proc = dse_here("run", "s.toml", "--out", "o", "--quick", cwd=d)
    assert proc.returncode == 0, proc.stderr
    return d / "o"


def finished_run(quick_out: Path, tmp_path: Path) -> None:
    """tmp_path as `dse run s.toml --out o --quick` of GOOD leaves it: the scenario and a copy of the outputs."""
    (tmp_path / "s.toml").write_text(GOOD)
    shutil.copytree(quick_out, tmp_path / "o", symlinks=True)


@pytest.mark.parametrize("sig,code", [(signal.SIGTERM, 143), (signal.SIGINT, 130)])
def test_a_signal_at_a_random_moment_stops_cleanly(scenario, tmp_path, sig, code):
    shutil.copy(scenario / "s.toml", tmp_path / "s.toml")
    rng = random.Random(int(sig))
    proc = subprocess.Popen([*DSE, "run", "s.toml", "--out", "o"], cwd=tmp_path, env=ENV, text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, start_new_session=True,
                            preexec_fn=sigint_as_from_a_terminal)
    lock = tmp_path / "o/.dse.lock"
    while not (lock.exists() and lock.read_text().startswith("pid")):  # started: past the imports, holding OUT
        assert proc.poll() is None, proc.communicate()
        time.sleep(0.05)
    time.sleep(rng.uniform(0.0, 2.5))  # then a moment anywhere in the scenario's loading, design or simulation
    os.killpg(proc.pid, sig)  # the whole process group, as a terminal or a job scheduler does
    _, err = proc.communicate(timeout=600)
    if proc.returncode == 0:  # finished before the signal: nothing to check about interruption
        return
    assert proc.returncode == code, err
    assert one_line(err), err
    time.sleep(0.5)
    alive = subprocess.run(["pgrep", "-g", str(proc.pid)], capture_output=True, text=True).stdout.split()
    assert not alive, f"processes of the stopped run still alive: {alive}"
    complete_outputs(tmp_path / "o")
    assert not (tmp_path / "o/run/ring5/report.json").exists()


def _tmpfs(path: Path, size: str) -> bool:
    path.mkdir(parents=True, exist_ok=True)
    ok = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(path)], capture_output=True)
    return ok.returncode == 0


def test_a_full_disk_is_one_line_and_leaves_the_previous_outputs(scenario, tmp_path):
    disk = tmp_path / "disk"
    if not _tmpfs(disk, "6m"):
        pytest.skip("cannot mount a small tmpfs here (needs root)")
    try:
        shutil.copy(scenario / "s.toml", tmp_path / "s.toml")
        small = (tmp_path / "s.toml").read_text().replace("trials = 400000", "trials = 4000")
        (tmp_path / "small.toml").write_text(small)
        first = dse_here("run", "small.toml", "--out", str(disk), "--quick", cwd=tmp_path)   # the previous outputs
        if first.returncode == 0:
            before = (disk / "run/ring5/report.json").read_bytes()
        filler = disk / "filler"
        with open(filler, "wb") as fh:  # leave almost nothing free
            try:
                while True:
                    fh.write(b"\0" * 65536)
            except OSError:
                pass
        again = dse("run", "small.toml", "--out", str(disk), "--seed", "7", "--quick", cwd=tmp_path)
        assert again.returncode == 2, again.stderr
        assert one_line(again.stderr) and "No space left" in again.stderr or "not usable" in again.stderr, again.stderr
        if first.returncode == 0:
            assert (disk / "run/ring5/report.json").read_bytes() == before  # the previous run is intact
        filler.unlink()
        complete_outputs(disk)
    finally:
        subprocess.run(["umount", str(disk)], capture_output=True)


def test_damaged_and_tampered_cache_entries_are_recomputed(quick_out, tmp_path):
    finished_run(quick_out, tmp_path)
    report = json.loads((tmp_path / "o/run/ring5/report.json").read_text())
    for memo in (tmp_path / "o/.cache").glob("*/runs"):
        shutil.rmtree(memo)  # the run memo would answer without loading the stage entries
    entries = sorted((tmp_path / "o/.cache").rglob("*.json"))
    assert entries
    entries[0].write_text("null")                                   # a sidecar holding null
    data = entries[1].with_suffix(".npz") if len(entries) > 1 else entries[0].with_suffix(".npz")
    data.unlink()
    data.mkdir()                                                     # an entry replaced by a directory
    again = dse("run", "s.toml", "--out", "o", "--quick", cwd=tmp_path)
    assert again.returncode == 0 and "Traceback" not in again.stderr, again.stderr
    assert "damaged" in again.stderr
    redone = json.loads((tmp_path / "o/run/ring5/report.json").read_text())
    assert [c["measured"] for c in redone["claims"]] == [c["measured"] for c in report["claims"]]


def test_odd_files_as_scenario_are_refused_before_reading(tmp_path):
    fifo = tmp_path / "fifo.toml"
    os.mkfifo(fifo)
    big = tmp_path / "big.toml"
    big.write_bytes(b"# " + b"x" * (2 << 20))
    for path in ("/dev/zero", str(fifo), str(big), str(tmp_path)):
        r = dse("run", path, "--out", "o", cwd=tmp_path, timeout=20)
        assert r.returncode == 2 and one_line(r.stderr), (path, r.stderr)
    assert not (tmp_path / "o").exists()


def test_damaged_run_json_in_verify_is_one_line(quick_out, tmp_path):
    finished_run(quick_out, tmp_path)
    (tmp_path / "o/run/ring5/run.json").write_text("{")
    r = dse("verify", "o", cwd=tmp_path)
    assert r.returncode == 2 and one_line(r.stderr) and "damaged" in r.stderr, r.stderr


def test_a_second_run_into_the_same_out_waits_for_the_first(tmp_path):
    (tmp_path / "s.toml").write_text(GOOD)
    first = subprocess.Popen([*DSE, "run", "s.toml", "--out", "o", "--quick"], cwd=tmp_path, env=ENV, text=True,
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    lock = tmp_path / "o/.dse.lock"
    while not (lock.exists() and lock.read_text().startswith("pid")):  # the first run holds the lock
        assert first.poll() is None, first.communicate()
        time.sleep(0.05)
    # the second run in this process (the lock is between processes all the same), without figures (not read here)
    second = dse_here("run", "s.toml", "--out", "o", "--quick", "--seed", "1", "--no-figures", cwd=tmp_path)
    out, err = first.communicate(timeout=300)
    assert first.returncode == 0 and second.returncode == 0, (err, second.stderr)
    assert "waiting for the other dse run" in second.stderr, second.stderr
    complete_outputs(tmp_path / "o")
    report = json.loads((tmp_path / "o/run/ring5/report.json").read_text())
    assert report["provenance"]["seed"] == 1  # the second run replaced the first as a whole


def test_a_scheduler_without_workers_times_out_with_a_message(tmp_path):
    from distributed import Scheduler  # noqa: F401  (dask is a dependency)

    import dse.sweeps.run as sw
    from dse.errors import ScenarioError
    from dse.sweeps.spec import parse_sweep

    port_proc = subprocess.Popen([str(Path(sys.executable).parent / "dask"), "scheduler", "--host", "127.0.0.1",
                                  "--port", "0", "--no-dashboard"], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                                 text=True, env={**ENV, "PATH": f"{Path(sys.executable).parent}:/usr/bin:/bin"})
    try:
        address = None
        deadline = time.time() + 30
        while time.time() < deadline and address is None:
            line = port_proc.stderr.readline()
            if "Scheduler at:" in line:
                address = line.split("Scheduler at:")[1].strip()
        assert address, "the scheduler did not start"
        spec = parse_sweep({"name": "nowork", "scenario": __import__("tomllib").loads(GOOD),
                            "grid": {"model.q": [0.5, 1.0]}, "quick": True}, base_dir=tmp_path)
        with pytest.raises(ScenarioError, match="no worker joined"):
            sw.run_sweep(spec, tmp_path, scheduler=address, log=lambda s: None, worker_timeout=3)
    finally:
        port_proc.terminate()
        port_proc.communicate(timeout=10)


def test_a_tampered_sweep_point_is_detected_and_recomputed(tmp_path):
    import dse.sweeps.run as sw
    from dse.sweeps.spec import parse_sweep

    spec = parse_sweep({"name": "tamper", "scenario": __import__("tomllib").loads(GOOD),
                        "grid": {"model.q": [0.5, 1.0]}, "quick": True}, base_dir=tmp_path)
    first = sw.run_sweep(spec, tmp_path, scheduler="inline", log=lambda s: None)
    assert first["ran"] == 2
    results = sorted(sw.points_dir(tmp_path, "tamper").glob("*/result.json"))
    doc = json.loads(results[0].read_text())
    doc["result"]["metrics"] = {k: v * 2 for k, v in doc["result"]["metrics"].items()} or {"x": 1.0}
    results[0].write_text(json.dumps(doc))   # a changed value, checksum left as it was
    results[1].write_text("{}")              # an empty point file
    again = sw.run_sweep(spec, tmp_path, scheduler="inline", log=lambda s: None)
    assert again["ran"] == 2 and again["reused"] == 0
    assert sw.verify_sweep(tmp_path / "sweep" / "tamper")[0] == []
