"""The report site (`dse site`, dse/site/): built from a small synthetic output root written in the
documented layout (docs/output.md), so that every test takes a fraction of a second. The browser test
of a real reproduction's site is `make check-site` (dse/site/browser_check.py)."""
from __future__ import annotations

import json
import os
import re
import tomllib
from pathlib import Path

import pytest

from dse import cli
from dse.outputs.tables import CSV_CELLS, Tables, spec
from dse.site import build as site_build
from dse.site import pages, tables as site_tables
from dse.site.build import build
from dse.site.staging import MANIFEST
from dse.site.viewer import viewer_assets

ROOT = Path(__file__).resolve().parents[1]
PNG = bytes.fromhex("89504e470d0a1a0a0000000d4948445200000001000000010806000000"
                    "1f15c4890000000d49444154789c6360000002000001e221bc330000000049454e44ae426082")


def claim(id, verdict, margin=1.0, source="§1", **extra):
    row = {"id": id, "source": source, "statement": f"statement of {id}", "kind": "inequality", "scope": "family",
           "hypotheses": [], "verdict": verdict, "measured": 1.5, "reference": 1.0, "tolerance": 1e-9,
           "margin": margin, "confidence": None, "trials": None, "printed": None, "corrected": None,
           "detail": f"how {id} was checked"}
    return {**row, **extra}


def write_run(directory: Path, paper: str, claims: list[dict], nodes_rows: int = 4) -> None:
    """A run directory as `dse reproduce` writes it: report.json, run.json, tables, a figure, a recording."""
    counts = {v: sum(c["verdict"] == v for c in claims) for v in ("pass", "fail", "erratum", "not-checkable", "error")}
    report = {"paper": paper, "title": f"{paper} title", "counts": counts,
              "hypotheses": [{"id": f"{paper}.hyp", "statement": "a hypothesis", "holds": True, "value": 0.0,
                              "threshold": 1e-10, "detail": "held", "error": ""},
                             {"id": f"{paper}.control", "statement": "broken on purpose", "holds": False, "value": 1.0,
                              "threshold": 1e-10, "detail": "a negative control", "error": "", "expected": False}],
              "statistics": {}, "omitted_paper_example_claims": [], "claims": claims,
              "provenance": {"seed": 0, "trials": 10, "quick": True, "workers": 1, "versions": {"dse": "0.1.0"},
                             "git": "abc", "compute_s": 0.5, "write_s": 0.1, "wall_s": 0.7, "stages": []}}
    (directory / "figures").mkdir(parents=True)
    (directory / "report.json").write_text(json.dumps(report))
    (directory / "run.json").write_text(json.dumps({"paper": paper, "scenario": None}))
    (directory / "figures" / "tails_e1.png").write_bytes(PNG)
    (directory / "figures" / "fig2.png").write_bytes(PNG)
    (directory / "e1.rrd").write_bytes(b"not opened by these tests")
    t = Tables()
    t.add(spec("claims", "claim", [("id", "", "claim id"), ("verdict", "", "the verdict")]),
          {"id": [c["id"] for c in claims], "verdict": [c["verdict"] for c in claims]})
    t.add(spec("nodes", "node of a scenario", [("scenario", "", "scenario name"), ("node", "", "node index"),
                                               ("mse", "m²", "mean-square error")], description="per node"),
          {"scenario": ["e1"] * (nodes_rows // 2) + ["e2"] * (nodes_rows // 2), "node": list(range(nodes_rows)),
           "mse": [float("nan")] + [0.5] * (nodes_rows - 1)})
    t.write(directory / "tables")


def write_sweep(directory: Path) -> None:
    import pyarrow as pa
    import pyarrow.parquet as pq

    directory.mkdir(parents=True)
    meta = {"name": "tiny-sweep", "family": "template", "scheduler": "inline", "workers": 1, "points": 2,
            "failures": 0, "wall_s": 1.0,
            "sweep": {"name": "tiny-sweep", "description": "two points", "seed": 0, "replicates": 1, "quick": True,
                      "grid": {"model.r": [1.0, 2.0]}}}
    (directory / "sweep.json").write_text(json.dumps(meta))
    (directory / "sweep.png").write_bytes(PNG)
    pq.write_table(pa.table({"point": [0, 1], "model.r": [1.0, 2.0], "status": ["ok", "ok"]}),
                   directory / "results.parquet")
    pq.write_table(pa.table({"point": [0, 1], "claim": ["t.rate", "t.rate"], "statement": ["rate holds"] * 2,
                             "verdict": ["pass", "fail"], "margin": [0.1, -0.2], "detail": ["ok", "too slow"]}),
                   directory / "claims.parquet")


@pytest.fixture()
def out(tmp_path, monkeypatch):
    """A small output root; its sites are built without the web viewer's 67 MB (test_viewer_... adds it)."""
    monkeypatch.setattr(site_build, "viewer_assets", lambda: ({}, ""))
    root = tmp_path / "out"
    write_run(root / "paper-a", "paper-a", [claim("a.ok", "pass"), claim("a.tails.e1", "fail", margin=-0.25),
                                             claim("a.fig", "erratum", source="Fig. 2", printed=3.0, corrected=2.0)])
    write_run(root / "run" / "mine", "mine", [claim("mine.ok", "pass")])
    write_sweep(root / "sweep" / "tiny-sweep")
    return root


def page(site: Path, rel: str) -> str:
    return (site / rel).read_text()


def test_index_lists_every_run_and_sweep_with_counts_and_the_failures_first(out):
    result = build(out)
    html = page(result.site, "index.html")
    for href in ("paper-a/index.html", "run-mine/index.html", "sweep-tiny-sweep/index.html"):
        assert f'href="{href}"' in html
    assert html.index("Failed claims") < html.index("Papers and runs")
    assert 'href="paper-a/index.html#claim-a.tails.e1"' in html
    assert html.count("data-claim ") == 4                       # every claim of every run, for the filter
    assert 'href="paper-a/index.html#fig-tails_e1.png"' in html    # and its evidence, from the index too
    assert 'href="paper-a/table-nodes.html#scenario=e1"' in html
    assert 'href="paper-a/index.html?recording=e1.rrd#rec-e1.rrd"' in html


def test_run_page_shows_a_fail_first_with_its_evidence_one_click_away(out):
    html = page(build(out).site, "paper-a/index.html")
    failures = html[html.index('id="failures"'):html.index('id="claims"')]
    assert "a.tails.e1" in failures and "-0.25" in failures
    assert 'href="#fig-tails_e1.png"' in failures                   # the scenario's figure
    assert 'href="table-nodes.html#scenario=e1"' in failures        # the scenario's rows
    assert 'href="table-claims.html#id=a.tails.e1"' in failures     # the claim's own row
    assert 'data-entity="/claims/a.tails.e1"' in failures and 'data-rrd="e1.rrd"' in failures
    rows = re.findall(r'<tr class="claim (\S+)" id="claim-', html)
    assert rows == ["fail", "erratum", "pass"]                      # worst verdict first
    assert "as printed: 3; corrected: 2" in html                    # an erratum's two numbers
    assert "does not hold (expected)" in html and ">holds<" in html  # a negative control is not a failure
    assert 'href="#fig-fig2.png"' in html                           # "Fig. 2" in the source links the figure
    assert 'id="fig-tails_e1.png"' in html and (out / "paper-a/figures/tails_e1.png").exists()


def test_table_page_has_units_definitions_downloads_and_the_rows(out):
    site = build(out).site
    html = page(site, "paper-a/table-nodes.html")
    assert "mean-square error" in html and "m²" in html and "node of a scenario" in html
    assert 'href="tables/nodes.parquet"' in html and 'href="tables/nodes.csv"' in html
    data = json.loads(re.search(r'<script type="application/json" id="table-data">(.*?)</script>', html, re.S)[1])
    assert [c["name"] for c in data["columns"]] == ["scenario", "node", "mse"]
    assert data["rows"][0] == ["e1", 0, "nan"] and len(data["rows"]) == 4
    assert (site / "paper-a/tables/nodes.parquet").exists() and (site / "paper-a/tables/nodes.csv").exists()
    assert (site / "static/vendor/tabulator/tabulator.min.js").exists()


def test_a_large_table_shows_its_first_rows_and_offers_no_csv_it_does_not_have(out, monkeypatch):
    big = CSV_CELLS // 3 + 2                                          # too many cells for a CSV twin
    write_run(out / "big", "big", [claim("big.ok", "pass")], nodes_rows=big)
    monkeypatch.setattr(site_tables, "BROWSE_ROWS", 100)
    html = page(build(out).site, "big/table-nodes.html")
    assert f"{big} rows: 100 are shown here (the first ones of each of its 2 scenarios)" in html
    rows = json.loads(re.search(r'id="table-data">(.*?)</script>', html, re.S)[1])["rows"]
    assert [r[0] for r in rows] == ["e1"] * 50 + ["e2"] * 50         # both scenarios' first rows, in table order
    assert "tables/nodes.csv" not in html and "CSV of the rows shown" in html


def test_sweep_page_has_the_figure_verdicts_per_point_and_the_results_table(out):
    site = build(out).site
    html = page(site, "sweep-tiny-sweep/index.html")
    assert 'src="sweep.png"' in html and 'href="table-results.html"' in html
    assert 'class="cell pass"' in html and 'class="cell fail"' in html and "too slow" in html
    assert 'data-verdict="fail pass"' in html                         # the filter finds the claim under either verdict
    assert (site / "sweep-tiny-sweep/results.parquet").exists()
    assert "model.r" in page(site, "sweep-tiny-sweep/table-results.html")


def test_a_page_whose_inputs_did_not_change_is_not_rewritten(out):
    site = build(out).site
    before = {p: (p.stat().st_ino, p.stat().st_mtime_ns) for p in site.rglob("*.html")}
    again = build(out)
    assert again.written == [] and len(again.skipped) == len(before)
    assert {p: (p.stat().st_ino, p.stat().st_mtime_ns) for p in site.rglob("*.html")} == before
    report = out / "run/mine/report.json"
    report.write_text(report.read_text().replace("statement of mine.ok", "a new statement"))
    changed = build(out)
    assert sorted(changed.written) == ["index.html", "run-mine/index.html"]
    assert "index.html" in build(out).skipped
    (out / "paper-a/figures/tails_e1.png").unlink()               # evidence gone: the run page and the index change
    assert sorted(build(out).written) == ["index.html", "paper-a/index.html"]
    assert "#fig-tails_e1.png" not in page(site, "index.html")
    assert "a new statement" in page(site, "run-mine/index.html")


def test_a_failed_build_leaves_the_previous_site_whole(out, monkeypatch):
    site = build(out).site
    before = {p.relative_to(site): p.read_bytes() for p in site.rglob("*") if p.is_file()}
    (out / "run/mine/report.json").write_text((out / "run/mine/report.json").read_text().replace("mine.ok", "x"))

    def broken(*a, **k):
        raise RuntimeError("a template error")

    monkeypatch.setattr(pages, "run_page", broken)
    with pytest.raises(RuntimeError):
        build(out)
    assert {p.relative_to(site): p.read_bytes() for p in site.rglob("*") if p.is_file()} == before
    assert sorted(p.name for p in out.iterdir()) == ["paper-a", "run", "site", "sweep"]   # no staging left


def test_a_killed_build_leaves_nothing_behind_the_next_one(out):
    import subprocess
    import sys

    gone = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    pid = int(gone.stdout)                       # a process that has exited: its staging directory is stale
    stale = out / f"site.staging-{pid}"
    (stale / "paper-a").mkdir(parents=True)
    (stale / "paper-a" / "index.html").write_text("half written")
    build(out)
    assert not stale.exists() and sorted(p.name for p in out.iterdir()) == ["paper-a", "run", "site", "sweep"]


def test_a_removed_run_leaves_the_site(out):
    import shutil

    site = build(out).site
    shutil.rmtree(out / "run" / "mine")
    build(out)
    assert not (site / "run-mine").exists()
    assert "run-mine" not in json.loads((site / MANIFEST).read_text()).__repr__()


def test_viewer_files_come_from_the_rerun_notebook_of_the_pinned_version(out, monkeypatch):
    monkeypatch.setattr(site_build, "viewer_assets", viewer_assets)
    files, note = viewer_assets()
    if files:
        site = build(out).site
        assert {p.name for p in (site / "static/viewer").iterdir()} == {"widget.js", "widget.css", "re_viewer_bg.wasm"}
        assert 'data-rrd="e1.rrd"' in page(site, "paper-a/index.html")
    import importlib.metadata as md

    real = md.version
    monkeypatch.setattr(md, "version", lambda name: "0.1.0" if name == "rerun-notebook" else real(name))
    files, note = viewer_assets()
    assert not files and "does not match rerun-sdk" in note


def test_pins_of_the_viewer_agree_with_rerun_sdk_and_the_makefile():
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    sdk = next(d for d in project["dependencies"] if d.startswith("rerun-sdk=="))
    version = sdk.split("==")[1]
    makefile = (ROOT / "Makefile").read_text()
    assert f"rerun-notebook=={version}" in project["optional-dependencies"]["site"]
    assert f"rerun-notebook=={version}" in makefile
    assert all(pin in makefile for pin in project["optional-dependencies"]["browser"])


def test_the_browser_check_tells_a_blank_viewer_from_a_drawn_one_and_lists_every_page(out):
    import io

    from PIL import Image, ImageDraw

    from dse.site import browser_check

    def png(draw: bool) -> bytes:
        image = Image.new("RGB", (400, 300), (28, 28, 28))
        if draw:
            pen = ImageDraw.Draw(image)
            for i in range(40):
                pen.line([(0, 7 * i), (400, 300 - 5 * i)], fill=(6 * i, 255 - 6 * i, 120), width=3)
        buffer = io.BytesIO()
        image.save(buffer, format="PNG")
        return buffer.getvalue()

    assert browser_check.blank(png(False)) and not browser_check.blank(png(True))
    site = build(out).site
    listed = browser_check.site_pages(site)
    assert listed[0] == "index.html" and set(listed) == {p.relative_to(site).as_posix() for p in site.rglob("*.html")}


def test_cli_builds_the_site_and_refuses_a_missing_root(out, tmp_path, capsys):
    assert cli.main(["site", str(out), "--to", str(tmp_path / "web")]) == 0
    assert "pages written" in capsys.readouterr().out and (tmp_path / "web/index.html").exists()
    assert cli.main(["site", str(tmp_path / "nowhere")]) == 2
    assert "is not a directory" in capsys.readouterr().err and not (tmp_path / "nowhere").exists()
    assert cli.main(["site", str(out), "--to", str(out)]) == 2 and "would replace the output root" in capsys.readouterr().err
    other = tmp_path / "notes"
    other.mkdir()
    (other / "mine.txt").write_text("keep me")
    assert cli.main(["site", str(out), "--to", str(other)]) == 2 and "is not a site" in capsys.readouterr().err
    assert [p.name for p in other.iterdir()] == ["mine.txt"] and (out / "paper-a" / "report.json").exists()
    empty = tmp_path / "empty"
    empty.mkdir()
    assert cli.main(["site", str(empty)]) == 2 and "holds no run or sweep" in capsys.readouterr().err
    assert sorted(os.listdir(empty)) in ([], [".dse.lock"])
