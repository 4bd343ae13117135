"""The vehicle's recorder hooks, and when they run.

``on_frame(direction, raw, msg, time_s)`` sees every frame of both links;
``on_truth(sim)`` sees the simulator at every control tick's state. Called at once, they
would sit on lockstep's critical path (reply → integrate → next state), which is serial:
the controller waits for the state. So while the vehicle crosses that stretch
:class:`HandOff` queues them (frames with the wall time their link stamped; truth as a
marker, the simulator does not change until the next reply is applied) and calls them, in
the order they happened, from :meth:`HandOff.flush` while the controller computes. A
recorder sees the same calls with the same arguments in the same order, only later.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any, Protocol

from tfl_mav.link.transport import FrameHook
from tfl_mav.sitl.simulator import Simulator

__all__ = ["HandOff", "TruthSink", "truth_hook"]

_TRUTH: tuple[Any, ...] = ("truth",)        # queued marker: call on_truth with the sim
_BATCH = object()                           # queued marker: a datagram's frames (on_frames)


class HandOff:
    """The recorder hooks of one vehicle: called at once, or queued until :meth:`flush`."""

    def __init__(self, sim: Simulator, on_frame: FrameHook | None,
                 on_truth: Callable[[Simulator], None] | None,
                 on_frames: Callable[..., None] | None = None) -> None:
        self.sim = sim
        self.on_frame = on_frame
        self.on_truth = on_truth
        self.on_frames = on_frames     # (direction, raws, msgs, time_s): a datagram at once
        self._queue: list[tuple[Any, ...]] | None = None   # None: call at once

    def defer(self, defer: bool) -> None:
        """Queue the hooks from now on, or flush and call them at once again."""
        if defer:
            if self._queue is None:
                self._queue = []
        else:
            self.flush()
            self._queue = None

    def flush(self) -> None:
        """Call the queued hooks, in the order they happened."""
        queued = self._queue
        if not queued:
            return
        self._queue = []
        for item in queued:
            if item is _TRUTH:
                self.on_truth(self.sim)   # type: ignore[misc]
            elif item[0] is _BATCH:
                self.on_frames(*item[1:])  # type: ignore[misc]
            else:
                self.on_frame(*item)      # type: ignore[misc]

    def frame(self, direction: str, raw: bytes, msg: Any, time_s: float) -> None:
        """The links' ``on_frame`` (given to them only when there is a hook)."""
        queue = self._queue
        if queue is None:
            self.on_frame(direction, raw, msg, time_s)   # type: ignore[misc]
        else:
            queue.append((direction, raw, msg, time_s))

    def frames(self, direction: str, raws: Any, msgs: Any, time_s: float) -> None:
        """The links' ``on_frames`` (one datagram's frames; given only with a hook)."""
        queue = self._queue
        if queue is None:
            self.on_frames(direction, raws, msgs, time_s)   # type: ignore[misc]
        else:
            queue.append((_BATCH, direction, raws, msgs, time_s))

    def truth(self) -> None:
        """The simulator's state of this tick, to ``on_truth`` (if any)."""
        if self.on_truth is not None:
            queue = self._queue
            if queue is None:
                self.on_truth(self.sim)
            else:
                queue.append(_TRUTH)


class TruthSink(Protocol):
    """The part of a flight recorder (``tfl_mav.flightlog``) that takes ground truth."""

    def truth(self, time_s: float, position_m: Sequence[float], velocity_mps: Sequence[float],
              quaternion_wxyz: Sequence[float], body_rates_radps: Sequence[float],
              rotor_thrust_n: Sequence[float], attack_rotor: int, attack_applied_n: float,
              attack_requested_n: float, wind_mps: Sequence[float] | None = None, /
              ) -> None: ...


def truth_hook(recorder: TruthSink) -> Callable[[Simulator], None]:
    """``Vehicle.on_truth`` → ``recorder.truth``: true state, rotor thrusts and attack, and
    in moving air the wind the state met (``/sim/truth/wind``)."""

    def on_truth(sim: Simulator) -> None:
        # the float state vector, sliced (sim.state would build five arrays a tick only to
        # turn them back into these very lists)
        x = sim.state_vector
        att = sim.attack
        if sim.wind is None:
            recorder.truth(sim.time_s, x[0:3], x[3:6], x[6:10], x[10:13],
                           sim.rotor_thrusts_n, att.rotor, att.applied_n, att.raw_n)
        else:
            recorder.truth(sim.time_s, x[0:3], x[3:6], x[6:10], x[10:13],
                           sim.rotor_thrusts_n, att.rotor, att.applied_n, att.raw_n,
                           sim.wind_mps)

    return on_truth
