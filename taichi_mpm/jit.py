"""Faster kernel building: Taichi re-reads and re-formats source text for every func call and syntax node.

Taichi (1.7) turns each kernel's Python AST into its IR on every first call, also when the compiled kernel then
comes from the offline cache (the cache is keyed by that IR). For every node it visits it formats a "File ...,
line ..." excerpt with a caret line through `textwrap` (`ASTTransformerContext.get_pos_info`), kept for error
messages. Statically unrolled stencils and inlined funcs visit the same source lines many times: the first step of
a 3D quadratic scene formatted 38 000 excerpts of ~700 distinct nodes, about 40 % of the AST time. The excerpt
depends only on the node's place in its source, so `install()` caches it by that place. It also caches each
func's source lines, which Taichi reads anew (inspect, tokenize) at each of the ~600 inlined calls of such a step.
Messages are unchanged (tests/test_jit.py compares them with Taichi's own). Together: the first step of that scene
with a filled offline cache 2.6 -> 1.2 s, with an empty one 8.0 -> 6.1 s (docs/performance.md, "Compile time").

Physics code only: no CLI, rendering or file I/O here.
"""

import linecache
import sys
import weakref

from . import traced

_CACHE_SIZE = 1 << 16


def _key(ctx, node):
    body = getattr(node, "body", None)
    first_body_line = body[0].lineno if isinstance(body, list) and body and hasattr(body[0], "lineno") else None
    return (ctx.file, ctx.lineno_offset, ctx.indent, ctx.func.func.__name__, type(node).__name__,
            node.lineno, getattr(node, "end_lineno", None), getattr(node, "col_offset", None),
            getattr(node, "end_col_offset", None), first_body_line)


def install():
    """Cache ASTTransformerContext.get_pos_info by source position (once per process; a no-op if Taichi's
    internals differ from what this expects)."""
    try:
        from taichi.lang.ast.ast_transformer_utils import ASTTransformerContext
    except ImportError:
        return False
    original = getattr(ASTTransformerContext, "get_pos_info", None)
    if original is None or getattr(original, "_cached", False):
        return original is not None
    cache = {}

    def get_pos_info(self, node, *args, **kwargs):
        if args or kwargs:           # a Taichi whose signature differs: no caching
            return original(self, node, *args, **kwargs)
        try:
            key = _key(self, node)
        except AttributeError:       # a context or node shaped differently: no caching
            return original(self, node)
        text = cache.get(key)
        if text is None:
            if len(cache) >= _CACHE_SIZE:
                cache.clear()
            text = cache[key] = original(self, node)
        return text

    get_pos_info._cached = True
    get_pos_info._original = original
    ASTTransformerContext.get_pos_info = get_pos_info
    _cache_source_lines()
    _fast_class_check()
    traced.install()
    return True


def _cache_source_lines():
    try:
        from taichi.lang import kernel_impl
    except ImportError:
        return
    read_lines, read_file = getattr(kernel_impl, "getsourcelines", None), getattr(kernel_impl, "getsourcefile", None)
    if read_lines is None or read_file is None or getattr(read_lines, "_cached", False):
        return
    lines, files = weakref.WeakKeyDictionary(), weakref.WeakKeyDictionary()   # funcs of dropped simulations go

    def getsourcelines(obj, *args, **kwargs):
        if args or kwargs:
            return read_lines(obj, *args, **kwargs)
        try:
            found = lines.get(obj)
        except TypeError:            # not weak-referenceable: read as Taichi does
            return read_lines(obj)
        if found is None:
            src, start = read_lines(obj)
            found = lines[obj] = (tuple(src), start)
        return list(found[0]), found[1]

    def getsourcefile(obj, *args, **kwargs):
        if args or kwargs:
            return read_file(obj, *args, **kwargs)
        try:
            found = files.get(obj)
        except TypeError:
            return read_file(obj)
        if found is None:
            found = files[obj] = read_file(obj)
        return found

    getsourcelines._cached = True
    kernel_impl.getsourcelines, kernel_impl.getsourcefile = getsourcelines, getsourcefile


def _fast_class_check():
    """Taichi asks, for every @ti.func and @ti.kernel it decorates, whether the decorator sits in a class body: it
    reads the caller's source line through inspect.getframeinfo, which looks the module up among all loaded ones
    (about 0.5 ms a call, ~150 calls while a simulation builds its kernels). The line itself comes from linecache
    directly here; the answer is the same (tests/test_jit.py)."""
    try:
        from taichi.lang import kernel_impl
        patterns = kernel_impl._KERNEL_CLASS_STACKFRAME_STMT_RES
        original = kernel_impl._inside_class
    except (ImportError, AttributeError):
        return
    if getattr(original, "_cached", False):
        return

    def inside_class(level_of_class_stackframe):
        try:
            frame = sys._getframe(level_of_class_stackframe)
            line = linecache.getline(frame.f_code.co_filename, frame.f_lineno, frame.f_globals).strip()
        except (ValueError, AttributeError):
            return False
        return any(p.match(line) for p in patterns)

    inside_class._cached = True
    inside_class._original = original
    kernel_impl._inside_class = inside_class
