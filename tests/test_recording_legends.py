"""Legends of the recordings' time-series views (they covered 30-40 % of the plots in the viewer): in the upper
right corner, once per grid of the same plot per node, a family's own choice kept."""
from types import SimpleNamespace

import rerun as rr
import rerun.blueprint as rrb

from dse.contract.views import Outputs, place_legends, recording


def legend(view):
    found = view.properties.get("PlotLegend")
    return None if found is None else (found.corner, found.visible)


def test_a_grid_of_the_same_plot_per_node_shows_one_legend_in_a_corner():
    grid = rrb.Grid(*[rrb.TimeSeriesView(origin=f"/nodes/{i}", name=f"node {i}: error") for i in range(4)])
    place_legends([grid])
    shown = [bool(v.properties["PlotLegend"].visible.as_arrow_array().to_pylist()[0]) for v in grid.contents]
    assert shown == [True, False, False, False]
    corner = grid.contents[0].properties["PlotLegend"].corner.as_arrow_array().to_pylist()[0]
    assert corner == rrb.components.Corner2D.RightTop.value


def test_other_views_have_it_in_a_corner_and_a_familys_choice_is_kept():
    own = rrb.TimeSeriesView(origin="/a", name="a", plot_legend=rrb.PlotLegend(visible=False))
    mixed = rrb.Grid(rrb.TimeSeriesView(origin="/b", name="roles"), rrb.TimeSeriesView(origin="/c", name="bounds"))
    place_legends([rrb.Horizontal(own, mixed)])
    assert own.properties["PlotLegend"].corner is None
    for v in mixed.contents:
        assert v.properties["PlotLegend"].visible.as_arrow_array().to_pylist() == [True]


def test_every_recording_gets_the_placement(tmp_path):
    family = SimpleNamespace(id="template", paper=None)
    out = Outputs(reproduction=SimpleNamespace(family=family, is_paper=False, paper_id="mine"), results=None,
                  tables=None, claims=[])
    tabs = lambda: [rrb.Grid(*[rrb.TimeSeriesView(origin=f"/n/{i}", name=f"node {i}") for i in range(3)])]  # noqa
    recording(tmp_path / "r.rrd", out, recording_id="t", tabs=tabs, timeline="k", log=lambda rec: None)
    reader = rr.chunk.RrdReader(str(tmp_path / "r.rrd"))
    visible = []
    for chunk in reader.stream(store=reader.blueprints()[0]):
        for key, values in chunk.to_record_batch().to_pydict().items():
            if key.endswith("PlotLegend:visible"):
                visible += [bool(x[0]) for x in values if x]
    assert sorted(visible) == [False, False, True]


def test_the_claims_tab_is_one_view_of_one_document(tmp_path):
    """The claims tab had a second view over one document per claim, which rerun cannot show ("one text document
    at a time; was given 29"): one view of /report holds the table and every claim in full."""
    family = SimpleNamespace(id="template", paper=None)
    claims = [{"id": f"mine.c{i}", "verdict": "pass", "source": "eq. (1)", "statement": f"claim {i}", "measured": i,
               "reference": 0, "margin": 1, "detail": f"detail {i}"} for i in range(3)]
    out = Outputs(reproduction=SimpleNamespace(family=family, is_paper=False, paper_id="mine"), results=None,
                  tables=None, claims=claims)
    recording(tmp_path / "r.rrd", out, recording_id="t", tabs=lambda: [], timeline="k", log=lambda rec: None)
    from dse.outputs import record

    kinds = record.blueprint_view_kinds(tmp_path / "r.rrd")
    assert kinds.count("TextDocument") == 1
    reader = rr.chunk.RrdReader(str(tmp_path / "r.rrd"))
    documents = {c.entity_path for c in reader.stream().filter(is_static=True)
                 if any(k.endswith("TextDocument:text") for k in c.to_record_batch().to_pydict())}
    assert documents == {"/report"}
    text = record.read_static(tmp_path / "r.rrd", "/report")["TextDocument:text"][0]
    assert "| `mine.c2` | **pass**" in text and "detail 2" in text
