"""Class and function sizes in core/ and plugins/, the limits of issue 30 kept.

Prints every class over 300 lines and every function over 80 (a class's or function's
span: ``end_lineno - lineno + 1``, decorators not counted). Exit status 1 when a class is
over 400 lines or a function over 80, unless that function is a documented table: a
comment line ``# size: table`` right above its ``def`` (or its decorators) says that
its length is a list of declarations, read as a table, not logic to split.

    .venv/bin/python scripts/code_sizes.py [--root DIR]
"""

from __future__ import annotations

import argparse
import ast
import sys
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
FOLDERS = ("core", "plugins")
CLASS_REPORT = 300
CLASS_LIMIT = 400
FUNCTION_LIMIT = 80
TABLE_MARKER = "# size: table"
GENERATED = ("_pb2.py",)


@dataclass(frozen=True)
class Span:
    kind: str  # "class" or "def"
    path: Path
    name: str
    line: int
    lines: int
    table: bool


def is_table(node: ast.FunctionDef | ast.AsyncFunctionDef, source: list[str]) -> bool:
    """A ``# size: table`` comment on the line above the function (or its decorators)."""
    first = min([node.lineno, *(d.lineno for d in node.decorator_list)])
    above = first - 2  # 0-based index of the line above
    return above >= 0 and source[above].strip() == TABLE_MARKER


def spans(path: Path, root: Path) -> Iterator[Span]:
    text = path.read_text(encoding="utf-8")
    source = text.splitlines()
    tree = ast.parse(text, filename=str(path))

    def walk(node: ast.AST, prefix: str) -> Iterator[Span]:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.ClassDef | ast.FunctionDef | ast.AsyncFunctionDef):
                name = f"{prefix}{child.name}"
                assert child.end_lineno is not None
                lines = child.end_lineno - child.lineno + 1
                if isinstance(child, ast.ClassDef):
                    yield Span("class", path.relative_to(root), name, child.lineno, lines, False)
                else:
                    table = is_table(child, source)
                    yield Span("def", path.relative_to(root), name, child.lineno, lines, table)
                yield from walk(child, f"{name}.")
            else:
                yield from walk(child, prefix)

    yield from walk(tree, "")


def measure(root: Path) -> list[Span]:
    found: list[Span] = []
    for folder in FOLDERS:
        for path in sorted((root / folder).rglob("*.py")):
            if not path.name.endswith(GENERATED):
                found.extend(spans(path, root))
    return found


def over_limit(span: Span) -> bool:
    if span.kind == "class":
        return span.lines > CLASS_LIMIT
    return span.lines > FUNCTION_LIMIT and not span.table


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--root", type=Path, default=ROOT, help="the tree (default: this one)")
    args = parser.parse_args(argv)
    found = measure(args.root)
    shown = [
        s
        for s in found
        if (s.kind == "class" and s.lines > CLASS_REPORT)
        or (s.kind == "def" and s.lines > FUNCTION_LIMIT)
    ]
    bad = [s for s in found if over_limit(s)]
    for span in sorted(shown, key=lambda s: (s.kind, -s.lines)):
        flag = "OVER" if over_limit(span) else ("table" if span.table else "")
        print(f"{span.kind:5} {span.lines:4}  {span.path}:{span.line} {span.name}  {flag}".rstrip())
    classes = [s for s in found if s.kind == "class"]
    functions = [s for s in found if s.kind == "def"]
    print(
        f"{len(classes)} classes ({sum(s.lines > CLASS_REPORT for s in classes)} over "
        f"{CLASS_REPORT}, limit {CLASS_LIMIT}), {len(functions)} functions (limit "
        f"{FUNCTION_LIMIT} but documented tables): {len(bad)} over the limits"
    )
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
