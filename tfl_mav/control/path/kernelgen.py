"""Tapes (:mod:`jetcode`) turned into compiled Python functions.

:func:`compile_kernel` makes one straight-line function of a traced computation (the path
kernels of :mod:`compiled`); :func:`trace_block` makes the same straight-line code as a
block of lines over named locals, for a generated function that also holds hand-written
control flow (the fused law tick of :mod:`fused`). Either way a temporary used once is
written into its use (:func:`_inline_single_use`): the same operations on the same operands,
so the same results bit for bit, with ~40 % fewer bytecodes.
"""

from __future__ import annotations
import __future__

import ast
import functools
import heapq
import inspect
import linecache
import math
import re
import textwrap
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

from tfl_mav.control.path.jetcode import _FUNCS, RAW, Sym, Tape, _text

__all__ = ["KERNEL_GLOBALS", "Kernel", "compile_kernel", "compile_source", "reuse_slots",
           "trace_block", "traceable"]

#: The names generated code may call: the whitelisted math functions, ``_sin`` etc.
KERNEL_GLOBALS: dict[str, Callable[..., float]] = {f"_{k}": v for k, v in _FUNCS.items()}


@dataclass(frozen=True)
class Kernel:
    """A compiled straight-line function and what it cost to make."""

    fn: Callable[..., tuple[float, ...]]
    source: str
    n_ops: int
    build_s: float


_INLINE_MAX_CHARS = 160     # longer expressions stay temporaries (bounded nesting)


# Division by a run-time value, a power, a math function (a literal divisor cannot raise).
_MAY_RAISE = re.compile(r"/ (?!\(?-?\d)|\*\*|\b_[a-z]+\(")


def _drop_dead(lines: Sequence[str], outputs: Sequence[str], temp: re.Pattern[str]
               ) -> list[str]:
    """``lines`` without the operations nothing reads (folded constants leave some); an
    operation that may raise (division, power, a math function) is kept, so that a tick
    fails exactly where the unfused kernels would."""
    live = {tok for o in outputs for tok in temp.findall(o)}
    kept = []
    for line in reversed(lines):
        name, _, expr = line.strip().partition(" = ")
        if not (line.startswith(RAW) or name in live or _MAY_RAISE.search(expr)):
            continue
        live.update(temp.findall(line if line.startswith(RAW) else expr))
        kept.append(line)
    return kept[::-1]


def _inline_single_use(lines: Sequence[str], outputs: Sequence[str], prefix: str = "t",
                       drop_dead: bool = False) -> tuple[list[str], list[str]]:
    """The tape with each temporary that is used once written into its use, in
    parentheses: ``t3 = (a * b) + c`` instead of ``t2 = a * b`` / ``t3 = t2 + c``.

    Every operation keeps its operands (the same expression tree), so the results are the
    same bit for bit; CPython just runs ~a third fewer instructions (no store and load per
    intermediate). A select's branches are never inlined into (the operands of ``a if c else
    b`` stay computed unconditionally, as the tape records them), and long expressions stay
    temporaries so that nesting stays shallow. Temporaries are ``prefix`` + a number;
    ``drop_dead``: see :func:`_drop_dead`."""
    temp = re.compile(rf"\b{re.escape(prefix)}\d+\b")
    if drop_dead:
        lines = _drop_dead(lines, outputs, temp)
    parsed = [("", ln) if ln.startswith(RAW) else ln.strip().split(" = ", 1) for ln in lines]
    uses: dict[str, int] = {}
    for text in [expr for _, expr in parsed] + list(outputs):
        for tok in temp.findall(text):
            uses[tok] = uses.get(tok, 0) + 1
    inline: dict[str, str] = {}

    def subst(text: str) -> str:
        return temp.sub(lambda m: inline.pop(m.group(0), m.group(0)), text)

    out_lines = []
    for line, (name, expr) in zip(lines, parsed, strict=True):
        if line.startswith(RAW):
            # Hand-written code: what it reads is computed before it, on its own lines.
            for tok in temp.findall(line):
                if tok in inline:
                    out_lines.append(f"    {tok} = {inline.pop(tok)[1:-1]}")
            out_lines.extend(line[len(RAW):].split("\n"))
            continue
        if " if " in expr:
            # A select: what it reads is computed on its own line first, unconditionally.
            for tok in temp.findall(expr):
                if tok in inline:
                    out_lines.append(f"    {tok} = {inline.pop(tok)[1:-1]}")
        else:
            expr = subst(expr)
        if uses.get(name, 0) == 1 and len(expr) <= _INLINE_MAX_CHARS:
            inline[name] = f"({expr})"
        else:
            out_lines.append(f"    {name} = {expr}")
    return out_lines, [subst(o) for o in outputs]


_TEMP = re.compile(r"\b[a-z]_\d+\b")


def reuse_slots(source: str, slot: str = "w_") -> str:
    """``source`` with its temporaries (``x_123``) renamed onto as few locals as their live
    ranges allow (``slot`` + a number): the same operations on the same values, but a
    frame of a few dozen locals instead of hundreds, which CPython zeroes and clears on
    every call and addresses with an extra EXTENDED_ARG instruction beyond 256.

    Live ranges are textual (first line to last line naming the temporary); one that
    enters a ``for`` loop from before it lives to the loop's end (its next iteration
    reads it again). Straight-line code and ``if`` blocks need nothing more."""
    lines = source.split("\n")
    first: dict[str, int] = {}
    last: dict[str, int] = {}
    for i, line in enumerate(lines):
        for tok in _TEMP.findall(line):
            first.setdefault(tok, i)
            last[tok] = i
    loops = []
    for i, line in enumerate(lines):
        if line.lstrip().startswith("for "):
            ind = len(line) - len(line.lstrip())
            end = next((j for j in range(i + 1, len(lines)) if lines[j].strip()
                        and len(lines[j]) - len(lines[j].lstrip()) <= ind
                        and not lines[j].lstrip().startswith("else:")), len(lines))
            loops.append((i, end))
    for tok in first:
        for a, b in loops:
            if first[tok] < a < last[tok] < b:
                last[tok] = b
    names: dict[str, str] = {}
    free: list[str] = []
    ending: list[tuple[int, str]] = []     # heap of (last line, slot) of the live ones
    n_slots = 0
    for tok in sorted(first, key=first.__getitem__):
        while ending and ending[0][0] < first[tok]:
            free.append(heapq.heappop(ending)[1])
        if free:
            names[tok] = free.pop()
        else:
            names[tok] = f"{slot}{n_slots}"
            n_slots += 1
        heapq.heappush(ending, (last[tok], names[tok]))
    return "\n".join(_TEMP.sub(lambda m: names.get(m.group(0), m.group(0)), ln)
                     for ln in lines)


def compile_source(name: str, source: str, extra: dict[str, Any] | None = None
                   ) -> Callable[..., Any]:
    """The function ``name`` defined by generated ``source`` (globals: the math functions
    and ``extra``)."""
    namespace: dict[str, Any] = {**KERNEL_GLOBALS, **(extra or {})}
    filename = f"<tfl-mav kernel {name}>"
    # Its text where inspect finds it: tracebacks, and the seam's front end inlines it.
    linecache.cache[filename] = (len(source), None, source.splitlines(True), filename)
    exec(compile(source, filename, "exec"), namespace)
    return namespace[name]  # type: ignore[no-any-return]


def compile_kernel(name: str, inputs: Sequence[Sequence[str]],
                   trace: Callable[..., Sequence[Any]], *, inline: bool = True) -> Kernel:
    """Trace ``trace(*symbol groups)`` and compile ``name(*groups)`` returning its outputs.

    ``inputs`` lists the argument groups: each group is one tuple argument of the compiled
    function, unpacked into the named locals at entry. ``inline``: temporaries used once
    are written into their use (:func:`_inline_single_use`; False: one line per operation).
    """
    t0 = time.perf_counter()
    tape = Tape()
    groups = [[tape.input(n) for n in group] for group in inputs]
    outputs = trace(*groups)
    args = [f"a{g}" for g in range(len(inputs))]
    head = [f"def {name}({', '.join(args)}):"]
    for arg, group in zip(args, inputs, strict=True):
        names = ", ".join(group)
        head.append(f"    {names}{',' if len(group) == 1 else ''} = {arg}")
    ret = [_text(o) for o in outputs]
    lines = tape.lines
    if inline:
        lines, ret = _inline_single_use(lines, ret)
    source = "\n".join([*head, *lines, f"    return ({', '.join(ret)},)"]) + "\n"
    return Kernel(compile_source(name, source), source, len(tape.lines),
                  time.perf_counter() - t0)


def trace_block(prefix: str, inputs: Sequence[Sequence[str]],
                trace: Callable[..., Sequence[Any]], outputs: Sequence[str],
                indent: str = "    ") -> tuple[list[str], int]:
    """Straight-line lines computing ``outputs`` (local names) from the locals ``inputs``
    (groups, passed to ``trace`` as lists of symbols), temporaries named ``prefix`` + a
    number; returns (lines indented by ``indent``, number of traced operations). ``trace``
    may put hand-written statements between the operations (:meth:`jetcode.Tape.raw`,
    indented by 4 as the top level of a function)."""
    tape = Tape(prefix)
    groups = [[tape.input(n) for n in group] for group in inputs]
    results = trace(*groups)
    if len(results) != len(outputs):
        raise ValueError(f"block {prefix!r}: {len(results)} results for {len(outputs)} names")
    lines, ret = _inline_single_use(tape.lines, [_text(r) for r in results], prefix,
                                    drop_dead=True)
    body = [indent + ln[4:] for ln in lines]    # _inline_single_use indents by 4
    body += [f"{indent}{name} = {expr}" for name, expr in zip(outputs, ret, strict=True)
             if name != expr]
    return body, len(tape.lines)


_OPS = {ast.Lt: "<", ast.LtE: "<=", ast.Gt: ">", ast.GtE: ">="}


def _operand(x: Any) -> str:
    """Source text of a select's operand; ±inf as the generated code's ``_inf``."""
    if type(x) is not Sym and math.isinf(x):
        return "_inf" if x > 0 else "(-_inf)"
    return _text(x)


def _select(op: str, left: Any, right: Any, a: Any, b: Any) -> Any:
    """``a if left op right else b`` on traced values: decided now for two constants, else
    one run-time select (the same comparison, so the same choice, NaN included)."""
    syms = [x for x in (left, right) if type(x) is Sym]
    if not syms:
        return a if {"<": left < right, "<=": left <= right, ">": left > right,
                     ">=": left >= right}[op] else b
    if _operand(a) == _operand(b):
        return a
    return syms[0].tape.emit(f"{_operand(a)} if {_operand(left)} {op} {_operand(right)} "
                             f"else {_operand(b)}")


class _Selects(ast.NodeTransformer):
    def visit_IfExp(self, node: ast.IfExp) -> ast.AST:
        self.generic_visit(node)
        t = node.test
        if (isinstance(t, ast.Compare) and len(t.ops) == 1
                and type(t.ops[0]) in _OPS):
            return ast.copy_location(ast.Call(
                ast.Name("_select", ast.Load()),
                [ast.Constant(_OPS[type(t.ops[0])]), t.left, t.comparators[0], node.body,
                 node.orelse], []), node)
        return node


@functools.cache
def traceable(fn: Callable[..., Any]) -> Callable[..., Any]:
    """``fn`` (a plain function whose value-dependent choices are conditional expressions
    ``a if x < y else b``) recompiled from its own source so that those choices become
    run-time selects when it runs on traced values (:mod:`jetcode`): the one definition
    the step-by-step law calls on floats, traced into generated code (:mod:`fused`). The
    generated code needs ``_inf`` among its globals if a bound is infinite."""
    tree = ast.parse(textwrap.dedent(inspect.getsource(fn)))
    tree = ast.fix_missing_locations(_Selects().visit(tree))
    namespace = {**fn.__globals__, "_select": _select}
    exec(compile(tree, f"<traceable {fn.__name__}>", "exec",
                 flags=__future__.annotations.compiler_flag, dont_inherit=True), namespace)
    return namespace[fn.__name__]  # type: ignore[no-any-return]
