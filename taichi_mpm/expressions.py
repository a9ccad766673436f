"""Safe arithmetic expressions of position and time for configs: `0.1*sin(pi*x/25)`, `min(t/0.01, 1)`.

No Python eval or exec: the text is parsed with `ast` and only a fixed grammar is accepted (docs/loads.md):
numbers, the variables a key allows (x, y, z for initial fields; t for time functions), the constants pi and e,
+ - * / ** %, unary minus, comparisons (giving 1 or 0), `a if cond else b`, `and`/`or`/`not`, and the functions
in FUNCTIONS. Evaluation is vectorised with numpy over arrays of particle positions.

Hostile input cannot hang or exhaust memory: the text is at most MAX_LENGTH characters and MAX_NODES syntax nodes
(so evaluation costs a bounded number of array operations), every number is a float (no big-integer powers), a
constant exponent is at most MAX_EXPONENT in size, and a non-finite result is an error naming the key.
"""
from __future__ import annotations

import ast
import math
import operator
from typing import Iterable

import numpy as np

from .errors import ConfigError

MAX_LENGTH = 500       # characters
MAX_NODES = 200        # ast nodes (numbers, names, operators, calls)
MAX_EXPONENT = 64      # |p| of a constant exponent in a ** p

CONSTANTS = {"pi": math.pi, "e": math.e}


def _minmax(reduce):
    def f(*args):
        out = args[0]
        for a in args[1:]:
            out = reduce(out, a)
        return out
    return f


# name -> (numpy function, smallest and largest number of arguments)
FUNCTIONS = {
    "sin": (np.sin, 1, 1), "cos": (np.cos, 1, 1), "tan": (np.tan, 1, 1),
    "asin": (np.arcsin, 1, 1), "acos": (np.arccos, 1, 1), "atan": (np.arctan, 1, 1), "atan2": (np.arctan2, 2, 2),
    "sinh": (np.sinh, 1, 1), "cosh": (np.cosh, 1, 1), "tanh": (np.tanh, 1, 1),
    "exp": (np.exp, 1, 1), "log": (np.log, 1, 1), "log10": (np.log10, 1, 1), "sqrt": (np.sqrt, 1, 1),
    "abs": (np.abs, 1, 1), "sign": (np.sign, 1, 1), "floor": (np.floor, 1, 1), "ceil": (np.ceil, 1, 1),
    "min": (_minmax(np.minimum), 2, 8), "max": (_minmax(np.maximum), 2, 8),
    "clip": (np.clip, 3, 3),                               # clip(v, lo, hi)
    "step": (lambda a: (np.asarray(a) >= 0).astype(float), 1, 1),  # Heaviside: 1 for a >= 0
}

_BINARY = {ast.Add: operator.add, ast.Sub: operator.sub, ast.Mult: operator.mul, ast.Div: operator.truediv,
           ast.Pow: operator.pow, ast.Mod: np.mod}
_COMPARE = {ast.Lt: np.less, ast.LtE: np.less_equal, ast.Gt: np.greater, ast.GtE: np.greater_equal,
            ast.Eq: np.equal, ast.NotEq: np.not_equal}
_OP_TEXT = {ast.BitXor: "^ (use ** for powers)", ast.FloorDiv: "//", ast.MatMult: "@", ast.LShift: "<<",
            ast.RShift: ">>", ast.BitAnd: "&", ast.BitOr: "|", ast.Invert: "~"}


class Expression:
    """A parsed, checked expression; `evaluate(**variables)` returns a float or a numpy array."""

    def __init__(self, text: str, variables: Iterable[str], key: str | None = None):
        self.text, self.key = text, key
        self.allowed = tuple(variables)
        self.tree = parse(text, self.allowed, key)
        self.names = sorted({n.id for n in ast.walk(self.tree) if isinstance(n, ast.Name)} & set(self.allowed))

    def __repr__(self):
        return f"Expression({self.text!r})"

    def evaluate(self, **values):
        """Vectorised value; the result is broadcast against the inputs. Non-finite values are ConfigErrors."""
        with np.errstate(all="ignore"):
            out = _eval(self.tree.body, values, self.key)
        arrays = [np.asarray(v) for v in values.values()]
        shape = np.broadcast_shapes(*[a.shape for a in arrays]) if arrays else ()
        out = np.broadcast_to(np.asarray(out, dtype=np.float64), shape).copy()
        if not np.isfinite(out).all():
            bad = np.flatnonzero(~np.isfinite(out.ravel()))[0]
            at = ", ".join(f"{k}={np.broadcast_to(np.asarray(v, float), shape).ravel()[bad]:.6g}"
                           for k, v in values.items())
            raise ConfigError(f"expression {_brief(self.text)} is not a finite number" + (f" at {at}" if at else ""),
                              key=self.key)
        return out if shape else float(out)


def parse(text: str, variables: Iterable[str], key: str | None = None) -> ast.Expression:
    """Parse and check `text`; ConfigError (naming `key`) for anything outside the grammar or the size limits."""
    allowed = tuple(variables)
    if not isinstance(text, str):
        raise ConfigError(f"an expression must be text, got {type(text).__name__}", key=key)
    if len(text) > MAX_LENGTH:
        raise ConfigError(f"expression longer than {MAX_LENGTH} characters ({len(text)})", key=key)
    if not text.strip():
        raise ConfigError("empty expression", key=key)
    try:
        tree = ast.parse(text.strip(), mode="eval")
    except SyntaxError as e:
        raise ConfigError(f"expression {_brief(text)} is not valid: {e.msg}", key=key) from None
    except (RecursionError, MemoryError, ValueError):  # deep nesting, NUL bytes
        raise ConfigError(f"expression {_brief(text)} is nested too deeply or holds invalid characters",
                          key=key) from None
    count, callees = 0, set()
    for node in ast.walk(tree):
        count += 1
        if count > MAX_NODES:
            raise ConfigError(f"expression has more than {MAX_NODES} terms", key=key)
        if id(node) not in callees:  # a function's name is checked with its call
            _check(node, allowed, text, key)
        if isinstance(node, ast.Call):
            callees.add(id(node.func))
    return tree


def _check(node, allowed, text, key):
    """One syntax node against the grammar: a ConfigError naming the key for anything else."""
    def bad(why):
        raise ConfigError(f"expression {_brief(text)}: {why}", key=key)

    if isinstance(node, (ast.Expression, ast.Load, ast.IfExp, ast.BoolOp, ast.And, ast.Or, ast.Not, ast.USub,
                         ast.UAdd)):
        return
    check = _NODE_CHECKS.get(type(node))
    if check is not None:
        check(node, allowed, bad)
    elif isinstance(node, (ast.Lt, ast.LtE, ast.Gt, ast.GtE, ast.Eq, ast.NotEq)) or type(node) in _BINARY:
        return
    else:
        bad(f"{type(node).__name__} is not allowed (numbers, names, arithmetic, comparisons, "
            f"'a if c else b' and functions only)")


def _check_constant(node, allowed, bad):
    if isinstance(node.value, bool) or not isinstance(node.value, (int, float)):
        bad(f"only numbers are allowed, not {node.value!r}")
    try:
        if not math.isfinite(float(node.value)):
            bad(f"the number {node.value!r} is not finite")
    except OverflowError:
        bad("a number is too large")


def _check_name(node, allowed, bad):
    if node.id not in allowed and node.id not in CONSTANTS:
        if node.id in FUNCTIONS:
            bad(f"'{node.id}' is a function: write {node.id}(...)")
        names = ", ".join(list(allowed) + list(CONSTANTS))
        bad(f"unknown name '{node.id}' (allowed here: {names}; functions: {', '.join(FUNCTIONS)})")


def _check_binop(node, allowed, bad):
    if type(node.op) not in _BINARY:
        bad(f"operator {_OP_TEXT.get(type(node.op), type(node.op).__name__)} is not allowed")
    if isinstance(node.op, ast.Pow):
        p = _constant_value(node.right)
        if p is not None and abs(p) > MAX_EXPONENT:
            bad(f"exponent {p:g} is larger than {MAX_EXPONENT}")


def _check_unary(node, allowed, bad):
    if type(node.op) not in (ast.USub, ast.UAdd, ast.Not):
        bad(f"operator {_OP_TEXT.get(type(node.op), type(node.op).__name__)} is not allowed")


def _check_compare(node, allowed, bad):
    if any(type(op) not in _COMPARE for op in node.ops):
        bad("only the comparisons < <= > >= == != are allowed")


def _check_call(node, allowed, bad):
    if not isinstance(node.func, ast.Name) or node.func.id not in FUNCTIONS:
        name = node.func.id if isinstance(node.func, ast.Name) else ast.dump(node.func)[:30]
        bad(f"unknown function {name!r} (functions: {', '.join(FUNCTIONS)})")
    if node.keywords or any(isinstance(a, ast.Starred) for a in node.args):
        bad(f"{node.func.id}() takes plain arguments only")
    _, lo, hi = FUNCTIONS[node.func.id]
    if not lo <= len(node.args) <= hi:
        want = f"{lo}" if lo == hi else f"{lo} to {hi}"
        bad(f"{node.func.id}() takes {want} argument{'s' if hi > 1 else ''}, got {len(node.args)}")


_NODE_CHECKS = {ast.Constant: _check_constant, ast.Name: _check_name, ast.BinOp: _check_binop,
                ast.UnaryOp: _check_unary, ast.Compare: _check_compare, ast.Call: _check_call}


def _constant_value(node):
    """The value of a constant exponent (a number, possibly negated), else None."""
    sign = 1.0
    while isinstance(node, ast.UnaryOp) and isinstance(node.op, (ast.USub, ast.UAdd)):
        sign = -sign if isinstance(node.op, ast.USub) else sign
        node = node.operand
    if isinstance(node, ast.Constant) and isinstance(node.value, (int, float)):
        return sign * float(node.value)
    return None


def _eval(node, values, key):
    if isinstance(node, ast.Constant):
        return float(node.value)
    if isinstance(node, ast.Name):
        if node.id in values:
            return np.asarray(values[node.id], dtype=np.float64)
        if node.id in CONSTANTS:
            return CONSTANTS[node.id]
        raise ConfigError(f"no value for '{node.id}' in this expression", key=key)
    if isinstance(node, ast.BinOp):
        left, right = _eval(node.left, values, key), _eval(node.right, values, key)
        if isinstance(node.op, ast.Pow):  # a ** p with a non-constant p: bounded the same way
            right = np.clip(right, -MAX_EXPONENT, MAX_EXPONENT)
            return np.power(np.asarray(left, float), right)
        return _BINARY[type(node.op)](np.asarray(left, float), right)
    if isinstance(node, ast.UnaryOp):
        v = _eval(node.operand, values, key)
        if isinstance(node.op, ast.Not):
            return (np.asarray(v) == 0).astype(float)
        return -np.asarray(v, float) if isinstance(node.op, ast.USub) else v
    if isinstance(node, ast.Compare):
        left = _eval(node.left, values, key)
        result = True
        for op, comp in zip(node.ops, node.comparators):
            right = _eval(comp, values, key)
            result = np.logical_and(result, _COMPARE[type(op)](left, right))
            left = right
        return np.asarray(result, float)
    if isinstance(node, ast.BoolOp):
        parts = [np.asarray(_eval(v, values, key)) != 0 for v in node.values]
        combine = np.logical_and if isinstance(node.op, ast.And) else np.logical_or
        out = parts[0]
        for p in parts[1:]:
            out = combine(out, p)
        return np.asarray(out, float)
    if isinstance(node, ast.IfExp):
        cond = np.asarray(_eval(node.test, values, key)) != 0
        return np.where(cond, _eval(node.body, values, key), _eval(node.orelse, values, key))
    if isinstance(node, ast.Call):
        fn = FUNCTIONS[node.func.id][0]
        return fn(*[np.asarray(_eval(a, values, key), float) for a in node.args])
    raise ConfigError(f"cannot evaluate {type(node).__name__}", key=key)  # unreachable after parse()


def _brief(text: str) -> str:
    return repr(text) if len(text) <= 60 else repr(text[:57]) + "..."


def evaluate(value, key: str | None, variables: Iterable[str], **values):
    """A number or an expression text -> its value (broadcast against `values`)."""
    if isinstance(value, str):
        return Expression(value, variables, key).evaluate(**values)
    arrays = [np.asarray(v) for v in values.values()]
    shape = np.broadcast_shapes(*[a.shape for a in arrays]) if arrays else ()
    return np.full(shape, float(value)) if shape else float(value)


def largest_magnitude(value, variables: Iterable[str], **values) -> float:
    """The largest finite |value| of a number (None: 0) or an expression over sample points (non-finite samples are left
    out: where they matter the evaluation at the particles reports them). Config checks of magnitudes."""
    if value is None:   # a free component
        return 0.0
    if not isinstance(value, str):
        return abs(float(value))
    try:
        tree = parse(value, tuple(variables))
        with np.errstate(all="ignore"):
            out = np.abs(np.asarray(_eval(tree.body, values, None), dtype=np.float64))
    except (ConfigError, ArithmeticError, ValueError, TypeError):
        return 0.0
    out = out[np.isfinite(out)]
    return float(out.max()) if out.size else 0.0
