"""docs/scenarios.md is generated from the declared keys and must match them."""
from dse.scenario import docs as scenario_docs


def test_scenarios_page_matches_the_declarations():
    assert scenario_docs.PAGE.read_text() == scenario_docs.page(), \
        "docs/scenarios.md is out of date: run `.venv/bin/python -m dse.scenario.docs`"


def test_every_key_is_documented():
    from dse import registry
    from dse.scenario.declare import reference_rows

    for family, fam in registry.families().items():
        model = fam.scenario_model
        for path, rows, _ in reference_rows(model):
            for row in rows:
                assert row["meaning"].strip(), f"{family}: key {path}.{row['key']} has no meaning"


def _sections(model, prefix=""):
    """(path, field info, section type) of every table nested in a scenario model."""
    from dse.scenario.declare import _section_type

    for name, info in model.model_fields.items():
        sub = _section_type(info.annotation)
        if sub is not None:
            path = f"{prefix}.{name}" if prefix else name
            yield path, info, sub
            yield from _sections(sub, path)


def test_a_table_whose_keys_all_have_defaults_is_optional():
    from dse import registry

    for family, fam in registry.families().items():
        for path, info, sub in _sections(fam.scenario_model):
            if all(not f.is_required() for f in sub.model_fields.values()):
                assert not info.is_required(), f"{family}: [{path}] has a default for every key but is required"


def test_the_page_says_which_tables_are_required():
    text = scenario_docs.PAGE.read_text()
    section = text.split("## `noisy-consensus-filter`")[1].split("\n## ")[0]
    assert "### `[sweep]`\n\n*Optional table*: every key has a default." in section
    assert "### `[model]`\n\n**Required table.**" in section


def test_every_key_with_a_pattern_states_its_rule():
    from dse import registry

    for family, fam in registry.families().items():
        for path, _, sub in [("", None, fam.scenario_model), *_sections(fam.scenario_model)]:
            for name, info in sub.model_fields.items():
                if any(getattr(m, "pattern", None) for m in info.metadata):
                    assert (info.json_schema_extra or {}).get("constraint"), f"{family}: {path}.{name} has an " \
                                                                             "undocumented pattern"


def test_string_lengths_are_in_characters_and_numbers_beside_a_choice_are_named():
    text = scenario_docs.PAGE.read_text()
    assert "at most 500 characters" in text and "at most 500 elements" not in text
    row = next(line for line in text.splitlines() if line.startswith("| `carli_scale`"))
    assert '"optimal" or number' in row and "one of `optimal`" not in row


def test_graph_n_declares_the_two_nodes_it_needs():
    import pytest

    from dse.errors import ScenarioError
    from dse.scenario.graphs import graph

    text = scenario_docs.PAGE.read_text()
    assert "| `n` | integer | none | >= 2;" in text and "| `n` | integer | none | >= 1;" not in text
    for table in ({"kind": "line", "n": 1}, {"kind": "grid", "rows": 1, "cols": 1}):
        with pytest.raises(ScenarioError):
            graph(table)


def test_random_comm_filter_declares_its_size_limit_where_n_is_documented():
    text = scenario_docs.PAGE.read_text()
    row = next(line for line in text.split("## `random-comm-filter`")[1].splitlines() if line.startswith("| `A`"))
    assert "N·n <= 40" in row
