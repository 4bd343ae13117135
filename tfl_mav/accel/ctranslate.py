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
from collections.abc import Callable

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

    def __init__(self, objects: set[str]) -> None:
        self.names: set[str] = set()
        self.objects = objects      # parameters kept as Python objects (sequences, None)
        self.tmp = 0

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
            if type(v) is bool or not isinstance(v, (int, float)):
                raise NativeError(f"constant {v!r} is not a number")
            f = float(v)
            if f != f or f in (float("inf"), float("-inf")):
                raise NativeError(f"constant {v!r} is not finite")
            return f"({float.hex(f)})"      # exact, whatever the C library's strtod
        if isinstance(e, ast.UnaryOp):
            x = self.expr(e.operand)
            if isinstance(e.op, ast.USub):
                return f"(-{x})"
            if isinstance(e.op, ast.UAdd):
                return x
            if isinstance(e.op, ast.Not):
                return f"(!{x})"
        if isinstance(e, ast.BinOp):
            a, b = self.expr(e.left), self.expr(e.right)
            op = _BINOPS.get(type(e.op))
            if op is not None:
                return f"({a} {op} {b})"
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
            op = " && " if isinstance(e.op, ast.And) else " || "
            return "(" + op.join(self.expr(v) for v in e.values) + ")"
        if isinstance(e, ast.IfExp):
            return f"({self.expr(e.test)} ? {self.expr(e.body)} : {self.expr(e.orelse)})"
        if isinstance(e, ast.Call) and isinstance(e.func, ast.Name) and not e.keywords:
            return self._call(e.func.id, [self.expr(a) for a in e.args])
        if isinstance(e, ast.Call) and isinstance(e.func, ast.Attribute) and not e.keywords \
                and isinstance(e.func.value, ast.Name) and e.func.value.id == "math":
            return self._call(f"_{e.func.attr}", [self.expr(a) for a in e.args])
        raise NativeError(f"cannot translate {ast.unparse(e)!r}")

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
                out.append(f"{ind}{elt.id} = PyFloat_AsDouble({item});")
            else:
                raise NativeError(f"cannot unpack into {ast.unparse(elt)!r}")
        out.append(f"{ind}Py_DECREF({s});")
        out.append(f"{ind}if (PyErr_Occurred()) {{ PyErr_Clear(); {release}goto bail; }}")

    def stmt(self, st: ast.stmt, ind: str, out: list[str]) -> None:
        if isinstance(st, ast.Assign) and len(st.targets) == 1 \
                and isinstance(st.targets[0], ast.Tuple):
            if not (isinstance(st.value, ast.Name) and st.value.id in self.objects):
                raise NativeError(f"only a sequence argument unpacks: {ast.unparse(st)!r}")
            out.append(f"{ind}{{")
            self.unpack(st.targets[0], st.value.id, ind + "    ", out)
            out.append(f"{ind}}}")
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


def _objects(fn: ast.FunctionDef) -> set[str]:
    """The parameters used as sequences (unpacked) or compared with None."""
    params = {a.arg for a in fn.args.args}
    objs = set()
    for node in ast.walk(fn):
        if isinstance(node, ast.Assign) and isinstance(node.targets[0], ast.Tuple) \
                and isinstance(node.value, ast.Name):
            objs.add(node.value.id)
        elif isinstance(node, ast.Compare) and isinstance(node.left, ast.Name) \
                and any(isinstance(op, (ast.Is, ast.IsNot)) for op in node.ops):
            objs.add(node.left.id)
    return objs & params


def _results(e: ast.expr, c: _C, body: list[str]) -> ast.expr:
    """``e`` with every leaf that is not a plain name computed into a new local first (in
    ``body``, before any object is made: a leaf may still decline)."""
    if isinstance(e, (ast.Tuple, ast.List)):
        return type(e)([_results(x, c, body) for x in e.elts], ast.Load())
    if isinstance(e, ast.Name):
        return e
    v = c.fresh()
    body.append(f"    {v} = {c.expr(e)};")
    c.names.add(v)
    return ast.Name(v, ast.Load())


def _pack(e: ast.expr, names: set[str], ind: str, out: list[str], fresh: Callable[[], str]
          ) -> str:
    """C building the result ``e`` (a name, or a tuple or list of results); returns the
    variable."""
    v = fresh()
    if isinstance(e, ast.Name):
        if e.id not in names:
            raise NativeError(f"result {e.id!r} is never set")
        out.append(f"{ind}PyObject *{v} = PyFloat_FromDouble({e.id});")
        out.append(f"{ind}if ({v} == NULL) return NULL;")
        return v
    if not isinstance(e, (ast.Tuple, ast.List)):
        raise NativeError(f"a result must be a name, a tuple or a list: {ast.unparse(e)!r}")
    kind = "Tuple" if isinstance(e, ast.Tuple) else "List"
    items = [_pack(x, names, ind, out, fresh) for x in e.elts]
    out.append(f"{ind}PyObject *{v} = Py{kind}_New({len(items)});")
    out.append(f"{ind}if ({v} == NULL) return NULL;")
    out.extend(f"{ind}Py{kind}_SET_ITEM({v}, {k}, {x});" for k, x in enumerate(items))
    return v


def translate(source: str, module: str) -> str:
    """C source of a CPython extension ``module`` whose one function is the Python
    function in ``source``: arguments that are numbers, or sequences of numbers (unpacked
    by ``a, (b, c) = arg``, possibly nested) or None (``arg is None``); straight-line float
    code with ``if``, ``for _ in range(n)`` (with ``break``/``else``), conditional
    expressions, the math calls of :mod:`jetcode` (``_sqrt``, or ``math.sqrt``) and
    ``_atan2``, ``return None`` (→ ``None``) and a final ``return (…)`` or ``return […]`` of
    float expressions and nested tuples of them (→ tuples or a list of floats)."""
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
    lines: list[str] = []
    c.block(body, "    ", lines)
    shape = _results(ret.value, c, lines)
    pack: list[str] = []
    result = _pack(shape, c.names, "    ", pack, c.fresh)
    local = sorted(c.names - set(args))
    name = fn.name
    conv = "\n".join(f"    PyObject *{a} = args[{i}];" if a in objects else
                     f"    double {a} = PyFloat_AsDouble(args[{i}]);"
                     for i, a in enumerate(args))
    decl = "".join(f"    double {v};\n" for v in local)
    return f"""/* Generated by tfl_mav.accel.native from the Python source below; do not edit.
{source.replace('*/', '* /')}*/
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <math.h>
{PRELUDE}
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
    if (tfl_py_hypot == NULL)
        return NULL;
    return PyModule_Create(&moduledef);
}}
"""
