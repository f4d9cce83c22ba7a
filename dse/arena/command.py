"""`dse arena NAME`: the command line of the arena (`run.run_arena`)."""
from __future__ import annotations

import json
import sys
from pathlib import Path

from dse.errors import ScenarioError

HELP = ("score a distributed filter (an installed `dse.estimators` entry point NAME, or --factory) against every "
        "built-in estimator over the standard suite of compare scenarios: leaderboard, frontier figure, recording "
        "(docs/plugins.md)")


def add_parser(sub_parser, nonnegative_int, task_flags) -> None:
    p = sub_parser("arena", help=HELP)
    p.add_argument("name", metavar="NAME", help="the filter's name: an installed one (entry point group "
                                                 "dse.estimators), or any name with --factory")
    p.add_argument("--factory", default=None, metavar="MODULE:CLASS",
                   help="the filter's class, package.module:Class (a dse.plugin.NetworkFilter), when it is not "
                        "installed under NAME")
    p.add_argument("--param", action="append", default=[], metavar="KEY=VALUE",
                   help="one of the filter's parameters (VALUE as TOML: 3, 0.5, true, \"text\"); repeatable")
    p.add_argument("--keys", action="store_true", help="print the filter's parameters (its Parameters schema) and exit")
    p.add_argument("--quick", action="store_true", help="the quick suite: one seed of each generated scenario, every "
                                                        "scenario with its quick trial count")
    p.add_argument("--seed", type=nonnegative_int, default=0, help="root random seed of every run (default 0)")
    p.add_argument("--out", default="out", help="output root; results go to OUT/arena/NAME/ (default out/)")
    task_flags(p, "one worker")
    p.add_argument("--fresh", action="store_true", help="recompute every scenario, ignoring those already done")
    p.set_defaults(func=cmd_arena)


def parse_params(items: list[str]) -> dict:
    """KEY=VALUE pairs, each VALUE read as a TOML value (a bare word is a string)."""
    import tomllib

    out = {}
    for item in items:
        key, eq, value = item.partition("=")
        if not eq or not key.strip():
            raise ScenarioError("--param", f"must be KEY=VALUE, got {item!r}")
        try:
            out[key.strip()] = tomllib.loads(f"v = {value}")["v"]
        except tomllib.TOMLDecodeError:
            out[key.strip()] = value
    return out


def keys_text(name: str, factory: str | None) -> str:
    """The filter's parameters: name, type, default, constraints and meaning, from its Parameters schema."""
    from dse.plugin.declare import load_class

    cls = load_class(name, factory)
    fields = cls.Parameters.model_fields
    lines = [f"{name}: {cls.title or cls.__name__} ({cls.__module__}.{cls.__qualname__})",
             f"keys of [estimators.{name}] besides factory and time_limit:" if fields else "no parameters"]
    for key, info in fields.items():
        default = "required" if info.is_required() else json.dumps(info.get_default(call_default_factory=True),
                                                                    default=str)
        bounds = "; ".join(str(m) for m in info.metadata)
        lines.append(f"  {key} ({getattr(info.annotation, '__name__', info.annotation)}, default {default}"
                     + (f"; {bounds}" if bounds else "") + f"): {info.description or ''}")
    return "\n".join(lines)


def cmd_arena(args) -> int:
    from dse.engine.outlock import output_lock

    from .run import run_arena

    if args.keys:
        print(keys_text(args.name, args.factory))
        return 0
    out_root = Path(args.out)
    with output_lock(out_root):
        r = run_arena(args.name, factory=args.factory, params=parse_params(args.param), out_root=out_root,
                      quick=args.quick, seed=args.seed, scheduler=args.scheduler, workers=args.workers,
                      fresh=args.fresh, log=lambda m: print(m, file=sys.stderr))
    print(f"arena {args.name}: {r['ran']} of {r['scenarios']} scenarios run, on the frontier in {r['on_frontier']}, "
          f"{r['fails']} failed verdicts, {len(r['faults'])} faults ({r['wall_s']:.1f} s) -> {r['out_dir']}")
    for line in r["faults"]:
        print(f"dse: estimator '{args.name}' left out of {line}", file=sys.stderr)
    return 4 if r["faults"] else 1 if r["failed"] else 0
