"""What a ground station may ask of the vehicle: arm/disarm, mode, parameters, mission, home.

Registered into :class:`~tfl_mav.sitl.commands.CommandHandler`'s tables, so it is served on both
ports (the GCS port is where it is meant to be used; the control port answers the same).

**Modes** use PX4's ``custom_mode`` encoding (``main_mode << 16 | sub_mode << 24``) with
``MAV_AUTOPILOT_PX4`` in HEARTBEAT, because the offboard link is PX4-style: MAVProxy and
mavsdk then show ``OFFBOARD``/``Offboard``. The vehicle has no on-board flight controller,
so OFFBOARD (the offboard controller flies) is the one mode it can honour;
``MAV_CMD_DO_SET_MODE`` or ``SET_MODE`` to OFFBOARD is ACCEPTED, any other mode DENIED with
a STATUSTEXT naming it.

**Arm/disarm** (``MAV_CMD_COMPONENT_ARM_DISARM``): disarm is the kill switch: the motors
are commanded to zero thrust at once and stay off, whatever the controller sends, until a
GCS arms again (then the controller's armed bit decides, as before). PX4's rule for a
disarm in the air applies: it is DENIED (with a STATUSTEXT saying why and how to force it)
unless ``param2`` is the force code 21196 (PX4 Commander: "Disarming denied: not landed";
one stray disarm flips a flying quadrotor in ~0.1 s). The simulated vehicle has no ground
contact: it is airborne from the start (the scenario's initial position) and its run ends
when it reaches the ground, so here every disarm is one in the air. On a signed vehicle
only signed commands reach here (:mod:`tfl_mav.link.signing`).

**Parameters** are read-only: ``PARAM_REQUEST_LIST``/``PARAM_REQUEST_READ`` answer the
scenario's ``[vehicle]`` and ``[attack]`` numbers (``V_``/``A_`` + the key, upper case, at
most 16 characters; list entries get ``_1``…; all ``MAV_PARAM_TYPE_REAL32``);
``PARAM_SET`` gets a PARAM_VALUE with the unchanged value and a STATUSTEXT saying how to
change it (``--set``).

**Mission**: there is none. ``MISSION_REQUEST_LIST`` → ``MISSION_COUNT`` 0; an upload
(``MISSION_COUNT`` > 0) → ``MISSION_ACK`` UNSUPPORTED; ``MISSION_CLEAR_ALL`` → ACCEPTED.

**Home**: ``HOME_POSITION`` (the configurable origin) on ``MAV_CMD_GET_HOME_POSITION`` or
``MAV_CMD_REQUEST_MESSAGE`` 242; ``AUTOPILOT_VERSION`` on ``MAV_CMD_REQUEST_MESSAGE`` 148.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

from tfl_mav.link.dialect import mav
from tfl_mav.link.transport import Link
from tfl_mav.scenario import Scenario
from tfl_mav.sitl.clock import HeldCommand
from tfl_mav.sitl.gcs import (
    PX4_MAIN_MODE_NAMES,
    PX4_MAIN_OFFBOARD,
    FlightStatus,
    Origin,
    StatusText,
    home_position,
)
from tfl_mav.sitl.results import VehicleStats
from tfl_mav.sitl.simulator import Simulator

__all__ = ["FORCE_DISARM", "GroundCommands", "scenario_parameters"]

_REAL32 = mav.MAV_PARAM_TYPE_REAL32
_PARAM_ID_LEN = 16
FORCE_DISARM = 21196.0
"""MAV_CMD_COMPONENT_ARM_DISARM.param2 that forces a disarm in the air (PX4, ArduPilot)."""


def scenario_parameters(scenario: Scenario) -> list[tuple[str, float]]:
    """The scenario's numeric ``[vehicle]`` and ``[attack]`` keys as (param id, value)."""
    out: list[tuple[str, float]] = []
    for prefix, section in (("V_", scenario.vehicle), ("A_", scenario.attack)):
        for f in dataclasses.fields(section):
            value = getattr(section, f.name)
            base = (prefix + f.name.upper())
            if isinstance(value, (list, tuple)):
                items = [(f"{base[:_PARAM_ID_LEN - 2]}_{i + 1}", v)
                         for i, v in enumerate(value)]
            else:
                items = [(base[:_PARAM_ID_LEN], value)]
            for name, v in items:
                if isinstance(v, bool) or not isinstance(v, (int, float)):
                    continue   # strings (attack.signal) have no MAVLink parameter type
                out.append((name, float(v)))
    names = [n for n, _ in out]
    if len(set(names)) != len(names):
        raise ValueError(f"parameter names collide after truncation: {names}")
    return out


class GroundCommands:
    """The handlers; :meth:`register` puts them into a CommandHandler's tables."""

    def __init__(self, scenario: Scenario, sim: Simulator, *, flight: FlightStatus,
                 stats: VehicleStats, status: StatusText, origin: Origin,
                 sysid: int, compid: int, held: HeldCommand) -> None:
        self.sim = sim
        self.flight = flight
        self.held = held
        self.stats = stats
        self.status = status
        self.origin = origin
        self.sysid = sysid
        self.compid = compid
        self.params = scenario_parameters(scenario)
        self._index = {name: i for i, (name, _) in enumerate(self.params)}

    def register(self, handler: Any) -> None:
        handler.commands.update({
            mav.MAV_CMD_COMPONENT_ARM_DISARM: self.arm_disarm,
            mav.MAV_CMD_DO_SET_MODE: self.do_set_mode,
            mav.MAV_CMD_GET_HOME_POSITION: self.get_home_position,
            mav.MAV_CMD_REQUEST_MESSAGE: self.request_message,
        })
        handler.routes.update({
            mav.MAVLINK_MSG_ID_SET_MODE: self.on_set_mode,
            mav.MAVLINK_MSG_ID_PARAM_REQUEST_LIST: self.on_param_request_list,
            mav.MAVLINK_MSG_ID_PARAM_REQUEST_READ: self.on_param_request_read,
            mav.MAVLINK_MSG_ID_PARAM_SET: self.on_param_set,
            mav.MAVLINK_MSG_ID_MISSION_REQUEST_LIST: self.on_mission_request_list,
            mav.MAVLINK_MSG_ID_MISSION_COUNT: self.on_mission_count,
            mav.MAVLINK_MSG_ID_MISSION_CLEAR_ALL: self.on_mission_clear_all,
        })
        self._ack = handler.ack

    def _ours(self, msg: Any, component: bool = True) -> bool:
        """Addressed to us (MAVLink routing; not counted: only commands are)."""
        return msg.target_system in (0, self.sysid) and (
            not component or msg.target_component in (0, self.compid))

    # ------------------------------------------------------------------ arm / disarm
    def arm_disarm(self, link: Link, msg: Any) -> None:
        """param1 1 = arm, 0 = disarm (the kill switch: motors off now, latched); in the
        air a disarm needs param2 = 21196 (:data:`FORCE_DISARM`)."""
        flight = self.flight
        if msg.param1 == 0.0 and msg.param2 != FORCE_DISARM:
            self.stats.commands_denied += 1
            self._ack(link, msg, mav.MAV_RESULT_DENIED)
            altitude_m = self.sim.state_vector[2]
            self.status.send(mav.MAV_SEVERITY_CRITICAL,
                             f"disarm denied: in the air ({altitude_m:.2f} m above ground, "
                             f"t = {self.sim.time_s:.3f} s), it would fall; param2 = 21196 "
                             "forces it (motors off at once)", key="disarm")
        elif msg.param1 == 0.0:
            flight.killed = True
            self.held.killed = True      # what the motors hold from now: zero
            self.sim.set_command([0.0, 0.0, 0.0, 0.0])
            self.stats.commands_accepted += 1
            self._ack(link, msg, mav.MAV_RESULT_ACCEPTED)
            link.send(flight.heartbeat())   # show the new state now, not within 1 s
            self.status.send(mav.MAV_SEVERITY_CRITICAL,
                             f"disarmed by the GCS at t = {self.sim.time_s:.3f} s: motors off "
                             "until a GCS arms again")
        elif msg.param1 == 1.0:
            was_killed = flight.killed
            flight.killed = False
            self.stats.commands_accepted += 1
            self._ack(link, msg, mav.MAV_RESULT_ACCEPTED)
            link.send(flight.heartbeat())
            self.status.send(mav.MAV_SEVERITY_NOTICE,
                             "armed by the GCS: the controller's commands drive the motors"
                             + (" again" if was_killed else ""))
        else:
            self.stats.commands_denied += 1
            self._ack(link, msg, mav.MAV_RESULT_DENIED)
            self.status.send(mav.MAV_SEVERITY_ERROR, "MAV_CMD_COMPONENT_ARM_DISARM.param1: "
                                                     f"must be 0 or 1, got {msg.param1}")

    # ------------------------------------------------------------------ modes
    def do_set_mode(self, link: Link, msg: Any) -> None:
        """param1 base mode (CUSTOM_MODE_ENABLED), param2 PX4 main mode, param3 sub mode."""
        values = [_small_int(msg.param1), _small_int(msg.param2), _small_int(msg.param3)]
        if None in values:
            self.stats.commands_denied += 1
            self._ack(link, msg, mav.MAV_RESULT_DENIED)
            self.status.send(mav.MAV_SEVERITY_ERROR, "MAV_CMD_DO_SET_MODE.param1-3: must be "
                                                     "whole numbers 0-255", key="mode")
            return
        ok = self._set_mode(*values)
        self.stats.commands_accepted += ok
        self.stats.commands_denied += not ok
        self._ack(link, msg, mav.MAV_RESULT_ACCEPTED if ok else mav.MAV_RESULT_DENIED)

    def on_set_mode(self, link: Link, msg: Any) -> None:
        """SET_MODE (deprecated, still sent by some GCSs): no COMMAND_ACK, the HEARTBEAT
        shows the outcome."""
        if not self._ours(msg, component=False):
            return
        custom = msg.custom_mode
        self._set_mode(msg.base_mode, (custom >> 16) & 0xFF, (custom >> 24) & 0xFF)

    def _set_mode(self, base_mode: int, main: int, sub: int) -> bool:
        if base_mode & mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED and main == PX4_MAIN_OFFBOARD:
            if self.flight.main_mode != PX4_MAIN_OFFBOARD:
                self.flight.main_mode = PX4_MAIN_OFFBOARD
                self.status.send(mav.MAV_SEVERITY_INFO, "mode OFFBOARD")
            return True
        name = (PX4_MAIN_MODE_NAMES.get(main, f"main mode {main}")
                if base_mode & mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
                else f"base mode {base_mode} without a custom mode")
        self.status.send(mav.MAV_SEVERITY_WARNING,
                         f"mode {name} denied: only OFFBOARD (the offboard controller flies); "
                         "disarm stops the motors", key="mode")
        return False

    # ------------------------------------------------------------------ home, version
    def get_home_position(self, link: Link, msg: Any) -> None:
        self.stats.commands_accepted += 1
        self._ack(link, msg, mav.MAV_RESULT_ACCEPTED)
        link.send(home_position(self.origin, self.sim.time_usec))

    def request_message(self, link: Link, msg: Any) -> None:
        """MAV_CMD_REQUEST_MESSAGE for HOME_POSITION or AUTOPILOT_VERSION."""
        wanted = _small_int(msg.param1, 0xFFFFFF)
        if wanted == mav.MAVLINK_MSG_ID_HOME_POSITION:
            reply = home_position(self.origin, self.sim.time_usec)
        elif wanted == mav.MAVLINK_MSG_ID_AUTOPILOT_VERSION:
            caps = (mav.MAV_PROTOCOL_CAPABILITY_MAVLINK2
                    | mav.MAV_PROTOCOL_CAPABILITY_PARAM_FLOAT
                    | mav.MAV_PROTOCOL_CAPABILITY_MISSION_INT)   # mavsdk needs it to ask
            reply = mav.MAVLink_autopilot_version_message(caps, 0, 0, 0, 0, [0] * 8, [0] * 8,
                                                          [0] * 8, 0, 0, 0)
        else:
            self.stats.commands_unsupported += 1
            self._ack(link, msg, mav.MAV_RESULT_UNSUPPORTED)
            return
        self.stats.commands_accepted += 1
        self._ack(link, msg, mav.MAV_RESULT_ACCEPTED)
        link.send(reply)

    # ------------------------------------------------------------------ parameters
    def _param_value(self, index: int) -> Any:
        name, value = self.params[index]
        return mav.MAVLink_param_value_message(name.encode(), value, _REAL32, len(self.params),
                                               index)

    def on_param_request_list(self, link: Link, msg: Any) -> None:
        if self._ours(msg):
            for i in range(len(self.params)):
                link.send(self._param_value(i))

    def on_param_request_read(self, link: Link, msg: Any) -> None:
        if not self._ours(msg):
            return
        index = msg.param_index if msg.param_index >= 0 else self._index.get(
            _param_id(msg.param_id), -1)
        if 0 <= index < len(self.params):
            link.send(self._param_value(index))
        else:
            self.status.send(mav.MAV_SEVERITY_WARNING,
                             f"PARAM_REQUEST_READ: no parameter {_param_id(msg.param_id)!r} "
                             f"(index {msg.param_index})", key="param")

    def on_param_set(self, link: Link, msg: Any) -> None:
        if not self._ours(msg):
            return
        name = _param_id(msg.param_id)
        index = self._index.get(name)
        if index is None:
            self.status.send(mav.MAV_SEVERITY_WARNING, f"PARAM_SET: no parameter {name!r}",
                             key="param")
            return
        link.send(self._param_value(index))
        self.status.send(mav.MAV_SEVERITY_WARNING,
                         f"PARAM_SET {name} refused: parameters are read-only; restart the "
                         "sim with --set (e.g. --set vehicle.mass_kg=1.2)", key="param")

    # ------------------------------------------------------------------ mission
    def on_mission_request_list(self, link: Link, msg: Any) -> None:
        if self._ours(msg):
            link.send(mav.MAVLink_mission_count_message(
                msg.get_srcSystem(), msg.get_srcComponent(), 0,
                getattr(msg, "mission_type", 0)))

    def on_mission_count(self, link: Link, msg: Any) -> None:
        if not self._ours(msg):
            return
        self.status.send(mav.MAV_SEVERITY_WARNING, "mission upload refused: this vehicle "
                                                   "flies the scenario's path only",
                         key="mission")
        link.send(mav.MAVLink_mission_ack_message(
            msg.get_srcSystem(), msg.get_srcComponent(), mav.MAV_MISSION_UNSUPPORTED,
            getattr(msg, "mission_type", 0)))

    def on_mission_clear_all(self, link: Link, msg: Any) -> None:
        if self._ours(msg):
            link.send(mav.MAVLink_mission_ack_message(
                msg.get_srcSystem(), msg.get_srcComponent(), mav.MAV_MISSION_ACCEPTED,
                getattr(msg, "mission_type", 0)))


def _param_id(raw: Any) -> str:
    text = raw.decode("ascii", "replace") if isinstance(raw, bytes) else str(raw)
    return text.split("\0", 1)[0]




def _small_int(value: float, limit: int = 0xFF) -> int | None:
    """A COMMAND_LONG float parameter holding a whole number in [0, limit], or None."""
    if not math.isfinite(value) or value != math.floor(value) or not 0 <= value <= limit:
        return None
    return int(value)
