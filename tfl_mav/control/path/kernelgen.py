"""Tapes (:mod:`jetcode`) turned into compiled Python functions.

:func:`compile_kernel` makes one straight-line function of a traced computation (the path
kernels of :mod:`compiled`). A temporary used once is written into its use
(:func:`_inline_single_use`): the same operations on the same operands, so the same results
bit for bit, with ~40 % fewer bytecodes. The accelerator seam inlines these functions into
the law's compiled step (their source is kept where :mod:`inspect` finds it).
"""

from __future__ import annotations

import linecache
import re
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

from tfl_mav.control.path.jetcode import _FUNCS, Tape, _text

__all__ = ["KERNEL_GLOBALS", "Kernel", "compile_kernel", "compile_source"]

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


def _inline_single_use(lines: Sequence[str], outputs: Sequence[str], prefix: str = "t"
                       ) -> tuple[list[str], list[str]]:
    """The tape with each temporary that is used once written into its use, in
    parentheses: ``t3 = (a * b) + c`` instead of ``t2 = a * b`` / ``t3 = t2 + c``.

    Every operation keeps its operands (the same expression tree), so the results are the
    same bit for bit; CPython just runs ~a third fewer instructions (no store and load per
    intermediate). A select's branches are never inlined into (the operands of ``a if c else
    b`` stay computed unconditionally, as the tape records them), and long expressions stay
    temporaries so that nesting stays shallow. Temporaries are ``prefix`` + a number."""
    temp = re.compile(rf"\b{re.escape(prefix)}\d+\b")
    parsed = [ln.strip().split(" = ", 1) for ln in lines]
    uses: dict[str, int] = {}
    for text in [expr for _, expr in parsed] + list(outputs):
        for tok in temp.findall(text):
            uses[tok] = uses.get(tok, 0) + 1
    inline: dict[str, str] = {}

    def subst(text: str) -> str:
        return temp.sub(lambda m: inline.pop(m.group(0), m.group(0)), text)

    out_lines = []
    for name, expr in parsed:
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
