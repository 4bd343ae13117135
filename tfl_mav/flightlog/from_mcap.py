"""Rebuild a :class:`~tfl_mav.flightlog.flight.FlightLog` from the MCAP files of a flight.

The vehicle's log (``run.mcap``) holds the ground truth (``/sim/truth/state``,
``/sim/truth/thrusts``, ``/sim/truth/attack``) and every MAVLink frame; the controller's
log (``ctl.mcap``, optional) holds ``/controller/state`` every tick (mode, detection,
estimate, saturation). The path distance is recomputed from the true positions with the
scenario's path, so it is the *true* distance, not the controller's measured one.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np
from mcap.records import Message

from tfl_mav.airframe import mix
from tfl_mav.build import scenario_path
from tfl_mav.control.paths import PathTracker
from tfl_mav.flightlog.flight import FlightLog
from tfl_mav.flightlog.logread import LogReader
from tfl_mav.modes import Mode
from tfl_mav.scenario import Scenario, ScenarioError, scenario_from_dict

__all__ = ["controller_states", "flight_log_from_mcap", "load_flight", "log_metadata",
           "scenario_from_log"]

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
    detected: list[int] = []
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
                   torque_nm=(tp, tq, tr),
                   # no controller record for this tick: unknown, not "unsaturated"
                   saturated=float(bool(c["saturated"])) if "saturated" in c else math.nan,
                   mode=int(Mode.parse(c.get("mode", "nominal"))))
        detected.append(int(c.get("detected_rotor") or 0))
    log.finish()
    if ctl:
        log.detected_rotor = np.asarray(detected, dtype=int)
    if len(log["t_s"]):
        rates = np.abs(log["body_rates_radps"])
        log.crashed = bool(np.max(rates) > 300.0)
    return log


def log_metadata(path: str | Path) -> dict[str, dict[str, str]]:
    """The MCAP metadata records of ``path`` (name → key/value map)."""
    reader = LogReader(path)
    for rec in reader.records():   # metadata precedes the chunked messages: stop early
        if isinstance(rec, Message):
            break
    return {md.name: dict(md.metadata) for md in reader.metadata}


def scenario_from_log(path: str | Path) -> Scenario:
    """The scenario a log was flown with (``scenario`` metadata: the vehicle writes
    ``scenario_json``, the controller ``toml``, both ``Scenario.to_dict()`` as JSON);
    :class:`ScenarioError` if there is none."""
    meta = log_metadata(path).get("scenario", {})
    text = meta.get("scenario_json") or meta.get("toml")
    if not text:
        raise ScenarioError("scenario", f"{path} has no scenario metadata: pass --scenario NAME")
    data = json.loads(text)
    data.pop("source", None)
    return scenario_from_dict(data, source=f"{path} (metadata)")


def load_flight(run_path: str | Path, scenario: Scenario | None = None,
                ctl_path: str | Path | None = None) -> tuple[FlightLog, Scenario]:
    """The flight of a vehicle log as ``report``, ``inspect`` and ``demo`` all see it:
    scenario from the log unless given, the controller's log from ``ctl_path`` or
    ``ctl.mcap`` next to it, the requested duration from the ``run`` metadata."""
    run_path = Path(run_path)
    sc = scenario if scenario is not None else scenario_from_log(run_path)
    ctl = Path(ctl_path) if ctl_path else run_path.with_name("ctl.mcap")
    log = flight_log_from_mcap(run_path, sc, ctl if ctl.exists() and ctl != run_path else None)
    duration = log_metadata(run_path).get("run", {}).get("duration_s")
    if duration is not None:
        log.duration_s = float(duration)
    return log, sc
