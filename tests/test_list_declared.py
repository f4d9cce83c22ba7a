"""`dse list` is declared: it expands every paper's (and family's) hypotheses and claims on the declared scenarios
(`Paper.declared`, `Family.example_declared`, through `Family.listing`), so that it reads no scenario file and
builds no scenario. The declarations cannot drift from the files: every declared value is compared with the parsed
file, and the listing made from the declarations with the listing made from the files."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from dse import registry
from dse.contract.family import Declared, Reproduction
from dse.scenario.fields import load_toml

ROOT = Path(__file__).resolve().parent.parent
FAMILIES = registry.families()


def parsed_run(family) -> Reproduction:
    """What the listing stands for, from the files: the paper's reproduction on its parsed scenarios, or a
    user's run of the parsed example."""
    if family.paper is not None:
        return Reproduction(family, True, tuple(family.paper_scenarios()))
    return registry.from_dict(load_toml(family.example_file()))


def differences(declared: Declared, actual, paper: bool, family, where: str) -> list[str]:
    """Where a declaration and the parsed scenario (or a part of it) disagree."""
    out = [] if declared.name == actual.name else [f"{where}: name {declared.name!r} vs {actual.name!r}"]
    if family is not None and declared.roles != family.roles(actual, paper):
        out.append(f"{where}: roles {sorted(declared.roles)} vs {sorted(family.roles(actual, paper))}")
    for key, value in declared.properties().items():
        got = getattr(actual, key)
        if isinstance(value, Declared):
            out += differences(value, got, paper, None, f"{where}.{key}")
        elif isinstance(value, tuple) and any(isinstance(v, Declared) for v in value):
            got = list(got)
            if len(got) != len(value):
                out.append(f"{where}.{key}: {len(value)} declared vs {len(got)} in the file")
            out += [d for v, g in zip(value, got) for d in differences(v, g, paper, None, f"{where}.{key}[{v.name}]")]
        elif value != got:
            out.append(f"{where}.{key}: declared {value!r}, the file gives {got!r}")
    return out


def listed(repro: Reproduction) -> tuple:
    """Everything `dse list` prints of a run, and what the claims rest on."""
    return (repro.title, repro.scenario_ids(), [(h.id, h.statement) for h in repro.hypotheses()],
            [(c.id, c.source, c.statement, c.kind, c.scope, c.hypotheses) for c in repro.claims()])


@pytest.mark.parametrize("family_id", list(FAMILIES))
def test_every_declaration_agrees_with_the_parsed_file(family_id):
    family = FAMILIES[family_id]
    declared = family.paper.declared if family.paper is not None else (family.example_declared,)
    scenarios = {sc.name: sc for sc in parsed_run(family).scenarios}
    assert {d.name for d in declared} <= set(scenarios)
    assert [d for d in declared for d in differences(d, scenarios[d.name], family.paper is not None, family,
                                                      d.name)] == []


@pytest.mark.parametrize("family_id", list(FAMILIES))
def test_the_listing_from_declarations_is_the_listing_from_the_files(family_id):
    family = FAMILIES[family_id]
    assert listed(family.listing()) == listed(parsed_run(family))


def test_a_declaration_that_misses_what_a_gate_reads_says_so():
    family = FAMILIES["hybrid-observer"]
    bare = Reproduction(family, True, tuple(Declared(name) for name in family.paper.scenario_ids))
    with pytest.raises(AttributeError, match="declared scenario 'paper' has no property 'runs'"):
        bare.hypotheses()


def test_a_paper_declares_only_its_own_scenarios_and_a_family_without_one_its_example():
    from dse.contract.family import Paper
    from dse.families.template.family import Template

    with pytest.raises(ValueError, match="declared scenarios x are not among"):
        Paper("p", "A paper", ("s",), declared=(Declared("x"),))
    with pytest.raises(TypeError, match="example_declared"):
        type("NoExampleName", (Template,), {"example_declared": None})


#: run in a fresh interpreter: records every .toml opened (an audit hook) and every scenario model built (the
#: constructors of `Section`, the base of every scenario file's model), during `dse list` and then, as a control
#: that the traps work, while one paper's scenarios are read
TRAPPED_LIST = """
import contextlib, io, json, sys
seen = {"list": [], "control": []}
phase = "list"
sys.addaudithook(lambda event, args: event == "open" and str(args[0]).endswith(".toml") and seen[phase].append(
    str(args[0])))
from dse.scenario.declare import Section
def trap(original, what):
    def built(*a, **k):
        seen[phase].append(what)
        return original(*a, **k)
    return built
Section.__init__ = trap(Section.__init__, "Section()")
Section.model_validate = classmethod(trap(Section.model_validate.__func__, "Section.model_validate"))
Section.model_construct = classmethod(trap(Section.model_construct.__func__, "Section.model_construct"))
from dse.cli import main
out = io.StringIO()
with contextlib.redirect_stdout(out):
    code = main(["list"])
phase = "control"
from dse import registry
registry.paper("kar-moura").scenarios
print(json.dumps({"code": code, "seen": seen, "out": out.getvalue()}))
"""


def test_dse_list_opens_no_scenario_file_and_builds_no_scenario():
    env = {"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin", "OPENBLAS_NUM_THREADS": "1"}
    proc = subprocess.run([sys.executable, "-c", TRAPPED_LIST], capture_output=True, text=True, env=env, cwd=ROOT,
                          timeout=600)
    assert proc.returncode == 0, proc.stderr[-2000:]
    got = json.loads(proc.stdout)
    assert got["code"] == 0 and got["seen"]["list"] == []
    assert "wang-liu-morse (family hybrid-observer)" in got["out"] and "\ncompare (a family without a paper" in got["out"]
    control = got["seen"]["control"]
    assert any(p.endswith("e1.toml") for p in control) and "Section.model_validate" in control, control
