"""Scalar code from a system's JAX field: trace to a jaxpr, interpret it element by element.

Why hand-written
----------------
The virtual rig advances a few-state system one sample at a time, millions of times per
campaign; only straight scalar code compiled with numba is fast enough (a few hundred ns
per sample, see :mod:`bifid.cbc._fastloop`). No library turns a JAX function into such
code: ``jax2tf`` / XLA emit array programs with per-operation dispatch, and SymPy's code
printers need SymPy expressions, which a JAX field is not (and which, built from a
jaxpr, lose the common subexpressions the jaxpr has). The translation is therefore done
here, on the jaxpr: every array is unrolled into a NumPy object array of scalar nodes of a
:class:`~bifid.cbc._scalar.Graph` (structural operations -- slicing, reshaping,
broadcasting, concatenation, gathers with constant indices -- just move nodes; elementwise
operations, reductions and ``dot_general`` create them; calls, ``custom_jvp``, ``cond``
and ``scan`` / ``fori_loop`` with a fixed trip count are inlined).

Operations the translator has no scalar form for are still accepted when they only
depend on the parameters (e.g. a matrix inverse or ``jnp.linalg.solve`` of parameter
matrices): they are *opaque*, evaluated by JAX once per parameter set
(:func:`TranslatedField.residual_function`), and their results enter the graph as leaves.
A field that applies such an operation to the state raises :class:`Unsupported` and the rig
uses its JAX engine instead.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from bifid.cbc._scalar import OPS, Graph, Unsupported, emit, evaluate

__all__ = ["TranslatedField", "Unsupported", "translate"]

Nodes = np.ndarray  # object array of node ids

_ELEMENTWISE = {
    "add": "add",
    "add_any": "add",
    "sub": "sub",
    "mul": "mul",
    "div": "div",
    "neg": "neg",
    "pow": "pow",
    "max": "max",
    "min": "min",
    "atan2": "atan2",
    "rem": "rem",
    "sin": "sin",
    "cos": "cos",
    "tan": "tan",
    "asin": "asin",
    "acos": "acos",
    "atan": "atan",
    "sinh": "sinh",
    "cosh": "cosh",
    "tanh": "tanh",
    "asinh": "asinh",
    "acosh": "acosh",
    "atanh": "atanh",
    "exp": "exp",
    "exp2": "exp2",
    "log": "log",
    "log1p": "log1p",
    "expm1": "expm1",
    "sqrt": "sqrt",
    "rsqrt": "rsqrt",
    "cbrt": "cbrt",
    "abs": "abs",
    "sign": "sign",
    "floor": "floor",
    "ceil": "ceil",
    "logistic": "logistic",
    "erf": "erf",
    "lgamma": "lgamma",
    "is_finite": "is_finite",
    "lt": "lt",
    "le": "le",
    "gt": "gt",
    "ge": "ge",
    "eq": "eq",
    "ne": "ne",
    "and": "and",
    "or": "or",
    "not": "not",
}
_IDENTITY = {"copy", "copy_p", "stop_gradient", "reduce_precision", "optimization_barrier"}
_CALLS = {
    "pjit": "jaxpr",
    "jit": "jaxpr",
    "closed_call": "call_jaxpr",
    "core_call": "call_jaxpr",
    "remat": "jaxpr",
    "checkpoint": "jaxpr",
    "custom_jvp_call": "call_jaxpr",
    "custom_vjp_call": "call_jaxpr",
    "custom_vjp_call_jaxpr": "fun_jaxpr",
}
MAX_UNROLL = 256  # longest scan / while loop unrolled into the scalar code


def _kind(aval) -> str:
    dt = np.dtype(aval.dtype)
    if dt == np.bool_:
        return "b"
    if np.issubdtype(dt, np.integer):
        return "i"
    if np.issubdtype(dt, np.floating):
        return "f"
    raise Unsupported(f"values of type {dt}")


def _map(fn: Callable, *arrays: Nodes) -> Nodes:
    shape = np.broadcast_shapes(*(a.shape for a in arrays))
    arrays = [np.broadcast_to(a, shape) for a in arrays]
    out = np.empty(shape, dtype=object)
    for idx in np.ndindex(shape):
        out[idx] = fn(*(a[idx] for a in arrays))
    return out


@dataclass
class _Opaque:
    eqn: Any  # the jaxpr equation, evaluated by JAX
    inputs: list[Nodes]  # its (state-independent) operands
    outputs: list[Nodes]  # the r leaves of its results


class _Interpreter:
    def __init__(self, graph: Graph) -> None:
        self.g = graph
        self.opaque: list[_Opaque] = []
        self.n_r = 0

    # -- values --------------------------------------------------------------------
    def constant(self, value: Any, kind: str) -> Nodes:
        arr = np.asarray(value)
        out = np.empty(arr.shape, dtype=object)
        for idx in np.ndindex(arr.shape):
            out[idx] = self.g.const(arr[idx].item(), kind)
        return out

    def concrete(self, nodes: Nodes) -> np.ndarray | None:
        vals = [self.g.value(n) for n in nodes.ravel()]
        if any(v is None for v in vals):
            return None
        return np.asarray(vals).reshape(nodes.shape)

    def read(self, env: dict, v) -> Nodes:
        if type(v).__name__ == "Literal":
            return self.constant(v.val, _kind(v.aval))
        return env[v]

    # -- jaxprs --------------------------------------------------------------------
    def run(self, jaxpr, consts: list, args: list[Nodes]) -> list[Nodes]:
        env: dict = {}
        for v, c in zip(jaxpr.constvars, consts, strict=True):
            env[v] = (
                c
                if isinstance(c, np.ndarray) and c.dtype == object
                else self.constant(np.asarray(c), _kind(v.aval))
            )
        for v, a in zip(jaxpr.invars, args, strict=True):
            env[v] = np.asarray(a, dtype=object).reshape(v.aval.shape)
        for eqn in jaxpr.eqns:
            ins = [self.read(env, v) for v in eqn.invars]
            mark = (len(self.opaque), self.n_r)
            try:
                outs = self.equation(eqn, ins)
            except Unsupported:
                if any(self.g.state[n] for a in ins for n in a.ravel()):
                    raise
                del self.opaque[mark[0] :]  # forget opaque parts of a failed inlining
                self.n_r = mark[1]
                outs = self.make_opaque(eqn, ins)
            for v, o in zip(eqn.outvars, outs, strict=True):
                env[v] = np.asarray(o, dtype=object).reshape(v.aval.shape)
        return [self.read(env, v) for v in jaxpr.outvars]

    def closed(self, cj, args: list[Nodes]) -> list[Nodes]:
        if hasattr(cj, "jaxpr") and hasattr(cj, "consts"):
            return self.run(cj.jaxpr, list(cj.consts), args)
        return self.run(cj, [], args)  # an open jaxpr (remat)

    def make_opaque(self, eqn, ins: list[Nodes]) -> list[Nodes]:
        if any(_kind(v.aval) != "f" for v in eqn.outvars):
            raise Unsupported(f"{eqn.primitive.name} on parameters with non-float results")
        outs = []
        for v in eqn.outvars:
            size = math.prod(v.aval.shape)
            leaves = [self.g.leaf("r", self.n_r + k) for k in range(size)]
            self.n_r += size
            outs.append(np.asarray(leaves, dtype=object).reshape(v.aval.shape))
        self.opaque.append(_Opaque(eqn, ins, outs))
        return outs

    # -- one equation ----------------------------------------------------------------
    def equation(self, eqn, ins: list[Nodes]) -> list[Nodes]:
        name, prm = eqn.primitive.name, eqn.params
        g = self.g
        if name in _ELEMENTWISE:
            op = _ELEMENTWISE[name]
            kind = _kind(eqn.outvars[0].aval)
            if op in ("and", "or", "not") and kind != "b":
                raise Unsupported(f"bitwise {name} on integers")
            if op == "div" and kind == "i":
                raise Unsupported("integer division")
            return [_map(lambda *a: g.op(op, *a), *ins)]
        if name in _IDENTITY:
            return list(ins)
        if name == "integer_pow":
            return [_map(lambda a: g.power(a, int(prm["y"])), ins[0])]
        if name == "round":  # lax.RoundingMethod: 0 away from zero, 1 to nearest even
            op = "rint" if int(prm.get("rounding_method", 0)) == 1 else "round_away"
            return [_map(lambda a: g.op(op, a), ins[0])]
        if name == "square":
            return [_map(lambda a: g.op("mul", a, a), ins[0])]
        if name == "convert_element_type":
            return [self.convert(ins[0], _kind(eqn.outvars[0].aval))]
        if name == "select_n":
            return [self.select(ins[0], ins[1:])]
        if name == "clamp":
            return [_map(lambda lo, x, hi: g.op("min", g.op("max", x, lo), hi), *ins)]
        if name in _CALLS:
            return self.closed(prm[_CALLS[name]], ins)
        if name == "cond":
            return self.cond(prm["branches"], ins[0], ins[1:])
        if name == "scan":
            return self.scan(prm, ins)
        if name == "while":
            return self.while_loop(prm, ins)
        if name == "dot_general":
            return [self.dot_general(ins[0], ins[1], prm["dimension_numbers"])]
        if name in (
            "reduce_sum",
            "reduce_max",
            "reduce_min",
            "reduce_prod",
            "reduce_and",
            "reduce_or",
        ):
            return [self.reduce(name[7:], ins[0], tuple(prm["axes"]))]
        if name in ("cumsum", "cumprod", "cummax", "cummin"):
            return [self.cumulative(name[3:], ins[0], prm["axis"], prm["reverse"])]
        if name == "triangular_solve":
            return [self.triangular_solve(ins[0], ins[1], prm)]
        return self.structural(eqn, ins)

    def convert(self, a: Nodes, kind: str) -> Nodes:
        g = self.g

        def one(n):
            k = g.kinds[n]
            if k == kind:
                return n
            if kind == "f":
                return g.op("to_float", n, kind="f")
            return g.op("to_int" if kind == "i" else "to_bool", n, kind=kind)

        return _map(one, a)

    def select(self, pred: Nodes, cases: list[Nodes]) -> Nodes:
        g = self.g

        def one(p, *cs):
            if len(cs) == 2 and g.kinds[p] == "b":
                return g.op("select", p, cs[0], cs[1])
            out = cs[-1]  # integer predicate: case i where p == i (the last otherwise)
            for i in range(len(cs) - 2, -1, -1):
                out = g.op("select", g.op("eq", p, g.const(i, g.kinds[p])), out, cs[i])
            return out

        return _map(one, pred, *cases)

    def cond(self, branches, index: Nodes, ops: list[Nodes]) -> list[Nodes]:
        which = self.concrete(index)
        if which is not None:
            k = int(np.clip(int(which), 0, len(branches) - 1))
            return self.closed(branches[k], ops)
        results = [self.closed(b, ops) for b in branches]  # pure: evaluate all, select
        return [self.select(index, list(rs)) for rs in zip(*results, strict=True)]

    def scan(self, prm, ins: list[Nodes]) -> list[Nodes]:
        n_c, n_carry, length = prm["num_consts"], prm["num_carry"], int(prm["length"])
        if length > MAX_UNROLL:
            raise Unsupported(f"a scan of {length} steps (more than {MAX_UNROLL})")
        consts, carry, xs = ins[:n_c], ins[n_c : n_c + n_carry], ins[n_c + n_carry :]
        ys = []
        order = range(length - 1, -1, -1) if prm["reverse"] else range(length)
        for i in order:
            outs = self.closed(prm["jaxpr"], [*consts, *carry, *(x[i, ...] for x in xs)])
            carry, y = outs[:n_carry], outs[n_carry:]
            ys.append((i, y))
        ys.sort(key=lambda t: t[0])
        stacked = [
            np.stack([y[j] for _, y in ys]) if ys else np.empty((0,), dtype=object)
            for j in range(len(prm["jaxpr"].jaxpr.outvars) - n_carry)
        ]
        return [*carry, *stacked]

    def while_loop(self, prm, ins: list[Nodes]) -> list[Nodes]:
        nc, nb = prm["cond_nconsts"], prm["body_nconsts"]
        cc, bc, carry = ins[:nc], ins[nc : nc + nb], ins[nc + nb :]
        for _ in range(MAX_UNROLL + 1):
            go = self.concrete(self.closed(prm["cond_jaxpr"], [*cc, *carry])[0])
            if go is None:
                raise Unsupported("a while loop whose condition depends on the state")
            if not bool(go):
                return carry
            carry = self.closed(prm["body_jaxpr"], [*bc, *carry])
        raise Unsupported(f"a while loop of more than {MAX_UNROLL} iterations")

    def _sum(self, terms: list[int]) -> int:
        if not terms:
            return self.g.const(0.0)
        acc = terms[0]
        for t in terms[1:]:
            acc = self.g.op("add", acc, t)
        return acc

    def dot_general(self, lhs: Nodes, rhs: Nodes, dims) -> Nodes:
        (lc, rc), (lb, rb) = dims
        lf = [d for d in range(lhs.ndim) if d not in lc and d not in lb]
        rf = [d for d in range(rhs.ndim) if d not in rc and d not in rb]
        a = np.transpose(lhs, [*lb, *lf, *lc])
        b = np.transpose(rhs, [*rb, *rc, *rf])
        bshape = a.shape[: len(lb)]
        fl, fr = a.shape[len(lb) : len(lb) + len(lf)], b.shape[len(rb) + len(rc) :]
        k = math.prod(a.shape[len(lb) + len(lf) :])
        a = a.reshape(math.prod(bshape), math.prod(fl), k)
        b = b.reshape(math.prod(bshape), k, math.prod(fr))
        out = np.empty((a.shape[0], a.shape[1], b.shape[2]), dtype=object)
        for i, j, m in np.ndindex(out.shape):
            out[i, j, m] = self._sum([self.g.op("mul", a[i, j, t], b[i, t, m]) for t in range(k)])
        return out.reshape(*bshape, *fl, *fr)

    def reduce(self, how: str, a: Nodes, axes: tuple[int, ...]) -> Nodes:
        op = {"sum": "add", "max": "max", "min": "min", "prod": "mul", "and": "and", "or": "or"}[
            how
        ]
        keep = [d for d in range(a.ndim) if d not in axes]
        moved = np.transpose(a, [*keep, *axes])
        flat = moved.reshape(*moved.shape[: len(keep)], -1)
        out = np.empty(flat.shape[:-1], dtype=object)
        for idx in np.ndindex(out.shape):
            terms = list(flat[idx])
            acc = terms[0]
            for t in terms[1:]:
                acc = self.g.op(op, acc, t)
            out[idx] = acc
        return out

    def cumulative(self, how: str, a: Nodes, axis: int, reverse: bool) -> Nodes:
        op = {"sum": "add", "prod": "mul", "max": "max", "min": "min"}[how]
        moved = np.moveaxis(a, axis, 0).copy()
        order = range(moved.shape[0] - 1, -1, -1) if reverse else range(moved.shape[0])
        prev = None
        for i in order:
            if prev is not None:
                moved[i, ...] = _map(
                    lambda x, y: self.g.op(op, y, x), moved[i, ...], moved[prev, ...]
                )
            prev = i
        return np.moveaxis(moved, 0, axis)

    def triangular_solve(self, a: Nodes, b: Nodes, prm) -> Nodes:
        """``op(a) x = b`` (left side) or ``x op(a) = b`` by substitution, per batch."""
        if a.ndim != 2 or b.ndim != 2 or prm.get("conjugate_a", False):
            raise Unsupported("batched or complex triangular_solve")
        m = a.T if prm["transpose_a"] else a
        lower = prm["lower"] != prm["transpose_a"]
        if not prm["left_side"]:  # x m = b  <=>  m^T x^T = b^T
            m, b, lower = m.T, b.T, not lower
        n = m.shape[0]
        x = np.empty(b.shape, dtype=object)
        rows = range(n) if lower else range(n - 1, -1, -1)
        for col in range(b.shape[1]):
            for i in rows:
                js = range(i) if lower else range(i + 1, n)
                s = self.g.op(
                    "sub", b[i, col], self._sum([self.g.op("mul", m[i, j], x[j, col]) for j in js])
                )
                x[i, col] = s if prm["unit_diagonal"] else self.g.op("div", s, m[i, i])
        return x if prm["left_side"] else x.T

    def structural(self, eqn, ins: list[Nodes]) -> list[Nodes]:
        """Operations that move values: NumPy on the node arrays for the common ones, else
        the primitive itself evaluated on arrays of node ids (as float64)."""
        name = eqn.primitive.name
        fast = _numpy_move(name, eqn.params, ins)
        if fast is not None:
            return fast
        data = {"gather": 1, "dynamic_slice": 1, "dynamic_update_slice": 2, "pad": 2}.get(
            name, len(ins)
        )
        if name not in _MOVES:
            raise Unsupported(f"the operation {name!r}")
        args = []
        for i, a in enumerate(ins):
            if i < data:
                args.append(np.asarray(a, dtype=np.float64))
            else:
                c = self.concrete(a)
                if c is None:
                    raise Unsupported(f"{name} with indices that are not constants")
                args.append(np.asarray(c, dtype=np.dtype(eqn.invars[i].aval.dtype)))
        with jax.ensure_compile_time_eval():
            outs = eqn.primitive.bind(*args, **eqn.params)
        outs = outs if eqn.primitive.multiple_results else [outs]
        result = []
        for o in outs:
            ids = np.asarray(o)
            if not np.all(np.isfinite(ids)):
                raise Unsupported(f"{name} with out-of-bounds fills")
            result.append(np.asarray(ids.astype(np.int64), dtype=object))
        return result


def _numpy_move(name: str, prm, ins: list[Nodes]) -> list[Nodes] | None:
    if name == "squeeze":
        return [np.squeeze(ins[0], axis=tuple(prm["dimensions"]))]
    if name == "reshape" and prm.get("dimensions") is None:
        return [ins[0].reshape(tuple(prm["new_sizes"]))]
    if name == "broadcast_in_dim":
        shape, dims = tuple(prm["shape"]), tuple(prm["broadcast_dimensions"])
        expanded = [1] * len(shape)
        for i, d in enumerate(dims):
            expanded[d] = ins[0].shape[i]
        return [np.broadcast_to(ins[0].reshape(expanded), shape)]
    if name == "slice":
        strides = prm["strides"] or (1,) * ins[0].ndim
        return [
            ins[0][
                tuple(
                    slice(a, b, c)
                    for a, b, c in zip(
                        prm["start_indices"], prm["limit_indices"], strides, strict=True
                    )
                )
            ]
        ]
    if name == "concatenate":
        return [np.concatenate(ins, axis=prm["dimension"])]
    if name == "stack" and "axis" in prm:
        return [np.stack(ins, axis=prm["axis"])]
    if name == "transpose":
        return [np.transpose(ins[0], tuple(prm["permutation"]))]
    if name == "rev":
        return [np.flip(ins[0], axis=tuple(prm["dimensions"]))]
    return None


_MOVES = {
    "squeeze",
    "reshape",
    "broadcast_in_dim",
    "expand_dims",
    "slice",
    "concatenate",
    "stack",
    "transpose",
    "rev",
    "pad",
    "gather",
    "dynamic_slice",
    "dynamic_update_slice",
    "split",
    "iota",
}


@dataclass(frozen=True, eq=False)
class TranslatedField:
    """A field as scalar code: ``_prepare(p, r, d)`` and ``_field(x, d, out)`` (numba)."""

    source: str  # the two functions (module level, no decorators)
    n_coefficients: int  # size of d
    n_states: int
    n_params: int
    n_opaque: int  # size of r
    _graph: Graph
    _opaque: tuple[_Opaque, ...]

    def residual_function(self) -> Callable[[np.ndarray], np.ndarray] | None:
        """``p -> r`` (jitted) when the field has opaque parameter-only operations."""
        if not self._opaque:
            return None
        return _residual_jit(self)


@functools.lru_cache(maxsize=16)
def _residual_jit(tf: TranslatedField) -> Callable:
    graph, opaque = tf._graph, tf._opaque

    def residuals(p):
        leaves: dict[int, Any] = {}
        for i in range(tf.n_params):
            leaves[graph.leaf("p", i)] = p[i]
        rs = []
        for op in opaque:
            ins = []
            for nodes in op.inputs:
                vals = evaluate(graph, list(nodes.ravel()), leaves, jnp)
                ins.append(
                    jnp.stack([jnp.asarray(v, dtype=jnp.result_type(float)) for v in vals]).reshape(
                        nodes.shape
                    )
                    if nodes.size
                    else jnp.zeros(nodes.shape)
                )
            ins = [x.astype(v.aval.dtype) for x, v in zip(ins, op.eqn.invars, strict=True)]
            outs = op.eqn.primitive.bind(*ins, **op.eqn.params)
            outs = outs if op.eqn.primitive.multiple_results else [outs]
            for nodes, val in zip(op.outputs, outs, strict=True):
                flat = jnp.ravel(val)
                for k, n in enumerate(nodes.ravel()):
                    leaves[n] = flat[k]
                rs.append(flat)
        return jnp.concatenate(rs).astype(jnp.float64)

    return jax.jit(residuals)


def translate(field: Callable, n_states: int, n_params: int) -> TranslatedField:
    """Trace ``field(x, p)`` and translate it to scalar code (raises :class:`Unsupported`)."""
    try:
        cj = jax.make_jaxpr(field)(jnp.zeros(n_states), jnp.zeros(n_params))
    except Exception as exc:  # a field that cannot be traced at all
        raise Unsupported(f"the field could not be traced ({type(exc).__name__}: {exc})") from None
    out_avals = [v.aval for v in cj.jaxpr.outvars]
    if len(out_avals) != 1 or tuple(out_avals[0].shape) != (n_states,):
        raise Unsupported(f"the field must return one array of shape ({n_states},)")
    graph = Graph()
    interp = _Interpreter(graph)
    x = np.asarray([graph.leaf("x", i) for i in range(n_states)], dtype=object)
    p = np.asarray([graph.leaf("p", i) for i in range(n_params)], dtype=object)
    (out,) = interp.run(cj.jaxpr, list(cj.consts), [x, p])
    outputs = [int(n) for n in out.ravel()]
    if any(graph.kinds[n] != "f" for n in outputs):
        outputs = [
            graph.op("to_float", n, kind="f") if graph.kinds[n] != "f" else n for n in outputs
        ]
    source, n_d = emit(graph, outputs)
    return TranslatedField(
        source=source,
        n_coefficients=n_d,
        n_states=n_states,
        n_params=n_params,
        n_opaque=interp.n_r,
        _graph=graph,
        _opaque=tuple(interp.opaque),
    )


assert set(_ELEMENTWISE.values()) <= set(OPS)
