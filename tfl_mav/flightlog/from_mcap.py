"""Rebuild a :class:`~tfl_mav.flightlog.flight.FlightLog` from the MCAP files of a flight.

The vehicle's log (``run.mcap``) holds the ground truth (``/sim/truth/state``,
``/sim/truth/thrusts``, ``/sim/truth/attack``) and every MAVLink frame; the controller's
log (``ctl.mcap``, optional) holds ``/controller/state`` every tick (mode, detection,
estimate, saturation). The path distance is recomputed from the true positions with the
scenario's path, so it is the *true* distance, not the controller's measured one.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from tfl_mav.airframe import mix
from tfl_mav.build import scenario_path
from tfl_mav.control.paths import PathTracker
from tfl_mav.flightlog.flight import FlightLog
from tfl_mav.flightlog.logread import LogReader
from tfl_mav.modes import Mode
from tfl_mav.scenario import Scenario

__all__ = ["controller_states", "flight_log_from_mcap"]

_TRUTH = {"/sim/truth/state", "/sim/truth/thrusts", "/sim/truth/attack"}


def controller_states(ctl_path: str | Path) -> dict[int, dict[str, Any]]:
    """``/controller/state`` messages keyed by sim time in µs."""
    out: dict[int, dict[str, Any]] = {}
    for m in LogReader(ctl_path).messages({"/controller/state"}):
        d = m.json()
        out[round(d["t_s"] * 1e6)] = d
    return out


def flight_log_from_mcap(run_path: str | Path, scenario: Scenario,
                         ctl_path: str | Path | None = None) -> FlightLog:
    """The flight in ``run_path`` (and ``ctl_path``) as a finished FlightLog."""
    truth: dict[int, dict[str, Any]] = {}
    for m in LogReader(run_path).messages(_TRUTH):
        d = m.json()
        truth.setdefault(round(d["t_s"] * 1e6), {}).update(
            {m.topic.rsplit("/", 1)[-1]: d})
    ctl = controller_states(ctl_path) if ctl_path and Path(ctl_path).exists() else {}
    v = scenario.vehicle
    log = FlightLog(thrust_max_n=v.thrust_max_n, attack_rotor=scenario.attack.rotor,
                    attack_start_s=scenario.attack.start_s if scenario.attack.rotor
                    else math.nan)
    path = scenario_path(scenario)
    log.path_points_m = path.sample(400)
    tracker = PathTracker(path)
    yaw_prev: float | None = None
    yaw_unwrapped = 0.0
    for key in sorted(truth):
        rec = truth[key]
        if not {"state", "thrusts", "attack"} <= rec.keys():
            continue
        st, th, at = rec["state"], rec["thrusts"], rec["attack"]
        # The recorder leaves non-finite values out (Foxglove cannot read null): a
        # diverged sample has no position/thrust/attack and is not plotted.
        if not ("position_m" in st and "quaternion_wxyz" in st and "thrust_n" in th
                and "applied_n" in at):
            continue
        pos = st["position_m"]
        w, x, y, z = st["quaternion_wxyz"]
        yaw = math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
        yaw_unwrapped = yaw if yaw_prev is None else \
            yaw_unwrapped + math.remainder(yaw - yaw_prev, math.tau)
        yaw_prev = yaw
        out = tracker.evaluate([[c, 0.0, 0.0, 0.0, 0.0] for c in pos])
        c = ctl.get(key, {})
        uf, tp, tq, tr = mix(v, th["thrust_n"])
        est = c.get("attack_estimate_n")
        log.append(t_s=st["t_s"], position_m=pos, velocity_mps=st["velocity_mps"],
                   body_rates_radps=st["body_rates_radps"], yaw_rad=yaw_unwrapped,
                   path_distance_m=out.distance_m, thrust_cmd_n=c.get("rotor_thrust_cmd_n",
                                                                     th["thrust_n"]),
                   thrust_true_n=th["thrust_n"], attack_true_n=at["applied_n"],
                   attack_estimate_n=est if est is not None else math.nan, uf_n=uf,
                   torque_nm=(tp, tq, tr), saturated=bool(c.get("saturated", False)),
                   mode=int(Mode.parse(c.get("mode", "nominal"))))
    log.finish()
    if len(log["t_s"]):
        rates = np.abs(log["body_rates_radps"])
        log.crashed = bool(np.max(rates) > 300.0)
    return log
