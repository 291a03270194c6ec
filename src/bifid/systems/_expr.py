"""Equations as text: parsed into SymPy expressions without executing anything, and evaluated
as JAX arrays.

Why not ``sympy.parse_expr`` / ``sympify`` / ``lambdify``: all three build Python source and run
it through ``eval`` / ``exec``, and a system file is data that must never run code. Here the
text is parsed by :func:`ast.parse` (which only parses), every node is checked against a short
grammar -- numbers, the known symbols, ``+ - * / **`` (``^`` is read as ``**``), and calls of
the functions of :data:`FUNCTIONS` -- and the SymPy expression is built from the checked tree.
The JAX evaluation walks the SymPy tree once per trace (under ``jit`` it costs nothing at run
time); numbers keep their float64 values, so a field written in a file gives the same numbers
as the same field written in Python, to round-off.
"""

from __future__ import annotations

import ast
import math
from collections.abc import Callable, Mapping

import jax.numpy as jnp
import sympy

from bifid.errors import BifidInputError

__all__ = ["FUNCTIONS", "RESERVED", "evaluate", "parse_equation"]

# the functions an equation may call: name -> (SymPy function, its JAX evaluation); sqrt is
# SymPy's Pow(x, 1/2), evaluated as jnp.sqrt by `evaluate`
_CALLS: dict[str, tuple[Callable[..., sympy.Expr], Callable[..., object] | None]] = {
    "exp": (sympy.exp, jnp.exp),
    "log": (sympy.log, jnp.log),
    "sqrt": (sympy.sqrt, None),
    "sin": (sympy.sin, jnp.sin),
    "cos": (sympy.cos, jnp.cos),
    "tan": (sympy.tan, jnp.tan),
    "asin": (sympy.asin, jnp.arcsin),
    "acos": (sympy.acos, jnp.arccos),
    "atan": (sympy.atan, jnp.arctan),
    "atan2": (sympy.atan2, jnp.arctan2),
    "sinh": (sympy.sinh, jnp.sinh),
    "cosh": (sympy.cosh, jnp.cosh),
    "tanh": (sympy.tanh, jnp.tanh),
    "abs": (sympy.Abs, jnp.abs),
    "sign": (sympy.sign, jnp.sign),
}
#: Functions an equation may call, by the name it uses.
FUNCTIONS: dict[str, Callable[..., sympy.Expr]] = {k: f for k, (f, _) in _CALLS.items()}
_JAX_FUNCTIONS = {f: j for f, j in _CALLS.values() if j is not None}
_CONSTANTS = {"pi": sympy.pi}
#: Names a state or parameter may not take.
RESERVED = frozenset(FUNCTIONS) | frozenset(_CONSTANTS) | {"t"}
_BINARY = {
    ast.Add: lambda a, b: a + b,
    ast.Sub: lambda a, b: a - b,
    ast.Mult: lambda a, b: a * b,
    ast.Div: lambda a, b: a / b,
    ast.Pow: lambda a, b: a**b,
}
_UNARY = {ast.USub: lambda a: -a, ast.UAdd: lambda a: a}


class _Unknown(Exception):
    """What in the text is not in the grammar (turned into one line by the caller)."""


def _build(node: ast.AST, symbols: Mapping[str, sympy.Symbol]) -> sympy.Expr:
    if isinstance(node, ast.Constant):
        value = node.value
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise _Unknown(f"a {type(value).__name__} constant {value!r}")
        if not math.isfinite(value):
            raise _Unknown(f"the non-finite number {value!r}")
        return sympy.Integer(value) if isinstance(value, int) else sympy.Float(value)
    if isinstance(node, ast.Name):
        if node.id in symbols:
            return symbols[node.id]
        if node.id in _CONSTANTS:
            return _CONSTANTS[node.id]
        if node.id in FUNCTIONS:
            raise _Unknown(f"the function {node.id!r} used without arguments")
        raise _Unknown(f"unknown symbol {node.id!r}")
    if isinstance(node, ast.BinOp) and type(node.op) in _BINARY:
        return _BINARY[type(node.op)](_build(node.left, symbols), _build(node.right, symbols))
    if isinstance(node, ast.UnaryOp) and type(node.op) in _UNARY:
        return _UNARY[type(node.op)](_build(node.operand, symbols))
    if isinstance(node, ast.Call):
        name = node.func.id if isinstance(node.func, ast.Name) else ast.unparse(node.func)
        if name not in FUNCTIONS:
            raise _Unknown(f"unknown function {name!r}")
        if node.keywords:
            raise _Unknown(f"keyword arguments in the call of {name!r}")
        args = [_build(a, symbols) for a in node.args]
        try:
            return FUNCTIONS[name](*args)
        except TypeError:
            raise _Unknown(f"{name!r} called with {len(args)} argument(s)") from None
    raise _Unknown(f"the construct {ast.unparse(node)!r}, which is not arithmetic")


def parse_equation(text: object, symbols: Mapping[str, sympy.Symbol], where: str) -> sympy.Expr:
    """The SymPy expression of ``text``, an equation's right-hand side.

    Parameters
    ----------
    text : str
        SymPy syntax: numbers, the names in ``symbols``, ``pi``, ``+ - * / ** ^``, and calls
        of :data:`FUNCTIONS`.
    symbols : mapping of str to sympy.Symbol
        The names the text may use (states and parameters).
    where : str
        Where the text comes from (``"model.toml: [equations] x"``), for the error message.

    Raises
    ------
    BifidInputError
        One line naming ``where``, the text and what is wrong (e.g. the unknown symbol).
    """
    if not isinstance(text, str) or not text.strip():
        raise BifidInputError(
            f"{where}: expected the equation as a non-empty string, got {text!r}."
        )
    known = ", ".join([*symbols, *_CONSTANTS])
    try:
        tree = ast.parse(text.strip().replace("^", "**"), mode="eval")
    except SyntaxError as exc:
        raise BifidInputError(
            f"{where} = {text!r}: syntax error at column {exc.offset} ({exc.msg})."
        ) from None
    try:
        return _build(tree.body, symbols)
    except _Unknown as exc:
        raise BifidInputError(
            f"{where} = {text!r}: {exc} (known symbols: {known}; functions: "
            f"{', '.join(FUNCTIONS)})."
        ) from None
    except (ValueError, TypeError, ZeroDivisionError, ArithmeticError) as exc:
        raise BifidInputError(f"{where} = {text!r}: {exc}.") from None


def evaluate(expr: sympy.Expr, values: Mapping[sympy.Symbol, object]):
    """Evaluate ``expr`` with JAX, the symbols taking ``values`` (traceable: ``jit``, ``grad``,
    ``vmap`` apply)."""
    if expr.is_Symbol:
        return values[expr]
    if expr.is_Integer:
        return int(expr)
    if expr.is_Number or expr.is_NumberSymbol:
        return float(expr)
    args = [evaluate(a, values) for a in expr.args]
    if expr.is_Add:
        out = args[0]
        for a in args[1:]:
            out = out + a
        return out
    if expr.is_Mul:
        out = args[0]
        for a in args[1:]:
            out = out * a
        return out
    if expr.is_Pow:
        base, exponent = args
        if expr.exp == sympy.S.Half:
            return jnp.sqrt(base)
        return base**exponent
    return _JAX_FUNCTIONS[expr.func](*args)
