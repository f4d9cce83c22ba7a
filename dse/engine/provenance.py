"""What produced a result: seed, trials, package versions, git commit, time, memory."""
from __future__ import annotations

import functools
import os
import platform
import subprocess
from importlib import metadata
from pathlib import Path
from typing import Any

PACKAGES = ("numpy", "scipy", "networkx", "control", "filterpy", "pandas", "matplotlib", "rerun-sdk", "dse")


@functools.lru_cache(maxsize=1)
def _versions() -> tuple[tuple[str, str], ...]:
    out = {"python": platform.python_version()}
    for name in PACKAGES:
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = "not installed"
    return tuple(out.items())


def package_versions() -> dict[str, str]:
    """Python's and every numeric dependency's version (read once per process: sweep points and
    scripts that run many scenarios pay for it once)."""
    return dict(_versions())


@functools.lru_cache(maxsize=1)
def git_revision() -> str:
    """The commit, with "-dirty" when tracked files differ from it (once per process, like
    `dse.engine.cache.project_fingerprint`)."""
    root = Path(__file__).resolve().parent.parent
    try:
        rev = subprocess.run(["git", "rev-parse", "HEAD"], cwd=root, capture_output=True, text=True, timeout=5)
        if rev.returncode != 0:
            return "unknown"
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=root,
                               capture_output=True, text=True, timeout=5).stdout.strip()
        return rev.stdout.strip() + ("-dirty" if dirty else "")
    except (OSError, subprocess.SubprocessError):
        return "unknown"


def provenance(**fields: Any) -> dict[str, Any]:
    return {**fields, "versions": package_versions(), "git": git_revision(), "cpus": os.cpu_count(),
            "platform": platform.platform()}
