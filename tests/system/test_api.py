"""The public API (tfl_mav.api): the real simulator, the real flight computer and detector,
and small controllers and attacks written the way a user would write them."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from tfl_mav.api import (
    Attack,
    Controller,
    Detector,
    Environment,
    FlightSoftware,
    FlightSoftwareError,
    Mode,
    load_flight_software,
    load_object,
    load_scenario,
    tick_result,
)
from tfl_mav.control.detect.detector import AttackDetector
from tfl_mav.controller.flight_computer import FlightComputer
from tfl_mav.offline import fly_offline

EXAMPLE = Path(__file__).resolve().parents[2] / "docs" / "examples" / "own_controller.py"
PathPD = load_object(f"{EXAMPLE}:PathPD")      # the example as a user's file


class PaperSignal:
    """The paper's attack A = 0.1 t + sin z written as a user's Attack."""

    rotor = 2
    start_s = 0.0

    def thrust_n(self, t_s, state):
        return 0.1 * t_s + math.sin(state.position_m[2])


class Hover:
    """The weight shared by four rotors, nothing else (a Controller, no attack)."""

    def reset(self, scenario):
        v = scenario.vehicle
        self.f = v.mass_kg * v.gravity_mps2 / 4.0

    def update(self, t_s, state, rpm):
        return [self.f] * 4


class Faulty(Hover):
    """Hovers, then at 0.05 s returns ``bad`` (or raises it, when it is an exception)."""

    def __init__(self, bad):
        self.bad = bad

    def update(self, t_s, state, rpm):
        if t_s < 0.05:
            return super().update(t_s, state, rpm)
        if isinstance(self.bad, Exception):
            raise self.bad
        return self.bad


def test_the_default_environment_is_the_detector_flight_of_fly_offline():
    sc = load_scenario("paper")
    log = fly_offline(sc, attack_info="detector", duration_s=1.0)
    arrays = Environment(sc).fly(1.0)
    assert np.array_equal(arrays.position_m, log["position_m"])
    assert np.array_equal(arrays.thrust_cmd_n, log["thrust_cmd_n"])
    assert arrays.detected_rotor[-1] == 2 and arrays.detection_time_s < 0.1
    # the true distance, computed after the flight, is what the TFL tracker measured
    assert np.allclose(arrays.path_distance_m, arrays.software_distance_m, atol=1e-9)
    assert arrays.quaternion_wxyz.shape == (1000, 4)
    assert np.allclose(np.linalg.norm(arrays.quaternion_wxyz, axis=1), 1.0)


def test_the_flight_computer_is_flight_software_and_flies_identically_injected():
    """FlightComputer satisfies the protocol; injected through the guard (a factory), the
    flight is bit-identical to the built-in one."""
    sc = load_scenario("paper")
    assert isinstance(FlightComputer(sc), FlightSoftware)
    assert isinstance(AttackDetector(8e-6, 8.0, 0.0, 0.001), Detector)
    built_in = Environment(sc).fly(1.0)
    injected = Environment(sc, FlightComputer).fly(1.0)
    assert np.array_equal(built_in.position_m, injected.position_m)
    assert injected.failure_reason is None


def test_a_user_attack_equal_to_the_paper_signal_flies_the_paper_flight_bit_for_bit():
    sc = load_scenario("paper")
    assert isinstance(PaperSignal(), Attack)
    scenario_signal = Environment(sc).fly(1.5)
    user_signal = Environment(sc, attack=PaperSignal()).fly(1.5)
    assert np.array_equal(scenario_signal.attack_true_n, user_signal.attack_true_n)
    assert np.array_equal(scenario_signal.position_m, user_signal.position_m)


def test_the_attack_rotor_and_start_come_from_the_attack():
    class Off:
        rotor, start_s = 3, 0.5

        def thrust_n(self, t_s, state):
            return 0.0

    a = Environment("paper", attack=Off()).fly(1.0)
    assert a.attack_rotor == 3 and a.attack_start_s == 0.5
    assert np.all(a.attack_true_n[a.t_s < 0.5] == 0.0)
    assert a.detected_rotor[-1] == 3          # found from rpm, nobody told the law


def test_a_controller_flies_through_the_protocol_and_reaches_the_path():
    """The example PD (2 rad/s position loop) from 3.85 m off the path, no attack: within
    10 cm after 15 s. Its steady error is the model's 2 % mass error over k_p = 4 s⁻²:
    0.02 g / 4 ≈ 5 cm at most (the distance is the error's normal part)."""
    assert isinstance(PathPD(), Controller)
    a = Environment("paper", PathPD(), settings=["attack.rotor=0"]).fly(20.0)
    assert not a.crashed and a.failure_reason is None
    assert a.path_distance_m[0] > 3.8
    assert np.max(a.path_distance_m[a.t_s >= 15.0]) < 0.1
    assert set(np.unique(a.mode)) == {int(Mode.NOMINAL)}


def test_same_scenario_and_seed_fly_the_same_trajectory_with_noise():
    settings = ["attack.rotor=0", "sensors.velocity_noise_std_mps=0.01", "run.seed=7"]
    env = Environment("paper", PathPD(), settings=settings)
    a, b = env.fly(1.0), env.fly(1.0)
    assert np.array_equal(a.position_m, b.position_m)
    c = Environment("paper", PathPD(), settings=[*settings[:2], "run.seed=8"]).fly(1.0)
    assert not np.array_equal(a.position_m, c.position_m)


@pytest.mark.parametrize(("bad", "words"), [
    (ZeroDivisionError("float division by zero"), "raised ZeroDivisionError: float division"),
    ([1.0, math.nan, 1.0, 1.0], "non-finite thrust for rotor 2"),
    ([1.0, 2.0, 3.0], "returned 3 thrusts, expected 4"),
    (None, "returned NoneType None, expected 4 rotor thrusts"),
])
def test_a_failing_controller_fails_its_flight_in_one_line_and_never_reaches_a_motor(bad, words):
    a = Environment("paper", Faulty(bad), name="my-controller",
                    settings=["attack.rotor=0"]).fly(1.0)
    assert a.failed and not a.crashed
    assert a.failure_reason.startswith("my-controller failed at t = 0.050 s: ")
    assert words in a.failure_reason and "\n" not in a.failure_reason
    assert a.t_s[-1] < 0.05                        # the flight ended at that tick
    assert np.all(np.isfinite(a.thrust_cmd_n)) and np.all(np.isfinite(a.thrust_true_n))


def test_a_failing_attack_fails_the_flight_and_says_which():
    class Broken:
        rotor = 1

        def thrust_n(self, t_s, state):
            return 1.0 if t_s < 0.2 else math.inf

    a = Environment("paper", attack=Broken()).fly(1.0)
    assert a.failed and "Broken failed at t = 0.200 s: returned a non-finite thrust (inf)" \
        in a.failure_reason
    assert a.t_s[-1] <= 0.201 and np.all(np.isfinite(a.attack_true_n))


def test_flight_software_may_return_a_tick_result_or_bare_thrusts():
    class Bare:
        detected_rotor, detection_time_s = 0, math.nan

        def __init__(self, scenario):
            self.f = scenario.vehicle.mass_kg * scenario.vehicle.gravity_mps2 / 4.0

        def step(self, t_s, state, rpm, applied_n):
            return (self.f, self.f, self.f, self.f) if t_s < 0.5 else tick_result([self.f] * 4)

    a = Environment("paper", Bare, settings=["attack.rotor=0"]).fly(1.0)
    assert not a.failed and len(a.t_s) == 1000
    assert np.allclose(a.position_m[-1], a.position_m[0], atol=0.05)   # ~hovering


def test_loading_software_by_name_says_what_is_wrong_in_one_line():
    _name, factory = load_flight_software("tfl")
    assert isinstance(factory(load_scenario("paper")), FlightComputer)
    for spec, words in [("nope", "unknown controller 'nope'"),
                        ("no_such_module_x:Foo", "cannot import 'no_such_module_x'"),
                        ("tfl_mav.api:NoSuch", "'tfl_mav.api' has no 'NoSuch'"),
                        ("tfl_mav.api:__all__", "is not a class or function")]:
        with pytest.raises(FlightSoftwareError, match=words) as info:
            load_flight_software(spec)
        assert "\n" not in str(info.value)


@pytest.mark.slow
def test_flight_arrays_report_the_laws_and_every_detection_as_data():
    from tfl_mav.api import Environment

    arrays = Environment("paper").fly(duration_s=3.0)
    times = arrays.time_in_law_s
    assert set(times) >= {"tfl", "recovery", "lost_rotor", "spin"}
    assert sum(times.values()) == pytest.approx(3.0, abs=2e-3)
    # the paper's zero-attack stretch begins near 1.9 s: one take-over in 3 s
    assert arrays.law_switches == 1 and times["lost_rotor"] > 0.5
    assert arrays.detections and arrays.detections[0][1] == 2
    assert arrays.detection_time_s == arrays.detections[0][0]
    assert arrays.releases == ()
