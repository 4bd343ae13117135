"""The detector's four-rotor tick compiled to C (:mod:`native`).

:func:`detector_kernel.rotors_source` writes the tick twice from one template: as Python on
the detector's attributes, and as a pure function of their numbers. The pure one is
compiled; the detector then calls a small Python function that reads its state, makes the
one call and writes the new state back — the same floats, so the same verdicts (the lagged
detector's update makes that call itself, through ``_core``: one Python call less a tick).
When the compiled tick declines (an operation that would raise in Python, a state that is not
numbers) the Python tick runs instead, from the same state.
"""

from __future__ import annotations

import weakref
from collections.abc import Callable
from typing import Any

from tfl_mav.accel import native
from tfl_mav.control.detect.detector_kernel import STATE, python_kernel, rotors_source

__all__ = ["attach"]

_CALLERS: dict[bool, tuple[Callable[..., float], dict[str, Any]]] = {}


def _caller(lagged: bool) -> tuple[Callable[..., float], dict[str, Any]]:
    """The calling function for one kind (lagged or not) and the globals it finds ``_core``
    in; one per process, whatever the number of detectors."""
    made = _CALLERS.get(lagged)
    if made is not None:
        return made
    state = [*STATE, ("_var", "v", "var")] if lagged else list(STATE)
    args = "r0, r1, r2, r3, c0, c1, c2, c3" + (", decay" if lagged else "")
    head = "self._band, self._sig2" if lagged else "self._sd0"
    reads = ", ".join(f"self.{attr}" for attr, _, _ in state)
    writes = ", ".join(f"self.{attr}" for attr, _, _ in state)
    source = f"""\
def rotors_native(self, {args}):
    r = _core({head}, self.thrust_max_n, {reads}, self.k, self.z_cap, self.k_f,
              self.detected_rotor, {args})
    if r is None:
        return _python(self, {args})
    top, nrej, {'self._band, ' if lagged else ''}{writes} = r
    if nrej:
        self.rejected_samples += int(nrej)
    return top
"""
    namespace: dict[str, Any] = {"_core": None, "_python": python_kernel(lagged)}
    exec(compile(source, "<tfl_mav.control.detect.detector_native>", "exec"), namespace)
    made = _CALLERS[lagged] = (namespace["rotors_native"], namespace)
    return made


def attach(detector: Any, lagged: bool) -> None:
    """Give ``detector`` (an :class:`detector.AttackDetector` running the Python kernel)
    the compiled tick: now if it is built (this process, the cache, or
    ``TFL_MAV_NATIVE=sync``), else when a background build completes (``auto``)."""
    if native.mode() == "off":
        return
    caller, namespace = _caller(lagged)
    python, ref = detector._rotors, weakref.ref(detector)
    if namespace["_core"] is not None:
        detector._rotors = caller
        if lagged:
            detector._core = namespace["_core"]
        return

    def ready(core: Callable[..., Any]) -> None:
        namespace["_core"] = core
        target = ref()
        if target is not None and target._rotors is python:
            target._rotors = caller
            if lagged:
                target._core = core

    core = native.obtain(rotors_source(lagged, pure=True), ready)
    if core is not None:
        ready(core)
