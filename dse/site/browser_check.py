"""The site in a real browser: `python -m dse.site.browser_check SITE [--screenshots DIR]` (`make check-site`).

Serves SITE over HTTP (as `python -m http.server` would) and loads every page in headless Chromium (Debian's
`chromium` package, driven by Playwright with that executable: no browser download), checking that

- no page logs a console error or an uncaught exception, and no request fails (nor answers 4xx/5xx);
- every image of every page loaded;
- every table page builds its table, and on one table page per run a click on a column header sorts it;
- the claim filter filters, on the index and on every run and sweep page (by verdict, by paper on the index,
  and by text);
- the index, a run page and a table page also work opened from file:// (no error, images and rows there);
- on one page per scenario family, the Rerun web viewer opens the page's first recording and renders it (a
  screenshot of the viewer that is not blank: many colours, no single colour covering almost all of it).

Prints one line per problem and exits 1 if there is any; screenshots of the index, a run page with a failed
claim, a table and every family's viewer go to DIR.
"""
from __future__ import annotations

import argparse
import functools
import http.server
import io
import re
import sys
import threading
import time
from pathlib import Path

CHROMIUM = "/usr/bin/chromium"
#: software WebGL (SwiftShader), which the viewer renders with on a machine without a GPU
CHROMIUM_ARGS = ["--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--ignore-gpu-blocklist"]
VIEWER_TIMEOUT_S = 180.0


class _Quiet(http.server.SimpleHTTPRequestHandler):
    def log_message(self, *args):
        pass


def serve(site: Path) -> tuple[http.server.ThreadingHTTPServer, str]:
    """The site on a free local port, served from a background thread; (server, base address)."""
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), functools.partial(_Quiet, directory=str(site)))
    threading.Thread(target=server.serve_forever, daemon=True).start()
    return server, f"http://127.0.0.1:{server.server_address[1]}/"


def watch(page, problems: list[str]) -> None:
    """Record console errors, uncaught exceptions and failed requests of `page` as problems."""
    where = lambda: page.url.split("/", 3)[-1]          # noqa: E731  (the page's path, at the time of the event)
    page.on("console", lambda m: m.type == "error" and problems.append(f"{where()}: console error: {m.text[:300]}"))
    page.on("pageerror", lambda e: problems.append(f"{where()}: uncaught: {e}"))
    page.on("requestfailed", lambda r: problems.append(f"{where()}: request failed: {r.url} ({r.failure})"))
    page.on("response", lambda r: r.status >= 400 and problems.append(f"{where()}: {r.status} for {r.url}"))


def broken_images(page) -> list[str]:
    return page.evaluate("Array.from(document.images).filter(i => !(i.complete && i.naturalWidth > 0))"
                         ".map(i => i.getAttribute('src'))")


def check_sort(page) -> str:
    """Click the header of a numeric column that is not in order yet; '' when the rows come out sorted."""
    fields = page.evaluate("""() => {
        const t = window.dseTable, num = (v) => typeof v === 'number';
        return t.getColumns().map(c => c.getField()).filter(f => {
            const v = t.getData().map(r => r[f]).filter(num);
            return v.length > 1 && v.some((x, i) => i > 0 && x < v[i - 1]);
        });
    }""")
    if not fields:
        return ""
    page.click(f'.tabulator-col[tabulator-field="{fields[0]}"] .tabulator-col-title')
    values = page.evaluate(f"window.dseTable.getRows('active').map(r => r.getData()['{fields[0]}'])"
                           ".filter(v => typeof v === 'number')")
    return "" if all(a <= b for a, b in zip(values, values[1:])) else f"clicking column {fields[0]} did not sort it"


_ROWS = "Array.from(document.querySelectorAll('[data-claim]'))"


def _filtered(page, field: str, value: str, matches) -> str:
    """Set one filter field; '' when exactly the rows `matches(row data)` accepts are shown, then clear it."""
    rows = page.evaluate(f"{_ROWS}.map(r => r.dataset)")
    if field == "text":
        page.fill("form.claim-filter input[name=text]", value)
    else:
        page.select_option(f"form.claim-filter select[name={field}]", value)
    shown = page.evaluate(f"{_ROWS}.map(r => !r.hidden)")
    expected = [bool(matches(r)) for r in rows]
    if field == "text":
        page.fill("form.claim-filter input[name=text]", "")
    else:
        page.select_option(f"form.claim-filter select[name={field}]", "")
    wrong = sum(a != b for a, b in zip(shown, expected))
    return "" if wrong == 0 and any(shown) else f"the {field} filter ({value}) shows {sum(shown)} rows, {wrong} wrongly"


def check_filter(page) -> str:
    """Filter the page's claims by the worst verdict present, by the first paper (on the index), and by a claim's
    id; '' when each shows exactly the rows it should."""
    if not page.query_selector("form.claim-filter") or not page.query_selector("[data-claim]"):
        return ""
    verdicts = {w for v in page.evaluate(f"{_ROWS}.map(r => r.dataset.verdict)") for w in v.split()}
    verdict = min(verdicts, key=lambda w: ("fail", "error", "erratum").index(w) if w in ("fail", "error", "erratum") else 9)
    problems = [_filtered(page, "verdict", verdict, lambda r: verdict in r["verdict"].split())]
    if page.query_selector("form.claim-filter select[name=paper]"):
        paper = page.evaluate("document.querySelector('[data-claim]').dataset.paper")
        problems.append(_filtered(page, "paper", paper, lambda r: r["paper"] == paper))
    text = page.evaluate("document.querySelector('[data-claim]').dataset.text.split(' ')[0]")
    problems.append(_filtered(page, "text", text, lambda r: text in r["text"]))
    return "; ".join(p for p in problems if p)


def blank(png: bytes) -> bool:
    """Whether a screenshot shows nothing: few colours, or one colour over 97% of it."""
    from PIL import Image

    image = Image.open(io.BytesIO(png)).convert("RGB").resize((320, 200))
    colours = image.getcolors(maxcolors=320 * 200) or []
    return len(colours) < 16 or max(n for n, _ in colours) > 0.97 * 320 * 200


def check_viewer(page, shot: Path | None) -> str:
    """Open the page's first recording in the web viewer; '' when the viewer reports the recording open (its
    `recording_open` event, sent once the file is loaded) and then draws it (a screenshot that is not blank)."""
    page.click("#recordings button.open-recording")
    try:
        page.wait_for_function("() => (window.dseViewerEvents || []).some(e => e.includes('\"recording_open\"'))",
                               timeout=VIEWER_TIMEOUT_S * 1000)
    except Exception as exc:        # playwright's TimeoutError
        return f"the web viewer did not open the recording within {VIEWER_TIMEOUT_S:.0f} s ({type(exc).__name__})"
    viewer = page.locator("#viewer")
    deadline = time.monotonic() + VIEWER_TIMEOUT_S
    while time.monotonic() < deadline:
        page.evaluate("() => new Promise(r => requestAnimationFrame(() => requestAnimationFrame(r)))")
        png = viewer.screenshot()
        if not blank(png):
            if shot:
                shot.write_bytes(png)
            return ""
    return f"the web viewer opened the recording but drew nothing for {VIEWER_TIMEOUT_S:.0f} s"


def site_pages(site: Path) -> list[str]:
    """Every page: the index, then each run's or sweep's page followed by its table pages."""
    out = ["index.html"]
    for d in sorted(p for p in site.iterdir() if (p / "index.html").exists()):
        out += [f"{d.name}/index.html"] + [f"{d.name}/{p.name}" for p in sorted(d.glob("table-*.html"))]
    return out


def _family(page) -> str:
    return page.evaluate("document.body.dataset.family || ''")


def check_page(page, base: str, rel: str, state: dict, shots: Path | None) -> list[str]:
    """Load one page and run the checks that apply to it; the problems found."""
    page.goto(base + rel, wait_until="load")
    found = [f"{rel}: image not loaded: {src}" for src in broken_images(page)]
    if "/table-" in rel:
        if page.evaluate("document.querySelectorAll('.tabulator-row').length") == 0 and "0 rows" not in page.content():
            found.append(f"{rel}: the table has no rows")
        if rel.split("/")[0] not in state["sorted"]:
            state["sorted"].add(rel.split("/")[0])
            found += [f"{rel}: {p}" for p in [check_sort(page)] if p]
        return found
    found += [f"{rel}: {p}" for p in [check_filter(page)] if p]
    family = _family(page)
    if family and family not in state["viewed"] and page.query_selector("#recordings button.open-recording"):
        state["viewed"].add(family)
        found += [f"{rel}: {p}" for p in [check_viewer(page, shots and shots / f"site-viewer-{family}.png")] if p]
    return found


def check_file_pages(page, site: Path) -> list[str]:
    """The index, a run page and a table page opened from file:// (no server): no errors, images and rows there."""
    pages = ["index.html"] + [p for p in site_pages(site) if p != "index.html"][:2]
    found = []
    for rel in pages:
        page.goto((site / rel).resolve().as_uri(), wait_until="load")
        found += [f"file://{rel}: image not loaded: {src}" for src in broken_images(page)]
        if "/table-" in rel and page.evaluate("document.querySelectorAll('.tabulator-row').length") == 0:
            found.append(f"file://{rel}: the table has no rows")
    return found


def _screenshots(page, base: str, site: Path, shots: Path) -> None:
    page.goto(base + "index.html", wait_until="load")
    page.screenshot(path=str(shots / "site-index.png"))
    failing = next((p.parent.name for p in sorted(site.glob("*/index.html")) if 'id="failures"' in p.read_text()), None)
    if failing:
        page.goto(base + f"{failing}/index.html", wait_until="load")
        page.screenshot(path=str(shots / "site-run-with-a-failure.png"))
        page.goto(base + f"{failing}/table-claims.html", wait_until="load")
        page.screenshot(path=str(shots / "site-table.png"))


def run_checks(site: Path, shots: Path | None) -> tuple[list[str], dict]:
    from playwright.sync_api import sync_playwright

    server, base = serve(site)
    problems: list[str] = []
    state = {"sorted": set(), "viewed": set(), "pages": 0}
    try:
        with sync_playwright() as p:
            browser = p.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
            page = browser.new_page(viewport={"width": 1400, "height": 1000})
            watch(page, problems)
            for rel in site_pages(site):
                problems += check_page(page, base, rel, state, shots)
                state["pages"] += 1
            problems += check_file_pages(page, site)
            if shots:
                _screenshots(page, base, site, shots)
            browser.close()
    finally:
        server.shutdown()
    return problems, state


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m dse.site.browser_check", description=__doc__.split("\n\n")[0])
    parser.add_argument("site", type=Path, help="a site `dse site` built")
    parser.add_argument("--screenshots", type=Path, default=None, metavar="DIR", help="where screenshots go")
    args = parser.parse_args(argv)
    if args.screenshots:
        args.screenshots.mkdir(parents=True, exist_ok=True)
    start = time.monotonic()
    problems, state = run_checks(args.site, args.screenshots)
    for line in problems:
        print("problem:", re.sub(r"\s+", " ", line))
    print(f"{state['pages']} pages, tables sorted on {len(state['sorted'])}, web viewer rendered for families "
          f"{', '.join(sorted(state['viewed'])) or 'none'}: {len(problems)} problems ({time.monotonic() - start:.0f} s)")
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
