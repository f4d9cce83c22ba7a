"""`[plot] metrics` naming metrics the points do not have: said in one accurate line and left out, or,
when none is left, the sweep is refused in one line (exit 2) instead of drawing a figure of nothing."""
from dse.cli import main

TEMPLATE = """name = "plot-none"
seed = 0
quick = true
trials = 200
[scenario]
family = "template"
graph = { kind = "ring", n = 4 }
model = { r = 1.0, rounds = 5 }
[grid]
"model.r" = [1.0, 2.0]
[plot]
metrics = ["kf_trP"]
"""

NOISY = """name = "plot-some"
seed = 0
quick = true
trials = 500
[scenario]
family = "noisy-consensus-filter"
graph = { kind = "ring", n = 3 }
model = { q = 1.0, r = 4.0 }
sweep = { rounds = [2], sigma_c = [0.5], n_steps = 4, eval_step = 2 }
[grid]
"model.r" = [4.0]
[plot]
metrics = ["carli_trP_typo", "kf_trP"]
"""


def test_no_metric_left_is_refused_in_one_line_and_draws_nothing(tmp_path, capsys):
    (tmp_path / "sweep.toml").write_text(TEMPLATE)
    assert main(["sweep", str(tmp_path / "sweep.toml"), "--scheduler", "inline", "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("dse: error: plot.metrics: kf_trP: not a metric of these points "
                                                   "(the points have no network-wide metric)")
    assert not (tmp_path / "out" / "sweep" / "plot-none").exists()


def test_unknown_metric_is_said_and_the_known_ones_are_plotted(tmp_path, capsys):
    (tmp_path / "sweep.toml").write_text(NOISY)
    assert main(["sweep", str(tmp_path / "sweep.toml"), "--scheduler", "inline", "--out", str(tmp_path / "out")]) == 0
    captured = capsys.readouterr()
    line = next((x for x in (captured.out + captured.err).splitlines() if "plot.metrics" in x), captured)
    assert "carli_trP_typo: not a metric of these points (the points' metrics are " in line
    assert "carli_trP_exact_per_agent" in line and line.endswith("plotting kf_trP only")
    assert (tmp_path / "out" / "sweep" / "plot-some" / "sweep.png").is_file()
