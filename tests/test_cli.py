"""The command line end to end: bad input, a user's scenario, verify from the cache, the paper in quick mode."""
import contextlib
import io
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import rerun as rr

from dse import cli
from dse.outputs import record

DSE = [sys.executable, "-m", "dse.cli"]
ROOT = Path(__file__).resolve().parent.parent
RERUN = Path(sys.executable).parent / "rerun"

GOOD = """
family = "noisy-consensus-filter"
name = "ring5"
[graph]
kind = "ring"
n = 5
[consensus]
weights = "metropolis"
[model]
q = 0.5
r = 4.0
sigma0 = 2.0
[sweep]
rounds = [0, 1, 3]
sigma_c = [0.0, 0.7]
n_steps = 6
eval_step = 3
[carli]
ell = 0.4
[gains]
rounds_max = 4
grid = [41, 41]
[monte_carlo]
trials = 4000
sample_paths = 2
"""


def dse(*args, cwd):
    return subprocess.run([*DSE, *args], cwd=cwd, capture_output=True, text=True, timeout=600,
                          env={"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin", "DSE_PROGRESS": "0"})


def dse_here(*args, cwd) -> subprocess.CompletedProcess:
    """`dse ARGS` run in `cwd` by the command's entry point in this process (`cli.main`, which `python -m dse.cli`
    exits with), its output captured: for the tests about what a command computes and writes. A fresh interpreter
    per command would only repeat the imports (about 1 s of CPU a run); what reaches a shell through a real process
    (exit codes, one line, signals, a killed run's files) is tested with `dse`."""
    out, err = io.StringIO(), io.StringIO()
    with pytest.MonkeyPatch.context() as patch, contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        patch.chdir(cwd)
        patch.setenv("DSE_PROGRESS", "0")
        code = cli.main([str(a) for a in args])   # an exception escaping main fails the test too
    return subprocess.CompletedProcess(["dse", *args], code, out.getvalue(), err.getvalue())


def sigint_as_from_a_terminal() -> None:
    """`preexec_fn` of a `dse` that a test interrupts with SIGINT: the signal's default action, as under a terminal.
    A shell that starts `make test` in the background (no job control) ignores SIGINT, its children inherit that,
    and Python then installs no KeyboardInterrupt handler: the Ctrl-C test waited for its 2,000,000 trials and
    failed, and test_faults' SIGINT case passed as 'finished before the signal'."""
    import signal

    signal.signal(signal.SIGINT, signal.SIG_DFL)


def edit(text, old, new):
    assert old in text, old
    return text.replace(old, new, 1)


BAD = [
    (lambda t: edit(t, "r = 4.0", "r = -4.0"), "model.r: must be >"),
    (lambda t: edit(t, "r = 4.0", "r = nan"), "model.r: must be finite"),
    (lambda t: edit(t, "q = 0.5", "q = \"half\""), "model.q: must be a number"),
    (lambda t: edit(t, "q = 0.5", "q = 0.5\nqq = 1"), "model.qq: unknown key"),
    (lambda t: edit(t, "kind = \"ring\"\nn = 5", "kind = \"edges\"\nn = 4\nedges = [[0, 1], [2, 3]]"), "graph: graph is not connected"),
    (lambda t: edit(t, "kind = \"ring\"\nn = 5", "kind = \"edges\"\nn = 3\nedges = [[0, 1], [1, 1]]"), "graph.edges[1]: self-loop"),
    (lambda t: edit(t, "weights = \"metropolis\"", "weights = \"matrix\"\nmatrix = [[0.5,0.5,0,0,0],[0.5,0.5,0,0,0],[0,0,1,0,0],[0,0,0,1,0],[0,0,0,0,1]]"),
     "consensus.matrix: must be primitive"),
    (lambda t: edit(t, "weights = \"metropolis\"", "weights = \"matrix\"\nmatrix = [[0.5,0,0,0,0.5],[0.5,0.5,0,0,0],[0,0.5,0.5,0,0],[0,0,0.5,0.5,0],[0,0,0,0.5,0.5]]\n"),
     "reinjection.gains: optimal gains use eq. (16)"),
    (lambda t: edit(t, "weights = \"metropolis\"", "weights = \"matrix\"\nmatrix = [[0.5,0.5,0,0,0],[0.5,0.5,0,0,0]]"),
     "consensus.matrix: must have shape 5x5"),
    (lambda t: edit(t, "weights = \"metropolis\"", "weights = \"matrix\"\nmatrix = [[0.6,0.4,0,0,0],[0.5,0.5,0,0,0],[0,0,1,0,0],[0,0,0,1,0],[0,0,0,0,1]]"),
     "consensus.matrix: columns must sum to 1"),
    (lambda t: edit(t, "weights = \"metropolis\"", "weights = \"laplacian\"\neps = 0.6"), "consensus.eps: must be < 1/d_max"),
    (lambda t: edit(t, "ell = 0.4", "ell = 1.5"), "carli.ell: must be <= 1"),
    (lambda t: edit(t, "rounds = [0, 1, 3]", "rounds = [0, 3, 1]"), "sweep.rounds: must be strictly increasing"),
    (lambda t: edit(t, "eval_step = 3", "eval_step = 6"), "sweep.eval_step: must be < n_steps"),
    (lambda t: edit(t, "family = \"noisy-consensus-filter\"", "family = \"nope\""), "family: must be one of"),
    (lambda t: edit(t, "[model]", "[modle]"), "modle: unknown key"),
    (lambda t: "", "empty scenario file"),
    (lambda t: t[:40], "invalid TOML"),
]


@pytest.mark.parametrize("mutate, message", BAD, ids=[m for _, m in BAD])
def test_bad_scenario_one_line_exit_2_no_output(tmp_path, monkeypatch, capsys, mutate, message):
    """`dse run` as the command's entry point runs it (`cli.main`, which `python -m dse.cli` exits with), in this
    process: each case is a message of the loader, and a fresh interpreter per case would only repeat the imports.
    That the exit code and the one line reach a shell through a real process is checked below (binary garbage,
    an unwritable output, test_faults.py)."""
    scenario = tmp_path / "s.toml"
    scenario.write_text(mutate(GOOD))
    out = tmp_path / "out"
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("DSE_PROGRESS", "0")
    capsys.readouterr()
    code = cli.main(["run", str(scenario), "--out", str(out)])   # an exception escaping main fails the test too
    std = capsys.readouterr()
    assert code == 2, std.err
    lines = std.err.strip().splitlines()
    assert len(lines) == 1 and message in lines[0] and "Traceback" not in std.err, std.err
    assert std.out == ""
    assert not out.exists()


def test_binary_garbage_is_rejected(tmp_path):
    scenario = tmp_path / "s.toml"
    scenario.write_bytes(bytes(range(256)) * 4)
    proc = dse("run", str(scenario), "--out", str(tmp_path / "out"), cwd=tmp_path)
    assert proc.returncode == 2 and "UTF-8" in proc.stderr and not (tmp_path / "out").exists()


def test_list(tmp_path):
    proc = dse_here("list", cwd=tmp_path)
    assert proc.returncode == 0 and "savas" in proc.stdout and "savas.thm1.ii" in proc.stdout


@pytest.fixture(scope="module")
def user_run(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("user")
    (tmp / "s.toml").write_text(GOOD)
    proc = dse_here("run", "s.toml", "--out", "out", "--seed", "3", cwd=tmp)
    assert proc.returncode == 0, proc.stderr
    return tmp / "out"


def test_user_scenario_report(user_run):
    report = json.loads((user_run / "run" / "ring5" / "report.json").read_text())
    verdicts = {c["id"]: c["verdict"] for c in report["claims"]}
    assert report["provenance"]["seed"] == 3 and report["provenance"]["trials"] == 4000
    # paper-only reference tables are not applied to a user's scenario
    assert "ring5.fig1.values" not in verdicts
    for claim in ("ring5.thm1.i", "ring5.thm1.ii", "ring5.mc.trace", "ring5.mc.per_agent", "ring5.reference.filterpy",
                  "ring5.reference.kf_lower_bound", "ring5.proof.pathwise", "ring5.carli.closed_form"):
        assert verdicts[claim] in ("pass", "erratum"), (claim, verdicts[claim])
    assert verdicts["ring5.thm1.ii"] == "erratum"


def test_user_scenario_recordings(user_run):
    d = user_run / "run" / "ring5"
    for rrd in ("ring5.rrd", "ring5_figures.rrd"):
        proc = subprocess.run([str(RERUN), "rrd", "verify", str(d / rrd)], capture_output=True, text=True, timeout=120)
        assert proc.returncode == 0, proc.stderr
    scalars = record.read_scalars(d / "ring5.rrd", "k")
    k, trace = scalars["/bounds/carli/trace"]
    assert np.array_equal(k, np.arange(6)) and trace.shape == (6, 1)
    edges = record.read_static(d / "ring5.rrd", "/graph")["GraphEdges:edges"]
    assert len(edges) == 5
    kinds = record.blueprint_view_kinds(d / "ring5.rrd")
    assert "TimeSeries" in kinds and "Graph" in kinds and "TextDocument" in kinds
    for rrd in ("ring5.rrd", "ring5_figures.rrd"):   # named after the user's family and scenario, not the paper
        (store,) = rr.chunk.RrdReader(str(d / rrd)).recordings()
        assert store.application_id == "dse-noisy-consensus-filter", store
        assert store.recording_id.startswith("noisy-consensus-filter-ring5-"), store
    for fig in ("fig1.png", "fig2.png", "fig3.png"):
        assert (d / "figures" / fig).stat().st_size > 10_000


def test_verify_from_cache_matches(user_run, tmp_path):
    proc = dse_here("verify", str(user_run / "run" / "ring5"), cwd=tmp_path)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "differs" not in proc.stdout


def test_same_seed_same_numbers_different_seed_different(user_run, tmp_path):
    (tmp_path / "s.toml").write_text(GOOD)
    # the numbers only (figures and recordings are drawn from them, and the fixture's run drew them)
    same = dse_here("run", "s.toml", "--out", "o1", "--seed", "3", "--no-figures", cwd=tmp_path)
    other = dse_here("run", "s.toml", "--out", "o2", "--seed", "4", "--no-figures", cwd=tmp_path)
    assert same.returncode == 0 and other.returncode == 0

    def numbers(path):
        return {c["id"]: c.get("measured") for c in json.loads(path.read_text())["claims"]}

    first = numbers(user_run / "run" / "ring5" / "report.json")
    again = numbers(tmp_path / "o1" / "run" / "ring5" / "report.json")
    changed = numbers(tmp_path / "o2" / "run" / "ring5" / "report.json")
    assert first == again
    assert first["ring5.mc.trace"] != changed["ring5.mc.trace"]


def test_unwritable_output_fails_before_computing(tmp_path):
    (tmp_path / "s.toml").write_text(GOOD)
    blocker = tmp_path / "file"
    blocker.write_text("x")
    proc = dse("run", "s.toml", "--out", str(blocker), cwd=tmp_path)
    assert proc.returncode == 2 and "is a file, not a directory" in proc.stderr, proc.stderr


def test_paper_quick(tmp_path):
    proc = dse_here("reproduce", "savas", "--quick", "--trials", "4000", "--out", "out", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    d = tmp_path / "out" / "savas"
    report = json.loads((d / "report.json").read_text())
    verdicts = {c["id"]: c["verdict"] for c in report["claims"]}
    # the paper's errors documented in docs/papers/savas.md show up as errata with both numbers
    for claim in ("savas.thm1.ii", "savas.proof.eq24", "savas.fig2.zeta_nonmonotone"):
        assert verdicts[claim] == "erratum"
    row = next(c for c in report["claims"] if c["id"] == "savas.thm1.ii")
    assert row["printed"] is not None and row["corrected"] is not None
    for claim in ("savas.fig1.values", "savas.fig3.values", "savas.fig2.values", "savas.thm1.i", "savas.mc.trace"):
        assert verdicts[claim] == "pass", (claim, verdicts[claim])
    for fig in ("fig1.png", "fig2.png", "fig3.png"):
        assert (d / "figures" / fig).exists()
    assert (tmp_path / "out" / "summary.md").read_text().count("savas") >= 1


NONSYMMETRIC = """
family = "noisy-consensus-filter"
name = "nonsym4"
[graph]
kind = "complete"
n = 4
[consensus]
weights = "matrix"
matrix = [[0.5, 0.5, 0.0, 0.0], [0.0, 0.2, 0.8, 0.0], [0.3, 0.0, 0.2, 0.5], [0.2, 0.3, 0.0, 0.5]]
[model]
q = 1.0
r = 10.0
[sweep]
rounds = [0, 2]
sigma_c = [0.0, 1.0]
n_steps = 5
eval_step = 3
[reinjection]
gains = "fixed"
ell = 0.3
zeta = 0.2
[monte_carlo]
trials = 3000
"""


def test_nonsymmetric_consensus_matrix_runs_with_modal_claims_not_checkable(tmp_path):
    (tmp_path / "s.toml").write_text(NONSYMMETRIC)
    proc = dse_here("run", "s.toml", "--out", "out", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    claims = {c["id"]: c for c in json.loads((tmp_path / "out/run/nonsym4/report.json").read_text())["claims"]}
    assert claims["nonsym4.thm1.ii"]["verdict"] == "not-checkable" and "symmetric" in claims["nonsym4.thm1.ii"]["detail"]
    for cid in ("nonsym4.thm1.i", "nonsym4.mc.trace", "nonsym4.mc.per_agent", "nonsym4.reference.kf_lower_bound"):
        assert claims[cid]["verdict"] == "pass", cid
    assert not (tmp_path / "out/run/nonsym4/figures/fig2.png").exists()


def _measured(path):
    return [c.get("measured") for c in json.loads(path.read_text())["claims"]]


def test_workers_do_not_change_numbers(user_run, tmp_path):
    (tmp_path / "s.toml").write_text(GOOD)
    proc = dse_here("run", "s.toml", "--out", "o", "--seed", "3", "--workers", "1", "--no-figures", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert _measured(tmp_path / "o/run/ring5/report.json") == _measured(user_run / "run/ring5/report.json")


@pytest.mark.parametrize("delay", [0.8, 2.0])
def test_sigkill_then_resume_gives_the_same_numbers(user_run, tmp_path, delay):
    import signal
    import time

    (tmp_path / "s.toml").write_text(GOOD)
    env = {"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin", "DSE_PROGRESS": "0"}
    proc = subprocess.Popen([*DSE, "run", "s.toml", "--out", "o", "--seed", "3"], cwd=tmp_path, env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    time.sleep(delay)
    os_kill = __import__("os").killpg
    try:
        os_kill(proc.pid, signal.SIGKILL)
    except ProcessLookupError:
        pass
    proc.wait()
    out = tmp_path / "o/run/ring5"
    for path in out.glob("*.json"):  # anything at a final path is complete
        json.loads(path.read_text())
    for path in out.glob("*.rrd"):
        assert subprocess.run([str(RERUN), "rrd", "verify", str(path)], capture_output=True).returncode == 0
    again = dse_here("run", "s.toml", "--out", "o", "--seed", "3", cwd=tmp_path)   # resumed by another process
    assert again.returncode == 0, again.stderr
    assert _measured(out / "report.json") == _measured(user_run / "run/ring5/report.json")


def test_ctrl_c_stops_cleanly_with_130(tmp_path):
    """Ctrl-C in the middle of a simulation: exit 130, one line, no report. The signal is sent once the run shows
    progress (an event, not a fixed sleep: on a loaded machine the start-up alone can take seconds)."""
    import os
    import signal
    import threading

    (tmp_path / "s.toml").write_text(GOOD.replace("trials = 4000", "trials = 2000000"))
    env = {"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin", "DSE_PROGRESS": "1"}
    proc = subprocess.Popen([*DSE, "run", "s.toml", "--out", "o"], cwd=tmp_path, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, start_new_session=True,
                            preexec_fn=sigint_as_from_a_terminal)
    err, started = bytearray(), threading.Event()

    def read_stderr():
        while chunk := os.read(proc.stderr.fileno(), 4096):
            err.extend(chunk)
            if b"%" in err:  # a progress bar is drawn: the run is computing
                started.set()
        started.set()

    reader = threading.Thread(target=read_stderr, daemon=True)
    reader.start()
    assert started.wait(timeout=600), "no progress shown"
    os.killpg(proc.pid, signal.SIGINT)  # as a terminal's Ctrl-C: the whole process group
    proc.wait(timeout=600)
    reader.join(timeout=60)
    proc.stdout.close()
    proc.stderr.close()
    text = err.decode(errors="replace")
    assert proc.returncode == 130, text
    assert text.strip().splitlines()[-1] == "dse: interrupted" and "Traceback" not in text
    assert not (tmp_path / "o/run/ring5/report.json").exists()


def test_an_interrupt_inside_code_run_by_exec_still_exits_130(tmp_path):
    """A Ctrl-C whose KeyboardInterrupt leaves code run by `exec` of a string (dataclasses build their methods so,
    during an import, say) made `python -m dse.cli` die of SIGINT (status -2) after printing 'dse: interrupted':
    CPython kept that interrupt marked as unhandled although main caught it (seen in test_faults' SIGINT case on a
    loaded machine, 8 times in 40). Here the interrupt is raised so, deterministically: the registry `dse list`
    reads is replaced, before the command runs, by one that raises it inside exec."""
    (tmp_path / "sitecustomize.py").write_text(
        "import dse.registry\n"
        "def interrupted(*args, **kwargs):\n"
        "    exec('raise KeyboardInterrupt')\n"
        "dse.registry.families = interrupted\n")
    proc = subprocess.run([*DSE, "list"], cwd=tmp_path, capture_output=True, text=True, timeout=120,
                          env={"PYTHONPATH": f"{tmp_path}:{ROOT}", "PATH": "/usr/bin:/bin"})
    assert proc.returncode == 130, (proc.returncode, proc.stderr)
    assert proc.stderr.strip().splitlines()[-1] == "dse: interrupted"


def test_a_reader_that_goes_away_stops_the_listing_quietly():
    """`dse list | head -1`: no traceback, no 'cannot use the file system', exit 141 as SIGPIPE would give."""
    proc = subprocess.Popen([sys.executable, "-m", "dse.cli", "list"], cwd=ROOT, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, env={"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin"})
    assert proc.stdout.readline()
    proc.stdout.close()
    rc = proc.wait(timeout=120)
    err = proc.stderr.read().decode()
    proc.stderr.close()
    assert rc == 141 and err == "", (rc, err)
