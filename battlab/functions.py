"""Parameter functions: safe expression strings (BPX syntax) and interpolation tables.

A BPX function string such as ``"1.97938*exp(-39.3631*x)+0.7"`` is parsed with :mod:`ast` into a whitelisted tree
(numbers, the variable ``x``, ``+ - * / **``, unary minus and a fixed set of functions) and evaluated against a
backend namespace, so the same function serves numpy (post-processing, screening) and CasADi (the model's
symbolic residual). Nothing is ever passed to ``eval``.
"""

from __future__ import annotations

import ast
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from protocols.errors import InputError

_BINOPS = {ast.Add: "add", ast.Sub: "sub", ast.Mult: "mul", ast.Div: "div", ast.Pow: "pow"}
_FUNCTIONS = ("exp", "log", "log10", "sqrt", "tanh", "sinh", "cosh", "sin", "cos", "arctan", "abs", "sign")
_ALIASES = {"atan": "arctan", "ln": "log"}
_CONSTANTS = {"pi": math.pi, "e": math.e}


def _namespace(backend: str) -> dict[str, Callable[..., Any]]:
    if backend == "numpy":
        return {name: getattr(np, name) for name in _FUNCTIONS}
    if backend == "casadi":
        import casadi as ca

        ns = {name: getattr(ca, name) for name in _FUNCTIONS if name not in ("abs", "arctan")}
        ns["abs"] = ca.fabs
        ns["arctan"] = ca.atan
        return ns
    raise ValueError(f"unknown backend {backend!r}")


def _check(node: ast.AST, variables: Sequence[str], text: str) -> None:
    """Reject anything but arithmetic on numbers, known variables and whitelisted functions."""
    for sub in ast.walk(node):
        if isinstance(sub, ast.Expression | ast.Load | ast.operator | ast.unaryop):
            if isinstance(sub, ast.operator) and type(sub) not in _BINOPS:
                raise InputError(f"function {text!r}: operator {type(sub).__name__} is not allowed")
            if isinstance(sub, ast.unaryop) and not isinstance(sub, ast.USub | ast.UAdd):
                raise InputError(f"function {text!r}: operator {type(sub).__name__} is not allowed")
            continue
        if isinstance(sub, ast.BinOp | ast.UnaryOp):
            continue
        if isinstance(sub, ast.Constant):
            if not isinstance(sub.value, int | float) or isinstance(sub.value, bool):
                raise InputError(f"function {text!r}: only numbers are allowed as constants, got {sub.value!r}")
            continue
        if isinstance(sub, ast.Name):
            if sub.id not in variables and sub.id not in _CONSTANTS and _ALIASES.get(sub.id, sub.id) not in _FUNCTIONS:
                raise InputError(f"function {text!r}: unknown name {sub.id!r} (variables: {', '.join(variables)})")
            continue
        if isinstance(sub, ast.Call):
            fname = sub.func.id if isinstance(sub.func, ast.Name) else None
            if fname is None or _ALIASES.get(fname, fname) not in _FUNCTIONS or sub.keywords:
                raise InputError(f"function {text!r}: call of {ast.unparse(sub.func)!r} is not allowed")
            if len(sub.args) != 1:
                raise InputError(f"function {text!r}: {fname}() takes one argument")
            continue
        raise InputError(f"function {text!r}: {type(sub).__name__} is not allowed in a parameter function")


@dataclass(frozen=True)
class Expr:
    """A parsed, whitelisted expression of ``variables`` (default: BPX's single variable ``x``)."""

    text: str
    variables: tuple[str, ...] = ("x",)

    def __post_init__(self) -> None:
        text = str(self.text).replace("^", "**")
        try:
            tree = ast.parse(text.strip(), mode="eval")
        except SyntaxError as exc:
            raise InputError(f"function {self.text!r}: not a valid expression ({exc.msg})") from None
        _check(tree, self.variables, self.text)
        object.__setattr__(self, "text", text.strip())
        object.__setattr__(self, "_tree", tree.body)

    def __reduce__(self) -> tuple:
        return (Expr, (self.text, self.variables))  # re-parsed (and re-checked) on unpickling

    def __call__(self, *args: Any, backend: str = "numpy") -> Any:
        if len(args) != len(self.variables):
            raise TypeError(f"{self.text!r} takes {len(self.variables)} argument(s)")
        env = dict(zip(self.variables, args, strict=True))
        return _evaluate(self._tree, env, _namespace(backend))  # type: ignore[attr-defined]


def _evaluate(node: ast.AST, env: dict[str, Any], ns: dict[str, Callable[..., Any]]) -> Any:
    if isinstance(node, ast.Constant):
        return float(node.value)
    if isinstance(node, ast.Name):
        if node.id in env:
            return env[node.id]
        return _CONSTANTS[node.id]
    if isinstance(node, ast.UnaryOp):
        v = _evaluate(node.operand, env, ns)
        return -v if isinstance(node.op, ast.USub) else v
    if isinstance(node, ast.BinOp):
        a, b = _evaluate(node.left, env, ns), _evaluate(node.right, env, ns)
        op = _BINOPS[type(node.op)]
        if op == "add":
            return a + b
        if op == "sub":
            return a - b
        if op == "mul":
            return a * b
        if op == "div":
            return a / b
        return a**b
    if isinstance(node, ast.Call):
        fname = _ALIASES.get(node.func.id, node.func.id)  # type: ignore[attr-defined]
        return ns[fname](_evaluate(node.args[0], env, ns))
    raise AssertionError(f"unchecked node {type(node).__name__}")  # _check rejects everything else


@dataclass(frozen=True, eq=False)
class Table:
    """A 1-D table y(x), linearly interpolated (flat beyond the ends), as BPX ``{"x": [...], "y": [...]}``."""

    x: tuple[float, ...]
    y: tuple[float, ...]

    def __post_init__(self) -> None:
        x, y = np.asarray(self.x, float), np.asarray(self.y, float)
        if x.ndim != 1 or x.shape != y.shape or x.size < 2:
            raise InputError(f"table: x and y must be equal-length lists of ≥ 2 numbers, got {x.shape} and {y.shape}")
        if not (np.all(np.isfinite(x)) and np.all(np.isfinite(y))):
            raise InputError("table: x and y must be finite")
        if np.any(np.diff(x) <= 0):
            raise InputError("table: x must increase strictly")
        object.__setattr__(self, "x", tuple(float(v) for v in x))
        object.__setattr__(self, "y", tuple(float(v) for v in y))

    def __call__(self, x: Any, backend: str = "numpy") -> Any:
        if backend == "numpy":
            return np.interp(x, self.x, self.y)
        import casadi as ca

        f = ca.interpolant("table", "linear", [list(self.x)], list(self.y))
        return f(ca.fmin(ca.fmax(x, self.x[0]), self.x[-1]))  # flat beyond the ends, as numpy

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Table) and self.x == other.x and self.y == other.y

    def __hash__(self) -> int:
        return hash((self.x, self.y))


Function = Expr | Table


def as_function(value: Any, variables: tuple[str, ...] = ("x",)) -> Function | float:
    """A number stays a number; a string becomes an :class:`Expr`; ``{"x", "y"}`` becomes a :class:`Table`."""
    if isinstance(value, Expr | Table):
        return value
    if isinstance(value, bool):
        raise InputError(f"expected a number, expression or table, got {value!r}")
    if isinstance(value, int | float):
        return float(value)
    if isinstance(value, str):
        return Expr(value, variables)
    if isinstance(value, dict) and set(value) >= {"x", "y"}:
        try:
            return Table(tuple(value["x"]), tuple(value["y"]))
        except InputError:
            raise
        except (TypeError, ValueError):  # not lists, or not of numbers
            raise InputError(f"table: x and y must be lists of numbers, got {value!r}") from None
    raise InputError(f"expected a number, expression string or {{'x': [...], 'y': [...]}} table, got {value!r}")


def evaluate(f: Function | float, x: Any, backend: str = "numpy") -> Any:
    """Evaluate a parameter that may be a constant, an expression or a table."""
    value = f if isinstance(f, float | int) else f(x, backend=backend)
    if backend == "numpy":
        return value + 0 * x  # a constant expression ("0") still has the shape of x
    import casadi as ca

    if hasattr(x, "shape") and (not hasattr(value, "shape") or value.shape != x.shape):
        return value * ca.DM.ones(x.shape)
    return value


def to_json(f: Function | float) -> Any:
    """The BPX representation: a number, a string or a table dict."""
    if isinstance(f, Expr):
        return f.text
    if isinstance(f, Table):
        return {"x": list(f.x), "y": list(f.y)}
    return float(f)
