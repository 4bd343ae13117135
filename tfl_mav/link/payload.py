"""Decode a MAVLink 2 frame's header and payload into JSON-ready values, from the wire bytes.

Why not pymavlink's ``decode``: the recorder needs the fields of frames this process *sent*
as they were on the wire (float32-rounded, truncated zeros restored), and building a full
message object (with a CRC check we do not need, the frame was packed here) costs ~9 µs;
unpacking with the message class's own ``struct`` and reshaping costs ~1-2 µs. The output
is what pymavlink's decoder would give: arrays as lists, ``char[N]`` cut at the first NUL
and decoded as ASCII with replacement, fields in ``fieldnames`` order.

Frames are assumed complete and MAVLink 2 (the link has already framed them).
"""

from __future__ import annotations

import struct
from collections.abc import Callable
from dataclasses import dataclass
from operator import itemgetter
from typing import Any

from tfl_mav.link.dialect import mav

__all__ = ["FrameHeader", "PayloadDecoder", "frame_header", "frame_payload"]

_HEADER_LEN = 10
_CRC_LEN = 2
_SIGNATURE_LEN = 13
_SCALAR, _ARRAY, _CHARS = 0, 1, 2


@dataclass(frozen=True)
class FrameHeader:
    msgid: int
    sysid: int
    compid: int
    seq: int


def frame_header(raw: bytes) -> FrameHeader | None:
    """The MAVLink 2 header of ``raw``, or None if it is not one (too short, wrong magic)."""
    if len(raw) < _HEADER_LEN + _CRC_LEN or raw[0] != 0xFD:
        return None
    return FrameHeader(raw[7] | raw[8] << 8 | raw[9] << 16, raw[5], raw[6], raw[4])



def frame_payload(raw: bytes, size: int, end: int | None = None) -> bytes:
    """The payload of the complete MAVLink 2 frame ``raw`` fitted to the message's ``size``
    bytes: MAVLink 2 trims trailing zero bytes, so a short payload is zero-extended, and a
    longer one (extension fields this dialect does not know) is cut. ``end``: where the
    payload ends, if the caller already knows (else: before the CRC and any signature)."""
    if end is None:
        end = len(raw) - _CRC_LEN - (_SIGNATURE_LEN if raw[2] & 0x01 else 0)
    payload = raw[_HEADER_LEN:end]
    n = len(payload)
    if n < size:
        return bytes(payload) + bytes(size - n)
    if n > size:
        return payload[:size]
    return payload

def _plan(cls: Any) -> Callable[[tuple[Any, ...]], dict[str, Any]]:
    """A function mapping the unpacked wire tuple of ``cls`` to its field dict."""
    wire_lengths = cls.lengths            # values per wire-ordered field ('50s' counts 1)
    char_names = {n for n, t in zip(cls.fieldnames, cls.fieldtypes, strict=True) if t == "char"}
    specs: list[tuple[str, int, int, int]] = []
    for i, name in enumerate(cls.fieldnames):
        wire = cls.orders[i]
        tip = sum(wire_lengths[:wire])
        count = wire_lengths[wire]
        kind = _CHARS if name in char_names else _ARRAY if count > 1 else _SCALAR
        specs.append((name, tip, count, kind))
    names = tuple(s[0] for s in specs)
    if all(kind == _SCALAR for *_, kind in specs):
        if len(specs) == 1:
            only = specs[0][1]
            return lambda t: {names[0]: t[only]}
        getter = itemgetter(*(tip for _, tip, _, _ in specs))
        return lambda t: dict(zip(names, getter(t), strict=True))

    def reshape(t: tuple[Any, ...]) -> dict[str, Any]:
        out: dict[str, Any] = {}
        for name, tip, count, kind in specs:
            if kind == _SCALAR:
                out[name] = t[tip]
            elif kind == _ARRAY:
                out[name] = list(t[tip:tip + count])
            else:
                out[name] = t[tip].split(b"\x00", 1)[0].decode("ascii", "replace")
        return out

    return reshape


class PayloadDecoder:
    """Per-message-type unpack plans, built on first use and cached."""

    def __init__(self) -> None:
        self._plans: dict[int, tuple[Any, int, Callable[[tuple[Any, ...]], dict[str, Any]]]] = {}

    def fields(self, raw: bytes, msgid: int) -> dict[str, Any] | None:
        """Field dict of the complete MAVLink 2 frame ``raw`` (message ``msgid``), or None
        if the id is not in the dialect or the payload does not unpack."""
        plan = self._plans.get(msgid)
        if plan is None:
            cls = mav.mavlink_map.get(msgid)
            if cls is None:
                return None
            plan = self._plans[msgid] = (cls.unpacker.unpack, cls.unpacker.size, _plan(cls))
        unpack, size, reshape = plan
        try:
            return reshape(unpack(frame_payload(raw, size)))
        except (struct.error, UnicodeError, IndexError):
            return None
