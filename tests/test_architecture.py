"""The package's shape (docs/architecture.md, "Layers and who may import whom"): no import cycle among the modules
of taichi_mpm/ (imports inside functions included: a lazy import is still a dependency), the physics core imports
no tool, I/O or window module, and no function is longer or more complex than the limits (tools/function_size.py,
also run by .ci/run)."""
from __future__ import annotations

import ast
import importlib.util
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "taichi_mpm"

# The layers, lowest first (docs/architecture.md, "Layers and who may import whom"): a module imports only modules
# of its own layer or a lower one. Named by the dotted path under taichi_mpm/; the longest listed prefix places a
# module ("io" covers io.runner, "io.render_options" only itself).
LAYERS = {
    # plain building blocks: errors, schema pieces, expressions, knot and map geometry, the material registry, the
    # output-field registry and the names render settings accept, Taichi trace-time helpers, the bases registry,
    # the field declarations, the transfer-scheme registry (its declarations and gradient pieces)
    "foundation": ("errors", "schema", "geometry", "expressions", "bases.registry", "bases.knots", "bases.mapgeom",
                   "traced", "jit", "sums", "host_copy", "host_scalars", "materials", "fields", "field_decl", "schemes",
                   "io.colour_range", "io.render_options", "tools.window_layout"),
    "config": ("config",),
    # what a simulation is made of; it reads a Config and writes nothing a user sees
    "physics": ("grid", "bases", "extensions", "loads", "scene", "backend", "states", "causes", "step", "layout",
                "budget", "solver", "analytic", "friction", "tearing"),
    # output files, probes, the output-writing run, frames and plots
    "outputs": ("io", "probes"),
    # the tools: studies, stability scenarios and the CFL search, advise, compare, the windows, the config reference
    "tools": ("tools",),
    "commands": ("cli", "__main__", ""),   # "": the package's __init__ (the public API)
}
# the physics core, and the modules it may never import (issue 26)
PHYSICS = ("solver", "bases", "grid", "materials", "extensions", "sums", "host_copy", "host_scalars", "traced", "jit",
           "scene", "loads", "analytic", "budget", "backend", "states", "causes", "step", "fields", "layout",
           "field_decl", "schemes", "friction", "tearing")
TOOLS = ("cli", "io", "tools", "probes")


def module_files(package: Path) -> dict[str, Path]:
    """Dotted module name -> file, for every module under `package` (a package is named by its __init__.py)."""
    out = {}
    for path in sorted(package.rglob("*.py")):
        parts = list(path.relative_to(package.parent).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts.pop()
        out[".".join(parts)] = path
    return out


def _absolute(module: str, is_package: bool, level: int, name: str | None) -> str:
    """The absolute name of a relative import `from .{level} name import ...` written in `module`."""
    if level == 0:
        return name or ""
    base = module.split(".")
    if not is_package:
        base = base[:-1]           # a module's `.` is its package
    base = base[:len(base) - (level - 1)]
    return ".".join(base + ([name] if name else []))


def imports_of(module: str, path: Path, known: set[str]) -> set[str]:
    """The project modules `module` imports, anywhere in its file (module level, functions, __main__ blocks).
    `from pkg import name` depends on the submodule pkg.name when there is one, else on pkg itself."""
    tree = ast.parse(path.read_text(), str(path))
    is_package = path.name == "__init__.py"
    deps = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            deps.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            target = _absolute(module, is_package, node.level, node.module)
            subs = {f"{target}.{a.name}" for a in node.names} & known
            deps.update(subs)
            if len(subs) < len(node.names):   # some names are attributes of `target` itself
                deps.add(target)
    top = module.split(".")[0]
    return {d for d in deps if d in known and d != module and d != top}


def import_graph(package: Path = PACKAGE) -> dict[str, set[str]]:
    files = module_files(package)
    return {m: imports_of(m, p, set(files)) for m, p in files.items()}


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (each holds an import cycle), or a module that
    imports itself; iterative Tarjan, so deep graphs need no recursion."""
    index, low, on_stack, stack, found = {}, {}, set(), [], []
    counter = 0
    for root in graph:
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = counter
        counter += 1
        stack.append(root)
        on_stack.add(root)
        while work:
            v, edges = work[-1]
            w = next(edges, None)
            if w is not None:
                if w not in index:
                    index[w] = low[w] = counter
                    counter += 1
                    stack.append(w)
                    on_stack.add(w)
                    work.append((w, iter(sorted(graph.get(w, ())))))
                elif w in on_stack:
                    low[v] = min(low[v], index[w])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[v])
            if low[v] == index[v]:
                comp = []
                while True:
                    w = stack.pop()
                    on_stack.discard(w)
                    comp.append(w)
                    if w == v:
                        break
                if len(comp) > 1 or v in graph.get(v, ()):
                    found.append(sorted(comp))
    return found


def _place(module: str, names) -> str | None:
    """The longest of `names` that is taichi_mpm.x.y's path under the package or a prefix of it ("" for the
    package itself), or None."""
    rel = module.split(".")[1:]
    for n in range(len(rel), -1, -1):
        key = ".".join(rel[:n])
        if key in names and (n or not rel):
            return key
    return None


def _in(module: str, names) -> bool:
    return _place(module, names) is not None


def layer_of(module: str) -> int:
    every = [n for names in LAYERS.values() for n in names]
    key = _place(module, every)
    for rank, names in enumerate(LAYERS.values()):
        if key is not None and key in names:
            return rank
    raise KeyError(f"{module} is in no layer of tests/test_architecture.py LAYERS: place it there")


def test_the_package_has_no_import_cycle():
    found = cycles(import_graph())
    assert not found, "import cycles: " + "; ".join(" <-> ".join(c) for c in found)


def test_the_physics_core_imports_no_tool_io_or_window_module():
    graph = import_graph()
    bad = sorted((m, d) for m, deps in graph.items() if _in(m, PHYSICS) for d in deps if _in(d, TOOLS))
    assert not bad, "\n".join(f"{m} imports {d}" for m, d in bad)


def test_every_module_imports_only_its_own_layer_or_lower_ones():
    graph = import_graph()
    names = list(LAYERS)
    up = sorted((m, d) for m, deps in graph.items() for d in deps if layer_of(d) > layer_of(m))
    assert not up, "\n".join(f"{m} ({names[layer_of(m)]}) imports {d} ({names[layer_of(d)]})" for m, d in up)


def test_the_tool_modules_import_no_private_name_of_another_module():
    """`from .study import _finished` ties one tool to another's insides: shared things get a public name. (The
    outputs, tools and commands layers; the physics core still shares schema._no_bool and grid._pow2.)"""
    bad = []
    tool_layers = list(LAYERS).index("outputs")
    for module, path in module_files(PACKAGE).items():
        if layer_of(module) < tool_layers:
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and (node.level or (node.module or "").startswith("taichi_mpm")):
                bad += [f"{module}: from {'.' * node.level}{node.module or ''} import {a.name}" for a in node.names
                        if a.name.startswith("_") and not a.name.startswith("__")]
    assert not bad, "\n".join(bad)


def test_every_named_module_exists():
    """The lists above name real modules (a renamed module would silently leave the checks)."""
    names = {".".join(m.split(".")[1:]) for m in module_files(PACKAGE)}
    listed = set(PHYSICS + TOOLS).union(*LAYERS.values())
    assert listed <= names, sorted(listed - names)


# ---------------------------------------------------------------- the checker itself
def _write(root: Path, files: dict[str, str]) -> Path:
    for rel, text in files.items():
        p = root / "pkg" / rel
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_text(text)
    return root / "pkg"


def test_a_cycle_through_a_function_level_relative_import_is_found(tmp_path):
    pkg = _write(tmp_path, {"__init__.py": "", "a.py": "from .b import f\n",
                            "b.py": "def f():\n    from . import a\n    return a\n", "c.py": "from . import a\n"})
    assert cycles(import_graph(pkg)) == [["pkg.a", "pkg.b"]]


def test_a_cycle_through_a_subpackage_and_its_parent_is_found(tmp_path):
    pkg = _write(tmp_path, {"__init__.py": "", "sub/__init__.py": "from .x import y\n",
                            "sub/x.py": "import pkg.top\ny = 1\n", "top.py": "def g():\n    from .sub import y\n"})
    assert cycles(import_graph(pkg)) == [["pkg.sub", "pkg.sub.x", "pkg.top"]]


def test_imports_without_a_cycle_pass(tmp_path):
    pkg = _write(tmp_path, {"__init__.py": "from .a import f\n", "a.py": "from .b import g\nfrom . import c\n",
                            "b.py": "import os\n", "c.py": "def h():\n    from .b import g\n"})
    assert cycles(import_graph(pkg)) == []
    assert import_graph(pkg)["pkg.a"] == {"pkg.b", "pkg.c"}


# ---------------------------------------------------------------- function size
def _size_tool():
    spec = importlib.util.spec_from_file_location("function_size", ROOT / "tools" / "function_size.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod   # (its dataclass looks its module up there)
    spec.loader.exec_module(mod)
    return mod


def test_no_function_is_longer_or_more_complex_than_the_limits():
    assert _size_tool().problems(PACKAGE) == []


def test_the_length_check_counts_nested_functions_in_their_enclosing_one(tmp_path):
    tool = _size_tool()
    body = "\n".join(f"        x{i} = {i}" for i in range(tool.MAX_LINES))
    (tmp_path / "m.py").write_text(f"@decorator\ndef outer():\n    def inner():\n{body}\n    return inner\n")
    assert [(f.name, f.lines) for f in tool.long_functions(tmp_path)] == [("outer", tool.MAX_LINES + 4)]
    assert tool.problems(tmp_path, allowed_lines={}, allowed_complexity={}) != []


def test_the_allow_lists_hold_exactly_the_current_figures(tmp_path):
    """An allowed function must match its figure: one that grew is reported, and so is one that got shorter (its
    entry must then go), so the lists only shrink."""
    tool = _size_tool()
    body = "\n".join(f"    x{i} = {i}" for i in range(tool.MAX_LINES + 10))
    (tmp_path / "m.py").write_text(f"def big():\n{body}\n\n\ndef small():\n    return 1\n")
    fits = {"m.py:big": tool.MAX_LINES + 11}
    assert tool.problems(tmp_path, fits, {}) == []
    assert tool.problems(tmp_path, {"m.py:big": tool.MAX_LINES + 10}, {}) != []          # grew
    assert tool.problems(tmp_path, {**fits, "m.py:small": 200}, {}) != []                 # shrank
    assert tool.problems(tmp_path, {**fits, "m.py:gone": 200}, {}) != []                  # gone


def test_the_complexity_check_finds_a_new_offender_and_holds_the_figures(tmp_path):
    tool = _size_tool()
    if tool.complexities(tmp_path) is None:
        pytest.skip("ruff is not installed (pip install -e '.[test]')")
    branches = "".join(f"        if x == {i}:\n            return {i}\n" for i in range(tool.MAX_COMPLEXITY + 1))
    (tmp_path / "m.py").write_text(f"class A:\n    def f(self, x):\n{branches}        return -1\n")
    figure = tool.MAX_COMPLEXITY + 2
    assert tool.complexities(tmp_path) == {"m.py:A.f": figure}
    assert tool.problems(tmp_path, {}, {}) != []
    assert tool.problems(tmp_path, {}, {"m.py:A.f": figure}) == []
    assert tool.problems(tmp_path, {}, {"m.py:A.f": figure + 1}) != []


def test_the_complexity_check_runs_where_ruff_cannot_keep_its_cache_and_never_passes_silently(tmp_path,
                                                                                              monkeypatch):
    """From a read-only checkout ruff could not create .ruff_cache in the working folder, printed nothing and the
    check read that as "no function over the limit" (this test's twin failed from the read-only copy). A file
    named .ruff_cache stands in for the read-only folder (root may write anywhere). A failing ruff is an error."""
    tool = _size_tool()
    if tool.complexities(tmp_path) is None:
        pytest.skip("ruff is not installed (pip install -e '.[test]')")
    work, pkg = tmp_path / "work", tmp_path / "pkg"
    work.mkdir()
    pkg.mkdir()
    (work / ".ruff_cache").write_text("not a folder")
    branches = "".join(f"        if x == {i}:\n            return {i}\n" for i in range(tool.MAX_COMPLEXITY + 1))
    (pkg / "m.py").write_text(f"class A:\n    def f(self, x):\n{branches}        return -1\n")
    monkeypatch.chdir(work)
    assert tool.complexities(pkg) == {"m.py:A.f": tool.MAX_COMPLEXITY + 2}
    import subprocess

    monkeypatch.setattr(subprocess, "run", lambda *a, **k: subprocess.CompletedProcess(a, 2, "", "error: boom"))
    with pytest.raises(RuntimeError, match="ruff failed \\(exit 2\\): error: boom"):
        tool.complexities(pkg)
