"""A scenario → the controller's parts: its (wrong on purpose) model, law, path, detector.

Shared by the offline runner and the daemon through
:class:`~tfl_mav.controller.flight_computer.FlightComputer`.
The controller's model is the scenario's vehicle scaled by ``model_mass_scale`` and
``model_inertia_scale``: the controller never sees the true mass or inertia. The detector's
motor model is the scenario's vehicle (``k_f``, ``thrust_max_n``, ``motor_time_constant_s``
scaled by ``detector.model_time_constant_scale``); its noise level is
``detector.rpm_noise_std``, or the vehicle's ``rpm_noise_std`` when that is 0 (the default),
so a scenario that adds ESC noise need not repeat it.
"""

from __future__ import annotations

import dataclasses

from tfl_mav.control.detect.detector import AttackDetector, DetectorConfig
from tfl_mav.control.path.paths import Path, build_path
from tfl_mav.control.spin.law import build as build_spin_law
from tfl_mav.control.spin.step import SpinParams
from tfl_mav.control.tfl.tfl_controller import LawConfig, ModelParams, TFLController
from tfl_mav.scenario import Scenario, ScenarioError

__all__ = ["build_controller", "build_detector", "detector_config", "law_config",
           "model_params", "noisy_measurements", "outdoors", "scenario_path",
           "translational_observer"]


def model_params(sc: Scenario) -> ModelParams:
    """The controller's (wrong on purpose) model of the vehicle."""
    v, c = sc.vehicle, sc.controller
    return ModelParams(
        mass_kg=v.mass_kg * c.model_mass_scale,
        inertia_kgm2=tuple(i * c.model_inertia_scale for i in v.inertia_kgm2),  # type: ignore[arg-type]
        arm_m=v.arm_m, drag_thrust_ratio_m=v.drag_thrust_ratio_m, k_t=v.k_t, k_r=v.k_r,
        thrust_max_n=v.thrust_max_n, gravity_mps2=v.gravity_mps2, k_f=v.k_f,
        motor_time_constant_s=v.motor_time_constant_s * c.motor_time_constant_scale)


def law_config(sc: Scenario) -> LawConfig:
    c = sc.controller
    robust = c.law == "robust"
    return LawConfig(
        speed_mps=sc.path.speed_mps, xi_pole=c.xi_pole, eta_pole=c.eta_pole,
        xi_pole_fine=c.xi_pole_fine, eta_pole_fine=c.eta_pole_fine, yaw_pole=c.yaw_pole,
        robust=robust, mass_estimator=c.mass_estimator, disturbance_observer=c.disturbance_observer,
        gain_switch=c.gain_switch, observer_tau_s=c.observer_tau_s,
        translational_observer=translational_observer(sc),
        translational_observer_tau_s=c.translational_observer_tau_s,
        translational_observer_vertical=sc.vehicle.rotor_aero,
        aware_of_attack=c.aware_of_attack)


def translational_observer(sc: Scenario) -> bool:
    """Whether the law runs its translational disturbance observer: ``on``, ``off``, or
    ``auto`` — on where the scenario flies outdoors (moving air, rotor aerodynamics, or the
    realistic sensors behind an estimator). In the still air of the ideal scenarios the
    paper's model has no horizontal push for it to find, and the envelope's ideal flights
    stay the law's own, bit for bit (docs/realworld.md gives the numbers with it on).

    It estimates the vertical too where the rotors' aerodynamics fly: their inflow drag
    (k_z ω u_z, 0.71 N per m/s at hover, 14× the model's k_t) is a vertical force that
    follows the climb rate, which the mass estimator — the law's vertical integral action
    in still air — cannot take for a mass (without it the built-in ``realistic`` flips)."""
    mode = sc.controller.translational_observer
    if mode == "auto":
        return outdoors(sc)
    return mode == "on"


def outdoors(sc: Scenario) -> bool:
    """Whether forces the paper's model lacks act on the vehicle or its measurements: moving
    air, the rotors' aerodynamics, or the realistic sensors behind an estimator. There the
    estimated mass also carries them (1.14 kg for 1.0 in the built-in ``realistic``), so
    f_max over it is not the climb authority (the safe law keeps its fixed limits:
    ``SafeParams.thrust_known``)."""
    return sc.wind.active or sc.vehicle.rotor_aero or sc.sensors.model == "realistic"


def noisy_measurements(sc: Scenario) -> bool:
    """Whether what the controller measures is noisy: ESC rpm noise, noisy state sensors,
    the realistic sensors behind an onboard estimator, or moving air and rotor aerodynamics
    (forces the model does not have, which the translational observer turns into noise).
    The safe law's outer loop is slower there (:func:`~tfl_mav.control.safe.safe_step.
    outer_loop_omega`)."""
    s = sc.sensors
    return (detector_config(sc).rpm_noise_std > 0.0 or s.position_noise_std_m > 0.0
            or s.velocity_noise_std_mps > 0.0 or s.attitude_noise_std_rad > 0.0
            or s.rate_noise_std_radps > 0.0 or outdoors(sc))


def scenario_path(sc: Scenario) -> Path:
    """The scenario's path; path-library errors are re-raised naming the scenario key."""
    from tfl_mav.control.path.paths import PathError

    try:
        return build_path(sc.path.kind, sc.path.params)
    except PathError as exc:
        raise ScenarioError(getattr(exc, "field", "path"), getattr(exc, "message", str(exc))) \
            from None


def build_controller(sc: Scenario, *, speed_mps: float | None = None) -> TFLController:
    """The scenario's TFL law; ``speed_mps``: the path speed to fly when it is not the
    scenario's (the highest feasible one). With motor lag the law's inverse filters the ESC
    noise the detector assumes."""
    cfg = law_config(sc)
    if speed_mps is not None and speed_mps != cfg.speed_mps:
        cfg = dataclasses.replace(cfg, speed_mps=speed_mps)
    ctrl = TFLController(model_params(sc), scenario_path(sc), cfg, sc.run.control_dt_s,
                         rpm_noise_std=detector_config(sc).rpm_noise_std)
    return ctrl


def detector_config(sc: Scenario) -> DetectorConfig:
    """The scenario's ``[detector]`` section, with ``rpm_noise_std = 0`` meaning the
    vehicle's ESC noise."""
    d = sc.detector
    return dataclasses.replace(d, rpm_noise_std=d.rpm_noise_std or sc.vehicle.rpm_noise_std)


def build_detector(sc: Scenario) -> AttackDetector:
    v = sc.vehicle
    return AttackDetector(v.k_f, v.thrust_max_n, v.motor_time_constant_s, sc.run.control_dt_s,
                          detector_config(sc))


def spin_params_for(sc: Scenario, rotor: int | None = None, *,
                    lag_inverted: bool = True) -> SpinParams:
    """The spin law for scenario ``sc``: its attacked rotor, the controller's model (mass and
    inertia scales), its motor lag model and its control period. ``lag_inverted``: its
    thrusts go through the motor-lag inverse (the flight computer's), so the gains are the
    lag-free design; False designs them for the lag (a torque weight 1 + (Ω τ_m)²)."""
    v, c = sc.vehicle, sc.controller
    lag = 0.0 if lag_inverted else c.motor_time_constant_scale * v.motor_time_constant_s
    return build_spin_law(v, rotor or sc.attack.rotor, sc.run.control_dt_s,
                 mass_scale=c.model_mass_scale, inertia_scale=c.model_inertia_scale,
                 motor_time_constant_s=lag)
