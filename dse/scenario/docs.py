"""docs/scenarios.md, generated from the families' declared scenario keys.

    .venv/bin/python -m dse.scenario.docs          # rewrite docs/scenarios.md
    .venv/bin/python -m dse.scenario.docs --check  # exit 1 when the page and the code disagree

Each family's reproduction module exposes `SCENARIO_MODEL`, the `dse.scenario.declare.Section`
of a whole scenario file, and `FAMILY_INTRO`, one paragraph on what the family models.
"""
from __future__ import annotations

import sys
from pathlib import Path

from dse.scenario.fields import MAX_FILE_BYTES
from dse.scenario.toml_depth import MAX_KEY_PARTS, MAX_NESTING

PAGE = Path(__file__).resolve().parents[2] / "docs" / "scenarios.md"

POLICY = f"""## Rules common to every family

- A scenario file is TOML with `family = "<family>"` and an optional `name` (letters, digits,
  `-` and `_`, at most 64 characters; it names the output directory `OUT/run/<name>/`).
- Each table of a family's reference below says whether a file must have it (**Required table**)
  or may leave it out (*Optional table*: its keys then take their defaults).
- A scenario or sweep file is a regular UTF-8 file of at most {MAX_FILE_BYTES:,} bytes; a dotted key or
  table header has at most {MAX_KEY_PARTS} parts, and tables, keys and arrays nest at most {MAX_NESTING} levels
  deep (`[grid]` then `"x" = [[1.0]]` is 4). Both are checked on the text before it is parsed.
- Unknown keys are errors (a typo never falls back to a default). Numbers must be finite and of
  magnitude at most 1e100; where an integer is required a float is rejected (write 3, not 3.0);
  strings are never converted to numbers.
- Graphs: nodes are 0..n-1; edges are undirected and listed once; self-loops and repeated edges
  (also reversed) are rejected. A network has at least 2 nodes. A family whose theorems need a
  connected graph rejects a disconnected one; a family for which a disconnected network is
  meaningful accepts it and reports connectivity as a hypothesis that does not hold.
- Matrices are lists of rows. A covariance must be symmetric to a relative 1e-10 of its largest
  entry (it is then symmetrised exactly) and positive semidefinite to the same relative
  tolerance; where a key says positive definite, its smallest eigenvalue must exceed 1e-12
  times its largest entry.
- An invalid file is rejected with one line naming the field (`dse: error: model.r: must be >
  0, got -1`), exit code 2, and nothing is written.
"""


def page() -> str:
    from dse import registry
    from dse.scenario.declare import reference_markdown

    parts = ["# Scenario keys", "",
             "Generated from the declarations in the code (`python -m dse.scenario.docs`); a test fails when "
             "this page and the code disagree. Every shipped scenario file under `dse/families/` is a commented "
             "example of its family.", "", POLICY]
    for family in registry.families().values():
        parts.append(reference_markdown(f"`{family.id}`", family.scenario_model, family.intro))
    return "\n".join(parts).rstrip() + "\n"


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    text = page()
    if "--check" in argv:
        if not PAGE.exists() or PAGE.read_text() != text:
            print(f"{PAGE} is out of date: run `python -m dse.scenario.docs`", file=sys.stderr)
            return 1
        return 0
    PAGE.write_text(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
