"""Reading TOML files, and field readers for what is not a declared scenario (sweep files, an
estimator's own parameters). A scenario file is validated by its family's declaration
(`dse.scenario.declare`); each reader here checks one field and raises :class:`ScenarioError`
naming it, so a bad file produces exactly one clear line, e.g. ``grid.model.r: must be > 0, got -1.0``.
"""
from __future__ import annotations

import json
import math
import tomllib
from pathlib import Path
from typing import Any, Iterable, Mapping

import numpy as np

from dse.errors import ScenarioError
from dse.scenario.toml_depth import check_depth

#: No scenario number is larger than this in magnitude: beyond it squares and sums of
#: squares overflow float64, and no physical or statistical quantity here needs it.
MAX_MAGNITUDE = 1e100


#: A scenario or sweep file is at most this large (the largest shipped one is a few kB).
MAX_FILE_BYTES = 1 << 20


def load_toml(path: str | Path) -> dict[str, Any]:
    """Parse a TOML scenario file; any read or syntax problem is a ScenarioError.

    Only a regular file of at most MAX_FILE_BYTES is read (a device such as /dev/zero, a
    FIFO or a directory is refused before reading, so nothing can hang or fill memory), and
    only a text whose keys and nesting are within `dse.scenario.toml_depth`'s limits is parsed."""
    import os
    import stat

    path = Path(path)
    try:
        st = os.stat(path)
        if not stat.S_ISREG(st.st_mode):
            kind = "a directory" if stat.S_ISDIR(st.st_mode) else "a FIFO" if stat.S_ISFIFO(st.st_mode) else \
                "a device" if stat.S_ISCHR(st.st_mode) or stat.S_ISBLK(st.st_mode) else "not a regular file"
            raise ScenarioError(str(path), f"is {kind}, not a scenario file")
        if st.st_size > MAX_FILE_BYTES:
            raise ScenarioError(str(path), f"is {st.st_size:,} bytes; a scenario file is at most {MAX_FILE_BYTES:,}")
        with open(path, "rb") as fh:
            raw = fh.read(MAX_FILE_BYTES + 1)
        if len(raw) > MAX_FILE_BYTES:
            raise ScenarioError(str(path), f"is larger than {MAX_FILE_BYTES:,} bytes")
    except OSError as exc:
        raise ScenarioError(str(path), f"cannot read file ({exc.strerror or exc})") from None
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError:
        raise ScenarioError(str(path), "not a UTF-8 text file") from None
    check_depth(text, str(path))
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ScenarioError(str(path), f"invalid TOML ({exc})") from None
    if not data:
        raise ScenarioError(str(path), "empty scenario file")
    return data


def join(prefix: str, name: str) -> str:
    return f"{prefix}.{name}" if prefix else name


def section(data: Any, field: str) -> Mapping[str, Any]:
    if not isinstance(data, Mapping):
        raise ScenarioError(field, f"must be a table, got {type(data).__name__}")
    return data


def reject_unknown(data: Mapping[str, Any], allowed: Iterable[str], prefix: str = "") -> None:
    """Unknown keys are errors: a typo must not silently fall back to a default."""
    allowed = set(allowed)
    for key in data:
        if key not in allowed:
            raise ScenarioError(join(prefix, key), f"unknown key (allowed: {', '.join(sorted(allowed))})")


def _check_range(x: float, field: str, low, high, low_open: bool, high_open: bool) -> None:
    if low is not None and (x < low or (low_open and x == low)):
        raise ScenarioError(field, f"must be {'>' if low_open else '>='} {low}, got {x}")
    if high is not None and (x > high or (high_open and x == high)):
        raise ScenarioError(field, f"must be {'<' if high_open else '<='} {high}, got {x}")


def as_float(value: Any, field: str, *, low=None, high=None, low_open=False, high_open=False) -> float:
    """A finite real number (TOML integer or float; booleans are rejected)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ScenarioError(field, f"must be a number, got {type(value).__name__}")
    x = float(value)
    if not math.isfinite(x):
        raise ScenarioError(field, f"must be finite, got {x}")
    if abs(x) > MAX_MAGNITUDE:
        raise ScenarioError(field, f"magnitude must be at most {MAX_MAGNITUDE:g}, got {x:g}")
    _check_range(x, field, low, high, low_open, high_open)
    return x


def as_int(value: Any, field: str, *, low=None, high=None) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise ScenarioError(field, f"must be an integer, got {type(value).__name__}")
    _check_range(value, field, low, high, False, False)
    return int(value)


def as_str(value: Any, field: str, choices: Iterable[str] | None = None) -> str:
    if not isinstance(value, str):
        raise ScenarioError(field, f"must be a string, got {type(value).__name__}")
    if choices is not None:
        choices = list(choices)
        if value not in choices:
            raise ScenarioError(field, f"must be one of {', '.join(choices)}; got '{value}'")
    return value


def as_list(value: Any, field: str, *, min_len: int = 1) -> list:
    if not isinstance(value, list):
        raise ScenarioError(field, f"must be a list, got {type(value).__name__}")
    if len(value) < min_len:
        raise ScenarioError(field, f"must have at least {min_len} element(s)")
    return value


def as_matrix(value: Any, field: str, *, shape: tuple[int, int] | None = None,
              symmetric: bool = False, psd: bool = False, tol: float = 1e-9) -> np.ndarray:
    """A real matrix given as a list of equal-length rows of numbers."""
    rows = as_list(value, field)
    if not all(isinstance(r, list) for r in rows):
        raise ScenarioError(field, "must be a list of rows (a list of lists of numbers)")
    width = len(rows[0])
    if width == 0 or any(len(r) != width for r in rows):
        raise ScenarioError(field, "rows must be non-empty and of equal length")
    M = np.array([[as_float(x, f"{field}[{i}][{j}]") for j, x in enumerate(r)] for i, r in enumerate(rows)])
    if shape is not None and M.shape != shape:
        raise ScenarioError(field, f"must have shape {shape[0]}x{shape[1]}, got {M.shape[0]}x{M.shape[1]}")
    if (symmetric or psd) and (M.shape[0] != M.shape[1] or not np.allclose(M, M.T, atol=tol, rtol=0)):
        raise ScenarioError(field, "must be symmetric")
    if psd and np.linalg.eigvalsh(M / 2 + M.T / 2).min() < -tol:
        raise ScenarioError(field, "must be positive semidefinite")
    return M


def toml_text(data: dict) -> str:
    """A scenario dict (a generated one, say) as TOML that `load_toml` reads back to the same dict: every
    top-level key on one line, tables inline."""
    def value(v):
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, str):
            return json.dumps(v)
        if isinstance(v, float) and not math.isfinite(v):
            return "nan" if math.isnan(v) else ("inf" if v > 0 else "-inf")
        if isinstance(v, (list, tuple)):
            return "[" + ", ".join(value(x) for x in v) + "]"
        if isinstance(v, dict):
            return "{" + ", ".join(f"{json.dumps(str(k))} = {value(x)}" for k, x in v.items()) + "}"
        return repr(v.item() if hasattr(v, "item") else v)

    return "\n".join(f"{json.dumps(str(k))} = {value(v)}" for k, v in data.items()) + "\n"
