"""Build the controller a scenario describes (shared by the offline runner and the daemon).

The controller's model is the scenario's vehicle scaled by ``model_mass_scale`` and
``model_inertia_scale``: the controller never sees the true mass or inertia.
"""

from __future__ import annotations

from tfl_mav.control.law import LawConfig, ModelParams, TFLController
from tfl_mav.control.paths import Path, build_path
from tfl_mav.scenario import Scenario, ScenarioError

__all__ = ["build_controller", "law_config", "model_params", "scenario_path"]


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
        aware_of_attack=c.aware_of_attack)


def scenario_path(sc: Scenario) -> Path:
    """The scenario's path; path-library errors are re-raised naming the scenario key."""
    from tfl_mav.control.paths import PathError

    try:
        return build_path(sc.path.kind, sc.path.params)
    except PathError as exc:
        raise ScenarioError(getattr(exc, "field", "path"), getattr(exc, "message", str(exc))) \
            from None


def build_controller(sc: Scenario) -> TFLController:
    return TFLController(model_params(sc), scenario_path(sc), law_config(sc),
                         sc.run.control_dt_s)
