"""The law's translational disturbance observer (:func:`estimators.tdob_update`): it finds a
constant horizontal push, leaves the vertical to the mass estimator, and gives the paper's
ξ-chain the integral action a wind asks for; the scenario key turns it on outdoors only.

The physics bound the flight tests hold it to: with four ξ poles at −p the paper's chain
settles at ξ = (k₂/k₀)·d = 6 d/p² for an unmodelled acceleration d. A steady 3 m/s wind on the
paper's drag (k_t = 0.05 N s/m, m = 1.1 kg) is d = 0.136 m/s², 131 mm at p = 2.5.
"""

from __future__ import annotations

import math

import pytest

from tfl_mav.control.tfl.estimators import TDOB_START, tdob_update
from tfl_mav.flightlog.flight import summarize
from tfl_mav.from_scenario import law_config, translational_observer
from tfl_mav.offline import fly_offline
from tfl_mav.scenario import ScenarioError, load_scenario

_G = 9.81
_M = 1.1
_KT = 0.05


def _feed(d_true, *, ticks, dt=1e-3, tau=0.25, v0=(0.3, -0.2, 0.1), tilt=0.05, vertical=0.0):
    """Run the observer on a vehicle whose acceleration is the model's plus ``d_true``
    (thrust at hover along a fixed tilted axis, drag on its own velocity): exact Euler."""
    b3 = (math.sin(tilt), 0.0, math.cos(tilt))
    thrust = _M * _G / math.cos(tilt)
    v = list(v0)
    s = TDOB_START
    for _ in range(ticks):
        s = tdob_update(tau, 8.0, s, dt, tuple(v), thrust, b3, _M, _KT, _G, vertical)
        a = [thrust / _M * b3[i] - _KT / _M * v[i] + d_true[i] for i in range(3)]
        a[2] -= _G
        v = [v[i] + dt * a[i] for i in range(3)]
    return s


def test_a_constant_push_is_found_and_the_vertical_only_when_asked():
    d = (0.136, -0.05, 0.3)
    s = _feed(d, ticks=2500)            # ten time constants
    # first-order filter of a step after 10 τ: e⁻¹⁰ of the step is left
    assert s.d_x == pytest.approx(d[0], abs=1e-4)
    assert s.d_y == pytest.approx(d[1], abs=1e-4)
    assert s.d_z == 0.0                 # vertically the mass estimator is the integral action
    assert _feed(d, ticks=2500, vertical=1.0).d_z == pytest.approx(d[2], abs=1e-4)


def test_it_follows_a_first_order_lag_of_tau():
    s = _feed((0.2, 0.0, 0.0), ticks=250)       # one τ
    assert s.d_x == pytest.approx(0.2 * (1.0 - math.exp(-1.0)), rel=0.02)


def test_no_push_reads_as_none_and_the_bound_holds():
    # the observer takes the model at the period's middle, this Euler step at its start:
    # they differ by (k_t/m)·a·Δt/2, a the tilted thrust's horizontal acceleration
    a_x = _G * math.tan(0.05)
    assert abs(_feed((0.0, 0.0, 0.0), ticks=1000).d_x) < 1.5 * _KT / _M * a_x * 1e-3 / 2
    assert _feed((50.0, -50.0, 50.0), ticks=3000, vertical=1.0)[:3] == (8.0, -8.0, 8.0)


def test_auto_is_on_outdoors_only_and_the_key_is_checked():
    paper = load_scenario("paper")
    assert not translational_observer(paper)
    assert not law_config(paper).translational_observer
    for keys in ({"wind.mean_mps": [0.0, 2.0, 0.0]}, {"wind.turbulence": "light"},
                 {"vehicle.rotor_aero": True}, {"sensors.model": "realistic"}):
        assert translational_observer(paper.replace(**keys)), keys
    assert translational_observer(paper.replace(**{"controller.translational_observer": "on"}))
    windy = paper.replace(**{"wind.mean_mps": [3.0, 0.0, 0.0]})
    assert not translational_observer(windy.replace(**{"controller.translational_observer":
                                                       "off"}))
    assert translational_observer(load_scenario("realistic"))
    # the vertical too where the rotors' inflow drag flies, not for wind alone
    assert law_config(load_scenario("realistic")).translational_observer_vertical
    assert not law_config(windy).translational_observer_vertical
    with pytest.raises(ScenarioError, match="translational_observer"):
        paper.replace(**{"controller.translational_observer": "yes"})


def _last10_mm(sc) -> float:
    log = fly_offline(sc)
    assert not log.crashed
    return 1000.0 * summarize(log)["max_path_distance_last_10s_m"]


@pytest.mark.slow
def test_the_paper_flight_in_a_steady_wind_is_held_on_the_path():
    """Without the observer the law sits at the chain's 6d/p² for its fine pole p = 8
    (12.8 mm; the gain switch engages within 20 cm, where the coarse pole left it 131 mm
    off); with it, on the path: the rest is the attack's own wobble."""
    windy = load_scenario("paper").replace(**{"wind.mean_mps": [3.0, 0.0, 0.0]})
    off = _last10_mm(windy.replace(**{"controller.translational_observer": "off"}))
    on = _last10_mm(windy)
    d = _KT * 3.0 / _M
    bound = 6.0 * d / 8.0 ** 2 * 1000.0
    assert 6.0 * d / 2.5 ** 2 < 0.2     # the coarse pole's offset is within the switch's
    assert 0.8 * bound < off < 1.2 * bound
    assert on < 0.1 * bound
