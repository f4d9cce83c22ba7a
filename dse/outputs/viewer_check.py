"""Open every recording in Rerun's own viewer, headless, and check what it shows.

The native viewer of the pinned rerun-sdk runs with ``--headless`` on loopback (a software
Vulkan driver, Debian's ``mesa-vulkan-drivers``, renders it) and is driven through
``rerun.experimental.ViewerClient``: the check asserts that the blueprint's views are all
listed, none reports an error, and it saves a screenshot per recording.

    python -m dse.outputs.viewer_check OUT_DIR [--screenshots DIR] [--jobs N]

Exit code 0 when every recording passes, 1 otherwise.
"""
from __future__ import annotations

import argparse
import socket
import os
import subprocess
import sys
import time
from pathlib import Path

import rerun_cli
from rerun.experimental import ViewerClient

from dse.outputs.record import blueprint_view_kinds
from dse.outputs.viewer_glyphs import drawable

VIEWER = Path(rerun_cli.__file__).with_name("rerun")


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _strings(value):
    if isinstance(value, str):
        yield value
    elif isinstance(value, (list, tuple)):
        for v in value:
            yield from _strings(v)
    elif isinstance(value, dict):
        for v in value.values():
            yield from _strings(v)


def undrawable_text(rrd: Path) -> list[str]:
    """Every character, in any string of the recording or its blueprint (view names, series
    names, labels, documents), that the viewer's font cannot draw: the viewer would panic
    when that text comes on screen, even in a tab that is not open at first."""
    import rerun as rr

    reader = rr.chunk.RrdReader(str(rrd))
    found: dict[str, str] = {}
    for store in [None, *reader.blueprints()]:
        for chunk in reader.stream() if store is None else reader.stream(store=store):
            for column, values in chunk.to_record_batch().to_pydict().items():
                for text in _strings(values):
                    for ch in text:
                        if not ch.isascii() and ch not in found and not drawable(ch) and ch not in "\n\t":
                            found[ch] = f"{chunk.entity_path} {column}: {text[:60]!r}"
    return [f"undrawable character {ch!r} (U+{ord(ch):04X}) in {where}" for ch, where in found.items()]


def embedded_font_coverage() -> set[int]:
    """Code points of the Inter font embedded in the viewer binary (needs fontTools)."""
    import io
    import re

    from fontTools.ttLib import TTFont

    data = VIEWER.read_bytes()
    for m in re.finditer(rb"\x00\x01\x00\x00\x00[\x08-\x20]", data):
        if not re.fullmatch(rb"[A-Za-z/ ]{4}", data[m.start() + 12:m.start() + 16]):
            continue
        try:
            font = TTFont(io.BytesIO(data[m.start():m.start() + 4_000_000]), lazy=True)
            if "Inter" in (font["name"].getDebugName(1) or ""):
                return set(font.getBestCmap())
        except Exception:  # not a font at this offset
            continue
    raise RuntimeError(f"no Inter font found in {VIEWER}")


def _viewer_env() -> dict[str, str]:
    """The viewer's environment: its own log lines back on (what it prints when it fails is read here)
    unless the user set RUST_LOG (dse turns rerun's Rust logging off otherwise)."""
    import dse

    return {k: v for k, v in os.environ.items() if not (k == "RUST_LOG" and dse.RUST_LOG_SET_HERE)}


def check_recording(rrd: Path, screenshot: Path | None, *, timeout: float = 60.0, settle: float = 4.0) -> list[str]:
    """Problems found with one recording (empty list when it renders cleanly)."""
    glyphs = undrawable_text(rrd)
    if glyphs:
        return glyphs
    port = _free_port()
    proc = subprocess.Popen([str(VIEWER), "--headless", "--bind", "127.0.0.1", "--port", str(port),
                             "--window-size", "1600x1000", "--hide-welcome-screen", str(rrd)],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, env=_viewer_env())
    expected = [k for k in blueprint_view_kinds(rrd) if k]
    try:
        deadline, state, client = time.monotonic() + timeout, None, None
        while time.monotonic() < deadline:
            if proc.poll() is not None:
                err = proc.stderr.read().decode(errors="replace")
                panic = [line for line in err.splitlines() if "panicked" in line]
                return [f"viewer exited with code {proc.returncode}: {(panic or [err[-400:]])[0]}"]
            try:
                client = client or ViewerClient.connect(f"rerun+http://127.0.0.1:{port}/proxy")
                state = client.get_state()
                if state.views and not state.loading and len(state.views) >= len(expected):
                    break
            except Exception:  # not listening yet
                pass
            time.sleep(0.5)
        if state is None or not state.views:
            return ["viewer listed no views before the timeout"]
        time.sleep(settle)
        state = client.get_state()
        problems = [f"view '{v.name}' ({v.view_class}): {v.reports}" for v in state.views if v.reports]
        shown = sorted(v.view_class for v in state.views)
        if shown != sorted(expected):
            problems.append(f"blueprint has views {sorted(expected)} but the viewer shows {shown}")
        if screenshot is not None:
            screenshot.parent.mkdir(parents=True, exist_ok=True)
            screenshot.write_bytes(client.take_screenshot())
        return problems
    finally:
        proc.terminate()
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out_dir")
    parser.add_argument("--screenshots", default=None, help="directory for one PNG per recording")
    parser.add_argument("--jobs", type=int, default=3, help="viewers open at once (default 3)")
    args = parser.parse_args(argv)
    root = Path(args.out_dir)
    # the stage cache and the report site's copies are not recordings of their own
    recordings = sorted(p for p in root.rglob("*.rrd") if p.relative_to(root).parts[0] not in (".cache", "site"))
    if not recordings:
        print(f"no recordings under {args.out_dir}", file=sys.stderr)
        return 1
    from concurrent.futures import ThreadPoolExecutor

    def check(rrd: Path) -> list[str]:
        shot = Path(args.screenshots) / f"{rrd.parent.name}-{rrd.stem}.png" if args.screenshots else None
        return check_recording(rrd, shot)

    failed = 0
    with ThreadPoolExecutor(max_workers=max(1, args.jobs)) as pool:     # each check mostly waits on its viewer
        for rrd, problems in zip(recordings, pool.map(check, recordings)):
            failed += bool(problems)
            print(f"{'FAIL' if problems else 'ok  '} {rrd}" + "".join(f"\n     {p}" for p in problems), flush=True)
    print(f"{len(recordings) - failed} passed, {failed} failed")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
