"""Limits on what a scenario or sweep file may contain, checked before the TOML parser runs."""
import tracemalloc

import pytest

from dse.cli import main
from dse.errors import ScenarioError
from dse.scenario.fields import load_toml
from dse.scenario.toml_depth import MAX_KEY_PARTS, MAX_NESTING

HEAD = 'family = "compare"\n'
CASES = {
    # the parser allocated about 6 GB and raised MemoryError on this 100 kB file
    "dotted key of 50,000 parts": HEAD + ".".join(["a"] * 50_000) + " = 1\n",
    # the parser raised RecursionError
    "100,000 nested brackets": HEAD + "x = " + "[" * 100_000 + "]" * 100_000 + "\n",
    # the parser accepted it and the declaration code raised RecursionError
    "dotted key of 10,000 parts": HEAD + ".".join(["a"] * 10_000) + " = 1\n",
    "table header of 10,000 parts": HEAD + "[" + ".".join(["t"] * 10_000) + "]\nx = 1\n",
    "nested inline tables": HEAD + "x = " + "{a = " * 5_000 + "1" + "}" * 5_000 + "\n",
}


@pytest.mark.parametrize("text", CASES.values(), ids=CASES.keys())
def test_deep_text_is_refused_in_one_line_with_bounded_memory(tmp_path, text):
    path = tmp_path / "deep.toml"
    path.write_text(text)
    tracemalloc.start()
    try:
        with pytest.raises(ScenarioError, match=r"line 2: .*(parts|levels deep); refused before parsing"):
            load_toml(path)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 5 * 2**20 + 4 * len(text), f"peak {peak / 2**20:.1f} MiB while refusing a {len(text)}-byte file"


@pytest.mark.parametrize("command", ["check", "run", "sweep"])
def test_cli_refuses_deep_files_with_exit_2_and_one_line(tmp_path, capsys, command):
    path = tmp_path / "deep.toml"
    path.write_text(CASES["dotted key of 50,000 parts"])
    assert main([command, str(path), *(["--out", str(tmp_path / "out")] if command != "check" else [])]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("dse: error: ") and "refused before parsing" in err
    assert not (tmp_path / "out").exists()


def test_limits_admit_what_they_promise_and_skip_strings_and_comments(tmp_path):
    keys = ".".join(f"k{i}" for i in range(MAX_KEY_PARTS))
    arrays = "[" * (MAX_NESTING - MAX_KEY_PARTS) + "1" + "]" * (MAX_NESTING - MAX_KEY_PARTS)
    text = (HEAD + f"{keys} = {arrays}\n"
            f'"{"a." * 100}" = "{"[" * 100}"\n'     # dots and brackets inside strings are not structure
            f"s = '''{'{' * 100}\n'''\n"
            f"# {'[' * 100} {'.' * 100}\n"
            "[[arr.of]]\nf = [1.5, 2.5, { x.y = 3.5 }]\n")
    path = tmp_path / "ok.toml"
    path.write_text(text)
    data = load_toml(path)
    assert data["arr"]["of"][0]["f"][2] == {"x": {"y": 3.5}}
    path.write_text(HEAD + f"{keys}.one_more = 1\n")
    with pytest.raises(ScenarioError, match=f"more than {MAX_KEY_PARTS} parts"):
        load_toml(path)
    path.write_text(HEAD + f"{keys} = [{arrays}]\n")
    with pytest.raises(ScenarioError, match=f"more than {MAX_NESTING} levels"):
        load_toml(path)
