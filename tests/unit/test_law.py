"""The control law's pieces: allocation, relabelling for any rotor, saturation, no NaN out."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tfl_mav.control.allocation import allocate_attacked, allocate_nominal, canonical_frame
from tfl_mav.control.tfl.tfl_controller import chain_gains
from tfl_mav.from_scenario import build_controller
from tfl_mav.model.modes import Mode
from tfl_mav.model.state import State
from tfl_mav.scenario import load_scenario
from tfl_mav.sitl.physics import RigidBodyParams, mix

L, D, FMAX = 0.2656, 0.016, 8.0
PARAMS = RigidBodyParams(1.1, (0.0020066, 0.0020038, 0.0013323), L, D, 0.05, 2.75e-3, 9.81)


def test_chain_gains_are_the_paper_numbers():
    """ξ poles at −2.5 and η poles at −2 give the gains quoted in the controller issue."""
    assert chain_gains(-2.5, 4) == pytest.approx((39.0625, 62.5, 37.5, 10.0))
    assert chain_gains(-2.0, 3) == pytest.approx((8.0, 12.0, 6.0))


def test_nominal_allocation_inverts_the_mixer():
    f = allocate_nominal(10.0, 0.1, -0.2, 0.01, L, D)
    assert mix(PARAMS, f) == pytest.approx((10.0, 0.1, -0.2, 0.01))


@pytest.mark.parametrize("rotor", [1, 2, 3, 4])
def test_attacked_allocation_for_any_rotor(rotor):
    """Relabelled allocation → physical rotors → the physical mixer reproduces, in the
    canonical frame, u_f, τ_q, τ_r and τ_p = (u_f − τ_r/d')l/2 − 2lA (eq. (6))."""
    frame = canonical_frame(rotor)
    uf, tq, tr, a = 10.0, 0.05, 0.08, 1.3
    d_c = D * frame.d_sign
    canon = allocate_attacked(uf, tq, tr, a, L, d_c)
    f = [0.0] * 4
    for i, phys in enumerate(frame.perm):
        f[phys] = canon[i]
    assert f[rotor - 1] == a                       # the attacked rotor carries A
    u, tp, tq_p, tr_p = mix(PARAMS, f)
    rot = np.array(frame.rot, dtype=float)
    tau_c = rot @ np.array([tp, tq_p, tr_p])       # physical torques in canonical axes
    assert u == pytest.approx(uf)
    assert tau_c[1] == pytest.approx(tq)
    assert tau_c[2] == pytest.approx(tr)
    assert tau_c[0] == pytest.approx((uf - tr / d_c) * L / 2 - 2 * L * a)


@settings(max_examples=300, deadline=None)
@given(uf=st.floats(0, 40), tq=st.floats(-3, 3), tr=st.floats(-1, 1), a=st.floats(0, FMAX))
def test_saturated_attacked_allocation_is_feasible_and_gives_up_what_it_must(uf, tq, tr, a):
    f = allocate_attacked(uf, tq, tr, a, L, D, FMAX)
    assert all(0.0 <= x <= FMAX for x in f)
    assert f[1] == a
    # u_f is kept whenever the three healthy rotors can carry u_f − A, unless a side rotor
    # sits at its top: there the collective went so that τ_q fits.
    top = max(f[0], f[2]) >= FMAX - 1e-9
    if a <= uf <= a + 3 * FMAX and not top:
        assert sum(f) == pytest.approx(uf, abs=1e-9)
    # τ_q is kept unless the side rotors cannot make it at any collective (|τ_q|/l > f_max)
    # or one of them sits at its bottom (raising the collective there would climb).
    if abs(tq) / L <= FMAX and min(f[0], f[2]) > 1e-9:
        assert L * (f[2] - f[0]) == pytest.approx(tq, abs=1e-9)


def test_a_saturated_climb_gives_up_thrust_not_the_pitch_torque():
    """A heavier airframe climbing on two side rotors: u_f asked beyond what they make
    with the pitch torque. τ_q stays exact (one side rotor at f_max, the other below it by
    τ_q/l) and the roll torque's rotor keeps A; only the collective is short. (The old
    order kept u_f and left τ_q = 0: the vehicle pitched over within 0.3 s.)"""
    a, tq = 0.5, 0.2
    uf = 16.5                              # f1 + f3 = 15.5 N asked, 2 f_max − τ_q/l made
    tr = D * (uf - 2.0 * (a + a))          # f4 = (u_f − τ_r/d)/2 − A = A: τ_p = 0
    f = allocate_attacked(uf, tq, tr, a, L, D, FMAX)
    assert f[3] == pytest.approx(a, abs=1e-12)
    assert L * (f[2] - f[0]) == pytest.approx(tq, abs=1e-12)
    assert f[2] == pytest.approx(FMAX, abs=1e-12)
    assert sum(f) == pytest.approx(2 * a + 2 * FMAX - tq / L, abs=1e-12)


@settings(max_examples=300, deadline=None)
@given(uf=st.floats(0, 40), tp=st.floats(-3, 3), tq=st.floats(-3, 3), tr=st.floats(-1, 1))
def test_saturated_nominal_allocation_is_feasible(uf, tp, tq, tr):
    f = allocate_nominal(uf, tp, tq, tr, L, D, FMAX)
    assert all(0.0 <= x <= FMAX for x in f)


def _state(pos=(1.5, 0.3, 0.5), vel=(0, 0, 0), q=(1, 0, 0, 0), w=(0, 0, 0)):
    return State(pos, vel, q, w)


@pytest.mark.parametrize("bad", [math.nan, math.inf])
def test_controller_never_outputs_nan(bad):
    ctrl = build_controller(load_scenario("paper"))
    ctrl.set_attack(2, 1.0)
    out = ctrl.update(_state(vel=(bad, 0, 0)))
    assert all(math.isfinite(x) and 0 <= x <= FMAX for x in out.rotor_thrust_n)
    assert out.mode is Mode.FALLBACK and out.reason
    ok = ctrl.update(_state())
    assert all(math.isfinite(x) for x in ok.rotor_thrust_n)


def test_nan_attack_estimate_is_ignored():
    ctrl = build_controller(load_scenario("paper"))
    ctrl.set_attack(2, 1.5)
    ctrl.set_attack(2, math.nan)
    assert ctrl.attack_estimate_n == 1.5


def test_attacked_output_gives_the_attacked_rotor_its_estimate():
    ctrl = build_controller(load_scenario("paper"))
    ctrl.set_attack(3, 2.25)
    out = ctrl.update(_state())
    assert out.mode is Mode.ATTACKED
    assert out.rotor_thrust_n[2] == 2.25


def test_far_from_the_path_falls_back_safely():
    """At the centre of a circle the projection is not unique: fallback, finite output."""
    sc = load_scenario("circle")
    ctrl = build_controller(sc)
    out = ctrl.update(_state(pos=(0.0, 0.0, 5.0)))
    assert out.mode is Mode.FALLBACK
    assert "tube" in out.reason
    assert all(math.isfinite(x) and 0 <= x <= FMAX for x in out.rotor_thrust_n)


def test_the_lost_projection_says_why_in_words():
    """Each code a lost projection can return reads as its own sentence, the numbers in it
    as measured (mm-resolution distance, the margin to two places)."""
    from tfl_mav.control.path.projection import VO, lost_reason
    assert lost_reason(VO.NONFINITE, math.nan, 0.0, "") == "non-finite state"
    assert lost_reason(VO.MARGIN, 0.12345, 0.0449, "") == (
        "distance 0.123 m near the radius of curvature (projection margin 0.04)")
    assert lost_reason(VO.FAILED, math.nan, 0.0, "math domain error {x}") == (
        "path evaluation failed: math domain error {x}")
    assert lost_reason(VO.REFERENCE, 0.5, 0.0, "outside the tube") == "outside the tube"
    assert lost_reason(VO.NO_ROOT, math.nan, 0.0, "") == (
        "closest-point search did not converge")


def test_both_trackers_fall_back_in_the_same_words():
    """0.2 m from the centre of a 2 m circle the closest point is 1.8 m away, inside the
    radius of curvature: the compiled projection (a code, told by lost_reason) and the
    reference tracker (its own words, passed through) say the same sentence."""
    from tfl_mav.control.path.compiled import make_tracker
    sc = load_scenario("circle")
    said = []
    for compiled in (True, False):
        ctrl = build_controller(sc)
        if not compiled:
            ctrl.tracker, ctrl.path_eval = make_tracker(ctrl.tracker.path, False)
        assert (ctrl.core == "reference jets") is not compiled
        out = ctrl.update(_state(pos=(0.2, 0.0, 5.0)))
        assert out.mode is Mode.FALLBACK
        said.append(out.reason)
    assert said[0] == said[1] == ("left the projection tube: distance 1.800 m near the "
                                  "radius of curvature (projection margin 0.10)")
