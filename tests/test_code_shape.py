"""The shape the code keeps (issue-level rules, checked so that they stay true): no source file
over 800 lines, no function over 80 lines outside the numerical kernels (dse/estimators), no
hand-written module list in a cache key, and a driver that calls only what the contract declares
(no getattr or hasattr on a reproduction or a family)."""
from __future__ import annotations

import ast
import re
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


def _names_a_module(name: str) -> bool:
    """`name` is a dotted module name of a file of the project ("dse.estimators.kalman", or "estimators.kalman"
    relative to dse/)."""
    if not re.fullmatch(r"[A-Za-z_]\w*(\.[A-Za-z_]\w*)+", name):
        return False
    rel = Path(*name.split("."))
    return any((b / rel).with_suffix(".py").is_file() or (b / rel / "__init__.py").is_file() for b in (ROOT, ROOT / "dse"))


def _module_name_lists(tree: ast.Module) -> list[int]:
    """Lines of module-level constants that list the project's modules by name: the shape of a cache key's
    hand-kept list of the code it depends on."""
    def names_modules(value) -> bool:
        return (isinstance(value, (ast.Tuple, ast.List, ast.Set)) and bool(value.elts)
                and all(isinstance(e, ast.Constant) and isinstance(e.value, str) for e in value.elts)
                and any(_names_a_module(e.value) for e in value.elts))

    return [node.lineno for node in tree.body if isinstance(node, (ast.Assign, ast.AnnAssign))
            and node.value is not None and names_modules(node.value)]


def test_no_hand_written_module_list_in_a_cache_key():
    """Stage keys hash the sources of the import closure (dse.contract.stages.code_closure): no module keeps a
    list of the modules its computations depend on."""
    found = [f"{_rel(p)}:{line}" for p in SOURCES if p.is_relative_to(ROOT / "dse")
             for line in _module_name_lists(ast.parse(p.read_text()))]
    assert not found, found


def test_a_hand_written_module_list_is_found():
    """The lists the stage keys once kept (names relative to the package root, or absolute) are found; a list of
    file patterns, paths or directory names is not."""
    text = ('KEY_CODE = ("estimators.network_comparison", "estimators.kalman")\n'
            'OTHER = ("a.toml", ".*.tmp.*", "savas/paper.toml")\n'
            'MORE = ["dse.simulate.seeding"]\nDIRS = (".cache", "run")\n')
    assert _module_name_lists(ast.parse(text)) == [1, 3]


def test_the_driver_does_not_probe_a_reproduction():
    probes = []
    for p in DRIVER:
        for node in ast.walk(ast.parse(p.read_text())):
            if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id in ("getattr", "hasattr") \
                    and node.args and isinstance(node.args[0], ast.Name) \
                    and node.args[0].id in ("repro", "reproduction", "run", "family", "fam"):
                probes.append(f"{_rel(p)}:{node.lineno}")
    assert not probes, probes
