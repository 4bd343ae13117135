"""The one lockstep client: a controller that answers every vehicle state with controls.

A lockstep vehicle (``tfl-mav sim`` or an in-process :class:`~tfl_mav.sitl.vehicle.Vehicle`) sends
one ODOMETRY + ACTUATOR_OUTPUT_STATUS + ESC_TELEMETRY_1_TO_4 per control tick (the last
ACTUATOR_OUTPUT_STATUS is kept in :attr:`Pilot.applied`) and waits for the
HIL_ACTUATOR_CONTROLS stamped with that tick's ``time_usec``. :class:`Pilot` is that
controller for the tests and the benchmarks, over our own
:class:`~tfl_mav.link.transport.Link` (so it signs when given a key, and counts what it
sends and receives in ``pilot.link.stats``). What it answers is a callable
``command(odometry, esc) -> controls`` (normalized thrusts in [0, 1], rotor order of the
ESC report); :func:`hover_controls` gives the usual constant hover.

Other traffic is sorted as it arrives: STATUSTEXT is reassembled into
:attr:`Pilot.statustexts`, COMMAND_ACK goes to :attr:`Pilot.acks`, HEARTBEAT to
:attr:`Pilot.heartbeats` (a POWEROFF or EMERGENCY one means the vehicle ended the run:
:attr:`Pilot.ended`). Waiting too long for a state raises :class:`NoStateError`, an
``AssertionError`` so that, in a test, a silent vehicle is a test failure with a message.
"""

from __future__ import annotations

import collections
import time
from collections.abc import Callable, Sequence
from typing import Any

from tfl_mav.link.codec import UNSENT, lite_class
from tfl_mav.link.dialect import mav
from tfl_mav.link.signing import Signing
from tfl_mav.link.transport import Address, FrameHook, Link

__all__ = ["Command", "NoStateError", "Pilot", "TickHook", "hover_controls", "hover_fraction"]

Command = Callable[[Any, Any], Sequence[float]]
"""``command(odometry, esc) -> controls``: normalized rotor thrusts in [0, 1]."""
TickHook = Callable[[int, Any, Any], bool | None]
"""``on_tick(k, odometry, esc)`` after the reply to new tick ``k`` (0-based) was sent;
returning True stops :meth:`Pilot.fly` there."""

ARMED = mav.MAV_MODE_FLAG_SAFETY_ARMED          # 128: the HIL_ACTUATOR_CONTROLS mode
_ENDS_RUN = (mav.MAV_STATE_POWEROFF, mav.MAV_STATE_EMERGENCY)
_STATUSTEXT_CHUNK = 50                           # characters per STATUSTEXT frame
_Controls = lite_class(mav.MAVLINK_MSG_ID_HIL_ACTUATOR_CONTROLS)
_ZERO_CONTROLS = (0.0,) * 16
_FLAGS = 1                                       # HIL_ACTUATOR_CONTROLS.flags: lockstep
_new = tuple.__new__


class NoStateError(AssertionError):
    """No state arrived in time (or the vehicle ended the run while one was awaited)."""


def hover_fraction(scenario: Any) -> float:
    """The normalized command (thrust / thrust_max) that holds the scenario's vehicle in
    hover: each rotor carries m·g/4."""
    v = scenario.vehicle
    return v.mass_kg * v.gravity_mps2 / 4.0 / v.thrust_max_n


def hover_controls(scenario: Any) -> Command:
    """A :data:`Command` answering every state with hover on all four rotors."""
    controls = [hover_fraction(scenario)] * 4
    return lambda _odom, _esc: controls


class Pilot:
    """The controller side of the lockstep link. See the module docstring.

    ``vehicle``: the vehicle's control address. ``sysid``/``compid``: ours (the vehicle pins
    the first HEARTBEAT's sender). ``key``: a 32-byte MAVLink 2 signing key, or None for an
    unsigned link. ``bind``: our own address (default an ephemeral loopback port).
    ``on_frame``: the Link's frame hook (e.g. to capture what was sent).
    """

    def __init__(self, vehicle: Address, *, sysid: int = 1, compid: int = 191,
                 key: bytes | None = None, bind: Address | None = None,
                 on_frame: FrameHook | None = None) -> None:
        self.link = Link.connect(vehicle, src_system=sysid, src_component=compid, bind=bind,
                                 signing=Signing(key) if key is not None else None,
                                 on_frame=on_frame)
        self.queue: collections.deque[Any] = collections.deque()   # ODOMETRY, ESC, ...
        self.statustexts: list[str] = []
        self.acks: list[Any] = []
        self.heartbeats: list[Any] = []
        self.ended = False            # the vehicle said POWEROFF or EMERGENCY
        self.last_usec = -1           # time_usec of the newest state answered
        self.applied: Any = None      # the last state's ACTUATOR_OUTPUT_STATUS
        self._chunks: dict[int, list[str]] = {}

    # ------------------------------------------------------------------ link
    def hello(self) -> None:
        """Send our HEARTBEAT: the lockstep vehicle starts its clock on it."""
        self.link.send(mav.MAVLink_heartbeat_message(
            mav.MAV_TYPE_ONBOARD_CONTROLLER, mav.MAV_AUTOPILOT_INVALID, 0, 0, 0, 3))

    def pump(self, timeout_s: float, *, drain: bool = True) -> None:
        """Receive for up to ``timeout_s`` and sort what came (see the module docstring);
        ``drain=False``: only the first datagram (a caller that loops saves the read that
        finds the queue empty)."""
        for m in self.link.recv(timeout_s, drain=drain):
            kind = m.get_type()
            if kind == "STATUSTEXT":
                self._statustext(m)
            elif kind == "COMMAND_ACK":
                self.acks.append(m)
            elif kind == "HEARTBEAT":
                self.heartbeats.append(m)
                if m.system_status in _ENDS_RUN:
                    self.ended = True
            else:
                self.queue.append(m)

    def _statustext(self, m: Any) -> None:
        """Reassemble chunked STATUSTEXT (id ≠ 0; a chunk under 50 characters ends it)."""
        if m.id == 0:
            self.statustexts.append(m.text)
            return
        self._chunks.setdefault(m.id, []).append(m.text)
        if len(m.text) < _STATUSTEXT_CHUNK:
            self.statustexts.append("".join(self._chunks.pop(m.id)))

    # ------------------------------------------------------------------ lockstep
    def state(self, timeout_s: float = 3.0) -> tuple[Any, Any]:
        """The next (ODOMETRY, ESC_TELEMETRY_1_TO_4) pair; :class:`NoStateError` if none
        within ``timeout_s`` or the vehicle ended the run with none left to read."""
        deadline = time.monotonic() + timeout_s
        while True:
            while len(self.queue) >= 3:
                odom = self.queue.popleft()
                if odom.get_type() != "ODOMETRY":
                    continue
                applied = self.queue.popleft()
                if applied.get_type() != "ACTUATOR_OUTPUT_STATUS":
                    raise NoStateError(f"ODOMETRY followed by {applied.get_type()}, not "
                                       "ACTUATOR_OUTPUT_STATUS")
                self.applied = applied
                esc = self.queue.popleft()
                if esc.get_type() != "ESC_TELEMETRY_1_TO_4":
                    raise NoStateError(f"ODOMETRY followed by {esc.get_type()}, not the ESC report")
                return odom, esc
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                raise NoStateError(f"no state from the vehicle within {timeout_s} s")
            if self.ended and not self.queue:
                raise NoStateError("no state from the vehicle: it ended the run")
            self.pump(min(remaining, 0.05) if self.ended else remaining, drain=False)

    def reply(self, odom: Any, controls: Sequence[float], mode: int = ARMED,
              time_usec: int | None = None) -> None:
        """Send HIL_ACTUATOR_CONTROLS for ``odom``'s tick (or ``time_usec``); ``controls``
        fill the first channels, the rest of the 16 are 0. ``mode`` 0 disarms."""
        t = odom.time_usec if time_usec is None else time_usec
        # Built as the codec's wire tuple (time_usec, flags, controls[16], mode): the bytes
        # of pymavlink's message, without its constructor (this is the bare client).
        self.link.send(_new(_Controls, (t, _FLAGS, *(*controls, *_ZERO_CONTROLS)[:16], mode,
                                        UNSENT)))

    def fly(self, n_ticks: int | None, command: Command, *, timeout_s: float = 3.0,
            keep: bool = True, on_tick: TickHook | None = None) -> list[tuple[Any, Any]]:
        """Answer states with ``command(odom, esc)`` for ``n_ticks`` new ticks (None: until
        the vehicle ends the run); return the (ODOMETRY, ESC) pairs of the new ticks
        (none if not ``keep``, for long benchmark runs).

        A state resent by the vehicle (its time_usec not newer than the last answered: our
        reply was lost) is answered again but is not a new tick. ``timeout_s`` bounds the
        wait for each state (:class:`NoStateError`).
        """
        out: list[tuple[Any, Any]] = []
        k = 0
        while n_ticks is None or k < n_ticks:
            if n_ticks is None and self.ended and len(self.queue) < 3:
                break
            try:
                odom, esc = self.state(timeout_s)
            except NoStateError:
                if n_ticks is None and self.ended:
                    break
                raise
            self.reply(odom, command(odom, esc))
            if odom.time_usec <= self.last_usec:
                continue
            self.last_usec = odom.time_usec
            if keep:
                out.append((odom, esc))
            k += 1
            if on_tick is not None and on_tick(k - 1, odom, esc):
                break
        return out

    def wait_ack(self, command: int, timeout_s: float = 3.0) -> Any:
        """The first COMMAND_ACK for ``command`` (removed from :attr:`acks`)."""
        deadline = time.monotonic() + timeout_s
        while True:
            for ack in self.acks:
                if ack.command == command:
                    self.acks.remove(ack)
                    return ack
            if time.monotonic() >= deadline:
                raise NoStateError(f"no COMMAND_ACK for {command}")
            self.pump(0.05)

    def close(self) -> None:
        self.link.close()

    def __enter__(self) -> Pilot:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
