"""The UDP link: peer pinning, MAVLink 2 only, every rejected datagram counted by reason."""

from __future__ import annotations

import socket
import struct

import pytest

from tfl_mav.link.dialect import mav, new_mavlink
from tfl_mav.link.transport import Link, LinkError, finite_fields, nonfinite_field, parse_address

LOOPBACK = ("127.0.0.1", 0)
WAIT_S = 1.0


def heartbeat():
    return mav.MAVLink_heartbeat_message(mav.MAV_TYPE_ONBOARD_CONTROLLER,
                                         mav.MAV_AUTOPILOT_INVALID, 0, 0, 0, 3)


def controls(time_usec=1000, values=(0.5, 0.5, 0.5, 0.5)):
    return mav.MAVLink_hil_actuator_controls_message(time_usec, [*values] + [0.0] * 12, 128, 1)


def frame(msg, sysid=2, compid=191) -> bytes:
    return bytes(msg.pack(new_mavlink(sysid, compid)))


def mavlink1_heartbeat(sysid=2, compid=191) -> bytes:
    """A valid MAVLink 1 HEARTBEAT (magic 0xFE, correct CRC)."""
    payload = struct.pack("<IBBBBB", 0, mav.MAV_TYPE_ONBOARD_CONTROLLER, 8, 0, 0, 3)
    header = struct.pack("<BBBBBB", 0xFE, len(payload), 0, sysid, compid, 0)
    crc = mav.x25crc(header[1:] + payload)
    crc.accumulate(bytes([mav.MAVLink_heartbeat_message.crc_extra]))
    return header + payload + struct.pack("<H", crc.crc)


def unknown_id_frame(msgid=60000, sysid=2, compid=191) -> bytes:
    payload = b"\x01\x02\x03"
    header = struct.pack("<BBBBBBBHB", 0xFD, len(payload), 0, 0, 0, sysid, compid,
                         msgid & 0xFFFF, msgid >> 16)
    return header + payload + b"\x00\x00"


class Raw:
    """A bare UDP socket: sends bytes exactly as given from its own address."""

    def __init__(self) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(LOOPBACK)

    def send(self, data: bytes, to) -> None:
        self.sock.sendto(data, to)

    def close(self) -> None:
        self.sock.close()


@pytest.fixture
def vehicle_side():
    link = Link.listen(LOOPBACK, src_system=1, src_component=1)
    yield link
    link.close()


@pytest.fixture
def raw():
    r = Raw()
    yield r
    r.close()


def drain(link: Link, expect_datagrams: int) -> list:
    """Receive until the link has seen ``expect_datagrams`` datagrams in total."""
    out: list = []
    for _ in range(50):
        out += link.recv(0.05)
        if link.stats.rx_datagrams >= expect_datagrams:
            break
    out += link.recv(0.0)
    return out


def test_peer_is_learned_from_the_first_heartbeat_and_pinned(vehicle_side, raw):
    addr = vehicle_side.local_address
    raw.send(frame(controls()), addr)            # before any HEARTBEAT: not a peer yet
    raw.send(frame(heartbeat()), addr)
    msgs = drain(vehicle_side, 2)
    assert [m.get_type() for m in msgs] == ["HEARTBEAT"]
    assert vehicle_side.stats.no_peer == 1
    assert vehicle_side.peer == raw.sock.getsockname()
    assert vehicle_side.peer_sysid == 2
    raw.send(frame(controls()), addr)             # now accepted
    assert [m.get_type() for m in drain(vehicle_side, 3)] == ["HIL_ACTUATOR_CONTROLS"]


def test_foreign_sender_is_dropped_and_never_answered(vehicle_side, raw):
    addr = vehicle_side.local_address
    raw.send(frame(heartbeat()), addr)
    drain(vehicle_side, 1)
    intruder = Raw()
    try:
        intruder.send(frame(heartbeat()), addr)
        intruder.send(frame(controls()), addr)
        assert drain(vehicle_side, 3) == []
        assert vehicle_side.stats.foreign == 2
        assert vehicle_side.peer == raw.sock.getsockname()
        vehicle_side.send(heartbeat())
        intruder.sock.settimeout(0.1)
        with pytest.raises(TimeoutError):
            intruder.sock.recvfrom(1024)          # nothing goes to the intruder
        raw.sock.settimeout(WAIT_S)
        assert raw.sock.recvfrom(1024)[0][0] == 0xFD
    finally:
        intruder.close()


def test_other_sysid_from_the_peer_address_is_dropped(vehicle_side, raw):
    addr = vehicle_side.local_address
    raw.send(frame(heartbeat(), sysid=2), addr)
    raw.send(frame(controls(), sysid=99), addr)
    assert [m.get_type() for m in drain(vehicle_side, 2)] == ["HEARTBEAT"]
    assert vehicle_side.stats.wrong_sysid == 1


def test_pinned_peer_rejects_everyone_else_even_with_heartbeats(raw):
    intruder = Raw()
    link = Link.listen(LOOPBACK, src_system=1, src_component=1, peer=raw.sock.getsockname())
    try:
        intruder.send(frame(heartbeat()), link.local_address)
        raw.send(frame(heartbeat()), link.local_address)
        assert [m.get_type() for m in drain(link, 2)] == ["HEARTBEAT"]
        assert link.stats.foreign == 1
    finally:
        link.close()
        intruder.close()


BAD_DATAGRAMS = {
    "garbage": b"\x00hello, this is not MAVLink",
    "mavlink1": mavlink1_heartbeat(),
    "truncated": frame(controls())[:-5],
    "bad_crc": (lambda b: b[:-1] + bytes([b[-1] ^ 0xFF]))(frame(controls())),
    "unknown_id": unknown_id_frame(),
    "bad_flags": (lambda b: b[:2] + b"\x80" + b[3:])(frame(controls())),
    "wrong_length": (lambda b: b[:1] + bytes([b[1] + 3]) + b[2:] + b"\x00\x00\x00")(
        frame(heartbeat())),   # header length grown to match: the CRC no longer does
}


COUNTER = {"wrong_length": "bad_crc"}


@pytest.mark.parametrize("reason", sorted(BAD_DATAGRAMS))
def test_each_bad_datagram_is_counted_once_and_the_link_keeps_working(vehicle_side, raw,
                                                                      reason):
    addr = vehicle_side.local_address
    raw.send(frame(heartbeat()), addr)
    drain(vehicle_side, 1)
    raw.send(BAD_DATAGRAMS[reason], addr)
    raw.send(frame(controls(time_usec=42)), addr)
    msgs = drain(vehicle_side, 3)
    assert [(m.get_type(), m.time_usec) for m in msgs] == [("HIL_ACTUATOR_CONTROLS", 42)]
    counts = vehicle_side.stats.as_dict()
    assert counts[COUNTER.get(reason, reason)] == 1, counts
    assert vehicle_side.stats.rejected == 1, counts


def test_a_bad_frame_does_not_swallow_the_next_datagram(vehicle_side, raw):
    addr = vehicle_side.local_address
    raw.send(frame(heartbeat()), addr)
    raw.send(frame(controls())[:20], addr)        # header promises more than arrives
    raw.send(frame(controls(time_usec=7)), addr)
    msgs = drain(vehicle_side, 3)
    assert [m.get_type() for m in msgs] == ["HEARTBEAT", "HIL_ACTUATOR_CONTROLS"]
    assert msgs[1].time_usec == 7
    assert vehicle_side.stats.truncated == 1


def test_several_frames_in_one_datagram_are_all_decoded(vehicle_side, raw):
    blob = frame(heartbeat()) + frame(controls(time_usec=1)) + frame(controls(time_usec=2))
    raw.send(blob, vehicle_side.local_address)
    msgs = drain(vehicle_side, 1)
    assert [getattr(m, "time_usec", None) for m in msgs] == [None, 1, 2]
    assert vehicle_side.stats.rx_frames == 3


def test_recorder_hook_sees_exact_bytes_both_ways(raw):
    seen = []
    link = Link.listen(LOOPBACK, src_system=1, src_component=1,
                       on_frame=lambda d, b, m, t: seen.append((d, bytes(b), m)))
    try:
        good = frame(heartbeat())
        raw.send(good, link.local_address)
        raw.send(b"\x01garbage", link.local_address)
        drain(link, 2)
        n = link.send(controls())
        raw.sock.settimeout(WAIT_S)
        sent = raw.sock.recvfrom(1024)[0]
        assert n == len(sent)
        assert [(d, b, m is not None) for d, b, m in seen] == [
            ("rx", good, True), ("rx", b"\x01garbage", False), ("tx", sent, True)]
    finally:
        link.close()


def test_on_frames_takes_a_datagrams_settled_frames_in_one_call_in_order(vehicle_side, raw):
    """With ``on_frames`` set beside ``on_frame``, the per-tick frames the settled link
    accepts reach it in one call per datagram (exact bytes, msgs None: all accepted); a
    frame after them that is not one (a STATUSTEXT) or is rejected still goes to on_frame,
    after them."""
    frames_calls, frame_calls = [], []
    raw.send(frame(heartbeat()), vehicle_side.local_address)       # pins peer and sysid
    drain(vehicle_side, 1)
    vehicle_side.on_frame = lambda d, b, m, t: frame_calls.append((d, bytes(b), m is not None))
    vehicle_side.on_frames = lambda d, bs, ms, t: frames_calls.append((d, list(bs), ms))
    c1, c2 = frame(controls(time_usec=1)), frame(controls(time_usec=2))
    hb = frame(mav.MAVLink_statustext_message(mav.MAV_SEVERITY_INFO, b"hi", 0, 0))
    bad = bytearray(frame(controls(time_usec=3)))
    bad[-1] ^= 0xFF                                                  # a bad CRC
    raw.send(c1 + c2 + hb + bytes(bad), vehicle_side.local_address)
    msgs = drain(vehicle_side, 2)
    assert [getattr(m, "time_usec", None) for m in msgs] == [1, 2, None]
    assert frames_calls == [("rx", [c1, c2], None)]
    assert frame_calls == [("rx", hb, True), ("rx", bytes(bad), False)]
    assert (vehicle_side.stats.rx_frames, vehicle_side.stats.bad_crc) == (4, 1)


def test_send_many_packs_frames_into_one_datagram_in_order(raw):
    seen = []
    link = Link.connect(raw.sock.getsockname(), src_system=1, src_component=1,
                        on_frame=lambda d, b, m, t: seen.append((d, bytes(b), m)))
    try:
        msgs = [controls(time_usec=1), heartbeat(), controls(time_usec=2)]
        n = link.send_many(msgs)
        raw.sock.settimeout(WAIT_S)
        datagram = raw.sock.recvfrom(4096)[0]
        assert n == len(datagram) == sum(len(b) for _, b, _ in seen)
        assert b"".join(b for _, b, _ in seen) == datagram
        assert [m for _, _, m in seen] == msgs
        assert [b[4] for _, b, _ in seen] == [0, 1, 2]           # consecutive sequence numbers
        assert link.stats.tx_frames == 3
        receiver = Link.listen(LOOPBACK, src_system=2, src_component=1)
        try:
            raw.send(frame(heartbeat(), sysid=1), receiver.local_address)
            raw.send(datagram, receiver.local_address)
            got = drain(receiver, 2)
            assert [(m.get_type(), getattr(m, "time_usec", None)) for m in got] == [
                ("HEARTBEAT", None), ("HIL_ACTUATOR_CONTROLS", 1), ("HEARTBEAT", None),
                ("HIL_ACTUATOR_CONTROLS", 2)]
        finally:
            receiver.close()
    finally:
        link.close()


def test_send_before_a_peer_is_known_is_counted_not_sent(vehicle_side):
    assert vehicle_side.send(heartbeat()) == 0
    assert vehicle_side.stats.unsent_no_peer == 1
    assert vehicle_side.stats.tx_frames == 0


def test_sequence_numbers_advance_per_frame(raw):
    link = Link.connect(raw.sock.getsockname(), src_system=1, src_component=1)
    try:
        raw.sock.settimeout(WAIT_S)
        seqs = []
        for _ in range(3):
            link.send(heartbeat())
            seqs.append(raw.sock.recvfrom(1024)[0][4])
        assert seqs == [0, 1, 2]
    finally:
        link.close()


def test_port_in_use_is_a_clear_link_error(vehicle_side):
    with pytest.raises(LinkError, match=r"in use|another process"):
        Link.listen(vehicle_side.local_address, src_system=1, src_component=1)


@pytest.mark.parametrize(("text", "match"), [
    ("localhost", "expected HOST:PORT"),
    (":14540", "expected HOST:PORT"),
    ("127.0.0.1:x", "port must be an integer"),
    ("127.0.0.1:70000", "port must be 0-65535"),
])
def test_bad_addresses_name_the_field(text, match):
    with pytest.raises(ValueError, match=f"--listen: {match}"):
        parse_address(text, "--listen")


def test_nonfinite_fields_are_named_element_by_element():
    msg = controls(values=(0.5, float("nan"), 0.5, 0.5))
    assert nonfinite_field(msg, ["time_usec", "controls"]) == "controls[1]"
    assert not finite_fields(msg, ["controls"])
    assert finite_fields(controls(), ["controls"])


def test_every_rejection_counter_is_counted_in_rejected_and_summary():
    """Adding a rejection reason (signing added four) must keep ``rejected``, ``as_dict``
    and ``summary`` in step: each counter that is not traffic or local trouble is one."""
    from tfl_mav.link.transport import LinkStats

    traffic = {"rx_datagrams", "rx_bytes", "rx_frames", "tx_frames", "tx_bytes"}
    local = {"recv_errors", "send_errors", "unsent_no_peer"}
    names = set(LinkStats().as_dict()) - traffic - local
    assert names == set(LinkStats.REJECTIONS)
    for i, name in enumerate(sorted(names), start=1):
        st = LinkStats(**{name: i})
        assert st.rejected == i
        assert f"{name} {i}" in st.summary()


def test_signed_frames_are_accepted_unchecked_on_an_unsigned_link(vehicle_side, raw):
    """Like any key-less MAVLink receiver: signing is opt-in on both ends."""
    packer = new_mavlink(2, 191)
    packer.signing.secret_key = bytes(range(1, 33))
    packer.signing.sign_outgoing = True
    raw.send(bytes(heartbeat().pack(packer)), vehicle_side.local_address)
    assert [m.get_type() for m in drain(vehicle_side, 1)] == ["HEARTBEAT"]
    assert vehicle_side.stats.rejected == 0


def test_statustext_chunks_are_joined_whole_per_sender():
    from tfl_mav.link.statustext import TEXT_LEN, Reassembler, split

    text = "crashed: flipped: thrust axis points down (tilt 90 deg) at t = 1.865 s"
    chunks = split(text)
    assert [len(c) for c in chunks] == [TEXT_LEN, len(text) - TEXT_LEN]
    assert split("x" * TEXT_LEN * 2)[-1] == b""          # a full last chunk: a terminator
    r = Reassembler()
    got = [r.add("a", c.decode(), 7, i) for i, c in enumerate(chunks)]
    assert got == [[], [text]]
    assert r.add("a", "short", 0, 0) == ["short"]       # id 0: a text on its own
    # interleaved senders, and a text whose end was lost (its id replaced by another)
    assert r.add("a", chunks[0].decode(), 8, 0) == []
    assert r.add("b", "hello", 3, 0) == ["hello"]
    assert r.add("a", "next", 9, 0) == [chunks[0].decode() + "…", "next"]
    assert r.flush() == []
