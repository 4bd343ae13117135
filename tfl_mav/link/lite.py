"""The message objects the link hands out for the per-tick messages (:mod:`tfl_mav.link.codec`).

Why its own module: these are what every tick of both processes reads, and their shape is a
contract with the codec's compiled layouts (wire order, one tuple item per value, the frame
bytes last), kept apart from the packing and checking code.

* :class:`LiteMessage`: a decoded (or to-be-sent) hot message as a tuple of its wire-order
  values, then the frame bytes; fields are properties over the tuple, methods answer as
  pymavlink's message would.
* **Lazy arrays** (:data:`LAZY_FIELDS`): a *received* message may leave big array fields
  nobody reads per tick out of its tuple (ODOMETRY's 42 covariance floats: the daemon reads
  pose and twist only). The decode's ``struct`` skips them as pad bytes and the property
  unpacks them from the frame bytes on first read, with the values pymavlink gives
  (tests/contract/test_codec.py). Such a message has a class of its own (``rx_lite_class``), which
  the codec packs field by field, as pymavlink's message.
"""

from __future__ import annotations

import struct
from operator import itemgetter
from typing import Any

from tfl_mav.link.dialect import mav
from tfl_mav.link.payload import frame_payload

__all__ = ["LAZY_FIELDS", "UNSENT", "LiteMessage"]

_IFLAG_SIGNED = 0x01
_SIGNATURE_LEN = 13
_HEADER_LEN = 10

UNSENT = bytes(10)
"""The frame item of a LiteMessage built to be sent: a zero header, so ``get_srcSystem()``,
``get_seq()``... answer 0, as an unsent pymavlink message's do."""

LAZY_FIELDS: dict[int, tuple[str, ...]] = {
    # the daemon reads ODOMETRY's pose and twist every tick, never its 42 covariance floats
    mav.MAVLINK_MSG_ID_ODOMETRY: ("pose_covariance", "velocity_covariance"),
    # ... of ACTUATOR_OUTPUT_STATUS its time_usec (actuator[0..3] only when the command it
    # names is not in its history: 32 floats unpacked for nothing otherwise) ...
    mav.MAVLINK_MSG_ID_ACTUATOR_OUTPUT_STATUS: ("actuator",),
    # ... and of ESC_TELEMETRY_1_TO_4 the four rpm (the tuple: rpm[0..3], then the frame)
    mav.MAVLINK_MSG_ID_ESC_TELEMETRY_1_TO_4: ("voltage", "current", "totalcurrent", "count",
                                              "temperature"),
}
"""Array fields a *received* LiteMessage does not unpack (module docstring)."""


class LiteMessage(tuple):  # type: ignore[type-arg]
    """A decoded hot message: the wire-order values of its payload, then the frame bytes
    (the last item). Read it like pymavlink's message: ``m.time_usec``, ``m.rpm`` (a new
    list), ``m.get_msgId()``, ``m.get_srcSystem()``, ``m.to_dict()``. Immutable."""

    __slots__ = ()
    # the message's id, name and fields in wire order (upper case: no MAVLink field is)
    MSG_ID = -1
    MSG_NAME = ""
    FIELDNAMES: tuple[str, ...] = ()

    def get_msgId(self) -> int:
        return self.MSG_ID

    def get_type(self) -> str:
        return self.MSG_NAME

    def get_fieldnames(self) -> list[str]:
        return list(self.FIELDNAMES)

    def get_srcSystem(self) -> int:
        return int(self[-1][5])

    def get_srcComponent(self) -> int:
        return int(self[-1][6])

    def get_seq(self) -> int:
        return int(self[-1][4])

    def get_signed(self) -> bool:
        return False    # as pymavlink's parser without a key says (the Link verifies)

    def get_link_id(self) -> None:
        return None

    def get_msgbuf(self) -> bytearray:
        return bytearray(self[-1])

    def _end(self) -> int:
        raw = self[-1]
        return len(raw) - 2 - (_SIGNATURE_LEN if raw[2] & _IFLAG_SIGNED else 0)

    def get_payload(self) -> bytearray:
        return bytearray(self[-1][6:self._end()])   # sic: pymavlink slices from 6

    def get_crc(self) -> int:
        raw, end = self[-1], self._end()
        return int(raw[end] | raw[end + 1] << 8)

    def get_header(self) -> Any:
        raw = self[-1]
        return mav.MAVLink_header(self.MSG_ID, raw[2], raw[3], raw[1], raw[4], raw[5], raw[6])

    def to_dict(self) -> dict[str, Any]:
        d: dict[str, Any] = {"mavpackettype": self.MSG_NAME}
        for name in self.FIELDNAMES:
            d[name] = getattr(self, name)
        return d

    def __str__(self) -> str:
        inner = ", ".join(f"{name} : {getattr(self, name)}" for name in self.FIELDNAMES)
        return f"{self.MSG_NAME} {{{inner}}}"

    __repr__ = __str__


_LITE_CLASSES: dict[type, type[LiteMessage]] = {}


def _lite_class(cls: Any, where: dict[str, int], lengths: dict[str, int]) -> type[LiteMessage]:
    """The LiteMessage subclass of one message class: a property per field. One per message
    class in the process (every codec shares it, so any codec packs what another built)."""
    lite = _LITE_CLASSES.get(cls)
    if lite is not None:
        return lite
    lite = _LITE_CLASSES[cls] = type(f"Lite{cls.__name__}", (LiteMessage,),
                                     _field_attrs(cls, where, lengths, {}))
    return lite


def _field_attrs(cls: Any, where: dict[str, int], lengths: dict[str, int],
                 special: dict[str, property]) -> dict[str, Any]:
    """A LiteMessage subclass's namespace: a property per field, reading the tuple at the
    field's index (``where``; an array of ``lengths[name]`` items as a fresh list), or the
    ``special`` property given for it."""
    attrs: dict[str, Any] = {"__slots__": (), "MSG_ID": cls.id, "MSG_NAME": cls.msgname,
                             "FIELDNAMES": tuple(cls.fieldnames)}
    for name in cls.fieldnames:
        i, n = where.get(name, -1), lengths[name]
        if name in special:
            attrs[name] = special[name]
        elif n:
            attrs[name] = property(lambda m, i=i, j=i + n: list(m[i:j]))
        else:
            attrs[name] = property(itemgetter(i))
    return attrs


_RX_CLASSES: dict[type, type[LiteMessage]] = {}


def _lazy_array(offset: int, code: str, n: int, size: int) -> property:
    """A property reading an array field of ``n`` items of ``struct`` type ``code`` at byte
    ``offset`` of the payload from the frame bytes (a trimmed payload zero-extended to
    ``size``, as the decode does), as a fresh list."""
    unpack_from = struct.Struct(f"<{n}{code}").unpack_from

    def read(m: Any) -> list[Any]:
        raw = m[-1]
        end = len(raw) - 2 - (_SIGNATURE_LEN if raw[2] & _IFLAG_SIGNED else 0)
        if end - _HEADER_LEN >= size:
            return list(unpack_from(raw, _HEADER_LEN + offset))
        return list(unpack_from(frame_payload(raw, size, end), offset))

    return property(read)


def _rx_lite_class(cls: Any, lazy: tuple[str, ...], where: dict[str, int],
                   lengths: dict[str, int], codes: dict[str, str],
                   offsets: dict[str, int]) -> type[LiteMessage]:
    """The received LiteMessage of one message class whose ``lazy`` arrays are left out of
    the tuple (see :data:`LAZY_FIELDS`); the other fields are read as :func:`_lite_class`
    reads them, at their indexes in the shorter tuple (``where``)."""
    rx = _RX_CLASSES.get(cls)
    if rx is not None:
        return rx
    size = cls.unpacker.size
    arrays = {name: _lazy_array(offsets[name], codes[name], lengths[name], size)
              for name in lazy}
    rx = _RX_CLASSES[cls] = type(f"LiteRx{cls.__name__}", (LiteMessage,),
                                 _field_attrs(cls, where, lengths, arrays))
    return rx


