"""Trace-time helpers: plain Python that builds Taichi expressions while a kernel is being compiled.

Taichi (1.7) compiles a `@ti.func` by walking its Python syntax tree node by node, at about 15 microseconds per
node, again at every call and every iteration of a `ti.static` loop; that walk is the larger part of a warm first
step (the compiled code itself comes from the offline cache). A plain Python function called from a kernel runs
once, at Python speed, and its operators on Taichi expressions build the same IR. This module holds such functions
for the small, hot, branch-free pieces: Taichi's own matrix helpers (`@`, transpose, determinant, inverse, outer
products, sums; `install()` swaps them in for kernel scope) and what the stencils need (element access, select,
a local copy). They may not branch on run-time values (use `select`) and take their arguments by value as a func
does (`local`), so that an argument expression is evaluated once.

Physics code only: no CLI, rendering or file I/O here.
"""

from taichi.lang import impl, matrix_ops, ops
from taichi.lang.matrix import make_matrix


class _NoPrint:
    has_print = False


def traced(fn):
    """Mark a plain Python function that kernels call: Taichi calls it as it is, without its warning about
    "non-taichi" functions (Taichi reads `.func.has_print` of what it takes for its own functions)."""
    fn._is_taichi_function = True
    fn.func = _NoPrint
    return fn


def local(value):
    """A local copy of `value` (a func's by-value argument): later reads load it instead of re-evaluating it."""
    return impl.expr_init_func(value)


def at(m, *index):
    """m[index] for a Taichi matrix expression or a Python-side Matrix, in kernel scope."""
    return impl.subscript(None, m, *index)


def select(cond, a, b):
    return ops.select(cond, a, b)


def total(terms):
    """terms[0] + terms[1] + ... in that order (the order Taichi's own matrix helpers add in)."""
    s = terms[0]
    for t in terms[1:]:
        s = s + t
    return s


def diagonal(values):
    """The diagonal matrix of `values` (float)."""
    n = len(values)
    return make_matrix([[values[a] if b == a else 0.0 for b in range(n)] for a in range(n)], float)


def _shape(m):
    return m.get_shape()


def matmul(x, y):
    x, y = local(x), local(y)
    sx, sy = _shape(x), _shape(y)
    if len(sx) == 1 and len(sy) == 1:
        return dot(x, y)
    if len(sx) == 1:   # vector @ matrix: the vector as a row
        return make_matrix([total([at(x, k) * at(y, k, j) for k in range(sx[0])]) for j in range(sy[1])])
    if len(sy) == 1:
        return make_matrix([total([at(x, i, k) * at(y, k) for k in range(sx[1])]) for i in range(sx[0])])
    return make_matrix([[total([at(x, i, k) * at(y, k, j) for k in range(sx[1])]) for j in range(sy[1])]
                        for i in range(sx[0])])


def dot(x, y):
    x, y = local(x), local(y)
    return total([at(x, i) * at(y, i) for i in range(_shape(x)[0])])


def outer_product(x, y):
    x, y = local(x), local(y)
    return make_matrix([[at(x, i) * at(y, j) for j in range(_shape(y)[0])] for i in range(_shape(x)[0])])


def transpose(m):
    m = local(m)
    rows, cols = _shape(m)
    return make_matrix([[at(m, i, j) for i in range(rows)] for j in range(cols)])


def elements(m):
    """The entries of a vector or matrix expression, row by row."""
    shape = _shape(m)
    if len(shape) == 1:
        return [at(m, i) for i in range(shape[0])]
    return [at(m, i, j) for i in range(shape[0]) for j in range(shape[1])]


def sum_(m):
    return total(elements(local(m)))


def norm_sqr(m):
    return sum_(m * m)


def trace(m):
    m = local(m)
    return total([at(m, i, i) for i in range(_shape(m)[0])])


def _cyclic(m, n):
    """E(i, j) = m[i mod n, j mod n]: the cofactor formulas of Taichi's determinant and inverse."""
    return lambda i, j: at(m, i % n, j % n)


def _det(m, n):
    E = _cyclic(m, n)
    if n == 1:
        return E(0, 0)
    if n == 2:
        return E(0, 0) * E(1, 1) - E(0, 1) * E(1, 0)
    return (E(0, 0) * (E(1, 1) * E(2, 2) - E(2, 1) * E(1, 2))
            - E(1, 0) * (E(0, 1) * E(2, 2) - E(2, 1) * E(0, 2))
            + E(2, 0) * (E(0, 1) * E(1, 2) - E(1, 1) * E(0, 2)))


def determinant(m):
    m = local(m)
    return _det(m, _shape(m)[0])


def inverse(m):
    m = local(m)
    n = _shape(m)[0]
    if n == 1:
        return make_matrix([[1.0 / at(m, 0, 0)]])
    inv_det = 1.0 / _det(m, n)
    if n == 2:
        return inv_det * make_matrix([[at(m, 1, 1), -at(m, 0, 1)], [-at(m, 1, 0), at(m, 0, 0)]])
    E = _cyclic(m, 3)
    return inv_det * make_matrix([[E(i + 1, j + 1) * E(i + 2, j + 2) - E(i + 2, j + 1) * E(i + 1, j + 2)
                                   for i in range(3)] for j in range(3)])


def _filled_vector(n, dtype, val):
    return make_matrix([val for _ in range(n)], dtype)


def _filled_matrix(n, m, dtype, val):
    return make_matrix([[val for _ in range(m)] for _ in range(n)], dtype)


def _identity_matrix(n, dtype):
    return make_matrix([[i == j for j in range(n)] for i in range(n)], dtype)


def _square_upto_3(m):
    shape = _shape(m)
    return len(shape) == 2 and shape[0] == shape[1] and shape[0] <= 3


# Taichi's matrix helper -> (trace-time version, when it applies: else Taichi's own, with its checks and messages)
_OPS = {
    "matmul": (matmul, lambda x, y: len(_shape(x)) + len(_shape(y)) >= 3 and _shape(x)[-1] == _shape(y)[0]),
    "dot": (dot, lambda x, y: len(_shape(x)) == len(_shape(y)) == 1 and _shape(x) == _shape(y)),
    "outer_product": (outer_product, lambda x, y: len(_shape(x)) == len(_shape(y)) == 1),
    "transpose": (transpose, lambda m: len(_shape(m)) == 2),
    "sum": (sum_, lambda m: len(_shape(m)) in (1, 2)),
    "norm_sqr": (norm_sqr, lambda m: len(_shape(m)) in (1, 2)),
    "trace": (trace, _square_upto_3),
    "determinant": (determinant, _square_upto_3),
    "inverse": (inverse, _square_upto_3),
    "_filled_vector": (_filled_vector, lambda n, dtype, val: True),
    "_filled_matrix": (_filled_matrix, lambda n, m, dtype, val: True),
    "_identity_matrix": (_identity_matrix, lambda n, dtype: True),
}


def install():
    """Use the trace-time versions of Taichi's matrix helpers inside kernels (once per process). Outside a kernel,
    with keyword arguments, or where the shapes are not what a version handles, Taichi's own runs."""
    for name, (fast, applies) in _OPS.items():
        original = getattr(matrix_ops, name, None)
        if original is None or getattr(original, "_traced", False):
            continue

        def dispatch(*args, _original=original, _fast=fast, _applies=applies, **kwargs):
            if not kwargs and impl.inside_kernel():
                try:
                    use = _applies(*args)
                except (AttributeError, TypeError, IndexError, ValueError):   # not a tensor: Taichi's message
                    use = False
                if use:
                    return _fast(*args)
            return _original(*args, **kwargs)

        traced(dispatch)
        dispatch._traced = True
        dispatch.__wrapped__ = original
        setattr(matrix_ops, name, dispatch)
