"""The simulator's RK4 step compiled to C (:mod:`tfl_mav.accel.native`).

:func:`physics.rk4_stepper`'s ``step`` — the classical RK4 step written out on floats — is
translated from its own source into C, with the airframe's constants as arguments (one build
serves every airframe; a sweep over masses does not build per mass). The compiled step does
the Python step's floating-point operations in its order, so the trajectory is the same to
the bit (tests/contract/test_native.py; the golden flights). It is used once it is built and only on
a state of plain floats; anything else — a numpy-scalar state on the diverging path, an
operation that would raise in Python — goes to the Python step, which decides as before.
"""

from __future__ import annotations

import ast
import functools
import inspect
import textwrap
from collections.abc import Callable
from typing import Any

from tfl_mav.accel import native

__all__ = ["core_source", "stepper"]

Step = Callable[..., list[float]]


@functools.cache
def core_source(constants: tuple[str, ...]) -> str:
    """``rk4_core(x, u_f, τ_p, τ_q, τ_r, h, *constants)``: the source of the nested ``step``
    of :func:`physics.rk4_stepper`, its closure's names made arguments."""
    from tfl_mav.sim import physics

    outer = ast.parse(textwrap.dedent(inspect.getsource(physics.rk4_stepper))).body[0]
    assert isinstance(outer, ast.FunctionDef)
    step = next(n for n in outer.body if isinstance(n, ast.FunctionDef) and n.name == "step")
    step.name = "rk4_core"
    step.returns = None
    step.args.args = [ast.arg(a.arg) for a in step.args.args] + [ast.arg(n) for n in constants]
    return ast.unparse(step) + "\n"


def stepper(python_step: Step) -> Step:
    """``python_step`` (a :func:`physics.rk4_stepper` step) on the compiled core where it can
    be: now if it is built (this process, the cache, ``TFL_MAV_NATIVE=sync``), else as soon
    as a background build completes (``auto``); ``off``: ``python_step`` itself."""
    if native.mode() == "off":
        return python_step
    names = python_step.__code__.co_freevars
    values = [c.cell_contents for c in python_step.__closure__ or ()]
    consts = ", ".join(f"_k{i}" for i in range(len(names)))
    namespace: dict[str, Any] = {"_core": None, "_python": python_step, "_float": float,
                                 **{f"_k{i}": v for i, v in enumerate(values)}}
    exec(compile(f"""\
def step(x, uf, tp, tq, tr, h):
    core = _core
    if core is not None and type(x[0]) is _float:
        r = core(x, uf, tp, tq, tr, h, {consts})
        if r is not None:
            return r
    return _python(x, uf, tp, tq, tr, h)
""", "<tfl_mav.sim.physics_native>", "exec"), namespace)

    def ready(core: Callable[..., Any]) -> None:
        namespace["_core"] = core

    core = native.obtain(core_source(names), ready)
    if core is not None:
        ready(core)
    return namespace["step"]  # type: ignore[no-any-return]
