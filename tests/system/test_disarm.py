"""A GCS disarms the vehicle mid-flight: the controller's account stays true.

Real parts only: ``tfl-mav sim`` and ``tfl-mav fly`` as subprocesses on loopback UDP, a
pymavlink ``mavutil`` ground station on the vehicle's GCS port sending
``MAV_CMD_COMPONENT_ARM_DISARM``, and both MCAP logs read back with the ``mcap`` library's
own reader. While no command drives the motors the vehicle says so (ACTUATOR_OUTPUT_STATUS
``active`` 0), the stopped rotors read 0 rpm despite the ESC noise, the detector raises
nothing, and ``fly.json`` keeps the detection made before the disarm.
"""

from __future__ import annotations

import json
import os
import re
from pathlib import Path

import pytest

os.environ.setdefault("MAVLINK20", "1")   # our links speak MAVLink 2 only
from foxglove_schemas_protobuf.Log_pb2 import Log
from mcap.reader import make_reader
from pymavlink import mavutil

from tfl_mav.flightlog.logread import LogReader, mavlink_messages
from tfl_mav.link.dialect import mav
from tfl_mav.tools.harness.ports import free_udp_port
from tfl_mav.tools.harness.processes import Proc, start_sim

mavutil.set_dialect("ardupilotmega")
pytestmark = pytest.mark.slow

# ESC noise, so a stopped rotor reading 0 is the sim's doing, not the noise-free default's;
# no motor lag, so the three driven rotors stop at once when disarmed. The attacker holds
# rotor 2 off: disarmed, it "obeys" the zero command like the others, and a detector that
# were not told would release it ("attack over") and detect it again when armed.
SETS = ["--set", "vehicle.rpm_noise_std=5", "--set", "run.duration_s=3",
        "--set", "attack.signal=off"]
DISARM_S, ARM_S = 1.0, 1.15    # sim time the GCS disarms, then arms again
ATTACK_RE = re.compile(r"ATTACK on rotor (\d) detected at t=([\d.]+) s")


def _sim_time_reached(gcs, t_s: float, timeout_s: float = 30.0) -> None:
    """Read the GCS telemetry until the vehicle's sim time reaches ``t_s``."""
    while True:
        m = gcs.recv_match(type="LOCAL_POSITION_NED", blocking=True, timeout=timeout_s)
        assert m is not None, "no GCS telemetry"
        if m.time_boot_ms >= t_s * 1000:
            return


def _records(path: Path, topic: str) -> list[tuple[float, dict]]:
    """(sim time in s, record) of every record on ``topic`` (a recorder record's t_s)."""
    return [(d["t_s"], d) for m in LogReader(path).messages({topic}) for d in [m.decode()]]


def test_disarm_from_a_gcs_raises_no_alarm_and_keeps_the_detection(tmp_path):
    gcs = mavutil.mavlink_connection("udpin:127.0.0.1:0", source_system=255,
                                     source_component=190)
    ctl_port = free_udp_port()
    run_mcap, ctl_mcap, fly_json = tmp_path / "run.mcap", tmp_path / "ctl.mcap", tmp_path / "f.json"
    sim, port = start_sim(["--controller", f"127.0.0.1:{ctl_port}",
                           "--gcs", f"127.0.0.1:{gcs.port.getsockname()[1]}",
                           "--mcap", str(run_mcap), *SETS])
    fly = Proc(["fly", "paper", "--vehicle", f"127.0.0.1:{port}", "--bind",
                f"127.0.0.1:{ctl_port}", "--mcap", str(ctl_mcap), "--summary-json",
                str(fly_json), *SETS])
    try:
        _sim_time_reached(gcs, DISARM_S)
        gcs.mav.command_long_send(1, 1, mav.MAV_CMD_COMPONENT_ARM_DISARM, 0,
                                  0, 21196, 0, 0, 0, 0, 0)     # forced: it is in the air
        _sim_time_reached(gcs, ARM_S)
        gcs.mav.command_long_send(1, 1, mav.MAV_CMD_COMPONENT_ARM_DISARM, 0,
                                  1, 0, 0, 0, 0, 0, 0)
        fly_rc, sim_rc = fly.wait(60), sim.wait(60)
    finally:
        fly.close()
        sim.close()
        gcs.close()
    text = fly.text()
    # Whether the law catches a vehicle that fell for ~0.15 s is the law's business, not
    # this test's: the run ends over (0) or crashed (1, said so), never otherwise.
    assert (fly_rc, sim_rc) in ((0, 0), (1, 1)), text
    if fly_rc == 1:
        assert "vehicle reported EMERGENCY (crashed)" in text
    # One detection, the real one (rotor 2 at once), and none while the motors were stopped.
    alarms = ATTACK_RE.findall(text)
    assert len(alarms) == 1, text
    rotor, t_alarm = int(alarms[0][0]), float(alarms[0][1])
    assert rotor == 2 and t_alarm < 0.1
    assert "attack detection paused" in text and "attack detection resumed" in text
    assert "attack over" not in text
    # the vehicle's STATUSTEXT, sent in chunks, printed whole on one line
    assert re.search(r"vehicle: disarmed by the GCS at t = [\d.]+ s: motors off until a GCS "
                     r"arms again$", text, re.M), text
    summary = json.loads(fly_json.read_text())
    assert summary["detected_rotor"] == 2
    assert summary["detection_time_s"] == pytest.approx(t_alarm, abs=1e-9)
    assert summary["stats"]["motors_off_periods"] == 1
    off_ticks = summary["stats"]["motors_off_ticks"]
    assert 0.1 * 1000 <= off_ticks <= 0.5 * 1000     # 0.15 s of sim time, give or take

    # The vehicle's side: while disarmed ACTUATOR_OUTPUT_STATUS says nothing drives the
    # motors, and the stopped rotors read exactly 0.
    # every tick's frames, decoded from /mavlink/raw (the decoded channels are at 50 Hz)
    applied = [(t * 1e-9, m) for t, m in mavlink_messages(run_mcap, "ACTUATOR_OUTPUT_STATUS",
                                                          1, 1)]
    off = [t for t, m in applied if m["active"] == 0]
    assert off and off[0] >= DISARM_S - 0.01 and off[-1] <= ARM_S + 0.2
    assert all(m["active"] == 0b1111 for t, m in applied if not off[0] <= t <= off[-1])
    esc = {round(t * 1e-9, 6): m["rpm"]
           for t, m in mavlink_messages(run_mcap, "ESC_TELEMETRY_1_TO_4", 1, 1)}
    stopped = [esc[round(t, 6)] for t in off[1:] if round(t, 6) in esc]
    assert len(stopped) >= 50
    assert all(r == [0, 0, 0, 0] for r in stopped), stopped[:5]

    # The controller's side: the verdict never moved; its /log has the text whole.
    states = _records(ctl_mcap, "/controller/state")
    assert states and all(m["detected_rotor"] == 2 for t, m in states if t >= t_alarm)
    with open(ctl_mcap, "rb") as f:
        logs = [Log.FromString(m.data).message
                for _s, _c, m in make_reader(f).iter_messages(topics=["/log"])]
    assert any(re.search(r"disarmed by the GCS at t = [\d.]+ s: motors off until a GCS arms "
                         r"again$", entry) for entry in logs), logs
