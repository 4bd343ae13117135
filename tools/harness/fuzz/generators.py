"""Hostile datagrams by category, for the vehicle's side and the daemon's."""

from __future__ import annotations

import math
import random
from typing import Any

from tfl_mav.link.dialect import mav, new_mavlink
from tfl_mav.tools.harness.fuzz.wire import (
    _BAD_CONTROLS,
    _FAR_USEC,
    _MAGIC_V2,
    _NASTY_FLOATS,
    _SIG_LEN,
    _SIGNED,
    FUZZER_COMPID,
    FUZZER_SYSID,
    MAX_UDP_PAYLOAD,
    VEHICLE_COMPID,
    VEHICLE_SYSID,
    frame_v2,
    mutate,
    recompute_crc,
)


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
            # the tick completes (tfl_mav.sitl.vehicle); or bad values only in the ignored 4-15.
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
                    # used by the daemon (the held command), counted nowhere
                    mav.MAVLink_actuator_output_status_message(
                        self.fuzz_time(), rng.randrange(2**32),
                        [self.nasty() for _ in range(32)]),
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
