"""Figures of a user's run: hybrid-observer's Theorem-1 figure names the user's scenario and has no empty
panel when the scenario has no idealised run."""
import dse
from dse.families.wang_liu_morse import figures as wlm_figures

ONE_SYNC_RUN = {"family": "hybrid-observer", "name": "mine",
                "system": {"A": [[-0.2, 0.3], [0.0, 0.1]], "C": [[[1.0, -1.0]], [[0.0, 1.0]]]},
                "design": {"T": 0.5, "q": "theory", "lambda": 0.8, "lambda_bar": 1.2},
                "graphs": {"neighbors": [[[2], [1]]]},
                "initial": {"x0": [1.0, -2.0], "xhat0": [[0.0, 0.0], [0.5, 0.5]]},
                "monte_carlo": {"trials": 8, "quick_trials": 8},
                "runs": [{"name": "sync", "intervals": 12, "monte_carlo": True}]}


def test_hybrid_observer_bounds_figure_of_a_user_scenario(tmp_path, monkeypatch):
    run = dse.run(ONE_SYNC_RUN, quick=True)
    drawn = {}
    monkeypatch.setattr(wlm_figures, "_save", lambda fig, path, **kw: drawn.setdefault("fig", fig))
    (label,) = run.results.parts
    wlm_figures._bounds_figure(run.results, wlm_figures.TableView(run.tables), label, tmp_path / "f.png")
    axes = drawn["fig"].axes
    assert len(axes) == 1, "a panel is drawn for a run the scenario does not have"
    assert axes[0].get_title().startswith("mine/sync:"), axes[0].get_title()


def test_compare_legend_stays_inside_the_figure(tmp_path, monkeypatch):
    """Two columns of long labels below the error-against-communication panel once ran off the figure's left
    edge; the legend now starts at the axes' left edge."""
    from types import SimpleNamespace

    import pandas as pd

    from dse.estimators.network import registry
    from dse.families.compare import views as compare_views

    names = list(registry())
    estimators = pd.DataFrame({"estimator": names, "network_mse": [1.0 + i for i in range(len(names) - 1)] + [1e9],
                               "exact": True, "network_mse_mc_se": 0.0, "scalars_per_step": range(len(names))})
    applicability = pd.DataFrame({"estimator": names, "applies": True, "reason": ""})
    res = SimpleNamespace(scenario=SimpleNamespace(name="x", simulation=SimpleNamespace(eval_step=3),
                                                   links=SimpleNamespace(model="reliable", noise_std=1.0),
                                                   estimator_specs=registry()))
    drawn = {}
    monkeypatch.setattr(compare_views, "save_figure", lambda fig, path: drawn.setdefault("fig", fig))
    compare_views.error_vs_communication(res, {"estimators": estimators, "applicability": applicability},
                                         tmp_path / "f.png")
    fig = drawn["fig"]
    fig.tight_layout()
    fig.canvas.draw()
    box = fig.axes[0].get_legend().get_window_extent()
    assert box.x0 >= 0 and box.x1 <= fig.bbox.width, (box, fig.bbox)
