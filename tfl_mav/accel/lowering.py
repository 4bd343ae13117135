"""The seam front end's rewriting: expressions and statements of a pure Python function
lowered to straight-line float code (the package docstring says what and why)."""

from __future__ import annotations

import ast
import types
from typing import Any

from tfl_mav.accel.ctranslate import NativeError
from tfl_mav.accel.lowering_values import (
    _INT_OPS,
    INTRINSICS,
    Frame,
    Rest,
    Tup,
    _int,
    _is_none,
    _is_range,
    _Lazy,
    _leaves,
    _own,
    _Ref,
    _retemp,
    _returns,
    _same_shape,
    _shape,
    _simple,
    _source,
    _tuple_op,
    _value,
    _zip_tup,
    named_class,
)

_TUPLE_NEW = tuple.__new__


class _Method:
    """``t._replace`` of a NamedTuple known at lowering (called next)."""

    def __init__(self, tup: Tup) -> None:
        self.tup = tup


def _is_int(e: Any) -> bool:
    return (isinstance(e, ast.Constant) and type(e.value) is int) or (
        isinstance(e, ast.UnaryOp) and isinstance(e.op, ast.USub) and _is_int(e.operand))


def _calls(f: Frame, e: ast.expr) -> bool:
    """``e`` calls a pure Python function (inlined: it cannot sit in an expression that
    runs on some paths only)."""
    for n in ast.walk(e):
        if isinstance(n, ast.Call):
            try:
                fn = f.low.expr(f, n.func, True) if not isinstance(n.func, ast.Name) \
                    or n.func.id not in f.assigned else None
            except NativeError:
                continue
            if isinstance(fn, _Ref) and isinstance(fn.obj, types.FunctionType):
                return True
    return False


class Lowerer:
    """One lowering: the statements made so far, the temporaries' counter, the functions
    being inlined."""

    def __init__(self) -> None:
        self.out: list[ast.stmt] = []
        self.n = 0
        self.stack: list[types.FunctionType] = []
        self.depth = 0                          # nesting in kept branches and loops
        self.files: set[str] = set()            # the source files of the functions read
        # the module constants read, as (module, name) → repr: folded into the lowering
        self.constants: dict[tuple[str, str], str] = {}

    def read(self, module: str | None, name: str, value: Any) -> None:
        if module is not None:
            self.constants[(module, name)] = repr(value)

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

    def block(self, f: Frame, body: list[ast.stmt]) -> list[ast.stmt]:
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
        self.n += 1
        f = Frame(self, fn, node, f"_i{self.n}_")
        for p in params:
            if p in bound:
                value = bound[p]
            elif p in defaults:
                value = _value(defaults[p], f"default of {p!r}")
            else:
                raise NativeError(f"{fn.__qualname__}: no argument for {p!r}")
            if isinstance(value, _Ref) or (isinstance(value, Tup) and all(
                    isinstance(x, _Ref) for x in value.items)):
                f.alias[p] = value          # a function passed in, or a tuple of them
                                            # (``sqrt=math.sqrt``, a path's kernels)
            else:
                f.bind(p, value)
        self.stack.append(fn)
        self.files.add(fn.__code__.co_filename)
        for st in node.body:
            self.stmt(f, st)
        self.stack.pop()
        result = f.result
        if f.result_named:
            return result
        return _retemp(self, result) if isinstance(result, Tup) else self.temp(result)

    def ret(self, f: Frame, e: ast.expr) -> None:
        """``return e``: the function's value. A return on one path of a branch (the
        others return too: :func:`~tfl_mav.accel.lowering_values._single_exit`) sets the result's
        locals, which every other return then sets."""
        value = self.value(f, e, False)
        if f.result is None and self.depth == f.depth:
            f.result = value                    # the one return, at the end
            f.done = True
            return
        if f.result is None:
            f.result = _zip_tup(lambda a, b: self.fresh(), value, value) \
                if isinstance(value, Tup) else self.fresh()
            f.result_named = True
        elif not f.result_named or not _same_shape(_shape(f.result), _shape(value)):
            raise NativeError(f"{f.fn.__qualname__}: its returns differ in shape: "
                              f"{ast.unparse(e)!r}")
        targets = _leaves(f.result)
        values = _leaves(value)
        self.out.extend(ast.Assign([ast.Name(t.id, ast.Store())], v)
                        for t, v in zip(targets, values, strict=True))
        if f.returned is not None:
            self.out.append(ast.Assign([ast.Name(f.returned.id, ast.Store())],
                                       ast.Constant(1)))


    # ----- expressions --------------------------------------------------------------------
    def num(self, f: Frame, e: ast.expr, cond: bool) -> Any:
        v = self.expr(f, e, cond)
        if isinstance(v, (Tup, _Ref)):
            raise NativeError(f"{ast.unparse(e)!r} is not a number here")
        return v

    def hoist(self, e: Any, cond: bool) -> Any:
        """``e`` computed once, ahead, into a local — unless only some paths compute it
        (``cond``): then written where it is used (the same operation, maybe twice)."""
        return e if cond else self.temp(e)

    def expr(self, f: Frame, e: ast.expr, cond: bool) -> Any:
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
            if isinstance(v, Tup) and v.fields and e.attr == "_replace":
                return _Ref(_Method(v))
            if isinstance(v, _Ref) and isinstance(v.obj, types.ModuleType) \
                    and hasattr(v.obj, e.attr):
                value = _value(getattr(v.obj, e.attr), _Lazy(e))
                if not isinstance(value, _Ref):
                    self.read(v.obj.__name__, e.attr, getattr(v.obj, e.attr))
                return value
            if isinstance(v, _Ref) and isinstance(v.obj, type) and hasattr(v.obj, e.attr) \
                    and isinstance(getattr(v.obj, e.attr), (int, float)):
                member = getattr(v.obj, e.attr)      # Why.FLOOR: an IntEnum's code
                self.read(v.obj.__module__, f"{v.obj.__qualname__}.{e.attr}", member)
                return _value(member, _Lazy(e))
            raise NativeError(f"cannot lower {ast.unparse(e)!r}")
        if isinstance(e, ast.Subscript):
            v = self.expr(f, e.value, cond)
            if not isinstance(v, Tup):
                raise NativeError(f"{ast.unparse(e.value)!r} is not a tuple")
            if isinstance(e.slice, ast.Slice):
                lo, hi, step = (None if x is None else _int(self.expr(f, x, cond), "a slice")
                                for x in (e.slice.lower, e.slice.upper, e.slice.step))
                return Tup(v.items[lo:hi:step])
            index = self.num(f, e.slice, cond)
            if not _is_int(index):
                return self.index(v, index, e, cond)
            k = _int(index, _Lazy(e))
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
            if all(isinstance(x, ast.Constant) and type(x.value) is int for x in (a, b)) \
                    and type(e.op) in _INT_OPS:     # an unrolled loop's index: i % 2
                return ast.Constant(_int(ast.BinOp(a, e.op, b), _Lazy(e)))
            return ast.BinOp(a, e.op, b)
        if isinstance(e, ast.UnaryOp):
            return ast.UnaryOp(e.op, self.num(f, e.operand, cond))
        if isinstance(e, ast.Compare):
            if len(e.ops) == 1 and isinstance(e.ops[0], (ast.Is, ast.IsNot)) \
                    and isinstance(e.comparators[0], ast.Constant) \
                    and e.comparators[0].value is None:
                # ``t is None`` of a tuple or a function: decided at lowering (a value that
                # may be None is not lowered at all).
                if not isinstance(self.expr(f, e.left, cond), (Tup, _Ref)):
                    raise NativeError(f"cannot lower {ast.unparse(e)!r}: a number is never None")
                return ast.Constant(int(isinstance(e.ops[0], ast.IsNot)))
            if any(isinstance(op, (ast.Is, ast.IsNot, ast.In, ast.NotIn)) for op in e.ops):
                raise NativeError(f"cannot lower {ast.unparse(e)!r}")
            left = self.num(f, e.left, cond)
            rights = [self.num(f, c, cond or k > 0) for k, c in enumerate(e.comparators)]
            if all(isinstance(x, ast.Constant) and type(x.value) is int
                   for x in (left, *rights)):          # indices of an unrolled loop
                return ast.Constant(int(eval(compile(ast.fix_missing_locations(
                    ast.Expression(ast.Compare(left, e.ops, rights))), "<index>", "eval"))))
            return ast.Compare(left, e.ops, rights)
        if isinstance(e, ast.BoolOp):
            if not cond and any(_calls(f, v) for v in e.values[1:]):
                return self.bool_op(f, e)
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

    def if_expr(self, f: Frame, test: Any, e: ast.IfExp) -> Any:
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

    def index(self, v: Tup, index: Any, e: ast.Subscript, cond: bool) -> Any:
        """``t[k]`` with ``k`` known only when it runs: each element of the result picks
        its item by ``k`` (``_index``: an int in range, as Python's indexing demands,
        else the compiled function declines). The items are computed first, as the tuple
        held them."""
        items = v.items
        if not items:
            raise NativeError(f"{ast.unparse(e)!r}: an index into an empty tuple")
        shape = _shape(items[0])
        if not all(_same_shape(shape, _shape(x)) for x in items):
            raise NativeError(f"{ast.unparse(e)!r}: a variable index into items of "
                              "different shapes")
        if cond:
            if not all(_simple(x) for it in items for x in _leaves(it)):
                raise NativeError(f"{ast.unparse(e)!r}: a variable index into computed "
                                  "items on some paths only")
        else:
            index = self.temp(index)
            items = [_retemp(self, x) if isinstance(x, Tup) else self.temp(x) for x in items]
        leaves = [_leaves(x) for x in items]
        picked = [ast.Call(ast.Name("_index", ast.Load()),
                           [index, *(lv[j] for lv in leaves)], [])
                  for j in range(len(leaves[0]))]
        if shape is None:
            return picked[0]
        it = iter(picked)
        cls = items[0].cls if all(x.cls is items[0].cls for x in items) else None
        return _zip_tup(lambda a, b: next(it), Tup(shape.items, shape.fields, cls),
                        Tup(shape.items, shape.fields, cls))

    def bool_op(self, f: Frame, e: ast.BoolOp) -> Any:
        """``a and f(x)`` (``or``) where a later operand calls a function: the value of
        the first operand that decides, each later one computed only when the ones before
        did not — Python's short circuit, as ``if`` statements."""
        result = self.fresh()
        self.out.append(ast.Assign([ast.Name(result.id, ast.Store())],
                                   self.num(f, e.values[0], False)))
        for v in e.values[1:]:
            test: ast.expr = ast.Name(result.id, ast.Load())
            if isinstance(e.op, ast.Or):
                test = ast.UnaryOp(ast.Not(), test)
            saved, self.out = self.out, []
            self.depth += 1
            x = self.num(f, v, False)
            self.out.append(ast.Assign([ast.Name(result.id, ast.Store())], x))
            self.depth -= 1
            block, self.out = self.out, saved
            self.out.append(ast.If(test, block, []))
        return result

    def value(self, f: Frame, e: ast.expr, cond: bool) -> Any:
        v = self.expr(f, e, cond)
        if isinstance(v, _Ref):
            raise NativeError(f"{ast.unparse(e)!r} is {v.obj!r}, not a number or tuple")
        return v

    def argument(self, f: Frame, e: ast.expr, cond: bool) -> Any:
        """An argument of an inlined call: a value, or a function or math function passed
        in (what the callee then calls)."""
        v = self.expr(f, e, cond)
        if isinstance(v, _Ref) and not (isinstance(v.obj, types.FunctionType)
                                        or v.obj in INTRINSICS):
            raise NativeError(f"{ast.unparse(e)!r} is {v.obj!r}, not a number or tuple")
        return v

    def tup(self, f: Frame, e: ast.expr, cond: bool) -> Tup:
        v = self.expr(f, e, cond)
        if not isinstance(v, Tup):
            raise NativeError(f"{ast.unparse(e)!r} is not a tuple")
        return v

    def call(self, f: Frame, e: ast.Call, cond: bool) -> Any:
        fv = self.expr(f, e.func, cond)
        what = _Lazy(e)
        if not isinstance(fv, _Ref):
            raise NativeError(f"{ast.unparse(e.func)!r} is not a function: {what!r}")
        obj = fv.obj
        if isinstance(obj, _Method):
            return self.replace(f, obj.tup, e, cond)
        if any(isinstance(a, ast.Starred) for a in e.args):      # f(*t): t's items
            e = ast.Call(e.func, [y for a in e.args for y in (
                [ast.Subscript(a.value, ast.Constant(k), ast.Load())
                 for k in range(len(self.tup(f, a.value, cond).items))]
                if isinstance(a, ast.Starred) else [a])], e.keywords)
        if isinstance(obj, types.FunctionType):
            if cond:
                raise NativeError(f"{what!r} is called on some paths only (a conditional "
                                  "expression, and/or): write it as an if statement")
            args = [self.argument(f, a, cond) for a in e.args]
            kwargs = {k.arg: self.argument(f, k.value, cond) for k in e.keywords
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
                        for n in obj._fields], obj._fields, named_class(obj))
        if obj is _TUPLE_NEW and len(e.args) == 2 and not e.keywords:
            # tuple.__new__(C, items): the NamedTuple C made without its Python __new__
            cls = self.expr(f, e.args[0], cond)
            items = self.tup(f, e.args[1], cond)
            if not (isinstance(cls, _Ref) and isinstance(cls.obj, type)
                    and hasattr(cls.obj, "_fields")
                    and len(cls.obj._fields) == len(items.items)):
                raise NativeError(f"{what!r}: not a NamedTuple class and its fields")
            return Tup(list(items.items), cls.obj._fields, named_class(cls.obj))
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
        if obj is int and len(e.args) == 1:      # int(x): toward zero; x itself if an int
            x = self.num(f, e.args[0], cond)
            return x if _is_int(x) else ast.Call(ast.Name("_int", ast.Load()), [x], [])
        if obj is bool and len(e.args) == 1:     # bool(x): x != 0 (a NaN is true)
            x = self.num(f, e.args[0], cond)
            if isinstance(x, ast.Constant):
                return ast.Constant(bool(x.value))
            return ast.Compare(x, [ast.NotEq()], [ast.Constant(0)])
        if obj is len and len(e.args) == 1:
            return ast.Constant(len(self.tup(f, e.args[0], cond).items))
        if obj in (tuple, list) and len(e.args) == 1:
            return Tup(list(self.tup(f, e.args[0], cond).items))
        try:
            name = INTRINSICS.get(obj)
        except TypeError:
            name = None
        if name is not None:
            return ast.Call(ast.Name(name, ast.Load()),
                            [self.num(f, a, cond) for a in e.args], [])
        raise NativeError(f"{what!r}: {obj!r} is neither a pure Python function nor a math "
                          "function the translator knows")

    def replace(self, f: Frame, v: Tup, e: ast.Call, cond: bool) -> Tup:
        """``t._replace(field=value, …)`` of a NamedTuple: a new one, those fields changed."""
        assert v.fields is not None
        if e.args or any(k.arg not in v.fields for k in e.keywords):
            raise NativeError(f"{ast.unparse(e)!r}: _replace takes the tuple's fields")
        items = list(v.items)
        for k in e.keywords:
            assert k.arg is not None
            items[v.fields.index(k.arg)] = self.value(f, k.value, cond)
        return Tup(items, v.fields, v.cls)

    def iteration(self, f: Frame, it: ast.expr, cond: bool) -> list[Any]:
        """The values a ``for`` takes: ``range`` of constants, or a tuple's items."""
        if _is_range(f, it):
            bounds = [_int(self.expr(f, a, cond), "a range bound") for a in it.args]
            return [ast.Constant(k) for k in range(*bounds)]
        return list(self.tup(f, it, cond).items)

    def comprehension(self, f: Frame, e: ast.GeneratorExp | ast.ListComp, cond: bool) -> Tup:
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
    def stmt(self, f: Frame, st: ast.stmt) -> None:
        if f.done:                  # after the function's own return: never runs
            return
        if isinstance(st, ast.If) and f.returned is None and _returns(st):
            # the flag the returns in it set, read by the Rest after it
            f.returned = self.fresh()
            self.out.append(ast.Assign([ast.Name(f.returned.id, ast.Store())],
                                       ast.Constant(0)))
        if isinstance(st, Rest):
            assert f.returned is not None
            self.out.append(ast.If(ast.UnaryOp(ast.Not(), ast.Name(f.returned.id, ast.Load())),
                                   self.block(f, st.body), []))
            return
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
            if not _is_none(st.value):
                self.ret(f, st.value)       # type: ignore[arg-type]
            elif f.prefix:
                raise NativeError(f"{f.fn.__qualname__}: an inlined function returns None: "
                                  f"{ast.unparse(st)!r}")
            else:                           # the decline: the caller's Python decides
                self.out.append(ast.Return(ast.Constant(None)))
        elif isinstance(st, ast.Break):
            self.out.append(ast.Break())
        elif isinstance(st, ast.Pass) or (isinstance(st, ast.Expr) \
                and isinstance(st.value, ast.Constant) and isinstance(st.value.value, str)):
            pass
        else:
            raise NativeError(f"cannot lower the statement {ast.unparse(st)!r}")

    def loop(self, f: Frame, st: ast.For) -> None:
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

