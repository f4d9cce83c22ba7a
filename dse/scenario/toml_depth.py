"""How deep a TOML text nests, measured before it is parsed.

The standard TOML parser recurses once per nested array or inline table and builds one table per
part of a dotted key: a small file of deeply nested brackets ends in a RecursionError, and a key of
tens of thousands of parts makes it allocate gigabytes. `check_depth` scans the text once (strings
and comments skipped, constant memory) and refuses, in one line, a key of more than MAX_KEY_PARTS
parts or a value nested more than MAX_NESTING levels deep, before the parser sees it. A text the
scan cannot follow (an unterminated string, say) is left to the parser, which reports its syntax
error.
"""
from __future__ import annotations

import re

from dse.errors import ScenarioError

#: At most this many parts in one dotted key or table header (`a.b.c` has 3). Shipped files use 2.
MAX_KEY_PARTS = 16
#: At most this many levels of tables, dotted-key parts and arrays inside one another, counted from
#: the top of the file as the indexings that reach a value (`[grid]` then `"x" = [[1.0]]` is 4:
#: grid, x and two arrays; an inline table counts by its keys). Shipped files use at most 7.
MAX_NESTING = 32

_TOKEN = re.compile(r'"""|\'\'\'|["\'#\[\]{}=,.\n]')
_STRING_END = {
    '"""': re.compile(r'(?:[^"\\]|\\.|"(?!""))*""""{0,2}', re.DOTALL),
    "'''": re.compile(r"(?:[^']|'(?!''))*'''(?:'{0,2})"),
    '"': re.compile(r'(?:[^"\\\n]|\\.)*"'),
    "'": re.compile(r"[^'\n]*'"),
}


class _Scan:
    """The state of the scan: open arrays and inline tables (with the depth inside each), whether
    a key is being read, and how many parts it has so far."""

    def __init__(self, text: str, field: str):
        self.text, self.field = text, field
        self.stack: list[tuple[str, int]] = []   # ('[' or '{', depth of what is inside)
        self.table_depth = 0                    # parts of the current [table] header
        self.in_key, self.in_header, self.parts, self.value_depth = True, False, 1, 0

    def refuse(self, pos: int, what: str) -> None:
        line = self.text.count("\n", 0, pos) + 1
        raise ScenarioError(self.field, f"line {line}: {what}; refused before parsing")

    def depth(self) -> int:
        return self.stack[-1][1] if self.stack else self.table_depth

    def start_key(self) -> None:
        self.in_key, self.parts = True, 1

    def key_part(self, pos: int) -> None:
        self.parts += 1
        if self.parts > MAX_KEY_PARTS:
            self.refuse(pos, f"a dotted key or table header has more than {MAX_KEY_PARTS} parts")
        self.nest(pos, (0 if self.in_header else self.depth()) + self.parts)

    def nest(self, pos: int, depth: int) -> None:
        if depth > MAX_NESTING:
            self.refuse(pos, f"tables, keys and arrays nest more than {MAX_NESTING} levels deep")

    def open(self, pos: int, kind: str) -> None:
        if self.in_header:
            return                                  # the second bracket of [[array of tables]]
        if not self.stack and self.in_key and not self.text[self.text.rfind("\n", 0, pos) + 1:pos].strip():
            self.in_header, self.parts = True, 1      # a [table] or [[array of tables]] header
            return
        inner = self.value_depth + (kind == "[")   # an array's elements are one level down; a table's keys count
        self.nest(pos, inner)
        self.stack.append((kind, inner))
        self.value_depth = inner
        if kind == "{":
            self.start_key()

    def close(self, kind: str) -> None:
        if self.in_header:
            if kind == "]" and self.in_key:
                self.table_depth, self.in_key = self.parts, False
            return
        if self.stack and self.stack[-1][0] == {"]": "[", "}": "{"}[kind]:
            self.stack.pop()
        self.in_key, self.value_depth = False, self.depth()

    def token(self, pos: int, tok: str) -> None:
        if tok == "\n":
            if not self.stack:
                self.in_header = False
                self.start_key()
        elif tok in "[{":
            self.open(pos, tok)
        elif tok in "]}":
            self.close(tok)
        elif tok == "=" and self.in_key and not self.in_header:
            self.in_key, self.value_depth = False, self.depth() + self.parts
        elif tok == "," and self.stack and self.stack[-1][0] == "{":
            self.start_key()
        elif tok == "." and self.in_key:
            self.key_part(pos)


def check_depth(text: str, field: str) -> None:
    """Raise ScenarioError(field, ...) naming the line when `text` nests deeper than MAX_NESTING or
    has a key of more than MAX_KEY_PARTS parts; one pass, constant memory."""
    scan, pos = _Scan(text, field), 0
    while (m := _TOKEN.search(text, pos)) is not None:
        tok, pos = m.group(), m.end()
        if tok in _STRING_END:
            end = _STRING_END[tok].match(text, pos)
            if end is None:
                return          # an unterminated string: the parser says where
            pos = end.end()
        elif tok == "#":
            newline = text.find("\n", pos)
            if newline < 0:
                return
            pos = newline
        else:
            scan.token(m.start(), tok)
