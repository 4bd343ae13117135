"""Build the attack detector a scenario describes (shared by the offline runner and the daemon).

The detector's motor model is the scenario's vehicle (``k_f``, ``thrust_max_n``,
``motor_time_constant_s`` scaled by ``detector.model_time_constant_scale``); its noise level
is ``detector.rpm_noise_std``, or the vehicle's ``rpm_noise_std`` when that is 0 (the
default), so a scenario that adds ESC noise need not repeat it.
"""

from __future__ import annotations

from tfl_mav.control.detector import AttackDetector, DetectorConfig
from tfl_mav.scenario import Scenario

__all__ = ["build_detector", "detector_config"]


def detector_config(sc: Scenario) -> DetectorConfig:
    """The detector's tuning from the scenario's ``[detector]`` section."""
    d = sc.detector
    return DetectorConfig(
        rpm_noise_std=d.rpm_noise_std or sc.vehicle.rpm_noise_std,
        cusum_drift_sigma=d.cusum_drift_sigma, cusum_threshold_sigma=d.cusum_threshold_sigma,
        min_ticks=d.min_ticks, enabled=d.enabled,
        model_time_constant_scale=d.model_time_constant_scale,
        time_constant_tolerance=d.time_constant_tolerance)


def build_detector(sc: Scenario) -> AttackDetector:
    v = sc.vehicle
    return AttackDetector(v.k_f, v.thrust_max_n, v.motor_time_constant_s, sc.run.control_dt_s,
                          detector_config(sc))
