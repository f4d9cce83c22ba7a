"""The Rerun web viewer's files, taken from the `rerun-notebook` package of exactly the pinned
rerun version (the same build the notebook integration of rerun-sdk uses), never from a CDN.

The package ships the viewer as one JavaScript module (`widget.js`, which loads `re_viewer_bg.wasm`
from beside itself) and is installed by the project's set-up (`make`: `pip install --no-deps
rerun-notebook==<rerun-sdk's version>`; the page needs its static files, not its Jupyter
dependencies). The site copies them to `static/viewer/` once; `static/viewer.js` (ours) opens a
recording in it.
"""
from __future__ import annotations

import importlib.metadata
import importlib.util
from pathlib import Path

VIEWER_PACKAGE = "rerun-notebook"
VIEWER_FILES = ("widget.js", "widget.css", "re_viewer_bg.wasm")


def rerun_version() -> str:
    return importlib.metadata.version("rerun-sdk")


def viewer_assets() -> tuple[dict[str, Path], str]:
    """The viewer's files ({name: path}) and an empty string, or no files and why not (one line)."""
    wanted = rerun_version()
    try:
        version = importlib.metadata.version(VIEWER_PACKAGE)
    except importlib.metadata.PackageNotFoundError:
        return {}, (f"the Rerun web viewer is not installed: pip install --no-deps {VIEWER_PACKAGE}=={wanted} "
                    "(make does it); recordings are offered as downloads only")
    if version != wanted:
        return {}, (f"{VIEWER_PACKAGE} {version} does not match rerun-sdk {wanted}: pip install --no-deps "
                    f"{VIEWER_PACKAGE}=={wanted}; recordings are offered as downloads only")
    spec = importlib.util.find_spec("rerun_notebook")       # finds the package without importing it
    static = Path(spec.origin).parent / "static" if spec and spec.origin else None
    files = {name: static / name for name in VIEWER_FILES} if static else {}
    if not files or not all(p.exists() for p in files.values()):
        return {}, f"{VIEWER_PACKAGE} {version} has no static/{'/'.join(VIEWER_FILES)}: reinstall it"
    return files, ""
