"""random-comm-filter numbers its nodes 0..N−1 in figures and recordings, as its tables and every other family do
(its figures and recordings said 1..N)."""
import numpy as np
import pandas as pd

from dse.families.tanwani import figures as rcf_figures
from dse.families.tanwani import recording as rcf_recording


class FakeTables:
    """The three tables the network figure and the network recording read, for a 3-node line."""

    N, main_rate, title = 3, 2.0, "three nodes"

    def __init__(self):
        self.frames = {"graph_nodes": pd.DataFrame({"x": [0.0, 1.0, 2.0], "y": [0.0, 0.0, 0.0]}),
                       "graph_edges": pd.DataFrame({"i": [0, 1], "j": [1, 2]}),
                       "path_events": pd.DataFrame({"path": [0, 0], "clock": [0, 1], "t": [0.1, 0.2],
                                                    "i": [0, 1], "j": [1, 2]})}

    def __getitem__(self, name):
        return self.frames[name]


def test_the_network_figure_labels_nodes_from_zero(tmp_path, monkeypatch):
    drawn = {}
    monkeypatch.setattr(rcf_figures, "_save", lambda fig, path, **kw: drawn.setdefault("fig", fig))
    rcf_figures.fig1(FakeTables(), tmp_path / "f.png")
    graph, clocks = drawn["fig"].axes[:2]
    assert sorted(t.get_text() for t in graph.texts if t.get_text() != "plant") == ["0", "1", "2"]
    assert [t.get_text() for t in clocks.get_yticklabels()] == ["0–1", "1–2"]


def test_the_recording_labels_nodes_and_edges_from_zero(monkeypatch):
    logged = {"graph": [], "series": []}
    monkeypatch.setattr(rcf_recording.rec_, "log_graph",
                        lambda rec, entity, pos, edges, labels=None, **kw: logged["graph"].append(list(labels)))
    monkeypatch.setattr(rcf_recording.rec_, "send_series",
                        lambda rec, entity, idx, values, names=None, **kw: logged["series"].append((entity, names)))

    class Rec:
        def log(self, entity, value, static=False):
            logged.setdefault("log", []).append(value)

        def send_columns(self, *a, **kw):
            pass

    rcf_recording._log_network(Rec(), FakeTables())
    assert logged["graph"] == [["sensor 0", "sensor 1", "sensor 2"]]
    assert logged["series"] == [("events/edge_0_1", "edge 0–1"), ("events/edge_1_2", "edge 1–2")]
    assert np.all(np.asarray(logged["log"][0].labels.as_arrow_array().to_pylist()) == ["sensor 0", "sensor 1", "sensor 2"])
