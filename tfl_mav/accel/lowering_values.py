"""The seam front end's values — a tuple known at lowering (:class:`Tup`), a reference to a
global — and one function being lowered (:class:`Frame`): its locals' floats, shapes and
renaming."""

from __future__ import annotations

import ast
import builtins
import inspect
import math
import re
import sys
import textwrap
import types
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from tfl_mav.accel.ctranslate import NativeError

if TYPE_CHECKING:
    from tfl_mav.accel.lowering import Lowerer

#: The functions a lowered source calls as they are (C's math intrinsics in translation),
#: each with the name it has there.
INTRINSICS: dict[Any, str] = {
    getattr(math, n): f"_{n}" for n in ("sqrt", "sin", "cos", "tan", "atan", "acos", "tanh",
                                        "log", "exp", "pow", "atan2", "copysign", "hypot",
                                        "isfinite", "isnan", "asin", "remainder")}
INTRINSICS[abs] = "abs"
_RESERVED = re.compile(r"_[itv]\d.*|.*__.*")     # the names lowering itself makes


@dataclass
class Tup:
    """A tuple known at lowering: its items (scalar expressions or Tups), NamedTuple
    fields if any."""

    items: list[Any]
    fields: tuple[str, ...] | None = None
    cls: type | None = None         # the NamedTuple class (returned as an instance of it)


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
    return Tup([_shape(x) for x in v.items], v.fields, v.cls) if isinstance(v, Tup) else None


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
        return ast.Constant(obj)                # a boolean stays one (returned as bool)
    if isinstance(obj, int) and type(obj) is not int:
        return ast.Constant(int(obj))           # an IntEnum member: its value
    if isinstance(obj, (int, float)):
        f = float(obj)
        if f != f:
            return ast.Name("_nan", ast.Load())
        if f in (math.inf, -math.inf):
            inf = ast.Name("_inf", ast.Load())
            return inf if f > 0 else ast.UnaryOp(ast.USub(), inf)
        return ast.Constant(obj)
    if isinstance(obj, (tuple, list)):
        return Tup([_value(x, what) for x in obj], getattr(obj, "_fields", None),
                   named_class(obj))
    if isinstance(obj, (types.FunctionType, types.ModuleType, type, types.BuiltinFunctionType)):
        return _Ref(obj)
    raise NativeError(f"{what} is a {type(obj).__name__}, not a number, tuple or function")


def named_class(x: Any) -> type | None:
    """The NamedTuple class of ``x`` (an instance or the class), if it is one a compiled
    function can return: a tuple subclass with fields, reachable by module and name."""
    cls = x if isinstance(x, type) else type(x)
    if not (issubclass(cls, tuple) and hasattr(cls, "_fields")):
        return None
    obj: Any = sys.modules.get(cls.__module__)
    for part in cls.__qualname__.split("."):
        obj = getattr(obj, part, None)
    return cls if obj is cls else None


def kind_of(annotation: Any) -> str:
    """A leaf's kind from its annotation: ``i`` (int), ``b`` (bool) or ``f`` (float)."""
    name = annotation if isinstance(annotation, str) else getattr(
        annotation, "__forward_arg__", getattr(annotation, "__name__", ""))
    return {"int": "i", "bool": "b"}.get(name, "f")


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
    node.body = _single_exit(fn, body)
    if not _ends(node.body):
        raise NativeError(f"{fn.__qualname__} must return a value on every path")
    return node


def _returns(st: ast.stmt) -> bool:
    """``st`` holds a ``return`` of a value (``return None`` is the seam's decline)."""
    return any(isinstance(n, ast.Return) and not _is_none(n.value) for n in ast.walk(st))


def _is_none(e: ast.expr | None) -> bool:
    return e is None or (isinstance(e, ast.Constant) and e.value is None)


class Rest(ast.stmt):
    """The statements after an ``if`` that returns on some of its paths: they run on the
    paths that did not return (the lowering guards them with a flag the returns set)."""

    _fields = ("body",)

    def __init__(self, body: list[ast.stmt]) -> None:
        super().__init__()
        self.body = body


def _single_exit(fn: types.FunctionType, body: list[ast.stmt]) -> list[ast.stmt]:
    """``body`` with what follows each ``if`` that returns on a path made one :class:`Rest`
    (nothing, if every path of the ``if`` returns): the same statements in the same order on
    every path, each written once."""
    out: list[ast.stmt] = []
    for k, st in enumerate(body):
        if isinstance(st, ast.Return):
            out.append(st)
            return out                          # what follows never runs
        if isinstance(st, ast.If) and _returns(st):
            branch = ast.If(st.test, _single_exit(fn, st.body), _single_exit(fn, st.orelse))
            out.append(branch)
            rest = body[k + 1:]
            if rest and not (_ends(branch.body) and _ends(branch.orelse)):
                out.append(Rest(_single_exit(fn, rest)))
            return out
        if _returns(st):
            raise NativeError(f"{fn.__qualname__}: a return inside a loop: "
                              f"{ast.unparse(st).splitlines()[0]!r}")
        out.append(st)
    return out


def _ends(body: list[ast.stmt]) -> bool:
    """Every path through ``body`` ends with a ``return`` (of a value, or the decline)."""
    if not body:
        return False
    last = body[-1]
    if isinstance(last, ast.Return):
        return True
    if isinstance(last, Rest):                  # the paths that get there end in it
        return _ends(last.body)
    return isinstance(last, ast.If) and _ends(last.body) and _ends(last.orelse)


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


class Frame:
    """One function being lowered: the top-level one, or one inlined instance of a callee."""

    def __init__(self, low: Lowerer, fn: types.FunctionType, node: ast.FunctionDef,
                 prefix: str) -> None:
        self.low, self.fn, self.prefix = low, fn, prefix
        self.globals = fn.__globals__
        self.shapes: dict[str, Any] = {}        # local → None (a float) or its Tup shape
        self.alias: dict[str, Any] = {}         # unrolled index → its constant
        self.version: dict[str, int] = {}       # a name rebound with another shape: new floats
        self.depth = low.depth                  # the branches and loops it is called in
        self.made: dict[tuple[str, int, int], tuple[Any, Any]] = {}     # local()'s, kept
        self.result: Any = None     # the returned value, or the locals every return sets
        self.result_named = False   # … it is locals (a return in a branch set them)
        self.returned: ast.Name | None = None   # 1 once a return in a branch ran
        self.done = False           # the return at the function's own level was lowered
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
            return Tup([walk(x, (*path, k)) for k, x in enumerate(s.items)], s.fields, s.cls)
        return walk(shape, ())

    def name(self, name: str) -> Any:
        if name in self.alias:
            return self.alias[name]
        if name in self.assigned:
            if name not in self.shapes:
                raise NativeError(f"{self.fn.__qualname__}: {name!r} is read before it is set")
            return self.local(name, self.shapes[name])
        if name in self.globals:
            value = _value(self.globals[name], f"global {name!r}")
            if not isinstance(value, _Ref):
                self.low.read(self.globals.get("__name__"), name, self.globals[name])
            return value
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


def _retemp(low: Lowerer, v: Any, names: bool = False) -> Any:
    """``v`` with each float computed into a local now (``names``: a name copied too)."""
    return Tup([_retemp(low, x, names) for x in v.items], v.fields, v.cls) \
        if isinstance(v, Tup) else low.temp(v, names)

def _is_range(f: Frame, it: ast.expr) -> bool:
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
                   a.fields, a.cls if isinstance(b, Tup) and b.cls is a.cls else None)
    return fn(a, b)

