"""The example plug-in package, examples/dse-consensus-measurements (a filter brought to the compare arena from
outside dse), is tested with the suite: its own tests are collected here and run against the installed package,
the way a researcher's package meets dse (`make test` installs it: the Makefile's $(STAMP))."""
from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "examples" / "dse-consensus-measurements"

if importlib.util.find_spec("dse_cm") is None:
    raise ImportError("the example package dse_cm is not installed: `make test` installs it, or "
                      "pip install --no-deps -e examples/dse-consensus-measurements")


def _package_tests():
    path = PACKAGE / "tests" / "test_consensus_measurements.py"
    spec = importlib.util.spec_from_file_location("dse_cm_package_tests", path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module              # its dataclasses look their module up
    spec.loader.exec_module(module)
    return module


globals().update({name: obj for name, obj in vars(_package_tests()).items() if name.startswith("test_")})


def test_the_installed_package_is_this_repositorys():
    """An editable install of another checkout would test that checkout's filter, not this one."""
    import dse_cm

    assert Path(dse_cm.__file__).resolve().is_relative_to(PACKAGE), (
        f"dse_cm is imported from {dse_cm.__file__}, not from {PACKAGE}: reinstall it "
        "(pip install --no-deps -e examples/dse-consensus-measurements)")
