"""Malformed scenario files, generated: every family's loader answers with one ScenarioError
naming a field, never another exception; through the CLI: exit 2, one line, no output."""
import copy
import json
import math
import re
import tempfile
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings, strategies as st

from dse import cli, registry
from dse.errors import ScenarioError
from dse.scenario.fields import load_toml

EXAMPLES = {fam_id: load_toml(fam.example_file()) for fam_id, fam in registry.families().items()}

BAD_VALUES = st.one_of(
    st.just(float("nan")), st.just(float("inf")), st.just(-float("inf")), st.just(-1), st.just(-1.5), st.just(0),
    st.just(1e308), st.just(10**12), st.just(True), st.just(""), st.just("x"), st.just([]), st.just([[]]),
    st.just([1, "a"]), st.just({}), st.just({"unexpected": 1}), st.just([[1.0, 2.0], [3.0]]),
    st.floats(allow_nan=True, allow_infinity=True), st.integers(-10**6, 10**6), st.text(st.characters(exclude_categories=("Cs",)), max_size=5),
    st.lists(st.floats(-10, 10), max_size=4),
)


def leaf_paths(doc, prefix=()):
    if isinstance(doc, dict):
        for k, v in doc.items():
            yield from leaf_paths(v, prefix + (k,))
    elif isinstance(doc, list):
        yield prefix
        for i, v in enumerate(doc):
            yield from leaf_paths(v, prefix + (i,))
    else:
        yield prefix


def set_path(doc, path, value):
    target = doc
    for p in path[:-1]:
        target = target[p]
    target[path[-1]] = copy.deepcopy(value)  # st.just values are shared objects: never alias them


def delete_path(doc, path):
    target = doc
    for p in path[:-1]:
        target = target[p]
    if isinstance(target, dict):
        del target[path[-1]]
    else:
        target.pop(path[-1])


@st.composite
def malformed(draw):
    family = draw(st.sampled_from(sorted(EXAMPLES)))
    doc = copy.deepcopy(EXAMPLES[family])
    paths = [p for p in leaf_paths(doc) if p and p[0] != "family"]
    for _ in range(draw(st.integers(1, 3))):
        paths = [p for p in leaf_paths(doc) if p and p[0] != "family"]
        path = draw(st.sampled_from(paths))
        action = draw(st.sampled_from(["replace", "replace", "replace", "delete", "unknown"]))
        try:
            if action == "replace":
                set_path(doc, path, draw(BAD_VALUES))
            elif action == "delete":
                delete_path(doc, path)
            else:
                parent = path[:-1]
                target = doc
                for p in parent:
                    target = target[p]
                if isinstance(target, dict):
                    target[draw(st.sampled_from(["typo", "Eps", "trials_", "n_"]))] = 1
        except (KeyError, IndexError, TypeError):
            pass
    return family, doc


@settings(max_examples=1000, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(malformed())
def test_loader_rejects_with_a_field_name(case):
    """Each case is written as a TOML file and read back as `dse run` reads it."""
    family, doc = case
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "s.toml"
        path.write_text(_toml(doc))
        parsed = load_toml(path)
    assert parsed == doc or _has_nan(doc)  # the file says what we meant
    try:
        registry.from_dict(parsed)
    except ScenarioError as exc:
        assert exc.field and exc.reason and "\n" not in str(exc)
        # a field path such as `graph.edges[1]` or `gains.rule` (a section may be a default the file omits)
        assert re.fullmatch(r"[A-Za-z_][\w-]*(\[\d+\])*(\.[A-Za-z_][\w-]*(\[\d+\])*)*", exc.field), str(exc)


def test_examples_are_valid():
    for doc in EXAMPLES.values():
        registry.from_dict(copy.deepcopy(doc))


def _has_nan(doc) -> bool:
    return any(isinstance(v, float) and math.isnan(v) for v in _values(doc))


def _values(doc):
    if isinstance(doc, dict):
        for v in doc.values():
            yield from _values(v)
    elif isinstance(doc, list):
        for v in doc:
            yield from _values(v)
    else:
        yield doc


def _toml(doc) -> str:
    """A tiny TOML writer for the documents above (tables of scalars and lists)."""
    def string(text):  # JSON escapes the C0 controls; TOML also forbids a raw DEL in a basic string
        return json.dumps(text, ensure_ascii=False).replace("\x7f", "\\u007f")

    def key(k):
        return string(k)

    def value(v):
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, float):
            return "nan" if math.isnan(v) else ("inf" if v == math.inf else "-inf" if v == -math.inf else repr(v))
        if isinstance(v, (list, tuple)):
            return "[" + ", ".join(value(x) for x in v) + "]"
        if isinstance(v, dict):
            return "{" + ", ".join(f"{key(k)} = {value(x)}" for k, x in v.items()) + "}"
        return string(v)
    top = [f"{key(k)} = {value(v)}" for k, v in doc.items() if not isinstance(v, dict)]
    tables = [f"[{key(k)}]\n" + "\n".join(f"{key(a)} = {value(b)}" for a, b in v.items())
              for k, v in doc.items() if isinstance(v, dict)]
    return "\n".join(top + tables) + "\n"


@settings(max_examples=10, deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])
@given(malformed())
def test_cli_exit_2_one_line_no_output(tmp_path_factory, monkeypatch, capsys, case):
    """`dse run s.toml --out out` through the command's entry point (`cli.main`, what `python -m dse.cli` exits
    with), in this process: a fresh interpreter per example would only repeat the imports; the exit code crossing a
    real process boundary is tested in tests/test_cli.py and tests/test_faults.py."""
    family, doc = case
    try:
        registry.from_dict(copy.deepcopy(doc))
        return  # the mutation happened to be valid; running it is not this test's business
    except ScenarioError:
        pass
    tmp = tmp_path_factory.mktemp("fuzz")
    (tmp / "s.toml").write_text(_toml(doc))
    monkeypatch.chdir(tmp)
    monkeypatch.delenv("DSE_PROGRESS", raising=False)   # the environment the command had as a subprocess
    capsys.readouterr()
    code = cli.main(["run", "s.toml", "--out", "out"])     # an exception escaping main fails the test too
    std = capsys.readouterr()
    assert code == 2, std.out + std.err
    lines = std.err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("dse: error: ") and "Traceback" not in std.err
    assert not (tmp / "out").exists()
