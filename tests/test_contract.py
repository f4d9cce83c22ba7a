"""The declared contract, checked on every registered family (`dse.families`): every family
implements the whole contract, documents every key, parses its shipped scenario files, has a
deterministic generator, names the field of an invalid value, and its stages' cache keys follow
the code they run (an edit of any module a stage imports, directly or transitively, invalidates
it; an edit of an unrelated module does not)."""
from __future__ import annotations

import importlib
import inspect
import pkgutil
import subprocess
import sys
from pathlib import Path

import pytest

from dse import registry
from dse.contract import stages as stage_mod
from dse.contract.family import Family
from dse.contract.stages import Stage, code_closure, code_hash
from dse.errors import ScenarioError
from dse.scenario.declare import reference_rows
from dse.scenario.fields import load_toml

FAMILIES = registry.families()
IDS = list(FAMILIES)

ROOT = Path(__file__).resolve().parent.parent


@pytest.fixture
def fresh_code_caches():
    """The code hashes are cached per process: clear them around a test that fakes an edit."""
    for f in (stage_mod.direct_imports, stage_mod.code_closure, stage_mod.code_hash):
        f.cache_clear()
    yield
    for f in (stage_mod.direct_imports, stage_mod.code_closure, stage_mod.code_hash):
        f.cache_clear()


@pytest.mark.parametrize("family_id", IDS)
def test_family_implements_the_whole_contract(family_id):
    family = FAMILIES[family_id]
    assert isinstance(family, Family) and family.id == family_id
    assert not getattr(type(family), "__abstractmethods__", None)
    assert family.intro.strip() and family.example and family.edges
    assert family.example_file().is_file()
    if family.paper is not None:
        assert family.paper.id and family.paper.title and family.paper.scenario_ids


@pytest.mark.parametrize("family_id", IDS)
def test_every_idle_import_names_a_module_that_imports(family_id):
    """A run imports `idle_imports` as a head start and ignores a failure there (what needs the module imports it
    again): a misspelt name would be skipped silently, so each one is imported here, and must be."""
    import sys

    family = FAMILIES[family_id]
    family.import_idle_imports()
    package = type(family).__module__.rpartition(".")[0]
    for name in family.idle_imports:
        assert (package + name if name.startswith(".") else name) in sys.modules, name


@pytest.mark.parametrize("family_id", IDS)
def test_every_key_is_documented_and_the_example_parses(family_id):
    family = FAMILIES[family_id]
    for path, rows, _ in reference_rows(family.scenario_model):
        for row in rows:
            assert row["meaning"].strip(), f"{family_id}: key {path}.{row['key']} has no meaning"
    data = load_toml(family.example_file())
    assert data["family"] == family_id
    run = registry.from_dict(data)
    assert run.family is family and len(run.scenarios) == 1


@pytest.mark.parametrize("family_id", IDS)
def test_every_shipped_scenario_file_parses(family_id):
    family = FAMILIES[family_id]
    files = sorted({*family.directory().glob("*.toml"), *family.directory().glob("scenarios/*.toml")})
    assert files
    for path in files:
        registry.from_dict(load_toml(path))


@pytest.mark.parametrize("family_id", IDS)
def test_generator_is_deterministic_and_valid(family_id):
    family = FAMILIES[family_id]
    for edge in (None, family.edges[0]):
        a, b = family.generate(7, edge), family.generate(7, edge)
        assert a == b, "a generator must be a function of its seed and edge case"
        assert a["family"] == family_id
        registry.from_dict(a)


@pytest.mark.parametrize("family_id", IDS)
def test_an_invalid_value_names_its_field(family_id):
    family = FAMILIES[family_id]
    data = load_toml(family.example_file())
    with pytest.raises(ScenarioError) as err:
        registry.from_dict({**data, "no_such_key": 1})
    assert err.value.field == "no_such_key"
    with pytest.raises(ScenarioError) as err:
        registry.from_dict({**data, "name": "not a name/"})
    assert err.value.field == "name"


def _stages(family) -> list[Stage]:
    package = importlib.import_module(type(family).__module__.rpartition(".")[0])
    found = []
    for info in pkgutil.iter_modules(package.__path__):
        module = importlib.import_module(f"{package.__name__}.{info.name}")
        found += [v for _, v in inspect.getmembers(module) if isinstance(v, Stage) and v.module == module.__name__]
    return found


@pytest.mark.parametrize("family_id", IDS)
def test_stage_keys_follow_the_code_they_run(family_id, tmp_path, monkeypatch, fresh_code_caches):
    """Every stage's closure holds its own module and no claims module; faking an edit of a module
    deep in the closure changes the stage's code hash, and of a module outside it does not."""
    found = _stages(FAMILIES[family_id])
    assert found, f"{family_id} declares no stage"
    real = stage_mod.module_file
    for st in found:
        closure = code_closure(st.module)
        assert st.module in closure
        assert not [m for m in closure if m.rpartition(".")[2].startswith("claims")], \
            f"stage {st.name} imports a claims module"
        inside = sorted(m for m in closure if m.startswith("dse.simulate.") or m.startswith("dse.estimators."))
        outside = "dse.outputs.report"
        assert outside not in closure
        before = code_hash(st.module)
        for target, changes in ((inside[-1] if inside else st.module, True), (outside, False)):
            edited = tmp_path / f"{target}.py"
            edited.write_bytes(real(target).read_bytes() + b"\n# an edit\n")
            monkeypatch.setattr(stage_mod, "module_file", lambda name, t=target, e=edited: e if name == t else real(name))
            code_hash.cache_clear()
            assert (code_hash(st.module) != before) is changes, (st.name, target)
            monkeypatch.setattr(stage_mod, "module_file", real)
            code_hash.cache_clear()


def test_every_family_of_this_package_is_registered():
    """pyproject.toml registers each subpackage of dse.families that has a family module (a broken
    entry point is skipped with a message, so a missing one would otherwise go unnoticed)."""
    import dse.families as package

    root = Path(package.__path__[0])
    here = {d.name for d in root.iterdir() if (d / "family.py").is_file()}
    registered = {type(f).__module__.split(".")[2] for f in FAMILIES.values()}
    assert here == registered


class ThirdPartyFamily(FAMILIES["template"].__class__):
    """A family an installed package would register (here: the template under another id)."""

    id = "third-party"


def test_an_installed_package_can_add_a_family_and_a_broken_one_is_skipped(monkeypatch, capsys):
    from importlib.metadata import EntryPoint

    from dse import registry

    builtin = list(registry.entry_points(group=registry.GROUP))
    extra = [EntryPoint("third-party", f"{__name__}:ThirdPartyFamily", registry.GROUP),
             EntryPoint("broken", "no_such_module_here:Family", registry.GROUP)]
    monkeypatch.setattr(registry, "entry_points", lambda group: builtin + extra)
    registry.cache_clear()
    try:
        found = registry.families()
        assert "third-party" in found and "broken" not in found and set(FAMILIES) < set(found)
        assert "family broken (no_such_module_here:Family) could not be loaded" in capsys.readouterr().err
        data = {**load_toml(FAMILIES["template"].example_file()), "family": "third-party"}
        assert registry.from_dict(data).family is found["third-party"]
    finally:
        monkeypatch.undo()
        registry.cache_clear()


def test_the_report_order_does_not_depend_on_which_check_module_is_imported_first():
    """Every module of every family package imported in reverse order before `dse list`: the same listing (a
    ClaimSet filled by several modules orders their entries by its declared `modules`, not by import order)."""
    code = """
import contextlib, importlib, io, pkgutil, sys
import dse.families
names = sorted(m.name for m in pkgutil.walk_packages(dse.families.__path__, "dse.families."))
for name in reversed(names):
    importlib.import_module(name)
from dse.cli import main
main(["list"])
"""
    env = {"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin", "OPENBLAS_NUM_THREADS": "1"}
    normal = subprocess.run([sys.executable, "-m", "dse.cli", "list"], capture_output=True, text=True, env=env,
                            cwd=ROOT, timeout=600)
    reversed_ = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, cwd=ROOT,
                               timeout=600)
    assert normal.returncode == 0 and reversed_.returncode == 0, reversed_.stderr[-2000:]
    assert reversed_.stdout == normal.stdout


def test_a_family_that_declares_a_paper_must_give_its_scenarios():
    from dse.contract.family import Paper
    from dse.families.template.family import Template

    with pytest.raises(TypeError, match="paper_scenarios"):
        type("WithPaper", (Template,), {"paper": Paper("p", "A paper", ("s",))})
    assert Template().paper_scenarios() == ()       # no paper: no paper scenarios


def test_the_import_scan_finds_every_import_statement_of_every_project_module():
    """The line scan behind the stage keys (`code_closure`) finds every import statement a full parse finds, in every
    module of the package (nested in functions, parenthesized over several lines, relative), and adds only
    statements written inside strings (a docstring's `import dse`); a line of prose that only starts like an import
    adds nothing."""
    import ast

    for path in sorted((ROOT / "dse").rglob("*.py")):
        source = path.read_bytes()
        tree = ast.parse(source)
        parsed = {ast.dump(n) for n in ast.walk(tree) if isinstance(n, (ast.Import, ast.ImportFrom))}
        scanned = {ast.dump(n): n for n in stage_mod._import_statements(source)}
        assert parsed <= set(scanned), (path, parsed - set(scanned))
        extras = set(scanned) - parsed
        if extras:      # the module's strings, only where the scan found more (a second walk of every tree is 0.2 s)
            strings = [n.value for n in ast.walk(tree) if isinstance(n, ast.Constant) and isinstance(n.value, str)]
        for extra in extras:
            assert any(ast.unparse(scanned[extra]) in s for s in strings), (path, ast.unparse(scanned[extra]))
    tricky = (b'"""Doc.\n\nfrom the paper import nothing here\nimport numbers as they are\n"""\n'
              b"def f():\n    from .a import (b,\n        c)  # (\n    import d.e \\\n        as g\n"
              b"from .h import i  # see (1\n")
    assert [ast.dump(n) for n in stage_mod._import_statements(tricky)] == [
        ast.dump(n) for n in ast.parse(b"from .a import (b,\n c)\nimport d.e as g\nfrom .h import i\n").body]
