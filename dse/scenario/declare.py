"""Scenario keys declared once: type, default, constraint, unit and meaning.

A family describes each table of its scenario file as a `Section` (a strict, frozen
pydantic model) whose fields are declared with `key(...)`. The same declaration
validates a user's file (`parse`: one `ScenarioError` naming the field, e.g.
``model.r: must be > 0, got -1.0``) and generates the reference page
(`reference_markdown`, collected into docs/scenarios.md by `dse.scenario.docs`).
Rules that tie several keys together live in the section's validators; their text is
declared in the field's `constraint` so that the page states them too.
"""
from __future__ import annotations

import re
import types
import typing
from typing import Annotated, Any, ClassVar, Literal, Mapping, get_args, get_origin

from annotated_types import Ge, Gt, Le, Lt, MaxLen, MinLen
from pydantic import AfterValidator, BaseModel, ConfigDict, Field, ValidationError
from pydantic.fields import FieldInfo
from pydantic_core import PydanticCustomError, PydanticUndefined

from dse.errors import ScenarioError
from dse.scenario.fields import MAX_MAGNITUDE

def _within_magnitude(x: float) -> float:
    if abs(x) > MAX_MAGNITUDE:
        raise PydanticCustomError("magnitude", "magnitude must be at most {limit}", {"limit": MAX_MAGNITUDE})
    return x


#: A finite real number of magnitude at most MAX_MAGNITUDE (TOML integer or float). The magnitude is
#: checked by a validator, not by ge/le bounds, which would override the bounds a key declares.
Real = Annotated[float, Field(allow_inf_nan=False), AfterValidator(_within_magnitude)]
#: A matrix as a list of rows; shape and symmetry rules are checked by the section.
Matrix = list[list[Real]]


class Section(BaseModel):
    """One table of a scenario file: unknown keys are errors, types are strict (no string
    to number conversion, no booleans as numbers), values are frozen once read."""

    model_config = ConfigDict(extra="forbid", strict=True, frozen=True, arbitrary_types_allowed=True)


#: a scenario name: a directory name (OUT/run/<name>/) and part of claim ids
NAME_PATTERN = r"^[A-Za-z0-9_-]{1,64}$"


class ScenarioFile(Section):
    """A whole scenario file of a family, declared once: its sections, keys and validators. The
    validated model is the scenario the family's stages read (derived quantities as cached
    properties), and `key()` is what determines its numbers (for the stage cache): every key but
    those in `unkeyed` (the name, and the trial counts, which the stages receive as arguments)."""

    #: keys that change no number, as for `model_dump(exclude=...)`
    unkeyed: ClassVar[dict[str, Any]] = {"name": True}

    def key(self) -> dict[str, Any]:
        return self.model_dump(mode="json", exclude=self.unkeyed)


def name_key(default: str = "scenario") -> Any:
    """The `name` key every scenario file has."""
    return key(default, doc="scenario name: the output directory OUT/run/<name>/", pattern=NAME_PATTERN,
               constraint="1 to 64 letters, digits, '-' or '_'")


def only_with(section: Section, name: str, switch: str, *values: str) -> None:
    """The rule of a key that belongs to some values of a switch key (`rate` with `model = 'poisson'`): it is
    required when `section.<switch>` is one of `values` and rejected otherwise (a ScenarioError naming it)."""
    given, value = getattr(section, name) is not None, getattr(section, switch)
    when = " or ".join(f"{switch} = '{v}'" for v in values)
    if value in values and not given:
        raise ScenarioError(name, f"missing (needed for {when})")
    if value not in values and given:
        raise ScenarioError(name, f"only with {when} ({switch} is '{value}')")


def computed_default(fn):
    """A default computed from the keys declared before it in the same table: `fn(data)` gets them
    (validated) and the first line of its docstring is what the reference page shows as the default."""
    if not (fn.__doc__ or "").strip():
        raise ValueError(f"computed default {fn.__name__} needs a docstring (the reference page shows it)")
    return fn


def derived_default(fn):
    """A default that depends on keys of other tables (or on the key's place in a list), which the
    table's own validation cannot see: the key reads None until the scenario file's validator sets
    it with `fn` (the code itself), whose docstring's first line is what the reference page shows."""
    if not (fn.__doc__ or "").strip():
        raise ValueError(f"derived default {fn.__name__} needs a docstring (the reference page shows it)")

    def unset() -> None:
        return None

    unset.__doc__ = fn.__doc__
    return unset


def key(default: Any = PydanticUndefined, *, doc: str, unit: str = "", constraint: str = "", inline: bool = False,
        **constraints) -> Any:
    """Declare one key: `doc` (its meaning, required), `unit`, and `constraint` for rules
    the type and bounds (`gt`, `ge`, `lt`, `le`, `min_length`, ...) do not say; `inline`: named tables
    written directly in the enclosing table (`[estimators.<name>]`, not `[estimators.plugins.<name>]`)."""
    if not doc.strip():
        raise ValueError("every scenario key needs a meaning (doc=...)")
    extra = {"unit": unit, "constraint": constraint, "inline": inline}
    if callable(default) and not isinstance(default, (int, float, str, bool, list, tuple)):
        return Field(default_factory=default, description=doc, json_schema_extra=extra, **constraints)
    return Field(default, description=doc, json_schema_extra=extra, **constraints)


def computed(text: str):
    """A default computed from other keys, for `key(default_factory=computed("..."))`: None here,
    resolved when the scenario is built; `text` says how, and is what the reference page shows."""
    def default():
        return None
    default.__doc__ = text
    return default


def parse(model: type[Section], data: Any, prefix: str = "") -> Section:
    """Validate `data` against a section; the first problem becomes one ScenarioError."""
    if not isinstance(data, Mapping):
        raise ScenarioError(prefix or "scenario", f"must be a table, got {type(data).__name__}")
    try:
        return model.model_validate(dict(data))
    except ValidationError as exc:
        errors = exc.errors()
        # an unknown key is named first: it is usually a typo that also explains a missing one
        first = next((e for e in errors if e["type"] == "extra_forbidden"), errors[0])
        raise _scenario_error(first, prefix, model, errors) from None


def _written(model: Any, loc: tuple) -> tuple:
    """`loc` as the file spells it: without the names of `inline` fields (their tables are written directly in
    the enclosing table, `[estimators.<name>]` for the field `estimators.plugins`)."""
    out, cur = [], model
    for part in loc:
        fields = getattr(cur, "model_fields", None) if isinstance(cur, type) else None
        if fields is not None and part in fields:
            extra = fields[part].json_schema_extra
            if not (isinstance(extra, dict) and extra.get("inline")):
                out.append(part)
            cur = fields[part].annotation
        else:
            out.append(part)
            args = get_args(cur)
            cur = next((a for a in args if hasattr(a, "model_fields")), args[-1] if args else None)
    return tuple(out)


def _path(prefix: str, loc: tuple) -> str:
    out = prefix
    for part in loc:
        if isinstance(part, int):
            out += f"[{part}]"
        else:
            out = f"{out}.{part}" if out else str(part)
    return out or "scenario"


_UNION_TAG = re.compile(r"(int|float|str|bool|none|constrained-\w+|[\w-]+\[.*\])", re.S)


def _is_union_tag(part: Any) -> bool:
    """pydantic names the member of a union a value was tried against in the error location
    (`int`, `constrained-int`, `literal['theory']`, `function-after[...]`): never a key of ours."""
    return isinstance(part, str) and _UNION_TAG.fullmatch(part) is not None


#: how a union member that rejected a value by its type is described ("must be an integer or ...")
_MEMBER_TYPES = {"int_type": "an integer", "int_from_float": "an integer", "float_type": "a number",
                 "string_type": "a string", "bool_type": "true or false", "list_type": "a list",
                 "model_type": "a table", "dict_type": "a table", "model_attributes_type": "a table"}


def _union_error(errors: list[dict], first: dict, prefix: str, model: type[Section]) -> ScenarioError:
    """One error for a value that no member of a union (`int | Literal["theory"]`) accepts: the
    member whose type matched explains the problem (a bound, say); else every alternative is listed."""
    def bare(e):
        return tuple(p for p in e["loc"] if not _is_union_tag(p))

    base = bare(first)
    same = [e for e in errors if bare(e) == base]
    matched = [e for e in same if e["type"] not in _MEMBER_TYPES and e["type"] != "literal_error"]
    if matched:
        return _scenario_error({**matched[0], "loc": base}, prefix, model)
    alternatives = []
    for e in same:
        text = _MEMBER_TYPES.get(e["type"]) or f"one of {(e.get('ctx') or {}).get('expected', '')}"
        if text not in alternatives:
            alternatives.append(text)
    return ScenarioError(_path(prefix, base), f"must be {' or '.join(alternatives)}, got {_show(first.get('input'))}")


def _scenario_error(err: dict, prefix: str, model: type[Section], errors: list[dict] | None = None) -> ScenarioError:
    if errors is not None and err["type"] != "extra_forbidden" and any(_is_union_tag(p) for p in err["loc"]):
        return _union_error(errors, err, prefix, model)
    kind, ctx, value = err["type"], err.get("ctx") or {}, err.get("input")
    if kind == "value_error" and isinstance(ctx.get("error"), ScenarioError):
        # a section's validator names the key relative to the section it validates
        inner, loc = ctx["error"], tuple(err["loc"])
        rel = tuple(p for p in inner.field.split(".") if p)
        if rel and loc[-len(rel):] == rel:
            rel = ()
        return ScenarioError(_path(prefix, loc + rel), inner.reason)
    field = _path(prefix, _written(model, tuple(err["loc"])))
    got = _show(value)
    reasons = {
        "missing": "missing",
        "extra_forbidden": f"unknown key (allowed: {_allowed(model, err['loc'])})",
        "greater_than": f"must be > {_num(ctx.get('gt'))}, got {got}",
        "greater_than_equal": f"must be >= {_num(ctx.get('ge'))}, got {got}",
        "less_than": f"must be < {_num(ctx.get('lt'))}, got {got}",
        "less_than_equal": (f"magnitude must be at most {MAX_MAGNITUDE:g}, got {got}" if ctx.get("le") == MAX_MAGNITUDE
                            else f"must be <= {_num(ctx.get('le'))}, got {got}"),
        "finite_number": f"must be finite, got {got}",
        "magnitude": f"magnitude must be at most {MAX_MAGNITUDE:g}, got {got}",
        "float_type": f"must be a number, got {_type(value)}",
        "int_type": f"must be an integer, got {_type(value)}",
        "int_from_float": f"must be an integer, got {_type(value)}",
        "string_type": f"must be a string, got {_type(value)}",
        "bool_type": f"must be true or false, got {_type(value)}",
        "list_type": f"must be a list, got {_type(value)}",
        "tuple_type": f"must be a list, got {_type(value)}",
        "model_type": f"must be a table, got {_type(value)}",
        "dict_type": f"must be a table, got {_type(value)}",
        "model_attributes_type": f"must be a table, got {_type(value)}",
        "literal_error": f"must be one of {ctx.get('expected', '')}; got {got}",
        "too_short": f"must have at least {ctx.get('min_length')} "
                     f"{'element' if ctx.get('min_length') == 1 else 'elements'}, got {ctx.get('actual_length')}",
        "too_long": f"must have at most {ctx.get('max_length')} element(s), got {ctx.get('actual_length')}",
        "string_too_short": f"must have at least {ctx.get('min_length')} character(s)",
        "string_too_long": f"must have at most {ctx.get('max_length')} characters",
        "string_pattern_mismatch": f"must match {ctx.get('pattern')}, got {got}",
    }
    if kind in reasons:
        return ScenarioError(field, reasons[kind])
    msg = err.get("msg", kind)
    return ScenarioError(field, msg.removeprefix("Value error, ").removeprefix("Assertion failed, "))


def _allowed(model: type[Section], loc) -> str:
    m: Any = model
    for part in loc[:-1]:
        if isinstance(part, str) and isinstance(m, type) and issubclass(m, BaseModel) and part in m.model_fields:
            m = _section_type(m.model_fields[part].annotation) or m
    names = sorted(info.alias or name for name, info in m.model_fields.items()) \
        if isinstance(m, type) and issubclass(m, BaseModel) else []
    return ", ".join(names)


def _show(value: Any) -> str:
    if isinstance(value, str):
        return repr(value[:60])
    if isinstance(value, float):
        return f"{value:g}"
    return str(value)[:60]


def _num(x: Any) -> str:
    return f"{x:g}" if isinstance(x, float) else str(x)


def _type(value: Any) -> str:
    return {bool: "boolean", str: "string", list: "list", dict: "table", int: "integer", float: "number"}.get(
        type(value), type(value).__name__)


# -- the reference page ----------------------------------------------------------------------------------

def _section_type(annotation: Any) -> type[Section] | None:
    if isinstance(annotation, type) and issubclass(annotation, Section):
        return annotation
    for arg in get_args(annotation):
        found = _section_type(arg)
        if found is not None:
            return found
    return None


def _type_name(annotation: Any) -> str:
    origin = get_origin(annotation)
    if origin is Annotated:
        return _type_name(get_args(annotation)[0])
    if origin is Literal:
        return "string"
    if origin in (list, tuple):
        args = [a for a in get_args(annotation) if a is not Ellipsis]
        return f"list of {_type_name(args[0])}" if args else "list"
    if origin is dict:
        return f"tables of {_type_name(get_args(annotation)[1])}" if get_args(annotation) else "table"
    if origin in (typing.Union, types.UnionType):
        members = [a for a in get_args(annotation) if a is not type(None)]
        if len(members) == 1:  # an optional key: its type is its one member's
            return _type_name(members[0])
        # a literal beside other types is written as its values: `number or "optimal"`, not `string or number`
        names = [" or ".join(f'"{v}"' for v in get_args(a)) if get_origin(a) is Literal else _type_name(a)
                 for a in members]
        return " or ".join(dict.fromkeys(names))
    if annotation is float:
        return "number"
    if annotation is int:
        return "integer"
    if annotation is str:
        return "string"
    if annotation is bool:
        return "boolean"
    if isinstance(annotation, type) and issubclass(annotation, Section):
        return "table"
    return getattr(annotation, "__name__", str(annotation))


def _constraint(info: FieldInfo) -> str:
    parts = []
    annotation = info.annotation
    unit = "character" if _type_name(annotation) == "string" else "element"
    literal = _literal_args(annotation)
    if literal and _type_name(annotation) == "string":  # a pure choice; in a union the type column lists them
        parts.append("one of " + ", ".join(f"`{a}`" for a in literal))
    for m in info.metadata:
        if isinstance(m, Gt):
            parts.append(f"> {_num(m.gt)}")
        elif isinstance(m, Ge) and m.ge != -MAX_MAGNITUDE:
            parts.append(f">= {_num(m.ge)}")
        elif isinstance(m, Lt):
            parts.append(f"< {_num(m.lt)}")
        elif isinstance(m, Le) and m.le != MAX_MAGNITUDE:
            parts.append(f"<= {_num(m.le)}")
        elif isinstance(m, MinLen):
            parts.append(f"at least {m.min_length} {unit}{'s' if m.min_length != 1 else ''}")
        elif isinstance(m, MaxLen):
            parts.append(f"at most {m.max_length} {unit}{'s' if m.max_length != 1 else ''}")
    extra = (info.json_schema_extra or {}).get("constraint", "") if isinstance(info.json_schema_extra, dict) else ""
    if extra:
        parts.append(extra)
    return "; ".join(parts)


def _literal_args(annotation: Any) -> tuple:
    if get_origin(annotation) is Literal:
        return get_args(annotation)
    for arg in get_args(annotation):
        found = _literal_args(arg)
        if found:
            return found
    return ()


def _default(info: FieldInfo) -> str:
    if info.is_required():
        return "required"
    if info.default_factory is not None:
        doc = getattr(info.default_factory, "__doc__", None)
        return (doc or "computed").strip().splitlines()[0]
    d = info.default
    if d is None:
        return "none"
    return f"`{d!r}`" if isinstance(d, str) else f"`{d}`"


def reference_rows(model: type[Section], prefix: str = "") -> list[tuple[str, list[dict[str, str]], str]]:
    """(table path, rows, table doc) for a section and every section nested in it, in declaration order."""
    here: list[dict[str, str]] = []
    nested: list[tuple[str, list[dict[str, str]], str]] = []
    for name, info in model.model_fields.items():
        name = info.alias or name                     # the key as written in the file (`lambda`)
        sub = _section_type(info.annotation)
        path = f"{prefix}.{name}" if prefix else name
        kind = _type_name(info.annotation)
        if sub is not None and kind in ("table", "list of table", "tables of table"):
            # a list of tables is [[path]] in the file; named tables ([path.<name>]) are documented once
            inline = isinstance(info.json_schema_extra, dict) and info.json_schema_extra.get("inline")
            label = {"table": path, "list of table": f"{path}[]",
                     "tables of table": f"{prefix if inline else path}.<name>"}[kind]
            found = reference_rows(sub, label)
            if found and found[0][0] == label:  # the table's own heading says whether the file must have it
                p, rows, d = found[0]
                found[0] = (p, rows, f"{_presence(info, sub)} {d or info.description or ''}".strip())
            nested += [(p, rows, d or info.description or "") for p, rows, d in found]
            continue
        extra = info.json_schema_extra if isinstance(info.json_schema_extra, dict) else {}
        here.append({"key": name, "type": _type_name(info.annotation), "default": _default(info),
                     "constraint": _constraint(info), "unit": extra.get("unit", ""), "meaning": info.description or ""})
    doc = " ".join((model.__doc__ or "").strip().split("\n\n")[0].split())
    return ([(prefix, here, doc)] if here else []) + nested


def _presence(info: FieldInfo, sub: type[Section]) -> str:
    """Whether a scenario file must have a table: "Required table." or why it may be left out."""
    if info.is_required():
        return "**Required table.**"
    if all(not f.is_required() for f in sub.model_fields.values()):
        return "*Optional table*: every key has a default."
    return "*Optional table*."


def reference_markdown(title: str, model: type[Section], intro: str = "") -> str:
    """The reference of one family: a table per scenario section."""
    lines = [f"## {title}", ""]
    if intro:
        lines += [intro, ""]
    for path, rows, doc in reference_rows(model):
        heading = f"`[[{path[:-2]}]]`" if path.endswith("[]") else f"`[{path}]`"
        lines += [f"### {heading}" if path else "### top level", ""]
        if doc:
            lines += [doc, ""]
        lines += ["| key | type | default | constraint | unit | meaning |", "|---|---|---|---|---|---|"]
        for r in rows:
            cells = [f"`{r['key']}`", r["type"], r["default"], r["constraint"], r["unit"], r["meaning"]]
            lines.append("| " + " | ".join(c.replace("|", "\\|").replace("\n", " ") for c in cells) + " |")
        lines.append("")
    return "\n".join(lines)


# -- matrices: one policy for every family -----------------------------------------------------------------

#: a covariance must be symmetric to this fraction of its largest entry (then it is symmetrised exactly)
SYMMETRY_RTOL = 1e-10
#: ... and positive semidefinite to the same fraction: its smallest eigenvalue >= −PSD_RTOL·max|entry|
PSD_RTOL = 1e-10
#: a positive definite one has its smallest eigenvalue > DEFINITE_RTOL·max|entry|
DEFINITE_RTOL = 1e-12


def matrix(rows: Any, field: str, *, shape: tuple[int | None, int | None] | None = None):
    """A real matrix from a list of equal-length rows (already typed by the section as
    `Matrix`); `shape` entries of None are free. Raises ScenarioError naming `field`."""
    import numpy as np

    if not rows or any(len(r) != len(rows[0]) for r in rows) or not rows[0]:
        raise ScenarioError(field, "rows must be non-empty and of equal length")
    M = np.array(rows, dtype=float)
    if shape is not None:
        want = tuple(M.shape[i] if s is None else s for i, s in enumerate(shape))
        if M.shape != want:
            raise ScenarioError(field, f"must have shape {want[0]}x{want[1]}, got {M.shape[0]}x{M.shape[1]}")
    return M


def covariance(rows: Any, field: str, *, n: int | None = None, definite: bool = False):
    """A covariance matrix under the project's one policy: square (n x n when given), symmetric to
    SYMMETRY_RTOL (then symmetrised exactly), positive semidefinite to PSD_RTOL, or positive
    definite (smallest eigenvalue > DEFINITE_RTOL·max|entry|) when `definite`."""
    import numpy as np

    M = matrix(rows, field, shape=(n, n) if n is not None else None)
    if M.shape[0] != M.shape[1]:
        raise ScenarioError(field, f"must be square, got {M.shape[0]}x{M.shape[1]}")
    scale = float(np.abs(M).max())
    if np.abs(M - M.T).max() > SYMMETRY_RTOL * scale:
        raise ScenarioError(field, f"must be symmetric (largest asymmetry {np.abs(M - M.T).max():.3g})")
    M = (M + M.T) / 2
    low = float(np.linalg.eigvalsh(M).min()) if scale > 0 else 0.0
    if definite and not low > DEFINITE_RTOL * scale:
        raise ScenarioError(field, f"must be positive definite (smallest eigenvalue {low:.3g})")
    if low < -PSD_RTOL * scale:
        raise ScenarioError(field, f"must be positive semidefinite (smallest eigenvalue {low:.3g})")
    return M
