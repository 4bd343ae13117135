"""The recorder's frame hot path in C: a hand-off batch's frames → two MCAP records each.

Why: a recorder child spends most of its CPU on frames (4-5 a 1 ms tick per
side): in Python, ~8-10 µs a frame (unpack, the JSON object, the raw record's base64,
two record headers and index entries), ~2× that in a full lockstep loop where four
processes share two cores and evict each other's caches. Here
:meth:`~tfl_mav.flightlog.framerec.FrameRecorder.on_frames`'s loop body runs in C for the
frames of a (direction, sysid, compid, msgid) already seen whose message prints by a
numbers-only plan: ~1 µs a frame.

Same bytes, by construction and by test (tests/contract/test_frames_c.py): JSON prints a float as
``float.__repr__`` does, which is CPython's ``PyOS_double_to_string(x, 'r', 0,
Py_DTSF_ADD_DOT_0)`` — called here; an int as its decimal digits; the keys and values in
the plan's order (:class:`~tfl_mav.flightlog.jsonenc.MavPlan`: ``fieldnames`` order, a list
only for an array of more than one value). The raw record is the Python path's ``%``
template; base64 is RFC 4648 with padding (``binascii.b2a_base64``); the record header and
index entry are :class:`~tfl_mav.flightlog.mcapfast.FastWriter`'s. A frame C does not take
— a NaN/inf value (left out and listed by the Python plan), a log time out of range, a
channel not in the table, a rejected frame — stops the loop at that frame, and the Python
path writes it; then C goes on.

Built by :mod:`tfl_mav.accel.native` (``TFL_MAV_NATIVE``, the compiled cores' cache); until it is
built, or with no compiler, the Python path writes every frame.
"""

from __future__ import annotations

import re
import struct
from collections.abc import Callable
from pathlib import Path
from typing import Any

from tfl_mav.accel import native

__all__ = ["C_SOURCE", "frame_key", "layout", "obtain"]

#: One fast-table key for a frame: direction (1: rx) | sysid << 1 | compid << 9 | msgid << 17.
def frame_key(rx: bool, head: bytes) -> int:
    """The C table's key of a frame whose bytes 5-9 are ``head`` (sysid, compid, msgid)."""
    return ((1 if rx else 0) | head[0] << 1 | head[1] << 9
            | (head[2] | head[3] << 8 | head[4] << 16) << 17)


_CODES = {"B": 1, "b": 1, "H": 2, "h": 2, "I": 4, "i": 4, "Q": 8, "q": 8, "f": 4, "d": 8}


def layout(cls: Any) -> tuple[bytes, int | None] | None:
    """A numbers-only MAVLink message class's fields for the C encoder, in ``fieldnames``
    order: per field its type code, value count, byte offset in the payload and JSON key
    text (``{"name":`` or ``,"name":``); and the byte offset of a ``time_usec`` field
    (None: none). None for a class with char fields or a format the encoder does not
    know."""
    fmt = cls.unpacker.format
    if not fmt.startswith("<"):
        return None
    wire: list[tuple[str, int, int]] = []          # (code, count, byte offset), wire order
    offset = 0
    for n, code in re.findall(r"(\d*)([a-zA-Z?])", fmt[1:]):
        if code not in _CODES:
            return None
        count = int(n or 1)
        wire.append((code, count, offset))
        offset += _CODES[code] * count
    if offset != cls.unpacker.size or len(wire) != len(cls.fieldnames):
        return None
    out = bytearray()
    time_off: int | None = None
    for i, name in enumerate(cls.fieldnames):
        code, count, off = wire[cls.orders[i]]
        if count != cls.lengths[cls.orders[i]] or not name.isascii() or not name.isidentifier():
            return None
        if name == "time_usec" and count == 1 and code == "Q":
            time_off = off
        key = (b"{" if i == 0 else b",") + b'"' + name.encode() + b'":'
        out += struct.pack("<cHHB", code.encode(), count, off, len(key)) + key
    return bytes(out), time_off


def obtain(ready: Callable[[Any], None]) -> Any:
    """The compiled ``frames`` function now (loaded, cached, or built with
    ``TFL_MAV_NATIVE=sync``), else None and ``ready(fn)`` when a background build is done."""
    return native.obtain_c(C_SOURCE, "frames", ready)


C_SOURCE = (Path(__file__).with_name("frames_c.c")).read_text()
"""The extension's C (``frames_c.c``, next to this file)."""
