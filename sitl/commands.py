"""What the vehicle accepts: rotor commands and COMMAND_LONG/COMMAND_INT.

**Rotor commands** (:class:`ActuatorControls`). ``HIL_ACTUATOR_CONTROLS``:
``controls[0..3]`` = rotor thrust / f_max in [0, 1] (rotor i+1 on index i; indices 4-15 are
ignored); ``mode`` bit 128 (armed) clear commands zero thrust. A NaN/inf or a value outside
[0, 1] by more than :data:`CONTROL_TOLERANCE` is rejected whole and counted
(``rejected_controls``): the motors keep the previous command, and in lockstep the reply
still completes its tick (the vehicle holds the previous command for that tick, as real
hardware would). What is held and since when is :class:`~tfl_mav.sitl.clock.HeldCommand`.

**Commands** (:class:`CommandHandler`). ``COMMAND_LONG``/``COMMAND_INT``
``MAV_CMD_INJECT_FAILURE`` (param1 = 101 motor, param2 = failure type, param3 = rotor 1-4)
on either port starts the attack now and is answered ``COMMAND_ACK ACCEPTED``; bad
parameters get ``DENIED`` and a STATUSTEXT naming the field; any other command gets
``UNSUPPORTED``. Commands addressed to another system or component are not ours and are left
unanswered (MAVLink routing). A new message is a new entry in :attr:`CommandHandler.routes`
(message id → handler); a new ``MAV_CMD`` is a new entry in :attr:`CommandHandler.commands`
(command id → handler that sends its own ``COMMAND_ACK`` with :meth:`CommandHandler.ack`).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from enum import Enum
from typing import Any

from tfl_mav.link.codec import rx_lite_class
from tfl_mav.link.dialect import mav
from tfl_mav.link.transport import Link
from tfl_mav.sitl.attacker import FAILURE_TYPES
from tfl_mav.sitl.clock import HeldCommand
from tfl_mav.sitl.gcs import FlightStatus, StatusText
from tfl_mav.sitl.results import VehicleStats
from tfl_mav.sitl.simulator import Simulator

__all__ = ["CONTROL_TOLERANCE", "ActuatorControls", "CommandHandler", "Handler", "Outcome",
           "check_controls"]

CONTROL_TOLERANCE = 1e-4
"""Normalised controls within this of [0, 1] are clamped; beyond it they are rejected."""

_ARMED = mav.MAV_MODE_FLAG_SAFETY_ARMED
_RxControls = rx_lite_class(mav.MAVLINK_MSG_ID_HIL_ACTUATOR_CONTROLS)
_LO, _HI = -CONTROL_TOLERANCE, 1.0 + CONTROL_TOLERANCE
# on_controls reads the link's tuple by index: time_usec at 0, mode at 18
assert (_RxControls.time_usec.fget(tuple(range(20))), _RxControls.mode.fget(tuple(range(20)))) \
    == (0, 18)

Handler = Callable[[Link, Any], None]
"""Handles one received message (or one COMMAND_LONG/INT) from the given port."""


class Outcome(Enum):
    """What :meth:`ActuatorControls.on_controls` did with a HIL_ACTUATOR_CONTROLS."""

    APPLIED = 0
    REJECTED = 1   # bad values: previous command held (in lockstep the tick still completes)
    STALE = 2      # not the awaited time_usec (lockstep) / older than the held one (real time)


# Enum members read through the class cost ~10× a global in CPython 3.11 (every tick)
_APPLIED, _REJECTED, _STALE = Outcome.APPLIED, Outcome.REJECTED, Outcome.STALE


class ActuatorControls:
    """Validates HIL_ACTUATOR_CONTROLS and applies it to the simulator's rotors."""

    def __init__(self, sim: Simulator, *, stats: VehicleStats, held: HeldCommand,
                 flight: FlightStatus, status: StatusText) -> None:
        self.sim = sim
        self.stats = stats
        self.held = held
        self.flight = flight
        self.status = status

    def on_controls(self, msg: Any, awaited_usec: int | None) -> Outcome:
        """Validate and apply one HIL_ACTUATOR_CONTROLS. Lockstep (``awaited_usec`` given):
        only the awaited time_usec counts. Real time: newest wins (an older or repeated
        time_usec is stale), never the future; one applied after its own tick is late."""
        stats = self.stats
        held = self.held
        rx = type(msg) is _RxControls   # the link's tuple: time_usec, flags, controls[16], mode
        t = msg[0] if rx else msg.time_usec
        if awaited_usec is not None:
            if t != awaited_usec:
                if t == held.time_usec:    # the answer to a resent state, already applied
                    stats.duplicate_controls += 1
                    return _STALE
                stats.stale_controls += 1
                self.status.send(mav.MAV_SEVERITY_WARNING,
                                 f"HIL_ACTUATOR_CONTROLS.time_usec: {t} is not the awaited "
                                 f"{awaited_usec}; ignored", key="stale")
                return _STALE
        elif t <= held.time_usec or t > self.sim.time_usec:
            # Older than (or a duplicate of) the held one, or for a tick not yet sent.
            stats.stale_controls += 1
            return _STALE
        c1, c2, c3, c4 = msg[2:6] if rx else msg.controls[:4]   # no 16-item list built
        # In range → finite (comparisons with NaN are False): one chained test for the norm.
        problem = (None if _LO <= c1 <= _HI and _LO <= c2 <= _HI and _LO <= c3 <= _HI
                   and _LO <= c4 <= _HI else check_controls((c1, c2, c3, c4)))
        if problem is not None:
            stats.rejected_controls += 1
            self.status.send(mav.MAV_SEVERITY_ERROR,
                             f"HIL_ACTUATOR_CONTROLS.{problem}; rejected, previous command held",
                             key="rejected_controls")
            return _REJECTED
        held.time_usec = t
        sim = self.sim
        age_usec = sim.time_usec - t    # > 0: its own tick was already integrated
        stats.command_age.add(age_usec)
        if age_usec > 0:
            stats.late_controls += 1
        flight = self.flight
        armed = bool((msg[18] if rx else msg.mode) & _ARMED)
        held.armed = armed
        if armed != flight.armed:
            flight.armed = armed
            self.status.send(mav.MAV_SEVERITY_NOTICE,
                             "armed by the controller" if armed else
                             "disarmed by the controller (mode bit 128 clear): motors stopped")
        fmax = sim.thrust_max_n
        held.killed = flight.killed
        if armed and not flight.killed:   # a GCS disarm (kill switch) outranks the controller
            sim.set_command_floats(c1 * fmax, c2 * fmax, c3 * fmax, c4 * fmax)
        else:
            sim.set_command([0.0, 0.0, 0.0, 0.0])
        stats.controls_applied += 1
        if held.motors_cut:
            held.motors_cut = False
            flight.system_status = mav.MAV_STATE_ACTIVE
            self.status.send(mav.MAV_SEVERITY_NOTICE, "commands resumed: motors restored")
        held.since_s = time.monotonic()
        return _APPLIED

    def cut_motors(self, silent_s: float, timeout_s: float) -> None:
        """Real time link loss: zero thrust, like an ESC whose signal stopped."""
        self.stats.command_timeouts += 1
        self.held.motors_cut = True
        self.flight.system_status = mav.MAV_STATE_EMERGENCY
        self.sim.set_command([0.0, 0.0, 0.0, 0.0])
        self.status.send(mav.MAV_SEVERITY_EMERGENCY,
                         f"link loss: no valid HIL_ACTUATOR_CONTROLS for {silent_s:.3f} s "
                         f"(> {timeout_s:g} s): motors cut")


class CommandHandler:
    """COMMAND_LONG / COMMAND_INT on either port: answer what we support, refuse the rest."""

    def __init__(self, sim: Simulator, *, stats: VehicleStats, status: StatusText,
                 sysid: int, compid: int, allow_failure_injection: bool) -> None:
        self.sim = sim
        self.stats = stats
        self.status = status
        self.sysid = sysid
        self.compid = compid
        self.allow_failure_injection = allow_failure_injection
        self._last_inject: tuple[Any, ...] | None = None   # (src sys, src comp, params)
        self.routes: dict[int, Handler] = {
            mav.MAVLINK_MSG_ID_COMMAND_LONG: self.on_command,
            mav.MAVLINK_MSG_ID_COMMAND_INT: self.on_command,
        }
        """Message id → handler, for the messages served on both ports."""
        self.commands: dict[int, Handler] = {
            mav.MAV_CMD_INJECT_FAILURE: self.inject_failure,
        }
        """``MAV_CMD_*`` → handler; each sends its own COMMAND_ACK."""

    def on_command(self, link: Link, msg: Any) -> None:
        """One COMMAND_LONG / COMMAND_INT: ours and supported → its handler."""
        if msg.target_system not in (0, self.sysid) or msg.target_component not in (
                0, self.compid):
            self.stats.commands_not_for_us += 1
            return
        handler = self.commands.get(msg.command)
        if handler is None:
            self.stats.commands_unsupported += 1
            self.ack(link, msg, mav.MAV_RESULT_UNSUPPORTED)
            return
        handler(link, msg)

    def ack(self, link: Link, msg: Any, result: int) -> None:
        """COMMAND_ACK for ``msg`` back to its sender."""
        link.send(mav.MAVLink_command_ack_message(msg.command, result, 0, 0,
                                                  msg.get_srcSystem(), msg.get_srcComponent()))

    def inject_failure(self, link: Link, msg: Any) -> None:
        """MAV_CMD_INJECT_FAILURE: start (or, type 0, clear) the attack on a rotor now."""
        stats = self.stats
        params = (msg.param1, msg.param2, msg.param3)
        key = (msg.get_srcSystem(), msg.get_srcComponent(), *params)
        if getattr(msg, "confirmation", 0) > 0 and key == self._last_inject:
            self.ack(link, msg, mav.MAV_RESULT_ACCEPTED)   # retransmission: already applied
            return
        try:
            rotor, failure_type = self._inject(*params)
        except ValueError as exc:
            stats.commands_denied += 1
            self.status.send(mav.MAV_SEVERITY_ERROR, f"MAV_CMD_INJECT_FAILURE denied: {exc}")
            self.ack(link, msg, mav.MAV_RESULT_DENIED)
            return
        self._last_inject = key
        stats.commands_accepted += 1
        self.ack(link, msg, mav.MAV_RESULT_ACCEPTED)
        if failure_type == 0:
            self.status.send(mav.MAV_SEVERITY_NOTICE,
                             f"failure cleared: rotor {rotor} at t = {self.sim.time_s:.3f} s")
            return
        stats.failures_injected += 1
        self.status.send(mav.MAV_SEVERITY_WARNING,
                         f"failure injected: rotor {rotor} "
                         f"{FAILURE_TYPES[failure_type].upper()} at t = {self.sim.time_s:.3f} s")

    def _inject(self, param1: float, param2: float, param3: float) -> tuple[int, int]:
        """Validate MAV_CMD_INJECT_FAILURE's parameters and start the attack; ValueError
        naming the parameter otherwise."""
        if not self.allow_failure_injection:
            raise ValueError("failure injection is disabled on this vehicle")
        unit = _whole(param1, "param1 (failure unit)")
        if unit != mav.FAILURE_UNIT_SYSTEM_MOTOR:
            raise ValueError(f"param1 (failure unit): only {mav.FAILURE_UNIT_SYSTEM_MOTOR} "
                             f"(FAILURE_UNIT_SYSTEM_MOTOR) is supported, got {unit}")
        failure_type = _whole(param2, "param2 (failure type)")
        rotor = _whole(param3, "param3 (instance)")
        self.sim.inject_failure(rotor, failure_type)
        return rotor, failure_type


def check_controls(controls: Any) -> str | None:
    """The first problem with controls[0..3] ("controls[2]: not finite (nan)"), or None."""
    lo, hi = -CONTROL_TOLERANCE, 1.0 + CONTROL_TOLERANCE
    for i in range(4):
        c = controls[i]
        if not math.isfinite(c):
            return f"controls[{i}]: not finite ({c})"
        if c < lo or c > hi:
            return f"controls[{i}]: {c:.6g} outside [0, 1]"
    return None


def _whole(value: float, name: str) -> int:
    """A COMMAND_LONG float parameter that must hold a whole number."""
    if not math.isfinite(value) or value != math.floor(value):
        raise ValueError(f"{name}: must be a whole number, got {value}")
    return int(value)
