"""Stages: cached computations keyed by what they are given and by the code they run.

A stage is a module-level function that returns named arrays, declared with `@stage`:

    @stage(unkeyed=("budget_bytes",), allow_nonfinite=("thresholds",))
    def monte_carlo(sc: MyScenario, seed: int, trials: int, budget_bytes: float) -> dict[str, np.ndarray]:
        ...

and run through a `StageContext` (`ctx.run(monte_carlo, sc, seed, trials, budget)`), which reads
the result from the stage cache or computes and stores it. The cache key is derived, never
written by hand, from

- the stage's name (the function's, unless given);
- every argument it is called with, by name: a scenario by its `key()`, an upstream stage's
  result by that stage's key, anything else by its canonical JSON; arguments declared
  `unkeyed` are left out (they cannot change the result: a memory budget, a progress label);
- the source of the stage's module and of every `dse` module it imports, directly or
  transitively, at module level or inside a function (`code_closure`, read from the import
  statements): editing any of them invalidates the stage, editing an unrelated module does not.

The context (`dse.contract.context.StageContext`) records every stage it ran, with its key and
whether it was read back from the cache; `report.json` lists them under `provenance.stages`.
"""
from __future__ import annotations

import ast
import functools
import importlib
import hashlib
import inspect
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Iterable

import numpy as np

PROJECT = "dse"


# -- the code a module runs --------------------------------------------------------------------------

@functools.lru_cache(maxsize=1)
def _project_root() -> Path:
    return Path(__file__).resolve().parents[1]


def module_file(name: str) -> Path | None:
    """The source file of a project module (a package's `__init__.py`), or None if there is none."""
    if name != PROJECT and not name.startswith(PROJECT + "."):
        return None
    rel = Path(*name.split(".")[1:])
    root = _project_root()
    for path in (root / rel.with_suffix(".py") if rel.parts else None, root / rel / "__init__.py"):
        if path is not None and path.is_file():
            return path
    return None


#: where an import statement can start: a line whose first word is `import` or `from X import`
_IMPORT_START = re.compile(rb"^[ \t]*(?:import[ \t]|from[ \t]+[\w.]+[ \t]+import\b)", re.M)


def _import_statements(source: bytes) -> Iterable[ast.Import | ast.ImportFrom]:
    """Every import statement of a module's source, at any depth, found without parsing the whole module (a full
    `ast.parse` of the modules a stage imports took a tenth of `dse check`): each line that starts like an import is
    parsed alone, with the lines an open parenthesis or a backslash carries it over to. Such a line inside a string (a
    docstring's example) can add a module, never drop one: a stage's key may then follow one more file, never one
    less. A statement that shares a line with another (`if x: import y`) is not seen; the project writes none
    (tests/test_contract.py checks the scan against a full parse of every module)."""
    for match in _IMPORT_START.finditer(source):
        lines, depth, pos = [], 0, match.start()
        while pos < len(source):
            nxt = source.find(b"\n", pos)
            nxt = len(source) if nxt < 0 else nxt
            lines.append(source[pos:nxt])
            code = lines[-1].split(b"#")[0]        # an import statement holds no string: '#' starts a comment
            depth += code.count(b"(") - code.count(b")")
            pos = nxt + 1
            if depth <= 0 and not code.rstrip().endswith(b"\\"):
                break
        try:
            tree = ast.parse(b"\n".join(lines).strip())
        except SyntaxError:               # prose in a string that happens to start like an import
            continue
        yield from (node for node in tree.body if isinstance(node, (ast.Import, ast.ImportFrom)))


@functools.lru_cache(maxsize=None)
def direct_imports(name: str) -> frozenset[str]:
    """The project modules `name` imports anywhere in its source (function bodies included), and
    the packages they live in (importing a module runs its packages' `__init__`)."""
    path = module_file(name)
    if path is None:
        return frozenset()
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found: set[str] = set()
    for node in _import_statements(path.read_bytes()):
        if isinstance(node, ast.Import):
            found.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                parts = package.split(".")
                base = ".".join(parts[:len(parts) - node.level + 1] + ([node.module] if node.module else []))
            else:
                base = node.module or ""
            found.add(base)
            found.update(f"{base}.{a.name}" for a in node.names)     # `from pkg import module`
    modules = {m for m in found if module_file(m) is not None}
    for m in list(modules):                                          # and the packages around it
        parts = m.split(".")
        modules.update(".".join(parts[:i]) for i in range(1, len(parts)))
    modules.discard(name)
    return frozenset(modules)


@functools.lru_cache(maxsize=None)
def code_closure(name: str) -> frozenset[str]:
    """`name` and every project module it imports, transitively."""
    seen: set[str] = set()
    todo = [name]
    while todo:
        m = todo.pop()
        if m not in seen:
            seen.add(m)
            todo.extend(direct_imports(m))
    return frozenset(seen)


@functools.lru_cache(maxsize=None)
def code_hash(name: str) -> str:
    """Hash of the source of every module in `code_closure(name)`."""
    h = hashlib.sha256()
    for m in sorted(code_closure(name)):
        h.update(m.encode())
        h.update(module_file(m).read_bytes())
    return h.hexdigest()[:16]


# -- stages -----------------------------------------------------------------------------------------------

class StageResult(dict):
    """A stage's arrays, carrying the stage's key (so that a downstream stage is keyed by it)."""

    key: str = ""


def _key_value(value: Any) -> Any:
    """What an argument contributes to a key."""
    if isinstance(value, StageResult):
        return {"stage": value.key}
    key = getattr(value, "key", None)
    if callable(key):                     # a scenario
        return key()
    if isinstance(value, (list, tuple)):
        return [_key_value(v) for v in value]
    if isinstance(value, dict):
        return {str(k): _key_value(v) for k, v in value.items()}
    if hasattr(value, "__dataclass_fields__"):
        from dataclasses import fields

        return {f.name: _key_value(getattr(value, f.name)) for f in fields(value)}
    return value


@dataclass(eq=False)
class Stage:
    """A declared stage (see the module docstring); `stage(...)` builds it from a function."""

    fn: Callable[..., dict[str, np.ndarray]]
    name: str
    unkeyed: tuple[str, ...] = ()
    allow_nonfinite: tuple[str, ...] | Callable[..., tuple[str, ...]] = ()

    def __call__(self, *args, **kwargs) -> dict[str, np.ndarray]:
        """The computation itself, uncached."""
        return self.fn(*args, **kwargs)

    @property
    def module(self) -> str:
        return self.fn.__module__

    def bound(self, args: tuple, kwargs: dict) -> dict[str, Any]:
        sig = inspect.signature(self.fn)
        b = sig.bind(*args, **kwargs)
        b.apply_defaults()
        return dict(b.arguments)

    def params(self, arguments: dict[str, Any]) -> dict[str, Any]:
        """The cache key's content: the keyed arguments and the code."""
        return {"stage": self.name, "code": code_hash(self.module),
                "inputs": {k: _key_value(v) for k, v in arguments.items() if k not in self.unkeyed}}

    def nonfinite_allowed(self, arguments: dict[str, Any]) -> tuple[str, ...]:
        allow = self.allow_nonfinite
        return tuple(allow(**arguments)) if callable(allow) else tuple(allow)


def stage(fn: Callable | None = None, *, name: str | None = None, unkeyed: Iterable[str] = (),
          allow_nonfinite: tuple[str, ...] | Callable[..., tuple[str, ...]] = ()):
    """Declare a stage: `@stage` or `@stage(name=..., unkeyed=(...), allow_nonfinite=(...))`.
    `allow_nonfinite` names arrays that may hold NaN or inf (a predicted divergence); it may be a
    function of the stage's arguments."""
    def wrap(f: Callable) -> Stage:
        params = inspect.signature(f).parameters
        missing = [u for u in unkeyed if u not in params]
        if missing:
            raise TypeError(f"stage {f.__name__}: unkeyed {missing} are not parameters")
        return functools.update_wrapper(Stage(f, name or f.__name__, tuple(unkeyed), allow_nonfinite), f)

    return wrap(fn) if fn is not None else wrap


def __getattr__(name: str):
    # StageContext lives in dse.contract.context (how stages are run is not part of what they compute,
    # so it is not in any stage's code closure); importable from here too
    if name == "StageContext":
        return importlib.import_module("dse.contract.context").StageContext
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
