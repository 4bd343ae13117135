"""The supervisor of the seam (controller/supervisor.py): a pure step, driven tick by tick."""

from __future__ import annotations

import math

import pytest

from tfl_mav.controller.supervisor import (
    Law,
    Start,
    SupervisorInputs,
    Why,
    initial_state,
    supervise,
    supervisor_params,
)

DT = 0.001
W = 1.1 * 9.81          # the paper vehicle's weight (N)
FMAX = 8.0
def inputs(*, rotor=2, a=1.0, sigma=0.0, flew=True, answer=True, opposite=2.0,
           sides=(3.0, 3.0), safe_distance=0.001, tilt_rad=0.05, pq_radps=0.1,
           speed_mps=0.5, path_distance_m=math.nan):
    # physical order for rotor 2 attacked: opposite = rotor 4, sides = rotors 1 and 3
    demand = (sides[0], a, sides[1], opposite)
    # a state of that tilt (about the body x axis), roll rate and speed
    quat = (math.cos(tilt_rad / 2.0), math.sin(tilt_rad / 2.0), 0.0, 0.0) \
        if math.isfinite(tilt_rad) else (math.nan,) * 4
    return SupervisorInputs(DT, rotor, a, sigma, flew, answer, demand, safe_distance, quat,
                            (pq_radps, 0.0, 30.0), (speed_mps, 0.0, 0.0), path_distance_m)


def fly(p, s, u, seconds):
    decisions = []
    for _ in range(round(seconds / DT)):
        s, d = supervise(p, s, u)
        decisions.append(d)
    return s, decisions


@pytest.fixture
def p():
    return supervisor_params("auto", W, FMAX, 0.5)


def test_a_short_floor_pin_keeps_tfl(p):
    s = initial_state()
    s, _ = fly(p, s, inputs(a=0.0, opposite=0.0), 0.05)     # 50 ms pinned: a transient
    s, _ = fly(p, s, inputs(a=0.0, opposite=1.0), 0.5)
    assert s.law == Law.TFL and s.switches == 0


def test_a_lasting_floor_pin_with_no_attack_thrust_takes_over(p):
    s, ds = fly(p, initial_state(), inputs(a=0.0, opposite=0.0), 0.3)
    assert s.law == Law.LOST_ROTOR
    first = next(d for d in ds if d[1] != Why.STAY)
    assert first == (Law.LOST_ROTOR, Why.FLOOR, Start.SAFE_PATH)
    # taken over after the share of the 0.2 s window passed one half: ln 2 × 0.2 s
    assert ds.index(first) * DT == pytest.approx(0.2 * math.log(2.0), abs=0.002)


def test_a_floor_pin_with_two_sided_authority_is_not_a_take_over(p):
    # A heavier airframe's saturated climb: f₄ asked below 0 with A = 0.5 N (τ_p of both
    # signs in reach); TFL keeps flying through half a second of it
    s, _ = fly(p, initial_state(), inputs(a=0.5, opposite=0.0), 0.5)
    assert s.law == Law.TFL
    # … but not forever: a pin that lasts is taken over whatever A
    s, _ = fly(p, s, inputs(a=0.5, opposite=0.0), 1.5)
    assert s.law == Law.LOST_ROTOR


def test_the_estimate_uncertainty_counts(p):
    # 0.3 N is below the take-over bound, but 0.3 + 2 × 0.05 is not: two-sided as far as
    # the estimate knows? no — the upper bound decides: small only if A + 2σ < 0.35 N
    s, _ = fly(p, initial_state(), inputs(a=0.3, sigma=0.05, opposite=0.0), 0.3)
    assert s.law == Law.TFL
    s, _ = fly(p, initial_state(), inputs(a=0.3, sigma=0.0, opposite=0.0), 0.3)
    assert s.law == Law.LOST_ROTOR


def test_hand_back_needs_margin_calm_and_time(p):
    s, _ = fly(p, initial_state(), inputs(a=0.0, opposite=0.0), 0.3)
    assert s.law == Law.LOST_ROTOR
    s, _ = fly(p, s, inputs(a=0.5, flew=False), 2.0)           # below the hand-back bound
    assert s.law == Law.LOST_ROTOR
    s, _ = fly(p, s, inputs(a=1.0, flew=False, tilt_rad=0.5), 2.0)   # tilted 29°
    assert s.law == Law.LOST_ROTOR
    s, ds = fly(p, s, inputs(a=1.0, flew=False), 0.6)
    assert s.law == Law.TFL
    back = [d for d in ds if d[1] == Why.HANDBACK]
    assert back == [(Law.TFL, Why.HANDBACK, Start.TFL_RESUME)]
    assert ds.index(back[0]) * DT == pytest.approx(0.5, abs=0.002)


def test_an_intermittent_attack_costs_one_round_trip_per_change(p):
    s = initial_state()
    for _ in range(5):      # 2 s at 0 N (pinned), 2 s at 4 N
        s, _ = fly(p, s, inputs(a=0.0, opposite=0.0), 2.0)
        s, _ = fly(p, s, inputs(a=4.0, opposite=3.0, flew=s.law == Law.TFL), 2.0)
    assert s.switches == 10


def test_no_answer_levels_and_holds(p):
    s, (law, why, start) = supervise(p, initial_state(), inputs(answer=False))
    assert (law, why, start) == (Law.LOST_ROTOR, Why.NO_ANSWER, Start.SAFE_HOLD)
    assert s.holding
    s, d = fly(p, s, inputs(flew=False), 1.1)
    follow = [x for x in d if x[1] == Why.FOLLOW]
    assert follow and follow[0][2] == Start.SAFE_PATH and not s.holding


def test_a_first_state_tfl_does_not_start_from_is_taken_over(p):
    _, d = supervise(p, initial_state(), inputs(flew=False, tilt_rad=math.radians(45)))
    assert d == (Law.RECOVERY, Why.START_NOT_BENIGN, Start.SAFE_HOLD)
    _, d = supervise(p, initial_state(), inputs(flew=False, path_distance_m=5.0))
    assert d[1] == Why.START_BEYOND_ROA
    _, d = supervise(p, initial_state(), inputs(flew=False, speed_mps=math.nan))
    assert d[1] == Why.START_NOT_BENIGN
    _, d = supervise(p, initial_state(), inputs(flew=False, tilt_rad=math.nan))
    assert d[1] == Why.START_NOT_BENIGN


def test_two_a_above_the_weight_is_hopeless(p):
    _, d = supervise(p, initial_state(), inputs(a=6.0, opposite=6.0))
    assert d == (Law.LOST_ROTOR, Why.HOPELESS, Start.SAFE_PATH)


def test_single_law_modes():
    only_tfl = supervisor_params("tfl", W, FMAX, 0.5)
    s, _ = fly(only_tfl, initial_state("tfl"), inputs(a=0.0, opposite=0.0, answer=False), 2.0)
    assert s.law == Law.TFL and s.switches == 0
    only_safe = supervisor_params("safe", W, FMAX, 0.5)
    s, _ = fly(only_safe, initial_state("safe"), inputs(a=2.0, flew=False), 2.0)
    assert s.law == Law.LOST_ROTOR and s.lost_rotor_s == pytest.approx(2.0)
    s, _ = fly(only_safe, s, inputs(rotor=0, a=math.nan, flew=False), 1.0)
    assert s.law == Law.RECOVERY and s.tfl_s == 0.0


def test_time_in_each_law_adds_up(p):
    s, _ = fly(p, initial_state(), inputs(a=0.0, opposite=0.0), 1.0)
    s, _ = fly(p, s, inputs(a=2.0, flew=False), 1.0)
    s, _ = fly(p, s, inputs(a=2.0), 1.0)
    assert s.tfl_s + s.recovery_s + s.lost_rotor_s == pytest.approx(3.0)
    assert s.switches == 2


def test_bad_params_are_refused():
    with pytest.raises(ValueError, match="auto, tfl, safe"):
        supervisor_params("both", W, FMAX, 0.5)
    with pytest.raises(ValueError):
        supervisor_params("auto", W, FMAX, 0.5, a_takeover_n=1.0, a_handback_n=0.5)


def test_the_scenario_key_is_checked():
    from tfl_mav.scenario import ScenarioError, scenario_from_dict

    with pytest.raises(ScenarioError, match=r"controller\.supervisor: must be 'auto', 'tfl' or "
                                            r"'safe', got 'both'"):
        scenario_from_dict({"controller": {"supervisor": "both"}})
    assert scenario_from_dict({"controller": {"supervisor": "safe"}}).controller.supervisor \
        == "safe"


def test_the_spin_ends_only_where_the_safe_law_can_hand_on_to_tfl(p):
    """Pinned high: the spin law takes over after spin_hold_s. It gives the vehicle back only
    once A + 2σ is below m g/2 by a_handback_n, where the safe law can hand on to TFL (a
    two-sided τ_p); between there and m g/2 the safe law could only climb or barely hold
    (2A ≈ m g) while the relaxed hover still exists, so the spin goes on."""
    half = W / 2.0
    pinned = inputs(a=7.0, flew=False)._replace(spin_ready=True)
    s, d = fly(p, initial_state(), inputs(a=6.0, opposite=6.0), DT)     # hopeless: safe law
    assert s.law == Law.LOST_ROTOR
    s, d = fly(p, s, pinned, p.spin_hold_s + 0.01)
    assert s.law == Law.SPIN and (Law.SPIN, Why.PINNED_HIGH, Start.SPIN) in d
    # just below m g/2 (by more than spin_margin_n, less than a_handback_n): still spinning
    between = half - 0.5 * (p.spin_margin_n + p.a_handback_n)
    s, d = fly(p, s, pinned._replace(attack_n=between), 1.0)
    assert s.law == Law.SPIN and all(x[1] == Why.STAY for x in d)
    # below m g/2 − a_handback_n for spin_hold_s: the safe law again
    s, d = fly(p, s, pinned._replace(attack_n=half - p.a_handback_n - 0.05),
               p.spin_hold_s + 0.01)
    assert s.law == Law.LOST_ROTOR and (Law.LOST_ROTOR, Why.RELENTED, Start.SAFE_PATH) in d
