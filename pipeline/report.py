"""report.json, report.md per paper, and out/summary.md over all papers."""
from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Sequence

from .atomic import atomic_write_text
from .verify import ERRATUM, FAIL, NOT_CHECKABLE, PASS


def verdict_counts(rows: Sequence[dict[str, Any]]) -> dict[str, int]:
    return {s: sum(r["verdict"] == s for r in rows) for s in (PASS, FAIL, ERRATUM, NOT_CHECKABLE)}


def write_report(out_dir: Path, *, paper: str, title: str, claims: Sequence[dict[str, Any]],
                 provenance: dict[str, Any], notes: str = "", extra: dict[str, Any] | None = None) -> None:
    doc = {"paper": paper, "title": title, "counts": verdict_counts(claims), "claims": list(claims),
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
    lines = [f"# {doc['title']}", "",
             f"Paper id `{doc['paper']}`: **{c[PASS]} pass, {c[FAIL]} fail, {c[ERRATUM]} erratum, "
             f"{c[NOT_CHECKABLE]} not checkable**.", "",
             f"Seed {prov.get('seed')}, {prov.get('trials')} Monte Carlo trials per cell, "
             f"wall {prov.get('wall_s', 0):.1f} s, peak memory {prov.get('peak_memory_mib', 0):.0f} MiB, "
             f"git `{prov.get('git')}`.", "",
             "| claim | source | kind | verdict | measured | reference | margin |",
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
        lines += [f"### `{r['id']}`: {r['verdict']}", "", f"*{r['source']}* — {r['statement']}", "", r.get("detail", ""), ""]
    if notes:
        lines += ["## Notes", "", notes, ""]
    lines += ["## Provenance", "", "```", json.dumps(prov, indent=1), "```", ""]
    return "\n".join(lines)


def write_summary(out_root: Path) -> Path:
    """One table over every out/<paper>/report.json present."""
    rows = ["# Summary", "", "| paper | pass | fail | erratum | not checkable | wall (s) |", "|---|---|---|---|---|---|"]
    for path in sorted(out_root.glob("*/report.json")):
        doc = json.loads(path.read_text())
        c = doc["counts"]
        rows.append(f"| [{doc['paper']}]({path.parent.name}/report.md) | {c[PASS]} | {c[FAIL]} | {c[ERRATUM]} | "
                    f"{c[NOT_CHECKABLE]} | {doc['provenance'].get('wall_s', 0):.1f} |")
    target = out_root / "summary.md"
    atomic_write_text(target, "\n".join(rows) + "\n")
    return target
