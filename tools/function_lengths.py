"""Function lengths in taichi_mpm/: no function may be longer than MAX_LINES lines, counted from its first
decorator to its last line, with the functions nested in it counted as part of it (a builder that holds its kernels
is as long as all of them). Methods count on their own; a class is not a function.

    python tools/function_lengths.py [PACKAGE]     # exit 1 and one line per problem when a function is too long

ALLOWED names the functions still over the limit, each with its exact current length: the list may only shrink.
A listed function that got shorter (or longer) is reported too, so the figure is lowered, or the entry removed,
when the function is split."""
from __future__ import annotations

import ast
import sys
from dataclasses import dataclass
from pathlib import Path

MAX_LINES = 150

# Builders being split by other branches (issue 26); remove each entry when its split lands.
ALLOWED = {
    "crack.py:CrackFinder.build": 951,
    "solver.py:Simulation._build_kernels": 594,
}


@dataclass(frozen=True)
class Function:
    file: str        # path relative to the package folder, with / separators
    name: str        # qualified: Class.method, or function
    line: int        # where its `def` is
    lines: int       # decorators to last line, nested functions included

    @property
    def key(self) -> str:
        return f"{self.file}:{self.name}"


def _outermost(tree: ast.AST, prefix: str = ""):
    """(qualified name, node) of every function not nested in another function: module level and in classes."""
    for node in ast.iter_child_nodes(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            yield prefix + node.name, node
        elif isinstance(node, ast.ClassDef):
            yield from _outermost(node, f"{prefix}{node.name}.")
        elif not isinstance(node, ast.Lambda):   # e.g. functions defined under `if` or `try` at module level
            yield from _outermost(node, prefix)


def functions(package: Path):
    for path in sorted(Path(package).rglob("*.py")):
        rel = path.relative_to(package).as_posix()
        tree = ast.parse(path.read_text(), str(path))
        for name, node in _outermost(tree):
            first = min([d.lineno for d in node.decorator_list] + [node.lineno])
            yield Function(rel, name, node.lineno, node.end_lineno - first + 1)


def long_functions(package: Path, limit: int = MAX_LINES) -> list[Function]:
    return [f for f in functions(package) if f.lines > limit]


def problems(package: Path, allowed: dict | None = None, limit: int = MAX_LINES) -> list[str]:
    """Messages for every function over the limit that is not allowed at its exact length, and for every allowed
    entry that no longer matches (shorter, longer or gone)."""
    allowed = ALLOWED if allowed is None else allowed
    found = {f.key: f for f in functions(package)}
    out = []
    for f in found.values():
        if f.lines > limit and allowed.get(f.key) != f.lines:
            was = f" (allowed {allowed[f.key]})" if f.key in allowed else ""
            out.append(f"{f.file}:{f.line} {f.name} is {f.lines} lines, over {limit}{was}: split it")
    for key, lines in allowed.items():
        f = found.get(key)
        if f is None:
            out.append(f"{key} is in the allow-list but no longer exists: remove the entry")
        elif f.lines != lines and f.lines <= limit:
            out.append(f"{key} is now {f.lines} lines (allowed {lines}): remove its allow-list entry")
    return out


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    package = Path(argv[0]) if argv else Path(__file__).resolve().parents[1] / "taichi_mpm"
    found = problems(package)
    for line in found:
        print(line)
    longest = max(functions(package), key=lambda f: f.lines)
    print(f"{'FAIL' if found else 'ok'}: longest function {longest.key} {longest.lines} lines "
          f"(limit {MAX_LINES}, {len(ALLOWED)} allowed over it)")
    return 1 if found else 0


if __name__ == "__main__":
    sys.exit(main())
