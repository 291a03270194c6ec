"""Scalar expression graphs: the common-subexpression-free form of a traced vector field.

A :class:`Graph` holds scalar nodes -- leaves (a state ``x[i]``, a parameter ``p[i]``, an
opaque parameter-only value ``r[i]``, a constant) and operations on earlier nodes. Nodes
are hash-consed, so an expression computed twice is one node (common subexpressions are
eliminated as the graph is built), and operations on constants are folded, with the
identities ``0·a = 0``, ``1·a = a``, ``a + 0 = a`` applied to literal constants (they
remove the structural zeros of matrices written out element by element).

Every node knows whether it depends on the state. :func:`emit` prints the graph as two
scalar Python functions for numba: ``_prepare(p, r, d)`` computes, once per parameter
set, every state-independent value the field needs (``d``), and ``_field(x, d, out)``
evaluates the rest. :func:`evaluate` evaluates nodes with NumPy or ``jax.numpy`` (for the
parameter-only inputs of opaque operations).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = ["OPS", "Graph", "Unsupported", "emit", "evaluate"]


class Unsupported(Exception):
    """A field uses an operation the scalar code generator cannot express."""


def _special(ns, name: str):
    """``math.erf`` / ``math.lgamma`` for NumPy, their ``jax.scipy.special`` twins for JAX."""
    if ns is np:
        return np.vectorize(getattr(math, name), otypes=[float])
    import jax.scipy.special as jss

    return {"erf": jss.erf, "lgamma": jss.gammaln}[name]


@dataclass(frozen=True)
class Op:
    """A scalar operation: how numba code prints it and how NumPy / JAX evaluate it."""

    template: str  # str.format template over the argument expressions
    evaluate: Callable[..., Any]  # evaluate(ns, *args) with ns = numpy or jax.numpy
    kind: str = "f"  # result kind: "f" float, "b" bool, "i" int, "=" like the first argument


def _u(template: str, name: str) -> Op:
    return Op(template, lambda ns, a: getattr(ns, name)(a))


def _b(template: str, name: str, kind: str = "f") -> Op:
    return Op(template, lambda ns, a, b: getattr(ns, name)(a, b), kind)


OPS: dict[str, Op] = {
    "add": Op("({0} + {1})", lambda ns, a, b: a + b, "="),
    "sub": Op("({0} - {1})", lambda ns, a, b: a - b, "="),
    "mul": Op("({0} * {1})", lambda ns, a, b: a * b, "="),
    "div": Op("({0} / {1})", lambda ns, a, b: a / b),
    "neg": Op("(-{0})", lambda ns, a: -a, "="),
    "pow": Op("({0} ** {1})", lambda ns, a, b: ns.power(a, b)),
    "max": _b("np.maximum({0}, {1})", "maximum", "="),
    "min": _b("np.minimum({0}, {1})", "minimum", "="),
    "atan2": _b("math.atan2({0}, {1})", "arctan2"),
    "rem": _b("np.fmod({0}, {1})", "fmod"),
    "sin": _u("math.sin({0})", "sin"),
    "cos": _u("math.cos({0})", "cos"),
    "tan": _u("math.tan({0})", "tan"),
    "asin": _u("math.asin({0})", "arcsin"),
    "acos": _u("math.acos({0})", "arccos"),
    "atan": _u("math.atan({0})", "arctan"),
    "sinh": _u("math.sinh({0})", "sinh"),
    "cosh": _u("math.cosh({0})", "cosh"),
    "tanh": _u("math.tanh({0})", "tanh"),
    "asinh": _u("math.asinh({0})", "arcsinh"),
    "acosh": _u("math.acosh({0})", "arccosh"),
    "atanh": _u("math.atanh({0})", "arctanh"),
    "exp": _u("math.exp({0})", "exp"),
    "exp2": _u("(2.0 ** {0})", "exp2"),
    "log": _u("math.log({0})", "log"),
    "log1p": _u("math.log1p({0})", "log1p"),
    "expm1": _u("math.expm1({0})", "expm1"),
    "sqrt": _u("math.sqrt({0})", "sqrt"),
    "rsqrt": Op("(1.0 / math.sqrt({0}))", lambda ns, a: 1.0 / ns.sqrt(a)),
    "cbrt": _u("np.cbrt({0})", "cbrt"),
    "abs": Op("abs({0})", lambda ns, a: ns.abs(a), "="),
    "sign": Op("np.sign({0})", lambda ns, a: ns.sign(a), "="),
    "floor": _u("math.floor({0})", "floor"),
    "rint": _u("np.rint({0})", "rint"),  # to nearest, ties to even
    "round_away": Op(
        "math.copysign(math.floor(abs({0}) + 0.5), {0})",
        lambda ns, a: ns.sign(a) * ns.floor(ns.abs(a) + 0.5),
    ),
    "ceil": _u("math.ceil({0})", "ceil"),
    "logistic": Op("(1.0 / (1.0 + math.exp(-{0})))", lambda ns, a: 1.0 / (1.0 + ns.exp(-a))),
    "erf": Op("math.erf({0})", lambda ns, a: _special(ns, "erf")(a)),
    "lgamma": Op("math.lgamma({0})", lambda ns, a: _special(ns, "lgamma")(a)),
    "is_finite": Op("math.isfinite({0})", lambda ns, a: ns.isfinite(a), "b"),
    "lt": _b("({0} < {1})", "less", "b"),
    "le": _b("({0} <= {1})", "less_equal", "b"),
    "gt": _b("({0} > {1})", "greater", "b"),
    "ge": _b("({0} >= {1})", "greater_equal", "b"),
    "eq": _b("({0} == {1})", "equal", "b"),
    "ne": _b("({0} != {1})", "not_equal", "b"),
    "and": _b("({0} and {1})", "logical_and", "b"),
    "or": _b("({0} or {1})", "logical_or", "b"),
    "not": Op("(not {0})", lambda ns, a: ns.logical_not(a), "b"),
    # select(pred, on_false, on_true): lax.select_n with a boolean predicate
    "select": Op("({2} if {0} else {1})", lambda ns, c, a, b: ns.where(c, b, a), "f"),
    "to_float": Op("float({0})", lambda ns, a: ns.asarray(a, dtype=ns.float64)),
    "to_int": Op("int({0})", lambda ns, a: ns.trunc(a).astype(ns.int64), "i"),
    "to_bool": Op("({0} != 0)", lambda ns, a: a != 0, "b"),
}


def _literal(value: Any, kind: str) -> str:
    if kind == "b":
        return "True" if value else "False"
    if kind == "i":
        return f"({int(value)})"
    v = float(value)
    if math.isnan(v):
        return "math.nan"
    if math.isinf(v):
        return "math.inf" if v > 0 else "(-math.inf)"
    return f"({v!r})"


def _cast(value: Any, kind: str) -> Any:
    return bool(value) if kind == "b" else int(value) if kind == "i" else float(value)


class Graph:
    """A hash-consed DAG of scalar nodes (see the module docstring)."""

    def __init__(self) -> None:
        self.nodes: list[tuple] = []  # ("x", i) | ("p", i) | ("r", i) | ("const", v) | (op, *args)
        self.kinds: list[str] = []
        self.state: list[bool] = []  # depends on the state x
        self._index: dict[tuple, int] = {}

    def _add(self, key: tuple, node: tuple, kind: str, state: bool) -> int:
        got = self._index.get(key)
        if got is not None:
            return got
        self.nodes.append(node)
        self.kinds.append(kind)
        self.state.append(state)
        self._index[key] = len(self.nodes) - 1
        return len(self.nodes) - 1

    def leaf(self, name: str, i: int) -> int:
        return self._add((name, i), (name, i), "f", name == "x")

    def const(self, value: Any, kind: str = "f") -> int:
        value = _cast(value, kind)
        key = ("const", kind, float(value).hex() if kind == "f" else value)
        return self._add(key, ("const", value), kind, False)

    def value(self, n: int) -> Any:
        """The constant of node ``n``, or None when it is not a constant."""
        node = self.nodes[n]
        return node[1] if node[0] == "const" else None

    def op(self, name: str, *args: int, kind: str | None = None) -> int:
        spec = OPS[name]
        kind = kind or (self.kinds[args[0]] if spec.kind == "=" else spec.kind)
        if name == "select":
            kind = self.kinds[args[1]]
        consts = [self.value(a) for a in args]
        if all(c is not None for c in consts):
            with np.errstate(all="ignore"):
                v = spec.evaluate(np, *(np.asarray(c) for c in consts))
            return self.const(v.item() if hasattr(v, "item") else v, kind)
        folded = self._identity(name, args, consts)
        if folded is not None:
            return folded
        if name in ("add", "mul", "max", "min", "eq", "ne", "and", "or") and args[0] > args[1]:
            args = (args[1], args[0])  # commutative: one node for a+b and b+a
        state = any(self.state[a] for a in args)
        return self._add((name, *args), (name, *args), kind, state)

    def _identity(self, name: str, args: Sequence[int], consts: Sequence[Any]) -> int | None:
        if name == "select" and consts[0] is not None:
            return args[2] if consts[0] else args[1]
        if name == "select" and args[1] == args[2]:
            return args[1]
        if name not in ("add", "sub", "mul", "div") or self.kinds[args[0]] != "f":
            return None
        a, b = args
        ca, cb = consts
        if name == "add" and ca == 0.0:
            return b
        if name in ("add", "sub") and cb == 0.0:
            return a
        if name == "sub" and ca == 0.0:
            return self.op("neg", b)
        if name == "mul" and (ca == 0.0 or cb == 0.0):
            return self.const(0.0)
        if name == "mul" and ca == 1.0:
            return b
        if name in ("mul", "div") and cb == 1.0:
            return a
        if name == "mul" and ca == -1.0:
            return self.op("neg", b)
        return None

    def power(self, a: int, y: int) -> int:
        """``a ** y`` for an integer ``y`` by repeated squaring (as XLA's integer_pow)."""
        if y == 0:
            return self.const(1.0, self.kinds[a])
        if y < 0:
            return self.op("div", self.const(1.0), self.power(a, -y))
        acc, base = None, a
        while y:
            if y & 1:
                acc = base if acc is None else self.op("mul", acc, base)
            y >>= 1
            if y:
                base = self.op("mul", base, base)
        return acc

    def ancestors(self, roots: Sequence[int]) -> list[int]:
        """Nodes that ``roots`` depend on (themselves included), in topological order."""
        seen = set()
        stack = list(roots)
        while stack:
            n = stack.pop()
            if n in seen:
                continue
            seen.add(n)
            node = self.nodes[n]
            if node[0] not in ("x", "p", "r", "const"):
                stack.extend(node[1:])
        return sorted(seen)  # children always have smaller ids


def evaluate(graph: Graph, roots: Sequence[int], values: dict[int, Any], ns: Any) -> list:
    """Values of ``roots`` with ``ns`` (numpy or jax.numpy); ``values`` gives the leaves."""
    vals = dict(values)
    for n in graph.ancestors(roots):
        if n in vals:
            continue
        node = graph.nodes[n]
        if node[0] == "const":
            vals[n] = node[1]
        elif node[0] in ("x", "p", "r"):
            raise KeyError(f"no value for leaf {node}")
        else:
            vals[n] = OPS[node[0]].evaluate(ns, *(vals[a] for a in node[1:]))
    return [vals[r] for r in roots]


def _expression(graph: Graph, n: int, names: dict[int, str]) -> str:
    node = graph.nodes[n]
    if n in names:
        return names[n]
    if node[0] == "const":
        return _literal(node[1], graph.kinds[n])
    return OPS[node[0]].template.format(*(_expression(graph, a, names) for a in node[1:]))


def _body(graph: Graph, nodes: Sequence[int], names: dict[int, str], indent: str) -> list[str]:
    lines = []
    for n in nodes:
        node = graph.nodes[n]
        if n in names or node[0] == "const":
            continue
        lines.append(f"{indent}t{n} = {_expression(graph, n, names)}")
        names[n] = f"t{n}"
    return lines


def emit(graph: Graph, outputs: Sequence[int]) -> tuple[str, int]:
    """Source of ``_prepare(p, r, d)`` and ``_field(x, d, out)``, and the size of ``d``.

    ``d`` holds the state-independent nodes that state-dependent nodes (or the outputs)
    use; ``_prepare`` computes them from the parameters ``p`` and the opaque values ``r``.
    """
    needed = graph.ancestors(outputs)
    state_nodes = [n for n in needed if graph.state[n]]
    boundary: list[int] = []
    for n in state_nodes:
        node = graph.nodes[n]
        if node[0] == "x":
            continue
        boundary.extend(a for a in node[1:] if not graph.state[a] and graph.nodes[a][0] != "const")
    boundary.extend(o for o in outputs if not graph.state[o] and graph.nodes[o][0] != "const")
    boundary = sorted(set(boundary))
    i4 = "    "
    # _prepare: p-only nodes needed by the boundary, then d[k] = boundary node k
    names: dict[int, str] = {}
    pre = ["def _prepare(p, r, d):"]
    for n in graph.ancestors(boundary):
        kind, i = graph.nodes[n][0], graph.nodes[n][-1]
        if kind in ("p", "r"):
            pre.append(f"{i4}t{n} = {kind}[{i}]")
            names[n] = f"t{n}"
    pre += _body(graph, graph.ancestors(boundary), names, i4)
    pre += [f"{i4}d[{k}] = {_expression(graph, n, names)}" for k, n in enumerate(boundary)]
    pre.append(f"{i4}return d")
    # _field: state leaves and d entries as locals, state nodes, outputs
    names = {n: f"d{k}" for k, n in enumerate(boundary)}
    fld = ["def _field(x, d, out):"]
    fld += [f"{i4}d{k} = d[{k}]" for k in range(len(boundary))]
    for n in state_nodes:
        if graph.nodes[n][0] == "x":
            fld.append(f"{i4}x{graph.nodes[n][1]} = x[{graph.nodes[n][1]}]")
            names[n] = f"x{graph.nodes[n][1]}"
    fld += _body(graph, state_nodes, names, i4)
    fld += [f"{i4}out[{i}] = {_expression(graph, o, names)}" for i, o in enumerate(outputs)]
    fld.append(f"{i4}return out")
    return "\n".join(pre) + "\n\n\n" + "\n".join(fld) + "\n", len(boundary)
