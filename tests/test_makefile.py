"""`make clean` removes what the project writes, and nothing that nothing creates."""
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def clean_paths() -> list[str]:
    lines = (ROOT / "Makefile").read_text().splitlines()
    start = lines.index("clean:")
    recipe = [line.strip() for line in lines[start + 1:] if line.startswith("\t")]
    return [word for line in recipe if line.startswith("rm -rf") for word in line.split()[2:]]


def test_make_clean_removes_only_generated_paths():
    ignored = {line.strip().rstrip("/") for line in (ROOT / ".gitignore").read_text().splitlines() if line.strip()}
    paths = clean_paths()
    assert "out" in paths
    for path in paths:
        assert path in ignored, f"make clean removes {path}, which no target writes (it is not in .gitignore)"
