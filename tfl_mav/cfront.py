"""The accelerator seam's front end: a natural pure Python function lowered, mechanically, to
the one straight-line function :mod:`ctranslate` translates.

:func:`lower` reads a function's own source (:func:`inspect.getsource`) and rewrites its
syntax tree, never its arithmetic:

* **calls inlined**: a call of another module-level pure Python function (found in the
  caller's module globals, or an attribute of a module there) is replaced by that function's
  body, its locals renamed, its parameters bound to the arguments' values; a NamedTuple
  class called is its tuple; ``min``/``max`` are the comparisons the builtins make
  (``min(a, b)`` is ``b if b < a else a``), ``float``/``len``/``tuple`` what they mean on
  floats and tuples;
* **loops unrolled**: ``for i in range(N)`` with a constant ``N`` whose body reads ``i``
  (and ``for x in <tuple>``, and ``tuple(… for i in range(N))``) becomes ``N`` copies of the
  body with ``i`` the constant; a loop that does not read its index stays a loop;
* **tuples scalar-replaced**: tuple literals, unpacking, ``t[k]`` and ``t.field`` with a
  constant ``k`` (NamedTuples: the field's index), ``+`` and ``*`` of tuples, are resolved at
  lowering into one float local per element; a sequence argument is unpacked once at entry
  (its shape taken from an example argument).

Every float operation of the original stays, with its operands, in the order each value
needs it: the compiled function returns the original's bits (tests/test_cfront.py). What it
cannot lower — a call inside a conditional expression (it would run unconditionally), a
non-constant index, a loop with ``break`` that must unroll, recursion, an early ``return``
of a value — is a :class:`~tfl_mav.ctranslate.NativeError` naming it.
"""

from __future__ import annotations

import ast
import builtins
import inspect
import math
import re
import textwrap
import types
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

from tfl_mav.ctranslate import NativeError

__all__ = ["Tup", "lower", "lower_files", "shape_key"]

#: math functions by object → the name the translator knows them by.
_INTRINSICS: dict[Any, str] = {
    getattr(math, n): f"_{n}" for n in ("sqrt", "sin", "cos", "tan", "atan", "acos", "tanh",
                                        "log", "exp", "pow", "atan2", "copysign", "hypot",
                                        "isfinite", "isnan")}
_INTRINSICS[abs] = "abs"
_RESERVED = re.compile(r"_[itv]\d.*|.*__.*")     # the names lowering itself makes


@dataclass
class Tup:
    """A tuple known at lowering: its items (scalar expressions or Tups), NamedTuple
    fields if any."""

    items: list[Any]
    fields: tuple[str, ...] | None = None


@dataclass
class _Ref:
    """A global that is not a number: a function, class or module."""

    obj: Any


class _Lazy:
    """An expression's text, made only for an error message."""

    def __init__(self, e: ast.AST) -> None:
        self.e = e

    def __repr__(self) -> str:
        return repr(ast.unparse(self.e))


def _shape(v: Any) -> Any:
    return Tup([_shape(x) for x in v.items], v.fields) if isinstance(v, Tup) else None


def _same_shape(a: Any, b: Any) -> bool:
    if a is None or b is None:
        return a is b
    return len(a.items) == len(b.items) and all(
        _same_shape(x, y) for x, y in zip(a.items, b.items, strict=True))


def _read(e: ast.AST) -> set[str]:
    return {n.id for n in ast.walk(e) if isinstance(n, ast.Name)}


def _leaves(v: Any) -> list[Any]:
    return [y for x in v.items for y in _leaves(x)] if isinstance(v, Tup) else [v]


def _simple(e: Any) -> bool:
    return isinstance(e, (ast.Name, ast.Constant)) or (
        isinstance(e, ast.UnaryOp) and isinstance(e.operand, ast.Constant))


def _int(e: Any, what: object) -> int:
    """The constant integer ``e`` is (an index, a range), folded from constants."""
    if isinstance(e, ast.Constant) and type(e.value) is int:
        return e.value
    if isinstance(e, ast.UnaryOp) and isinstance(e.op, ast.USub):
        return -_int(e.operand, what)
    if isinstance(e, ast.BinOp) and type(e.op) in _INT_OPS:
        return int(_INT_OPS[type(e.op)](_int(e.left, what), _int(e.right, what)))
    raise NativeError(f"{what} is not a constant integer: {ast.unparse(e)!r}")


_INT_OPS: dict[type, Callable[[int, int], int]] = {
    ast.Add: int.__add__, ast.Sub: int.__sub__, ast.Mult: int.__mul__,
    ast.FloorDiv: int.__floordiv__, ast.Mod: int.__mod__}


def _value(obj: Any, what: object) -> Any:
    """A global's value: a number (a constant), a tuple of them, or a reference."""
    if isinstance(obj, bool):
        return ast.Constant(int(obj))
    if isinstance(obj, (int, float)):
        f = float(obj)
        if f != f:
            return ast.Name("_nan", ast.Load())
        if f in (math.inf, -math.inf):
            inf = ast.Name("_inf", ast.Load())
            return inf if f > 0 else ast.UnaryOp(ast.USub(), inf)
        return ast.Constant(obj)
    if isinstance(obj, (tuple, list)):
        return Tup([_value(x, what) for x in obj], getattr(obj, "_fields", None))
    if isinstance(obj, (types.FunctionType, types.ModuleType, type, types.BuiltinFunctionType)):
        return _Ref(obj)
    raise NativeError(f"{what} is a {type(obj).__name__}, not a number, tuple or function")


def _source(fn: types.FunctionType) -> ast.FunctionDef:
    """``fn``'s definition, its docstring dropped (parsed once: lowering never changes it)."""
    node = _SOURCES.get(fn.__code__)
    if node is None:
        node = _SOURCES[fn.__code__] = _parse(fn)
    return node


_SOURCES: dict[types.CodeType, ast.FunctionDef] = {}


def _parse(fn: types.FunctionType) -> ast.FunctionDef:
    if fn.__closure__:
        raise NativeError(f"{fn.__qualname__} is a closure: only module-level functions")
    try:
        tree = ast.parse(textwrap.dedent(inspect.getsource(fn)))
    except (OSError, TypeError) as exc:
        raise NativeError(f"no source for {fn.__qualname__}: {exc}") from None
    node = tree.body[0]
    if not isinstance(node, ast.FunctionDef):
        raise NativeError(f"{fn.__qualname__} is not a plain def")
    a = node.args
    if a.vararg or a.kwarg or a.kwonlyargs or a.posonlyargs or node.decorator_list:
        raise NativeError(f"{fn.__qualname__}: only plain positional parameters")
    body = node.body
    if body and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant):
        body = body[1:]                                 # the docstring
    node.body = body
    return node


def _assigned(fn: types.FunctionType, node: ast.FunctionDef) -> set[str]:
    """The function's local names (a name assigned anywhere in it is local)."""
    names = _ASSIGNED.get(fn.__code__)
    if names is None:
        names = {n.id for n in ast.walk(node) if isinstance(n, ast.Name)
                 and isinstance(n.ctx, ast.Store)} | {a.arg for a in node.args.args}
        for name in names:
            if _RESERVED.fullmatch(name):
                raise NativeError(f"{fn.__qualname__}: the name {name!r} is the seam's own")
        _ASSIGNED[fn.__code__] = names
    return names


_ASSIGNED: dict[types.CodeType, set[str]] = {}


class _Frame:
    """One function being lowered: the top-level one, or one inlined instance of a callee."""

    def __init__(self, low: _Lowerer, fn: types.FunctionType, node: ast.FunctionDef,
                 prefix: str) -> None:
        self.low, self.fn, self.prefix = low, fn, prefix
        self.globals = fn.__globals__
        self.shapes: dict[str, Any] = {}        # local → None (a float) or its Tup shape
        self.alias: dict[str, Any] = {}         # unrolled index → its constant
        self.version: dict[str, int] = {}       # a name rebound with another shape: new floats
        self.depth = low.depth                  # the branches and loops it is called in
        self.made: dict[tuple[str, int, int], tuple[Any, Any]] = {}     # local()'s, kept
        self.assigned = _assigned(fn, node)

    # ----- names ------------------------------------------------------------------------
    def local(self, name: str, shape: Any) -> Any:
        """The value of local ``name`` of this shape: its float variables."""
        key = (name, self.version.get(name, 0), id(shape))
        made = self.made.get(key)
        if made is None or made[0] is not shape:
            made = self.made[key] = (shape, self._local(name, shape))
        return made[1]

    def _local(self, name: str, shape: Any) -> Any:
        ver = self.version.get(name, 0)
        base = self.prefix + name + (f"__v{ver}" if ver else "")
        if shape is None:
            return ast.Name(base, ast.Load())

        def walk(s: Any, path: tuple[int, ...]) -> Any:
            if s is None:
                return ast.Name(f"{base}__{'_'.join(map(str, path))}", ast.Load())
            return Tup([walk(x, (*path, k)) for k, x in enumerate(s.items)], s.fields)
        return walk(shape, ())

    def name(self, name: str) -> Any:
        if name in self.alias:
            return self.alias[name]
        if name in self.assigned:
            if name not in self.shapes:
                raise NativeError(f"{self.fn.__qualname__}: {name!r} is read before it is set")
            return self.local(name, self.shapes[name])
        if name in self.globals:
            return _value(self.globals[name], f"global {name!r}")
        if hasattr(builtins, name):
            return _Ref(getattr(builtins, name))
        raise NativeError(f"{self.fn.__qualname__}: name {name!r} is not defined")

    def bind(self, name: str, value: Any) -> None:
        """``name = value``: a float, or one float variable per element of a tuple."""
        if isinstance(value, _Ref):
            raise NativeError(f"{name!r} is bound to {value.obj!r}, not a number or tuple")
        old = self.shapes.get(name, ...)
        shape = _shape(value)
        if old is not ... and not _same_shape(old, shape):
            if self.low.depth > self.depth:      # which shape would depend on the path
                raise NativeError(f"{self.fn.__qualname__}: {name!r} changes shape in a "
                                  "branch or a loop")
            self.version[name] = self.version.get(name, 0) + 1
        self.shapes[name] = shape
        targets = _leaves(self.local(name, shape))
        values = _leaves(value)
        out = self.low.out
        if isinstance(value, Tup) and {t.id for t in targets} & set().union(
                *(_read(v) for v in values)):
            values = [self.low.temp(v, True) for v in values]   # t = (t[1], t[0])
        out.extend(ast.Assign([ast.Name(t.id, ast.Store())], v) for t, v in
                   zip(targets, values, strict=True))

    def unpack(self, target: ast.expr, value: Any) -> None:
        """``target = value`` for a name or a (nested) tuple of names."""
        if isinstance(target, ast.Name):
            self.bind(target.id, value)
            return
        if not isinstance(target, (ast.Tuple, ast.List)):
            raise NativeError(f"cannot assign to {ast.unparse(target)!r}")
        elts = list(target.elts)
        star = [k for k, t in enumerate(elts) if isinstance(t, ast.Starred)]
        if not isinstance(value, Tup) or (len(value.items) != len(elts) if not star
                                          else len(value.items) < len(elts) - 1):
            raise NativeError(f"cannot unpack into {ast.unparse(target)!r}: not a tuple of "
                              f"{len(elts)}")
        if star:                                # a, *rest, b = t: rest is a tuple
            k, m = star[0], len(value.items) - len(elts) + 1
            elts[k] = elts[k].value     # type: ignore[attr-defined]
            value = Tup([*value.items[:k], Tup(value.items[k:k + m]), *value.items[k + m:]])
        written = {n.id for n in ast.walk(target) if isinstance(n, ast.Name)}
        if any(self.prefix + w in _read(x) or any(
                n.startswith(self.prefix + w + "__") for n in _read(x))
               for w in written for x in _leaves(value)):
            value = _retemp(self.low, value, True)      # a, b = b, a: read first
        for t, v in zip(elts, value.items, strict=True):
            self.unpack(t, v)


def _retemp(low: _Lowerer, v: Any, names: bool = False) -> Any:
    """``v`` with each float computed into a local now (``names``: a name copied too)."""
    return Tup([_retemp(low, x, names) for x in v.items], v.fields) if isinstance(v, Tup) \
        else low.temp(v, names)


class _Lowerer:
    def __init__(self) -> None:
        self.out: list[ast.stmt] = []
        self.n = 0
        self.stack: list[types.FunctionType] = []
        self.depth = 0                          # nesting in kept branches and loops
        self.files: set[str] = set()            # the source files of the functions read

    def fresh(self) -> ast.Name:
        self.n += 1
        return ast.Name(f"_t{self.n}", ast.Load())

    def temp(self, e: Any, names: bool = False) -> Any:
        if isinstance(e, ast.Constant) or (_simple(e) and not names):
            return e
        self.n += 1
        name = f"_t{self.n}"
        self.out.append(ast.Assign([ast.Name(name, ast.Store())], e))
        return ast.Name(name, ast.Load())

    def block(self, f: _Frame, body: list[ast.stmt]) -> list[ast.stmt]:
        saved, self.out = self.out, []
        self.depth += 1
        for st in body:
            self.stmt(f, st)
        self.depth -= 1
        block, self.out = self.out, saved
        return block or [ast.Pass()]

    def inline(self, fn: types.FunctionType, args: list[Any], kwargs: dict[str, Any]) -> Any:
        """A call of ``fn``: its body here, renamed; the value of its final ``return``."""
        if fn in self.stack:
            raise NativeError(f"{fn.__qualname__} is recursive")
        node = _source(fn)
        params = [a.arg for a in node.args.args]
        defaults = dict(zip(params[len(params) - len(fn.__defaults__ or ()):],
                            fn.__defaults__ or (), strict=True))
        if len(args) > len(params) or set(kwargs) - set(params):
            raise NativeError(f"{fn.__qualname__}: wrong arguments")
        bound = dict(zip(params, args, strict=False)) | kwargs
        *body, ret = node.body or [ast.Pass()]
        if not isinstance(ret, ast.Return) or ret.value is None or any(
                isinstance(n, ast.Return) for st in body for n in ast.walk(st)):
            raise NativeError(f"{fn.__qualname__}: an inlined function must end with its "
                              "one return of a value")
        self.n += 1
        f = _Frame(self, fn, node, f"_i{self.n}_")
        for p in params:
            if p in bound:
                f.bind(p, bound[p])
            elif p in defaults:
                f.bind(p, _value(defaults[p], f"default of {p!r}"))
            else:
                raise NativeError(f"{fn.__qualname__}: no argument for {p!r}")
        self.stack.append(fn)
        self.files.add(fn.__code__.co_filename)
        for st in body:
            self.stmt(f, st)
        result = self.expr(f, ret.value, False)
        self.stack.pop()
        return _retemp(self, result) if isinstance(result, Tup) else self.temp(result)


    # ----- expressions --------------------------------------------------------------------
    def num(self, f: _Frame, e: ast.expr, cond: bool) -> Any:
        v = self.expr(f, e, cond)
        if isinstance(v, (Tup, _Ref)):
            raise NativeError(f"{ast.unparse(e)!r} is not a number here")
        return v

    def hoist(self, e: Any, cond: bool) -> Any:
        """``e`` computed once, ahead, into a local — unless only some paths compute it
        (``cond``): then written where it is used (the same operation, maybe twice)."""
        return e if cond else self.temp(e)

    def expr(self, f: _Frame, e: ast.expr, cond: bool) -> Any:
        """``e``'s value: a float expression, a :class:`Tup`, or a reference. ``cond``: only
        some paths evaluate ``e`` (a branch of ``… if … else …``, a later operand of
        ``and``/``or`` or of a comparison chain): no call is inlined ahead of it there."""
        if isinstance(e, ast.Constant):
            if e.value is None or not isinstance(e.value, (int, float)):
                raise NativeError(f"constant {e.value!r} is not a number")
            return _value(e.value, "constant")
        if isinstance(e, ast.Name):
            return f.name(e.id)
        if isinstance(e, ast.Attribute):
            v = self.expr(f, e.value, cond)
            if isinstance(v, Tup) and v.fields and e.attr in v.fields:
                return v.items[v.fields.index(e.attr)]
            if isinstance(v, _Ref) and isinstance(v.obj, types.ModuleType) \
                    and hasattr(v.obj, e.attr):
                return _value(getattr(v.obj, e.attr), _Lazy(e))
            raise NativeError(f"cannot lower {ast.unparse(e)!r}")
        if isinstance(e, ast.Subscript):
            v = self.expr(f, e.value, cond)
            if not isinstance(v, Tup):
                raise NativeError(f"{ast.unparse(e.value)!r} is not a tuple")
            if isinstance(e.slice, ast.Slice):
                lo, hi, step = (None if x is None else _int(self.expr(f, x, cond), "a slice")
                                for x in (e.slice.lower, e.slice.upper, e.slice.step))
                return Tup(v.items[lo:hi:step])
            k = _int(self.expr(f, e.slice, cond), _Lazy(e))
            if not -len(v.items) <= k < len(v.items):
                raise NativeError(f"{ast.unparse(e)!r}: index {k} out of range")
            return v.items[k]
        if isinstance(e, (ast.Tuple, ast.List)):
            items: list[Any] = []
            for x in e.elts:
                if isinstance(x, ast.Starred):
                    items.extend(self.tup(f, x.value, cond).items)
                else:
                    items.append(self.value(f, x, cond))
            return Tup(items)
        if isinstance(e, ast.BinOp):
            a, b = self.value(f, e.left, cond), self.value(f, e.right, cond)
            if isinstance(a, Tup) or isinstance(b, Tup):
                return _tuple_op(a, e.op, b, _Lazy(e))
            return ast.BinOp(a, e.op, b)
        if isinstance(e, ast.UnaryOp):
            return ast.UnaryOp(e.op, self.num(f, e.operand, cond))
        if isinstance(e, ast.Compare):
            if any(isinstance(op, (ast.Is, ast.IsNot, ast.In, ast.NotIn)) for op in e.ops):
                raise NativeError(f"cannot lower {ast.unparse(e)!r}")
            left = self.num(f, e.left, cond)
            rights = [self.num(f, c, cond or k > 0) for k, c in enumerate(e.comparators)]
            if all(isinstance(x, ast.Constant) and type(x.value) is int
                   for x in (left, *rights)):          # indices of an unrolled loop
                return ast.Constant(int(eval(compile(ast.Expression(ast.Compare(
                    left, e.ops, rights)), "<index>", "eval"))))
            return ast.Compare(left, e.ops, rights)
        if isinstance(e, ast.BoolOp):
            return ast.BoolOp(e.op, [self.num(f, v, cond or k > 0)
                                     for k, v in enumerate(e.values)])
        if isinstance(e, ast.IfExp):
            test = self.num(f, e.test, cond)
            if isinstance(test, ast.Constant):
                return self.expr(f, e.body if test.value else e.orelse, cond)
            if not cond:
                return self.if_expr(f, test, e)
            body, orelse = self.value(f, e.body, True), self.value(f, e.orelse, True)
            if not (isinstance(body, Tup) or isinstance(orelse, Tup)):
                return ast.IfExp(test, body, orelse)
            if not (_same_shape(_shape(body), _shape(orelse)) and isinstance(body, Tup)):
                raise NativeError(f"{ast.unparse(e)!r}: the branches differ in shape")
            test = self.hoist(test, cond)
            return _zip_tup(lambda a, b: ast.IfExp(test, a, b), body, orelse)
        if isinstance(e, ast.Call):
            return self.call(f, e, cond)
        if isinstance(e, (ast.GeneratorExp, ast.ListComp)):
            return self.comprehension(f, e, cond)
        raise NativeError(f"cannot lower {ast.unparse(e)!r}")

    def if_expr(self, f: _Frame, test: Any, e: ast.IfExp) -> Any:
        """``a if test else b``: as it is when its branches are expressions, else (a call
        inlined, a ``min`` computed ahead) an ``if`` statement setting new locals — only the
        branch taken is computed, as in Python."""
        saved, self.depth = self.out, self.depth + 1
        self.out = []
        body = self.value(f, e.body, False)
        body_st, self.out = self.out, []
        orelse = self.value(f, e.orelse, False)
        orelse_st, self.out, self.depth = self.out, saved, self.depth - 1
        if not (body_st or orelse_st or isinstance(body, Tup) or isinstance(orelse, Tup)):
            return ast.IfExp(test, body, orelse)
        if not _same_shape(_shape(body), _shape(orelse)):
            raise NativeError(f"{ast.unparse(e)!r}: the branches differ in shape")
        if not (body_st or orelse_st):
            test = self.hoist(test, False)
            return _zip_tup(lambda a, b: ast.IfExp(test, a, b), body, orelse)
        names = _zip_tup(lambda a, b: self.fresh(), body, orelse)
        for st, v in ((body_st, body), (orelse_st, orelse)):
            st.extend(ast.Assign([ast.Name(n.id, ast.Store())], x)
                      for n, x in zip(_leaves(names), _leaves(v), strict=True))
        self.out.append(ast.If(test, body_st, orelse_st))
        return names

    def value(self, f: _Frame, e: ast.expr, cond: bool) -> Any:
        v = self.expr(f, e, cond)
        if isinstance(v, _Ref):
            raise NativeError(f"{ast.unparse(e)!r} is {v.obj!r}, not a number or tuple")
        return v

    def tup(self, f: _Frame, e: ast.expr, cond: bool) -> Tup:
        v = self.expr(f, e, cond)
        if not isinstance(v, Tup):
            raise NativeError(f"{ast.unparse(e)!r} is not a tuple")
        return v

    def call(self, f: _Frame, e: ast.Call, cond: bool) -> Any:
        fv = self.expr(f, e.func, cond)
        what = _Lazy(e)
        if not isinstance(fv, _Ref):
            raise NativeError(f"{ast.unparse(e.func)!r} is not a function: {what!r}")
        obj = fv.obj
        if any(isinstance(a, ast.Starred) for a in e.args):      # f(*t): t's items
            e = ast.Call(e.func, [y for a in e.args for y in (
                [ast.Subscript(a.value, ast.Constant(k), ast.Load())
                 for k in range(len(self.tup(f, a.value, cond).items))]
                if isinstance(a, ast.Starred) else [a])], e.keywords)
        if isinstance(obj, types.FunctionType):
            if cond:
                raise NativeError(f"{what!r} is called on some paths only (a conditional "
                                  "expression, and/or): write it as an if statement")
            args = [self.value(f, a, cond) for a in e.args]
            kwargs = {k.arg: self.value(f, k.value, cond) for k in e.keywords
                      if k.arg is not None}
            return self.inline(obj, args, kwargs)
        if isinstance(obj, type) and issubclass(obj, tuple) and hasattr(obj, "_fields"):
            items = dict(zip(obj._fields, (self.value(f, a, cond) for a in e.args),
                             strict=False))
            items |= {k.arg: self.value(f, k.value, cond) for k in e.keywords}
            defaults = obj._field_defaults
            missing = [n for n in obj._fields if n not in items and n not in defaults]
            if missing or set(items) - set(obj._fields):
                raise NativeError(f"{what!r}: fields do not match {obj.__name__}")
            return Tup([items[n] if n in items else _value(defaults[n], n)
                        for n in obj._fields], obj._fields)
        if e.keywords:
            raise NativeError(f"cannot lower keyword arguments: {what!r}")
        if obj in (min, max):
            args = [self.value(f, a, cond) for a in e.args]
            if len(args) == 1 and isinstance(args[0], Tup):
                args = args[0].items
            if not args or any(isinstance(a, Tup) for a in args):
                raise NativeError(f"{what!r}: min/max of numbers only")
            op = ast.Lt() if obj is min else ast.Gt()
            best = self.hoist(args[0], cond)
            for k, b in enumerate(args[1:]):
                b = self.hoist(b, cond)     # the builtin: the first of equals, b op best
                best = ast.IfExp(ast.Compare(b, [op], [best]), b, best)
                if k < len(args) - 2:
                    best = self.hoist(best, cond)
            return best
        if obj is float and len(e.args) == 1:
            return self.num(f, e.args[0], cond)
        if obj is len and len(e.args) == 1:
            return ast.Constant(len(self.tup(f, e.args[0], cond).items))
        if obj in (tuple, list) and len(e.args) == 1:
            return Tup(list(self.tup(f, e.args[0], cond).items))
        try:
            name = _INTRINSICS.get(obj)
        except TypeError:
            name = None
        if name is not None:
            return ast.Call(ast.Name(name, ast.Load()),
                            [self.num(f, a, cond) for a in e.args], [])
        raise NativeError(f"{what!r}: {obj!r} is neither a pure Python function nor a math "
                          "function the translator knows")

    def iteration(self, f: _Frame, it: ast.expr, cond: bool) -> list[Any]:
        """The values a ``for`` takes: ``range`` of constants, or a tuple's items."""
        if _is_range(f, it):
            bounds = [_int(self.expr(f, a, cond), "a range bound") for a in it.args]
            return [ast.Constant(k) for k in range(*bounds)]
        return list(self.tup(f, it, cond).items)

    def comprehension(self, f: _Frame, e: ast.GeneratorExp | ast.ListComp, cond: bool) -> Tup:
        gen = e.generators
        if len(gen) != 1 or gen[0].ifs or not isinstance(gen[0].target, ast.Name):
            raise NativeError(f"only (… for x in range(N) / a tuple): {ast.unparse(e)!r}")
        name = gen[0].target.id
        saved = f.alias.get(name, ...)
        items = []
        for v in self.iteration(f, gen[0].iter, cond):
            f.alias[name] = v
            items.append(self.value(f, e.elt, cond))
        if saved is ...:
            f.alias.pop(name, None)
        else:
            f.alias[name] = saved
        return Tup(items)

    # ----- statements ---------------------------------------------------------------------
    def stmt(self, f: _Frame, st: ast.stmt) -> None:
        if isinstance(st, (ast.Assign, ast.AnnAssign)) and st.value is not None:
            value = self.value(f, st.value, False)
            targets = st.targets if isinstance(st, ast.Assign) else [st.target]
            if len(targets) > 1:
                value = _retemp(self, value) if isinstance(value, Tup) else self.temp(value)
            for t in targets:
                f.unpack(t, value)
        elif isinstance(st, ast.AugAssign) and isinstance(st.target, ast.Name):
            cur = f.name(st.target.id)
            value = self.value(f, st.value, False)
            if isinstance(cur, Tup) or isinstance(value, Tup):
                f.bind(st.target.id, _tuple_op(cur, st.op, value, _Lazy(st)))
            else:
                f.bind(st.target.id, ast.BinOp(cur, st.op, value))
        elif isinstance(st, ast.If):
            test = self.num(f, st.test, False)
            if isinstance(test, ast.Constant):          # decided at lowering
                for s in st.body if test.value else st.orelse:
                    self.stmt(f, s)
                return
            self.out.append(ast.If(test, self.block(f, st.body),
                                   self.block(f, st.orelse) if st.orelse else []))
        elif isinstance(st, ast.For):
            self.loop(f, st)
        elif isinstance(st, ast.Return):
            if not (st.value is None or (isinstance(st.value, ast.Constant)
                    and st.value.value is None)) or f.prefix:
                raise NativeError(f"{f.fn.__qualname__}: only the last statement returns a "
                                  f"value: {ast.unparse(st)!r}")
            self.out.append(ast.Return(ast.Constant(None)))
        elif isinstance(st, ast.Break):
            self.out.append(ast.Break())
        elif isinstance(st, ast.Pass) or (isinstance(st, ast.Expr) \
                and isinstance(st.value, ast.Constant) and isinstance(st.value.value, str)):
            pass
        else:
            raise NativeError(f"cannot lower the statement {ast.unparse(st)!r}")

    def loop(self, f: _Frame, st: ast.For) -> None:
        """A loop that does not read its index stays a loop; any other is unrolled."""
        it = st.iter
        is_range = _is_range(f, it)
        simple_range = is_range and len(it.args) == 1  # type: ignore[attr-defined]
        reads_index = not isinstance(st.target, ast.Name) or st.target.id in {
            n.id for s in st.body for n in ast.walk(s) if isinstance(n, ast.Name)}
        if simple_range and not reads_index:
            n = _int(self.expr(f, it.args[0], False), "a loop count")
            self.out.append(ast.For(ast.Name("_", ast.Store()),
                                    ast.Call(ast.Name("range", ast.Load()),
                                             [ast.Constant(n)], []),
                                    self.block(f, st.body),
                                    self.block(f, st.orelse) if st.orelse else []))
            return
        if any(isinstance(n, (ast.Break, ast.Continue)) for s in st.body for n in _own(s)):
            raise NativeError(f"a loop that reads its index is unrolled, and cannot break: "
                              f"{ast.unparse(st.target)!r}")
        for v in self.iteration(f, it, False):
            if is_range and isinstance(st.target, ast.Name):
                f.alias[st.target.id] = v          # the index: a constant in each copy
            else:
                f.unpack(st.target, v)
            for s in st.body:
                self.stmt(f, s)
        if is_range and isinstance(st.target, ast.Name):
            f.alias.pop(st.target.id, None)
        for s in st.orelse:                         # no break: the else always runs
            self.stmt(f, s)


def _is_range(f: _Frame, it: ast.expr) -> bool:
    return isinstance(it, ast.Call) and isinstance(it.func, ast.Name) \
        and it.func.id not in f.assigned and f.name(it.func.id) == _Ref(range)


def _own(st: ast.stmt) -> list[ast.AST]:
    """The nodes of ``st`` outside any loop nested in it."""
    if isinstance(st, (ast.For, ast.While)):
        return [n for s in st.orelse for n in _own(s)]
    out: list[ast.AST] = [st]
    for child in ast.iter_child_nodes(st):
        if isinstance(child, ast.stmt):
            out.extend(_own(child))
        else:
            out.extend(ast.walk(child))
    return out


def _tuple_op(a: Any, op: ast.operator, b: Any, what: object) -> Tup:
    if isinstance(op, ast.Add) and isinstance(a, Tup) and isinstance(b, Tup):
        return Tup(a.items + b.items)
    if isinstance(op, ast.Mult):
        t, n = (a, b) if isinstance(a, Tup) else (b, a)
        if isinstance(t, Tup) and not isinstance(n, Tup):
            return Tup(t.items * _int(n, "a tuple's repeat count"))
    raise NativeError(f"cannot lower the tuple operation {what}")


def _zip_tup(fn: Callable[[Any, Any], Any], a: Any, b: Any) -> Any:
    if isinstance(a, Tup):
        return Tup([_zip_tup(fn, x, y) for x, y in zip(a.items, b.items, strict=True)],
                   a.fields)
    return fn(a, b)


def _entry_shape(x: Any, what: str) -> Any:
    if isinstance(x, (bool, int, float)):
        return None
    if isinstance(x, (tuple, list)) and x:
        return Tup([_entry_shape(v, what) for v in x], getattr(x, "_fields", None))
    raise NativeError(f"{what}: an argument must be a number or a non-empty tuple of them")


def lower(fn: Callable[..., Any], example: Sequence[Any]) -> str:
    """The source of one function the translator takes, doing what ``fn`` does on arguments
    shaped like ``example`` (numbers, and tuples or lists of them, nested; NamedTuples name
    their fields): the same name, the same parameters, each sequence unpacked at entry."""
    return lower_files(fn, example)[0]


def shape_key(example: Sequence[Any]) -> str:
    """The shapes of ``example`` as text (what the lowering depends on besides the code)."""
    return repr(tuple(_entry_shape(x, "an argument") for x in example))


def lower_files(fn: Callable[..., Any], example: Sequence[Any]) -> tuple[str, set[str]]:
    """:func:`lower`, and the source files of every function it read."""
    if not isinstance(fn, types.FunctionType):
        raise NativeError(f"{fn!r} is not a Python function")
    node = _source(fn)
    params = [a.arg for a in node.args.args]
    if len(params) != len(example):
        raise NativeError(f"{fn.__qualname__}: {len(params)} parameters, "
                          f"{len(example)} example arguments")
    low = _Lowerer()
    low.files.add(fn.__code__.co_filename)
    f = _Frame(low, fn, node, "")
    for p, x in zip(params, example, strict=True):
        shape = f.shapes[p] = _entry_shape(x, f"{fn.__qualname__}({p})")
        if shape is not None:
            target = _target(f.local(p, shape))
            low.out.append(ast.Assign([target], ast.Name(p, ast.Load())))
    *body, ret = node.body or [ast.Pass()]
    if not isinstance(ret, ast.Return) or ret.value is None:
        raise NativeError(f"{fn.__qualname__} must end with return (…)")
    for st in body:
        low.stmt(f, st)
    result = low.expr(f, ret.value, False)
    if not isinstance(result, Tup):
        raise NativeError(f"{fn.__qualname__} must return a tuple")
    low.out.append(ast.Return(_tuple(result)))
    out = ast.FunctionDef(name=fn.__name__, args=ast.arguments(
        posonlyargs=[], args=[ast.arg(p) for p in params], kwonlyargs=[], kw_defaults=[],
        defaults=[]), body=low.out, decorator_list=[], lineno=1)
    _number(low.out)
    return ast.unparse(ast.Module([out], [])) + "\n", low.files


def _number(body: list[ast.stmt]) -> None:
    """Line numbers on the statements (ast.unparse reads them; the expressions need none)."""
    for st in body:
        st.lineno = 1
        for block in (getattr(st, "body", None), getattr(st, "orelse", None)):
            if block:
                _number(block)


def _target(v: Any) -> ast.expr:
    if isinstance(v, Tup):
        return ast.Tuple([_target(x) for x in v.items], ast.Store())
    return ast.Name(v.id, ast.Store())


def _tuple(v: Any) -> ast.expr:
    return ast.Tuple([_tuple(x) for x in v.items], ast.Load()) if isinstance(v, Tup) else v
