"""What the controller says reaches the ground station, and STATUSTEXT chunking at exactly
50 characters.

Real parts: a lockstep :class:`~tfl_mav.sitl.vehicle.Vehicle` and the controller
:class:`~tfl_mav.controller.daemon.Daemon` in threads on loopback UDP, a GCS socket on the
vehicle's GCS port, and the vehicle's MCAP log read back with the ``mcap`` library's reader.
"""

from __future__ import annotations

import threading
import time

from foxglove_schemas_protobuf.Log_pb2 import Log
from mcap.reader import make_reader

from tfl_mav.controller.daemon import Daemon
from tfl_mav.flightlog.recorder import Recorder
from tfl_mav.link.dialect import mav, new_mavlink
from tfl_mav.link.statustext import Reassembler
from tfl_mav.link.transport import Link
from tfl_mav.scenario import load_scenario
from tfl_mav.sitl.vehicle import Vehicle

LOOPBACK = ("127.0.0.1", 0)


def test_controller_safety_events_reach_the_gcs_with_their_severity(tmp_path) -> None:
    sc = load_scenario("paper").replace(**{"run.duration_s": 0.3})
    gcs = Link.listen(LOOPBACK, src_system=255, src_component=190)
    vehicle = Vehicle(sc, listen=LOOPBACK, gcs=gcs.local_address)
    daemon = Daemon(sc, vehicle=vehicle.listen_address, silence_end_s=3.0)
    threads = [threading.Thread(target=vehicle.run, daemon=True),
               threading.Thread(target=daemon.run, daemon=True)]
    for t in threads:
        t.start()
    texts: list[tuple[int, int, int, str]] = []     # sysid, compid, severity, text
    try:
        deadline = time.monotonic() + 30.0
        while time.monotonic() < deadline and any(t.is_alive() for t in threads):
            for m in gcs.recv(0.05):
                if m.get_type() == "STATUSTEXT":
                    texts.append((m.get_srcSystem(), m.get_srcComponent(), m.severity,
                                  m.text))
        for m in gcs.recv(0.2):
            if m.get_type() == "STATUSTEXT":
                texts.append((m.get_srcSystem(), m.get_srcComponent(), m.severity, m.text))
    finally:
        vehicle.stop()
        daemon.stop()
        for t in threads:
            t.join(5.0)
        vehicle.close()
        daemon.close()
        gcs.close()
    ctl = [(sev, text) for sysid, comp, sev, text in texts
           if (sysid, comp) == (1, mav.MAV_COMP_ID_ONBOARD_COMPUTER)]
    attack = [(sev, text) for sev, text in ctl if text.startswith("ATTACK on rotor 2")]
    assert attack, texts
    assert attack[0][0] == mav.MAV_SEVERITY_CRITICAL        # a failure detected (PX4)
    # the vehicle's own texts still come from the vehicle's ids
    assert any(comp == 1 and "simulation ended" in text for _, comp, _, text in texts)


def test_a_50_character_statustext_is_whole_in_the_vehicle_log(tmp_path) -> None:
    """Exactly 50 characters fit one STATUSTEXT without a terminator: sent with id 0 it is
    whole at once; sent as a chunk (id ≠ 0, as MAVLink allows) the log completes it when no
    next chunk comes. Both reach the vehicle's ``/log``."""
    fifty = "x" * 20 + " exactly fifty characters long!"[:30]
    assert len(fifty) == 50
    sc = load_scenario("paper").replace(**{"run.duration_s": 0.2})
    path = tmp_path / "run.mcap"
    recorder = Recorder(path)
    vehicle = Vehicle(sc, listen=LOOPBACK, on_frame=recorder.on_frame)
    thread = threading.Thread(target=vehicle.run, daemon=True)
    thread.start()
    ctl = Link.connect(vehicle.listen_address, src_system=1,
                       src_component=mav.MAV_COMP_ID_ONBOARD_COMPUTER)
    try:
        ctl.send(mav.MAVLink_heartbeat_message(mav.MAV_TYPE_ONBOARD_CONTROLLER,
                                               mav.MAV_AUTOPILOT_INVALID, 0, 0, 0, 3))
        ctl.send(mav.MAVLink_statustext_message(4, fifty.encode(), 0, 0))
        ctl.send(mav.MAVLink_statustext_message(4, fifty.upper().encode(), 9, 0))
        time.sleep(1.3)         # > CHUNK_TIMEOUT_S: no next chunk came
        ctl.send(mav.MAVLink_statustext_message(6, b"later", 0, 0))
        time.sleep(0.3)
    finally:
        vehicle.stop()
        thread.join(5.0)
        vehicle.close()
        ctl.close()
        recorder.close()
    with open(path, "rb") as f:
        logs = [Log.FromString(m.data).message
                for _s, _c, m in make_reader(f).iter_messages(topics=["/log"])]
    assert any(text.endswith(fifty) for text in logs), logs
    assert any(text.endswith(fifty.upper()) for text in logs), logs
    assert any(text.endswith("later") for text in logs), logs


def test_vehicle_statustext_chunks_match_the_reassembler() -> None:
    """The vehicle's chunking and every receiver's reassembly agree on every length,
    50 and its multiples included, and the 8-chunk limit (400 characters)."""
    from tfl_mav.sitl.gcs import StatusText
    from tfl_mav.sitl.results import VehicleStats

    status = StatusText([], VehicleStats())
    packer = new_mavlink(1, 1)
    for n in (1, 49, 50, 51, 99, 100, 150, 200, 250, 399, 400, 401, 1000):
        text = "".join(chr(ord("a") + i % 26) for i in range(n))
        r = Reassembler()
        out: list[str] = []
        for msg in status.messages(4, text):
            back = mav.MAVLink(None).decode(bytearray(msg.pack(packer)))
            out += r.add((1, 1), back.text, back.id, back.chunk_seq)
        # 400 = 8 full chunks, no room for a terminator: cut or not, it cannot say; "…"
        assert out == [text if n < 400 else text[:400] + "…"], n
        assert r.flush() == []


def test_an_attack_expression_leaving_its_domain_is_said_to_the_gcs() -> None:
    """``sqrt(0.05 - t)`` has no value after 0.05 s: the vehicle flies on (rotor 2 at 0 N;
    open-loop hover here, so only 10 ms more) and says so once, with the time, by
    STATUSTEXT."""
    from tfl_mav.tools.harness.pilot import Pilot, hover_fraction

    sc = load_scenario("paper").replace(**{"attack.signal": "sqrt(0.05 - t)"})
    gcs = Link.listen(LOOPBACK, src_system=255, src_component=190)
    vehicle = Vehicle(sc, listen=LOOPBACK, gcs=gcs.local_address)
    thread = threading.Thread(target=vehicle.run, args=(0.2,), daemon=True)
    thread.start()
    pilot = Pilot(vehicle.listen_address)
    texts: list[tuple[int, str]] = []
    whole = Reassembler()
    try:
        pilot.hello()
        u = hover_fraction(sc)
        pilot.fly(60, lambda _o, _e: [u] * 4, timeout_s=10.0)
        deadline = time.monotonic() + 3.0
        while time.monotonic() < deadline and not any("attack.signal" in t for _, t in texts):
            for m in gcs.recv(0.05):
                if m.get_type() == "STATUSTEXT":       # chunks: whole texts
                    texts += [(m.severity, t) for t in whole.add(
                        m.get_srcComponent(), m.text, m.id, m.chunk_seq)]
    finally:
        vehicle.stop()
        thread.join(5.0)
        vehicle.close()
        pilot.close()
        gcs.close()
    said = [(sev, t) for sev, t in texts if t.startswith("attack.signal")]
    assert said, texts
    assert said[0][0] == mav.MAV_SEVERITY_WARNING
    assert said[0][1].startswith("attack.signal 'sqrt(0.05 - t)' is not finite (nan) at "
                                 "t = 0.05")
    assert vehicle.sim.attacker.nonfinite_from_s is not None
    assert 0.05 < vehicle.sim.attacker.nonfinite_from_s <= 0.052
