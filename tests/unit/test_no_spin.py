"""An airframe with no relaxed hover for the attack: said before and during the flight, with
the numbers, and flown without the law raising (the vehicle keeps its attitude)."""

from __future__ import annotations

import numpy as np
import pytest

from tfl_mav.controller.feasibility import check_scenario
from tfl_mav.harness.offline import fly_offline
from tfl_mav.scenario import apply_overrides, load_scenario

# The paper airframe with a yaw drag-to-thrust ratio of 2 mm instead of 16 mm: the rotors'
# reaction cannot spin the body fast enough (|ω_z| ≤ d (f2 + f4)/k_r ≈ 12 rad/s) for the
# gyroscopic torque to carry the pinned rotor's roll torque; equilibrium.solve finds no
# relaxed hover of any vertical force from 6 to 8 N (docs/relaxed-hover.md).
NO_SPIN = ["attack.signal=constant", "attack.value_n=8.0", "vehicle.drag_thrust_ratio_m=0.002"]


def test_preflight_says_no_relaxed_hover_with_the_numbers() -> None:
    sc = apply_overrides(load_scenario("paper"), NO_SPIN)
    text = [w for w in check_scenario(sc) if "no relaxed hover" in w]
    assert len(text) == 1
    assert "8.00 N" in text[0] and "0.002" in text[0] and "16.0 N" in text[0]


def test_the_paper_airframe_has_its_relaxed_hover() -> None:
    sc = apply_overrides(load_scenario("paper"), NO_SPIN[:2])
    assert not [w for w in check_scenario(sc) if "no relaxed hover" in w]


@pytest.mark.parametrize("lag_s", [0.0])
def test_flight_says_it_and_never_raises(lag_s: float) -> None:
    sc = apply_overrides(load_scenario("paper"), [*NO_SPIN, "run.duration_s=1.5",
                                                   f"vehicle.motor_time_constant_s={lag_s}"])
    log = fly_offline(sc, attack_info="detector")
    texts = [e for _, e in log.events]
    said = [e for e in texts if e.startswith("spin: no relaxed hover")]
    assert len(said) == 1 and "8 N" in said[0], texts
    assert not [e for e in texts if "internal error" in e], texts
    assert not log.crashed, log.crash_reason
    cmd = log["thrust_cmd_n"]
    assert np.all(np.isfinite(cmd)) and cmd.min() >= 0.0 and cmd.max() <= 8.0
