"""The air: Dryden turbulence against the standard's spectra, the gust's shape, seeded replay,
and the air-relative drag and rotor aerodynamics of the physics step."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from scipy import signal

from tfl_mav.scenario import ScenarioError, WindConfig, load_scenario, scenario_from_dict
from tfl_mav.sitl.physics import (
    RigidBodyParams,
    RotorAeroParams,
    derivative,
    derivative_air,
    rk4_air_step,
    rk4_air_stepper,
)
from tfl_mav.sitl.simulator import Simulator
from tfl_mav.sitl.wind import (
    FT,
    KNOT,
    TURBULENCE_HZ,
    WindField,
    dryden_psd,
    dryden_scales,
)

G = 9.81
PARAMS = RigidBodyParams(1.1, (0.0020066, 0.0020038, 0.0013323), 0.2656, 0.016, 0.05,
                         2.75e-3, G)
# Band-averaged PSD of 1200 s of turbulence (Welch, 20 s Hann segments: ~120 averages)
# against the standard's: within this factor in each half-decade band from 0.1 to 10 Hz.
# The estimate's own scatter in the lowest band (5 bins) is ~5–10 % (1 σ); over seeds 0–4
# at 600 s the worst band of the three components was off by 23 %.
PSD_TOLERANCE = 1.3


def test_scales_are_mil_f_8785c_low_altitude():
    s = dryden_scales("moderate")
    h = 20.0                                        # ft: the reference altitude
    sigma_w = 0.1 * 30.0 * KNOT                     # σ_w = 0.1 W₂₀, W₂₀ = 30 kt
    assert s.sigma_mps[2] == pytest.approx(sigma_w)
    assert s.sigma_mps[0] == pytest.approx(sigma_w / (0.177 + 0.000823 * h) ** 0.4)
    assert s.length_m[2] == pytest.approx(h * FT)
    assert s.length_m[0] == pytest.approx(h / (0.177 + 0.000823 * h) ** 1.2 * FT)
    assert dryden_scales("none").sigma_mps == (0.0, 0.0, 0.0)
    # light < moderate < severe, in proportion 15 : 30 : 45 kt
    assert dryden_scales("severe").sigma_mps[2] == pytest.approx(3 * dryden_scales(
        "light").sigma_mps[2])


@pytest.mark.parametrize("axis", [0, 1, 2])
def test_psd_integrates_to_the_variance(axis):
    omega = np.linspace(0.0, 2000.0, 2_000_001)
    psd = dryden_psd(axis, omega, 1.3, 40.0, 3.0)
    assert np.trapezoid(psd, omega) == pytest.approx(1.3 ** 2, rel=2e-3)


@pytest.mark.parametrize(("level", "mean", "seed"), [("light", (3.0, 0.0, 0.0), 0),
                                                      ("moderate", (0.0, 5.0, 0.0), 1),
                                                      ("severe", (6.0, 6.0, 0.0), 2)])
def test_turbulence_spectra_fit_the_dryden_psds(level, mean, seed):
    field = WindField(WindConfig(mean_mps=mean, turbulence=level), seed, 1e-3)
    x = field.turbulence_samples(1200)              # (u, v, w) at 100 Hz, 1200 s
    s = field.scales
    edges = np.logspace(-1.0, 1.0, 5)               # 0.1 … 10 Hz, half-decade bands
    for axis in range(3):
        f_hz, p = signal.welch(x[:, axis], fs=TURBULENCE_HZ, nperseg=2048)
        measured = p / (2.0 * math.pi)              # per Hz → per rad/s (one-sided)
        standard = dryden_psd(axis, 2.0 * math.pi * f_hz, s.sigma_mps[axis],
                              s.length_m[axis], s.airspeed_mps)
        for lo, hi in itertools.pairwise(edges):
            band = (f_hz >= lo) & (f_hz < hi)
            ratio = measured[band].mean() / standard[band].mean()
            assert 1 / PSD_TOLERANCE < ratio < PSD_TOLERANCE, (axis, lo, ratio)
    # w decorrelates in L_w/V ≈ 1–2 s: 1200 s pin its variance within 10 %
    assert np.var(x[:, 2]) == pytest.approx(s.sigma_mps[2] ** 2, rel=0.1)


def test_seeded_wind_replays_bit_for_bit_and_seeds_differ():
    cfg = WindConfig(mean_mps=(3.0, 1.0, 0.0), turbulence="light", gust_mps=(0.0, 6.0, 0.0),
                     gust_start_s=1.0, gust_duration_s=2.0)
    steps = np.arange(0, 5000)
    a = WindField(cfg, 7, 1e-3).series(steps)
    b = WindField(cfg, 7, 1e-3).series(steps)
    assert a.tobytes() == b.tobytes()
    assert not np.array_equal(a, WindField(cfg, 8, 1e-3).series(steps))


def test_gust_is_one_minus_cosine_with_its_peak_mid_gust():
    cfg = WindConfig(mean_mps=(1.0, 0.0, 0.0), gust_mps=(0.0, 6.0, -2.0), gust_start_s=2.0,
                     gust_duration_s=1.0)
    field = WindField(cfg, 0, 1e-3)
    w = field.series(np.arange(0, 4001))
    assert w[1999].tolist() == [1.0, 0.0, 0.0]          # before
    assert w[2500] == pytest.approx([1.0, 6.0, -2.0])   # mid-gust: the peak
    assert w[2250] == pytest.approx([1.0, 3.0, -1.0])   # a quarter in: half of it
    assert w[3001].tolist() == [1.0, 0.0, 0.0]          # after
    assert np.all(w[:, 1] <= 6.0 + 1e-12)


def test_wind_keys_are_checked():
    with pytest.raises(ScenarioError, match=r"wind\.turbulence: must be one of none, light"):
        scenario_from_dict({"wind": {"turbulence": "gusty"}})
    with pytest.raises(ScenarioError, match=r"wind.mean_mps: must be a list of 3"):
        scenario_from_dict({"wind": {"mean_mps": [1.0, 2.0]}})
    with pytest.raises(ScenarioError, match=r"wind.gust_duration_s: must be in \[0, 3600\] s"):
        scenario_from_dict({"wind": {"gust_duration_s": -1.0}})
    sc = scenario_from_dict({"wind": {"mean_mps": [3, 0, 0], "turbulence": "light"}})
    assert sc.wind.mean_mps == (3.0, 0.0, 0.0) and sc.wind.active
    assert not load_scenario("paper").wind.active
    # the scenario's dict (what a log keeps, from_mcap reads back) round-trips
    data = sc.to_dict()
    data.pop("source")
    assert scenario_from_dict(data).wind == sc.wind


# ------------------------------------------------------------------ physics in moving air
def _state(vel=(0.0, 0.0, 0.0), rates=(0.0, 0.0, 0.0)):
    return [0.0, 0.0, 5.0, *vel, 1.0, 0.0, 0.0, 0.0, *rates]


def test_still_air_without_rotor_aero_is_the_paper_model():
    x = [0.1, -0.2, 4.0, 0.7, -0.3, 0.2, 0.98, 0.1, -0.1, 0.13, 0.4, -0.3, 0.2]
    x[6:10] = (np.asarray(x[6:10]) / np.linalg.norm(x[6:10])).tolist()
    wrench = (11.0, 0.02, -0.01, 0.003)
    a = derivative(PARAMS, x, wrench)
    b = derivative_air(PARAMS, RotorAeroParams(), x, wrench, (0.0, 0.0, 0.0, 2.7, 2.7, 2.7, 2.7))
    assert b == pytest.approx(a, rel=1e-13, abs=1e-15)


def test_drag_acts_on_the_air_relative_velocity():
    hover = PARAMS.mass_kg * G
    # at rest in a 3 m/s wind along x: pushed downwind by k_t · 3 m/s
    d = derivative_air(PARAMS, RotorAeroParams(), _state(), (hover, 0, 0, 0),
                       (3.0, 0.0, 0.0, hover / 4, hover / 4, hover / 4, hover / 4))
    assert d[3] == pytest.approx(PARAMS.k_t * 3.0 / PARAMS.mass_kg)
    # moving with the air: no drag
    d = derivative_air(PARAMS, RotorAeroParams(), _state(vel=(3.0, 0.0, 0.0)),
                       (hover, 0, 0, 0), (3.0, 0.0, 0.0, hover / 4, hover / 4, hover / 4,
                                          hover / 4))
    assert d[3] == 0.0


def test_rotor_drag_is_rotor_speed_times_in_plane_airspeed():
    hover = PARAMS.mass_kg * G
    f = hover / 4
    k_f = 8e-6
    kd = 1.56e-4
    aero = RotorAeroParams(kd, 0.0, 0.0, (0.0, 0.0, 0.0), 1.0 / k_f)
    still = PARAMS._replace(k_t=0.0)
    d = derivative_air(still, aero, _state(vel=(2.0, 0.0, 0.0)), (hover, 0, 0, 0),
                       (0.0, 0.0, 0.0, f, f, f, f))
    omega = math.sqrt(f / k_f)
    assert d[3] == pytest.approx(-4 * omega * kd * 2.0 / PARAMS.mass_kg)
    assert d[4] == pytest.approx(0.0) and d[11] == pytest.approx(0.0)
    # twice the rotor speed (four times the thrust), twice the drag
    d4 = derivative_air(still, aero, _state(vel=(2.0, 0.0, 0.0)), (4 * hover, 0, 0, 0),
                        (0.0, 0.0, 0.0, 4 * f, 4 * f, 4 * f, 4 * f))
    assert d4[3] == pytest.approx(2 * d[3])


def test_compiled_air_step_is_the_python_step():
    aero = RotorAeroParams(1.56e-4, 3.04e-4, 4.06e-3, (1.22e-2, 1.22e-2, 2.44e-2), 1 / 8e-6,
                           6e-5)
    step = rk4_air_stepper(PARAMS, aero)
    rng = np.random.default_rng(3)
    for _ in range(50):
        x = _state(vel=tuple(rng.normal(0, 3, 3)), rates=tuple(rng.normal(0, 2, 3)))
        q = rng.normal(0, 1, 4)
        x[6:10] = (q / np.linalg.norm(q)).tolist()
        x = [float(c) for c in x]
        air = (*rng.normal(0, 4, 3).tolist(), *rng.uniform(0, 8, 4).tolist())
        wrench = (float(sum(air[3:])), 0.01, -0.02, 0.001)
        assert tuple(step(x, wrench, air, 1e-3)) == tuple(
            rk4_air_step(PARAMS, aero, x, wrench, air, 1e-3))


def test_simulator_in_wind_replays_and_logs_the_wind():
    sc = load_scenario("paper").replace(**{"attack.rotor": 0, "wind.mean_mps": [3.0, 0.0, 0.0],
                                           "wind.turbulence": "light", "run.seed": 4})
    runs = []
    for _ in range(2):
        sim = Simulator(sc)
        hover = sc.vehicle.mass_kg * G / 4
        xs = []
        for _ in range(300):
            sim.set_command([hover] * 4)
            sim.step_control_period()
            xs.append(tuple(sim.state_vector) + sim.wind_mps)
        runs.append(xs)
    assert runs[0] == runs[1]
    # hover thrust in a wind blowing toward +x: the vehicle drifts downwind
    assert runs[0][-1][3] > 0.0
    field = WindField(sc.wind, 4, sc.run.physics_dt_s)
    assert list(runs[0][-1][13:]) == field.series(np.arange(0, 301))[-1].tolist()


def test_rotor_aero_is_off_in_the_paper_scenario():
    sc = load_scenario("paper")
    assert sc.vehicle.rotor_aero is False
    # the still-air rigid-body step flies: no air step swapped in for it
    assert Simulator(sc).step_control_period.__func__ is Simulator.step_control_period


def test_rotor_momentum_gives_the_gyroscopic_torque():
    hover = PARAMS.mass_kg * G
    k_f, jr = 8e-6, 6e-5
    f_13, f_24 = 2.4, 3.0                        # rotors 2, 4 faster: h_r along +b3
    aero = RotorAeroParams(0.0, 0.0, 0.0, (0.0, 0.0, 0.0), 1.0 / k_f, jr)
    air = (0.0, 0.0, 0.0, f_13, f_24, f_13, f_24)
    x = _state(rates=(1.0, 0.0, 0.0))
    with_h = derivative_air(PARAMS, aero, x, (hover, 0, 0, 0), air)
    without = derivative_air(PARAMS, aero._replace(rotor_inertia_kgm2=0.0), x,
                             (hover, 0, 0, 0), air)
    h_r = jr * 2 * (math.sqrt(f_24 / k_f) - math.sqrt(f_13 / k_f))
    # −Ω × h_r b3 with Ω = (1, 0, 0): (0, h_r, 0)
    assert with_h[11] - without[11] == pytest.approx(h_r / PARAMS.inertia_kgm2[1])
    assert with_h[10] == without[10] and with_h[12] == without[12]


def test_spinning_rotors_up_turns_the_body_the_other_way():
    """J_r ω̇ about b3: rotors 1, 3 (spinning about −b3) sped up push the body's yaw rate
    positive on top of their drag's reaction, by J_r Σ±Δω / I_z over the step."""
    base = load_scenario("paper").replace(**{"attack.rotor": 0, "vehicle.rotor_aero": True,
                                             "initial.position_m": [0.0, 0.0, 5.0]})
    hover = base.vehicle.mass_kg * G / 4
    cmd = [hover + 0.5, hover - 0.5, hover + 0.5, hover - 0.5]
    r = []
    for jr in (6e-5, 0.0):
        sim = Simulator(base.replace(**{"vehicle.rotor_inertia_kgm2": jr}))
        w0 = list(sim.motors.omega_radps)
        sim.set_command(cmd)
        sim.step_control_period()
        w1 = sim.motors.omega_radps
        r.append(sim.state_vector[12])
    dw = [b - a for a, b in zip(w0, w1, strict=True)]
    expected = 6e-5 * (dw[0] - dw[1] + dw[2] - dw[3]) / base.vehicle.inertia_kgm2[2]
    assert expected > 0
    assert r[0] - r[1] == pytest.approx(expected, rel=0.02)
