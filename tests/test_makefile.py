"""`make clean` removes what the project writes, and nothing that nothing creates; `make test` hands out the
longest test files first."""
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


def test_make_test_hands_out_the_longest_files_first(request):
    """`make test` keeps the collected order of files (xdist's default would reorder them by number of tests),
    every file tests/conftest.py names as longest exists, and this session collected them first, in that order."""
    from conftest import LONGEST_FILES

    recipe = (ROOT / "Makefile").read_text().split("\ntest:", 1)[1].split("\n\n", 1)[0]
    assert "--dist loadfile" in recipe and "--no-loadscope-reorder" in recipe
    assert all((ROOT / "tests" / name).is_file() for name in LONGEST_FILES), LONGEST_FILES
    files = list(dict.fromkeys(item.path.name for item in request.session.items))
    present = [name for name in LONGEST_FILES if name in files]
    assert files[:len(present)] == present


def test_make_test_keeps_the_rewritten_test_modules():
    """The suite's collection reads pytest's rewritten test modules from tests/__pycache__ when they are there:
    `make test` lets them be written even where PYTHONDONTWRITEBYTECODE is set (each of its workers collects the
    whole suite, and rewriting every module's asserts was 45% of a worker's collection CPU)."""
    recipe = (ROOT / "Makefile").read_text().split("\ntest:", 1)[1].split("\n\n", 1)[0]
    assert "PYTHONDONTWRITEBYTECODE= " in recipe
