"""Reference models of what the link, the vehicle and the daemon count for each datagram."""

from __future__ import annotations

import math
import struct
from collections import Counter
from typing import Any

from tfl_mav.link.dialect import mav, new_mavlink
from tfl_mav.tools.harness.fuzz.wire import (
    _MAGIC_V1,
    _MAGIC_V2,
    _SIG_LEN,
    _SIGNED,
    FUZZER_SYSID,
    VEHICLE_SYSID,
    crc_extra,
)


# ---------------------------------------------------------------------------- models
class LinkModel:
    """Reference model of :class:`~tfl_mav.link.transport.Link`'s documented accounting for
    datagrams from the (already known) peer address: a list of outcomes per datagram, each
    a reason string or an accepted, decoded message."""

    def __init__(self, peer_sysid: int, own: tuple[int, int]) -> None:
        self.peer_sysid = peer_sysid
        self.own = own               # the endpoint's own (sysid, compid): a reflection
        self._unpacker = new_mavlink(255, 0)

    def outcomes(self, data: bytes) -> list[Any]:
        out: list[Any] = []
        n, i = len(data), 0
        while i < n:
            magic = data[i]
            if magic != _MAGIC_V2:
                out.append("mavlink1" if magic == _MAGIC_V1 else "garbage")
                break
            if n - i < 12:
                out.append("truncated")
                break
            incompat = data[i + 2]
            if incompat & ~_SIGNED:
                out.append("bad_flags")
                break
            end = i + 12 + data[i + 1] + (_SIG_LEN if incompat else 0)
            if end > n:
                out.append("truncated")
                break
            raw = data[i:end]
            i = end
            out.append("reflected" if (raw[5], raw[6]) == self.own
                       else self._frame(raw, incompat))
        return out

    def _frame(self, raw: bytes, incompat: int) -> Any:
        msgid = raw[7] | raw[8] << 8 | raw[9] << 16
        extra = crc_extra(msgid)
        if extra is None:
            return "unknown_id"
        crc_end = len(raw) - (_SIG_LEN if incompat else 0)
        want = mav.x25crc(raw[1:crc_end - 2] + bytes([extra])).crc
        if struct.unpack("<H", raw[crc_end - 2:crc_end])[0] != want:
            return "bad_crc"
        try:
            msg = self._unpacker.decode(bytearray(raw))
        except Exception:  # whatever pymavlink raises, the link says malformed
            return "malformed"
        if msg.get_srcSystem() != self.peer_sysid:
            return "wrong_sysid"
        return msg


class _EndpointModel:
    """What one endpoint counts for a datagram: the link's verdicts, then each accepted
    frame through the endpoint's own ``_message``."""

    link: LinkModel

    def expect(self, data: bytes) -> Counter[str]:
        c: Counter[str] = Counter()
        for outcome in self.link.outcomes(data):
            if isinstance(outcome, str):
                c[outcome] += 1
            else:
                c["rx_frames"] += 1
                self._message(outcome, c)
        return c

    def _message(self, msg: Any, c: Counter[str]) -> None:
        raise NotImplementedError


class VehicleModel(_EndpointModel):
    """What :class:`~tfl_mav.sitl.vehicle.Vehicle` counts for each datagram from its controller, in
    lockstep while it awaits ``awaited_usec`` (set to -1 once the tick is completed)."""

    def __init__(self, sysid: int = 1, compid: int = 1) -> None:
        self.link = LinkModel(FUZZER_SYSID, (sysid, compid))
        self.sysid, self.compid = sysid, compid
        self.awaited_usec = 0
        self.applied_usec = -1    # time_usec of the newest applied controls (held command)

    def save(self) -> Any:
        return self.awaited_usec, self.applied_usec

    def restore(self, saved: Any) -> None:
        self.awaited_usec, self.applied_usec = saved

    def _message(self, msg: Any, c: Counter[str]) -> None:
        mid = msg.get_msgId()
        if mid == mav.MAVLINK_MSG_ID_HIL_ACTUATOR_CONTROLS:
            if msg.time_usec != self.awaited_usec:
                # the answer to a tick already applied (a resent state's) is a duplicate
                c["duplicate_controls" if msg.time_usec == self.applied_usec
                  else "stale_controls"] += 1
                return
            ctl = msg.controls[:4]
            if all(math.isfinite(u) and -1e-4 <= u <= 1.0 + 1e-4 for u in ctl):
                c["controls_applied"] += 1
                self.applied_usec = msg.time_usec
                if not msg.mode & mav.MAV_MODE_FLAG_SAFETY_ARMED:
                    c["ends_run"] += 1      # disarmed: the vehicle would fall
            else:
                c["rejected_controls"] += 1
            self.awaited_usec = -1
        elif mid in (mav.MAVLINK_MSG_ID_COMMAND_LONG, mav.MAVLINK_MSG_ID_COMMAND_INT):
            if msg.target_system not in (0, self.sysid) or \
                    msg.target_component not in (0, self.compid):
                c["commands_not_for_us"] += 1
            elif msg.command in _GCS_COMMANDS:
                outcome = _gcs_command(msg)
                c[outcome] += 1
                if outcome == "commands_accepted" and msg.command == \
                        mav.MAV_CMD_COMPONENT_ARM_DISARM:
                    c["ends_run"] += 1      # a real disarm/arm: not bad input
            elif msg.command != mav.MAV_CMD_INJECT_FAILURE:
                c["commands_unsupported"] += 1
            elif _inject_ok(msg.param1, msg.param2, msg.param3):
                c["commands_accepted"] += 1
                c["ends_run"] += 1          # a real attack: not bad input
            else:
                c["commands_denied"] += 1


_GCS_COMMANDS = (mav.MAV_CMD_COMPONENT_ARM_DISARM, mav.MAV_CMD_DO_SET_MODE,
                 mav.MAV_CMD_REQUEST_MESSAGE, mav.MAV_CMD_GET_HOME_POSITION)


def _small_int(p: float, limit: int = 0xFF) -> int | None:
    ok = math.isfinite(p) and p == math.floor(p) and 0 <= p <= limit
    return int(p) if ok else None


def _gcs_command(msg: Any) -> str:
    """The counter a ground-station command lands in (tfl_mav.sitl.ground)."""
    cmd = msg.command
    if cmd == mav.MAV_CMD_COMPONENT_ARM_DISARM:
        # always airborne: a disarm needs the force code (tfl_mav.sitl.ground.FORCE_DISARM)
        ok = msg.param1 == 1.0 or (msg.param1 == 0.0 and msg.param2 == 21196.0)
        return "commands_accepted" if ok else "commands_denied"
    if cmd == mav.MAV_CMD_DO_SET_MODE:
        base, main = _small_int(msg.param1), _small_int(msg.param2)
        sub = _small_int(msg.param3)
        ok = (None not in (base, main, sub) and base & mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
              and main == 6)
        return "commands_accepted" if ok else "commands_denied"
    if cmd == mav.MAV_CMD_REQUEST_MESSAGE:
        wanted = _small_int(msg.param1, 0xFFFFFF)
        return ("commands_accepted" if wanted in (mav.MAVLINK_MSG_ID_HOME_POSITION,
                                                 mav.MAVLINK_MSG_ID_AUTOPILOT_VERSION)
                else "commands_unsupported")
    return "commands_accepted"   # GET_HOME_POSITION


def _inject_ok(p1: float, p2: float, p3: float) -> bool:
    """MAV_CMD_INJECT_FAILURE parameters the vehicle accepts (docs/design.md;
    tfl_mav.sitl.attacker)."""
    whole = all(math.isfinite(p) and p == math.floor(p) for p in (p1, p2, p3))
    return whole and p1 == 101 and int(p2) in (0, 1, 2, 4, 8) and 1 <= p3 <= 4


class DaemonModel(_EndpointModel):
    """What :class:`~tfl_mav.controller.daemon.Daemon` (in lockstep) counts for each datagram from
    its vehicle, including how it classifies a complete state against its watermark."""

    def __init__(self) -> None:
        from tfl_mav.controller import arrivals
        from tfl_mav.model.frames import paper_from_odometry

        self.link = LinkModel(VEHICLE_SYSID, (1, mav.MAV_COMP_ID_ONBOARD_COMPUTER))
        self._paper = paper_from_odometry
        self._ahead = round(arrivals.AHEAD_S * 1e6)
        self._back = round(arrivals.BACKSTEP_S * 1e6)
        self._confirm = arrivals.JUMP_CONFIRM
        self._old_max = arrivals.RESTART_OLD_STATES
        self.pending: int | None = None     # time_usec of a state awaiting its ESC report
        self.watermark = -1
        self.jump = (-1, 0)                 # last implausible time, how many in a row
        self.old_in_row = 0

    def save(self) -> Any:
        return self.pending, self.watermark, self.jump, self.old_in_row

    def restore(self, saved: Any) -> None:
        self.pending, self.watermark, self.jump, self.old_in_row = saved

    def _complete(self, t: int, c: Counter[str]) -> None:
        """One complete state (tfl_mav.controller.daemon: Daemon._arrive). ``genuine``: the daemon
        would take it as the vehicle's (fresh, or a confirmed new time line)."""
        w = self.watermark
        if w >= 0:
            if t == w:
                c["repeated_states"] += 1
                self.jump = (-1, 0)
                return
            if w - self._back <= t < w:
                self.jump = (-1, 0)
                self.old_in_row += 1
                if self.old_in_row < self._old_max:
                    c["old_states"] += 1
                    return
                c["genuine"] += 1
            elif not w < t <= w + self._ahead:
                j, n = self.jump
                n = n + 1 if n > 0 and 0 <= t - j <= self._ahead else 1
                self.jump = (t, n)
                if n < self._confirm:
                    c["implausible_states"] += 1
                    return
                c["genuine"] += 1
        self.jump = (-1, 0)
        self.old_in_row = 0
        self.watermark = t
        c["ticks"] += 1
        c["genuine"] += 1

    def _message(self, msg: Any, c: Counter[str]) -> None:
        mid = msg.get_msgId()
        if mid == mav.MAVLINK_MSG_ID_ODOMETRY:
            try:
                self._paper(msg)
            except ValueError:
                c["bad_states"] += 1
                self.pending = None
                return
            c["states"] += 1
            self.pending = msg.time_usec
        elif mid == mav.MAVLINK_MSG_ID_ESC_TELEMETRY_1_TO_4:
            c["esc_reports"] += 1
            if self.pending is not None:
                t, self.pending = self.pending, None
                self._complete(t, c)
        elif mid == mav.MAVLINK_MSG_ID_HEARTBEAT:
            if msg.system_status in (mav.MAV_STATE_POWEROFF, mav.MAV_STATE_EMERGENCY):
                c["ends_run"] += 1
        elif mid not in (mav.MAVLINK_MSG_ID_STATUSTEXT,
                         mav.MAVLINK_MSG_ID_ACTUATOR_OUTPUT_STATUS):
            # ACTUATOR_OUTPUT_STATUS is used (the held command of the next complete state,
            # tfl_mav.controller.daemon_intake), not counted anywhere
            c["ignored_messages"] += 1
