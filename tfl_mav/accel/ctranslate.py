"""Python float functions translated to C, operation for operation.

:func:`translate` turns one Python function of the restricted form the law's generated
code takes — numbers and sequences of numbers in, straight-line float arithmetic with
``if``, ``for _ in range(n)``, conditional expressions and the math functions of
:mod:`jetcode`, nested tuples of numbers out — into the C source of a one-function CPython
extension. Every operation keeps its operands and its order, and every operation for which
CPython raises (division by zero, ``sqrt`` of a negative, an overflowing ``**`` or ``exp``,
``sin`` of ±∞, ``log`` of a non-positive) makes the C function return ``None`` instead: the
caller's Python then decides. :mod:`native` builds and caches the result; why it is the
same bits is said there.
"""

from __future__ import annotations

import ast

from tfl_mav.accel.cruntime import PRELUDE

__all__ = ["NativeError", "translate"]


class NativeError(RuntimeError):
    """The Python source cannot be translated, or the build failed."""


_BINOPS = {ast.Add: "+", ast.Sub: "-", ast.Mult: "*"}
_CMPOPS = {ast.Lt: "<", ast.LtE: "<=", ast.Gt: ">", ast.GtE: ">=", ast.Eq: "==",
           ast.NotEq: "!="}
# name → (C call, the condition on the argument under which CPython's math raises).
_UNARY = {
    "_sqrt": ("__builtin_sqrt({0})", "{0} < 0.0"),
    "_sin": ("sin({0})", "__builtin_isinf({0})"),
    "_cos": ("cos({0})", "__builtin_isinf({0})"),
    "_tan": ("tan({0})", "__builtin_isinf({0})"),
    "_atan": ("atan({0})", "0"),
    "_acos": ("acos({0})", "{0} < -1.0 || {0} > 1.0"),
    "_asin": ("asin({0})", "{0} < -1.0 || {0} > 1.0"),
    "_tanh": ("tanh({0})", "0"),
    "_log": ("log({0})", "{0} <= 0.0"),
    "abs": ("__builtin_fabs({0})", "0"),
    "_abs": ("__builtin_fabs({0})", "0"),
}


class _C:
    """One function's translation: expressions to C text, checks to ``goto bail``."""

    def __init__(self, objects: set[str], kinds: dict[str, str] | None = None) -> None:
        self.names: set[str] = set()
        self.objects = objects      # parameters kept as Python objects (sequences, None)
        self.tmp = 0
        self.kinds: dict[str, str] = kinds or {}    # a name's kind where it is not float
        self.memos: list[str] = []      # the module's static memo declarations (``memo``)

    def kind(self, e: ast.expr) -> str | None:
        """What Python's value of ``e`` is: ``f`` float, ``i`` int, ``b`` bool (None: not
        known yet, while :func:`_infer` iterates). C holds each as a double."""
        if isinstance(e, ast.Constant):
            return {bool: "b", int: "i"}.get(type(e.value), "f")
        if isinstance(e, ast.Name):
            return "f" if e.id in ("_inf", "_nan") else self.kinds.get(e.id)
        if isinstance(e, ast.UnaryOp):
            if isinstance(e.op, ast.Not):
                return "b"
            k = self.kind(e.operand)
            return "i" if k in ("i", "b") else k
        if isinstance(e, ast.BinOp):
            a, b = self.kind(e.left), self.kind(e.right)
            if a is None or b is None:
                return None
            if isinstance(e.op, ast.Pow):
                n = e.right
                return "i" if a in ("i", "b") and isinstance(n, ast.Constant) \
                    and type(n.value) is int and n.value >= 0 else "f"
            if isinstance(e.op, (ast.Add, ast.Sub, ast.Mult, ast.Mod)):
                return "i" if a in ("i", "b") and b in ("i", "b") else "f"
            return "f"
        if isinstance(e, ast.Compare):
            return "b"
        if isinstance(e, ast.BoolOp):
            return _join(*(self.kind(v) for v in e.values))
        if isinstance(e, ast.IfExp):
            return _join(self.kind(e.body), self.kind(e.orelse))
        if isinstance(e, ast.Call) and isinstance(e.func, ast.Name):
            fn = e.func.id
            if fn == "_index":
                return _join(*(self.kind(a) for a in e.args[1:]))
            if fn == "_int":
                return "i"
            if fn in ("_isfinite", "_isnan"):
                return "b"
            if fn in ("abs", "_abs") and e.args:
                k = self.kind(e.args[0])
                return "i" if k in ("i", "b") else k
        return "f"

    def fresh(self) -> str:
        self.tmp += 1
        return f"_v{self.tmp}"

    def expr(self, e: ast.expr) -> str:
        if isinstance(e, ast.Name):
            if e.id == "_inf":
                return "INFINITY"
            if e.id == "_nan":
                return "Py_NAN"
            if e.id in self.objects:
                raise NativeError(f"{e.id!r} is a sequence or None, not a number")
            if e.id not in self.names:
                raise NativeError(f"name {e.id!r} is read before it is set")
            return e.id
        if isinstance(e, ast.Constant):
            v = e.value
            if type(v) is bool:
                return "(1.0)" if v else "(0.0)"
            if not isinstance(v, (int, float)):
                raise NativeError(f"constant {v!r} is not a number")
            f = float(v)
            if f != f or f in (float("inf"), float("-inf")):
                raise NativeError(f"constant {v!r} is not finite")
            return f"({float.hex(f)})"      # exact, whatever the C library's strtod
        if isinstance(e, ast.UnaryOp):
            x = self.expr(e.operand)
            if isinstance(e.op, ast.USub):
                # an int has no −0: the int's negation of 0 is +0 (x + 0.0 makes it so)
                return f"((-{x}) + 0.0)" if self.kind(e) == "i" else f"(-{x})"
            if isinstance(e.op, ast.UAdd):
                return x
            if isinstance(e.op, ast.Not):
                return f"(!{x})"
        if isinstance(e, ast.BinOp):
            a, b = self.expr(e.left), self.expr(e.right)
            op = _BINOPS.get(type(e.op))
            if op is not None:
                if self.kind(e) == "i" and not isinstance(e.op, ast.Add):
                    return f"(({a} {op} {b}) + 0.0)"      # no −0 among ints
                return f"({a} {op} {b})"
            if isinstance(e.op, ast.Mod):     # CPython's float_rem: the divisor's sign
                x, y, m = self.fresh(), self.fresh(), self.fresh()
                zero = " + 0.0" if self.kind(e) == "i" else ""
                return (f"({{ double {x} = {a}; double {y} = {b}; if ({y} == 0.0) goto bail;"
                        f" double {m} = fmod({x}, {y}); if ({m}) {{ if (({y} < 0) != ({m} < 0))"
                        f" {m} += {y}; }} else {m} = copysign(0.0, {y}); {m}{zero}; }})")
            if isinstance(e.op, ast.Div):     # ZeroDivisionError in Python
                d = self.fresh()
                return f"({{ double {d} = {b}; if ({d} == 0.0) goto bail; ({a}) / {d}; }})"
            if isinstance(e.op, ast.Pow):
                n, sign = e.right, 1
                if isinstance(n, ast.UnaryOp) and isinstance(n.op, ast.USub):
                    n, sign = n.operand, -1
                if not (isinstance(n, ast.Constant) and type(n.value) is int):
                    raise NativeError("only x ** <int literal> is translated")
                return self._ipow(a, sign * n.value)
        if isinstance(e, ast.Compare) and len(e.ops) == 1 \
                and isinstance(e.ops[0], (ast.Is, ast.IsNot)):
            obj, none = e.left, e.comparators[0]
            if not (isinstance(obj, ast.Name) and obj.id in self.objects
                    and isinstance(none, ast.Constant) and none.value is None):
                raise NativeError(f"cannot translate {ast.unparse(e)!r}")
            return f"({obj.id} {'==' if isinstance(e.ops[0], ast.Is) else '!='} Py_None)"
        if isinstance(e, ast.Compare):
            parts, left = [], self.expr(e.left)
            for op, right in zip(e.ops, e.comparators, strict=True):
                c = _CMPOPS.get(type(op))
                if c is None:
                    raise NativeError(f"comparison {type(op).__name__}")
                r = self.expr(right)
                parts.append(f"({left} {c} {r})")
                left = r
            return "(" + " && ".join(parts) + ")"
        if isinstance(e, ast.BoolOp):
            # Python's value: the first operand that decides (not C's 0 or 1)
            text = self.expr(e.values[-1])
            for v in reversed(e.values[:-1]):
                t = self.fresh()
                x = self.expr(v)
                text = (f"({{ double {t} = {x}; {t} ? {text} : {t}; }})"
                        if isinstance(e.op, ast.And) else
                        f"({{ double {t} = {x}; {t} ? {t} : {text}; }})")
            return text
        if isinstance(e, ast.IfExp):
            return f"({self.expr(e.test)} ? {self.expr(e.body)} : {self.expr(e.orelse)})"
        if isinstance(e, ast.Call) and isinstance(e.func, ast.Name) and not e.keywords \
                and e.func.id == "_index":
            return self._index(e)
        if isinstance(e, ast.Call) and isinstance(e.func, ast.Name) and not e.keywords:
            return self._call(e.func.id, [self.expr(a) for a in e.args])
        if isinstance(e, ast.Call) and isinstance(e.func, ast.Attribute) and not e.keywords \
                and isinstance(e.func.value, ast.Name) and e.func.value.id == "math":
            return self._call(f"_{e.func.attr}", [self.expr(a) for a in e.args])
        raise NativeError(f"cannot translate {ast.unparse(e)!r}")

    def _index(self, e: ast.Call) -> str:
        """``_index(k, a₀, …, aₙ₋₁)``: ``(a₀, …)[k]`` — an int ``k`` in [−n, n), as Python
        indexes; any other declines (Python raises IndexError there)."""
        if len(e.args) < 2:
            raise NativeError("_index needs an index and items")
        if self.kind(e.args[0]) not in ("i", "b"):
            raise NativeError(f"a variable index must be an int: {ast.unparse(e.args[0])!r}")
        k, j = self.fresh(), self.fresh()
        items = [self.expr(a) for a in e.args[1:]]
        n = len(items)
        pick = items[-1]
        for m in range(n - 2, -1, -1):
            pick = f"({j} == {m} ? {items[m]} : {pick})"
        return (f"({{ double {k} = {self.expr(e.args[0])}; if (!(__builtin_fabs({k}) <= {n}.0))"
                f" goto bail; long {j} = (long){k}; if ((double){j} != {k}) goto bail;"
                f" if ({j} < 0) {j} += {n};"
                f" if ({j} < 0 || {j} >= {n}) goto bail; {pick}; }})")

    def _ipow(self, x: str, n: int) -> str:
        """CPython's float ** int (floatobject.c float_pow): a NaN returned as it is, x = ±0
        handled apart, else pow(|x|, n), negated for an odd n and x < 0; OverflowError (inf
        from finite) and 0 ** −n raise."""
        v, r = self.fresh(), self.fresh()
        odd = n % 2 == 1
        nd = f"{float(n)!r}"
        if n < 0:
            zero = f"({v} == 0.0 ? ({{ goto bail; 0.0; }}) : "
        else:
            zero = f"({v} == 0.0 ? {v if odd else '0.0'} : "
        neg = f"({v} < 0.0 ? -{r} : {r})" if odd else r
        return (f"({{ double {v} = {x}; double {r}; {r} = __builtin_isnan({v}) ? {v} : "
                f"{zero}pow(__builtin_fabs({v}), {nd}));"
                f" if (__builtin_isinf({r}) && __builtin_isfinite({v})) goto bail;"
                f" {neg}; }})")

    def _call(self, fn: str, args: list[str]) -> str:
        if fn == "_atan2" and len(args) == 2:
            return f"tfl_atan2({args[0]}, {args[1]})"
        if fn == "_copysign" and len(args) == 2:
            return f"copysign({args[0]}, {args[1]})"
        if fn == "_hypot" and len(args) == 2:       # CPython's own (not libm's): called
            r = self.fresh()
            return (f"({{ double {r}; if (tfl_hypot({args[0]}, {args[1]}, &{r})) goto bail;"
                    f" {r}; }})")
        if fn == "_int" and len(args) == 1:      # int(x): toward zero; NaN, ±inf raise
            v = self.fresh()
            return (f"({{ double {v} = {args[0]}; if (!(__builtin_fabs({v}) < 9007199254740992.0))"
                    f" goto bail; (double)(long long){v}; }})")
        if fn == "_isfinite" and len(args) == 1:
            return f"__builtin_isfinite({args[0]})"
        if fn == "_isnan" and len(args) == 1:
            return f"__builtin_isnan({args[0]})"
        if fn in _UNARY and len(args) == 1:
            call, raises = _UNARY[fn]
            v = self.fresh()
            check = raises.format(v)
            guard = "" if check == "0" else f" if ({check}) goto bail;"
            return f"({{ double {v} = {args[0]};{guard} {call.format(v)}; }})"
        if fn == "_exp" and len(args) == 1:     # OverflowError: inf from a finite x
            v, r = self.fresh(), self.fresh()
            return (f"({{ double {v} = {args[0]}; double {r} = exp({v});"
                    f" if (__builtin_isinf({r}) && __builtin_isfinite({v})) goto bail; {r}; }})")
        if fn == "_remainder" and len(args) == 2:
            # IEEE 754 remainder is exact, so libm's is CPython's; ValueError for x = ±inf
            # or y = 0 (NaN operands give NaN).
            x, y = self.fresh(), self.fresh()
            return (f"({{ double {x} = {args[0]}; double {y} = {args[1]};"
                    f" if ((__builtin_isinf({x}) && !__builtin_isnan({y}))"
                    f" || ({y} == 0.0 && !__builtin_isnan({x}))) goto bail;"
                    f" remainder({x}, {y}); }})")
        if fn == "_pow" and len(args) == 2:     # math.pow: the finite, non-raising cases only
            x, y, r = self.fresh(), self.fresh(), self.fresh()
            return (f"({{ double {x} = {args[0]}; double {y} = {args[1]};"
                    f" if (!__builtin_isfinite({x}) || !__builtin_isfinite({y})"
                    f" || ({x} == 0.0 && {y} < 0.0)) goto bail; double {r} = pow({x}, {y});"
                    f" if (!__builtin_isfinite({r})) goto bail; {r}; }})")
        raise NativeError(f"call of {fn!r} with {len(args)} arguments")

    def block(self, body: list[ast.stmt], ind: str, out: list[str]) -> None:
        for st in body:
            self.stmt(st, ind, out)

    def unpack(self, target: ast.Tuple, obj: str, ind: str, out: list[str],
               held: tuple[str, ...] = ()) -> None:
        """``a, (b, c) = obj``: the sequence's items as floats (nested tuples recursively);
        anything else (a wrong length, not a sequence, not numbers) → None. A flat target
        reads a tuple or list directly, a float64 array through its buffer (numpy's state
        vectors), anything else through PySequence_Fast."""
        n = len(target.elts)
        release = "".join(f"Py_DECREF({h}); " for h in held)
        if all(isinstance(e, ast.Name) and e.id not in self.objects for e in target.elts):
            names = [e.id for e in target.elts]   # type: ignore[attr-defined]
            self.names.update(names)
            v = self.fresh()
            out.append(f"{ind}double {v}[{n}];")
            out.append(f"{ind}if (tfl_unpack({obj}, {v}, {n})) {{ {release}goto bail; }}")
            out.extend(f"{ind}{name} = {v}[{k}];" for k, name in enumerate(names))
            return
        s = self.fresh()
        fail = "".join(f"Py_DECREF({h}); " for h in (s, *held))
        out.append(f"{ind}PyObject *{s} = tfl_fast({obj});")
        out.append(f"{ind}if ({s} == NULL) {{ PyErr_Clear(); {release}goto bail; }}")
        out.append(f"{ind}if (PySequence_Fast_GET_SIZE({s}) != {n}) {{ {fail}goto bail; }}")
        for k, elt in enumerate(target.elts):
            item = f"PySequence_Fast_GET_ITEM({s}, {k})"
            if isinstance(elt, ast.Tuple):
                self.unpack(elt, item, ind, out, (s, *held))
            elif isinstance(elt, ast.Name) and elt.id not in self.objects:
                self.names.add(elt.id)
                out.append(f"{ind}{elt.id} = tfl_double({item});")
            else:
                raise NativeError(f"cannot unpack into {ast.unparse(elt)!r}")
        out.append(f"{ind}Py_DECREF({s});")
        out.append(f"{ind}if (PyErr_Occurred()) {{ PyErr_Clear(); {release}goto bail; }}")

    def memo(self, target: ast.Tuple, obj: str, ind: str, out: list[str]) -> None:
        """``target = obj`` for a sequence argument (:meth:`unpack`), remembered: an
        argument passed again as the same object (a law's constants, every tick) whose
        numbers cannot have changed — tuples of floats and ints all the way down — has them
        read from the module's copy instead. The object is held (a strong reference), so
        the same address is the same object; ``ok``: 0 not yet checked (seen once), 1 its
        numbers kept, −1 it could change (a list, an array): read each time."""
        names = _leaf_names(target)
        k = len(self.memos)
        o, ok, v = f"tfl_memo{k}_obj", f"tfl_memo{k}_ok", f"tfl_memo{k}"
        self.memos.append(f"static PyObject *{o} = NULL;\nstatic int {ok} = 0;\n"
                          f"static double {v}[{len(names)}];")
        i2 = ind + "    "
        out.append(f"{ind}if ({obj} == {o} && {ok} == 1) {{")
        out.extend(f"{i2}{x} = {v}[{j}];" for j, x in enumerate(names))
        out.append(f"{ind}}} else {{")
        self.unpack(target, obj, i2, out)
        out.append(f"{i2}if ({obj} != {o}) {{")
        # The new object in first, the old one released last: releasing it may run code
        # that calls this function again, which then finds the memo whole.
        out.append(f"{i2}    PyObject *old = {o};")
        out.append(f"{i2}    Py_INCREF({obj});")
        out.append(f"{i2}    {o} = {obj};")
        out.append(f"{i2}    {ok} = 0;")
        out.append(f"{i2}    Py_XDECREF(old);")
        out.append(f"{i2}}} else if ({ok} == 0) {{")
        out.append(f"{i2}    {ok} = tfl_frozen({obj}) ? 1 : -1;")
        out.extend(f"{i2}    {v}[{j}] = {x};" for j, x in enumerate(names))
        out.append(f"{i2}}}")
        out.append(f"{ind}}}")

    def stmt(self, st: ast.stmt, ind: str, out: list[str]) -> None:
        if isinstance(st, ast.Assign) and len(st.targets) == 1 \
                and isinstance(st.targets[0], ast.Tuple):
            if not (isinstance(st.value, ast.Name) and st.value.id in self.objects):
                raise NativeError(f"only a sequence argument unpacks: {ast.unparse(st)!r}")
            self.memo(st.targets[0], st.value.id, ind, out)
        elif isinstance(st, ast.Assign) and len(st.targets) == 1 \
                and isinstance(st.targets[0], ast.Name):
            value = self.expr(st.value)
            self.names.add(st.targets[0].id)
            out.append(f"{ind}{st.targets[0].id} = {value};")
        elif isinstance(st, ast.AugAssign) and isinstance(st.target, ast.Name) \
                and type(st.op) in _BINOPS:
            out.append(f"{ind}{st.target.id} = ({self.expr(st.target)} "
                       f"{_BINOPS[type(st.op)]} {self.expr(st.value)});")
        elif isinstance(st, ast.If):
            out.append(f"{ind}if ({self.expr(st.test)}) {{")
            self.block(st.body, ind + "    ", out)
            if st.orelse:
                out.append(f"{ind}}} else {{")
                self.block(st.orelse, ind + "    ", out)
            out.append(f"{ind}}}")
        elif isinstance(st, ast.Return) and isinstance(st.value, ast.Constant) \
                and st.value.value is None:
            out.append(f"{ind}goto bail;")
        elif isinstance(st, ast.Break):
            out.append(f"{ind}break;")
        elif isinstance(st, ast.For) and isinstance(st.iter, ast.Call) \
                and isinstance(st.iter.func, ast.Name) and st.iter.func.id == "range" \
                and len(st.iter.args) == 1 and isinstance(st.iter.args[0], ast.Constant):
            n = int(st.iter.args[0].value)
            k = self.fresh()
            out.append(f"{ind}{{ int {k}; for ({k} = 0; {k} < {n}; {k}++) {{")
            self.block(st.body, ind + "    ", out)
            out.append(f"{ind}}}")
            if st.orelse:       # for … else: runs when no break left the loop
                out.append(f"{ind}if ({k} == {n}) {{")
                self.block(st.orelse, ind + "    ", out)
                out.append(f"{ind}}}")
            out.append(f"{ind}}}")
        elif isinstance(st, ast.Pass):
            pass
        else:
            raise NativeError(f"cannot translate statement {ast.unparse(st)!r}")


def _leaf_names(target: ast.expr) -> list[str]:
    """The names an unpacking target assigns, in order (nested tuples flattened)."""
    if isinstance(target, ast.Tuple):
        return [x for e in target.elts for x in _leaf_names(e)]
    return [target.id] if isinstance(target, ast.Name) else []


def _objects(fn: ast.FunctionDef) -> set[str]:
    """The parameters used as sequences (unpacked) or compared with None, and those bound
    at lowering (annotated ``"bound"``: a path's kernels, inlined; never read here)."""
    params = {a.arg for a in fn.args.args}
    objs = {a.arg for a in fn.args.args if isinstance(a.annotation, ast.Constant)
            and a.annotation.value == "bound"}
    for node in ast.walk(fn):
        if isinstance(node, ast.Assign) and isinstance(node.targets[0], ast.Tuple) \
                and isinstance(node.value, ast.Name):
            objs.add(node.value.id)
        elif isinstance(node, ast.Compare) and isinstance(node.left, ast.Name) \
                and any(isinstance(op, (ast.Is, ast.IsNot)) for op in node.ops):
            objs.add(node.left.id)
    return objs & params


def _join(*kinds: str | None) -> str | None:
    """The kind of a value that is one of these: theirs if they agree, else float."""
    if any(k is None for k in kinds):
        return None
    return kinds[0] if all(k == kinds[0] for k in kinds) else "f"


def _infer(fn: ast.FunctionDef, c: _C) -> None:
    """Each local's kind (``c.kinds``): the arguments' from their annotations (a literal
    of ``f``/``i``/``b`` leaves, the lowering's), every other name the join of what it is
    assigned, iterated until nothing changes (a loop assigns a name from itself)."""
    assigns: list[tuple[str, ast.expr]] = []
    notes = {a.arg: ast.literal_eval(a.annotation) for a in fn.args.args if a.annotation}

    def from_note(target: ast.expr, note: object) -> None:
        if isinstance(target, ast.Name):
            c.kinds[target.id] = note if isinstance(note, str) else "f"
        elif isinstance(target, ast.Tuple) and isinstance(note, tuple) \
                and len(note) == len(target.elts):
            for t, n in zip(target.elts, note, strict=True):
                from_note(t, n)

    for a, note in notes.items():
        if isinstance(note, str):
            c.kinds[a] = note
    for node in ast.walk(fn):
        if isinstance(node, ast.Assign) and len(node.targets) == 1:
            t = node.targets[0]
            if isinstance(t, ast.Name):
                assigns.append((t.id, node.value))
            elif isinstance(node.value, ast.Name) and node.value.id in notes:
                from_note(t, notes[node.value.id])
        elif isinstance(node, ast.AugAssign) and isinstance(node.target, ast.Name):
            assigns.append((node.target.id, ast.BinOp(ast.Name(node.target.id, ast.Load()),
                                                      node.op, node.value)))
    known = dict(c.kinds)           # the arguments' own, fixed
    changed = True
    while changed:
        changed = False
        for name, e in assigns:
            k = c.kind(e)
            if k is None or name in known:
                continue
            old = c.kinds.get(name)
            new = k if old is None else _join(old, k)
            if new != old:
                c.kinds[name] = new         # type: ignore[assignment]
                changed = True


def _results(e: ast.expr, c: _C, body: list[str]) -> ast.expr:
    """``e`` with every leaf that is not a plain name computed into a new local first (in
    ``body``, before any object is made: a leaf may still decline). An int or bool leaf
    must hold one (an argument annotated int given 2.5 declines here)."""
    if isinstance(e, (ast.Tuple, ast.List)):
        return type(e)([_results(x, c, body) for x in e.elts], ast.Load())
    if isinstance(e, ast.Name) and e.id not in c.objects:
        v = e.id
    else:
        v = c.fresh()
        body.append(f"    {v} = {c.expr(e)};")
        c.names.add(v)
        c.kinds[v] = c.kind(e) or "f"
    kind = c.kinds.get(v, "f")
    if kind == "i":
        body.append(f"    if (!(__builtin_fabs({v}) < 9007199254740992.0)"
                    f" || {v} != (double)(long long){v}) goto bail;")
    elif kind == "b":
        body.append(f"    if ({v} != 0.0 && {v} != 1.0) goto bail;")
    return ast.Name(v, ast.Load())


_BOX = {"f": "tfl_float({0})", "i": "PyLong_FromLongLong((long long){0})",
        "b": "PyBool_FromLong({0} != 0.0)"}


def _pack(e: ast.expr, c: _C, ind: str, out: list[str], classes: object,
          named: list[str]) -> str:
    """C building the result ``e`` (a name, or a tuple or list of results; ``classes``:
    which are NamedTuples, :func:`frontend._classes`' literal); returns the variable."""
    v = c.fresh()
    if isinstance(e, ast.Name):
        if e.id not in c.names:
            raise NativeError(f"result {e.id!r} is never set")
        out.append(f"{ind}PyObject *{v} = {_BOX[c.kinds.get(e.id, 'f')].format(e.id)};")
        out.append(f"{ind}if ({v} == NULL) return NULL;")
        return v
    if not isinstance(e, (ast.Tuple, ast.List)):
        raise NativeError(f"a result must be a name, a tuple or a list: {ast.unparse(e)!r}")
    cls = None
    if isinstance(classes, dict):
        ((cls, classes),) = classes.items()
    subs = classes if isinstance(classes, tuple) and len(classes) == len(e.elts) \
        else (None,) * len(e.elts)
    items = [_pack(x, c, ind, out, sub, named) for x, sub in zip(e.elts, subs, strict=True)]
    if cls is not None and isinstance(e, ast.Tuple):
        if cls not in named:
            named.append(cls)
        t = f"((PyTypeObject *)tfl_classes[{named.index(cls)}])"
        out.append(f"{ind}PyObject *{v} = {t}->tp_alloc({t}, {len(items)});")
        kind = "Tuple"
    else:
        kind = "Tuple" if isinstance(e, ast.Tuple) else "List"
        out.append(f"{ind}PyObject *{v} = Py{kind}_New({len(items)});")
    out.append(f"{ind}if ({v} == NULL) return NULL;")
    out.extend(f"{ind}Py{kind}_SET_ITEM({v}, {k}, {x});" for k, x in enumerate(items))
    return v


def _classes_init(named: list[str]) -> str:
    """C of the module's init importing the NamedTuple classes its results are."""
    if not named:
        return ""
    lines = [f"    tfl_classes[{k}] = tfl_class(\"{m}\", \"{q}\");\n"
             f"    if (tfl_classes[{k}] == NULL)\n        return NULL;"
             for k, (m, q) in enumerate(n.split(":") for n in named)]
    return "\n".join(lines) + "\n"


def translate(source: str, module: str) -> str:
    """C source of a CPython extension ``module`` whose one function is the Python
    function in ``source``: arguments that are numbers, or sequences of numbers (unpacked
    by ``a, (b, c) = arg``, possibly nested) or None (``arg is None``); straight-line
    code with ``if``, ``for _ in range(n)`` (with ``break``/``else``), conditional
    expressions, ``and``/``or`` (Python's operand), ``%``, the math calls of :mod:`jetcode`
    (``_sqrt``, or ``math.sqrt``) and ``_atan2``, ``_index`` and ``_int``, ``return None``
    (→ ``None``) and a final ``return (…)`` or ``return […]`` of expressions and nested
    tuples of them. Each number is held as a double; its kind (float, int, bool: the
    arguments' from their annotations, a literal of ``f``/``i``/``b`` leaves, the rest
    inferred) says how a result is returned, and the return annotation which tuples are
    NamedTuples (``{"module:Class": (…)}``)."""
    tree = ast.parse(source)
    if len(tree.body) != 1 or not isinstance(tree.body[0], ast.FunctionDef):
        raise NativeError("the source must hold one function")
    fn = tree.body[0]
    args = [a.arg for a in fn.args.args]
    *body, ret = fn.body
    if not (isinstance(ret, ast.Return) and isinstance(ret.value, (ast.Tuple, ast.List))):
        raise NativeError("the function must end with return (…) or return […]")
    objects = _objects(fn)
    c = _C(objects)
    c.names.update(a for a in args if a not in objects)
    _infer(fn, c)
    lines: list[str] = []
    c.block(body, "    ", lines)
    shape = _results(ret.value, c, lines)
    pack: list[str] = []
    named: list[str] = []
    classes = ast.literal_eval(fn.returns) if fn.returns is not None else None
    result = _pack(shape, c, "    ", pack, classes, named)
    local = sorted(c.names - set(args))
    name = fn.name
    conv = "\n".join(f"    PyObject *{a} = args[{i}];" if a in objects else
                     f"    double {a} = tfl_double(args[{i}]);"
                     for i, a in enumerate(args))
    decl = "".join(f"    double {v};\n" for v in local)
    return f"""/* Generated by tfl_mav.accel.native from the Python source below; do not edit.
{source.replace('*/', '* /')}*/
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <math.h>
{PRELUDE}
static PyObject *tfl_classes[{max(len(named), 1)}];
{chr(10).join(c.memos)}

static PyObject *
{name}(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{{
    if (nargs != {len(args)}) {{
        PyErr_Format(PyExc_TypeError, "{name}() takes {len(args)} arguments (%zd given)", nargs);
        return NULL;
    }}
{conv}
    if (PyErr_Occurred()) {{    /* an argument that is not a number: the caller decides */
        PyErr_Clear();
        Py_RETURN_NONE;
    }}
{decl}{chr(10).join(lines)}
    {{
{chr(10).join(pack)}
    return {result};
    }}
bail:
    Py_RETURN_NONE;
}}

static PyMethodDef methods[] = {{
    {{"{name}", (PyCFunction)(void (*)(void)){name}, METH_FASTCALL, NULL}},
    {{NULL, NULL, 0, NULL}}
}};

static struct PyModuleDef moduledef = {{PyModuleDef_HEAD_INIT, "{module}", NULL, -1, methods}};

PyMODINIT_FUNC __attribute__((visibility("default")))
PyInit_{module}(void)
{{
    PyObject *math = PyImport_ImportModule("math");
    if (math == NULL)
        return NULL;
    tfl_py_hypot = PyObject_GetAttrString(math, "hypot");
    Py_DECREF(math);
    if (tfl_py_hypot == NULL || tfl_init_floats() != 0)
        return NULL;
{_classes_init(named)}    return PyModule_Create(&moduledef);
}}
"""
