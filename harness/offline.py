"""Fly a scenario in-process: the sitl simulator ↔ the flight computer, no network.

The controller runs at ``control_hz`` with a zero-order hold on the sitl physics, seeing the
measured state (with the scenario's sensor noise). How it learns about the attack is chosen
by ``attack_info`` (:class:`~tfl_mav.flight_computer.FlightComputer`): ``"oracle"`` (the
paper's assumption: told which rotor once the attack starts, thrust from its rpm) or
``"detector"`` (found from ESC rpm, as the daemon does).
"""

from __future__ import annotations

import math
import re
import time
from collections.abc import Callable

import numpy as np

from sitl.simulator import Simulator
from tfl_mav.airframe import mix
from tfl_mav.flight_computer import FlightComputer
from tfl_mav.flightlog.flight import FlightLog
from tfl_mav.geometry import yaw_from_quaternion
from tfl_mav.scenario import Scenario

__all__ = ["DETECTION_EVENT", "detections", "fly_offline"]

# The event a detector alarm leaves in ``FlightLog.events`` (rotor 1-4, sim time in s).
DETECTION_EVENT = "attack detected on rotor {rotor}"
_DETECTION_RE = re.compile(r"^attack detected on rotor (\d)$")


def detections(log: FlightLog) -> list[tuple[float, int]]:
    """The detector's alarms of an offline flight as (sim time s, rotor 1-4), in order."""
    out = []
    for t_s, text in log.events:
        if match := _DETECTION_RE.match(text):
            out.append((t_s, int(match.group(1))))
    return out


def fly_offline(sc: Scenario, *, attack_info: str = "oracle",
                progress: Callable[[float, float], None] | None = None,
                duration_s: float | None = None,
                hook: Callable[[Simulator], None] | None = None) -> FlightLog:
    """Fly ``sc`` and return its :class:`FlightLog` (finished, arrays).

    ``hook(sim)`` is called before every control tick (benches use it to inject failures
    mid-flight, as MAV_CMD_INJECT_FAILURE does on the link).
    """
    fc = FlightComputer(sc, attack_info=attack_info)
    sim = Simulator(sc)
    ctrl = fc.controller
    v = sc.vehicle
    log = FlightLog(thrust_max_n=v.thrust_max_n, attack_rotor=sc.attack.rotor,
                    attack_start_s=sc.attack.start_s if sc.attack.rotor else math.nan)
    log.path_points_m = ctrl.tracker.path.sample(400)
    duration = sc.run.duration_s if duration_s is None else duration_s
    n_ticks = round(duration / sim.control_dt_s)
    yaw_prev = None
    yaw_unwrapped = 0.0
    applied = list(sim.rotor_commands_n)
    t0 = time.perf_counter()
    next_progress = 0.0
    detected: list[int] = []
    for _ in range(n_ticks):
        if hook is not None:
            hook(sim)
        att = sim.attack
        if attack_info == "oracle":
            fc.tell_attack(att.rotor)
        res = fc.step(sim.time_s, sim.measured, sim.measured_rpm(), applied)
        if res.new_detection:
            log.events.append((fc.detection_time_s,
                               DETECTION_EVENT.format(rotor=fc.detected_rotor)))
        out = res.law
        for text in res.events:
            log.events.append((sim.time_s, text))
        sim.set_command(res.thrust_n)
        applied = list(sim.rotor_commands_n)
        x = sim.state_vector
        yaw = yaw_from_quaternion(x[6:10])
        if yaw_prev is not None:
            yaw_unwrapped += math.remainder(yaw - yaw_prev, math.tau)
        else:
            yaw_unwrapped = yaw
        yaw_prev = yaw
        true_f = sim.rotor_thrusts_n
        uf, tp, tq, tr = mix(sim.params, true_f)
        log.append_row((   # SERIES order
            sim.time_s, x[0:3], x[3:6], x[10:13], yaw_unwrapped, out.path_distance_m,
            res.thrust_n,
            res.thrust_requested_n if res.thrust_requested_n is not None else res.thrust_n,
            true_f, att.applied_n if att.rotor else 0.0, res.attack_estimate_n, uf,
            (tp, tq, tr), any(out.saturated), int(out.mode)))
        detected.append(fc.detected_rotor)
        sim.step_control_period()
        reason = sim.crash_reason()
        if reason:
            log.crashed, log.crash_reason = True, reason
            break
        if progress and sim.time_s >= next_progress:
            progress(sim.time_s, duration)
            next_progress += 1.0
    log.wall_time_s = time.perf_counter() - t0
    log.duration_s = duration
    if attack_info == "detector":
        log.detected_rotor = np.asarray(detected, dtype=int)
    log.events.append((0.0, f"fallbacks: {ctrl.fallback_count}, "
                            f"saturated ticks: {ctrl.saturation_count}"))
    return log.finish()
