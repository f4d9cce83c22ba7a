"""No raw warning or foreign log line reaches stderr: a number beyond what an output can hold is a
result (NaN where it cannot be drawn, the number in the tables), and a recording rerun could not
write is one error of ours, without rerun's own (coloured) log lines."""
import copy
import os
import subprocess
import sys
import textwrap
import warnings
from pathlib import Path

import numpy as np
import pytest

import dse
from dse.outputs import record

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))
from test_tran_pipeline import SMALL  # noqa: E402


def test_positions_beyond_float32_are_nan_without_a_cast_warning():
    import rerun as rr

    huge = np.array([[1e40, 1.0], [-1e300, np.inf], [2.0, 3.0]])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        safe = record.as_float32(huge)
        rr.Points2D.columns(positions=safe)
        record.display_positions(np.array([[0.0, 0.0], [1e100, 0.0], [1e100, 1e-300]]))
    assert safe.dtype == np.float32
    np.testing.assert_array_equal(np.isnan(safe), [[True, False], [True, True], [False, False]])
    assert (safe[2] == [2.0, 3.0]).all() and safe[0, 1] == 1.0


def test_coestimation_run_whose_plant_leaves_float32_draws_without_warnings(tmp_path):
    # an input offset of 1e40 is inside the documented magnitudes; rerun's float32 cast of the
    # positions in the plane overflowed ("RerunWarning: Vec2DBatch: overflow encountered in cast")
    data = copy.deepcopy(SMALL)
    data["name"], data["input"]["offset"] = "huge-input", [1e40]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        run = dse.run(data, quick=True, seed=2, workers=1)
        out = run.write(tmp_path / "huge-input")
    assert run.counts["error"] == 0 and list(out.glob("*.rrd"))


GOSSIP_OVERFLOW = """family = "gossip-kalman"
name = "km-overflow"
[model]
F = [[1e3, 0.0], [0.0, 1.1]]
Q = [[0.1, 0.0], [0.0, 0.1]]
P0 = [[1.0, 0.0], [0.0, 1.0]]
[sensors]
types = [0, 1, 0, 1]
C = [[[1.0, 0.0]], [[0.0, 1.0]]]
R = [[[1.0]], [[1.0]]]
[graph]
kind = "ring"
n = 4
[protocol]
kind = "single-edge"
edge_prob = 0.2
[simulation]
slots = 40
runs = 100
reference_runs = 100
quick_runs = 100
quick_reference_runs = 100
quick_slots = 40
record_times = [1, 2, 5, 10, 20, 40]
"""


def test_gossip_kalman_on_a_fast_unstable_plant_prints_no_numpy_warning(tmp_path, capfd):
    # a sensor's covariance grows by 1e6 per slot between gossip exchanges: the GIKF maps overflowed
    # and numpy printed "RuntimeWarning: overflow encountered in multiply" (gikf_maps.py) three times
    from dse.cli import main

    path = tmp_path / "km.toml"
    path.write_text(GOSSIP_OVERFLOW)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        code = main(["run", str(path), "--quick", "--workers", "1", "--no-figures", "--out", str(tmp_path / "out")])
    err = capfd.readouterr().err
    assert code == 0 and "Warning" not in err, err


def test_recording_rerun_cannot_write_is_one_oserror_without_rust_log_lines(tmp_path):
    script = textwrap.dedent("""
        import resource, signal, sys
        import numpy as np
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)              # a write past the limit fails with EFBIG
        resource.setrlimit(resource.RLIMIT_FSIZE, (20_000, 20_000))
        from dse.outputs import record
        import rerun.blueprint as rrb
        record.FLUSH_TIMEOUT_S = 2.0                                # the write fails either way
        try:
            with record.recording(sys.argv[1], application_id="t", recording_id="t", blueprint=rrb.Blueprint()) as rec:
                record.send_series(rec, "x", record.sequence_index("k", np.arange(50_000)), np.linspace(0, 1, 50_000))
            print("written")
        except OSError as exc:
            print("OSError", exc.filename)
    """)
    env = {k: v for k, v in os.environ.items() if k != "RUST_LOG"} | {"PYTHONPATH": str(ROOT)}
    proc = subprocess.run([sys.executable, "-c", script, str(tmp_path / "r.rrd")], capture_output=True, text=True,
                          env=env, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.startswith("OSError") and ".tmp.rrd" in proc.stdout
    assert proc.stderr == "", proc.stderr                       # no "ERROR re_log_encoding::rrd::file_sink" lines
    assert not list(tmp_path.iterdir())                         # the temporary file is removed, nothing renamed


def test_complete_recording_passes_and_a_truncated_one_is_refused(tmp_path):
    import rerun.blueprint as rrb

    path = tmp_path / "r.rrd"
    with record.recording(path, application_id="t", recording_id="t", blueprint=rrb.Blueprint()) as rec:
        record.send_series(rec, "x", record.sequence_index("k", np.arange(100)), np.arange(100.0))
    record.check_complete(path)
    (tmp_path / "cut.rrd").write_bytes(path.read_bytes()[:-20])
    with pytest.raises(OSError, match="the recording is incomplete: no footer"):
        record.check_complete(tmp_path / "cut.rrd")


def test_family_tables_with_an_overflowing_column_hold_inf_without_warnings(monkeypatch):
    # a derived column that overflows or divides by zero (seen in gossip-kalman's and coestimation's
    # tables) printed numpy RuntimeWarnings; it now holds inf or NaN
    import pandas as pd

    repro = dse.load(ROOT / "dse" / "families" / "template" / "example.toml")

    def tables(run, results):
        mean = np.array([1e200, 1.0])
        yield "t", pd.DataFrame({"var": mean**2 - mean**2, "ratio": np.array([1.0, 0.0]) / np.array([0.0, 0.0])})

    monkeypatch.setattr(repro.family, "tables", tables)
    monkeypatch.setattr(repro.family, "design_tables", tables)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        (name, frame), = repro.tables(None)
        repro.design_tables(None)
    assert np.isnan(frame["var"][0]) and np.isinf(frame["ratio"][0]) and np.isnan(frame["ratio"][1])
