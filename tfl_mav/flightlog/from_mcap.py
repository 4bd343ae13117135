"""Rebuild a :class:`~tfl_mav.flightlog.flight.FlightLog` from the MCAP files of a flight.

The vehicle's log (``run.mcap``) holds the ground truth (``/sim/truth/state``: the rigid
body, the true rotor thrusts and the attack, one message a tick; older files had the
thrusts and the attack on ``/sim/truth/thrusts``, ``/sim/truth/attack``) and every MAVLink
frame; the controller's
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

from tfl_mav.build import scenario_path
from tfl_mav.flightlog.flight import FlightLog
from tfl_mav.flightlog.logread import LogReader
from tfl_mav.flightlog.pathdist import path_distances
from tfl_mav.model.airframe import mix
from tfl_mav.model.modes import Mode
from tfl_mav.scenario import Scenario, ScenarioError, scenario_from_dict

__all__ = ["TRUTH_TOPICS", "add_truth", "controller_states", "flight_log_from_mcap",
           "load_flight", "log_metadata", "scenario_from_log", "truth_parts"]

_TRUTH = {"/sim/truth/state", "/sim/truth/thrusts", "/sim/truth/attack"}


def controller_states(ctl_path: str | Path) -> dict[int, dict[str, Any]]:
    """``/controller/state`` messages keyed by sim time in µs."""
    out: dict[int, dict[str, Any]] = {}
    for m in LogReader(ctl_path).messages({"/controller/state"}):
        d = m.decode()
        out[round(d["t_s"] * 1e6)] = d
    return out


TRUTH_TOPICS = frozenset(_TRUTH)


def add_truth(truth: dict[int, dict[str, Any]], topic: str, record: dict[str, Any]) -> None:
    """File one decoded ``/sim/truth/*`` record under its tick (sim time in µs), as the
    parts ``state``, ``thrusts`` and ``attack`` (:func:`truth_parts`)."""
    truth.setdefault(round(record["t_s"] * 1e6), {}).update(
        truth_parts(topic, record))


def truth_parts(topic: str, record: dict[str, Any]) -> dict[str, dict[str, Any]]:
    """A ``/sim/truth/*`` record as the parts it holds: ``state`` (t_s, position_m,
    velocity_mps, quaternion_wxyz, body_rates_radps), ``thrusts`` (t_s, thrust_n,
    attack_rotor), ``attack`` (t_s, rotor, active, applied_n, requested_n)."""
    name = topic.rsplit("/", 1)[-1]
    if name != "state" or "thrust_n" not in record:     # an older file's separate part
        return {name: record}
    t, rotor = record["t_s"], record.get("attack_rotor", 0)
    thrusts = {"t_s": t, "attack_rotor": rotor, "thrust_n": record["thrust_n"]}
    attack = {"t_s": t, "rotor": rotor, "active": rotor != 0}
    for key in ("applied_n", "requested_n"):
        if f"attack_{key}" in record:
            attack[key] = record[f"attack_{key}"]
    return {"state": record, "thrusts": thrusts, "attack": attack}


def flight_log_from_mcap(run_path: str | Path, scenario: Scenario,
                         ctl_path: str | Path | None = None,
                         truth: dict[int, dict[str, Any]] | None = None,
                         texts: list[str] | None = None) -> FlightLog:
    """The flight in ``run_path`` (and ``ctl_path``) as a finished FlightLog. ``truth``
    and ``texts``: its truth records (:func:`add_truth`) and ``/log`` texts already read
    (a reader that passes over the file anyway), else they are read here."""
    if truth is None:
        truth, texts = {}, []
        for m in LogReader(run_path).messages(_TRUTH | {"/log"}):
            if m.topic == "/log":
                texts.append(log_texts(m.data))
            else:
                add_truth(truth, m.topic, m.decode())
    crashed = crash_reason(texts or [])
    ctl = controller_states(ctl_path) if ctl_path and Path(ctl_path).exists() else {}
    v = scenario.vehicle
    log = FlightLog(thrust_max_n=v.thrust_max_n, attack_rotor=scenario.attack.rotor,
                    attack_start_s=scenario.attack.start_s if scenario.attack.rotor
                    else math.nan)
    path = scenario_path(scenario)
    log.path_points_m = path.sample(400)
    detected: list[int] = []
    yaw_prev: float | None = None
    yaw_unwrapped = 0.0
    rows = []
    for key in sorted(truth):
        rec = truth[key]
        if not {"state", "thrusts", "attack"} <= rec.keys():
            continue
        st, th, at = rec["state"], rec["thrusts"], rec["attack"]
        # older files left non-finite values out (JSON has no NaN): such a sample has no
        # position/thrust/attack; a diverged one is not plotted
        if not ("position_m" in st and "quaternion_wxyz" in st and "thrust_n" in th
                and "applied_n" in at) or not all(map(math.isfinite, (
                    *st["position_m"], *st["quaternion_wxyz"], *th["thrust_n"],
                    at["applied_n"]))):
            continue
        rows.append((key, st, th, at))
    # the true distance of every sample, as a tracker evaluating each in turn gives it
    distances = path_distances(path, [st["position_m"] for _, st, _, _ in rows])
    for (key, st, th, at), distance in zip(rows, distances, strict=True):
        pos = st["position_m"]
        w, x, y, z = st["quaternion_wxyz"]
        yaw = math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
        yaw_unwrapped = yaw if yaw_prev is None else \
            yaw_unwrapped + math.remainder(yaw - yaw_prev, math.tau)
        yaw_prev = yaw
        c = ctl.get(key, {})
        uf, tp, tq, tr = mix(v, th["thrust_n"])
        est = c.get("attack_estimate_n")
        log.append(t_s=st["t_s"], position_m=pos, velocity_mps=st["velocity_mps"],
                   body_rates_radps=st["body_rates_radps"], yaw_rad=yaw_unwrapped,
                   path_distance_m=distance, thrust_cmd_n=c.get("rotor_thrust_cmd_n",
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
    if crashed:                  # the vehicle said so (flipped, hit the ground, ...)
        log.crashed, log.crash_reason = True, crashed
    return log


def log_metadata(path: str | Path) -> dict[str, dict[str, str]]:
    """The MCAP metadata records of ``path`` (name → key/value map; of an unfinished file,
    those before its first message)."""
    return {md.name: dict(md.metadata) for md in LogReader(path).read_metadata()}


def crash_reason(texts: list[str]) -> str:
    """The vehicle's own word on a crash among its logged texts (its "crashed: ..."
    STATUSTEXT, on ``/log``), or ""."""
    for text in texts:
        at = text.find("crashed: ")
        if at >= 0:
            return text[at + len("crashed: "):]
    return ""


def log_texts(data: bytes) -> str:
    """The text of one ``/log`` message (foxglove.Log, protobuf)."""
    from foxglove_schemas_protobuf.Log_pb2 import Log

    return str(Log.FromString(data).message)


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
                ctl_path: str | Path | None = None,
                truth: dict[int, dict[str, Any]] | None = None,
                texts: list[str] | None = None) -> tuple[FlightLog, Scenario]:
    """The flight of a vehicle log as ``report``, ``inspect`` and ``demo`` all see it:
    scenario from the log unless given, the controller's log from ``ctl_path`` or
    ``ctl.mcap`` next to it, the requested duration from the ``run`` metadata
    (``truth``, ``texts``: as :func:`flight_log_from_mcap`)."""
    run_path = Path(run_path)
    sc = scenario if scenario is not None else scenario_from_log(run_path)
    ctl = Path(ctl_path) if ctl_path else run_path.with_name("ctl.mcap")
    log = flight_log_from_mcap(run_path, sc, ctl if ctl.exists() and ctl != run_path else None,
                               truth, texts)
    meta = log_metadata(run_path)
    duration = meta.get("run", {}).get("duration_s")
    if duration is not None:
        log.duration_s = float(duration)
    wall = meta.get("timeline", {}).get("wall_time_s")     # lockstep logs keep the wall clock
    if wall is not None:
        log.wall_time_s = float(wall)
    return log, sc
