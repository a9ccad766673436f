"""Function size in taichi_mpm/: no function longer than MAX_LINES lines, counted from its first decorator to its
last line with the functions nested in it counted as part of it (a builder that holds its kernels is as long as
all of them; methods count on their own), and none more complex than MAX_COMPLEXITY (ruff's McCabe rule C901, run
here without the per-file ignores of pyproject.toml, so a new offender in an exempted file is still found).

    python tools/function_size.py [PACKAGE]     # exit 1 and one line per problem

ALLOWED_LINES and ALLOWED_COMPLEXITY name the functions still over a limit, each with its exact current figure:
the lists may only shrink. A listed function whose figure changed (shorter, longer, gone) is reported too, so the
figure is updated, or the entry removed, when the function is split."""
from __future__ import annotations

import ast
import json
import re
import shutil
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

MAX_LINES = 150
MAX_COMPLEXITY = 30

# Functions allowed over a limit, each with its exact figure: none (issue 26 split the last two builders).
ALLOWED_LINES: dict = {}
ALLOWED_COMPLEXITY: dict = {}


@dataclass(frozen=True)
class Function:
    file: str        # path relative to the package folder, with / separators
    name: str        # qualified: Class.method, outer.inner, or function
    line: int        # where its `def` is
    lines: int       # decorators to last line, nested functions included
    nested: bool     # defined inside another function

    @property
    def key(self) -> str:
        return f"{self.file}:{self.name}"


def _functions_in(tree: ast.AST, rel: str, prefix: str = "", nested: bool = False):
    for node in ast.iter_child_nodes(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            first = min([d.lineno for d in node.decorator_list] + [node.lineno])
            yield Function(rel, prefix + node.name, node.lineno, node.end_lineno - first + 1, nested)
            yield from _functions_in(node, rel, f"{prefix}{node.name}.", True)
        elif isinstance(node, ast.ClassDef):
            yield from _functions_in(node, rel, f"{prefix}{node.name}.", nested)
        else:   # functions defined under `if`, `try`, `with` ...
            yield from _functions_in(node, rel, prefix, nested)


def functions(package: Path) -> list[Function]:
    """Every function of the package, nested ones included (flagged)."""
    out = []
    for path in sorted(Path(package).rglob("*.py")):
        rel = path.relative_to(package).as_posix()
        out += _functions_in(ast.parse(path.read_text(), str(path)), rel)
    return out


def long_functions(package: Path, limit: int = MAX_LINES) -> list[Function]:
    return [f for f in functions(package) if not f.nested and f.lines > limit]


def complexities(package: Path, limit: int = MAX_COMPLEXITY) -> dict[str, int] | None:
    """{file:qualified name: McCabe complexity} of the functions over `limit`, by ruff (None without ruff)."""
    ruff = shutil.which("ruff") or (Path(sys.executable).parent / "ruff")
    if not Path(ruff).exists():
        return None
    # --no-cache: ruff's cache goes to .ruff_cache in the working folder, and in a read-only checkout ruff then
    # fails with no output, which read as "nothing over the limit"; a ruff that fails is an error, never a pass
    cmd = [str(ruff), "check", "--isolated", "--no-cache", "--select", "C901", "--output-format", "json",
           "--config", f"lint.mccabe.max-complexity = {limit}", str(package)]
    res = subprocess.run(cmd, capture_output=True, text=True, check=False)
    if res.returncode not in (0, 1):   # 1: findings; anything else: ruff could not check
        raise RuntimeError(f"ruff failed (exit {res.returncode}): {(res.stderr.strip().splitlines() or [''])[0]}")
    found = json.loads(res.stdout or "[]")
    by_line = {(f.file, f.line): f for f in functions(package)}
    out = {}
    for item in found:
        rel = Path(item["filename"]).resolve().relative_to(Path(package).resolve()).as_posix()
        f = by_line.get((rel, item["location"]["row"]))
        name = f.key if f else f"{rel}:{item['location']['row']}"
        out[name] = int(re.search(r"\((\d+) >", item["message"]).group(1))
    return out


def _against(found: dict[str, int], allowed: dict[str, int], what: str, limit: int) -> list[str]:
    out = []
    for key, value in found.items():
        if allowed.get(key) != value:
            was = f" (allowed {allowed[key]})" if key in allowed else ""
            out.append(f"{key}: {what} {value}, over {limit}{was}: split it")
    for key, value in allowed.items():
        if key not in found:
            out.append(f"{key}: allowed {what} {value}, now within {limit} or gone: remove its allow-list entry")
    return out


def problems(package: Path, allowed_lines: dict | None = None, allowed_complexity: dict | None = None) -> list[str]:
    """Every function over a limit that is not allowed at its exact figure, and every allowed entry that no
    longer matches."""
    lines = {f.key: f.lines for f in long_functions(package)}
    out = _against(lines, ALLOWED_LINES if allowed_lines is None else allowed_lines, "lines", MAX_LINES)
    found = complexities(package)
    if found is not None:
        allowed = ALLOWED_COMPLEXITY if allowed_complexity is None else allowed_complexity
        out += _against(found, allowed, "complexity", MAX_COMPLEXITY)
    return out


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    package = Path(argv[0]) if argv else Path(__file__).resolve().parents[1] / "taichi_mpm"
    found = problems(package)
    for line in found:
        print(line)
    longest = max((f for f in functions(package) if not f.nested), key=lambda f: f.lines)
    print(f"{'FAIL' if found else 'ok'}: longest function {longest.key} {longest.lines} lines (limit {MAX_LINES}); "
          f"allowed over the limits: {len(ALLOWED_LINES)} by length, {len(ALLOWED_COMPLEXITY)} by complexity"
          + ("" if complexities(package) is not None else "; complexity not checked (no ruff)"))
    return 1 if found else 0


if __name__ == "__main__":
    sys.exit(main())
