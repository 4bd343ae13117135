"""Frames on the wire: the dialect's constants, MAVLink 2 frames built, mutated and re-CRC'd."""

from __future__ import annotations

import math
import random
import struct
from typing import Any

from tfl_mav.link.dialect import mav

# Link-level rejection reasons, as named in LinkStats.
LINK_REASONS = ("garbage", "mavlink1", "truncated", "bad_flags", "bad_crc", "bad_signature",
                "malformed", "unknown_id", "foreign", "wrong_sysid", "no_peer", "reflected")
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
