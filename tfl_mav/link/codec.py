"""Precompiled MAVLink 2 pack/decode for the few messages of every control tick.

Why: pymavlink packs a message in ~40 µs and decodes a frame in ~70 µs on the machines we
measured, mostly generic Python (header objects, per-field loops, list
building). A lockstep tick carries ODOMETRY + ESC_TELEMETRY_1_TO_4 (+ ACTUATOR_OUTPUT_STATUS)
one way and HIL_ACTUATOR_CONTROLS back, so that is ~350 µs a tick across both processes.

Here, for each hot message, the layout is taken from pymavlink's own class (wire field
order, ``struct`` format, ``crc_extra``, array lengths) and turned once into straight-line
code: one ``struct.pack`` of the fields in wire order, MAVLink 2 trailing-zero truncation,
the header, CRC-16/MCRF4XX (pymavlink's own C ``fastcrc`` when it has it) and, on a signing
packer, the signature block exactly as pymavlink's ``sign_packet`` makes it. Decoding checks
the CRC, restores truncated zeros and builds an instance of **pymavlink's class** with the
same attributes its ``decode`` sets (fields, ``_header``, ``_msgbuf``, ``_payload``, ``_crc``,
``_signed``...), so callers cannot tell the difference. tests/contract/test_codec.py checks both
directions byte for byte and attribute for attribute against pymavlink (hypothesis), signed
and truncated frames included. Anything else goes through pymavlink unchanged.

:meth:`FastCodec.decode_lite` is what :class:`~tfl_mav.link.transport.Link` hands out on
every tick: the same checks (CRC, lengths, the parser's signature count), but the message is
a :class:`LiteMessage`, the unpacked wire tuple itself plus the frame bytes. Its fields are
properties that read the tuple (arrays as fresh lists, as pymavlink gives them), so a field
nobody reads costs nothing; the ``get_*`` methods, ``to_dict`` and ``str`` answer as
pymavlink's message would (tests/contract/test_codec.py checks every field and method). Building
pymavlink's object (a dict of every field, the header object, two buffer copies) was most of
a decode's cost. The message classes, and the array fields a received message leaves
in its frame bytes until read (ODOMETRY's covariances), are in :mod:`tfl_mav.link.lite`.

A sender on the hot path can build the LiteMessage itself (:func:`lite_class`, its wire-order
values and :data:`UNSENT` for the frame): :meth:`FastCodec.pack` packs it with one
``struct.pack`` of the tuple, into the bytes pymavlink's message with the same fields packs to
(tests/contract/test_codec.py), without pymavlink's constructor or the per-field attribute reads.
"""

from __future__ import annotations

import hashlib
import re
import struct
from collections.abc import Callable, Iterable
from typing import Any

from tfl_mav.link.dialect import mav
from tfl_mav.link.lite import (
    _IFLAG_SIGNED,
    _SIGNATURE_LEN,
    LAZY_FIELDS,
    UNSENT,
    LiteMessage,
    _lite_class,
    _rx_lite_class,
)
from tfl_mav.link.payload import frame_payload

__all__ = ["HOT_MESSAGE_IDS", "LAZY_FIELDS", "PACK_ONLY_IDS", "UNSENT", "FastCodec",
           "LiteMessage", "Prepacked", "SkimmedMessage", "lite_class", "prepacked_class",
           "rx_lite_class", "skim", "trim"]

HOT_MESSAGE_IDS = (
    mav.MAVLINK_MSG_ID_ODOMETRY,
    mav.MAVLINK_MSG_ID_ESC_TELEMETRY_1_TO_4,
    mav.MAVLINK_MSG_ID_HIL_ACTUATOR_CONTROLS,
    mav.MAVLINK_MSG_ID_ACTUATOR_OUTPUT_STATUS,
    mav.MAVLINK_MSG_ID_HEARTBEAT,
    # the vehicle's GCS telemetry (tfl_mav.sitl.gcs), 50 times a second of sim time in lockstep
    mav.MAVLINK_MSG_ID_ATTITUDE,
    mav.MAVLINK_MSG_ID_LOCAL_POSITION_NED,
    mav.MAVLINK_MSG_ID_GLOBAL_POSITION_INT,
    mav.MAVLINK_MSG_ID_SYS_STATUS,
)

PACK_ONLY_IDS = (
    # the controller's own telemetry (tfl_mav.controller.daemon), 50 times a second of sim time
    mav.MAVLINK_MSG_ID_NAMED_VALUE_FLOAT,
    mav.MAVLINK_MSG_ID_DEBUG_FLOAT_ARRAY,
)
"""Messages compiled for sending only, from a :class:`LiteMessage` whose char field holds the
raw ``bytes`` pymavlink packs (``_name_raw``); never decoded here (pymavlink decodes a char
field to ``str``), so a receiver still gets pymavlink's message."""

_HEADER = struct.Struct("<BBBBBBBHB")
_MAX_HEADERS = 4096       # unsigned headers kept per message (bounds a fuzzer's lengths)
_SIGN_BLOCK = struct.Struct("<BQ")
_new_tuple = tuple.__new__

_crc16: Callable[[bytes, int], int]
if mav.mcrf4xx is not None:     # pymavlink's own choice: fastcrc's C implementation
    _crc16 = mav.mcrf4xx
else:                           # pragma: no cover - pymavlink without fastcrc
    def _crc16(data: bytes, crc: int) -> int:
        acc = mav.x25crc()
        acc.crc = crc
        acc.accumulate(data)
        return acc.crc


def rx_lite_class(msgid: int) -> type[LiteMessage]:
    """The LiteMessage class the link hands out for a received hot message ``msgid``:
    :func:`lite_class`'s, unless the message has :data:`LAZY_FIELDS` (then a class of its
    own, whose tuple leaves them out: never build one by hand, only decode)."""
    if msgid not in HOT_MESSAGE_IDS:
        raise ValueError(f"rx_lite_class: message id {msgid} is not compiled")
    return _Layout(mav.mavlink_map[msgid]).rx_lite


def lite_class(msgid: int) -> type[LiteMessage]:
    """The LiteMessage class of hot message ``msgid``. A message to send is
    ``tuple.__new__(cls, (*wire_order_values, UNSENT))``, arrays flattened in place, every
    array element given (the wire order is pymavlink's ``ordered_fieldnames``)."""
    if msgid in HOT_MESSAGE_IDS:
        return _Layout(mav.mavlink_map[msgid]).lite
    if msgid in PACK_ONLY_IDS:       # a char field is given as bytes
        return _Layout(mav.mavlink_map[msgid], chars=True).lite
    raise ValueError(f"lite_class: message id {msgid} is not compiled")


class Prepacked(tuple):  # type: ignore[type-arg]
    """A hot message to send that its sender packed itself: ``(payload, head, tail)``.

    ``payload`` is the trimmed payload (MAVLink 2: trailing zeros cut, ≥ 1 byte) of the
    wire-order values ``head + tail`` (a sender's constant tail kept as one tuple), exactly
    what :meth:`FastCodec.pack` makes of the :func:`lite_class` message of those values.
    Why: the vehicle's per-tick state is framed without rebuilding and re-packing ~100
    values, half of them constants (ODOMETRY's covariances, the unused actuator outputs).
    Fields and methods answer as that LiteMessage, built on first read; a recorder hook
    that only asks whether there is a message never builds it. Make the class with
    :func:`prepacked_class`, an instance with ``tuple.__new__(cls, (payload, head, tail))``.
    """

    __slots__ = ()
    _lite: type[LiteMessage] = LiteMessage

    def lite(self) -> LiteMessage:
        """The LiteMessage of ``head + tail`` (a new one each call)."""
        return _new_tuple(self._lite, (*self[1], *self[2], UNSENT))

    def get_msgId(self) -> int:
        return self._lite.MSG_ID

    def get_type(self) -> str:
        return self._lite.MSG_NAME

    def __getattr__(self, name: str) -> Any:
        if name.startswith("__"):
            raise AttributeError(name)
        return getattr(self.lite(), name)

    def __str__(self) -> str:
        return str(self.lite())

    __repr__ = __str__


_PREPACKED: dict[int, type[Prepacked]] = {}


def prepacked_class(msgid: int) -> type[Prepacked]:
    """The :class:`Prepacked` class of hot message ``msgid`` (one per process)."""
    cls = _PREPACKED.get(msgid)
    if cls is None:
        lite = lite_class(msgid)
        attrs: dict[str, Any] = {"__slots__": (), "_lite": lite}
        for name in lite.FIELDNAMES:   # fields named like tuple methods (count) too
            attrs[name] = property(lambda m, name=name: getattr(m.lite(), name))
        cls = _PREPACKED[msgid] = type(f"Prepacked{lite.__name__[4:]}", (Prepacked,), attrs)
    return cls


def trim(payload: bytes) -> bytes:
    """A MAVLink 2 payload without its trailing zeros (at least one byte kept)."""
    return payload.rstrip(b"\x00") or payload[:1]


class _Layout:
    """One message class compiled: ``pack(msg) -> payload`` and ``fields(tuple) -> dict``.
    ``chars``: allow char fields (packing a LiteMessage only, see :data:`PACK_ONLY_IDS`)."""

    def __init__(self, cls: Any, chars: bool = False) -> None:
        if "char" in cls.fieldtypes and not chars:
            raise ValueError(f"{cls.msgname}: char fields are not compiled")
        self.cls = cls
        self.msgid = cls.id
        self.crc_extra_byte = bytes([cls.crc_extra])
        self.headers: dict[int, tuple[bytes, int]] = {}   # FastCodec.pack_many's, unsigned
        self.size = cls.unpacker.size
        self.unpack = cls.unpacker.unpack
        self.pack_wire: Callable[..., bytes] = cls.unpacker.pack   # the wire-order values
        # array_lengths is in wire order (ordered_fieldnames), fieldtypes in fieldnames order
        lengths = dict(zip(cls.ordered_fieldnames, cls.array_lengths, strict=True))
        # pack: the wire-ordered fields, arrays as their first n elements (pymavlink indexes
        # 0..n-1; one slice unpacked is cheaper than n subscripts)
        args = [f"*m.{name}[:{lengths[name]}]" if lengths[name] else f"m.{name}"
                for name in cls.ordered_fieldnames]
        # fields: wire tuple index of every field, in fieldnames order
        tip, where = 0, {}
        for name in cls.ordered_fieldnames:
            where[name] = tip
            tip += max(1, lengths[name])
        items = []
        for name in cls.fieldnames:
            i, n = where[name], lengths[name]
            items.append(f"{name!r}: [{', '.join(f't[{i + k}]' for k in range(n))}]" if n
                         else f"{name!r}: t[{i}]")
        fixed = (f"'_fieldnames': _cls.fieldnames, '_type': {cls.msgname!r}, "
                 "'_instance_field': _cls.instance_field, "
                 "'_instance_offset': _cls.instance_offset, '_instances': None, "
                 "'_link_id': None, '_signed': False")
        src = (f"def pack(m):\n    return _pack({', '.join(args)})\n"
               f"def fields(t):\n    return {{{', '.join(items)}, {fixed}}}\n")
        scope: dict[str, Any] = {"_pack": cls.unpacker.pack, "_cls": cls}
        exec(compile(src, f"<codec {cls.msgname}>", "exec"), scope)
        self.pack: Callable[[Any], bytes] = scope["pack"]
        self.fields: Callable[[tuple[Any, ...]], dict[str, Any]] = scope["fields"]
        self.lite = _lite_class(cls, where, lengths)
        # the receive side: LAZY_FIELDS as pad bytes in the unpack, read on first access
        self.rx_lite = self.lite
        self.rx_unpack = self.unpack
        self.rx_unpack_from = cls.unpacker.unpack_from
        lazy = LAZY_FIELDS.get(cls.id, ())
        if lazy and not chars:
            tokens = re.findall(r"(\d*)([a-zA-Z])", cls.unpacker.format)
            codes = {name: code for name, (_, code) in
                     zip(cls.ordered_fieldnames, tokens, strict=True)}
            fmt, offsets, rx_where, byte, tip = "<", {}, {}, 0, 0
            for name, (count, code) in zip(cls.ordered_fieldnames, tokens, strict=True):
                width = struct.calcsize(f"<{count}{code}")
                offsets[name] = byte
                byte += width
                if name in lazy:
                    fmt += f"{width}x"
                    continue
                fmt += f"{count}{code}"
                rx_where[name] = tip
                tip += max(1, lengths[name])
            rx_struct = struct.Struct(fmt)
            assert rx_struct.size == self.size, cls.msgname
            self.rx_unpack = rx_struct.unpack
            self.rx_unpack_from = rx_struct.unpack_from
            self.rx_lite = _rx_lite_class(cls, lazy, rx_where, lengths, codes, offsets)


class FastCodec:
    """Pack and decode the hot messages exactly as pymavlink does, faster. One per link."""

    def __init__(self, ids: tuple[int, ...] = HOT_MESSAGE_IDS,
                 pack_only: tuple[int, ...] = PACK_ONLY_IDS) -> None:
        self.by_class: dict[type, _Layout] = {}
        self.by_id: dict[int, _Layout] = {}
        self.by_lite: dict[type, _Layout] = {}
        for msgid in ids:
            layout = _Layout(mav.mavlink_map[msgid])
            self.by_class[layout.cls] = layout
            self.by_id[msgid] = layout
            self.by_lite[layout.lite] = layout
            if layout.rx_lite is not layout.lite:   # packed field by field, as pymavlink's
                self.by_class[layout.rx_lite] = layout
        for msgid in pack_only:          # LiteMessages only: pymavlink's still pack as before
            layout = _Layout(mav.mavlink_map[msgid], chars=True)
            self.by_lite[layout.lite] = layout
        self.by_prepacked: dict[type, _Layout] = {
            prepacked_class(msgid): self.by_id[msgid] for msgid in ids}

    def pack(self, msg: Any, packer: Any) -> bytes | None:
        """The frame ``msg.pack(packer)`` would return (same bytes, same signing timestamp
        step), or None if ``msg`` is not a hot message (the caller uses pymavlink).
        Unlike pymavlink, ``msg`` is not modified (no ``_msgbuf``/``_header`` cached on it).
        A :class:`LiteMessage` (:func:`lite_class`) is packed from its tuple, a
        :class:`Prepacked` is framed from its payload.
        """
        layout = self.by_class.get(type(msg))
        if layout is not None:
            payload = layout.pack(msg)
        else:
            layout = self.by_lite.get(type(msg))
            if layout is None:
                layout = self.by_prepacked.get(type(msg))
                if layout is None:
                    return None
                return self.frame(layout, msg[0], packer)
            payload = layout.pack_wire(*msg[:-1])
        return self.frame(layout, payload.rstrip(b"\x00") or payload[:1], packer)

    def frame(self, layout: _Layout, trimmed: bytes, packer: Any) -> bytes:
        """The frame of one payload, already trimmed (MAVLink 2: its trailing zeros cut,
        ≥ 1 byte), with ``packer``'s sequence number, ids and signing."""
        signing = packer.signing
        signed = signing.sign_outgoing
        msgid = layout.msgid
        buf = _HEADER.pack(0xFD, len(trimmed), _IFLAG_SIGNED if signed else 0, 0, packer.seq,
                           packer.srcSystem, packer.srcComponent, msgid & 0xFFFF,
                           msgid >> 16) + trimmed
        crc = _crc16(layout.crc_extra_byte, _crc16(buf[1:], 0xFFFF))
        buf += crc.to_bytes(2, "little")
        if signed:
            buf += _SIGN_BLOCK.pack(signing.link_id, signing.timestamp)[:7]
            h = hashlib.sha256(signing.secret_key)
            h.update(buf)
            buf += h.digest()[:6]
            signing.timestamp += 1
        return buf

    def pack_many(self, msgs: Iterable[Any], packer: Any) -> list[bytes]:
        """The frames of ``msgs`` on consecutive sequence numbers (``packer.seq`` advanced
        past them), as :meth:`pack` (or pymavlink, for a message that is not hot) makes each
        one. Unsigned, a :class:`Prepacked` message is framed here with the packer's fields
        read once for the batch (the vehicle's per-tick datagram)."""
        frames: list[bytes] = []
        append = frames.append
        if packer.signing.sign_outgoing:
            for msg in msgs:
                append(self.pack(msg, packer) or msg.pack(packer))
                packer.seq = (packer.seq + 1) & 0xFF
            return frames
        prepacked = self.by_prepacked.get
        head = _HEADER.pack
        crc16 = _crc16
        seq, src_system, src_component = packer.seq, packer.srcSystem, packer.srcComponent
        ids = src_system << 8 | src_component
        for msg in msgs:
            layout = prepacked(type(msg))
            if layout is None:
                packer.seq = seq
                append(self.pack(msg, packer) or msg.pack(packer))
            else:   # frame() unsigned, on the parts (a CRC carries over its input's pieces)
                payload = msg[0]
                # the header and the CRC over it, kept per (length, seq, ids): a sender's
                # few lengths × 256 sequence numbers
                key = len(payload) << 24 | seq << 16 | ids
                known = layout.headers.get(key)
                if known is None:
                    msgid = layout.msgid
                    header = head(0xFD, len(payload), 0, 0, seq, src_system, src_component,
                                  msgid & 0xFFFF, msgid >> 16)
                    known = (header, crc16(header[1:], 0xFFFF))
                    if len(layout.headers) < _MAX_HEADERS:
                        layout.headers[key] = known
                header, crc = known
                crc = crc16(layout.crc_extra_byte, crc16(payload, crc))
                append(header + payload + crc.to_bytes(2, "little"))
            seq = (seq + 1) & 0xFF
        packer.seq = seq
        return frames

    def _checked(self, raw: bytes, parser: Any) -> tuple[Any, int, int] | None:
        """(layout, payload end, CRC) of a hot message's frame whose CRC checks (counting a
        signature as pymavlink's parser does), None if not a hot message; raises
        ``mav.MAVError`` for a bad CRC, as pymavlink does."""
        layout = self.by_id.get(raw[7] | raw[8] << 8 | raw[9] << 16)
        if layout is None:
            return None
        sig_len = _SIGNATURE_LEN if raw[2] & _IFLAG_SIGNED else 0
        end = len(raw) - 2 - sig_len
        crc = raw[end] | raw[end + 1] << 8
        if _crc16(layout.crc_extra_byte, _crc16(raw[1:end], 0xFFFF)) != crc:
            raise mav.MAVError(f"invalid MAVLink CRC in msgID {layout.msgid} 0x{crc:04x}")
        if sig_len:
            parser.signing.sig_count += 1
        return layout, end, crc

    def decode(self, raw: bytes, parser: Any) -> Any:
        """What ``parser.decode(bytearray(raw))`` returns for a complete MAVLink 2 frame of a
        hot message: the message, or ``mav.MAVError`` raised for a bad CRC. None if the
        frame is not a hot message (the caller uses pymavlink). ``parser`` must not hold a
        signing key (the link verifies signatures itself, before decoding)."""
        checked = self._checked(raw, parser)
        if checked is None:
            return None
        layout, end, crc = checked
        incompat = raw[2]
        d = layout.fields(layout.unpack(frame_payload(raw, layout.size, end)))
        msgbuf = bytearray(raw)
        d["_msgbuf"] = msgbuf
        d["_payload"] = msgbuf[6:end]        # sic: pymavlink slices from 6, as here
        d["_crc"] = crc
        d["_header"] = mav.MAVLink_header(layout.msgid, incompat, raw[3], raw[1], raw[4],
                                          raw[5], raw[6])
        msg = object.__new__(layout.cls)
        msg.__dict__ = d
        return msg

    def decode_lite(self, raw: bytes, parser: Any) -> LiteMessage | None:
        """:meth:`decode`, with the same checks and errors, answering a :class:`LiteMessage`
        (``raw`` must be ``bytes``: the message keeps it)."""
        checked = self._checked(raw, parser)
        if checked is None:
            return None
        layout, end, _crc = checked
        return _new_tuple(layout.rx_lite,
                          (*layout.rx_unpack(frame_payload(raw, layout.size, end)), raw))


class SkimmedMessage:
    """A frame that passed every check pymavlink's ``decode`` makes (known id, CRC, the
    signature count) but was not decoded: for messages a receiver only routes, counts or
    records by their bytes (the vehicle ignores the daemon's NAMED_VALUE_FLOAT and
    DEBUG_FLOAT_ARRAY telemetry; the recorders decode ``raw`` themselves). The ``get_*``
    header methods answer from the frame; any field is decoded by pymavlink on first read,
    so ``m.value`` is what pymavlink's message would say (tests/contract/test_link_skim.py)."""

    __slots__ = ("_decoded", "raw")

    def __init__(self, raw: bytes) -> None:
        self.raw = raw
        self._decoded: Any = None

    def get_msgId(self) -> int:
        raw = self.raw
        return raw[7] | raw[8] << 8 | raw[9] << 16

    def get_type(self) -> str:
        return str(mav.mavlink_map[self.get_msgId()].msgname)

    def get_srcSystem(self) -> int:
        return int(self.raw[5])

    def get_srcComponent(self) -> int:
        return int(self.raw[6])

    def get_seq(self) -> int:
        return int(self.raw[4])

    def decoded(self) -> Any:
        """pymavlink's message of the frame (decoded once, by a parser of its own, so the
        link's parser counts the frame's signature once, as when it was checked)."""
        if self._decoded is None:
            self._decoded = mav.MAVLink(None).decode(bytearray(self.raw))
        return self._decoded

    def __getattr__(self, name: str) -> Any:
        if name.startswith("__"):
            raise AttributeError(name)
        return getattr(self.decoded(), name)

    def __str__(self) -> str:
        return str(self.decoded())


def skim(raw: bytes, parser: Any) -> SkimmedMessage | None:
    """What ``parser.decode(bytearray(raw))`` accepts or rejects, without decoding: a
    :class:`SkimmedMessage` for a complete MAVLink 2 frame of a known message whose CRC
    checks (a signature counted on ``parser``, as its decode counts it), ``mav.MAVError``
    for a bad CRC, None for an id not in the dialect (the caller lets pymavlink answer).
    As for :meth:`FastCodec.decode`, ``parser`` holds no signing key: the link verifies."""
    cls = mav.mavlink_map.get(raw[7] | raw[8] << 8 | raw[9] << 16)
    if cls is None:
        return None
    sig_len = _SIGNATURE_LEN if raw[2] & _IFLAG_SIGNED else 0
    end = len(raw) - 2 - sig_len
    crc = raw[end] | raw[end + 1] << 8
    if _crc16(bytes((cls.crc_extra,)), _crc16(raw[1:end], 0xFFFF)) != crc:
        raise mav.MAVError(f"invalid MAVLink CRC in msgID {cls.id} 0x{crc:04x}")
    if sig_len:
        parser.signing.sig_count += 1
    return SkimmedMessage(raw)
