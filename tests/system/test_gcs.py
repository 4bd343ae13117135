"""A ground station drives the simulated vehicle: pymavlink's ``mavutil`` as the GCS.

What MAVProxy, QGroundControl and mavsdk do on connect, done here with pymavlink on real
loopback UDP against an in-process :class:`~tfl_mav.sitl.vehicle.Vehicle` flown by the test
:class:`~tfl_mav.tools.harness.pilot.Pilot`: mode names, arm/disarm (the kill switch), read-only
parameters, "no mission", global position about the origin, and a GCS that says hello on
the control port is refused as controller.
"""

from __future__ import annotations

import math
import os
import threading
import time

import pytest

os.environ.setdefault("MAVLINK20", "1")   # our links speak MAVLink 2 only
from pymavlink import mavutil

from tfl_mav.link.dialect import mav
from tfl_mav.link.transport import Link
from tfl_mav.scenario import load_scenario
from tfl_mav.sitl.gcs import EARTH_RADIUS_M, Origin
from tfl_mav.sitl.ground import scenario_parameters
from tfl_mav.sitl.vehicle import Vehicle
from tfl_mav.tools.harness.pilot import NoStateError, Pilot, hover_fraction
from tfl_mav.tools.harness.ports import LOOPBACK

mavutil.set_dialect("ardupilotmega")
TIMEOUT_S = 5.0
ORIGIN = Origin(-33.8568, 151.2153, 12.0)   # not the default: the test sees it is used


def hover_scenario():
    return load_scenario("paper").replace(**{"attack.rotor": 0})


class GcsFlight:
    """A vehicle in a thread with a mavutil GCS on its GCS port and (optionally) a pilot."""

    def __init__(self, **kw) -> None:
        self.gcs = mavutil.mavlink_connection("udpin:127.0.0.1:0", source_system=255,
                                              source_component=190)
        gcs_addr = self.gcs.port.getsockname()
        self.scenario = hover_scenario()
        self.vehicle = Vehicle(self.scenario, listen=LOOPBACK, gcs=gcs_addr, origin=ORIGIN,
                               **kw)
        self.thread = threading.Thread(target=self.vehicle.run, args=(math.inf,), daemon=True)
        self.thread.start()
        self.gcs.wait_heartbeat(timeout=TIMEOUT_S)
        self.pilot: Pilot | None = None
        self.texts: list = []
        self._fly = threading.Event()
        self._flyer: threading.Thread | None = None

    def start_pilot(self) -> Pilot:
        """A hovering pilot answering every tick in its own thread until close()."""
        pilot = self.pilot = Pilot(self.vehicle.listen_address)
        pilot.hello()
        u = hover_fraction(self.scenario)

        def fly() -> None:
            while not self._fly.is_set():
                try:
                    pilot.fly(1, lambda _o, _e: [u] * 4, timeout_s=TIMEOUT_S)
                except NoStateError:
                    # The vehicle ended the run (close() stopped it, or a disarmed vehicle
                    # reached the ground): nothing left to answer; the test's assertions
                    # run on the main thread.
                    return

        self._flyer = threading.Thread(target=fly, daemon=True)
        self._flyer.start()
        return pilot

    def recv(self, kind: str, cond=lambda m: True, timeout_s: float = TIMEOUT_S):
        """The first ``kind`` message matching ``cond``, including STATUSTEXTs that arrived
        while waiting for something else (kept in :attr:`texts`)."""
        if kind == "STATUSTEXT":
            for m in self.texts:
                if cond(m):
                    self.texts.remove(m)
                    return m
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            m = self.gcs.recv_match(blocking=True, timeout=0.1)
            if m is None:
                continue
            if m.get_type() == kind and cond(m):
                return m
            if m.get_type() == "STATUSTEXT":
                self.texts.append(m)
        raise AssertionError(f"no {kind} within {timeout_s} s")

    def text_seen(self, fragment: str, timeout_s: float = TIMEOUT_S) -> str:
        """Wait until the STATUSTEXTs received (chunks joined in order) contain
        ``fragment``; return their text."""
        deadline = time.monotonic() + timeout_s
        while True:
            text = "".join(m.text for m in self.texts)
            if fragment in text:
                return text
            if time.monotonic() > deadline:
                raise AssertionError(f"no STATUSTEXT with {fragment!r}: {text!r}")
            m = self.gcs.recv_match(type="STATUSTEXT", blocking=True, timeout=0.1)
            if m is not None:
                self.texts.append(m)

    def command(self, command: int, *params: float):
        self.gcs.mav.command_long_send(1, 1, command, 0, *params, *[0.0] * (7 - len(params)))
        return self.recv("COMMAND_ACK", lambda m: m.command == command)

    def close(self) -> None:
        self._fly.set()
        self.vehicle.stop()
        self.thread.join(5.0)
        if self._flyer is not None:
            self._flyer.join(5.0)
        self.vehicle.close()
        self.gcs.close()
        if self.pilot is not None:
            self.pilot.close()


@pytest.fixture
def gcs_flight():
    made: list[GcsFlight] = []

    def make(**kw) -> GcsFlight:
        f = GcsFlight(**kw)
        made.append(f)
        return f

    yield make
    for f in made:
        f.close()


def test_heartbeat_names_the_mode_as_px4_does(gcs_flight):
    f = gcs_flight()
    hb = f.recv("HEARTBEAT")
    assert hb.autopilot == mav.MAV_AUTOPILOT_PX4
    assert f.gcs.flightmode == "OFFBOARD"            # what MAVProxy prints
    assert hb.base_mode & mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
    ack = f.command(mav.MAV_CMD_DO_SET_MODE, mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 6, 0)
    assert ack.result == mav.MAV_RESULT_ACCEPTED
    ack = f.command(mav.MAV_CMD_DO_SET_MODE, mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 3, 0)
    assert ack.result == mav.MAV_RESULT_DENIED       # POSCTL: no on-board controller
    f.text_seen("POSCTL denied")


def test_sys_status_claims_only_what_is_simulated(gcs_flight):
    f = gcs_flight()
    f.start_pilot()
    st = f.recv("SYS_STATUS")
    assert st.onboard_control_sensors_present & mav.MAV_SYS_STATUS_GEOFENCE == 0
    assert st.onboard_control_sensors_present & mav.MAV_SYS_STATUS_SENSOR_3D_MAG == 0
    assert st.onboard_control_sensors_health == st.onboard_control_sensors_present


def test_parameters_are_the_scenarios_and_read_only(gcs_flight):
    f = gcs_flight()
    expected = dict(scenario_parameters(f.scenario))
    f.gcs.mav.param_request_list_send(1, 1)
    got = {}
    while len(got) < len(expected):
        m = f.recv("PARAM_VALUE")
        assert m.param_count == len(expected)
        got[m.param_id] = m.param_value
    assert got.keys() == expected.keys()
    for name, value in expected.items():   # float32 on the wire
        assert got[name] == pytest.approx(value, rel=1e-6), name
    assert got["V_MASS_KG"] == pytest.approx(f.scenario.vehicle.mass_kg, rel=1e-6)
    f.gcs.mav.param_set_send(1, 1, b"V_MASS_KG", 5.0, mav.MAV_PARAM_TYPE_REAL32)
    m = f.recv("PARAM_VALUE", lambda m: m.param_id == "V_MASS_KG")
    assert m.param_value == pytest.approx(f.scenario.vehicle.mass_kg, rel=1e-6)
    f.text_seen("read-only")
    f.gcs.mav.param_request_read_send(1, 1, b"A_ROTOR", -1)
    assert f.recv("PARAM_VALUE", lambda m: m.param_id == "A_ROTOR").param_value == 0.0


def test_mission_is_none_not_silence(gcs_flight):
    f = gcs_flight()
    f.gcs.mav.mission_request_list_send(1, 1)
    assert f.recv("MISSION_COUNT").count == 0
    f.gcs.mav.mission_count_send(1, 1, 3)
    assert f.recv("MISSION_ACK").type == mav.MAV_MISSION_UNSUPPORTED


def test_global_position_and_home_come_from_the_origin(gcs_flight):
    f = gcs_flight()
    f.start_pilot()
    home = f.recv("HOME_POSITION")
    assert (home.latitude, home.longitude, home.altitude) == (
        round(ORIGIN.lat_deg * 1e7), round(ORIGIN.lon_deg * 1e7), round(ORIGIN.alt_m * 1e3))
    ack = f.command(mav.MAV_CMD_REQUEST_MESSAGE, mav.MAVLINK_MSG_ID_HOME_POSITION)
    assert ack.result == mav.MAV_RESULT_ACCEPTED
    # Same datagram, same tick: GLOBAL_POSITION_INT must be LOCAL_POSITION_NED about ORIGIN.
    local = f.recv("LOCAL_POSITION_NED")
    glob = f.recv("GLOBAL_POSITION_INT", lambda m: m.time_boot_ms == local.time_boot_ms)
    north = math.radians(glob.lat * 1e-7 - ORIGIN.lat_deg) * EARTH_RADIUS_M
    east = (math.radians(glob.lon * 1e-7 - ORIGIN.lon_deg) * EARTH_RADIUS_M
            * math.cos(math.radians(ORIGIN.lat_deg)))
    # 1e-7 degree quantisation is 1.1 cm north, 0.9 cm east at this latitude.
    assert north == pytest.approx(local.x, abs=0.012)
    assert east == pytest.approx(local.y, abs=0.012)
    assert glob.relative_alt == round(-local.z * 1000)
    assert glob.alt == round((ORIGIN.alt_m - local.z) * 1000)


def test_disarm_from_the_gcs_is_a_kill_switch_and_arm_releases_it(gcs_flight):
    f = gcs_flight()
    pilot = f.start_pilot()
    f.recv("HEARTBEAT", lambda m: m.base_mode & mav.MAV_MODE_FLAG_SAFETY_ARMED)
    # in the air a disarm needs PX4's force code (param2 = 21196)
    assert f.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 0, 21196).result == \
        mav.MAV_RESULT_ACCEPTED
    # No motor lag in this scenario: the next tick's ESC report reads 0 rpm on all rotors,
    # although the pilot keeps commanding hover with the armed bit set.
    f.recv("HEARTBEAT", lambda m: not m.base_mode & mav.MAV_MODE_FLAG_SAFETY_ARMED)
    assert not f.gcs.motors_armed()
    f.recv("ESC_TELEMETRY_1_TO_4", lambda m: max(m.rpm) == 0)   # falling: arm again soon
    assert f.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == mav.MAV_RESULT_ACCEPTED
    f.recv("ESC_TELEMETRY_1_TO_4", lambda m: min(m.rpm) > 0)
    f.recv("HEARTBEAT", lambda m: m.base_mode & mav.MAV_MODE_FLAG_SAFETY_ARMED)
    assert pilot.link.stats.rx_frames > 0


def test_disarm_in_the_air_without_the_force_code_is_denied_and_says_why(gcs_flight):
    """PX4's rule: MAV_CMD_COMPONENT_ARM_DISARM 0 in flight is refused unless param2 =
    21196; the GCS gets COMMAND_ACK DENIED and a STATUSTEXT saying why and how."""
    f = gcs_flight()
    f.start_pilot()
    f.recv("HEARTBEAT", lambda m: m.base_mode & mav.MAV_MODE_FLAG_SAFETY_ARMED)
    for param2 in (0.0, 21195.0, 21196.5):
        ack = f.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 0, param2)
        assert ack.result == mav.MAV_RESULT_DENIED
    text = f.text_seen("param2 = 21196 forces it")
    assert "disarm denied: in the air" in text
    assert f.vehicle.flight.killed is False
    # the motors never stopped: every ESC report after the refusals still turns
    f.recv("ESC_TELEMETRY_1_TO_4", lambda m: min(m.rpm) > 0)
    f.recv("HEARTBEAT", lambda m: m.base_mode & mav.MAV_MODE_FLAG_SAFETY_ARMED)
    assert f.vehicle.stats.commands_denied == 3


def test_signed_vehicle_ignores_an_unsigned_disarm(gcs_flight):
    key = bytes(range(32))
    f = gcs_flight(key=key)   # the mavutil GCS has no key: it reads nothing it can verify
    f.gcs.mav.command_long_send(1, 1, mav.MAV_CMD_COMPONENT_ARM_DISARM, 0, 0, 0, 0, 0, 0, 0, 0)
    time.sleep(0.3)
    assert f.vehicle.flight.killed is False
    assert f.vehicle.stats.gcs_link is not None and f.vehicle.stats.gcs_link.unsigned >= 1


def test_a_heartbeat_only_client_is_refused_as_controller(gcs_flight):
    f = gcs_flight(lockstep_timeout_s=0.3)
    ctl = f.vehicle.listen_address
    # mavsdk's default identity: a GCS (type 6, component 190).
    with Link.connect(ctl, src_system=245, src_component=190) as hello:
        hello.send(mav.MAVLink_heartbeat_message(mav.MAV_TYPE_GCS, mav.MAV_AUTOPILOT_INVALID,
                                                 0, 0, 0, 3))
        deadline = time.monotonic() + TIMEOUT_S
        text = ""
        while "GCS port" not in text and time.monotonic() < deadline:
            text += "".join(m.text for m in hello.recv(0.1) if m.get_type() == "STATUSTEXT")
        assert "refused as controller" in text, text
    assert f.vehicle.stats.controllers_refused == 1
    assert f.vehicle.controller_address is None and f.vehicle.stats.ticks == 0
    # An onboard controller that only says hello (mavsdk as a companion computer) gets the
    # first state, sends no HIL_ACTUATOR_CONTROLS, and is released after the timeout.
    with Link.connect(ctl, src_system=245, src_component=191) as companion:
        companion.send(mav.MAVLink_heartbeat_message(mav.MAV_TYPE_ONBOARD_CONTROLLER,
                                                     mav.MAV_AUTOPILOT_INVALID, 0, 0, 0, 3))
        f.text_seen("released")
    assert f.vehicle.stats.controllers_released == 1
    pilot = f.start_pilot()
    deadline = time.monotonic() + TIMEOUT_S
    while f.vehicle.stats.ticks < 10 and time.monotonic() < deadline:
        time.sleep(0.05)
    assert f.vehicle.stats.ticks >= 10
    assert f.vehicle.controller_address == pilot.link.local_address


def test_keep_alive_resets_and_waits_for_the_next_flight():
    import signal
    import subprocess

    from tfl_mav.tools.harness.processes import CLI, LISTEN_RE

    sim = subprocess.Popen([*CLI, "sim", "paper", "--set", "attack.rotor=0", "--listen",
                            "127.0.0.1:0", "--legacy-ports", "--gcs", "none", "--duration",
                            "0.01", "--keep-alive"], stdout=subprocess.PIPE,
                           stderr=subprocess.PIPE, text=True)
    try:
        m = LISTEN_RE.search(sim.stdout.readline())
        assert m, "sim did not start"
        address = (m.group(1), int(m.group(2)))
        sc = hover_scenario()
        u = hover_fraction(sc)
        for _flight in range(2):   # two whole flights on the same port, one process
            with Pilot(address) as pilot:
                while not pilot.queue:    # the reset vehicle may still be binding the port
                    pilot.hello()
                    pilot.pump(0.2)
                ticks = pilot.fly(None, lambda _o, _e: [u] * 4, timeout_s=TIMEOUT_S)
                assert len(ticks) == 10 and pilot.ended
        sim.send_signal(signal.SIGTERM)
        out, _err = sim.communicate(timeout=30)
    finally:
        if sim.poll() is None:
            sim.kill()
    assert sim.returncode == 128 + signal.SIGTERM
    assert "waiting for the next controller (flight 2)" in out
