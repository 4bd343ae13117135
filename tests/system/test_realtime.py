"""Real time without false alarms, degrading instead of falling, restarts.

Pure and fast where the mechanism allows it: the detector is fed late, lost and reordered
commands through :meth:`FlightComputer.step` offline (a seeded link model between the
flight computer and the simulator); the daemon's batch handling is driven by a scripted
vehicle over real UDP on loopback, with the time stamps chosen by the test, so nothing
depends on the machine's speed.
"""

from __future__ import annotations

import random
import threading
import time
from typing import Any

import pytest

from tfl_mav.controller.daemon import Daemon
from tfl_mav.controller.flight_computer import FlightComputer
from tfl_mav.link.transport import Link
from tfl_mav.scenario import Scenario, load_scenario
from tfl_mav.sitl.power import PowerModel
from tfl_mav.sitl.simulator import Simulator
from tfl_mav.sitl.state_report import StateReport


# ---------------------------------------------------------------------------- detector
def _fly_through_link(sc: Scenario, seed: int, *, n_ticks: int, loss: float,
                      max_delay_ticks: int, tell_applied: bool) -> tuple[int, str | None]:
    """Flight computer ↔ a lossy, jittery, reordering link ↔ simulator, offline.

    Each command is lost with probability ``loss`` or arrives 0..``max_delay_ticks`` ticks
    late (uniform: later ones overtake earlier ones); the vehicle holds the newest by
    time_usec and ignores older ones, as :class:`tfl_mav.sitl.commands.ActuatorControls` does. The
    flight computer is given the command the vehicle held over the last period (what
    ACTUATOR_OUTPUT_STATUS reports) or, ``tell_applied`` False, the last one it sent (the
    old daemon). Returns (tick of the first alarm or -1, crash reason or None)."""
    rng = random.Random(seed)
    fc = FlightComputer(sc)
    sim = Simulator(sc)
    in_flight: list[tuple[int, int, list[float]]] = []   # (arrival tick, time_usec, thrust)
    held_usec = -1
    applied = list(sim.rotor_commands_n)
    last_sent = list(applied)
    for k in range(n_ticks):
        res = fc.step(sim.time_s, sim.measured, sim.measured_rpm(),
                      applied if tell_applied else last_sent)
        if fc.detected_rotor:
            return k, None
        last_sent = res.thrust_n
        if rng.random() >= loss:
            in_flight.append((k + rng.randint(0, max_delay_ticks), sim.time_usec, last_sent))
        due = [c for c in in_flight if c[0] <= k]
        in_flight = [c for c in in_flight if c[0] > k]
        for _, t_usec, thrust in due:
            if t_usec > held_usec:
                held_usec = t_usec
                sim.set_command(thrust)
        applied = list(sim.rotor_commands_n)
        sim.step_control_period()
        if (reason := sim.crash_reason()) is not None:
            return -1, reason
    return -1, None


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_late_lost_reordered_commands_are_never_an_attack(seed):
    """No attack, 20 % loss, 0-4 ticks of delay (reordering): compared with what was
    applied, every rotor obeys, so the CUSUM never moves (k = 2σ per sample is never
    exceeded by noise alone, and the command/rpm pairs now match exactly)."""
    sc = load_scenario("nominal")
    alarm, crash = _fly_through_link(sc, seed, n_ticks=600, loss=0.2, max_delay_ticks=4,
                                     tell_applied=True)
    assert crash is None
    assert alarm == -1


def test_comparing_with_the_sent_command_is_what_raised_false_alarms():
    """The same link, the old comparison (last command *sent*): the start transient moves
    the command by far more than the rpm noise per tick, so a delayed command looks like a
    rotor that disobeys. Seed 0 alarms within the first few ticks: the test above has
    teeth."""
    sc = load_scenario("nominal")
    alarm, _ = _fly_through_link(sc, 0, n_ticks=100, loss=0.2, max_delay_ticks=4,
                                 tell_applied=False)
    assert 0 <= alarm < 100


def test_the_attack_is_still_found_through_a_lossy_link():
    """Applied-command comparison keeps its power: the paper's rotor-2 attack, 20 % loss."""
    sc = load_scenario("paper")
    alarm, crash = _fly_through_link(sc, 3, n_ticks=200, loss=0.2, max_delay_ticks=4,
                                     tell_applied=True)
    assert crash is None
    assert 0 <= alarm <= round((sc.attack.start_s + 0.02) / sc.run.control_dt_s)


# ---------------------------------------------------------------------------- daemon
class ScriptedVehicle:
    """A vehicle whose states carry the time stamps the test chooses (real UDP)."""

    def __init__(self, sc: Scenario) -> None:
        self.sim = Simulator(sc)
        v = sc.vehicle
        power = PowerModel(drag_thrust_ratio_m=v.drag_thrust_ratio_m, k_f=v.k_f)
        power.step(self.sim.motors.omega_radps, 0.0)
        self.report = StateReport(self.sim, power, sc.sensors)
        self.link = Link.listen(("127.0.0.1", 0), src_system=1, src_component=1)
        self.answers: list[Any] = []

    def await_controller(self, timeout_s: float = 10.0) -> None:
        deadline = time.monotonic() + timeout_s
        while self.link.peer is None:
            assert time.monotonic() < deadline, "the daemon never sent its HEARTBEAT"
            self.link.recv(0.05)

    def states(self, *times_usec: int, applied_usec: int = 0, driven: bool = True
               ) -> list[Any]:
        msgs: list[Any] = []
        for t in times_usec:
            odom, applied, esc = self.report.update(applied_usec, driven)
            odom.time_usec = t
            msgs += [odom, applied, esc]
        return msgs

    def send(self, *times_usec: int, driven: bool = True) -> None:
        """All these states in one datagram (one batch for the daemon); ``driven`` False:
        ACTUATOR_OUTPUT_STATUS says no command drives the motors."""
        self.link.send_many(self.states(*times_usec, driven=driven))

    def collect(self, n: int, timeout_s: float = 10.0) -> list[int]:
        """time_usec of the next ``n`` HIL_ACTUATOR_CONTROLS (AssertionError if fewer)."""
        got: list[int] = []
        deadline = time.monotonic() + timeout_s
        while len(got) < n:
            assert time.monotonic() < deadline, f"only {got} answered"
            for m in self.link.recv(0.05):
                if m.get_type() == "HIL_ACTUATOR_CONTROLS":
                    got.append(m.time_usec)
                    self.answers.append(m)
        return got

    def quiet(self, wait_s: float = 0.3) -> list[int]:
        """Answers arriving within ``wait_s`` (expected: none)."""
        end = time.monotonic() + wait_s
        got = []
        while time.monotonic() < end:
            got += [m.time_usec for m in self.link.recv(0.05)
                    if m.get_type() == "HIL_ACTUATOR_CONTROLS"]
        return got


@pytest.fixture
def scripted() -> Any:
    sc = load_scenario("nominal")
    vehicle = ScriptedVehicle(sc)
    daemon = Daemon(sc, vehicle=vehicle.link.local_address, realtime=True,
                    state_timeout_s=30.0)
    thread = threading.Thread(target=daemon.run, kwargs={"duration_s": 1e9}, daemon=True)
    thread.start()
    vehicle.await_controller()
    yield vehicle, daemon
    daemon.stop()
    thread.join(5.0)
    daemon.close()
    vehicle.link.close()


def test_daemon_answers_the_newest_state_once_and_never_an_older_one(scripted):
    vehicle, daemon = scripted
    vehicle.send(0)
    assert vehicle.collect(1) == [0]
    vehicle.send(1000, 2000, 3000)              # a backlog: only the newest is controlled
    assert vehicle.collect(1) == [3000]
    assert vehicle.quiet() == []
    st = daemon.stats
    assert (st.ticks, st.skipped_states) == (2, 2)
    assert st.gap_ticks == 1                    # 3 ms since the last: integrated as such
    first = vehicle.answers[-1].controls[:4]
    vehicle.send(3000)                          # the same state again (a lockstep resend)
    assert vehicle.collect(1) == [3000]
    assert list(vehicle.answers[-1].controls[:4]) == list(first)   # same command, law not rerun
    vehicle.send(2000)                          # an older state: dropped
    assert vehicle.quiet() == []
    assert (st.ticks, st.repeated_states, st.old_states) == (2, 1, 1)


def test_daemon_rebuilds_when_vehicle_time_goes_backwards(scripted):
    vehicle, daemon = scripted
    for k in range(5):
        vehicle.send(k * 100_000)               # fly to t = 0.4 s (gaps, but in order)
        assert vehicle.collect(1) == [k * 100_000]
    old = daemon.computer
    vehicle.send(0)                             # a restarted simulator: t = 0 again ...
    assert vehicle.quiet() == []                # (one datagram could be forged: not yet)
    assert daemon.stats.implausible_states == 1
    vehicle.send(0)                             # ... and again (its start-up resend)
    assert vehicle.collect(1) == [0]
    assert daemon.stats.rebuilds == 1
    assert daemon.computer is not old
    vehicle.send(1000)
    assert vehicle.collect(1) == [1000]


def test_one_forged_future_state_does_not_lock_the_daemon_out(scripted):
    """A single state far ahead (say time_usec = 2^63) is implausible: not flown, and the
    genuine states that follow are still answered (it did not move the watermark)."""
    vehicle, daemon = scripted
    vehicle.send(0)
    assert vehicle.collect(1) == [0]
    vehicle.send(2**63)
    assert vehicle.quiet() == []
    vehicle.send(1000)
    assert vehicle.collect(1) == [1000]
    st = daemon.stats
    assert (st.ticks, st.implausible_states, st.rebuilds) == (2, 1, 0)


def test_a_shuffled_burst_of_old_states_is_reordering_not_a_restart(scripted):
    """A relay stalled for tens of ms releases its backlog shuffled: many old states in a
    row, at *different* times. That is reordering (dropped, counted), never a restarted
    vehicle — rebuilding the flight computer mid-flight would throw the flight away."""
    vehicle, daemon = scripted
    vehicle.send(100_000)
    assert vehicle.collect(1) == [100_000]
    late = list(range(1000, 100_000, 1000))        # 99 older states, each time once
    random.Random(3).shuffle(late)
    for t in late:
        vehicle.send(t)
    assert vehicle.quiet() == []
    st = daemon.stats
    assert (st.rebuilds, st.old_states) == (0, len(late))
    vehicle.send(101_000)                          # the flight goes on, same controller
    assert vehicle.collect(1) == [101_000]


def test_a_new_vehicle_waiting_at_its_first_state_is_a_restart(scripted):
    """A vehicle restarted less than BACKSTEP_S into a flight resends its first state until
    answered: old states in a row at one time are a new time line (rebuild)."""
    vehicle, daemon = scripted
    for k in range(1, 6):
        vehicle.send(k * 20_000)                   # fly to t = 0.1 s
        assert vehicle.collect(1) == [k * 20_000]
    old = daemon.computer
    for _ in range(24):                            # RESTART_OLD_STATES − 1: still old
        vehicle.send(0)
    assert vehicle.quiet() == []
    vehicle.send(0)                                # the 25th at the same time: a restart
    assert vehicle.collect(1) == [0]
    assert daemon.stats.rebuilds == 1 and daemon.computer is not old


def _daemon_with_hold(sc: Scenario, vehicle: ScriptedVehicle, hold: list[bool]) -> Any:
    daemon = Daemon(sc, vehicle=vehicle.link.local_address, realtime=True,
                    state_timeout_s=30.0, hold_start=lambda: hold[0])
    thread = threading.Thread(target=daemon.run, kwargs={"duration_s": 1e9}, daemon=True)
    thread.start()
    vehicle.await_controller()
    return daemon, thread


@pytest.mark.parametrize("first_usec", [0, 4_000_000])
def test_only_a_vehicle_waiting_at_t0_waits_for_hold_start(first_usec):
    """A vehicle at t = 0 has not started its clock (it waits for our first command): the
    daemon may wait there (for its recorder). A vehicle already flying (a restart) is
    answered at once, whatever hold_start says: its motors are cut 0.25 s after the last
    command."""
    sc = load_scenario("nominal")
    vehicle = ScriptedVehicle(sc)
    hold = [True]
    daemon, thread = _daemon_with_hold(sc, vehicle, hold)
    try:
        vehicle.send(first_usec)
        if first_usec == 0:
            assert vehicle.quiet() == []
            vehicle.send(0)                          # its resend every 10 ms ...
            assert vehicle.quiet() == []
            hold[0] = False
            vehicle.send(0)                          # ... answered once the hold ends
        assert vehicle.collect(1) == [first_usec]
        assert daemon.stats.ticks == 1
    finally:
        daemon.stop()
        thread.join(5.0)
        daemon.close()
        vehicle.link.close()


def test_motors_not_driven_pause_the_detector_and_are_said_once_a_second():
    """ACTUATOR_OUTPUT_STATUS active 0 (disarmed, cut): the detector is told; a vehicle
    flipping the bit every state is counted every time but said at most once a second."""
    sc = load_scenario("nominal")
    vehicle = ScriptedVehicle(sc)
    events: list[str] = []
    daemon = Daemon(sc, vehicle=vehicle.link.local_address, realtime=True,
                    state_timeout_s=30.0, on_event=lambda _lvl, text, _t: events.append(text))
    thread = threading.Thread(target=daemon.run, kwargs={"duration_s": 1e9}, daemon=True)
    thread.start()
    try:
        vehicle.await_controller()
        vehicle.send(0)
        assert vehicle.collect(1) == [0]
        for k in range(1, 41):                 # 40 ms: off, on, off, on, ...
            vehicle.send(k * 1000, driven=k % 2 == 0)
            assert vehicle.collect(1) == [k * 1000]
            assert daemon.computer.detector.motors_off is (k % 2 == 1)
        st = daemon.stats
        assert (st.motors_off_periods, st.motors_off_ticks) == (20, 20)
        said = [e for e in events if "motors" in e]
        assert len(said) == 2 and "paused" in said[0] and "resumed" in said[1], said
        vehicle.send(600_000)
        assert vehicle.collect(1) == [600_000]
        vehicle.send(1_100_000, driven=False)   # a second later: said again
        assert vehicle.collect(1) == [1_100_000]
        assert "paused" in [e for e in events if "motors" in e][-1]
    finally:
        daemon.stop()
        thread.join(5.0)
        daemon.close()
        vehicle.link.close()


def test_degraded_real_time_is_said_when_it_starts_and_ends_not_every_gap():
    """Gaps (states skipped) for 0.2 s, then 1.1 s on time: one warning at the first gap,
    one line when it recovered (with the episode's counts), and the counts in the stats."""
    sc = load_scenario("nominal")
    vehicle = ScriptedVehicle(sc)
    events: list[str] = []
    daemon = Daemon(sc, vehicle=vehicle.link.local_address, realtime=True,
                    state_timeout_s=30.0, on_event=lambda _lvl, text, _t: events.append(text))
    thread = threading.Thread(target=daemon.run, kwargs={"duration_s": 1e9}, daemon=True)
    thread.start()
    try:
        vehicle.await_controller()
        t = 0
        vehicle.send(t)
        assert vehicle.collect(1) == [0]
        for _ in range(50):                     # 4 ms steps, two states a batch: 50 gaps
            t += 4000
            vehicle.send(t - 2000, t)
            assert vehicle.collect(1) == [t]
        for _ in range(1100):                   # on time again, 1 ms a state
            t += 1000
            vehicle.send(t)
            assert vehicle.collect(1) == [t]
        st = daemon.stats
        assert (st.gap_ticks, st.skipped_states, st.degraded_episodes) == (50, 50, 1)
        said = [e for e in events if "degraded" in e or "recovered" in e]
        assert len(said) == 2, said
        assert said[0].startswith("degraded real time at t=0.004 s")
        assert "real time recovered" in said[1] and "50 gaps integrated, 50 states skipped" \
            in said[1], said
    finally:
        daemon.stop()
        thread.join(5.0)
        daemon.close()
        vehicle.link.close()
