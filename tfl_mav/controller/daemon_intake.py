"""The daemon's intake: the vehicle's messages → complete, classified states.

:class:`Intake` is an object the :class:`~tfl_mav.controller.daemon.Daemon` owns; it runs for
every message received (three a tick in lockstep), with its own state: the pending
ODOMETRY (converted to the paper frame at once, :mod:`tfl_mav.model.frames`) and
ACTUATOR_OUTPUT_STATUS, waiting for the ESC report that completes the state; then each
complete state classified (:mod:`tfl_mav.controller.arrivals`) and queued for this loop's control
tick, answered again (a repeat), counted (old, implausible) or taken as a new flight (restart).
HEARTBEAT and STATUSTEXT say when the vehicle is done; anything else is counted as ignored.
What it asks of the daemon is three functions it is given: say an event, answer a repeated
state, start a new flight; what the daemon takes from it is :meth:`Intake.take` (this loop's
complete states) and :attr:`Intake.vehicle_done`.

The per-tick messages arrive as the link's LiteMessage tuples (:func:`~tfl_mav.link.codec
.rx_lite_class`): :meth:`Intake.on_odometry` passes ODOMETRY's first 16 items straight to
:func:`~tfl_mav.model.frames.paper_from_odometry_fields` and :meth:`Intake.on_esc` reads the rpm
items, with no property read (same values as the attribute path, tests/unit/test_frames.py).
Bad input is counted in :class:`~tfl_mav.controller.daemon_wire.DaemonStats` and never raises.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

from tfl_mav.controller.arrivals import FRESH, OLD, REPEATED, RESTART, Arrivals
from tfl_mav.controller.daemon_wire import DaemonStats
from tfl_mav.link.codec import rx_lite_class
from tfl_mav.link.dialect import mav
from tfl_mav.link.statustext import Reassembler
from tfl_mav.model.frames import paper_from_odometry, paper_from_odometry_fields
from tfl_mav.model.state import State

__all__ = ["ODOMETRY_FIELDS", "Intake", "RxOdometry"]

_ID_ODOMETRY = mav.MAVLINK_MSG_ID_ODOMETRY
_ID_ACTUATOR_OUTPUT_STATUS = mav.MAVLINK_MSG_ID_ACTUATOR_OUTPUT_STATUS
_ID_ESC_TELEMETRY_1_TO_4 = mav.MAVLINK_MSG_ID_ESC_TELEMETRY_1_TO_4
#: The type of the ODOMETRY tuples the link hands the intake: read by position (the first
#: :data:`ODOMETRY_FIELDS` items), not through pymavlink's message.
RxOdometry = rx_lite_class(_ID_ODOMETRY)
_RxEsc = rx_lite_class(_ID_ESC_TELEMETRY_1_TO_4)
#: ODOMETRY's leading fields (in wire order: time_usec, x, y, z, q[4], vx..vz, rates[3],
#: frame_id, child_frame_id) that ``paper_from_odometry_fields`` takes: the link's tuple's
#: first items.
ODOMETRY_FIELDS = 16
_ESC_RPM = slice(0, 4)    # rpm[4]: the received tuple's only values (link.lite.LAZY_FIELDS)
_from_fields = paper_from_odometry_fields

Batch = list[tuple[State, Any, list[float]]]    # complete states: (state, applied msg, rpm)


class Intake:
    """The vehicle's messages → this loop's complete, classified states (module docstring).

    ``event(level, text, send=..., quiet=...)`` says something (the daemon's events);
    ``answer_repeat(t_usec)``: a state of ``t_usec`` came again with nothing newer in this
    batch; ``new_flight(t_usec, from_usec)``: vehicle time jumped from ``from_usec`` to
    ``t_usec`` (a restart), the daemon starts a new flight before the state joins the batch.
    """

    def __init__(self, stats: DaemonStats, realtime: bool, *,
                 event: Callable[..., None], answer_repeat: Callable[[int], None],
                 new_flight: Callable[[int, int], None]) -> None:
        self.stats = stats                        # the daemon's counters, shared
        self.arrivals = Arrivals(realtime)        # the watermark and the restart rule
        self._event = event
        self._answer_repeat = answer_repeat
        self._new_flight = new_flight
        self._pending_state: State | None = None  # ODOMETRY waiting for its ESC report
        self._pending_applied: Any = None         # ... and its ACTUATOR_OUTPUT_STATUS
        self._complete: Batch = []                # this batch's complete states
        self._arrived = False                     # a valid state arrived this loop
        self.vehicle_done = ""                    # why the vehicle is done ("": it is not)
        self._texts = Reassembler()   # the vehicle's STATUSTEXT chunks → whole texts
        self.handlers: dict[type, Callable[[Any], None]] = {
            # the per-tick messages, by the link's classes: the daemon's loop calls these
            # directly, everything else goes through handle()
            RxOdometry: self.on_odometry,
            rx_lite_class(_ID_ACTUATOR_OUTPUT_STATUS): self.on_applied,
            _RxEsc: self.on_esc}

    def take(self) -> tuple[Batch, bool]:
        """This loop's complete states, oldest first, and whether a valid state arrived
        (for the failsafe's clock); both start again empty."""
        batch, arrived = self._complete, self._arrived
        self._arrived = False
        if batch:
            self._complete = []
        return batch, arrived

    def handle(self, msg: Any) -> None:
        """Dispatch one accepted message; a complete state joins this batch's."""
        handler = self.handlers.get(type(msg))      # the link's LiteMessage classes
        if handler is not None:
            handler(msg)
            return
        mid = msg.get_msgId()
        if mid == _ID_ODOMETRY:
            self.on_odometry(msg)
            return
        if mid == _ID_ACTUATOR_OUTPUT_STATUS:
            self._pending_applied = msg
            return
        if mid == _ID_ESC_TELEMETRY_1_TO_4:
            self.on_esc(msg)
            return
        if mid == mav.MAVLINK_MSG_ID_HEARTBEAT:
            if msg.system_status in (mav.MAV_STATE_POWEROFF, mav.MAV_STATE_EMERGENCY) \
                    and self.stats.ticks > 0:
                self.vehicle_done = ("vehicle reported EMERGENCY (crashed)"
                                     if msg.system_status == mav.MAV_STATE_EMERGENCY
                                     else "vehicle powered off (run over)")
            return
        if mid == mav.MAVLINK_MSG_ID_STATUSTEXT:
            # whole texts, not chunks (MAVLink 2: chunks share an id; one shorter than 50
            # characters ends it): printed once, and the end of a flight is read from all
            # of it, so the log holds all of it too
            for text in self._texts.add(msg.get_srcComponent(), msg.text,
                                        getattr(msg, "id", 0), getattr(msg, "chunk_seq", 0),
                                        time.monotonic()):
                self._event("info", f"vehicle: {text}", send=False)
                if self.stats.ticks > 0 and not self.vehicle_done:
                    if text.startswith("crashed:"):
                        self.vehicle_done = "vehicle reported EMERGENCY (crashed)"
                    elif text.startswith("simulation ended"):
                        self.vehicle_done = "vehicle powered off (run over)"
            return
        self.stats.ignored_messages += 1

    def on_odometry(self, msg: Any) -> None:
        self._pending_applied = None
        try:
            if type(msg) is RxOdometry:   # the link's tuple: fields in wire order
                self._pending_state = _from_fields(*msg[:ODOMETRY_FIELDS])
            else:
                self._pending_state = paper_from_odometry(msg)
        except ValueError as exc:
            self.stats.bad_states += 1
            self._event("warning", f"ODOMETRY rejected: {exc}", quiet=True)
            self._pending_state = None
            return
        self.stats.states += 1

    def on_applied(self, msg: Any) -> None:
        self._pending_applied = msg

    def on_esc(self, msg: Any) -> None:
        state = self._pending_state
        rpm = [*map(float, msg[_ESC_RPM] if type(msg) is _RxEsc else msg.rpm)]
        self.stats.esc_reports += 1
        if state is None:
            return
        self._pending_state = None
        applied, self._pending_applied = self._pending_applied, None
        kind = self.arrivals.classify(state.time_usec)   # :mod:`tfl_mav.controller.arrivals`
        if kind == FRESH:
            self._arrived = True
            self._complete.append((state, applied, rpm))
            return
        self._arrive(kind, state, applied, rpm)

    def _arrive(self, kind: int, state: State, applied_msg: Any, rpm: list[float]) -> None:
        """Act on a complete state that is not fresh, classified as ``kind``."""
        t_usec = state.time_usec
        stats = self.stats
        if kind == REPEATED:
            stats.repeated_states += 1
            self._arrived = True
            if not self._complete:
                self._answer_repeat(t_usec)
            return
        if kind == OLD:
            self._arrived = True
            stats.old_states += 1
            return
        if kind != RESTART:
            stats.implausible_states += 1
            return
        # a new flight: the pending batch belongs to the old time line
        arrivals = self.arrivals
        from_usec = arrivals.newest_usec
        stats.skipped_states += len(self._complete)
        self._complete = []
        self._new_flight(t_usec, from_usec)
        arrivals.reset()
        arrivals.accept(t_usec)
        self._arrived = True
        self._complete.append((state, applied_msg, rpm))
