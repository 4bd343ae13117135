"""The daemon's intake: the vehicle's messages → complete, classified states.

Why its own module: this is the half of :class:`~tfl_mav.controller.daemon.Daemon` that runs for
every message received (three a tick in lockstep), with its own small state: the pending
ODOMETRY (converted to the paper frame at once, :mod:`tfl_mav.model.frames`) and
ACTUATOR_OUTPUT_STATUS, waiting for the ESC report that completes the state; then each
complete state classified (:mod:`tfl_mav.controller.arrivals`) and queued for this loop's control
tick, answered again (a repeat), counted (old, implausible) or taken as a new flight (restart).
HEARTBEAT and STATUSTEXT say when the vehicle is done; anything else is counted as ignored.

The per-tick messages arrive as the link's LiteMessage tuples (:func:`~tfl_mav.link.codec
.rx_lite_class`): :meth:`Intake._on_odometry` passes ODOMETRY's first 16 items straight to
:func:`~tfl_mav.model.frames.paper_from_odometry_fields` and :meth:`Intake._on_esc` reads the rpm
items, with no property read (same values as the attribute path, tests/unit/test_frames.py).
Bad input is counted in :class:`~tfl_mav.controller.daemon_io.DaemonStats` and never raises.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from typing import Any

from tfl_mav.controller import arrivals
from tfl_mav.controller.arrivals import FRESH, OLD, REPEATED, RESTART, Arrivals
from tfl_mav.controller.daemon_io import DaemonStats
from tfl_mav.link.codec import rx_lite_class
from tfl_mav.link.dialect import mav
from tfl_mav.link.statustext import Reassembler
from tfl_mav.model.frames import paper_from_odometry, paper_from_odometry_fields
from tfl_mav.model.state import State

__all__ = ["Intake"]

_ID_ODOMETRY = mav.MAVLINK_MSG_ID_ODOMETRY
_ID_ACTUATOR_OUTPUT_STATUS = mav.MAVLINK_MSG_ID_ACTUATOR_OUTPUT_STATUS
_ID_ESC_TELEMETRY_1_TO_4 = mav.MAVLINK_MSG_ID_ESC_TELEMETRY_1_TO_4
_RxOdometry = rx_lite_class(_ID_ODOMETRY)
_RxEsc = rx_lite_class(_ID_ESC_TELEMETRY_1_TO_4)
_ODOMETRY_FIELDS = 16     # time_usec, x, y, z, q[4], vx..vz, rates[3], frame_id, child_frame_id
_ESC_RPM = slice(0, 4)    # rpm[4]: the received tuple's only values (link.lite.LAZY_FIELDS)
_from_fields = paper_from_odometry_fields
_AHEAD_USEC = arrivals.AHEAD_S * 1e6     # Arrivals.classify's plausible step (float, as there)


class Intake:
    """The message handlers of :class:`~tfl_mav.controller.daemon.Daemon` (which sets the attributes
    named below and provides the methods it calls back); see the module docstring."""

    stats: DaemonStats
    _arrivals: Arrivals
    _complete: list[tuple[State, Any, list[float]]]
    _pending_state: Any
    _pending_applied: Any
    _arrived: bool
    _last_usec: int
    _last_cmd: list[float]
    _vehicle_done: str
    _texts: Reassembler
    _handlers: dict[type, Any]
    _fresh_ahead_usec: float

    def _init_intake(self) -> None:
        self._pending_state = None
        self._pending_applied = None
        # _on_esc's fast path: lockstep only (real time's plausible step grows with the wall
        # clock, so classify decides there; -inf fails every test)
        self._fresh_ahead_usec = -math.inf if self._arrivals.realtime else _AHEAD_USEC
        self._complete = []           # this batch's complete states
        self._arrived = False         # a valid state arrived this loop (failsafe clock)
        self._vehicle_done = ""
        self._texts = Reassembler()   # the vehicle's STATUSTEXT chunks → whole texts
        self._handlers = {            # the per-tick messages, by the link's classes
            _RxOdometry: self._on_odometry,
            rx_lite_class(_ID_ACTUATOR_OUTPUT_STATUS): self._on_applied,
            _RxEsc: self._on_esc}

    _event: Callable[..., None]             # the Daemon's methods, called back
    _send_command: Callable[[int, Any], None]
    _rebuild: Callable[[int], None]

    def _handle(self, msg: Any) -> None:
        """Dispatch one accepted message; a complete state joins this batch's."""
        handler = self._handlers.get(type(msg))      # the link's LiteMessage classes
        if handler is not None:
            handler(msg)
            return
        mid = msg.get_msgId()
        if mid == _ID_ODOMETRY:
            self._on_odometry(msg)
            return
        if mid == _ID_ACTUATOR_OUTPUT_STATUS:
            self._pending_applied = msg
            return
        if mid == _ID_ESC_TELEMETRY_1_TO_4:
            self._on_esc(msg)
            return
        if mid == mav.MAVLINK_MSG_ID_HEARTBEAT:
            if msg.system_status in (mav.MAV_STATE_POWEROFF, mav.MAV_STATE_EMERGENCY) \
                    and self.stats.ticks > 0:
                self._vehicle_done = ("vehicle reported EMERGENCY (crashed)"
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
                if self.stats.ticks > 0 and not self._vehicle_done:
                    if text.startswith("crashed:"):
                        self._vehicle_done = "vehicle reported EMERGENCY (crashed)"
                    elif text.startswith("simulation ended"):
                        self._vehicle_done = "vehicle powered off (run over)"
            return
        self.stats.ignored_messages += 1

    def _on_odometry(self, msg: Any) -> None:
        self._pending_applied = None
        try:
            if type(msg) is _RxOdometry:   # the link's tuple: fields in wire order
                self._pending_state = _from_fields(*msg[:_ODOMETRY_FIELDS])
            else:
                self._pending_state = paper_from_odometry(msg)
        except ValueError as exc:
            self.stats.bad_states += 1
            self._event("warning", f"ODOMETRY rejected: {exc}", quiet=True)
            self._pending_state = None
            return
        self.stats.states += 1

    def _on_applied(self, msg: Any) -> None:
        self._pending_applied = msg

    def _on_esc(self, msg: Any) -> None:
        state = self._pending_state
        rpm = [*map(float, msg[_ESC_RPM] if type(msg) is _RxEsc else msg.rpm)]
        self.stats.esc_reports += 1
        if state is None:
            return
        self._pending_state = None
        applied, self._pending_applied = self._pending_applied, None
        # classified (:mod:`tfl_mav.controller.arrivals`); a fresh state, the usual one, joins the
        # batch here (one call less a tick). Lockstep's usual case, written out: newer than
        # the watermark by at most the plausible step is FRESH (classify's last branch; its
        # wall times stay 0.0 in lockstep), no call at all.
        arr = self._arrivals
        t_usec = state.time_usec
        w = arr.newest_usec
        if w < t_usec <= w + self._fresh_ahead_usec:
            arr.jumps_in_row = arr.old_in_row = 0
            arr.newest_usec = t_usec
            self._arrived = True
            self._complete.append((state, applied, rpm))
            return
        kind = arr.classify(t_usec)
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
            if not self._complete and self._last_usec == t_usec:
                self._send_command(t_usec, self._last_cmd)
            return
        if kind == OLD:
            self._arrived = True
            stats.old_states += 1
            return
        if kind != RESTART:
            stats.implausible_states += 1
            return
        self._rebuild(t_usec)
        self._arrivals.accept(t_usec)
        self._arrived = True
        self._complete.append((state, applied_msg, rpm))

