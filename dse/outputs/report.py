"""report.json, report.md per paper, and out/summary.md over all papers."""
from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Sequence

from dse.engine.atomic import atomic_write_text
from dse.verify.rules import ERRATUM, ERROR, FAIL, NOT_CHECKABLE, PASS, STATUSES, Evaluation


def verdict_counts(rows: Sequence[dict[str, Any]]) -> dict[str, int]:
    return {s: sum(r["verdict"] == s for r in rows) for s in STATUSES}


def counts_line(c: dict[str, int]) -> str:
    """'12 pass, 0 fail, 1 erratum, 2 not checkable, 0 errors' (errors are our defects)."""
    return (f"{c[PASS]} pass, {c[FAIL]} fail, {c[ERRATUM]} erratum, {c[NOT_CHECKABLE]} not checkable, "
            f"{c.get(ERROR, 0)} error{'s' if c.get(ERROR, 0) != 1 else ''}")


def write_report(out_dir: Path, *, paper: str, title: str, evaluation: Evaluation,
                 provenance: dict[str, Any], notes: str = "", extra: dict[str, Any] | None = None) -> None:
    ev = evaluation
    doc = {"paper": paper, "title": title, "counts": verdict_counts(ev.claims),
           "hypotheses": ev.hypotheses, "statistics": ev.statistics,
           "omitted_paper_example_claims": ev.omitted_paper_example, "claims": list(ev.claims),
           "provenance": provenance, **(extra or {})}
    atomic_write_text(out_dir / "report.json", json.dumps(doc, indent=1, allow_nan=False))
    atomic_write_text(out_dir / "report.md", report_markdown(doc, notes))


def _fmt(x: Any) -> str:
    if x is None:
        return ""
    if isinstance(x, float):
        return f"{x:.6g}"
    if isinstance(x, list):
        return "[" + ", ".join(_fmt(v) for v in x[:6]) + (", …]" if len(x) > 6 else "]")
    return str(x)


def report_markdown(doc: dict[str, Any], notes: str = "") -> str:
    c = doc["counts"]
    prov = doc["provenance"]
    st = doc.get("statistics", {})
    lines = [f"# {doc['title']}", "",
             f"Paper id `{doc['paper']}`: **{counts_line(c)}**.", "",
             f"Seed {prov.get('seed')}, {prov.get('trials')} Monte Carlo trials per cell, "
             f"wall {prov.get('wall_s', 0):.1f} s, peak memory {prov.get('peak_memory_mib', 0):.0f} MiB, "
             f"git `{prov.get('git')}`.", ""]
    if st:
        lines += [f"Statistical claims: {st['statistical_claims']} checked with family-wise confidence "
                  f"{st['family_confidence']} ({st['method']}: each at {st['per_claim_confidence']:.6g})."
                  + "".join(f" The {g['statistical_claims']} of {name.replace('plugin:', 'plug-in ')} share the same "
                            f"family-wise confidence apart (each at {g['per_claim_confidence']:.6g})."
                            for name, g in st.get("groups", {}).items()),
                  ""]
    if doc.get("omitted_paper_example_claims"):
        lines += [f"{doc['omitted_paper_example_claims']} claims about the paper's own example are not evaluated on "
                  "this scenario.", ""]
    if c.get(ERROR):
        lines += [f"**{c[ERROR]} checks raised an error: these are defects of this software, not findings.**", ""]
    hyps = doc.get("hypotheses", [])
    if hyps:
        lines += ["## Hypotheses", "", "| hypothesis | statement | holds | value | threshold |", "|---|---|---|---|---|"]
        for h in hyps:
            holds = "error" if h.get("error") else hypothesis_status(h, {True: "yes", False: "**no**", None: "undecided"})
            lines.append(f"| `{h['id']}` | {h['statement']} | {holds} | {_fmt(h.get('value'))} | {_fmt(h.get('threshold'))} |")
        lines += [""] + [f"- `{h['id']}`: {h['detail']}" for h in hyps if h.get("detail")] + [""]
    lines += ["## Claims", "", "| claim | source | kind | verdict | measured | reference | margin |",
              "|---|---|---|---|---|---|---|"]
    for r in doc["claims"]:
        lines.append(f"| `{r['id']}` | {r['source']} | {r['kind']} | **{r['verdict']}** | {_fmt(r.get('measured'))} | "
                     f"{_fmt(r.get('reference'))} | {_fmt(r.get('margin'))} |")
    errata = [r for r in doc["claims"] if r["verdict"] == ERRATUM]
    if errata:
        lines += ["", "## Errata found", ""]
        for r in errata:
            lines.append(f"- `{r['id']}` ({r['source']}): printed gives {_fmt(r.get('printed'))}, corrected gives "
                         f"{_fmt(r.get('corrected'))}, reference {_fmt(r.get('reference'))}. {r.get('detail', '')}")
    lines += ["", "## Claims in detail", ""]
    for r in doc["claims"]:
        needs = f" Rests on: {', '.join(f'`{h}`' for h in r['hypotheses'])}." if r.get("hypotheses") else ""
        lines += [f"### `{r['id']}`: {r['verdict']}", "", f"*{r['source']}* — {r['statement']}.{needs}", "",
                  r.get("detail", ""), ""]
    if notes:
        lines += ["## Notes", "", notes, ""]
    lines += ["## Provenance", "", "```", json.dumps(prov, indent=1), "```", ""]
    return "\n".join(lines)


def write_summary(out_root: Path) -> Path:
    """One table over every out/<paper>/report.json present."""
    rows = ["# Summary", "", "| paper | pass | fail | erratum | not checkable | errors | wall (s) |",
            "|---|---|---|---|---|---|---|"]
    for path in sorted(out_root.glob("*/report.json")):
        doc = json.loads(path.read_text())
        c = doc["counts"]
        rows.append(f"| [{doc['paper']}]({path.parent.name}/report.md) | {c[PASS]} | {c[FAIL]} | {c[ERRATUM]} | "
                    f"{c[NOT_CHECKABLE]} | {c.get(ERROR, 0)} | {doc['provenance'].get('wall_s', 0):.1f} |")
    target = out_root / "summary.md"
    atomic_write_text(target, "\n".join(rows) + "\n")
    return target


def hypothesis_status(h: dict, words: dict) -> str:
    """How a hypothesis is shown: `words[holds]`, except where the scenario declares it should not hold (a
    negative control): "does not hold (expected)", or "holds (expected not to)"."""
    if h.get("expected") is False and h.get("holds") is not None:
        return "holds (expected not to)" if h["holds"] else "does not hold (expected)"
    return words[h.get("holds")]
