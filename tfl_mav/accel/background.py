"""A pure law step with its constants, compiled by the seam in the background.

A law made during a flight (the spin law when the attack nears m g/2, the coning hover where
no relaxed hover holds the weight) must not stall the tick for the compiler: its step flies
in Python until the compiled one is built (:func:`native.obtain_function` with
``now=False``), and wherever the C declines (it bails where Python raises), the same bits
either way (tests/contract/test_native.py).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, Generic, TypeVar

from tfl_mav.accel import native

__all__ = ["BackgroundLaw"]

P = TypeVar("P")
S = TypeVar("S")
U = TypeVar("U")
O = TypeVar("O")


class BackgroundLaw(Generic[P, S, U, O]):
    """``step(params, state, inputs) -> (state, outputs)`` bound to ``params``; the
    examples give the compiler the shapes of a state and of the inputs."""

    def __init__(self, step: Callable[[P, S, U], tuple[S, O]], params: P, example_state: S,
                 example_inputs: U) -> None:
        self.params = params
        self._python = step
        self._core: Callable[..., Any] | None = None
        core = native.obtain_function(step, (params, example_state, example_inputs),
                                      self._ready, now=False)
        if core is not None:
            self._ready(core)

    def _ready(self, core: Callable[..., Any]) -> None:
        self._core = core           # one reference store: atomic under the GIL

    @property
    def compiled(self) -> bool:
        """Whether the step runs compiled."""
        return self._core is not None

    def step(self, state: S, inputs: U) -> tuple[S, O]:
        """One control period."""
        core = self._core
        out = core(self.params, state, inputs) if core is not None else None
        if out is None:         # not built, or the C bails where Python raises
            out = self._python(self.params, state, inputs)
        return out  # type: ignore[no-any-return]
