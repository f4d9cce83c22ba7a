"""The shape the code keeps (issue-level rules, checked so that they stay true): no source file
over 800 lines, no function over 80 lines outside the numerical kernels (dse/estimators), no
hand-written module list in a cache key, and a driver that calls only what the contract declares
(no getattr or hasattr on a reproduction or a family)."""
from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
SOURCES = sorted(p for d in ("dse", "tests", "benchmarks") for p in (ROOT / d).rglob("*.py"))
MAX_FILE_LINES = 800
MAX_FUNCTION_LINES = 80
KERNELS = ROOT / "dse" / "estimators"
DRIVER = [ROOT / "dse" / f for f in ("api.py", "cli.py", "registry.py", "engine/driver.py", "sweeps/run.py")]


def _rel(p: Path) -> str:
    return str(p.relative_to(ROOT))


def test_no_source_file_over_800_lines():
    long = {_rel(p): n for p in SOURCES if (n := len(p.read_text().splitlines())) > MAX_FILE_LINES}
    assert not long, long


def test_no_function_over_80_lines_outside_the_kernels():
    long = {}
    for p in SOURCES:
        if p.is_relative_to(KERNELS) or not p.is_relative_to(ROOT / "dse"):
            continue
        for node in ast.walk(ast.parse(p.read_text())):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                n = node.end_lineno - node.lineno + 1
                if n > MAX_FUNCTION_LINES:
                    long[f"{_rel(p)}:{node.lineno} {node.name}"] = n
    assert not long, long


def test_no_hand_written_module_list_in_a_cache_key():
    found = [_rel(p) for p in SOURCES if p.is_relative_to(ROOT / "dse")
             and ("CODE_MODULES" in (text := p.read_text()) or "code_fingerprint(" in text)]
    assert not found, found


def test_the_driver_does_not_probe_a_reproduction():
    probes = []
    for p in DRIVER:
        for node in ast.walk(ast.parse(p.read_text())):
            if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id in ("getattr", "hasattr") \
                    and node.args and isinstance(node.args[0], ast.Name) \
                    and node.args[0].id in ("repro", "reproduction", "run", "family", "fam"):
                probes.append(f"{_rel(p)}:{node.lineno}")
    assert not probes, probes
