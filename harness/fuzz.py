"""Fuzzing both UDP endpoints over real loopback sockets.

Shared by ``tests/test_fuzz.py`` (a small seeded set) and ``bench/bench_fuzz.py`` (≥ 100 000
inputs per endpoint). Nothing here is mocked: a real :class:`~sitl.vehicle.Vehicle` or
:class:`~tfl_mav.daemon.Daemon` runs in a thread on a loopback socket, and the fuzzer is its
pinned peer on another socket.

**How a run goes.** The fuzzer sends a valid HEARTBEAT first (so it becomes the peer), then
flies the endpoint in lockstep. Every tick it sends one *batch*: a few hostile datagrams of
one category, then one *completer* (vehicle side: the awaited ``HIL_ACTUATOR_CONTROLS`` at
hover; daemon side: a valid ODOMETRY + ESC_TELEMETRY_1_TO_4 datagram), and waits for the
endpoint's answer to the completer. Datagrams from one socket arrive in order, so when that
answer arrives the endpoint has handled the whole batch and its counters are quiescent:
the counters' change over the batch is exactly what the batch caused.

**Accounting, exactly.** :class:`LinkModel` is a reference model of the framing rules that
``tfl_mav/link/transport.py`` documents (MAVLink 2 only, one datagram at a time, nothing
carried over, reasons ``garbage``/``mavlink1``/``truncated``/``bad_flags``/``bad_crc``/
``malformed``/``unknown_id``/``wrong_sysid``); it checks the CRC itself and asks pymavlink
only to unpack payloads. :class:`VehicleModel` and :class:`DaemonModel` add what each
endpoint does with an accepted message (stale/rejected controls, commands not for us,
denied, unsupported; bad/good states, ESC reports, ticks, ignored messages). Per batch the
predicted counters must equal the endpoint's counters; ``mismatches`` lists every batch
where they do not. A datagram the kernel drops (``rx_datagrams`` short of what was sent) is
reported as ``lost`` and its batch is not compared.

**Invariants.** No exception escapes the endpoint's loop (``crashes``); no non-finite value
reaches physics (state, rotor commands and thrusts are checked at every tick through
``on_truth``) or a motor command (every ``HIL_ACTUATOR_CONTROLS`` the daemon sends is
checked through ``on_frame``: finite, in [0, 1]); and no non-finite float leaves either
endpoint in any frame.

Inputs the protocol defines as *ending* the run (a HEARTBEAT with MAV_STATE_POWEROFF or
EMERGENCY to the daemon, an accepted MAV_CMD_INJECT_FAILURE to the vehicle) are not sent:
they are legitimate commands, not bad input. Nor are states the daemon must take as
genuine: a state whose time is a plausible successor of the newest one (it would be
flown, and answered instead of the completer), or one that confirms a new time line (a
restart, see the daemon's "Restart"). They are counted in ``skipped``. The daemon's
``extreme_state`` batches are a single absurd state at the completer's time, flown by the
law (and answered, even when the law raises).
"""

from __future__ import annotations

import math
import random
import socket
import struct
import threading
import time
from collections import Counter
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import Any

from harness.pilot import NoStateError, Pilot
from tfl_mav.link.dialect import mav, new_mavlink

__all__ = [
    "DAEMON_CATEGORIES",
    "VEHICLE_CATEGORIES",
    "CategoryReport",
    "DaemonModel",
    "EndpointReport",
    "LinkModel",
    "VehicleModel",
    "fuzz_daemon",
    "fuzz_vehicle",
    "nonfinite_floats",
]

# Link-level rejection reasons, as named in LinkStats.
LINK_REASONS = ("garbage", "mavlink1", "truncated", "bad_flags", "bad_crc", "bad_signature",
                "malformed", "unknown_id", "foreign", "wrong_sysid", "no_peer")
VEHICLE_REJECTS = ("rejected_controls", "stale_controls", "duplicate_controls",
                   "commands_not_for_us", "commands_denied", "commands_unsupported")
VEHICLE_ACCEPTS = ("controls_applied", "commands_accepted")
DAEMON_REJECTS = ("bad_states", "implausible_states", "old_states", "repeated_states")
DAEMON_ACCEPTS = ("states", "esc_reports", "ticks", "ignored_messages")

MAX_UDP_PAYLOAD = 65507     # IPv4: 65535 − 20 (IP header) − 8 (UDP header)
_MAGIC_V2, _MAGIC_V1 = 0xFD, 0xFE
_SIGNED = 0x01
_SIG_LEN = 13
_FAR_USEC = 0xA5A5_A5A5_A5A5_A5A5   # never a lockstep time, even after a few bit flips
_NASTY_FLOATS = (math.nan, -math.nan, math.inf, -math.inf, 1e38, -1e38, 3.4e38, 1e-45,
                 -0.0, 1e30, -1e30)
_BAD_CONTROLS = (math.nan, math.inf, -math.inf, -0.5, 1.5, 1e30, -1e30, 1.0 + 2e-4,
                 -2e-4, 3.4e38)

STATE_TIMEOUT_S = 5.0       # an endpoint silent this long has stalled
FUZZER_SYSID = 42           # the fuzzer as a controller (vehicle side)
FUZZER_COMPID = 191
VEHICLE_SYSID = 1           # the fuzzer as a vehicle (daemon side)
VEHICLE_COMPID = 1


# ---------------------------------------------------------------------------- frames
def crc_extra(msgid: int) -> int | None:
    """The dialect's CRC_EXTRA for ``msgid``, or None if the id is unknown."""
    cls = mav.mavlink_map.get(msgid)
    return None if cls is None else cls.crc_extra


def frame_v2(msgid: int, payload: bytes, *, sysid: int, compid: int, seq: int = 0,
             extra: int | None = None, incompat: int = 0, signature: bytes = b"") -> bytes:
    """A MAVLink 2 frame built by hand, CRC over header + payload + ``extra`` (the
    message's CRC_EXTRA by default: pass one for an id the dialect does not know)."""
    if extra is None:
        extra = crc_extra(msgid)
        assert extra is not None, f"msgid {msgid} unknown: give extra"
    header = struct.pack("<BBBBBBBHB", _MAGIC_V2, len(payload), incompat, 0, seq & 0xFF,
                         sysid, compid, msgid & 0xFFFF, msgid >> 16)
    body = header[1:] + payload
    crc = mav.x25crc(body + bytes([extra])).crc
    return header + payload + struct.pack("<H", crc) + signature


def recompute_crc(raw: bytes, rng: random.Random) -> bytes:
    """Re-frame a (mutated) frame so its CRC is right for the msgid and length its header
    now claims: the mutation then reaches pymavlink's payload decoder."""
    if len(raw) < 10:
        return raw
    b = bytearray(raw)
    b[0] = _MAGIC_V2
    length, incompat = b[1], b[2]
    msgid = b[7] | b[8] << 8 | b[9] << 16
    payload = bytes(b[10:10 + length])
    payload += bytes(rng.randrange(256) for _ in range(length - len(payload)))
    extra = crc_extra(msgid)
    if extra is None:
        extra = rng.randrange(256)
    sig = bytes(rng.randrange(256) for _ in range(_SIG_LEN)) if incompat & _SIGNED else b""
    return frame_v2(msgid, payload, sysid=b[5], compid=b[6], seq=b[4], extra=extra,
                    incompat=incompat, signature=sig)


def mutate(raw: bytes, rng: random.Random) -> bytes:
    """1-4 mutations: bit flips, byte inserts/deletes, length or flags or msgid rewrites."""
    b = bytearray(raw)
    for _ in range(rng.randint(1, 4)):
        kind = rng.randrange(6)
        if kind == 0 and b:
            i = rng.randrange(len(b))
            b[i] ^= 1 << rng.randrange(8)
        elif kind == 1:
            i = rng.randrange(len(b) + 1)
            b[i:i] = bytes(rng.randrange(256) for _ in range(rng.randint(1, 3)))
        elif kind == 2 and len(b) > 1:
            i = rng.randrange(len(b))
            del b[i:i + rng.randint(1, 3)]
        elif kind == 3 and len(b) > 1:
            b[1] = rng.choice((0, 1, b[1] - 1 & 0xFF, b[1] + 1 & 0xFF, rng.randrange(256)))
        elif kind == 4 and len(b) > 2:
            b[2] = rng.choice((1, 2, 0x80, rng.randrange(256)))
        elif kind == 5 and len(b) > 9:
            b[7 + rng.randrange(3)] = rng.randrange(256)
    return bytes(b)


def nonfinite_floats(msg: Any) -> list[str]:
    """Names of float fields (and array elements) of a decoded message that are NaN/inf."""
    bad = []
    for name in msg.get_fieldnames():
        value = getattr(msg, name)
        if isinstance(value, float) and not math.isfinite(value):
            bad.append(name)
        elif isinstance(value, (list, tuple)):
            bad += [f"{name}[{i}]" for i, v in enumerate(value)
                    if isinstance(v, float) and not math.isfinite(v)]
    return bad


# ---------------------------------------------------------------------------- models
class LinkModel:
    """Reference model of :class:`~tfl_mav.link.transport.Link`'s documented accounting for
    datagrams from the (already known) peer address: a list of outcomes per datagram, each
    a reason string or an accepted, decoded message."""

    def __init__(self, peer_sysid: int) -> None:
        self.peer_sysid = peer_sysid
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
            out.append(self._frame(raw, incompat))
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
    """What :class:`~sitl.vehicle.Vehicle` counts for each datagram from its controller, in
    lockstep while it awaits ``awaited_usec`` (set to -1 once the tick is completed)."""

    def __init__(self, sysid: int = 1, compid: int = 1) -> None:
        self.link = LinkModel(FUZZER_SYSID)
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
    """The counter a ground-station command lands in (sitl.ground)."""
    cmd = msg.command
    if cmd == mav.MAV_CMD_COMPONENT_ARM_DISARM:
        return "commands_accepted" if msg.param1 in (0.0, 1.0) else "commands_denied"
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
    """MAV_CMD_INJECT_FAILURE parameters the vehicle accepts (docs/design.md; sitl.attacker)."""
    whole = all(math.isfinite(p) and p == math.floor(p) for p in (p1, p2, p3))
    return whole and p1 == 101 and int(p2) in (0, 1, 2, 4, 8) and 1 <= p3 <= 4


class DaemonModel(_EndpointModel):
    """What :class:`~tfl_mav.daemon.Daemon` (in lockstep) counts for each datagram from its
    vehicle, including how it classifies a complete state against its watermark."""

    def __init__(self) -> None:
        from tfl_mav import daemon
        from tfl_mav.frames import paper_from_odometry

        self.link = LinkModel(VEHICLE_SYSID)
        self._paper = paper_from_odometry
        self._ahead = round(daemon._AHEAD_S * 1e6)
        self._back = round(daemon._BACKSTEP_S * 1e6)
        self._confirm = daemon._JUMP_CONFIRM
        self._old_max = daemon._RESTART_OLD_STATES
        self.pending: int | None = None     # time_usec of a state awaiting its ESC report
        self.watermark = -1
        self.jump = (-1, 0)                 # last implausible time, how many in a row
        self.old_in_row = 0

    def save(self) -> Any:
        return self.pending, self.watermark, self.jump, self.old_in_row

    def restore(self, saved: Any) -> None:
        self.pending, self.watermark, self.jump, self.old_in_row = saved

    def _complete(self, t: int, c: Counter[str]) -> None:
        """One complete state (tfl_mav.daemon: Daemon._arrive). ``genuine``: the daemon
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
        elif mid != mav.MAVLINK_MSG_ID_STATUSTEXT:
            c["ignored_messages"] += 1


# ---------------------------------------------------------------------------- generators
class _Gen:
    """Datagram generators shared by both sides; ``sysid``/``compid`` are the fuzzer's."""

    def __init__(self, rng: random.Random, sysid: int, compid: int) -> None:
        self.rng = rng
        self.sysid, self.compid = sysid, compid
        self.mv = new_mavlink(sysid, compid)

    def pack(self, msg: Any, *, sysid: int | None = None, v1: bool = False) -> bytes:
        mv = self.mv if sysid is None else new_mavlink(sysid, self.compid)
        mv.seq = self.rng.randrange(256)
        return msg.pack(mv, force_mavlink1=v1)

    def randbytes(self, n: int) -> bytes:
        return self.rng.randbytes(n)

    def random(self) -> bytes:
        rng = self.rng
        data = self.randbytes(rng.randint(1, 300))
        if rng.random() < 0.4:      # past the magic check, into framing and CRC
            data = bytes([_MAGIC_V2]) + data[1:]
        return data

    def common(self, category: str, templates: list[Any]) -> bytes | None:
        """One datagram of a category both endpoints are fuzzed with (None: not one)."""
        if category == "random":
            return self.random()
        if category == "mutated":
            return self.mutated(templates, fix_crc=False)
        if category == "mutated_crc_ok":
            return self.mutated(templates, fix_crc=True)
        if category == "truncated":
            return self.truncated(templates)
        if category == "mavlink1":
            return self.mavlink1(templates)
        if category == "unknown_id":
            return self.unknown_id()
        if category == "random_known_id":
            return self.random_known()
        return None

    def truncated(self, templates: list[Any]) -> bytes:
        raw = self.pack(self.rng.choice(templates))
        cut = self.rng.randint(1, len(raw) - 1)
        if self.rng.random() < 0.3:   # a good frame, then a truncated one, one datagram
            return raw + raw[:cut]
        return raw[:cut]

    def oversize(self, templates: list[Any]) -> bytes:
        rng = self.rng
        size = rng.choice((MAX_UDP_PAYLOAD, rng.randint(1500, MAX_UDP_PAYLOAD)))
        kind = rng.randrange(3)
        if kind == 0:
            return self.randbytes(size)
        if kind == 1:
            return bytes([_MAGIC_V2]) + self.randbytes(size - 1)
        frame = self.pack(rng.choice(templates))   # valid frames, then a garbage tail
        data = frame * (size // len(frame))
        return data + self.randbytes(size - len(data))

    def mavlink1(self, templates: list[Any]) -> bytes:
        msg = self.rng.choice([m for m in templates if m.get_msgId() < 256])
        raw = self.pack(msg, v1=True)
        if self.rng.random() < 0.3:   # a v1 frame first poisons the rest of the datagram
            raw += self.pack(msg)
        return raw

    def mutated(self, templates: list[Any], fix_crc: bool) -> bytes:
        raw = mutate(self.pack(self.rng.choice(templates)), self.rng)
        return recompute_crc(raw, self.rng) if fix_crc else raw

    def unknown_id(self) -> bytes:
        rng = self.rng
        while True:
            msgid = rng.randrange(1 << 24) if rng.random() < 0.7 else rng.randrange(1 << 16)
            if msgid not in mav.mavlink_map:
                break
        signed = rng.random() < 0.2
        return frame_v2(msgid, self.randbytes(rng.randint(0, 255)), sysid=self.sysid,
                        compid=self.compid, seq=rng.randrange(256), extra=rng.randrange(256),
                        incompat=_SIGNED if signed else 0,
                        signature=self.randbytes(_SIG_LEN) if signed else b"")

    def nasty(self) -> float:
        return self.rng.choice(_NASTY_FLOATS)

    def random_known(self) -> bytes:
        """A known message id with a random payload and the right CRC: reaches decode."""
        rng = self.rng
        msgid = rng.choice(list(mav.mavlink_map))
        cls = mav.mavlink_map[msgid]
        size = cls.unpacker.size
        return frame_v2(msgid, self.randbytes(rng.randint(0, size)), sysid=self.sysid,
                        compid=self.compid, seq=rng.randrange(256))


class VehicleGen(_Gen):
    """Hostile controller traffic for the vehicle's control port."""

    def __init__(self, rng: random.Random, hover: float) -> None:
        super().__init__(rng, FUZZER_SYSID, FUZZER_COMPID)
        self.hover = hover

    def controls(self, time_usec: int, values: list[float], mode: int | None = None) -> Any:
        armed = mav.MAV_MODE_FLAG_SAFETY_ARMED
        return mav.MAVLink_hil_actuator_controls_message(
            time_usec, values, armed if mode is None else mode, 1)

    def hover_controls(self, time_usec: int) -> Any:
        return self.controls(time_usec, [self.hover] * 4 + [0.0] * 12)

    def templates(self) -> list[Any]:
        r = self.rng
        return [
            mav.MAVLink_heartbeat_message(mav.MAV_TYPE_ONBOARD_CONTROLLER,
                                          mav.MAV_AUTOPILOT_INVALID, 0, 0, 0, 3),
            self.controls(_FAR_USEC, [self.hover] * 4 + [0.0] * 12),
            mav.MAVLink_command_long_message(1, 1, 511, 0, 1, 2, 3, 4, 5, 6, 7),
            mav.MAVLink_command_long_message(1, 1, mav.MAV_CMD_INJECT_FAILURE, 0,
                                             100, 1, 2, 0, 0, 0, 0),
            mav.MAVLink_statustext_message(4, b"fuzz %d" % r.randrange(1000)),
            mav.MAVLink_named_value_float_message(0, b"x", 1.0),
        ]

    def command(self, *, for_us: bool) -> Any:
        rng = self.rng
        if for_us:
            ts, tc = rng.choice((0, 1)), rng.choice((0, 1))
        else:
            ts, tc = rng.choice(((rng.randint(2, 255), rng.choice((0, 1))),
                                 (rng.choice((0, 1)), rng.randint(2, 255)),
                                 (rng.randint(2, 255), rng.randint(2, 255))))
        kind = rng.randrange(4)
        if kind == 0:                                  # another command
            command = rng.choice((0, 16, 176, 400, 511, 512, 0xFFFF, rng.randrange(1 << 16)))
            if command == mav.MAV_CMD_INJECT_FAILURE:
                command += 1
            params = [self.nasty() if rng.random() < 0.5 else rng.uniform(-1e3, 1e3)
                      for _ in range(7)]
        else:                                          # INJECT_FAILURE, garbage parameters
            command = mav.MAV_CMD_INJECT_FAILURE
            p1 = rng.choice((101.0, 101.0, 100.0, 101.5, -101.0, 0.0, *_NASTY_FLOATS))
            p2 = rng.choice((0.0, 1.0, 3.0, 5.0, 9.0, 2.5, -1.0, 1e9, *_NASTY_FLOATS))
            p3 = rng.choice((0.0, 5.0, 2.5, -1.0, 255.0, 1e9, *_NASTY_FLOATS))
            params = [p1, p2, p3] + [self.nasty() for _ in range(4)]
        if rng.random() < 0.5:
            return mav.MAVLink_command_long_message(ts, tc, command, rng.randrange(256),
                                                    *params)
        return mav.MAVLink_command_int_message(
            ts, tc, rng.randrange(256), command, rng.randrange(256), rng.randrange(256),
            *params[:4], rng.randint(-2**31, 2**31 - 1), rng.randint(-2**31, 2**31 - 1),
            params[6])

    def batch(self, category: str, n: int, awaited_usec: int) -> tuple[list[bytes], bytes]:
        """``n`` hostile datagrams of ``category`` and the datagram that completes the tick."""
        rng = self.rng
        done = self.pack(self.hover_controls(awaited_usec))
        tpl = self.templates()
        out: list[bytes] = []
        for _ in range(n):
            if (raw := self.common(category, tpl)) is not None:
                out.append(raw)
            elif category == "wrong_sysid":
                msg = rng.choice([self.hover_controls(awaited_usec), *tpl[:3]])
                out.append(self.pack(msg, sysid=rng.choice(
                    [s for s in range(1, 256) if s != FUZZER_SYSID])))
            elif category == "wrong_target":
                out.append(self.pack(self.command(for_us=False)))
            elif category == "command_garbage":
                out.append(self.pack(self.command(for_us=True)))
            elif category == "stale_controls":
                t = rng.choice((awaited_usec - 1000, awaited_usec + 1000, awaited_usec + 1,
                                0, _FAR_USEC, 2**64 - 1))
                values = [rng.choice(_BAD_CONTROLS) if rng.random() < 0.5 else rng.random()
                          for _ in range(16)]
                out.append(self.pack(self.controls(t, values)))
            elif category not in ("oversize", "bad_controls"):
                raise ValueError(f"unknown category {category!r}")
        if category == "bad_controls":
            # The awaited tick with bad controls 0-3: rejected, previous command held, and
            # the tick completes (sitl.vehicle); or bad values only in the ignored 4-15.
            values = [self.hover] * 4 + [0.0] * 12
            if rng.random() < 0.8:
                for i in rng.sample(range(4), rng.randint(1, 4)):
                    values[i] = rng.choice(_BAD_CONTROLS)
            else:
                for i in range(4, 16):
                    values[i] = rng.choice(_BAD_CONTROLS)
            done = self.pack(self.controls(awaited_usec, values))
        elif category == "oversize":
            out = [self.oversize(tpl)]
        return out, done


VEHICLE_CATEGORIES = ("random", "mutated", "mutated_crc_ok", "truncated", "oversize",
                      "mavlink1", "unknown_id", "random_known_id", "wrong_sysid",
                      "wrong_target", "command_garbage", "stale_controls", "bad_controls")


class DaemonGen(_Gen):
    """Hostile vehicle traffic for the daemon."""

    def __init__(self, rng: random.Random, hover_rpm: int, position_ned: tuple[float, ...]
                 ) -> None:
        super().__init__(rng, VEHICLE_SYSID, VEHICLE_COMPID)
        self.hover_rpm = hover_rpm
        self.position_ned = position_ned

    def odometry(self, time_usec: int, **override: Any) -> Any:
        f = dict(x=self.position_ned[0], y=self.position_ned[1], z=self.position_ned[2],
                 q=[1.0, 0.0, 0.0, 0.0], vx=0.0, vy=0.0, vz=0.0, rollspeed=0.0,
                 pitchspeed=0.0, yawspeed=0.0, frame_id=mav.MAV_FRAME_LOCAL_NED,
                 child_frame_id=mav.MAV_FRAME_BODY_FRD)
        f.update(override)
        cov = [0.0] * 21
        return mav.MAVLink_odometry_message(
            time_usec, f["frame_id"], f["child_frame_id"], f["x"], f["y"], f["z"], f["q"],
            f["vx"], f["vy"], f["vz"], f["rollspeed"], f["pitchspeed"], f["yawspeed"], cov,
            cov, 0, mav.MAV_ESTIMATOR_TYPE_MOCAP, 100)

    def esc(self, rpm: list[int]) -> Any:
        return mav.MAVLink_esc_telemetry_1_to_4_message([30] * 4, [1200] * 4, [500] * 4,
                                                        [0] * 4, rpm, [1] * 4)

    def state(self, time_usec: int) -> bytes:
        """The completer: a valid hover state, as the simulator sends it (one datagram)."""
        return self.pack(self.odometry(time_usec)) + self.pack(self.esc([self.hover_rpm] * 4))

    def fuzz_time(self) -> int:
        t = self.rng.choice((0, 1, 2**63, 2**64 - 1, self.rng.randrange(2**64)))
        return t if t % 1000 else t + 1      # never a completer's time (k * 1000)

    def templates(self) -> list[Any]:
        return [
            mav.MAVLink_heartbeat_message(mav.MAV_TYPE_QUADROTOR, mav.MAV_AUTOPILOT_GENERIC,
                                          0, 0, mav.MAV_STATE_ACTIVE, 3),
            self.odometry(self.fuzz_time()),
            self.esc([self.hover_rpm] * 4),
            mav.MAVLink_statustext_message(4, b"fuzz"),
            mav.MAVLink_command_ack_message(420, 0, 0, 0, 42, 191),
        ]

    def bad_odometry(self) -> Any:
        rng = self.rng
        kind = rng.randrange(4)
        if kind == 0:                     # a NaN/inf scalar
            name = rng.choice(("x", "y", "z", "vx", "vy", "vz", "rollspeed", "pitchspeed",
                               "yawspeed"))
            return self.odometry(self.fuzz_time(), **{name: rng.choice(_NASTY_FLOATS[:4])})
        if kind == 1:                     # a bad quaternion
            q = [rng.choice((*_NASTY_FLOATS, 0.0, 0.5, 2.0)) for _ in range(4)]
            return self.odometry(self.fuzz_time(), q=q)
        if kind == 2:
            return self.odometry(self.fuzz_time(), frame_id=rng.choice((0, 8, 12, 255)))
        return self.odometry(self.fuzz_time(), child_frame_id=rng.choice((0, 8, 255)))

    def extreme_odometry(self, time_usec: int) -> Any:
        """Finite but absurd states: accepted by the frame check, flown by the law."""
        rng = self.rng

        def big() -> float:
            return rng.choice((1e38, -1e38, 3.4e38, 1e6, -1e6, 1e-38, rng.uniform(-1e3, 1e3)))

        q = [rng.gauss(0, 1) for _ in range(4)]
        norm = math.sqrt(sum(c * c for c in q)) or 1.0
        return self.odometry(
            time_usec, x=big(), y=big(), z=big(), vx=big(), vy=big(), vz=big(),
            rollspeed=big(), pitchspeed=big(), yawspeed=big(), q=[c / norm for c in q],
            child_frame_id=rng.choice((mav.MAV_FRAME_BODY_FRD, mav.MAV_FRAME_LOCAL_NED)))

    def batch(self, category: str, n: int, time_usec: int) -> tuple[list[bytes], bytes]:
        rng = self.rng
        tpl = self.templates()
        out: list[bytes] = []
        for _ in range(n):
            if (raw := self.common(category, tpl)) is not None:
                out.append(raw)
            elif category == "wrong_sysid":
                other = rng.choice([s for s in range(1, 256) if s != VEHICLE_SYSID])
                out.append(self.pack(self.odometry(self.fuzz_time()), sysid=other)
                           + self.pack(self.esc([self.hover_rpm] * 4), sysid=other))
            elif category == "bad_odometry":
                raw = self.pack(self.bad_odometry())
                if rng.random() < 0.5:
                    raw += self.pack(self.esc([rng.randrange(65536) for _ in range(4)]))
                out.append(raw)
            elif category == "esc_only":
                out.append(self.pack(self.esc([rng.randrange(65536) for _ in range(4)])))
            elif category == "other_messages":
                out.append(self.pack(rng.choice((
                    mav.MAVLink_heartbeat_message(rng.randrange(256), rng.randrange(256),
                                                  rng.randrange(256), rng.randrange(2**32),
                                                  rng.choice((0, 1, 2, 3, 4, 5)), 3),
                    mav.MAVLink_statustext_message(rng.randrange(256), self.randbytes(50),
                                                   rng.randrange(65536), rng.randrange(256)),
                    mav.MAVLink_hil_actuator_controls_message(
                        self.fuzz_time(), [self.nasty() for _ in range(16)], 128, 1),
                    mav.MAVLink_command_long_message(1, 0, 420, 0, *[self.nasty()] * 7),
                ))))
            elif category not in ("oversize", "bad_controls", "extreme_state"):
                raise ValueError(f"unknown category {category!r}")
        if category == "oversize":
            out = [self.oversize(tpl)]
        if category == "extreme_state":       # the completer itself (module docstring)
            return [], (self.pack(self.extreme_odometry(time_usec))
                        + self.pack(self.esc([rng.choice((0, 65535, rng.randrange(65536)))
                                              for _ in range(4)])))
        return out, self.state(time_usec)


DAEMON_CATEGORIES = ("random", "mutated", "mutated_crc_ok", "truncated", "oversize",
                     "mavlink1", "unknown_id", "random_known_id", "wrong_sysid",
                     "bad_odometry", "extreme_state", "esc_only", "other_messages")


# ---------------------------------------------------------------------------- reports
@dataclass
class CategoryReport:
    """One category of one endpoint: what was sent and what the endpoint counted."""

    sent: int = 0                # hostile datagrams sent
    arrived: int = 0             # of those, received by the endpoint (rx_datagrams)
    counted: Counter[str] = field(default_factory=Counter)   # endpoint's counter deltas
    expected: Counter[str] = field(default_factory=Counter)  # the model's prediction
    batches: int = 0
    mismatched_batches: int = 0
    lost_batches: int = 0
    skipped: int = 0             # run-ending legitimate inputs not sent (module docstring)


@dataclass
class EndpointReport:
    endpoint: str
    seed: int
    categories: dict[str, CategoryReport]
    crashes: list[str]
    nan_to_physics: int          # vehicle: ticks with a non-finite state/command/thrust
    nan_to_motors: int           # daemon: HIL_ACTUATOR_CONTROLS non-finite or out of [0, 1]
    nonfinite_tx: list[str]      # any frame either endpoint sent with a NaN/inf float
    mismatches: list[str]        # first few batches where counters ≠ model
    ticks: int
    elapsed_s: float
    completed: bool

    @property
    def sent(self) -> int:
        return sum(c.sent for c in self.categories.values())

    @property
    def inputs_per_s(self) -> float:
        return self.sent / self.elapsed_s if self.elapsed_s > 0 else math.nan


def _rejects(counted: Counter[str], endpoint_rejects: tuple[str, ...]) -> Counter[str]:
    return Counter({k: v for k, v in counted.items()
                    if k in LINK_REASONS or k in endpoint_rejects})


def rejected_total(c: CategoryReport, endpoint: str) -> int:
    rej = VEHICLE_REJECTS if endpoint == "vehicle" else DAEMON_REJECTS
    return sum(_rejects(c.counted, rej).values())


def reject_reasons(c: CategoryReport, endpoint: str) -> Counter[str]:
    rej = VEHICLE_REJECTS if endpoint == "vehicle" else DAEMON_REJECTS
    return _rejects(c.counted, rej)


# ---------------------------------------------------------------------------- harness
def _schedule(categories: tuple[str, ...], n_inputs: int, rng: random.Random,
              batch: int) -> Iterator[tuple[str, int]]:
    """(category, size) per tick until ``n_inputs`` hostile datagrams: categories in a
    seeded random order, each drawn about equally often."""
    sent = 0
    while sent < n_inputs:
        cat = rng.choice(categories)
        size = 1 if cat in ("oversize", "bad_controls", "extreme_state") \
            else min(batch, n_inputs - sent)
        if cat in ("bad_controls", "extreme_state"):
            yield cat, 0
            sent += 1
            continue
        yield cat, size
        sent += size


class _Endpoint:
    """The endpoint's thread, and what escaped from it."""

    def __init__(self) -> None:
        self.crashes: list[str] = []
        self.thread: threading.Thread | None = None

    def start(self, target: Callable[[], Any]) -> None:
        def run() -> None:
            try:
                target()
            except BaseException as exc:  # a crash is what we look for
                self.crashes.append(f"{type(exc).__name__}: {exc}")

        self.thread = threading.Thread(target=run, daemon=True)
        self.thread.start()

    def alive(self) -> bool:
        return self.thread is not None and self.thread.is_alive()


@dataclass
class _Batch:
    """One tick's traffic: hostile datagrams, then the datagram that completes the tick
    (itself hostile for ``bad_controls``, whose bad reply completes the tick)."""

    category: str
    hostile: list[bytes]
    done: bytes
    done_is_hostile: bool = False


class _Runner:
    """Send batches, wait for the endpoint's answer, compare its counters with the model."""

    def __init__(self, endpoint: str, model: Any, send: Callable[[bytes], Any],
                 counters: list[tuple[Any, tuple[str, ...]]],
                 wait: Callable[[], bool], categories: tuple[str, ...]) -> None:
        self.endpoint, self.model, self.send = endpoint, model, send
        self.counters, self.wait = counters, wait
        self.reports = {c: CategoryReport() for c in categories}
        self.mismatches: list[str] = []
        self.sent = 0

    def _snapshot(self) -> dict[str, int]:
        out: dict[str, int] = {}
        for obj, names in self.counters:
            out.update((k, getattr(obj, k)) for k in names)
        return out

    def run(self, b: _Batch) -> bool:
        """One batch; False if the endpoint did not answer (stalled or crashed)."""
        rep = self.reports[b.category]
        model = self.model
        expected: Counter[str] = Counter()
        send: list[bytes] = []
        for data in b.hostile:
            saved = model.save()
            e = model.expect(data)
            if e["ends_run"] or e["genuine"]:
                rep.skipped += 1
                model.restore(saved)
                continue
            send.append(data)
            expected += e
        done_expect = model.expect(b.done)
        done_expect.pop("genuine", None)      # the completer is meant to be flown
        before = self._snapshot()
        for data in send:
            self.send(data)
        self.send(b.done)
        answered = self.wait()
        after = self._snapshot()
        delta = Counter({k: after[k] - before[k] for k in after if after[k] != before[k]})
        n_hostile = len(send) + (1 if b.done_is_hostile else 0)
        arrived = delta.pop("rx_datagrams", 0) - (0 if b.done_is_hostile else 1)
        rep.sent += n_hostile
        rep.arrived += arrived
        rep.batches += 1
        self.sent += n_hostile
        if arrived < n_hostile:
            rep.lost_batches += 1
            return answered
        total = expected + done_expect
        if delta != total:
            rep.mismatched_batches += 1
            if len(self.mismatches) < 10:
                self.mismatches.append(f"{self.endpoint} {b.category}: counted {dict(delta)} "
                                       f"expected {dict(total)}")
        if b.done_is_hostile:
            expected = total
        else:
            delta.subtract(done_expect)
        rep.counted += +delta
        rep.expected += expected
        return answered


_LINK_FIELDS = ("rx_datagrams", "rx_frames", *LINK_REASONS)


def fuzz_vehicle(n_inputs: int, seed: int, *, batch: int = 16,
                 progress: Callable[[int, int], None] | None = None) -> EndpointReport:
    """Fuzz a lockstep :class:`~sitl.vehicle.Vehicle`'s control port with ``n_inputs``
    hostile datagrams (see the module docstring)."""
    from sitl.vehicle import Vehicle
    from tfl_mav.scenario import load_scenario

    sc = load_scenario("paper").replace(**{"attack.rotor": 0,
                                           "initial.position_m": [0.0, 0.0, 5.0]})
    fmax = sc.vehicle.thrust_max_n
    hover = sc.vehicle.mass_kg * sc.vehicle.gravity_mps2 / 4.0 / fmax
    rng = random.Random(seed)
    gen = VehicleGen(random.Random(rng.randrange(2**32)), hover)
    ep = _Endpoint()
    nan_ticks = [0]
    nonfinite_tx: list[str] = []

    def on_truth(sim: Any) -> None:
        values = [*sim.state.as_list(), *sim.rotor_commands_n, *sim.rotor_thrusts_n]
        if not all(math.isfinite(v) for v in values) or not all(
                0.0 <= f <= fmax for f in sim.rotor_commands_n):
            nan_ticks[0] += 1

    def on_frame(direction: str, raw: bytes, msg: Any, t: float) -> None:
        if direction == "tx" and msg is not None:
            bad = nonfinite_floats(msg)
            if bad and len(nonfinite_tx) < 20:
                nonfinite_tx.append(f"vehicle sent {msg.get_type()} with {bad}")

    vehicle = Vehicle(sc, listen=("127.0.0.1", 0), on_truth=on_truth, on_frame=on_frame)
    ep.start(lambda: vehicle.run(math.inf))
    # The fuzzer is the vehicle's controller: the lockstep client, sending the hostile
    # datagrams from its own (pinned) address and reading the states it gets back.
    pilot = Pilot(vehicle.listen_address, sysid=FUZZER_SYSID, compid=FUZZER_COMPID)
    awaited = [-1]

    def next_state() -> bool:
        """Receive until the vehicle's state for the tick after ``awaited``."""
        while True:
            try:
                odom, _esc = pilot.state(STATE_TIMEOUT_S)
            except (NoStateError, OSError):
                return False
            if odom.time_usec > awaited[0]:
                awaited[0] = odom.time_usec
                return True

    model = VehicleModel()
    runner = _Runner("vehicle", model, pilot.link.send_raw,
                     [(vehicle.stats.control_link, _LINK_FIELDS),
                      (vehicle.stats, (*VEHICLE_REJECTS, *VEHICLE_ACCEPTS))],
                     next_state, VEHICLE_CATEGORIES)
    t0 = time.perf_counter()
    pilot.link.send_raw(gen.pack(mav.MAVLink_heartbeat_message(
        mav.MAV_TYPE_ONBOARD_CONTROLLER, mav.MAV_AUTOPILOT_INVALID, 0, 0, 0, 3)))
    completed = next_state()
    for category, size in _schedule(VEHICLE_CATEGORIES, n_inputs, rng, batch):
        if not completed or not ep.alive():
            completed = False
            break
        model.awaited_usec = awaited[0]
        hostile, done = gen.batch(category, size, awaited[0])
        b = (_Batch(category, [], done, True) if category == "bad_controls"
             else _Batch(category, hostile, done))
        completed = runner.run(b)
        if progress is not None:
            progress(runner.sent, n_inputs)
    elapsed = time.perf_counter() - t0
    vehicle.stop()
    if ep.thread is not None:
        ep.thread.join(5.0)
    if ep.alive():
        ep.crashes.append("vehicle thread did not stop within 5 s")
    ticks = vehicle.stats.ticks
    vehicle.close()
    pilot.close()
    return EndpointReport("vehicle", seed, runner.reports, ep.crashes, nan_ticks[0], 0,
                          nonfinite_tx, runner.mismatches, ticks, elapsed,
                          completed and not ep.crashes)


def fuzz_daemon(n_inputs: int, seed: int, *, batch: int = 16,
                progress: Callable[[int, int], None] | None = None) -> EndpointReport:
    """Fuzz a :class:`~tfl_mav.daemon.Daemon` with ``n_inputs`` hostile datagrams, the
    fuzzer acting as its vehicle (see the module docstring)."""
    from tfl_mav.daemon import Daemon
    from tfl_mav.frames import enu_to_ned
    from tfl_mav.scenario import load_scenario

    sc = load_scenario("paper").replace(**{"attack.rotor": 0})
    v = sc.vehicle
    hover_radps = math.sqrt(v.mass_kg * v.gravity_mps2 / 4.0 / v.k_f)
    hover_rpm = round(hover_radps * 60.0 / (2.0 * math.pi))
    position_ned = tuple(float(c) for c in enu_to_ned(sc.initial.position_m))
    rng = random.Random(seed)
    gen = DaemonGen(random.Random(rng.randrange(2**32)), hover_rpm, position_ned)
    ep = _Endpoint()
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)   # the fuzzer, as the vehicle
    sock.bind(("127.0.0.1", 0))
    sock.settimeout(STATE_TIMEOUT_S)
    bad_cmds = [0]
    nonfinite_tx: list[str] = []

    def on_frame(direction: str, raw: bytes, msg: Any, t: float) -> None:
        if direction != "tx" or msg is None:
            return
        bad = nonfinite_floats(msg)
        if bad and len(nonfinite_tx) < 20:
            nonfinite_tx.append(f"daemon sent {msg.get_type()} with {bad}")
        if msg.get_msgId() == mav.MAVLINK_MSG_ID_HIL_ACTUATOR_CONTROLS:
            c = msg.controls
            if not (all(math.isfinite(u) and 0.0 <= u <= 1.0 for u in c[:4])
                    and all(u == 0.0 for u in c[4:])):
                bad_cmds[0] += 1

    daemon = Daemon(sc, vehicle=sock.getsockname(), on_frame=on_frame)
    address = daemon.link.local_address
    ep.start(lambda: daemon.run(math.inf))
    parser = new_mavlink(255, 0)
    tick = [1]

    def await_reply() -> bool:
        """Receive until the daemon's HIL_ACTUATOR_CONTROLS for the completer's time."""
        want = tick[0] * 1000
        while True:
            try:
                data = sock.recv(65535)
            except (TimeoutError, OSError):
                return False
            for msg in parser.parse_buffer(data) or ():
                if (msg.get_msgId() == mav.MAVLINK_MSG_ID_HIL_ACTUATOR_CONTROLS
                        and msg.time_usec == want):
                    return True

    model = DaemonModel()
    runner = _Runner("daemon", model, lambda data: sock.sendto(data, address),
                     [(daemon.link.stats, _LINK_FIELDS),
                      (daemon.stats, (*DAEMON_REJECTS, *DAEMON_ACCEPTS))],
                     await_reply, DAEMON_CATEGORIES)
    t0 = time.perf_counter()
    sock.sendto(gen.pack(mav.MAVLink_heartbeat_message(
        mav.MAV_TYPE_QUADROTOR, mav.MAV_AUTOPILOT_GENERIC, 0, 0, mav.MAV_STATE_ACTIVE, 3)),
        address)
    first = gen.state(tick[0] * 1000)
    model.expect(first)
    sock.sendto(first, address)
    completed = await_reply()
    for category, size in _schedule(DAEMON_CATEGORIES, n_inputs, rng, batch):
        if not completed or not ep.alive():
            completed = False
            break
        tick[0] += 1
        hostile, done = gen.batch(category, max(size, 1), tick[0] * 1000)
        completed = runner.run(_Batch(category, hostile, done, category == "extreme_state"))
        if progress is not None:
            progress(runner.sent, n_inputs)
    elapsed = time.perf_counter() - t0
    daemon.stop()
    if ep.thread is not None:
        ep.thread.join(5.0)
    if ep.alive():
        ep.crashes.append("daemon thread did not stop within 5 s")
    ticks = daemon.stats.ticks
    daemon.close()
    sock.close()
    return EndpointReport("daemon", seed, runner.reports, ep.crashes, 0, bad_cmds[0],
                          nonfinite_tx, runner.mismatches, ticks, elapsed,
                          completed and not ep.crashes)
