"""The safe law's outer loop: its pole, the limits of what the rotors can make, the integral
held as an acceleration, and TFL's settle timer counting the safe law's ticks.

The bounds are the physics the functions state: a demand the rotors cannot make is not
asked (m |a + g e₃| ≤ the most thrust along b₃), a descent is never asked faster than the
climb that arrests it, and the learnt acceleration does not move with the pole."""

from __future__ import annotations

import itertools
import math
import random

import pytest

from tfl_mav.control.safe.safe_step import (
    ATTACK_TAU_S,
    LAG_POLE_PRODUCT,
    MAX_TILT_RAD,
    MAX_VERTICAL_G,
    MIN_POS_OMEGA,
    POS_OMEGA,
    SIDE_SHARE_FAST,
    SIDE_SHARE_SLOW,
    SafeParams,
    SafeState,
    accel_demand,
    attack_omega,
    no_path,
    outer_loop_omega,
    pid_gains,
    safe_tick,
)
from tfl_mav.control.tfl.step import settle
from tfl_mav.from_scenario import build_controller
from tfl_mav.scenario import load_scenario

G = 9.81
ZERO = (0.0, 0.0, 0.0)


def _params(mass_kg: float = 1.0) -> SafeParams:
    return SafeParams((mass_kg, 0.0, G, 0.2, 8.0), 0.5, 0.001, POS_OMEGA, False, True,
                      (0.01, 0.01, 0.02, 0.0, 0.01))


def _demand(p: SafeParams, error_m, velocity_mps=ZERO, integral=ZERO, omega=POS_OMEGA,
            thrust_max_n=math.inf):
    a0, a1, a2, *_ = accel_demand(p, error_m, ZERO, ZERO, integral, ZERO, 0.0, ZERO,
                                  velocity_mps, G, 0.0, omega, thrust_max_n)
    return a0, a1, a2


def test_the_pole_falls_with_the_motor_lag_and_with_noise():
    assert outer_loop_omega(0.0, False) == POS_OMEGA
    assert outer_loop_omega(0.0, True) == MIN_POS_OMEGA
    for tau in (0.02, 0.035, 0.05, 0.06, 0.2):
        w = outer_loop_omega(tau, False)
        assert MIN_POS_OMEGA <= w <= POS_OMEGA
        assert w * tau <= LAG_POLE_PRODUCT + 1e-12 or w == MIN_POS_OMEGA
    assert outer_loop_omega(0.05, False) == pytest.approx(LAG_POLE_PRODUCT / 0.05)


def test_the_pole_falls_as_the_attack_leaves_the_side_rotors_less_of_the_weight():
    weight = G
    # the side rotors carry (m g − 2A)/(m g) of the weight
    a_fast = (1.0 - SIDE_SHARE_FAST) * weight / 2.0
    a_slow = (1.0 - SIDE_SHARE_SLOW) * weight / 2.0
    assert attack_omega(POS_OMEGA, 0.0, weight) == POS_OMEGA
    assert attack_omega(POS_OMEGA, a_fast, weight) == pytest.approx(POS_OMEGA)
    assert attack_omega(POS_OMEGA, a_slow, weight) == pytest.approx(MIN_POS_OMEGA)
    assert attack_omega(POS_OMEGA, 5.0, weight) == MIN_POS_OMEGA
    ws = [attack_omega(POS_OMEGA, 0.05 * k, weight) for k in range(120)]
    assert all(b <= a + 1e-12 for a, b in itertools.pairwise(ws))


@pytest.mark.parametrize("thrust_max_n", [11.0, 12.5, 16.0, 17.2, 26.0])
def test_the_demand_is_within_the_thrust_the_rotors_make(thrust_max_n):
    rng = random.Random(7)
    for mass in (1.0, 1.45):
        p = _params(mass)
        top = thrust_max_n / mass
        for _ in range(400):
            e = tuple(rng.uniform(-3.0, 3.0) for _ in range(3))
            v = tuple(rng.uniform(-2.0, 2.0) for _ in range(3))
            a0, a1, a2 = _demand(p, e, v, omega=rng.choice((MIN_POS_OMEGA, POS_OMEGA)),
                                 thrust_max_n=thrust_max_n)
            if top <= G:          # cannot hover: the fixed limits only
                assert abs(a2) <= MAX_VERTICAL_G * G + 1e-12
                continue
            # m |a + g e3| ≤ the most thrust, and a descent never faster than the climb
            assert math.sqrt(a0 * a0 + a1 * a1 + (G + a2) ** 2) <= top * (1.0 + 1e-12)
            assert -a2 <= min(top - G, MAX_VERTICAL_G * G) + 1e-12
            assert math.hypot(a0, a1) <= (G + a2) * math.tan(MAX_TILT_RAD) + 1e-9


def test_a_heavy_airframe_is_not_asked_to_dive_faster_than_it_can_climb():
    # 1.45 kg on two side rotors at 8 N and a 0.6 N attack: it climbs at ~1.8 m/s² at most
    p = _params(1.45)
    thrust = 2.0 * 8.0 + 2.0 * 0.6
    climb = thrust / 1.45 - G
    _a0, _a1, a2 = _demand(p, (0.0, 0.0, -0.5), (0.0, 0.0, 0.4), thrust_max_n=thrust)
    assert a2 == pytest.approx(-climb)
    _a0, _a1, a2_fixed = _demand(p, (0.0, 0.0, -0.5), (0.0, 0.0, 0.4))
    assert a2_fixed == pytest.approx(-MAX_VERTICAL_G * G)


def test_the_learnt_acceleration_does_not_move_with_the_pole():
    p = _params()
    learnt = (0.3, -0.2, 0.9)
    for w in (MIN_POS_OMEGA, 2.0, POS_OMEGA):
        assert _demand(p, ZERO, integral=learnt, omega=w) == pytest.approx(learnt)
    kp, kd, ki = pid_gains(2.0)
    assert (kp, kd, ki) == pytest.approx((12.0, 6.0, 8.0))


def test_the_settle_timer_switches_once_after_settle_time():
    ctrl = build_controller(load_scenario("paper"))
    p = ctrl.params
    fine, settled = False, 0.0
    for _ in range(round(p.settle_time_s / p.dt_s) - 1):
        fine, settled = settle(p, fine, settled, 0.5 * p.settle_alpha, p.dt_s)
    assert not fine
    fine, settled = settle(p, fine, settled, 0.5 * p.settle_alpha, p.dt_s + 1e-9)
    assert fine
    # once fine, always fine; off the path the timer starts again
    assert settle(p, True, 0.0, 10.0, p.dt_s) == (True, 0.0)
    assert settle(p, False, 0.7, 2.0 * p.settle_alpha, p.dt_s) == (False, 0.0)


def test_a_vehicle_the_safe_law_held_on_the_path_resumes_on_the_fine_poles():
    sc = load_scenario("paper")
    held, far = build_controller(sc), build_controller(sc)
    ticks = round(held.params.settle_time_s / held.params.dt_s) + 1
    for _ in range(ticks):
        held.settle_on(0.2 * held.params.settle_alpha)
        far.settle_on(math.nan)            # holding a point: no distance to the path
    assert held.fine and not far.fine


def test_without_a_known_authority_the_fixed_limits_hold():
    p = _params(1.45)
    assert _demand(p, (0.0, 0.0, -0.5), (0.0, 0.0, 0.4), thrust_max_n=0.0) == \
        pytest.approx(_demand(p, (0.0, 0.0, -0.5), (0.0, 0.0, 0.4)))


def test_the_pole_follows_the_attacks_level_not_its_steps():
    # 0-5 N switched every 1.25 s (an intermittent attack near m g/2): the pole reads the
    # attack low-passed over ATTACK_TAU_S, so it stays near the mean's, not jumping between
    # the fast and the slow pole at each step.
    p = _params()._replace(has_path=False)
    s = SafeState(0.0, True, (0.0, 0.0, 5.0), ZERO, ZERO, 0.0, 0.0)
    rot = (1, 0, 0, 0, 1, 0)
    lps = []
    for i in range(int(20.0 / p.dt_s)):
        a_n = 5.0 if (i * p.dt_s) % 2.5 < 1.25 else 0.0
        s, _out = safe_tick(p, s, ((0.0, 0.0, 5.0), ZERO, (1.0, 0.0, 0.0, 0.0), ZERO, a_n,
                                   rot, (0, 1, 2, 3), ((0.0,) * 4, (0.0,) * 4)), no_path)
        lps.append(s.attack_lp_n)
    assert lps[0] == 5.0                     # started at the first estimate
    late = lps[len(lps) * 3 // 5:]     # periodic by then (5 τ in)
    # a first-order filter's ripple on a square wave: ±(A/2) tanh(T_half/(2τ)) = ±0.76 N
    ripple = 2.5 * math.tanh(1.25 / (2.0 * ATTACK_TAU_S))
    assert min(late) > 2.5 - ripple - 0.05 and max(late) < 2.5 + ripple + 0.05
    poles = [attack_omega(POS_OMEGA, a, G) for a in late]
    # near the slow pole throughout (read unfiltered, the pole would jump between 1.25 and
    # 3 rad/s at every step)
    assert min(poles) >= MIN_POS_OMEGA and max(poles) < MIN_POS_OMEGA + 0.3
    assert ATTACK_TAU_S > 1.25               # longer than a step of this attack
