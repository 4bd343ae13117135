"""Issue #14: the attack class flown offline — a dead rotor, 250 Hz control, lag + ESC noise,
a take-over from a tilted state, feasibility warnings. Bounds are derived from the physics
here, not tuned: see each test."""

from __future__ import annotations

import math

import numpy as np
import pytest

from harness.offline import fly_offline
from tfl_mav.control.feasibility import check_scenario, path_demand
from tfl_mav.control.recovery import POS_OMEGA
from tfl_mav.modes import Mode
from tfl_mav.scenario import apply_overrides, load_scenario

WINDOW_S = 10.0


def _last_max(log, window_s: float = WINDOW_S) -> float:
    t = log["t_s"]
    return float(np.max(log["path_distance_m"][t >= t[-1] - window_s]))


def _safe_law_bound(sc) -> float:
    """The reduced-attitude law's steady error: its PD position loop (ω_n) against the
    model's mass error Δm g (the only unmodelled steady force), ×1.5 for the spinning
    attitude loop's own wobble. 2 % of g at ω_n = 1 rad/s: 0.196 m → 0.29 m."""
    dm = abs(sc.controller.model_mass_scale - 1.0)
    return 1.5 * dm * sc.vehicle.gravity_mps2 / POS_OMEGA ** 2


@pytest.mark.slow
@pytest.mark.parametrize("start_s", [0.0, 5.0])
def test_dead_rotor_flies_on_the_paper_path(start_s: float) -> None:
    sc = apply_overrides(load_scenario("paper"), ["attack.signal=off",
                                                  f"attack.start_s={start_s}"])
    log = fly_offline(sc, attack_info="detector")
    assert not log.crashed, log.crash_reason
    assert log["t_s"][-1] >= sc.run.duration_s - 0.01
    assert int(Mode.LOST_ROTOR) in set(log["mode"].astype(int))
    assert _last_max(log) <= _safe_law_bound(sc)
    # the spin is the relaxed hover's: r̄ = d (m g − 4A)/k_r with A = 0, within 20 %
    v = sc.vehicle
    spin = v.drag_thrust_ratio_m * v.mass_kg * v.gravity_mps2 / v.k_r
    r = np.abs(log["body_rates_radps"][-1000:, 2])
    assert np.all(np.abs(r - spin) < 0.2 * spin)


@pytest.mark.slow
def test_paper_flight_at_250_hz() -> None:
    """At 250 Hz the law holds its command for h = 4 ms; the sample-and-hold misplaces the
    vehicle by at most the distance flown in one period, speed × h = 2 mm."""
    sc = apply_overrides(load_scenario("paper"), ["run.control_hz=250.0"])
    log = fly_offline(sc, attack_info="detector")
    assert not log.crashed, log.crash_reason
    assert _last_max(log) <= sc.path.speed_mps * sc.run.control_dt_s


@pytest.mark.slow
@pytest.mark.parametrize("tau_s", [0.02, 0.05])
def test_lag_and_100_rpm_noise_fly(tau_s: float) -> None:
    """No attack, a lagging motor and 100 rpm ESC noise: the filtered lag inverse must not
    pass the noise on. Bound: the thrust noise left after the Kalman filter acts as a white
    force of std δf = 2 k_f ω σ_ω̂ per period h; through the double integrator over the
    law's settling time T = 4/|ξ pole| it moves the vehicle by ~δf/m · h^½ · T^{3/2}, far
    below the issue's 10 mm, which is the bound asserted."""
    sc = apply_overrides(load_scenario("paper"), [
        "attack.rotor=0", f"vehicle.motor_time_constant_s={tau_s}", "vehicle.rpm_noise_std=100"])
    log = fly_offline(sc, attack_info="detector")
    assert not log.crashed, log.crash_reason
    assert _last_max(log) <= 0.010


def test_takeover_from_a_tilted_state_levels_and_holds() -> None:
    """A controller started on a vehicle tilted 45° and falling at 2 m/s: recovery on the
    first tick, level within a second, the descent arrested (it may not fall more than
    v²/(2 a_max) with a_max = 0.5 g, plus the time to level at ≤ 1 s × 2 m/s)."""
    sc = apply_overrides(load_scenario("nominal"), [
        "initial.euler_rad=[0.785, 0.0, 0.0]", "initial.velocity_mps=[0.0, 0.0, -2.0]",
        "initial.position_m=[1.5, 0.3, 6.0]"])
    log = fly_offline(sc, attack_info="detector", duration_s=3.0)
    assert not log.crashed, log.crash_reason
    assert int(log["mode"][0]) == int(Mode.RECOVERY)
    z = log["position_m"][:, 2]
    g = sc.vehicle.gravity_mps2
    assert 6.0 - float(np.min(z)) <= 2.0 ** 2 / (2 * 0.5 * g) + 2.0 * 1.0
    rates = log["body_rates_radps"]
    assert float(np.max(np.abs(rates[-500:, :2]))) < 1.0


def test_feasibility_flags_the_impossible_and_passes_the_paper() -> None:
    paper = load_scenario("paper")
    # the paper's signal is clamped to 0 for a while: said (the safe law flies), not impossible
    assert not any("cannot" in w for w in check_scenario(paper))
    fast = apply_overrides(paper, ["path.speed_mps=2.0", "attack.rotor=0"])
    d = path_demand(fast)
    # top bend of z = 8 − 4 cos y1 at y1 = π: |σ'| = 1, κN = (0, 1, −4) → a_z = −4 s² = −16
    assert math.isclose(d.min_vertical_mps2, -16.0, rel_tol=1e-3)
    assert any("cannot be followed" in w for w in check_scenario(fast))
    strong = apply_overrides(paper, ["attack.signal=constant", "attack.value_n=5.0"])
    assert any("cannot follow the path" in w for w in check_scenario(strong))
