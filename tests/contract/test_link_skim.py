"""Skimmed messages (``Link(skim_ids=...)``): checked and counted as pymavlink's decode checks
them, handed out undecoded, and read (when read at all) as pymavlink's message reads."""

from __future__ import annotations

import socket

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tfl_mav.link.codec import SkimmedMessage, skim
from tfl_mav.link.dialect import mav, new_mavlink
from tfl_mav.link.signing import Signing
from tfl_mav.link.transport import Link

LOOPBACK = ("127.0.0.1", 0)
TELEMETRY = (mav.MAVLINK_MSG_ID_NAMED_VALUE_FLOAT, mav.MAVLINK_MSG_ID_DEBUG_FLOAT_ARRAY)
KEY = bytes(range(32))


def telemetry(value: float = 1.5, data=(0.25,) * 58) -> list:
    """What the daemon sends the vehicle at ≤ 50 Hz (tfl_mav.controller.daemon._telemetry)."""
    return [mav.MAVLink_named_value_float_message(7, b"atk_est_n", value),
            mav.MAVLink_named_value_float_message(7, b"mode", 2.0),
            mav.MAVLink_debug_float_array_message(7000, b"tfl", 1, list(data))]


def receive_both(datagrams: list[bytes], *, signing: bool = False) -> tuple[Link, Link, list,
                                                                           list]:
    """The same datagrams (from one pinned sender) through a skimming and a plain link."""
    links = [Link.listen(LOOPBACK, src_system=1, src_component=1, peer=None,
                         signing=Signing(KEY) if signing else None,
                         skim_ids=TELEMETRY if skim_it else ())
             for skim_it in (True, False)]
    sender = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sender.bind(LOOPBACK)
    got: list[list] = [[], []]
    try:
        for link in links:
            link.peer = sender.getsockname()
            link.peer_sysid = 2
            for d in datagrams:
                sender.sendto(d, link.local_address)
        for i, link in enumerate(links):
            for _ in range(50):
                got[i] += link.recv(0.05)
                if link.stats.rx_datagrams >= len(datagrams):
                    break
    finally:
        sender.close()
        for link in links:
            link.close()
    return links[0], links[1], got[0], got[1]


def packed(msgs, *, signing: bool = False) -> bytes:
    packer = new_mavlink(2, 191)
    if signing:
        Signing(KEY).configure_packer(packer, 0)
    return b"".join(bytes(m.pack(packer)) for m in msgs)


def test_skimmed_frames_count_and_read_as_decoded_ones():
    skimmed, plain, got_s, got_p = receive_both([packed(telemetry())])
    assert skimmed.stats == plain.stats
    assert len(got_s) == len(got_p) == 3
    for s, p in zip(got_s, got_p, strict=True):
        assert isinstance(s, SkimmedMessage)
        assert not isinstance(p, SkimmedMessage)
        assert (s.get_msgId(), s.get_type(), s.get_srcSystem(), s.get_srcComponent(),
                s.get_seq()) == (p.get_msgId(), p.get_type(), p.get_srcSystem(),
                                 p.get_srcComponent(), p.get_seq())
        assert s.to_dict() == p.to_dict()
        assert str(s) == str(p)
    assert got_s[0].value == 1.5 and got_s[0].name == got_p[0].name


def test_a_bad_crc_or_unknown_id_is_rejected_as_before():
    good = bytearray(packed(telemetry()[:1]))
    bad = bytes(good[:-3]) + bytes([good[-3] ^ 0x40]) + bytes(good[-2:])   # payload flipped
    skimmed, plain, got_s, got_p = receive_both([bad, bytes(good)])
    assert skimmed.stats == plain.stats
    assert skimmed.stats.bad_crc == 1 and len(got_s) == len(got_p) == 1


def test_signed_frames_verify_and_count_as_decoded_ones():
    skimmed, plain, got_s, got_p = receive_both([packed(telemetry(), signing=True)],
                                                signing=True)
    assert skimmed.stats == plain.stats
    assert skimmed.stats.rx_frames == 3
    assert skimmed.receiver.parser.signing.sig_count == plain.receiver.parser.signing.sig_count == 3
    assert [m.to_dict() for m in got_s] == [m.to_dict() for m in got_p]


@settings(max_examples=200, deadline=None)
@given(value=st.floats(width=32), data=st.lists(st.floats(width=32), min_size=58, max_size=58),
       flip=st.integers(0, 200))
def test_skim_accepts_and_rejects_exactly_what_pymavlink_decodes(value, data, flip):
    """Any frame, intact or with one byte flipped past the header: skim raises where
    pymavlink's decode raises, and the fields read back are pymavlink's."""
    for msg in telemetry(value, data):
        raw = bytearray(packed([msg]))
        if flip < len(raw) - 10:
            raw[10 + flip] ^= 0x5A
        raw = bytes(raw)
        try:
            ref = new_mavlink(1, 1).decode(bytearray(raw))
        except mav.MAVError:
            with pytest.raises(mav.MAVError, match="CRC"):
                skim(raw, new_mavlink(1, 1))
            continue
        got = skim(raw, new_mavlink(1, 1))
        assert got is not None
        assert repr(got.to_dict()) == repr(ref.to_dict())   # NaN-safe, to the bit
