"""The safe expression evaluator (taichi_mpm/expressions.py): values against numpy written out by hand, the grammar's
refusals, the size limits, and fuzzing: any text gives a value or a ConfigError, quickly, and never runs code."""
import math
import time

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from taichi_mpm.errors import ConfigError
from taichi_mpm.expressions import FUNCTIONS, MAX_LENGTH, MAX_NODES, Expression, evaluate

X = np.linspace(-2.0, 3.0, 11)


@pytest.mark.parametrize("text, expected", [
    ("0.1*sin(pi*x/25)", 0.1 * np.sin(np.pi * X / 25)),
    ("x**2 - 3*x + 1", X**2 - 3 * X + 1),
    ("-x", -X),
    ("2**-1", np.full_like(X, 0.5)),
    ("exp(-x**2) + log(1 + x**2) + sqrt(abs(x))", np.exp(-X**2) + np.log1p(X**2) + np.sqrt(np.abs(X))),
    ("min(x, 1) + max(x, 0, -5)", np.minimum(X, 1) + np.maximum(X, 0)),
    ("1 if x < 0 else x", np.where(X < 0, 1, X)),
    ("(x > 0) * x", np.where(X > 0, X, 0)),
    ("0 < x <= 1", ((X > 0) & (X <= 1)).astype(float)),
    ("x > 0 and x < 1 or x == -2", (((X > 0) & (X < 1)) | (X == -2)).astype(float)),
    ("not x", (X == 0).astype(float)),
    ("x % 2", np.mod(X, 2)),
    ("atan2(x, 1) + tanh(x) + clip(x, -1, 1) + step(x)",
     np.arctan2(X, 1) + np.tanh(X) + np.clip(X, -1, 1) + (X >= 0)),
    ("e", np.full_like(X, math.e)),
])
def test_values_match_numpy(text, expected):
    np.testing.assert_allclose(Expression(text, ("x",)).evaluate(x=X), expected, rtol=1e-14, atol=1e-15)


def test_scalars_and_broadcasting():
    assert Expression("min(t / 0.01, 1)", ("t",)).evaluate(t=0.005) == pytest.approx(0.5)
    assert evaluate(2.5, "k", ("x",), x=X).shape == X.shape  # a number broadcasts like an expression
    out = Expression("x + y", ("x", "y")).evaluate(x=X, y=1.0)
    np.testing.assert_allclose(out, X + 1)


@pytest.mark.parametrize("text, says", [
    ("__import__('os').system('echo hi')", "unknown function"),
    ("x.real", "Attribute"),
    ("().__class__", "Attribute"),
    ("[x for x in (1,)]", "not allowed"),
    ("lambda: 1", "Lambda"),
    ("x[0]", "Subscript"),
    ("'text'", "only numbers"),
    ("True", "only numbers"),
    ("1j", "only numbers"),
    ("y", "unknown name 'y'"),
    ("sin", "is a function"),
    ("sin(1, 2)", "takes 1 argument"),
    ("max(x)", "takes 2 to 8"),
    ("sin(x=1)", "plain arguments"),
    ("sin(*x)", "plain arguments"),
    ("x ^ 2", "use ** for powers"),
    ("x // 2", "//"),
    ("2 ** 65", "exponent 65"),
    ("x ** -100", "exponent -100"),
    ("1e400", "not finite"),
    ("x if 1", "not valid"),
    ("x = 1", "not valid"),
    ("", "empty"),
    ("x\x00", "not valid"),
])
def test_refused_with_the_key(text, says):
    with pytest.raises(ConfigError) as e:
        Expression(text, ("x",), key="bodies.0.velocity.0")
    assert e.value.key == "bodies.0.velocity.0" and says in str(e.value)


def test_size_limits():
    with pytest.raises(ConfigError, match="longer than"):
        Expression("x+" * MAX_LENGTH + "x", ("x",))
    with pytest.raises(ConfigError, match=f"more than {MAX_NODES}"):
        Expression("+".join(["x"] * (MAX_NODES // 2)), ("x",))
    # nesting: parentheses alone are no terms; nested calls are refused (node limit or parser), never a RecursionError
    assert Expression("(" * 150 + "x" + ")" * 150, ("x",)).evaluate(x=2.0) == 2.0
    with pytest.raises(ConfigError):
        Expression("sin(" * 160 + "x" + ")" * 160, ("x",))
    with pytest.raises(ConfigError):
        Expression("-" * 450 + "x", ("x",))


def test_non_finite_values_name_the_point():
    with pytest.raises(ConfigError, match=r"not a finite number at x=-1") as e:
        Expression("log(x)", ("x",), key="k").evaluate(x=np.array([1.0, -1.0]))
    assert e.value.key == "k"
    with pytest.raises(ConfigError, match="not a finite"):
        Expression("1 / (t - 1)", ("t",)).evaluate(t=1.0)


def test_towers_of_powers_stay_bounded():
    # every number is a float and an exponent is clipped to 64: no big integers, at worst inf (then an error)
    t0 = time.perf_counter()
    for text in ("9**9**9**9", "x**x**x**x**x**x", "2**64**64"):
        try:
            Expression(text, ("x",)).evaluate(x=np.full(1000, 3.0))
        except ConfigError:
            pass
    assert time.perf_counter() - t0 < 5.0   # a big-integer tower would take minutes; 5 s leaves room for a loaded machine


# ---------------------------------------------------------------- fuzzing
ATOMS = ["x", "t", "pi", "e", "1", "0", "2.5", "1e3", "-1", "y", "q", "__import__", "os", "'a'", "None", "[1]"]
OPS = ["+", "-", "*", "/", "**", "%", "<", "==", " and ", " or ", " if ", " else ", "^", "//", "@", ".", ",", "="]
FUNCS = list(FUNCTIONS) + ["eval", "exec", "open", "getattr"]


@st.composite
def expression_texts(draw):
    """Mostly well-formed expressions built from the grammar's pieces and some outside it; then noise."""
    def term(depth):
        kind = draw(st.integers(0, 3 if depth < 4 else 0))
        if kind == 0:
            return draw(st.sampled_from(ATOMS))
        if kind == 1:
            return f"({term(depth + 1)}{draw(st.sampled_from(OPS))}{term(depth + 1)})"
        if kind == 2:
            args = ", ".join(term(depth + 1) for _ in range(draw(st.integers(0, 3))))
            return f"{draw(st.sampled_from(FUNCS))}({args})"
        return f"-{term(depth + 1)}"
    text = term(0)
    if draw(st.booleans()):
        pos = draw(st.integers(0, len(text)))
        text = text[:pos] + draw(st.text(max_size=4)) + text[pos:]
    return text


@settings(max_examples=800, deadline=None, derandomize=True, database=None,
          suppress_health_check=list(HealthCheck))
@given(st.one_of(expression_texts(), st.text(max_size=40)))
def test_fuzz_only_values_or_config_errors(text):
    t0 = time.perf_counter()
    try:
        out = Expression(text, ("x", "t"), key="k").evaluate(x=X, t=0.5)
        assert out.shape == X.shape and np.isfinite(out).all()
    except ConfigError as e:
        assert e.key == "k"
    assert time.perf_counter() - t0 < 2.0   # bounded work per text (ms); 2 s only catches a runaway
