"""The precompiled codec of the hot messages (tfl_mav.link.codec) against pymavlink itself:
the same frame bytes when packing (signed or not, trailing zeros truncated), the same message
(every attribute pymavlink's ``decode`` sets) or the same error when decoding any payload
length, with or without a signature block. Random messages from hypothesis."""

from __future__ import annotations

import struct
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tfl_mav.link.codec import (
    HOT_MESSAGE_IDS,
    LAZY_FIELDS,
    PACK_ONLY_IDS,
    UNSENT,
    FastCodec,
    lite_class,
    prepacked_class,
    rx_lite_class,
    trim,
)
from tfl_mav.link.dialect import mav, new_mavlink
from tfl_mav.link.transport import Link

CODEC = FastCodec()
_INT_RANGES = {
    "uint8_t": (0, 2**8 - 1), "int8_t": (-2**7, 2**7 - 1),
    "uint16_t": (0, 2**16 - 1), "int16_t": (-2**15, 2**15 - 1),
    "uint32_t": (0, 2**32 - 1), "int32_t": (-2**31, 2**31 - 1),
    "uint64_t": (0, 2**64 - 1), "int64_t": (-2**63, 2**63 - 1),
}


def _value(ftype: str) -> st.SearchStrategy[Any]:
    """Values of one wire type, zero often (so MAVLink 2 truncation is exercised)."""
    if ftype in ("float", "double"):
        width = 32 if ftype == "float" else 64
        return st.one_of(st.just(0.0), st.floats(width=width, allow_nan=True,
                                                 allow_infinity=True))
    lo, hi = _INT_RANGES[ftype]
    return st.one_of(st.just(0), st.integers(lo, hi))


@st.composite
def hot_messages(draw: st.DrawFn) -> Any:
    cls = mav.mavlink_map[draw(st.sampled_from(HOT_MESSAGE_IDS))]
    tail_zero = draw(st.booleans())          # all-zero tail: a truncated frame
    lengths = dict(zip(cls.ordered_fieldnames, cls.array_lengths, strict=True))
    args = []
    for name, ftype in zip(cls.fieldnames, cls.fieldtypes, strict=True):
        n = lengths[name]
        value = _value(ftype)
        if tail_zero:
            value = st.just(0.0 if ftype in ("float", "double") else 0)
        args.append(draw(st.lists(value, min_size=n, max_size=n)) if n else draw(value))
    return cls(*args)


def _packer(sysid: int, compid: int, seq: int, signing: tuple[bytes, int, int] | None
            ) -> Any:
    packer = new_mavlink(sysid, compid)
    packer.seq = seq
    if signing is not None:
        key, link_id, timestamp = signing
        packer.signing.secret_key = key
        packer.signing.link_id = link_id
        packer.signing.timestamp = timestamp
        packer.signing.sign_outgoing = True
    return packer


signings = st.one_of(st.none(), st.tuples(st.binary(min_size=32, max_size=32),
                                          st.integers(0, 255), st.integers(0, 2**48 - 2)))


@settings(max_examples=400, deadline=None)
@given(msg=hot_messages(), sysid=st.integers(1, 255), compid=st.integers(0, 255),
       seq=st.integers(0, 255), signing=signings)
def test_pack_is_pymavlinks_frame(msg: Any, sysid: int, compid: int, seq: int,
                                  signing: tuple[bytes, int, int] | None) -> None:
    ours, theirs = _packer(sysid, compid, seq, signing), _packer(sysid, compid, seq, signing)
    frame = CODEC.pack(msg, ours)
    assert frame == msg.pack(theirs)
    assert ours.signing.timestamp == theirs.signing.timestamp   # one step per signed frame


def _wire_values(msg: Any) -> list[Any]:
    """A pymavlink message's field values in wire order, arrays flattened."""
    cls = type(msg)
    values: list[Any] = []
    for name, n in zip(cls.ordered_fieldnames, cls.array_lengths, strict=True):
        value = getattr(msg, name)
        values += list(value[:n]) if n else [value]
    return values


@settings(max_examples=300, deadline=None)
@given(msg=hot_messages(), seq=st.integers(0, 255), signing=signings)
def test_built_lite_message_packs_as_pymavlinks(msg: Any, seq: int,
                                                signing: tuple[bytes, int, int] | None
                                                ) -> None:
    """A LiteMessage a sender builds (wire tuple + UNSENT) packs to pymavlink's frame of the
    message with the same fields, and reads its fields as that message does."""
    lite = tuple.__new__(lite_class(msg.get_msgId()), (*_wire_values(msg), UNSENT))
    ours, theirs = _packer(1, 1, seq, signing), _packer(1, 1, seq, signing)
    assert CODEC.pack(lite, ours) == msg.pack(theirs)
    assert ours.signing.timestamp == theirs.signing.timestamp
    for name in msg.get_fieldnames():
        assert repr(getattr(lite, name)) == repr(getattr(msg, name)), name
    assert lite.get_srcSystem() == 0 and lite.get_type() == msg.get_type()


@st.composite
def pack_only_messages(draw: st.DrawFn) -> tuple[Any, tuple[Any, ...]]:
    """(pymavlink's message, the same fields in wire order with the char field as bytes)."""
    cls = mav.mavlink_map[draw(st.sampled_from(PACK_ONLY_IDS))]
    lengths = dict(zip(cls.ordered_fieldnames, cls.array_lengths, strict=True))
    kwargs: dict[str, Any] = {}
    for name, ftype in zip(cls.fieldnames, cls.fieldtypes, strict=True):
        n = lengths[name]
        if ftype == "char":     # a name: up to 10 printable bytes, NUL-padded on the wire
            kwargs[name] = draw(st.binary(min_size=0, max_size=n).filter(
                lambda b: b"\x00" not in b))
            continue
        value = _value(ftype)
        kwargs[name] = draw(st.lists(value, min_size=n, max_size=n)) if n else draw(value)
    wire: list[Any] = []
    for name, n in zip(cls.ordered_fieldnames, cls.array_lengths, strict=True):
        value = kwargs[name]
        wire += list(value) if n and not isinstance(value, bytes) else [value]
    return cls(**kwargs), tuple(wire)


@settings(max_examples=300, deadline=None)
@given(msgs=st.lists(hot_messages(), min_size=1, max_size=4), seq=st.integers(0, 255),
       signing=signings, split=st.integers(0, 80), ids=st.sampled_from([(1, 1), (7, 191)]))
def test_prepacked_messages_pack_as_pymavlinks(msgs: list[Any], seq: int,
                                               signing: tuple[bytes, int, int] | None,
                                               split: int, ids: tuple[int, int]) -> None:
    """A Prepacked message (payload packed by its sender, values split anywhere into head
    and tail) frames to pymavlink's bytes, alone or in a batch (pack_many: consecutive
    sequence numbers, mixed with pymavlink's own messages); its fields read as pymavlink's."""
    built: list[Any] = []
    for i, msg in enumerate(msgs):
        wire = _wire_values(msg)
        if i % 2:        # every other one left to pymavlink, to mix the batch
            built.append(msg)
            continue
        cls = prepacked_class(msg.get_msgId())
        payload = trim(type(msg).unpacker.pack(*wire))
        pre = tuple.__new__(cls, (payload, tuple(wire[:split]), tuple(wire[split:])))
        assert pre.get_msgId() == msg.get_msgId()
        for name in msg.get_fieldnames():
            assert repr(getattr(pre, name)) == repr(getattr(msg, name))
        built.append(pre)
    ours, theirs = _packer(*ids, seq, signing), _packer(*ids, seq, signing)
    frames = CODEC.pack_many(built, ours)
    expected = []
    for msg in msgs:
        expected.append(bytes(msg.pack(theirs)))
        theirs.seq = (theirs.seq + 1) & 0xFF
    assert [bytes(f) for f in frames] == expected
    assert ours.seq == theirs.seq
    assert ours.signing.timestamp == theirs.signing.timestamp
    one = _packer(*ids, seq, signing)
    assert CODEC.pack(built[0], one) == expected[0]   # (same frames: the cached headers)


@settings(max_examples=300, deadline=None)
@given(pair=pack_only_messages(), seq=st.integers(0, 255), signing=signings)
def test_pack_only_lite_message_packs_as_pymavlinks(pair: tuple[Any, tuple[Any, ...]],
                                                     seq: int,
                                                     signing: tuple[bytes, int, int] | None
                                                     ) -> None:
    """The controller's telemetry (NAMED_VALUE_FLOAT, DEBUG_FLOAT_ARRAY) built as a
    LiteMessage, name as bytes, packs to pymavlink's frame; decoding stays pymavlink's."""
    msg, wire = pair
    lite = tuple.__new__(lite_class(msg.get_msgId()), (*wire, UNSENT))
    ours, theirs = _packer(1, 191, seq, signing), _packer(1, 191, seq, signing)
    assert CODEC.pack(lite, ours) == msg.pack(theirs)
    assert ours.signing.timestamp == theirs.signing.timestamp
    assert CODEC.pack(msg, _packer(1, 191, seq, None)) is None   # pymavlink's: not compiled
    assert msg.get_msgId() not in CODEC.by_id                    # never decoded here


def test_lite_class_is_shared_and_only_for_hot_messages() -> None:
    """Every codec packs the LiteMessages another module built (one class per message)."""
    cls = lite_class(mav.MAVLINK_MSG_ID_ODOMETRY)
    assert cls is lite_class(mav.MAVLINK_MSG_ID_ODOMETRY)
    assert cls in FastCodec().by_lite
    with pytest.raises(ValueError, match="not compiled"):
        lite_class(mav.MAVLINK_MSG_ID_STATUSTEXT)


def _same(a: Any, b: Any) -> None:
    """Every attribute equal (NaN equal to NaN: compared by repr), headers by value."""
    da, db = dict(vars(a)), dict(vars(b))
    ha, hb = vars(da.pop("_header")), vars(db.pop("_header"))
    assert ha == hb
    assert type(a) is type(b)
    assert {k: repr(v) for k, v in da.items()} == {k: repr(v) for k, v in db.items()}


def _frame(msgid: int, payload: bytes, signature: bytes | None, crc_ok: bool,
           seq: int = 7) -> bytes:
    cls = mav.mavlink_map[msgid]
    header = struct.pack("<BBBBBBBHB", 0xFD, len(payload), 1 if signature else 0, 0, seq, 3,
                         191, msgid & 0xFFFF, msgid >> 16)
    crc = mav.x25crc(header[1:] + payload)
    crc.accumulate(bytes([cls.crc_extra]))
    value = crc.crc if crc_ok else crc.crc ^ 0x0101
    return header + payload + struct.pack("<H", value) + (signature or b"")


@settings(max_examples=400, deadline=None)
@given(msgid=st.sampled_from(HOT_MESSAGE_IDS), data=st.data(),
       signature=st.one_of(st.none(), st.binary(min_size=13, max_size=13)),
       crc_ok=st.booleans())
def test_decode_is_pymavlinks_message(msgid: int, data: st.DataObject,
                                      signature: bytes | None, crc_ok: bool) -> None:
    """Any payload length 1..255 (short ones are zero-padded, long ones cut, as pymavlink
    does), signed or not, good or bad CRC."""
    size = mav.mavlink_map[msgid].unpacker.size
    payload = data.draw(st.binary(min_size=1, max_size=min(255, size + 20)))
    raw = _frame(msgid, payload, signature, crc_ok)
    ours_parser, theirs_parser = new_mavlink(1, 1), new_mavlink(1, 1)
    try:
        expected = theirs_parser.decode(bytearray(raw))
    except mav.MAVError:
        with pytest.raises(mav.MAVError):
            CODEC.decode(raw, ours_parser)
        return
    got = CODEC.decode(raw, ours_parser)
    _same(got, expected)
    assert ours_parser.signing.sig_count == theirs_parser.signing.sig_count


@settings(max_examples=200, deadline=None)
@given(msg=hot_messages(), signing=signings)
def test_round_trip_through_pymavlink_pack(msg: Any,
                                           signing: tuple[bytes, int, int] | None) -> None:
    raw = msg.pack(_packer(5, 6, 200, signing))
    _same(CODEC.decode(raw, new_mavlink(1, 1)), new_mavlink(1, 1).decode(bytearray(raw)))


def test_other_messages_are_left_to_pymavlink() -> None:
    msg = mav.MAVLink_statustext_message(6, b"hello", 0, 0)
    assert CODEC.pack(msg, new_mavlink(1, 1)) is None
    raw = msg.pack(new_mavlink(1, 1))
    assert CODEC.decode(raw, new_mavlink(1, 1)) is None


def _same_lite(lite: Any, full: Any) -> None:
    """A LiteMessage answers every field and method as pymavlink's message does."""
    for name in full.get_fieldnames():
        assert repr(getattr(lite, name)) == repr(getattr(full, name)), name
    for method in ("get_msgId", "get_type", "get_fieldnames", "get_srcSystem",
                   "get_srcComponent", "get_seq", "get_signed", "get_link_id", "get_msgbuf",
                   "get_payload", "get_crc"):
        assert getattr(lite, method)() == getattr(full, method)(), method
    assert vars(lite.get_header()) == vars(full.get_header())
    assert repr(lite.to_dict()) == repr(full.to_dict())
    assert str(lite) == str(full)


@settings(max_examples=400, deadline=None)
@given(msgid=st.sampled_from(HOT_MESSAGE_IDS), data=st.data(),
       signature=st.one_of(st.none(), st.binary(min_size=13, max_size=13)),
       crc_ok=st.booleans())
def test_decode_lite_reads_as_pymavlinks_message(msgid: int, data: st.DataObject,
                                                 signature: bytes | None,
                                                 crc_ok: bool) -> None:
    """What the Link hands out: same error, same fields and methods, any payload length."""
    size = mav.mavlink_map[msgid].unpacker.size
    payload = data.draw(st.binary(min_size=1, max_size=min(255, size + 20)))
    raw = _frame(msgid, payload, signature, crc_ok)
    ours_parser, theirs_parser = new_mavlink(1, 1), new_mavlink(1, 1)
    try:
        expected = theirs_parser.decode(bytearray(raw))
    except mav.MAVError as exc:
        with pytest.raises(mav.MAVError, match="CRC" if "CRC" in exc.message else None):
            CODEC.decode_lite(raw, ours_parser)
        return
    _same_lite(CODEC.decode_lite(raw, ours_parser), expected)
    assert ours_parser.signing.sig_count == theirs_parser.signing.sig_count


@settings(max_examples=200, deadline=None)
@given(msg=hot_messages(), signing=signings)
def test_decode_lite_round_trip(msg: Any, signing: tuple[bytes, int, int] | None) -> None:
    raw = bytes(msg.pack(_packer(5, 6, 200, signing)))
    _same_lite(CODEC.decode_lite(raw, new_mavlink(1, 1)),
               new_mavlink(1, 1).decode(bytearray(raw)))
    statustext = mav.MAVLink_statustext_message(6, b"hello", 0, 0).pack(new_mavlink(1, 1))
    assert CODEC.decode_lite(bytes(statustext), new_mavlink(1, 1)) is None


_PEER = ("127.0.0.1", 9)


@settings(max_examples=300, deadline=None)
@given(frames=st.lists(st.tuples(st.sampled_from(HOT_MESSAGE_IDS), st.data(),
                                 st.one_of(st.none(), st.binary(min_size=13, max_size=13)),
                                 st.booleans()), min_size=1, max_size=4))
def test_link_receive_loop_is_pymavlinks_decode(
        frames: list[tuple[int, st.DataObject, bytes | None, bool]]) -> None:
    """The Link's receive loop decodes the per-tick messages inline (tfl_mav.link.receive):
    one datagram of several frames, any payload length, signed or not, good or bad CRC,
    gives what pymavlink's decode gives frame by frame: the same messages (as
    LiteMessages), a bad CRC counted ``bad_crc``, the same signature count."""
    raws = []
    for msgid, data, signature, crc_ok in frames:
        size = mav.mavlink_map[msgid].unpacker.size
        payload = data.draw(st.binary(min_size=1, max_size=min(255, size + 20)))
        raws.append(_frame(msgid, payload, signature, crc_ok))
    theirs_parser = new_mavlink(1, 1)
    expected, bad_crc = [], 0
    for raw in raws:
        try:
            expected.append(theirs_parser.decode(bytearray(raw)))
        except mav.MAVError as exc:
            assert "CRC" in exc.message
            bad_crc += 1
    link = Link.listen(("127.0.0.1", 0), src_system=1, src_component=1, peer=_PEER,
                       peer_sysid=3)
    try:
        out: list[Any] = []
        link.receiver.ingest(b"".join(raws), _PEER, out)
    finally:
        link.close()
    assert len(out) == len(expected)
    for got, full in zip(out, expected, strict=True):
        _same_lite(got, full)
    st_ = link.stats
    assert (st_.rx_frames, st_.bad_crc, st_.rejected) == (len(expected), bad_crc, bad_crc)
    assert link.receiver.parser.signing.sig_count == theirs_parser.signing.sig_count


@settings(max_examples=100, deadline=None)
@given(msg=hot_messages())
def test_a_received_message_packs_as_pymavlinks(msg: Any) -> None:
    """A received LiteMessage (ODOMETRY's leaves its covariances in the frame bytes,
    LAZY_FIELDS) sent on again packs to the bytes pymavlink's decoded message packs to."""
    raw = bytes(msg.pack(_packer(5, 6, 200, None)))
    lite = CODEC.decode_lite(raw, new_mavlink(1, 1))
    full = new_mavlink(1, 1).decode(bytearray(raw))
    assert CODEC.pack(lite, new_mavlink(3, 4)) == bytes(full.pack(new_mavlink(3, 4)))
    if msg.get_msgId() in LAZY_FIELDS:
        assert type(lite) is rx_lite_class(msg.get_msgId())
        cls = type(full)
        kept = sum(max(1, n) for name, n in zip(cls.ordered_fieldnames, cls.array_lengths,
                                                 strict=True)
                   if name not in LAZY_FIELDS[msg.get_msgId()])
        assert len(lite) == kept + 1      # the values unpacked, then the frame bytes
