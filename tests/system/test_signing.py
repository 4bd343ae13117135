"""MAVLink 2 signing: key files, the signature, verify-then-advance, and the signed link.

Everything on the wire goes over real UDP sockets on loopback. The pymavlink parser used as
the "victim" in the future-timestamp test is pymavlink's own, configured the documented way
(``signing.secret_key``): the test records its flaw as a fact and shows ours does not share it.
"""

from __future__ import annotations

import itertools
import json
import os
import re
import select
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from tfl_mav.link.dialect import mav, new_mavlink
from tfl_mav.link.signing import (
    KEY_LEN,
    MAVLINK_EPOCH_UNIX_S,
    TIMESTAMP_UNITS_PER_S,
    KeyFileError,
    Signing,
    load_key,
    mavlink_timestamp,
    parse_key,
    signature48,
)
from tfl_mav.link.transport import Link
from tfl_mav.scenario import load_scenario
from tfl_mav.sitl.vehicle import Vehicle
from tfl_mav.tools.harness.pilot import Pilot

LOOPBACK = ("127.0.0.1", 0)
KEY = bytes(range(1, 33))
OTHER_KEY = bytes(range(101, 133))
CLI = [sys.executable, "-m", "tfl_mav.tools.cli"]
REPO = Path(__file__).resolve().parents[2]
T0_S = 1_750_000_000.0      # a fixed "now" (2025) for deterministic timestamp tests
WINDOW = 60 * TIMESTAMP_UNITS_PER_S


def heartbeat():
    return mav.MAVLink_heartbeat_message(mav.MAV_TYPE_ONBOARD_CONTROLLER,
                                         mav.MAV_AUTOPILOT_INVALID, 0, 0, 0, 3)


def controls(time_usec=1000, value=0.5):
    return mav.MAVLink_hil_actuator_controls_message(time_usec, [value] * 4 + [0.0] * 12,
                                                     128, 1)


def inject_failure(rotor=2):
    return mav.MAVLink_command_long_message(1, 1, mav.MAV_CMD_INJECT_FAILURE, 0, 101, 1,
                                           rotor, 0, 0, 0, 0)


def signed(msg, key=KEY, timestamp=None, sysid=2, compid=191, link_id=0, unix_s=T0_S):
    """One frame signed by pymavlink's packer with the given key, ids and timestamp."""
    packer = new_mavlink(sysid, compid)
    packer.signing.secret_key = key
    packer.signing.sign_outgoing = True
    packer.signing.link_id = link_id
    packer.signing.timestamp = (mavlink_timestamp(unix_s) if timestamp is None
                                else timestamp)
    return bytes(msg.pack(packer))


def packed(msg, sysid: int, key: bytes | None) -> bytes:
    """``msg`` packed as ``sysid`` would, signed with ``key`` now (or unsigned)."""
    packer = new_mavlink(sysid, 191)
    if key is not None:
        Signing(key).configure_packer(packer, link_id=0)
    return bytes(msg.pack(packer))


def timestamp_of(frame: bytes) -> int:
    return int.from_bytes(frame[-12:-6], "little")


class FixedClock:
    """A settable wall clock (Unix seconds) for Signing."""

    def __init__(self, t_s: float = T0_S) -> None:
        self.t_s = t_s

    def __call__(self) -> float:
        return self.t_s


def drain(link: Link, expect_datagrams: int) -> list:
    out: list = []
    for _ in range(60):
        out += link.recv(0.05)
        if link.stats.rx_datagrams >= expect_datagrams:
            break
    return out + link.recv(0.0)


# ---------------------------------------------------------------------------- key files
HEX = KEY.hex()


@pytest.mark.parametrize("text", [HEX, HEX + "\n", HEX.upper() + "\r\n",
                                  " ".join(HEX[i:i + 8] for i in range(0, 64, 8)) + "\n",
                                  "\n".join(HEX[i:i + 16] for i in range(0, 64, 16))])
def test_hex_key_with_any_whitespace(text):
    assert parse_key(text.encode()) == KEY


def test_raw_32_byte_key():
    raw = bytes([0xFF, 0x00, 0x80, *range(29)])
    assert parse_key(raw) == raw


@pytest.mark.parametrize(("data", "match"), [
    (b"", "empty"),
    (b" \n", "empty"),
    (HEX[:-1].encode(), "63 hex digits, expected 64"),
    (HEX[:32].encode(), "32 hex digits, expected 64"),    # not 32 weak ASCII bytes
    ((HEX + "00").encode(), "66 hex digits"),
    (b"not a key at all", "expected 64 hex digits or exactly 32 raw bytes, got 16 bytes"),
    (bytes(range(200, 231)), "got 31 bytes"),
    (b"0" * 64, "all zeros"),
    (bytes(32), "all zeros"),
])
def test_bad_key_contents_name_the_option_and_the_problem(data, match):
    with pytest.raises(KeyFileError, match=rf"^--key-file: .*{match}"):
        parse_key(data)


def _key_file(tmp_path, data: bytes, mode: int = 0o600) -> Path:
    p = tmp_path / "key"
    p.write_bytes(data)
    p.chmod(mode)
    return p


def test_load_key_reads_a_private_file(tmp_path):
    assert load_key(_key_file(tmp_path, (HEX + "\n").encode())) == KEY
    assert load_key(_key_file(tmp_path, KEY, 0o400)) == KEY


@pytest.mark.skipif(os.name != "posix", reason="POSIX permissions")
@pytest.mark.parametrize("mode", [0o644, 0o640, 0o604, 0o620])
def test_load_key_refuses_a_file_others_can_access(tmp_path, mode):
    p = _key_file(tmp_path, HEX.encode(), mode)
    with pytest.raises(KeyFileError, match=rf"group/others .*mode {mode:03o}.*chmod 600"):
        load_key(p)


def test_load_key_unreadable_missing_directory_and_huge(tmp_path):
    with pytest.raises(KeyFileError, match=r"^--key-file '.*nope': cannot read it \(No such"):
        load_key(tmp_path / "nope")
    with pytest.raises(KeyFileError, match=r"not a regular file|cannot read"):
        load_key(tmp_path)
    with pytest.raises(KeyFileError, match="larger than 4096 bytes"):
        load_key(_key_file(tmp_path, b"a" * 5000))
    with pytest.raises(KeyFileError, match=r"^--key-file '.*key': 2 hex digits"):
        load_key(_key_file(tmp_path, b"ab\n"))


def test_signing_refuses_bad_keys_in_code_too():
    with pytest.raises(ValueError, match="32 bytes"):
        Signing(b"short")
    with pytest.raises(ValueError, match="all zeros"):
        Signing(bytes(KEY_LEN))


# ---------------------------------------------------------------------------- the signature
def test_timestamp_units_and_epoch():
    assert mavlink_timestamp(MAVLINK_EPOCH_UNIX_S) == 0
    assert mavlink_timestamp(MAVLINK_EPOCH_UNIX_S + 1.0) == 100_000   # 10 µs units
    # 48 bits of 10 µs last ~89 years from 2015: no wrap to worry about.
    assert mavlink_timestamp(T0_S) < 2**48


def test_our_signature_equals_pymavlink_packer_and_pymavlink_accepts_ours():
    frame = signed(controls(), link_id=7, timestamp=123456789)
    assert frame[2] & 1 and frame[-13] == 7 and timestamp_of(frame) == 123456789
    assert frame[-6:] == signature48(KEY, frame[:-6])
    # A frame from our Link's packer is accepted by pymavlink's own verifier (interop).
    sender = Link.connect(("127.0.0.1", 9), src_system=2, src_component=191,
                          signing=Signing(KEY), link_id=3)
    try:
        sender.signing.stamp(sender.packer)
        ours = bytes(controls().pack(sender.packer))
    finally:
        sender.close()
    theirs = new_mavlink(1, 1)
    theirs.signing.secret_key = KEY
    msg = theirs.decode(bytearray(ours))
    assert msg.get_type() == "HIL_ACTUATOR_CONTROLS" and theirs.signing.goodsig_count == 1


def test_verify_accepts_fresh_frames_and_names_every_rejection():
    clock = FixedClock()
    s = Signing(KEY, clock=clock)
    now = mavlink_timestamp(T0_S)
    assert s.verify(signed(heartbeat(), timestamp=now)) is None
    assert s.verify(signed(heartbeat(), timestamp=now + 1)) is None
    assert s.verify(signed(heartbeat(), timestamp=now + 1)) == "replayed"      # same
    assert s.verify(signed(heartbeat(), timestamp=now - 5)) == "replayed"      # older
    assert s.verify(bytes(heartbeat().pack(new_mavlink(2, 191)))) == "unsigned"
    assert s.verify(signed(heartbeat(), key=OTHER_KEY, timestamp=now + 9)) == "bad_signature"
    tampered = bytearray(signed(controls(value=0.5), timestamp=now + 10))
    tampered[12] ^= 0x40                                    # one payload bit
    assert s.verify(bytes(tampered)) == "bad_signature"
    assert s.verify(signed(heartbeat(), timestamp=now + WINDOW + 1)) == "bad_timestamp"
    # A new stream may start up to 60 s in the past (the spec's rule), not earlier.
    assert s.verify(signed(heartbeat(), sysid=3, timestamp=now - WINDOW)) is None
    assert s.verify(signed(heartbeat(), sysid=4, timestamp=now - WINDOW - 1)) == "bad_timestamp"
    # Streams are (sysid, compid, link_id): each has its own last timestamp.
    assert s.verify(signed(heartbeat(), link_id=1, timestamp=now)) is None
    assert s.verify(signed(heartbeat(), compid=1, timestamp=now)) is None
    assert s.streams == {(2, 191, 0): now + 1, (3, 191, 0): now - WINDOW,
                         (2, 191, 1): now, (2, 1, 0): now}


def test_the_future_timestamp_attack_blocks_pymavlink_but_not_us():
    """One forged frame with a far-future timestamp and the victim's stream ids.

    pymavlink 2.4.50 stores the stream's timestamp before checking the hash, so every later
    genuine frame is "too old" (a documented fact, asserted here so an upgrade that fixes it
    shows up). Our verifier checks the hash first and keeps accepting the genuine frames.
    """
    now = mavlink_timestamp(T0_S)
    genuine = [signed(controls(time_usec=k), timestamp=now + k) for k in range(1, 6)]
    forged = signed(controls(value=1.0), key=OTHER_KEY, timestamp=now + 10**9)

    victim = new_mavlink(1, 1)
    victim.signing.secret_key = KEY
    victim.decode(bytearray(genuine[0]))
    with pytest.raises(mav.MAVError, match="Invalid signature"):
        victim.decode(bytearray(forged))
    assert victim.signing.stream_timestamps[(0, 2, 191)] == now + 10**9   # the flaw
    for frame in genuine[1:]:
        with pytest.raises(mav.MAVError, match="Invalid signature"):
            victim.decode(bytearray(frame))

    ours = Signing(KEY, clock=FixedClock())
    assert ours.verify(genuine[0]) is None
    assert ours.verify(forged) == "bad_signature"
    assert [ours.verify(f) for f in genuine[1:]] == [None] * 4
    assert ours.streams[(2, 191, 0)] == now + 5


def test_outgoing_timestamps_increase_strictly_even_if_the_clock_steps_back():
    clock = FixedClock()
    s = Signing(KEY, clock=clock)
    packer = new_mavlink(2, 191)
    s.configure_packer(packer, link_id=0)
    stamps = []
    for step_s in (0.0, 0.0, -5.0, 0.0, 10.0):
        clock.t_s += step_s
        s.stamp(packer)
        stamps.append(timestamp_of(bytes(heartbeat().pack(packer))))
    assert all(b > a for a, b in itertools.pairwise(stamps))
    assert stamps[-1] == mavlink_timestamp(T0_S + 5.0)     # caught up with the clock again


# ---------------------------------------------------------------------------- over UDP
@pytest.fixture
def pair():
    """A signed listening link ("vehicle") and a signed client ("controller")."""
    vehicle = Link.listen(LOOPBACK, src_system=1, src_component=1, signing=Signing(KEY))
    controller = Link.connect(vehicle.local_address, src_system=2, src_component=191,
                              signing=Signing(KEY))
    yield vehicle, controller
    vehicle.close()
    controller.close()


def test_signed_links_talk_and_the_recorder_sees_signed_bytes(pair):
    vehicle, controller = pair
    seen = []
    controller.on_frame = lambda d, b, m, t: seen.append(bytes(b))
    controller.send(heartbeat())
    controller.send_many([controls(time_usec=1), controls(time_usec=2)])
    got = drain(vehicle, 2)
    assert [getattr(m, "time_usec", None) for m in got] == [None, 1, 2]
    assert vehicle.peer == controller.local_address and vehicle.peer_sysid == 2
    assert vehicle.stats.rejected == 0
    assert all(b[2] & 1 and b[-6:] == signature48(KEY, b[:-6]) for b in seen)
    assert [timestamp_of(b) for b in seen] == sorted({timestamp_of(b) for b in seen})
    vehicle.send(heartbeat())
    assert [m.get_type() for m in drain(controller, 1)] == ["HEARTBEAT"]


def test_unsigned_or_forged_heartbeats_never_pin_the_peer(pair):
    vehicle, controller = pair
    intruder = Link.connect(vehicle.local_address, src_system=2, src_component=191)
    forger = Link.connect(vehicle.local_address, src_system=2, src_component=191,
                          signing=Signing(OTHER_KEY))
    try:
        intruder.send(heartbeat())
        forger.send(heartbeat())
        assert drain(vehicle, 2) == []
        assert vehicle.peer is None and vehicle.peer_sysid is None
        assert (vehicle.stats.unsigned, vehicle.stats.bad_signature) == (1, 1)
        controller.send(heartbeat())
        drain(vehicle, 3)
        assert vehicle.peer == controller.local_address
    finally:
        intruder.close()
        forger.close()


def test_future_timestamp_attack_over_udp_does_not_block_the_peer(pair):
    """The forged frame arrives from the peer's own address (as if spoofed on the path)."""
    vehicle, controller = pair
    controller.send(heartbeat())
    drain(vehicle, 1)
    far = mavlink_timestamp(time.time()) + 10**9
    controller.send_raw(signed(controls(value=1.0), key=OTHER_KEY, sysid=2, compid=191,
                               timestamp=far))
    controller.send_raw(signed(controls(value=1.0), key=OTHER_KEY, sysid=2, compid=191,
                               timestamp=far + 1))
    for k in range(1, 4):
        controller.send(controls(time_usec=k))
    got = drain(vehicle, 6)
    assert [m.time_usec for m in got] == [1, 2, 3]
    assert vehicle.stats.bad_signature == 2 and vehicle.stats.rejected == 2


def test_replayed_datagrams_are_rejected(pair):
    vehicle, controller = pair
    sent = []
    controller.on_frame = lambda d, b, m, t: sent.append(bytes(b))
    controller.send(heartbeat())
    controller.send(controls(time_usec=1))
    controller.send(controls(time_usec=2))
    assert len(drain(vehicle, 3)) == 3
    for frame in sent[1:] + sent[1:2]:      # the same timestamp again, and an older one
        controller.send_raw(frame)
    assert drain(vehicle, 6) == []
    assert vehicle.stats.replayed == 3


def test_mavlink1_is_rejected_on_a_signed_link(pair):
    vehicle, controller = pair
    controller.send(heartbeat())
    drain(vehicle, 1)
    controller.send_raw(controls().pack(new_mavlink(2, 191), force_mavlink1=True))
    assert drain(vehicle, 2) == []
    assert vehicle.stats.mavlink1 == 1


def test_a_restarted_sender_is_accepted_without_restarting_the_receiver():
    """Outgoing timestamps follow the wall clock, so a new process's stream continues."""
    clock = FixedClock()
    vehicle = Link.listen(LOOPBACK, src_system=1, src_component=1,
                          signing=Signing(KEY, clock=clock))
    bind = None
    try:
        for restart in range(3):
            controller = Link.connect(vehicle.local_address, src_system=2, src_component=191,
                                      bind=bind, signing=Signing(KEY, clock=clock))
            bind = controller.local_address       # same address: the pinned peer
            controller.send(heartbeat())
            for k in range(50):                   # a burst: +1 per frame, clock still
                controller.send(controls(time_usec=k))
            controller.close()
            clock.t_s += 0.001                    # the restart takes 1 ms = 100 units > 51
            drain(vehicle, 51 * (restart + 1))
        assert vehicle.stats.rx_frames == 153 and vehicle.stats.rejected == 0
    finally:
        vehicle.close()


# ---------------------------------------------------------------------------- peer takeover
def controller(address, *, key: bytes | None, sysid: int = 2) -> Pilot:
    """A lockstep controller (the harness Pilot) that has said HEARTBEAT."""
    pilot = Pilot(address, sysid=sysid, key=key)
    pilot.hello()
    return pilot


@pytest.mark.parametrize("key", [None, KEY], ids=["unsigned", "signed"])
def test_a_second_sender_cannot_take_over_the_control_port(key):
    sc = load_scenario("paper").replace(**{"attack.rotor": 0})
    v = sc.vehicle
    hover = v.mass_kg * v.gravity_mps2 / 4.0 / v.thrust_max_n
    vehicle = Vehicle(sc, listen=LOOPBACK, key=key)
    result = {}
    thread = threading.Thread(target=lambda: result.update(r=vehicle.run(0.2)), daemon=True)
    thread.start()
    pilot = controller(vehicle.listen_address, key=key)
    hold = lambda o, e: [hover] * 4   # noqa: E731
    pilot_address = pilot.link.local_address
    intruder = None
    try:
        last = pilot.fly(20, hold)[-1][0].time_usec
        # The intruder even holds the key (an insider on another host), same system id.
        intruder = controller(vehicle.listen_address, key=key, sysid=2)
        for k in range(1, 30):         # full throttle for every upcoming tick, and an attack
            intruder.link.send(controls(last + 1000 * k, 1.0))
        intruder.link.send(inject_failure())
        intruder.link.send(heartbeat())
        # From the pilot's own address, another system id (a second system behind a router).
        for msg in (controls(last + 1000, 1.0), inject_failure()):
            pilot.link.send_raw(packed(msg, sysid=9, key=key))
        pilot.fly(180, hold)
        thread.join(5.0)
        assert not thread.is_alive()
        assert intruder.link.recv(0.1) == []            # never answered
    finally:
        vehicle.stop()
        thread.join(5.0)
        vehicle.close()
        pilot.link.close()
        if intruder is not None:
            intruder.link.close()
    st = vehicle.stats
    assert result["r"].ticks == 200
    assert vehicle.controller_address == pilot_address
    assert st.control_link.foreign == 32 and st.control_link.wrong_sysid == 2
    assert st.controls_applied == 200 and st.stale_controls == 0
    assert st.commands_accepted == st.failures_injected == 0
    # 200 ticks of hover (no motor lag in this scenario): one control period of full
    # throttle would have added (4 f_max / m - g)·T ≈ 19 mm/s; hover leaves float32 dust.
    dv_one_tick = (4 * v.thrust_max_n / v.mass_kg - v.gravity_mps2) * sc.run.control_dt_s
    assert max(abs(x) for x in vehicle.sim.state.velocity_mps) < dv_one_tick / 100


def test_gcs_port_is_signed_too_and_refuses_unsigned_commands():
    """MAV_CMD_INJECT_FAILURE moves a motor, so the GCS port needs the key as well."""
    sc = load_scenario("paper").replace(**{"attack.rotor": 0})
    seen: list[bytes] = []
    gcs = Link.listen(LOOPBACK, src_system=255, src_component=190, signing=Signing(KEY),
                      on_frame=lambda d, b, m, t: seen.append(bytes(b)) if d == "rx" else None)
    vehicle = Vehicle(sc, listen=LOOPBACK, gcs=gcs.local_address, key=KEY)
    thread = threading.Thread(target=vehicle.run, daemon=True)   # waits for a controller
    thread.start()
    try:
        deadline = time.monotonic() + 3.0
        while gcs.peer is None and time.monotonic() < deadline:
            gcs.recv(0.05)                        # the vehicle's signed HEARTBEAT pins it
        assert gcs.peer == vehicle.gcs_local_address and gcs.stats.rejected == 0
        assert seen[0][-13] == 1                  # the GCS port signs with link id 1
        gcs.send_raw(packed(inject_failure(), sysid=255, key=None))
        gcs.send_raw(packed(inject_failure(), sysid=255, key=OTHER_KEY))
        gcs.send(inject_failure())
        acks = []
        while not acks and time.monotonic() < deadline:
            acks = [m for m in gcs.recv(0.05) if m.get_type() == "COMMAND_ACK"]
        assert [a.result for a in acks] == [mav.MAV_RESULT_ACCEPTED]
    finally:
        vehicle.stop()
        thread.join(5.0)
        vehicle.close()
        gcs.close()
    st = vehicle.stats
    assert st.commands_accepted == st.failures_injected == 1
    assert (st.gcs_link.unsigned, st.gcs_link.bad_signature) == (1, 1)


# ---------------------------------------------------------------------------- the CLIs
def _key_files(tmp_path):
    paths = []
    for name, key in (("k1", KEY), ("k2", OTHER_KEY)):
        p = tmp_path / name
        p.write_text(key.hex() + "\n")
        p.chmod(0o600)
        paths.append(str(p))
    return paths


def _start_sim(tmp_path, key_file: str, duration: str):
    sim = subprocess.Popen([*CLI, "sim", "paper", "--listen", "127.0.0.1:0", "--duration",
                            duration, "--key-file", key_file, "--json",
                            str(tmp_path / "sim.json")],
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=REPO)
    line = sim.stdout.readline()
    match = re.search(r"listening on [\d.]+:(\d+) .*MAVLink 2 signing on", line)
    assert match, line + sim.stderr.read()
    return sim, int(match.group(1))


@pytest.mark.slow
def test_cli_pair_with_the_same_key_flies_in_lockstep(tmp_path):
    k1, _ = _key_files(tmp_path)
    sim, port = _start_sim(tmp_path, k1, "1")
    try:
        fly = subprocess.run([*CLI, "fly", "paper", "--vehicle", f"127.0.0.1:{port}",
                              "--duration", "1", "--key-file", k1, "--summary-json",
                              str(tmp_path / "fly.json")],
                             capture_output=True, text=True, timeout=60, cwd=REPO)
        assert sim.wait(timeout=30) == 0, sim.stderr.read()
    finally:
        if sim.poll() is None:
            sim.kill()
    assert fly.returncode == 0, fly.stderr
    report = json.loads((tmp_path / "sim.json").read_text())
    assert report["signed"] and report["ticks"] == 1000
    ctl = report["stats"]["control_link"]
    assert ctl["rx_frames"] >= 1000
    assert sum(ctl[k] for k in ("unsigned", "bad_signature", "replayed", "bad_timestamp")) == 0
    link = json.loads((tmp_path / "fly.json").read_text())["stats"]["link"]
    assert link["rx_frames"] >= 2000 and link["bad_signature"] == link["unsigned"] == 0


@pytest.mark.slow
def test_cli_controller_with_the_wrong_key_never_flies_the_vehicle(tmp_path):
    k1, k2 = _key_files(tmp_path)
    sim, port = _start_sim(tmp_path, k1, "1")
    fly = subprocess.Popen([*CLI, "fly", "paper", "--vehicle", f"127.0.0.1:{port}",
                            "--duration", "1", "--key-file", k2],
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=REPO)
    fly_err = ""
    try:
        # The daemon says why it is waiting 2 s (wall) into its run.
        deadline = time.monotonic() + 20.0
        while "no vehicle state" not in fly_err and time.monotonic() < deadline:
            if select.select([fly.stderr], [], [], 0.2)[0]:
                fly_err += fly.stderr.readline()
        assert sim.poll() is None and fly.poll() is None
    finally:
        for p in (fly, sim):
            p.send_signal(signal.SIGINT)
        fly_err += fly.communicate(timeout=20)[1]
        sim_err = sim.communicate(timeout=20)[1]
    report = json.loads((tmp_path / "sim.json").read_text())
    assert report["ticks"] == 0 and report["status"] == "stopped"
    assert report["stats"]["control_link"]["bad_signature"] >= 2   # HEARTBEAT at 0 s, 1 s, 2 s
    assert report["stats"]["controls_applied"] == 0
    assert "refused by signing (bad_signature" in sim_err
    assert re.search(r"no vehicle state after \d+ s: 0 frames accepted.*--key-file", fly_err)


@pytest.mark.parametrize("command", ["sim", "fly"])
def test_cli_bad_key_file_is_a_usage_error(tmp_path, command):
    p = _key_file(tmp_path, HEX.encode(), 0o644)
    out = subprocess.run([*CLI, command, "--key-file", str(p)], capture_output=True,
                         text=True, timeout=30, cwd=REPO)
    assert out.returncode == 2
    assert re.search(r"--key-file '.*key': group/others may access it .*chmod 600",
                     out.stderr), out.stderr
    assert len(out.stderr.strip().splitlines()) == 1

