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
  constant ``k`` (NamedTuples: the field's index), ``t._replace(field=…)``,
  ``tuple.__new__(C, items)``, ``+`` and ``*`` of tuples, are resolved at lowering into one
  local per element; a sequence argument is unpacked once at entry (its shape taken from an
  example argument);
* **an index known when it runs**: ``t[i]`` with ``i`` computed (an int: ``rotors[k - 1]``)
  picks each element by ``i`` (``_index``; an ``i`` out of range declines, as Python
  raises);
* **booleans, ints and IntEnum codes**: ``True``/``False`` stay booleans, an IntEnum member
  (``Why.FLOOR``) its int, ``int(x)``/``bool(x)`` what they mean; an argument's kinds come
  from its NamedTuple's field annotations (``law: int``, ``holding: bool``) or its own; the
  translator returns each result as the kind Python's is (a bool a bool) and a NamedTuple
  built in the function as its class;
* **returns on several paths**: what follows an ``if`` that returns on some of its paths
  runs on the others (:class:`~tfl_mav.accel.lowering_values.Rest`, guarded by a flag the returns
  set); every return sets the result's locals;
* **a short circuit that calls**: ``a and f(x)`` (``or``) is ``if`` statements, ``f`` called
  only where Python calls it.

Every float operation of the original stays, with its operands, in the order each value
needs it: the compiled function returns the original's bits and types
(tests/contract/test_accel.py, test_accel_language.py). What it cannot lower — a call on
some paths of an expression that cannot be statements (a later comparison of a chain), a
loop with ``break`` that must unroll, a return inside a loop, recursion, returns of
different shapes, an index that is not an int — is a
:class:`~tfl_mav.accel.ctranslate.NativeError` naming it.
"""

from __future__ import annotations

import ast
import types
from collections.abc import Callable, Sequence
from typing import Any, NamedTuple

from tfl_mav.accel.ctranslate import NativeError
from tfl_mav.accel.lowering import Lowerer
from tfl_mav.accel.lowering_values import Frame, Tup, _source, _value, kind_of, named_class

__all__ = ["BOUND", "Lowered", "Tup", "bound", "bound_functions", "lower", "lower_files",
           "shape_key"]


BOUND = "bound"
"""The annotation of a parameter bound at lowering (:func:`bound`): the translator takes
the argument as an object it never reads."""


def bound(x: Any) -> bool:
    """Whether an example argument is bound at lowering rather than read when the compiled
    function runs: a function, or a non-empty tuple of functions (a NamedTuple of a path's
    kernels). Its calls are inlined — the compiled function is the function on *these*
    functions, and the caller gives it the same ones (the lowering is keyed on them)."""
    if isinstance(x, types.FunctionType):
        return True
    return isinstance(x, tuple) and bool(x) and all(
        isinstance(v, types.FunctionType) for v in x)


def bound_functions(example: Sequence[Any]) -> tuple[types.FunctionType, ...]:
    """The functions the bound arguments of ``example`` hold, in order."""
    return tuple(g for x in example if bound(x)
                 for g in (x if isinstance(x, tuple) else (x,)))


def _entry_shape(x: Any, what: str) -> Any:
    if isinstance(x, (bool, int, float)):
        return None
    if bound(x):
        return BOUND
    if isinstance(x, (tuple, list)) and x:
        return Tup([_entry_shape(v, what) for v in x], getattr(x, "_fields", None),
                   named_class(x))
    raise NativeError(f"{what}: an argument must be a number or a non-empty tuple of them")


def _entry_kinds(x: Any, kind: str) -> Any:
    """The kinds of an argument's numbers (``f``, ``i``, ``b``) as its annotations say:
    a NamedTuple's fields' own, a parameter's, else float. The items of a plain tuple
    have no annotation of their own (``tuple[int, ...]`` is not read): an int or a bool
    there is taken as the example holds it, so that a rotor index in a plain tuple can
    index another tuple as it does in Python."""
    if not isinstance(x, (tuple, list)) or bound(x):
        return kind
    fields = getattr(x, "_fields", None)
    if fields:
        notes = getattr(type(x), "__annotations__", {})
        return tuple(_entry_kinds(v, kind_of(notes.get(n))) for v, n in zip(x, fields,
                                                                           strict=True))
    return tuple(_entry_kinds(v, _item_kind(v, kind)) for v in x)


def _item_kind(v: Any, kind: str) -> str:
    """A plain tuple's item's kind: a bool's or an int's own, else the tuple's."""
    if type(v) is bool:
        return "b"
    if type(v) is int:
        return "i"
    return kind


def _floats_only(kinds: Any) -> bool:
    return all(_floats_only(k) for k in kinds) if isinstance(kinds, tuple) else kinds == "f"


def _classes(v: Any) -> Any:
    """The result's NamedTuple classes, as the translator reads them: a leaf None, a
    tuple its items', a NamedTuple ``{"module:name": (items…)}``."""
    if not isinstance(v, Tup):
        return None
    items = tuple(_classes(x) for x in v.items)
    if v.cls is not None:
        return {f"{v.cls.__module__}:{v.cls.__qualname__}": items}
    return items


def _has_class(c: Any) -> bool:
    return isinstance(c, dict) or (isinstance(c, tuple) and any(_has_class(x) for x in c))


def lower(fn: Callable[..., Any], example: Sequence[Any]) -> str:
    """The source of one function the translator takes, doing what ``fn`` does on arguments
    shaped like ``example`` (numbers, and tuples or lists of them, nested; NamedTuples name
    their fields): the same name, the same parameters, each sequence unpacked at entry."""
    return lower_files(fn, example)[0]


def shape_key(example: Sequence[Any]) -> str:
    """The shapes of ``example`` and the kinds of its numbers as text (what the lowering
    depends on besides the code: a plain tuple's ints index, its floats do not)."""
    return repr(tuple((_entry_shape(x, "an argument"), _entry_kinds(x, "f")) for x in example))


class Lowered(NamedTuple):
    """A lowering and what it depends on besides the shapes."""

    source: str
    files: set[str]                         # the source files of every function read
    constants: dict[tuple[str, str], str]   # the module constants folded in: repr by name


def lower_files(fn: Callable[..., Any], example: Sequence[Any]) -> Lowered:
    """:func:`lower`, and what it read: functions' files, modules' constants."""
    if not isinstance(fn, types.FunctionType):
        raise NativeError(f"{fn!r} is not a Python function")
    node = _source(fn)
    params = [a.arg for a in node.args.args]
    if len(params) != len(example):
        raise NativeError(f"{fn.__qualname__}: {len(params)} parameters, "
                          f"{len(example)} example arguments")
    low = Lowerer()
    low.files.add(fn.__code__.co_filename)
    f = Frame(low, fn, node, "")
    args = []
    for a, x in zip(node.args.args, example, strict=True):
        p = a.arg
        if bound(x):            # its calls inlined; the compiled function does not read it
            f.alias[p] = _value(x, f"{fn.__qualname__}({p})")
            args.append(ast.arg(p, ast.Constant(BOUND)))
            continue
        shape = f.shapes[p] = _entry_shape(x, f"{fn.__qualname__}({p})")
        if shape is not None:
            target = _target(f.local(p, shape))
            low.out.append(ast.Assign([target], ast.Name(p, ast.Load())))
        # The kinds of its numbers (int, bool), where they are not floats: what the
        # translator boxes a result computed from them as.
        kinds = _entry_kinds(x, kind_of(getattr(a.annotation, "id", None)))
        args.append(ast.arg(p, None if _floats_only(kinds) else ast.Constant(kinds)))
    for st in node.body:
        low.stmt(f, st)
    result = f.result
    if not isinstance(result, Tup):
        raise NativeError(f"{fn.__qualname__} must return a tuple")
    low.out.append(ast.Return(_tuple(result)))
    classes = _classes(result)
    out = ast.FunctionDef(name=fn.__name__, args=ast.arguments(
        posonlyargs=[], args=args, kwonlyargs=[], kw_defaults=[], defaults=[]),
        body=low.out, decorator_list=[], lineno=1,
        returns=ast.parse(repr(classes), mode="eval").body if _has_class(classes) else None)
    _number(low.out)
    return Lowered(ast.unparse(ast.Module([out], [])) + "\n", low.files, low.constants)


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
