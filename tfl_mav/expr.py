"""Safe arithmetic expressions for scenario files (attack signals, paths).

A scenario may say ``signal = "0.1*t + sin(z)"`` or ``s = ["y - cos(x)", ...]``. Running
such text through ``eval`` would let a scenario file execute arbitrary code, so the text is
parsed with :mod:`ast`, checked against a whitelist (numbers, the declared variable names,
``+ - * / **``, unary minus, and calls to whitelisted functions by bare name) and compiled
into a tree of plain closures. Attribute access, subscripts, lambdas, comprehensions,
strings, keywords and any name not declared are rejected with an error naming the field.

The compiled expression is generic over the number type: the caller passes a *function
library* (``MATH`` for floats, :data:`tfl_mav.control.path.jets.JET_LIB` for Taylor jets), so a
path written once as text is differentiated exactly by evaluating it on jets.
"""

from __future__ import annotations

import ast
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from tfl_mav.control.scalar import clamp

__all__ = ["MATH", "Expr", "ExprError", "compile_expr"]

# Function names a scenario may call. Every library passed to Expr.__call__ must provide
# these (a library may raise for ones that make no sense for its number type).
FUNCTION_NAMES: tuple[str, ...] = (
    "sin", "cos", "tan", "exp", "log", "sqrt", "atan", "tanh", "abs", "min", "max",
    "clip", "step",
)

CONSTANTS: dict[str, float] = {"pi": math.pi, "e": math.e}

MAX_EXPR_LENGTH = 2000
MAX_EXPR_NODES = 500


def _step(x: float) -> float:
    """Heaviside step: 0 for x < 0, 1 for x >= 0."""
    return 1.0 if x >= 0.0 else 0.0


MATH: Mapping[str, Callable[..., Any]] = {
    "sin": math.sin, "cos": math.cos, "tan": math.tan, "exp": math.exp, "log": math.log,
    "sqrt": math.sqrt, "atan": math.atan, "tanh": math.tanh, "abs": abs, "min": min,
    "max": max, "clip": clamp, "step": _step,
}


class ExprError(ValueError):
    """An expression in a scenario is malformed or unsafe; ``field`` names where it came from."""

    def __init__(self, field: str, message: str) -> None:
        super().__init__(f"{field}: {message}")
        self.field = field
        self.message = message


_BINOPS: dict[type, Callable[[Any, Any], Any]] = {
    ast.Add: lambda a, b: a + b,
    ast.Sub: lambda a, b: a - b,
    ast.Mult: lambda a, b: a * b,
    ast.Div: lambda a, b: a / b,
    ast.Pow: lambda a, b: a**b,
}

_Node = Callable[[Mapping[str, Any], Mapping[str, Callable[..., Any]]], Any]


@dataclass(frozen=True)
class Expr:
    """A compiled, safe expression. Call with variable values and a function library."""

    text: str
    variables: tuple[str, ...]
    _fn: _Node

    def __call__(
        self, values: Mapping[str, Any], lib: Mapping[str, Callable[..., Any]] = MATH
    ) -> Any:
        return self._fn(values, lib)

    def depends_on(self, name: str) -> bool:
        """True if the variable ``name`` occurs in the expression."""
        tree = ast.parse(self.text, mode="eval")
        return any(isinstance(n, ast.Name) and n.id == name for n in ast.walk(tree))


def compile_expr(text: str, variables: Sequence[str], *, field: str) -> Expr:
    """Parse and compile ``text`` allowing only ``variables``; errors name ``field``.

    Raises :class:`ExprError` for syntax errors, unknown names, disallowed constructs,
    numbers beyond float range, too long or too deeply nested text, expressions that do not
    evaluate to a number at a neutral point (all variables 0.5), and expressions without
    variables that cannot be evaluated or are not finite (``1/0``, ``9**9**9``): they would
    fail at every tick. Evaluation cost is bounded by ``MAX_EXPR_NODES`` float operations.
    """
    if not isinstance(text, str):
        raise ExprError(field, f"expected an expression string, got {type(text).__name__}")
    if len(text) > MAX_EXPR_LENGTH:
        raise ExprError(field, f"expression longer than {MAX_EXPR_LENGTH} characters")
    if not text.strip():
        raise ExprError(field, "empty expression")
    if "\x00" in text:
        raise ExprError(field, f"expression contains a NUL character: {text!r}")
    try:
        tree = ast.parse(text.strip(), mode="eval")
    except SyntaxError as exc:
        where = f" at column {exc.offset}" if exc.offset else ""
        raise ExprError(field, f"syntax error{where} ({exc.msg}): {text!r}") from None
    except (RecursionError, MemoryError):   # nesting deeper than Python's parser allows
        raise ExprError(field, "expression nested too deeply") from None
    nodes = sum(1 for _ in ast.walk(tree))
    if nodes > MAX_EXPR_NODES:
        raise ExprError(field, f"expression too complex ({nodes} nodes > {MAX_EXPR_NODES})")
    allowed = tuple(variables)
    fn = _compile(tree.body, allowed, field)
    expr = Expr(text.strip(), allowed, fn)
    probe = dict.fromkeys(allowed, 0.5)
    constant = not any(isinstance(n, ast.Name) and n.id in allowed for n in ast.walk(tree))
    try:
        value = expr(probe)
    except (ArithmeticError, ValueError, TypeError) as exc:
        if constant:   # no variable can ever make it defined: say so now, not mid-flight
            raise ExprError(field, f"constant expression cannot be evaluated ({exc}): "
                                   f"{text!r}") from None
        return expr  # e.g. log(x - 1) is valid but undefined at the probe point
    if not isinstance(value, (int, float)):
        raise ExprError(field, f"expression does not evaluate to a number: {text!r}")
    if constant and not math.isfinite(value):
        raise ExprError(field, f"constant expression is not finite ({value}): {text!r}")
    return expr


def _compile(node: ast.AST, variables: tuple[str, ...], field: str) -> _Node:
    if isinstance(node, ast.Constant):
        if isinstance(node.value, bool) or not isinstance(node.value, (int, float)):
            raise ExprError(field, f"only numbers are allowed as constants, got {node.value!r}")
        try:
            c = float(node.value)
        except OverflowError:   # an integer literal beyond float range
            raise ExprError(field, "number too large for a float (max ~1.8e308)") from None
        if not math.isfinite(c):   # 1e999 parses as inf
            raise ExprError(field, "number too large for a float (max ~1.8e308)")
        return lambda v, lib: c
    if isinstance(node, ast.Name):
        name = node.id
        if name in variables:
            return lambda v, lib: v[name]
        if name in CONSTANTS:
            c = CONSTANTS[name]
            return lambda v, lib: c
        if name in FUNCTION_NAMES:
            raise ExprError(field, f"function {name!r} must be called, e.g. {name}(x)")
        allowed = ", ".join(variables) or "none"
        raise ExprError(field, f"unknown name {name!r} (variables allowed here: {allowed})")
    if isinstance(node, ast.BinOp):
        op = _BINOPS.get(type(node.op))
        if op is None:
            raise ExprError(field, f"operator {type(node.op).__name__} is not allowed")
        left = _compile(node.left, variables, field)
        right = _compile(node.right, variables, field)
        return lambda v, lib: op(left(v, lib), right(v, lib))
    if isinstance(node, ast.UnaryOp):
        operand = _compile(node.operand, variables, field)
        if isinstance(node.op, ast.USub):
            return lambda v, lib: -operand(v, lib)
        if isinstance(node.op, ast.UAdd):
            return operand
        raise ExprError(field, f"operator {type(node.op).__name__} is not allowed")
    if isinstance(node, ast.Call):
        if not isinstance(node.func, ast.Name):
            raise ExprError(field, "only calls of whitelisted functions by name are allowed")
        name = node.func.id
        if name not in FUNCTION_NAMES:
            raise ExprError(
                field, f"unknown function {name!r} (allowed: {', '.join(FUNCTION_NAMES)})"
            )
        if node.keywords:
            raise ExprError(field, f"keyword arguments are not allowed in {name}()")
        args = [_compile(a, variables, field) for a in node.args]
        arity = {"clip": 3, "min": 2, "max": 2}.get(name, 1)
        if len(args) != arity:
            raise ExprError(field, f"{name}() takes {arity} argument(s), got {len(args)}")
        if arity == 1:
            a0 = args[0]
            return lambda v, lib: lib[name](a0(v, lib))
        return lambda v, lib: lib[name](*(a(v, lib) for a in args))
    raise ExprError(field, f"{type(node).__name__} is not allowed in an expression")
