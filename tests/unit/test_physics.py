"""Physics of the simulated vehicle against closed-form results and the paper's Euler model."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from tfl_mav.model.geometry import euler_to_quaternion
from tfl_mav.model.geometry import rotation_from_quaternion as rotation_matrix
from tfl_mav.scenario import AttackConfig, load_scenario
from tfl_mav.sitl.attacker import Attacker
from tfl_mav.sitl.motors import RADPS_TO_RPM, MotorBank
from tfl_mav.sitl.physics import RigidBodyParams, derivative, mix, rk4_step
from tfl_mav.sitl.simulator import Simulator

G = 9.81


@pytest.fixture
def scenario():
    return load_scenario("paper").replace(**{"attack.rotor": 0})


def params(**kw) -> RigidBodyParams:
    base = dict(mass_kg=1.1, inertia_kgm2=(0.0020066, 0.0020038, 0.0013323), arm_m=0.2656,
                drag_thrust_ratio_m=0.016, k_t=0.05, k_r=2.75e-3, gravity_mps2=G)
    base.update(kw)
    return RigidBodyParams(**base)


def state(pos=(0, 0, 5), vel=(0, 0, 0), euler=(0, 0, 0), rates=(0, 0, 0)) -> list[float]:
    return [*pos, *vel, *euler_to_quaternion(*euler), *rates]


def test_hover_is_an_equilibrium(scenario):
    sim = Simulator(scenario)
    hover = scenario.vehicle.mass_kg * G / 4
    for _ in range(2000):
        sim.set_command([hover] * 4)
        sim.step_control_period()
    st = sim.state
    assert np.allclose(st.position_m, scenario.initial.position_m, atol=1e-9)
    assert np.allclose(st.velocity_mps, 0, atol=1e-9)
    assert np.allclose(st.body_rates_radps, 0, atol=1e-12)


def test_free_fall_with_drag_matches_closed_form():
    p = params()
    x = state()
    h = 0.001
    for _ in range(1000):
        x = rk4_step(p, x, (0, 0, 0, 0), h)
    # v̇ = −g − (k_t/m) v  ⇒  v(t) = −(g m/k_t)(1 − e^{−k_t t/m})
    c = p.k_t / p.mass_kg
    v_exact = -(G / c) * (1 - math.exp(-c))
    z_exact = 5 - (G / c) * (1 - (1 - math.exp(-c)) / c)
    assert x[5] == pytest.approx(v_exact, abs=1e-9)
    assert x[2] == pytest.approx(z_exact, abs=1e-9)


@pytest.mark.parametrize("axis", [0, 1, 2])
def test_pure_torque_spins_up_about_its_axis(axis):
    p = params(k_r=0.0)
    tau = [0.0, 0.0, 0.0]
    tau[axis] = 0.01
    x = state()
    for _ in range(100):
        x = rk4_step(p, x, (0.0, *tau), 0.001)
    rates = np.array(x[10:13])
    expected = 0.01 * 0.1 / p.inertia_kgm2[axis]  # ω = τ t / I (no gyroscopic term on one axis)
    assert rates[axis] == pytest.approx(expected, rel=1e-9)
    assert np.allclose(np.delete(rates, axis), 0, atol=1e-12)


def test_yaw_spin_up_from_drag_coupling():
    """Rotors 1, 3 faster than 2, 4 → net +d·Δf about b3 and no roll/pitch torque."""
    p = params(k_r=0.0)
    f = [3.0, 2.0, 3.0, 2.0]
    uf, tp, tq, tr = mix(p, f)
    assert (tp, tq) == (0.0, 0.0)
    assert tr == pytest.approx(p.drag_thrust_ratio_m * 2.0)
    x = state()
    for _ in range(500):
        x = rk4_step(p, x, (uf, tp, tq, tr), 0.001)
    assert x[12] == pytest.approx(tr * 0.5 / p.inertia_kgm2[2], rel=1e-9)


def test_mixer_matches_paper_matrix():
    p = params()
    ell, d = p.arm_m, p.drag_thrust_ratio_m
    M = np.array([[1, 1, 1, 1], [0, -ell, 0, ell], [-ell, 0, ell, 0], [d, -d, d, -d]])
    f = np.array([1.0, 2.0, 3.0, 4.5])
    assert np.allclose(mix(p, f), M @ f)


def test_quaternion_stays_unit_norm_while_tumbling():
    p = params()
    x = state(rates=(20.0, -15.0, 60.0))
    for _ in range(20000):
        x = rk4_step(p, x, (11.0, 0.003, -0.002, 0.01), 0.001)
    assert math.sqrt(sum(c * c for c in x[6:10])) == pytest.approx(1.0, abs=1e-12)


def test_rotational_energy_decays_with_drag_and_is_conserved_without():
    J = np.array(params().inertia_kgm2)

    def energy(x):
        w = np.array(x[10:13])
        return 0.5 * float(w @ (J * w))

    for k_r, expect_decay in ((2.75e-3, True), (0.0, False)):
        p = params(k_r=k_r, gravity_mps2=0.0)
        x = state(rates=(5.0, 3.0, 8.0))
        e0 = energy(x)
        energies = []
        for _ in range(2000):
            x = rk4_step(p, x, (0, 0, 0, 0), 0.001)
            energies.append(energy(x))
        if expect_decay:
            assert all(b < a for a, b in itertools.pairwise(energies))
            assert energies[-1] < 0.5 * e0
        else:
            assert energies[-1] == pytest.approx(e0, rel=1e-9)


def paper_euler_rhs(p: RigidBodyParams, euler, rates, vel, wrench):
    """eq. (3), written from the paper: Φ̇ = Y⁻¹Ω, JΩ̇ = τ − k_rΩ − Ω×JΩ, v̇ = …"""
    phi, th, _psi = euler
    Yinv = np.array([[1, math.sin(phi) * math.tan(th), math.cos(phi) * math.tan(th)],
                     [0, math.cos(phi), -math.sin(phi)],
                     [0, math.sin(phi) / math.cos(th), math.cos(phi) / math.cos(th)]])
    J = np.diag(p.inertia_kgm2)
    w = np.asarray(rates)
    tau = np.asarray(wrench[1:])
    dphi = Yinv @ w
    dw = np.linalg.solve(J, tau - p.k_r * w - np.cross(w, J @ w))
    R = rotation_matrix(euler_to_quaternion(*euler))
    dv = wrench[0] / p.mass_kg * R[:, 2] - np.array([0, 0, G]) - p.k_t / p.mass_kg * np.asarray(vel)
    return dphi, dw, dv


def test_plant_agrees_with_the_papers_euler_model():
    rng = np.random.default_rng(1)
    p = params()
    for _ in range(50):
        euler = rng.uniform([-1, -1, -3], [1, 1, 3])
        rates = rng.normal(0, 5, 3)
        vel = rng.normal(0, 2, 3)
        wrench = (rng.uniform(0, 30), *rng.normal(0, 0.5, 3))
        x = state(vel=vel, euler=euler, rates=rates)
        dx = derivative(p, x, wrench)
        dphi, dw, dv = paper_euler_rhs(p, euler, rates, vel, wrench)
        assert np.allclose(dx[3:6], dv, atol=1e-12)
        assert np.allclose(dx[10:13], dw, atol=1e-9)
        # Euler rates from the quaternion derivative: finite difference of the chart.
        h = 1e-7
        q = np.array(x[6:10])
        q2 = q + h * np.array(dx[6:10])
        R1, R2 = rotation_matrix(q), rotation_matrix(q2 / np.linalg.norm(q2))
        e1 = np.array([math.atan2(R1[2, 1], R1[2, 2]), -math.asin(R1[2, 0]),
                       math.atan2(R1[1, 0], R1[0, 0])])
        e2 = np.array([math.atan2(R2[2, 1], R2[2, 2]), -math.asin(R2[2, 0]),
                       math.atan2(R2[1, 0], R2[0, 0])])
        assert np.allclose((e2 - e1) / h, dphi, rtol=1e-4, atol=1e-4)


def test_motor_lag_follows_first_order_response():
    tau = 0.02
    bank = MotorBank(8e-6, 8.0, tau, [2.0] * 4)
    w0 = bank.omega_radps[0]
    target = bank.omega_for_thrust(6.0)
    for _ in range(20):
        bank.step([target] * 4, 0.001)
    expected = target + (w0 - target) * math.exp(-0.02 / tau)
    assert bank.omega_radps[0] == pytest.approx(expected, rel=1e-12)
    assert bank.rpm[0] == pytest.approx(expected * RADPS_TO_RPM)


def test_motor_thrust_is_clamped_to_limits():
    bank = MotorBank(8e-6, 8.0, 0.0, [2.0] * 4)
    thrust = bank.step([bank.omega_for_thrust(f) for f in (-1.0, 0.0, 8.0, 12.0)], 0.001)
    assert thrust == pytest.approx([0.0, 0.0, 8.0, 8.0])


@pytest.mark.parametrize("rotor", [1, 2, 3, 4])
def test_attacked_rotor_shows_in_rpm(scenario, rotor):
    sc = scenario.replace(**{"attack.rotor": rotor, "attack.signal": "constant",
                             "attack.value_n": 1.0, "attack.start_s": 0.01})
    sim = Simulator(sc)
    hover = sc.vehicle.mass_kg * G / 4
    for _ in range(15):
        sim.set_command([hover] * 4)
        sim.step_control_period()
    rpm = sim.measured_rpm()
    expected = math.sqrt(1.0 / sc.vehicle.k_f) * RADPS_TO_RPM
    hover_rpm = math.sqrt(hover / sc.vehicle.k_f) * RADPS_TO_RPM
    assert rpm[rotor - 1] == pytest.approx(expected, rel=1e-9)
    others = np.delete(rpm, rotor - 1)
    assert np.allclose(others, hover_rpm, rtol=1e-9)


def test_attack_value_is_clamped_and_reported():
    att = Attacker(AttackConfig(rotor=3, signal="10 - t"), 8.0)
    s = att.sample(0.0, (0, 0, 0), 2.0)
    assert (s.raw_n, s.applied_n, s.clamped) == (10.0, 8.0, True)
    s = att.sample(12.0, (0, 0, 0), 2.0)
    assert (s.applied_n, s.clamped) == (0.0, True)
    s = att.sample(5.0, (0, 0, 0), 2.0)
    assert (s.applied_n, s.clamped) == (5.0, False)


def test_paper_signal_and_stuck_and_injection():
    att = Attacker(AttackConfig(rotor=2, start_s=0.0, signal="paper"), 8.0)
    assert att.sample(3.0, (0, 0, 1.0), 2.0).applied_n == pytest.approx(0.3 + math.sin(1.0))
    att = Attacker(AttackConfig(rotor=0), 8.0)
    assert att.sample(1.0, (0, 0, 0), 2.5).rotor == 0
    att.inject(4, 2, 1.0)  # STUCK at the command at onset
    assert att.sample(1.5, (0, 0, 0), 2.5).applied_n == 2.5
    assert att.sample(2.0, (0, 0, 0), 6.0).applied_n == 2.5
    with pytest.raises(ValueError, match="param2"):
        att.inject(1, 3, 1.0)
    with pytest.raises(ValueError, match="param3"):
        att.inject(5, 1, 1.0)


def test_nan_command_is_rejected_and_previous_kept(scenario):
    sim = Simulator(scenario)
    sim.set_command([2.0, 2.0, 2.0, 2.0])
    with pytest.raises(ValueError, match="rotor 3"):
        sim.set_command([2.0, 2.0, math.nan, 2.0])
    assert sim.rotor_commands_n == [2.0] * 4
    assert sim.rejected_commands == 1


def test_same_seed_same_noisy_measurements(scenario):
    sc = scenario.replace(**{"vehicle.rpm_noise_std": 10.0,
                             "sensors.velocity_noise_std_mps": 0.01})
    runs = []
    for _ in range(2):
        sim = Simulator(sc)
        out = []
        for _ in range(50):
            sim.step_control_period()
            out.append((*sim.measured_rpm(), *sim.measured.velocity_mps))
        runs.append(out)
    assert runs[0] == runs[1]


def test_float_and_numpy_measurements_are_the_same_numbers(scenario):
    """The hot loops read ``measured_floats``; everyone else the numpy ``measured``."""
    sc = scenario.replace(**{"vehicle.rpm_noise_std": 10.0,
                             "sensors.position_noise_std_m": 0.01,
                             "sensors.velocity_noise_std_mps": 0.01,
                             "sensors.attitude_noise_std_rad": 0.01,
                             "sensors.rate_noise_std_radps": 0.005})
    sim = Simulator(sc)
    for _ in range(20):
        sim.step_control_period()
        fast, arrays = sim.measured_floats, sim.measured
        for name in ("position_m", "velocity_mps", "quaternion_wxyz", "body_rates_radps"):
            assert isinstance(getattr(arrays, name), np.ndarray)
            assert list(getattr(fast, name)) == getattr(arrays, name).tolist()
        assert fast.time_usec == arrays.time_usec == sim.time_usec
        assert list(sim.measured_rpm_floats) == sim.measured_rpm().tolist()
        assert sim.measured is arrays        # built once per tick


def test_crash_reasons_are_sentences(scenario):
    sim = Simulator(scenario)
    sim.set_command([0.0] * 4)
    while sim.crash_reason() is None:
        sim.step_control_period()
    assert "hit the ground" in sim.crash_reason()


def test_the_state_is_plain_floats_and_a_diverging_one_ends_the_run(scenario):
    """Python floats throughout (numpy scalars cost RK4 4-6×); where floats would raise on a
    diverging state (a zero quaternion norm, ``**`` overflowing), the step falls back to
    numpy's inf/NaN and the run ends with a reason, never an exception."""
    sim = Simulator(scenario)
    sim.step_control_period()
    assert all(type(c) is float for c in sim.state_vector)
    assert all(type(c) is float for c in sim.measured_floats.quaternion_wxyz)
    # Spinning at 1e80 rad/s (a state built through the scenario): within the first step a
    # ``**`` overflows and floats raise OverflowError.
    sim = Simulator(scenario.replace(**{"initial.body_rates_radps": (1e80, 0.0, 0.0)}))
    sim.step_control_period()
    assert "non-finite" in sim.crash_reason()


def test_a_huge_but_finite_state_is_a_crash_said_in_words(scenario):
    """1e160 rad/s is a finite float whose square is not: asked before any step, the crash
    check says the vehicle spins too fast rather than raising OverflowError."""
    sim = Simulator(scenario.replace(**{"initial.body_rates_radps": (1e160, 0.0, 0.0)}))
    assert "spinning at" in sim.crash_reason()
    sim = Simulator(scenario.replace(**{"initial.velocity_mps": (0.0, 1e160, 0.0)}))
    assert "runaway" in sim.crash_reason()
