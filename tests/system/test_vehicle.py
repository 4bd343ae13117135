"""The vehicle endpoint over real UDP on loopback, flown by a bare pymavlink client.

The vehicle runs in a thread (or, for the CLI, a subprocess); the client is our
:class:`~tfl_mav.link.transport.Link` with pymavlink's message classes, nothing else.
"""

from __future__ import annotations

import collections
import json
import math
import signal
import socket
import subprocess
import threading
import time
from collections.abc import Callable

import pytest

from tfl_mav.link.dialect import mav, new_mavlink
from tfl_mav.link.transport import Address, Link
from tfl_mav.scenario import Scenario, load_scenario
from tfl_mav.sitl.vehicle import ExitStatus, Vehicle, VehicleResult
from tfl_mav.tools.harness.pilot import Pilot
from tfl_mav.tools.harness.ports import LOOPBACK
from tfl_mav.tools.harness.processes import CLI, popen_sim

RPM_PER_RADPS = 60.0 / (2.0 * math.pi)
# Float32 on the wire: relative resolution 6e-8. Over 1 s the float32 rounding of the
# hover command (≤ 6e-8·g of acceleration) moves the vehicle < 1e-6 m; 1e-5 m is generous.
POSITION_TOL_M = 1e-5
RPM_TOL = 0.5   # the ESC reports whole rpm


def hover_scenario(**settings) -> Scenario:
    return load_scenario("paper").replace(**{"attack.rotor": 0, **settings})


def hover_fraction(sc: Scenario) -> float:
    v = sc.vehicle
    return v.mass_kg * v.gravity_mps2 / 4.0 / v.thrust_max_n


def rpm_for(thrust_n: float, sc: Scenario) -> float:
    return math.sqrt(thrust_n / sc.vehicle.k_f) * RPM_PER_RADPS


class Flight:
    """A :class:`Vehicle` flying in a background thread."""

    def __init__(self, scenario: Scenario, duration_s: float = math.inf, **kw) -> None:
        self.vehicle = Vehicle(scenario, listen=LOOPBACK, **kw)
        self.result: VehicleResult | None = None
        self.thread = threading.Thread(target=self._run, args=(duration_s,), daemon=True)
        self.thread.start()

    def _run(self, duration_s: float) -> None:
        self.result = self.vehicle.run(duration_s)

    def finish(self, timeout_s: float = 5.0) -> VehicleResult:
        self.thread.join(timeout_s)
        assert not self.thread.is_alive(), "vehicle did not end"
        assert self.result is not None
        return self.result

    def close(self) -> VehicleResult:
        self.vehicle.stop()
        result = self.finish()
        self.vehicle.close()
        return result


def inject(link: Link, rotor: float, failure_type: float = 4, unit: float = 101,
           target_system: int = 1, command: int = mav.MAV_CMD_INJECT_FAILURE) -> None:
    link.send(mav.MAVLink_command_long_message(target_system, 1, command, 0, unit,
                                               failure_type, rotor, 0, 0, 0, 0))


@pytest.fixture
def flight_factory():
    made: list[tuple[Flight, Pilot]] = []

    def make(scenario: Scenario, duration_s: float = math.inf, **kw) -> tuple[Flight, Pilot]:
        flight = Flight(scenario, duration_s, **kw)
        pilot = Pilot(flight.vehicle.listen_address)
        pilot.hello()
        made.append((flight, pilot))
        return flight, pilot

    yield make
    for flight, pilot in made:
        flight.close()
        pilot.close()


# ---------------------------------------------------------------------------- physics
def test_hover_in_lockstep_holds_position_and_reports_hover_rpm(flight_factory):
    sc = hover_scenario()
    flight, pilot = flight_factory(sc)
    u = hover_fraction(sc)
    states = pilot.fly(1000, lambda o, e: [u] * 4)
    x0, y0, z0 = sc.initial.position_m
    hover_rpm = rpm_for(sc.vehicle.mass_kg * sc.vehicle.gravity_mps2 / 4, sc)
    for k, (odom, esc) in enumerate(states):
        assert odom.time_usec == k * 1000
        assert (odom.frame_id, odom.child_frame_id) == (1, 12)    # LOCAL_NED, BODY_FRD
        assert (odom.x, odom.y, odom.z) == pytest.approx((y0, x0, -z0), abs=POSITION_TOL_M)
        assert odom.q == pytest.approx([math.sqrt(0.5), 0, 0, math.sqrt(0.5)], abs=1e-7)
        assert max(abs(odom.vx), abs(odom.vy), abs(odom.vz)) < 1e-5
        assert esc.rpm == pytest.approx([hover_rpm] * 4, abs=RPM_TOL)
        assert esc.count == [k + 1] * 4
    esc = states[-1][1]
    # Plausible electrics: a 4S pack under load, a few amps per ESC, warming up.
    assert all(1400 <= cv <= 1680 for cv in esc.voltage)
    assert all(100 <= ca <= 500 for ca in esc.current)
    assert all(25 <= t <= 40 for t in esc.temperature)
    assert flight.close().ticks == 1000


def test_climb_matches_the_closed_form_with_drag(flight_factory):
    """10 % above hover: z(t) = z0 + (a m/k)(t − (m/k)(1 − e^{−k t/m})), a = (4f − mg)/m."""
    sc = hover_scenario()
    v = sc.vehicle
    m, k, g = v.mass_kg, v.k_t, v.gravity_mps2
    u = hover_fraction(sc) * 1.1
    f = u * v.thrust_max_n
    a = (4 * f - m * g) / m
    _flight, pilot = flight_factory(sc)
    states = pilot.fly(1000, lambda o, e: [u] * 4)
    z0 = sc.initial.position_m[2]
    for i, (odom, esc) in enumerate(states):
        t = i * 1e-3
        z = z0 + a * m / k * (t - m / k * (1 - math.exp(-k * t / m)))
        vz = a * m / k * (1 - math.exp(-k * t / m))
        assert -odom.z == pytest.approx(z, abs=POSITION_TOL_M)
        assert -odom.vz == pytest.approx(vz, abs=1e-5)      # body FRD z = down when level
        # Tick 0 reports the initial (hover) rotor speed; the command acts from tick 1.
        assert esc.rpm == pytest.approx([rpm_for(f if i else m * g / 4, sc)] * 4, abs=RPM_TOL)


# ---------------------------------------------------------------------------- commands
def test_inject_failure_on_each_rotor_changes_that_rotors_rpm(flight_factory):
    sc = hover_scenario(**{"attack.signal": "constant", "attack.value_n": 1.0})
    flight, pilot = flight_factory(sc)
    u = hover_fraction(sc)
    hover_rpm = rpm_for(u * sc.vehicle.thrust_max_n, sc)
    attacked_rpm = rpm_for(1.0, sc)
    hold = lambda o, e: [u] * 4   # noqa: E731
    pilot.fly(5, hold)
    for rotor in (1, 2, 3, 4):
        inject(pilot.link, rotor)
        ack = None
        while ack is None:               # keep the lockstep loop turning until the ACK
            pilot.fly(1, hold)
            ack = next((a for a in pilot.acks if a.command == 420), None)
        pilot.acks.remove(ack)
        assert (ack.result, ack.target_system, ack.target_component) == (
            mav.MAV_RESULT_ACCEPTED, 1, 191)
        _, esc = pilot.fly(3, hold)[-1]
        expected = [hover_rpm] * 4
        expected[rotor - 1] = attacked_rpm
        assert esc.rpm == pytest.approx(expected, abs=RPM_TOL), rotor
        inject(pilot.link, rotor, failure_type=0)            # FAILURE_TYPE_OK ends it
        pilot.fly(3, hold)
        assert pilot.wait_ack(420).result == mav.MAV_RESULT_ACCEPTED
        _, esc = pilot.fly(2, hold)[-1]
        assert esc.rpm == pytest.approx([hover_rpm] * 4, abs=RPM_TOL)
    assert any("failure injected: rotor 4 WRONG" in s for s in pilot.statustexts)
    assert flight.vehicle.stats.failures_injected == 4


class Gcs:
    """A ground station listening on its own port; the vehicle sends to it."""

    def __init__(self) -> None:
        self.link = Link.listen(LOOPBACK, src_system=255, src_component=190)
        self.msgs: list = []

    def pump(self, until: Callable[[list], bool], timeout_s: float = 3.0) -> list:
        deadline = time.monotonic() + timeout_s
        while not until(self.msgs):
            assert time.monotonic() < deadline, "GCS: condition not met"
            self.msgs += self.link.recv(0.05)
        return self.msgs

    def of(self, kind: str) -> list:
        return [m for m in self.msgs if m.get_type() == kind]

    def ack_for(self, n: int) -> list:
        self.pump(lambda ms: len(self.of("COMMAND_ACK")) >= n)
        return self.of("COMMAND_ACK")


@pytest.fixture
def gcs():
    g = Gcs()
    yield g
    g.link.close()


def test_gcs_commands_are_answered_before_the_flight_starts(gcs):
    flight = Flight(hover_scenario(), gcs=gcs.link.local_address)
    try:
        gcs.pump(lambda ms: any(m.get_type() == "HEARTBEAT" for m in ms))
        hb = gcs.of("HEARTBEAT")[0]
        assert (hb.type, hb.system_status) == (mav.MAV_TYPE_QUADROTOR, mav.MAV_STATE_STANDBY)
        cases = [  # (param1 unit, param2 type, param3 rotor, command) → result, field named
            (101, 4, 2, 420, mav.MAV_RESULT_ACCEPTED, None),
            (101, 4, 2, 22, mav.MAV_RESULT_UNSUPPORTED, None),    # NAV_TAKEOFF: not ours
            (100, 4, 2, 420, mav.MAV_RESULT_DENIED, "param1"),
            (101, 3, 2, 420, mav.MAV_RESULT_DENIED, "param2"),    # GARBAGE: not supported
            (101, 4, 5, 420, mav.MAV_RESULT_DENIED, "param3"),
            (101, 4, 0, 420, mav.MAV_RESULT_DENIED, "param3"),
            (101, 4, 2.5, 420, mav.MAV_RESULT_DENIED, "param3"),
            (101, math.nan, 2, 420, mav.MAV_RESULT_DENIED, "param2"),
        ]
        for i, (unit, ftype, rotor, command, result, field) in enumerate(cases):
            inject(gcs.link, rotor, ftype, unit, command=command)
            ack = gcs.ack_for(i + 1)[-1]
            assert (ack.command, ack.result) == (command, result), cases[i]
            assert (ack.target_system, ack.target_component) == (255, 190)
            if field is not None:
                gcs.pump(lambda ms, f=field: any(m.get_type() == "STATUSTEXT"
                                                 and f in m.text for m in ms))
        inject(gcs.link, 2, target_system=42)          # for another system: no answer
        time.sleep(0.1)
        gcs.msgs += gcs.link.recv(0.05)
        assert len(gcs.of("COMMAND_ACK")) == len(cases)
        st = flight.vehicle.stats
        assert (st.commands_accepted, st.commands_unsupported, st.commands_denied,
                st.commands_not_for_us) == (1, 1, 6, 1)
    finally:
        result = flight.close()
    assert result.status is ExitStatus.STOPPED and result.ticks == 0


@pytest.mark.slow
def test_gcs_sees_telemetry_at_50_hz_of_sim_time(flight_factory, gcs):
    # Lockstep paces the GCS by sim time (as PX4's lockstep SITL does): 1 s of flight is
    # 51 datagrams (t = 0, 0.02, ..., 1.0) and two HEARTBEATs (t = 0, 1 s) however fast or
    # slow the run went.
    sc = hover_scenario()
    _flight, pilot = flight_factory(sc, gcs=gcs.link.local_address, gcs_rate_hz=50.0)
    u = hover_fraction(sc)
    pilot.fly(1000, lambda o, e: [u] * 4)
    gcs.pump(lambda ms: len([m for m in ms if m.get_type() == "ATTITUDE"]) >= 51)
    attitude = gcs.of("ATTITUDE")
    assert [m.time_boot_ms for m in attitude] == list(range(0, 1001, 20))
    assert (attitude[-1].roll, attitude[-1].pitch, attitude[-1].yaw) == pytest.approx(
        (0.0, 0.0, math.pi / 2), abs=1e-6)
    pos = gcs.of("LOCAL_POSITION_NED")[-1]
    x0, y0, z0 = sc.initial.position_m
    assert (pos.x, pos.y, pos.z) == pytest.approx((y0, x0, -z0), abs=POSITION_TOL_M)
    out = gcs.of("ACTUATOR_OUTPUT_STATUS")[-1]
    assert out.actuator[:4] == pytest.approx([u] * 4, abs=1e-6)
    sys_status = gcs.of("SYS_STATUS")[-1]
    assert 14000 < sys_status.voltage_battery <= 16800
    assert 0 < sys_status.current_battery < 3000 and sys_status.battery_remaining > 90
    assert any(m.get_type() == "HEARTBEAT" and m.base_mode & 128 for m in gcs.msgs)
    hover_rpm = rpm_for(u * sc.vehicle.thrust_max_n, sc)
    assert gcs.of("ESC_TELEMETRY_1_TO_4")[-1].rpm == pytest.approx([hover_rpm] * 4,
                                                                   abs=RPM_TOL)


def test_unsupported_command_on_the_control_port_gets_unsupported(flight_factory):
    sc = hover_scenario()
    _flight, pilot = flight_factory(sc)
    u = hover_fraction(sc)
    pilot.fly(2, lambda o, e: [u] * 4)
    pilot.link.send(mav.MAVLink_command_long_message(1, 1, mav.MAV_CMD_REQUEST_MESSAGE, 0,
                                                     33, 0, 0, 0, 0, 0, 0))
    pilot.fly(3, lambda o, e: [u] * 4)
    assert pilot.wait_ack(mav.MAV_CMD_REQUEST_MESSAGE).result == mav.MAV_RESULT_UNSUPPORTED


# ---------------------------------------------------------------------------- lockstep
def _closed_loop(sc: Scenario, n_ticks: int) -> list[tuple[bytes, bytes]]:
    """Fly a small state-feedback law (altitude and attitude damping); return payloads."""
    flight = Flight(sc)
    pilot = Pilot(flight.vehicle.listen_address)
    pilot.hello()
    u0 = hover_fraction(sc)

    def law(odom, esc) -> list[float]:
        dz = odom.z + 1.0                       # NED: hold 1 m up
        base = u0 - 0.2 * dz - 0.05 * odom.vz   # body FRD vz ≈ down speed
        p, q = odom.rollspeed, odom.pitchspeed
        return [base - 0.01 * q, base + 0.01 * p, base + 0.01 * q, base - 0.01 * p]

    try:
        states = pilot.fly(n_ticks, law)
    finally:
        flight.close()
        pilot.close()
    return [(bytes(o.get_payload()), bytes(e.get_payload())) for o, e in states]


def test_lockstep_is_deterministic_byte_for_byte():
    sc = load_scenario("nominal").replace(**{
        "sensors.position_noise_std_m": 0.01, "sensors.velocity_noise_std_mps": 0.02,
        "sensors.attitude_noise_std_rad": 0.002, "sensors.rate_noise_std_radps": 0.01,
        "run.seed": 7})
    first = _closed_loop(sc, 400)
    second = _closed_loop(sc, 400)
    assert first == second
    assert len({o for o, _ in first}) == 400           # the states did change
    third = _closed_loop(sc.replace(**{"run.seed": 8}), 50)
    assert third != first[:50]                          # and the seed matters


def test_missing_reply_is_counted_and_the_state_resent_never_skipped(flight_factory):
    sc = hover_scenario()
    flight, pilot = flight_factory(sc, lockstep_timeout_s=0.15)
    u = hover_fraction(sc)
    pilot.fly(3, lambda o, e: [u] * 4)
    odom, _ = pilot.state()                  # tick 3: do not answer
    t0 = time.monotonic()
    again, _ = pilot.state(timeout_s=2.0)    # resent after the 20 ms resend interval,
    resent_after_s = time.monotonic() - t0   # long before the 0.15 s give-up timeout
    assert again.time_usec == odom.time_usec == 3000
    assert resent_after_s < 0.15
    while not any("lockstep" in s for s in pilot.statustexts):   # then reported, once
        pilot.state(timeout_s=2.0)
    pilot.queue.clear()
    pilot.reply(again, [u] * 4)
    nxt, _ = pilot.state()
    while nxt.time_usec == 3000:             # resends of tick 3 still in flight
        nxt, _ = pilot.state()
    assert nxt.time_usec == 4000
    st = flight.vehicle.stats
    assert st.lockstep_timeouts == 1 and st.lockstep_resends >= 2


def test_duration_ends_the_run_with_completed(flight_factory):
    sc = hover_scenario()
    flight, pilot = flight_factory(sc, duration_s=0.05)
    u = hover_fraction(sc)
    pilot.fly(50, lambda o, e: [u] * 4)
    result = flight.finish()
    assert (result.status, result.ticks, result.sim_time_s) == (ExitStatus.COMPLETED, 50, 0.05)
    pilot.pump(0.2)
    assert pilot.heartbeats[-1].system_status == mav.MAV_STATE_POWEROFF


def test_crash_ends_the_run_with_the_reason(flight_factory):
    sc = hover_scenario(**{"initial.position_m": [0.0, 0.0, 0.1]})
    flight, pilot = flight_factory(sc)
    # Motors off from 0.1 m: the ground is ~0.14 s away (slightly more with drag).
    with pytest.raises(AssertionError, match="no state"):
        pilot.fly(1000, lambda o, e: [0.0] * 4, timeout_s=0.5)
    result = flight.finish()
    assert result.status is ExitStatus.CRASHED
    assert "hit the ground" in result.reason
    assert 140 <= result.ticks <= 150
    pilot.pump(0.1)
    assert any(s.startswith("crashed: hit the ground") for s in pilot.statustexts)


def test_disarmed_controls_stop_the_motors(flight_factory):
    sc = hover_scenario(**{"initial.position_m": [0.0, 0.0, 10.0]})
    _flight, pilot = flight_factory(sc)
    u = hover_fraction(sc)
    pilot.fly(2, lambda o, e: [u] * 4)
    odom, _ = pilot.state()
    pilot.reply(odom, [u] * 4, mode=0)
    _, esc = pilot.state()
    assert esc.rpm == [0, 0, 0, 0]
    assert any("disarmed" in s for s in pilot.statustexts)


# ---------------------------------------------------------------------------- bad input
def test_bad_datagrams_and_bad_controls_are_survived_counted_and_never_applied(
        flight_factory):
    sc = hover_scenario()
    flight, pilot = flight_factory(sc)
    vehicle = flight.vehicle
    u = hover_fraction(sc)
    hover_rpm = rpm_for(u * sc.vehicle.thrust_max_n, sc)
    pilot.fly(3, lambda o, e: [u] * 4)

    good = new_mavlink(1, 191)
    odom, _ = pilot.state()
    t = odom.time_usec
    valid = bytes(mav.MAVLink_hil_actuator_controls_message(
        t, [1.0] * 4 + [0.0] * 12, 128, 1).pack(good))
    intruder = Link.connect(vehicle.listen_address, src_system=1, src_component=191)
    other_sysid = bytes(mav.MAVLink_hil_actuator_controls_message(
        t, [1.0] * 4 + [0.0] * 12, 128, 1).pack(new_mavlink(9, 191)))
    bad = [
        b"\x00garbage",
        valid[:-4],                                           # truncated
        valid[:-1] + bytes([valid[-1] ^ 0x55]),               # bad CRC
        b"\xfd\x01\x00\x00\x00\x01\xbf\x60\xea\x00\x00\x00\x00",  # unknown id 60000
        b"\xfe\x09\x00\x01\xbf\x00" + bytes(11),              # MAVLink 1
        other_sysid,                                          # wrong sysid, peer's address
    ]
    for datagram in bad:
        pilot.link.send_raw(datagram)
    intruder.send_raw(valid)                                  # foreign: full thrust, dropped
    # Controls for the awaited tick that must be refused, in order, then a good one.
    pilot.reply(odom, [u] * 4, time_usec=t + 1000)           # stale: not the awaited tick
    pilot.reply(odom, [math.nan, u, u, u])                    # rejected, tick consumed
    ticks = []
    for values in ([u, math.inf, u, u], [u, u, 1.5, u], [u, u, u, -0.01],
                   [1.0 + 5e-5, u, u, u]):                    # last: within tolerance
        odom, esc = pilot.state()
        ticks.append((odom.time_usec, esc.rpm))
        pilot.reply(odom, values)
    odom, esc = pilot.state()
    ticks.append((odom.time_usec, esc.rpm))
    intruder.close()

    # Every refused command left the previous (hover) command in place; no tick skipped.
    assert [t_ for t_, _ in ticks] == [t + 1000 * i for i in range(1, 6)]
    for _, rpm in ticks[:-1]:
        assert rpm == pytest.approx([hover_rpm] * 4, abs=RPM_TOL)
    assert ticks[-1][1][0] == pytest.approx(rpm_for(sc.vehicle.thrust_max_n, sc), abs=RPM_TOL)
    assert all(math.isfinite(c) for c in vehicle.sim.rotor_commands_n)
    link = vehicle.stats.control_link
    assert (link.garbage, link.truncated, link.bad_crc, link.unknown_id, link.mavlink1,
            link.wrong_sysid, link.foreign) == (1, 1, 1, 1, 1, 1, 1)
    st = vehicle.stats
    assert (st.rejected_controls, st.stale_controls) == (4, 1)
    pilot.pump(0.05)
    assert any("controls[0]: not finite (nan)" in s for s in pilot.statustexts)
    assert flight.thread.is_alive()


# ---------------------------------------------------------------------------- real time
@pytest.mark.slow
def test_realtime_holds_the_last_command_and_cuts_the_motors_on_link_loss(flight_factory):
    """Wall-clock assertions are one-sided or loose: the test must hold on a loaded machine
    (the vehicle then falls behind and says so in ``overruns``)."""
    sc = hover_scenario(**{"initial.position_m": [0.0, 0.0, 50.0]})
    flight, pilot = flight_factory(sc, realtime=True, command_timeout_s=0.1)
    u = hover_fraction(sc) * 0.5
    half = rpm_for(u * sc.vehicle.thrust_max_n, sc)
    t_start = time.monotonic()
    odom, _ = pilot.state()
    pilot.reply(odom, [u] * 4)
    t_reply = time.monotonic()
    seen = []
    while time.monotonic() - t_reply < 0.6:                   # silent from here on
        odom, esc = pilot.state()
        seen.append((time.monotonic(), odom.time_usec, esc.rpm))
    rpms = [r for _, _, r in seen]
    first = next(i for i, r in enumerate(rpms) if r == pytest.approx([half] * 4, abs=RPM_TOL))
    cut = next(i for i, r in enumerate(rpms) if r == [0, 0, 0, 0])
    # Hover until the command lands, then held (zero-order hold) until the cut, then zero.
    assert all(r[0] > half for r in rpms[:first])
    assert all(r == pytest.approx([half] * 4, abs=RPM_TOL) for r in rpms[first:cut])
    assert all(r == [0, 0, 0, 0] for r in rpms[cut:])
    # Cut only after the 0.1 s command timeout (wall time), and not much later.
    assert 0.1 <= seen[cut][0] - t_reply < 1.0
    # Sim time follows the wall clock, unless the vehicle reported falling behind.
    wall, sim_usec, _ = seen[-1]
    vehicle = flight.vehicle
    if vehicle.stats.overruns == 0:
        assert sim_usec / 1e6 == pytest.approx(wall - t_start, abs=0.15)
    assert any("link loss" in s for s in pilot.statustexts)
    assert vehicle.stats.command_timeouts == 1
    # The next valid command restores the motors.
    odom, _ = pilot.state()
    pilot.reply(odom, [u] * 4)
    deadline = time.monotonic() + 2.0
    while pilot.state()[1].rpm != pytest.approx([half] * 4, abs=RPM_TOL):
        assert time.monotonic() < deadline, "motors not restored"
    pilot.pump(0.05)
    assert any("commands resumed" in s for s in pilot.statustexts)


def test_pinned_peer_gets_heartbeats_before_the_flight_and_nobody_else_can_start_it():
    pilot_sock = Link.listen(LOOPBACK, src_system=1, src_component=191)   # reserve an address
    address = pilot_sock.local_address
    pilot_sock.close()
    flight = Flight(hover_scenario(), peer=address)
    intruder = Pilot(flight.vehicle.listen_address)
    pilot = Pilot(flight.vehicle.listen_address, bind=address)
    try:
        intruder.hello()
        pilot.pump(1.0)
        assert pilot.heartbeats and pilot.heartbeats[0].system_status == mav.MAV_STATE_STANDBY
        assert not pilot.queue                         # no state: the flight has not started
        assert flight.vehicle.stats.control_link.foreign == 1
        pilot.hello()
        odom, _ = pilot.state()
        assert odom.time_usec == 0
        assert intruder.link.recv(0.1) == []          # nothing was ever sent to the intruder
    finally:
        flight.close()
        pilot.close()
        intruder.close()


@pytest.mark.slow
def test_stop_before_the_controller_connects():
    flight = Flight(hover_scenario())
    time.sleep(0.05)
    t0 = time.monotonic()
    result = flight.close()
    assert time.monotonic() - t0 < 0.5
    assert (result.status, result.ticks) == (ExitStatus.STOPPED, 0)


# ---------------------------------------------------------------------------- CLI
def _start_cli(*args: str) -> tuple[subprocess.Popen, Address]:
    return popen_sim(args)


@pytest.mark.slow
def test_cli_flies_and_exits_cleanly_on_sigterm(tmp_path):
    report, run_mcap = tmp_path / "sim.json", tmp_path / "run.mcap"
    # Exact frame counts below: no resend may interleave (a loaded machine can delay a
    # reply past the 5 ms default), so the resend interval is the 2 s timeout here.
    proc, address = _start_cli("--set", "attack.rotor=0", "--duration", "0",
                               "--json", str(report), "--mcap", str(run_mcap),
                               "--resend-interval", "2", "--gcs", "none")
    pilot = Pilot(address)
    try:
        pilot.hello()
        sc = hover_scenario()
        states = pilot.fly(100, lambda o, e: [hover_fraction(sc)] * 4)
        assert states[-1][0].time_usec == 99_000
        proc.send_signal(signal.SIGTERM)
        out, err = proc.communicate(timeout=10)
    finally:
        pilot.close()
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 143, err
    assert "stopped on request" in out and "ticks" in out
    data = json.loads(report.read_text())
    assert (data["status"], data["exit_code"], data["ticks"]) == ("stopped", 143, 100)
    assert data["stats"]["controls_applied"] == 100
    link = data["stats"]["control_link"]
    assert link["rx_frames"] == 101                        # HEARTBEAT + 100 replies
    # The recording: ground truth at every tick's state (initial + 100 steps), every frame.
    from mcap.reader import make_reader

    with run_mcap.open("rb") as fh:
        counts = collections.Counter(ch.topic for _, ch, _ in make_reader(fh).iter_messages())
    with run_mcap.open("rb") as fh:
        meta = {m.name: m.metadata for m in make_reader(fh).iter_metadata()}
    recorded = json.loads(meta["scenario"]["scenario_json"])
    assert recorded["attack"]["rotor"] == 0 and recorded["name"] == "paper"
    assert counts["/sim/truth/state"] == 101
    # Decoded MAVLink channels at ≤ 50 Hz of sim time (ticks 0, 20, …, 100 of 1 ms); every
    # frame of every tick is in /mavlink/raw, a datagram a message (and decodes from there
    # on read).
    from tfl_mav.flightlog.logread import raw_frames

    assert counts["/mavlink/1/1/ODOMETRY"] == 6
    assert sum(1 for _ in raw_frames(run_mcap)) == link["rx_frames"] + link["tx_frames"]
    assert counts["/mavlink/raw"] < link["rx_frames"] + link["tx_frames"]


@pytest.mark.slow
def test_cli_exit_codes_for_interrupt_crash_and_port_in_use():
    proc, address = _start_cli()                     # waiting for a controller
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=10)
    assert proc.returncode == 130, err

    proc, address = _start_cli("--set", "attack.rotor=0", "--set",
                               "initial.position_m=[0, 0, 0.05]")
    pilot = Pilot(address)
    try:
        pilot.hello()
        with pytest.raises(AssertionError, match="no state"):
            pilot.fly(1000, lambda o, e: [0.0] * 4, timeout_s=0.5)
        out, err = proc.communicate(timeout=10)
    finally:
        pilot.close()
    assert proc.returncode == 1
    assert "hit the ground" in err and "crashed" in out

    busy = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    busy.bind(LOOPBACK)
    try:
        port = busy.getsockname()[1]
        done = subprocess.run([*CLI, "sim", "--listen", f"127.0.0.1:{port}"],
                              capture_output=True, text=True, timeout=20)
    finally:
        busy.close()
    assert done.returncode == 3
    assert "cannot bind" in done.stderr
