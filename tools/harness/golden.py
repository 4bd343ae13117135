"""The golden flights: which they are and how one is reduced to comparable numbers.

Used by ``tests/golden/test_golden.py`` (compare) and ``tests/golden/capture.py`` (recapture);
the captured results live in ``tests/golden/*.json``.
"""

from __future__ import annotations

import hashlib
from pathlib import Path
from typing import Any

import numpy as np

# name → (scenario, duration_s, [--set overrides])
LOCKSTEP_CASES: dict[str, tuple[str, float, list[str]]] = {
    "paper": ("paper", 4.0, []),
    "paper-exact": ("paper-exact", 4.0, []),
    "rotor1": ("paper", 3.0, ["attack.rotor=1"]),
    "rotor3": ("paper", 3.0, ["attack.rotor=3"]),
    "rotor4": ("paper", 3.0, ["attack.rotor=4"]),
    "lag20ms": ("paper", 3.0, ["vehicle.motor_time_constant_s=0.02",
                               "controller.motor_time_constant_scale=1.2",
                               "vehicle.rpm_noise_std=10"]),
}

# name → (scenario, duration_s, attack_info, [--set overrides])
OFFLINE_CASES: dict[str, tuple[str, float, str, list[str]]] = {
    "paper-oracle": ("paper", 3.0, "oracle", []),
    "paper-detector": ("paper", 3.0, "detector", []),
    "nominal": ("nominal", 2.0, "detector", []),
    "lag20ms-noise": ("paper", 2.0, "detector", ["vehicle.motor_time_constant_s=0.02",
                                                 "vehicle.rpm_noise_std=10"]),
}

_DETERMINISTIC = ("crashed", "sim_time_s", "final_path_distance_m",
                  "max_path_distance_last_10s_m", "rms_path_distance_last_10s_m",
                  "thrust_min_n", "thrust_max_n", "saturated_fraction", "max_yaw_rate_radps",
                  "fallback_fraction", "detected_rotor", "detection_time_s")


def _digest(a: np.ndarray) -> str:
    return hashlib.sha256(np.ascontiguousarray(a, dtype=np.float64).tobytes()).hexdigest()[:16]


def reduce(summary: dict[str, Any], log: Any) -> dict[str, Any]:
    out = {k: summary.get(k) for k in _DETERMINISTIC if k in summary}
    out["n_samples"] = len(log["t_s"])
    out["position_sha"] = _digest(log["position_m"])
    out["thrust_cmd_sha"] = _digest(log["thrust_cmd_n"])
    return out


def _scenario(name: str, settings: list[str]) -> Any:
    from tfl_mav.scenario import apply_overrides, load_scenario

    return apply_overrides(load_scenario(name), settings)


def fly_offline_case(name: str, duration_s: float, attack_info: str,
                     settings: list[str]) -> dict[str, Any]:
    from tfl_mav.flightlog.flight import summarize
    from tfl_mav.offline import fly_offline

    sc = _scenario(name, settings)
    log = fly_offline(sc, attack_info=attack_info, duration_s=duration_s)
    s = summarize(log)
    s.pop("detection_time_s", None)   # not part of the captured offline results
    if attack_info == "detector":
        est = log["attack_estimate_n"]
        s["detected_rotor"] = sc.attack.rotor if np.any(np.isfinite(est)) else 0
    return reduce(s, log)


def fly_lockstep(name: str, duration_s: float, settings: list[str], *,
                 out: Path) -> dict[str, Any]:
    from tfl_mav.flightlog.from_mcap import flight_log_from_mcap
    from tfl_mav.tools.harness.demo import run_demo

    sc = _scenario(name, settings)
    summary = run_demo(name, out, settings=settings, duration_s=duration_s, plots=False,
                       scenario=sc)
    log = flight_log_from_mcap(out / "run.mcap", sc, out / "ctl.mcap")
    return reduce(summary, log)
