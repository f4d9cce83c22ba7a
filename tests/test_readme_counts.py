"""The README's Python example prints what its comment says (the ring8 scenario of the README, quick, seed 1)."""
import ast
import re
from pathlib import Path

import dse

ROOT = Path(__file__).resolve().parents[1]


def test_the_counts_comment_is_what_the_example_gives(tmp_path):
    readme = (ROOT / "README.md").read_text()
    scenario = re.search(r"```toml\n(family = \"noisy-consensus-filter\"\nname = \"ring8\".*?)```", readme, re.S).group(1)
    comment = re.search(r"^run\.counts\s+# (\{.*\})$", readme, re.M).group(1)
    assert 'dse.run("ring8.toml", quick=True, seed=1)' in readme
    (tmp_path / "ring8.toml").write_text(scenario)
    run = dse.run(str(tmp_path / "ring8.toml"), quick=True, seed=1)
    assert dict(run.counts) == ast.literal_eval(comment)
