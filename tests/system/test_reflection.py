"""A frame that claims the receiver's own identity is never accepted: the reflected signed
frame (docs/SIGNING.md, "Reflected frames").

The vehicle's signed telemetry travels in clear, so anyone on the path can capture one of its
frames and send it back to the GCS port from the GCS's address. It verifies (our key signed
it), and before this rule one reflected HEARTBEAT pinned the GCS link to the vehicle's own
system id: the real, keyed GCS was refused (``wrong_sysid``), its disarm included. Real UDP
sockets on loopback, a real captured frame.
"""

from __future__ import annotations

import threading
import time

from tfl_mav.link.dialect import mav, new_mavlink
from tfl_mav.link.signing import Signing
from tfl_mav.link.transport import Link
from tfl_mav.scenario import load_scenario
from tfl_mav.sitl.vehicle import Vehicle

LOOPBACK = ("127.0.0.1", 0)
KEY = bytes(range(1, 33))


def _arm(target_system: int = 1) -> mav.MAVLink_command_long_message:
    return mav.MAVLink_command_long_message(target_system, 1,
                                            mav.MAV_CMD_COMPONENT_ARM_DISARM, 0,
                                            1, 0, 0, 0, 0, 0, 0)


def _acks(link: Link, timeout_s: float) -> list[int]:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        acks = [m.result for m in link.recv(0.05) if m.get_type() == "COMMAND_ACK"]
        if acks:
            return acks
    return []


def _fly_gcs_case(key: bytes | None) -> tuple[Vehicle, list[int]]:
    """A vehicle waiting for its controller, a GCS on its GCS port; the vehicle's own
    captured HEARTBEAT is sent back to it from the GCS's address, then the GCS arms."""
    sc = load_scenario("paper").replace(**{"attack.rotor": 0})
    captured: list[bytes] = []
    gcs = Link.listen(LOOPBACK, src_system=255, src_component=190,
                      signing=Signing(key) if key else None,
                      on_frame=lambda d, b, m, t: captured.append(bytes(b))
                      if d == "rx" and m is not None and m.get_type() == "HEARTBEAT" else None)
    vehicle = Vehicle(sc, listen=LOOPBACK, gcs=gcs.local_address, key=key)
    thread = threading.Thread(target=vehicle.run, daemon=True)   # waits for a controller
    thread.start()
    try:
        deadline = time.monotonic() + 5.0
        while not captured and time.monotonic() < deadline:
            gcs.recv(0.05)
        assert captured, "the vehicle sent no HEARTBEAT to its GCS port"
        reflected = captured[0]
        assert (reflected[5], reflected[6]) == (1, 1)
        assert bool(reflected[2] & 1) == (key is not None)    # signed iff keyed
        gcs.send_raw(reflected)           # from the GCS's own address: no spoofing needed
        time.sleep(0.2)                   # the vehicle serves its GCS port every ~50 ms
        gcs.send(mav.MAVLink_heartbeat_message(mav.MAV_TYPE_GCS, mav.MAV_AUTOPILOT_INVALID,
                                               0, 0, 0, 3))   # the real GCS says hello
        gcs.send(_arm())                  # and arms, keyed (or not, like the vehicle)
        acks = _acks(gcs, 3.0)
    finally:
        vehicle.stop()
        thread.join(5.0)
        vehicle.close()
        gcs.close()
    return vehicle, acks


def test_reflected_signed_heartbeat_does_not_lock_the_gcs_out() -> None:
    vehicle, acks = _fly_gcs_case(KEY)
    st = vehicle.stats.gcs_link
    assert acks == [mav.MAV_RESULT_ACCEPTED]
    assert vehicle.gcs_link is not None and vehicle.gcs_link.peer_sysid == 255
    assert st.reflected == 1 and st.wrong_sysid == 0
    assert st.bad_signature == st.unsigned == st.replayed == 0   # it did verify: ours


def test_reflected_heartbeat_does_not_pin_an_unsigned_gcs_link_either() -> None:
    vehicle, acks = _fly_gcs_case(None)
    assert acks == [mav.MAV_RESULT_ACCEPTED]
    assert vehicle.gcs_link is not None and vehicle.gcs_link.peer_sysid == 255
    assert vehicle.stats.gcs_link.reflected == 1
    assert vehicle.stats.gcs_link.wrong_sysid == 0


def test_signing_refuses_its_own_outgoing_stream_and_nothing_else() -> None:
    """The rule at the source: ``Signing.verify`` says ``reflected`` for a frame of a packer
    it signs for, and stores nothing for it; a keyed peer's frame still verifies."""
    ours, theirs = Signing(KEY), Signing(KEY)
    own = new_mavlink(1, 1)
    peer = new_mavlink(255, 190)
    ours.configure_packer(own, link_id=1)
    theirs.configure_packer(peer, link_id=0)
    hb = mav.MAVLink_heartbeat_message(mav.MAV_TYPE_QUADROTOR, mav.MAV_AUTOPILOT_PX4, 0, 0,
                                       0, 3)
    ours.stamp(own)
    mine = hb.pack(own)
    theirs.stamp(peer)
    from_peer = hb.pack(peer)
    assert theirs.verify(mine) is None          # anyone with the key accepts it...
    assert ours.verify(mine) == "reflected"     # ...but not its own sender
    assert ours.streams == {}
    assert ours.verify(from_peer) is None and (255, 190, 0) in ours.streams


def test_controller_link_refuses_its_own_frames_sent_back() -> None:
    """The controller shares the vehicle's sysid (1) with its own compid (191): a frame
    claiming (1, 191) sent to it is its own, also on the settled, unsigned per-tick path."""
    ctl = Link.listen(LOOPBACK, src_system=1, src_component=191, peer_sysid=1)
    vehicle = new_mavlink(1, 1)
    me = new_mavlink(1, 191)
    hb = mav.MAVLink_heartbeat_message(mav.MAV_TYPE_QUADROTOR, mav.MAV_AUTOPILOT_PX4, 0, 0,
                                       0, 3)
    odom = mav.MAVLink_odometry_message(1000, 1, 2, 0, 0, 0, [1, 0, 0, 0], 0, 0, 0, 0, 0, 0,
                                        [0.0] * 21, [0.0] * 21, 0, 0, 0)
    with ctl, Link.connect(ctl.local_address, src_system=1, src_component=1) as src:
        src.send_raw(hb.pack(vehicle))                       # pins the peer
        got = ctl.recv(1.0)
        assert [m.get_type() for m in got] == ["HEARTBEAT"] and ctl.peer is not None
        src.send_raw(odom.pack(me) + odom.pack(vehicle))     # ours, then the vehicle's
        got = ctl.recv(1.0)
        assert [m.get_srcComponent() for m in got] == [1]
        assert ctl.stats.reflected == 1
