"""The safe expression parser (Expr) and interpolation tables (Table) of battlab.functions."""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from battlab.functions import Expr, Table, as_function, evaluate, to_json
from protocols.errors import InputError


def _casadi(f: Expr | Table, x: np.ndarray) -> np.ndarray:
    sym = ca.SX.sym("x")
    fun = ca.Function("f", [sym], [evaluate(f, sym, "casadi")])
    return np.array([float(fun(v)) for v in x])


@pytest.mark.parametrize(
    "text",
    [
        "0.194 + 1.5*exp(-120.0*x) + 0.0351*tanh((x - 0.286)/0.083)",
        "-0.8090*x + 4.4875 - 17.7326*tanh(15.7890*(x - 0.3117))",
        "1e-4*exp(2.302585093*(-4.43 - 54/(69.15 - 0.005*x) - 0.00022*x))",
        "(0.601 - 0.24*(x/1000)**0.5 + 0.96*(x/1000)**1.5)/(1 - 0.38) - 1",
        "sqrt(x) + log(x) + sinh(x) + cosh(x) + arctan(x) + abs(-x) + log10(x)",
        "atan(x) + ln(x) + pi*e + x^2 + +x",
    ],
)
def test_numpy_and_casadi_agree(text: str) -> None:
    f = Expr(text)
    x = np.array([0.05, 0.3, 0.7, 1.0, 2.5])
    ref = f(x)
    assert np.all(np.isfinite(ref))
    np.testing.assert_allclose(_casadi(f, x), ref, rtol=1e-13, atol=1e-15)


def test_caret_is_power_and_aliases() -> None:
    assert Expr("x^2")(3.0) == pytest.approx(9.0)
    assert Expr("ln(x)")(np.e) == pytest.approx(1.0)
    assert Expr("atan(x)")(1.0) == pytest.approx(np.pi / 4)
    assert Expr("2*pi")(0.0) == pytest.approx(2 * np.pi)


@pytest.mark.parametrize(
    "text",
    [
        "x.__class__",  # attribute access
        "(1).__class__.__bases__",
        "__import__('os').system('true')",  # call of a non-whitelisted name
        "eval('1')",
        "open('/etc/passwd')",
        "exec('x=1')",
        "getattr(x, 'real')",
        "os.system('true')",
        "exp.__globals__",
        "lambda: 1",
        "x[0]",  # subscript
        "x > 1",  # comparison
        "x if x else 1",
        "'abc'",  # string constant
        "True",  # bool constant
        "exp(x=1)",  # keyword
        "exp(x, 2)",  # two arguments
        "y + 1",  # unknown variable
        "[x for x in (1, 2)]",
        "(x := 2)",
        "x // 2",  # operator outside + - * / **
        "x % 2",
        "~x",
        "not x",
        "import os",  # statement
        "x +",  # syntax error
    ],
)
def test_parser_refuses(text: str) -> None:
    with pytest.raises(InputError) as err:
        Expr(text)
    assert "\n" not in str(err.value)


def test_other_variables() -> None:
    f = Expr("a*b + 1", ("a", "b"))
    assert f(2.0, 3.0) == 7.0
    with pytest.raises(TypeError):
        f(1.0)
    with pytest.raises(InputError):
        Expr("a*x", ("a",))


_TABLE = Table((0.0, 0.5, 1.0), (1.0, 2.0, 0.0))


def test_table_interpolates_and_is_flat_outside() -> None:
    x = np.array([-0.5, 0.0, 0.25, 0.75, 1.0, 1.5])
    np.testing.assert_allclose(_TABLE(x), [1.0, 1.0, 1.5, 1.0, 0.0, 0.0])
    inside = x[1:-1]
    np.testing.assert_allclose(_casadi(_TABLE, inside), _TABLE(inside), atol=1e-14)


def test_table_casadi_is_flat_outside() -> None:
    x = np.array([-0.5, 1.5])
    np.testing.assert_allclose(_casadi(_TABLE, x), _TABLE(x), atol=1e-14)


@pytest.mark.parametrize(
    ("x", "y"),
    [
        ((0.0, 1.0), (1.0,)),
        ((0.0,), (1.0,)),
        ((0.0, 0.0, 1.0), (1, 2, 3)),
        ((1.0, 0.0), (0, 1)),
        ((0, 1), (0, np.nan)),
    ],
)
def test_bad_tables(x: tuple, y: tuple) -> None:
    with pytest.raises(InputError):
        Table(x, y)


def test_as_function_and_json_round_trip() -> None:
    assert as_function(3) == 3.0 and isinstance(as_function(3), float)
    e = as_function("2*x")
    assert isinstance(e, Expr) and e(2.0) == 4.0
    t = as_function({"x": [0, 1], "y": [2, 3]})
    assert isinstance(t, Table)
    for f in (2.5, e, t):
        assert as_function(to_json(f)) == f
    for bad in (True, [1, 2], {"a": 1}, None):
        with pytest.raises(InputError):
            as_function(bad)


def test_evaluate_constant_broadcasts() -> None:
    out = evaluate(2.0, np.zeros(4))
    assert out.shape == (4,) and np.all(out == 2.0)
    assert evaluate(2.0, ca.SX.sym("x"), "casadi") == 2.0


@settings(max_examples=60, deadline=None)
@given(
    st.lists(st.floats(-5, 5, allow_nan=False), min_size=3, max_size=3),
    st.floats(0.0, 1.0, allow_nan=False),
)
def test_random_expressions_agree(coef: list[float], x: float) -> None:
    a, b, c = coef
    f = Expr(f"{a!r}*exp({b!r}*x) + tanh({c!r}*(x - 0.5)) + x**3")
    assert _casadi(f, np.array([x]))[0] == pytest.approx(float(f(x)), rel=1e-12, abs=1e-12)
