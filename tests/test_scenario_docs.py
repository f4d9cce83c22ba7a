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
