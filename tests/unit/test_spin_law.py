"""The spin law's pure step (tfl_mav.control.spin.step) and its construction (law): at a
relaxed hover it asks for that hover's forces, the attacked rotor is reported as what it
measures, the canonical relabelling puts every rotor in rotor 2's place, no input makes a
non-finite or out-of-range command, and an airframe without an equilibrium is told so."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tfl_mav.control.spin import equilibrium as eqm
from tfl_mav.control.spin import law
from tfl_mav.control.spin.step import (
    SpinInputs,
    SpinOutputs,
    SpinState,
    gain_at,
    hover_at,
    spin_step,
)
from tfl_mav.model.geometry import euler_to_quaternion
from tfl_mav.scenario import load_scenario

PAPER = load_scenario("paper")


@pytest.fixture(scope="module")
def params2() -> law.SpinParams:
    return law.build(PAPER.vehicle, 2, PAPER.run.control_dt_s)


def _at_equilibrium(eq: eqm.Equilibrium, pos: tuple[float, float, float] = (0.0, 0.0, 5.0)
                    ) -> SpinInputs:
    n = eq.axis
    q = euler_to_quaternion(math.atan2(n[1], n[2]), -math.asin(n[0]), 0.0).tolist()
    return SpinInputs(pos, (0.0, 0.0, 0.0), tuple(q), eq.rates_radps, eq.f_stuck_n, pos,
                      (0.0, 0.0, 0.0), (0.0, 0.0, 0.0))


@pytest.mark.parametrize("f_stuck", [6.0, 7.0, 8.0])
def test_at_the_hover_it_asks_for_the_hover(params2: law.SpinParams, f_stuck: float) -> None:
    """On a table point, at the equilibrium's attitude and rates with no position error the
    law's command is the equilibrium's forces (the feed-forward alone: every error is 0)."""
    a = eqm.airframe_from_scenario(PAPER.vehicle, 2)
    eq = eqm.solve(a, f_stuck, symmetric=True)
    assert eq is not None
    state, out = spin_step(params2, law.initial_state(params2, eq.rates_radps, f_stuck),
                           _at_equilibrium(eq))
    assert isinstance(out, SpinOutputs) and isinstance(state, SpinState)
    assert out.thrusts_n[1] == f_stuck          # the attacked rotor: its measured thrust
    assert out.thrusts_n == pytest.approx(eq.thrusts_n, abs=1e-6)
    assert out.exists and not out.clipped and out.rho == 1.0
    assert out.spin_radps == pytest.approx(eq.spin_radps, rel=1e-9)
    assert out.cone_rad == pytest.approx(eq.cone_rad, rel=1e-9)
    assert out.drift_m == pytest.approx(eq.radius_m, rel=1e-9)
    assert out.axis_error_rad < 1e-6


def test_the_step_is_pure(params2: law.SpinParams) -> None:
    a = eqm.airframe_from_scenario(PAPER.vehicle, 2)
    eq = eqm.solve(a, 7.5, symmetric=True)
    inp = _at_equilibrium(eq)._replace(position_m=(0.3, -0.2, 5.1),
                                        velocity_mps=(0.1, 0.0, -0.2))
    s0 = law.initial_state(params2, eq.rates_radps, 7.5)
    assert spin_step(params2, s0, inp) == spin_step(params2, s0, inp)
    s1, _ = spin_step(params2, s0, inp)
    assert s0.integral_ms == (0.0, 0.0, 0.0) and s1.integral_ms != s0.integral_ms


@pytest.mark.parametrize("rotor", [1, 3, 4])
def test_every_rotor_maps_to_rotor_2(rotor: int) -> None:
    """The same hover seen from another attacked rotor: relabel the body by the canonical
    frame's quarter turns; the command is the rotor-2 hover's forces, permuted."""
    from tfl_mav.control.allocation import canonical_frame

    params = law.build(PAPER.vehicle, rotor, PAPER.run.control_dt_s, f_stuck_grid=[7.5, 8.0])
    a = eqm.airframe_from_scenario(PAPER.vehicle, rotor)
    eq = eqm.solve(a, 8.0, symmetric=True)
    fr = canonical_frame(rotor)
    rot = np.array(fr.rot, dtype=float)
    # the canonical axis and rates back in the physical body: v = rotᵀ v'
    n = rot.T @ np.array(eq.axis)
    w = rot.T @ np.array(eq.rates_radps)
    q = euler_to_quaternion(math.atan2(n[1], n[2]), -math.asin(n[0]), 0.0).tolist()
    pos = (0.0, 0.0, 5.0)
    inp = SpinInputs(pos, (0.0, 0.0, 0.0), tuple(q), tuple(w.tolist()), 8.0, pos,
                     (0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
    _, out = spin_step(params, law.initial_state(params, tuple(w.tolist()), 8.0), inp)
    expected = [0.0] * 4
    for i, phys in enumerate(fr.perm):
        expected[phys] = eq.thrusts_n[i]
    assert out.thrusts_n[rotor - 1] == 8.0
    assert out.thrusts_n == pytest.approx(expected, abs=1e-6)


def test_no_input_makes_a_bad_command(params2: law.SpinParams) -> None:
    """Random attitudes, rates up to 200 rad/s, positions 20 m off and stuck thrusts over
    [0, f_max]: every command is finite, within [0, f_max], the attacked one as measured."""
    rng = np.random.default_rng(7)
    fmax = PAPER.vehicle.thrust_max_n
    state = law.initial_state(params2)
    for _ in range(2000):
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        stuck = float(rng.uniform(0.0, fmax))
        inp = SpinInputs(tuple(rng.uniform(-20, 20, 3)), tuple(rng.uniform(-10, 10, 3)),
                         tuple(q), tuple(rng.uniform(-200, 200, 3)), stuck,
                         tuple(rng.uniform(-20, 20, 3)), tuple(rng.uniform(-1, 1, 3)),
                         tuple(rng.uniform(-1, 1, 3)))
        state, out = spin_step(params2, state, inp)
        assert all(math.isfinite(f) and 0.0 <= f <= fmax for f in out.thrusts_n), out
        assert out.thrusts_n[1] == stuck
        assert all(math.isfinite(c) for c in state.integral_ms)


def test_no_equilibrium_is_said_with_the_numbers() -> None:
    """An airframe too heavy to hover spinning with a rotor at 8 N (m = 3.4 kg: even the
    greatest vertical force of a spin is short of m g): the law is built, says none exists,
    and flies the spin of the greatest vertical force, with the sink rate left over."""
    heavy = PAPER.replace(**{"vehicle.mass_kg": 3.4}).vehicle
    a = eqm.airframe_from_scenario(heavy, 2)
    _, hi = eqm.vertical_range(a, 8.0)
    assert hi < a.mass_kg * a.gravity_mps2
    params = law.build(heavy, 2, 0.001, f_stuck_grid=[8.0])
    hover = params.table[0].hover
    assert not hover.exists and hover.vertical_excess_mps2 < 0.0
    inp = SpinInputs((0.0, 0.0, 5.0), (0.0, 0.0, 0.0), (1.0, 0.0, 0.0, 0.0), (0.0, 0.0, 0.0),
                     8.0, (0.0, 0.0, 5.0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
    _, out = spin_step(params, law.initial_state(params), inp)
    assert not out.exists
    assert out.vertical_excess_mps2 == pytest.approx(hover.vertical_excess_mps2)
    # the least-bad spin sinks no faster than the greatest vertical force allows
    assert out.vertical_excess_mps2 >= (hi - a.mass_kg * a.gravity_mps2) / a.mass_kg - 0.5


def _mean(u: tuple[float, ...], v: tuple[float, ...]) -> list[float]:
    return [0.5 * (x + y) for x, y in zip(u, v, strict=True)]


def test_between_rows_the_table_is_blended() -> None:
    """A 3 kg airframe holds m g in a relaxed hover with a rotor at 7 N but not at 6 or 6.5 N.
    Between two rows the hover and the gains are linear in f_stuck (half way: the mean of
    the two rows); a relaxed hover is said to exist wherever the blend leans on a row that
    has one; on a row and beyond the ends the row itself."""
    heavy = PAPER.replace(**{"vehicle.mass_kg": 3.0}).vehicle
    params = law.build(heavy, 2, PAPER.run.control_dt_s, f_stuck_grid=[6.0, 6.5, 7.0])
    table = params.table
    r6, r65, r7 = (row.hover for row in table)
    assert (r6.exists, r65.exists, r7.exists) == (False, False, True)
    assert hover_at(table, 5.0) == r6 and hover_at(table, 9.0) == r7
    assert hover_at(table, 6.5) == r65 and hover_at(table, 7.0) == r7
    assert not hover_at(table, 6.25).exists
    mid = hover_at(table, 6.75)
    assert mid.exists
    assert mid.spin_radps == pytest.approx(0.5 * (r65.spin_radps + r7.spin_radps), rel=1e-12)
    assert mid.axis == pytest.approx(_mean(r65.axis, r7.axis), rel=1e-12)
    for rho in (0.0, 0.33, 1.0, 2.5):
        k_mid, k_lo, k_hi = (gain_at(table, f, rho) for f in (6.75, 6.5, 7.0))
        for row_mid, row_lo, row_hi in zip(k_mid, k_lo, k_hi, strict=True):
            assert row_mid == pytest.approx(_mean(row_lo, row_hi), rel=1e-12, abs=1e-12)
    # on a schedule point the gain is the one designed there
    assert gain_at(table, 7.0, 1.0) == table[2].gains[10]


@pytest.mark.parametrize("phase_rad", [0.0, 1.0, 2.5])
def test_the_cone_circle_is_not_fed_back(params2: law.SpinParams, phase_rad: float) -> None:
    """At the hover the centre of mass runs the cone's circle (velocity 0.3-0.4 m/s turning
    at Ω). The outer loop steers the *mean*: given the circle's velocity and offset at any
    phase of the spin, the command stays the hover's (to the drag's k_t/(m Ω) ≈ 1e-3 share
    the law neglects); fed back, the circle would be a constant axis bias in the body."""
    a = eqm.airframe_from_scenario(PAPER.vehicle, 2)
    eq = eqm.solve(a, 6.0, symmetric=True)
    base = _at_equilibrium(eq)
    # the same attitude turned by the spin's phase about the vertical
    n = eq.axis
    q = euler_to_quaternion(math.atan2(n[1], n[2]), -math.asin(n[0]), phase_rad).tolist()
    from tfl_mav.model.geometry import rotation_from_quaternion

    R = rotation_from_quaternion(q)
    acc = eq.total_n / a.mass_kg * complex(R[0, 2], R[1, 2])
    v = acc / complex(a.k_t / a.mass_kg, eq.spin_radps)      # the circle's velocity
    x = v / complex(0.0, eq.spin_radps)                       # and offset from the mean
    mean = (0.0, 0.0, 5.0)
    inp = base._replace(quaternion_wxyz=tuple(q), velocity_mps=(v.real, v.imag, 0.0),
                        position_m=(mean[0] + x.real, mean[1] + x.imag, mean[2]),
                        target_m=mean)
    state = law.initial_state(params2, eq.rates_radps, 6.0)._replace(total_n=eq.total_n)
    _, out = spin_step(params2, state, inp)
    assert out.thrusts_n == pytest.approx(eq.thrusts_n, abs=0.02)
    # and without the correction (no spin known yet) the same input would not be the hover
    _, raw = spin_step(params2, state._replace(total_n=0.0), inp)
    assert max(abs(f - g) for f, g in zip(raw.thrusts_n, eq.thrusts_n, strict=True)) > 0.1
