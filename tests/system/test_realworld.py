"""The real world through the command line and the API: a scenario file with wind and an
attacker that moves between rotors; seeded wind replays the same flight."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from tfl_mav.offline import fly_offline
from tfl_mav.scenario import load_scenario

SCHEDULE = """
name = "moving-attacker"
[attack]
value_n = 1.5
[[attack.phases]]
rotor = 2
signal = "constant"
start_s = 1.0
[[attack.phases]]
rotor = 0
start_s = 3.0
[[attack.phases]]
rotor = 3
signal = "constant"
start_s = 4.0
[wind]
mean_mps = [2.0, 0.0, 0.0]
turbulence = "light"
[run]
duration_s = 6.0
"""


@pytest.mark.slow
def test_cli_flies_a_moving_attacker_in_wind_and_reports_each_move(tmp_path):
    path = tmp_path / "moving.toml"
    path.write_text(SCHEDULE)
    out = subprocess.run([sys.executable, "-m", "tfl_mav.tools.cli", "offline", str(path),
                          "--attack-info", "detector"],
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    lines = [line.split("s  ", 1)[1] for line in out.stdout.splitlines() if "t = " in line]
    said = [t for t in lines if t.startswith(("attacker", "attack detected", "rotor obeys"))]
    assert said == ["attacker seizes rotor 2", "attack detected on rotor 2",
                    "attacker lets go",
                    "rotor obeys its commands again: attack over, four-rotor law",
                    "attacker seizes rotor 3", "attack detected on rotor 3"]


def test_seeded_wind_replays_the_flight_bit_for_bit():
    sc = load_scenario("paper").replace(**{"wind.mean_mps": [3.0, 0.0, 0.0],
                                           "wind.turbulence": "moderate",
                                           "run.duration_s": 1.5})
    a, b = fly_offline(sc), fly_offline(sc)
    for key in ("position_m", "quaternion_wxyz", "thrust_cmd_n", "wind_mps"):
        assert a[key].tobytes() == b[key].tobytes()
    c = fly_offline(sc.replace(**{"run.seed": 1}))
    assert not np.array_equal(a["wind_mps"], c["wind_mps"])
    assert a["wind_mps"].shape == (len(a["t_s"]), 3)


@pytest.mark.slow
def test_realistic_vehicle_sends_the_estimate_and_its_raw_sensors_over_mavlink():
    """ODOMETRY carries the onboard estimate with its covariance (GPS_INS); the GCS gets
    HIGHRES_IMU and GPS_RAW_INT beside ATTITUDE and LOCAL_POSITION_NED."""
    import math
    import os
    import threading

    os.environ.setdefault("MAVLINK20", "1")
    from pymavlink import mavutil

    from tfl_mav.link.dialect import mav
    from tfl_mav.sitl.vehicle import Vehicle
    from tfl_mav.tools.harness.pilot import Pilot, hover_fraction
    from tfl_mav.tools.harness.ports import LOOPBACK

    mavutil.set_dialect("ardupilotmega")
    sc = load_scenario("paper").replace(**{"attack.rotor": 0, "sensors.model": "realistic"})
    gcs = mavutil.mavlink_connection("udpin:127.0.0.1:0", source_system=255,
                                     source_component=190)
    vehicle = Vehicle(sc, listen=LOOPBACK, gcs=gcs.port.getsockname())
    thread = threading.Thread(target=vehicle.run, args=(math.inf,), daemon=True)
    thread.start()
    pilot = Pilot(vehicle.listen_address)
    try:
        gcs.wait_heartbeat(timeout=5.0)
        pilot.hello()
        u = hover_fraction(sc)
        odometry = []
        pilot.fly(300, lambda o, _e: odometry.append(o) or [u] * 4, timeout_s=5.0)
        o = odometry[-1]
        assert o.estimator_type == mav.MAV_ESTIMATOR_TYPE_GPS_INS
        assert 0.0 < o.pose_covariance[0] < 0.1 ** 2          # σ < 10 cm, NED north
        assert o.velocity_covariance[0] > 0.0
        seen = {}
        deadline = 200
        while len(seen) < 4 and deadline:
            deadline -= 1
            m = gcs.recv_match(blocking=True, timeout=0.1)
            if m is not None and m.get_type() in ("HIGHRES_IMU", "GPS_RAW_INT", "ATTITUDE",
                                                  "LOCAL_POSITION_NED"):
                seen[m.get_type()] = m
            if len(seen) < 4:
                pilot.fly(20, lambda _o, _e: [u] * 4, timeout_s=5.0)
        imu, gps = seen["HIGHRES_IMU"], seen["GPS_RAW_INT"]
        assert imu.zacc == pytest.approx(-9.81, abs=0.5)      # FRD: hover specific force up
        assert abs(imu.xgyro) < 0.1 and imu.fields_updated
        assert gps.fix_type == 6 and gps.satellites_visible > 0 and gps.h_acc == 20
        assert abs(seen["LOCAL_POSITION_NED"].z + 0.5) < 0.2   # the estimate, near 0.5 m up
    finally:
        vehicle.stop()
        thread.join(5.0)
        vehicle.close()
        pilot.close()
        gcs.close()


def test_builtin_realistic_scenario_is_everything_at_once():
    sc = load_scenario("realistic")
    assert sc.vehicle.rotor_aero and sc.sensors.model == "realistic"
    assert sc.wind.turbulence == "light" and sc.wind.mean_mps == (2.0, 0.0, 0.0)
    assert sc.attack == load_scenario("paper").attack and sc.path == load_scenario("paper").path
    log = fly_offline(sc.replace(**{"run.duration_s": 1.0}))
    assert not log.crashed
    # the log's distance is the truth's; the controller's, from its estimate, beside it
    assert log["path_distance_m"].shape == log.data["path_distance_estimated_m"].shape
    assert not np.array_equal(log["path_distance_m"], log.data["path_distance_estimated_m"])


def test_api_flies_wind_and_a_moving_attacker_from_settings():
    """The public API takes the new keys as --set does; the detector follows the attacker."""
    from tfl_mav.api import Environment

    env = Environment("paper", settings=[
        "wind.mean_mps=[2.0, 0.0, 0.0]", "wind.turbulence=light", "attack.value_n=1.5",
        "attack.phases=[{rotor = 2, start_s = 0.5, signal = 'constant'},"
        " {rotor = 3, start_s = 2.0, signal = 'constant'}]"])
    assert env.scenario.wind.active and len(env.scenario.attack.phases) == 2
    flight = env.fly(3.0)
    assert not flight.crashed
    t, rotor = flight.t_s, flight.detected_rotor
    assert set(rotor[(t > 0.6) & (t < 2.0)]) == {2}
    assert rotor[-1] == 3
