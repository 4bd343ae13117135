"""Fly a scenario in-process: the sitl simulator ↔ the flight computer, no network.

The controller runs at ``control_hz`` with a zero-order hold on the sitl physics, seeing the
measured state (with the scenario's sensor noise). How it learns about the attack is chosen
by ``attack_info`` (:class:`~tfl_mav.controller.flight_computer.FlightComputer`): ``"oracle"`` (the
paper's assumption: told which rotor once the attack starts, thrust from its rpm) or
``"detector"`` (found from ESC rpm, as the daemon does).
"""

from __future__ import annotations

import gc
import math
import re
import time
from collections.abc import Callable, Sequence
from itertools import chain
from typing import Any, NamedTuple

import numpy as np

from tfl_mav.controller.flight_computer import FlightComputer
from tfl_mav.flightlog.flight import FlightLog
from tfl_mav.flightlog.pathdist import path_distances
from tfl_mav.from_scenario import scenario_path
from tfl_mav.scenario import Scenario
from tfl_mav.sitl.attacker import AttackSignal
from tfl_mav.sitl.simulator import Simulator
from tfl_mav.sitl.wind import WindField

__all__ = ["ATTACK_MOVE_EVENT", "ATTACK_RELEASE_EVENT", "DETECTION_EVENT", "TickRow", "detections",
           "fly_offline"]

# The event a detector alarm leaves in ``FlightLog.events`` (rotor 1-4, sim time in s).
DETECTION_EVENT = "attack detected on rotor {rotor}"
_DETECTION_RE = re.compile(r"^attack detected on rotor (\d)$")
# The events an attack schedule ([[attack.phases]]) leaves: where the attacker went, when.
ATTACK_MOVE_EVENT = "attacker seizes rotor {rotor}"
ATTACK_RELEASE_EVENT = "attacker lets go"


class TickRow(NamedTuple):
    """One control tick of an offline flight, as the loop records it (the log's series are
    built from the rows after the flight, :func:`_fill`)."""

    t_s: float                              # sim time of the tick (s)
    state: Sequence[float]                  # the true state, 13 floats (paper frame)
    thrust_cmd_n: Sequence[float]           # the four commanded thrusts (N)
    thrust_req_n: Sequence[float]           # what the law asked before the allocator (N)
    thrust_true_n: Sequence[float]          # the rotors' true thrusts (N)
    attack_true_n: float                    # the attacked rotor's thrust (N; 0: none)
    attack_estimate_n: float                # the flight software's estimate of it (N)
    path_distance_m: float                  # the software's distance to the path (m)
    saturated: bool                         # any thrust at its bound
    mode: int                               # the law flying (Mode)
    detected_rotor: int                     # the detector's verdict (0: none)


_row = tuple.__new__      # a TickRow from a plain tuple: no generated __new__ call a tick


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
                hook: Callable[[Simulator], None] | None = None,
                flight_software: Any = None,
                attack_signal: AttackSignal | None = None,
                stop: Callable[[], bool] | None = None) -> FlightLog:
    """Fly ``sc`` and return its :class:`FlightLog` (finished, arrays).

    ``hook(sim)`` is called before every control tick (benches use it to inject failures
    mid-flight, as MAV_CMD_INJECT_FAILURE does on the link).

    ``flight_software``: fly this instead of a new :class:`FlightComputer` (anything with
    its ``step`` returning a :class:`~tfl_mav.controller.flight_computer.TickResult` and its
    ``detected_rotor``/``detection_time_s``; told the attack with an oracle only if it has
    ``tell_attack``). ``attack_signal(t_s, x)``: the attacked rotor's thrust instead of the
    scenario's signal (:meth:`~tfl_mav.sitl.attacker.Attacker.use_signal`). ``stop()``: asked after
    every control decision; True ends the flight before that command reaches the motors
    (``log.interrupted``). Without them the flight is exactly the scenario's.
    """
    ctrl: Any = None
    if flight_software is None:
        # No deadline here: the safe law designs its gains when first met (the same gains).
        fc = FlightComputer(sc, attack_info=attack_info, design_gains=False)
        ctrl = fc.controller
    else:
        fc = flight_software
    sim = Simulator(sc, attack_signal=attack_signal)
    # the attack expression leaving its domain mid-flight is said (an event), not silent
    sim.attacker.on_nonfinite = lambda t_s, text: log.events.append((t_s, text))
    v = sc.vehicle
    first = sim.attacker.moves[0] if sim.attacker.moves else (sc.attack.start_s,
                                                               sc.attack.rotor)
    log = FlightLog(thrust_max_n=v.thrust_max_n, attack_rotor=sc.attack.first_rotor,
                    attack_start_s=first[0] if sc.attack.first_rotor else math.nan)
    log.path_points_m = (ctrl.tracker.path if ctrl is not None
                         else scenario_path(sc)).sample(400)
    duration = sc.run.duration_s if duration_s is None else duration_s
    n_ticks = round(duration / sim.control_dt_s)
    applied = sim.rotor_commands_n    # replaced (never changed in place) by set_command
    oracle = attack_info == "oracle" and hasattr(fc, "tell_attack")
    rows: list[TickRow] = []     # one per tick; the series are built at the end (_fill)
    events = log.events
    append = rows.append
    fc_step, set_command = fc.step, sim.set_command
    step_period, crash_reason = sim.step_control_period, sim.crash_reason
    t0 = time.perf_counter()
    next_progress = 0.0
    # The loop makes no reference cycles (measured: a 20 s flight leaves none; refcounting
    # frees each tick's garbage), so the cyclic collector would only rescan the growing
    # rows, ~60 ms of a 20 s paper flight: off for the loop and for building the log from
    # the rows (its allocations would set it scanning them again: 1-3 µs a tick more).
    gc_was_enabled = gc.isenabled()
    gc.disable()
    try:
        for _ in range(n_ticks):
            if hook is not None:
                hook(sim)
            att = sim.attack
            if oracle:
                fc.tell_attack(att.rotor)
            t_s = sim.time_s
            thrust, out, _, _, estimate, new, req, tick_events = fc_step(
                t_s, sim.measured_floats, sim.measured_rpm_floats, applied)
            if stop is not None and stop():
                log.interrupted = True
                break
            if new:
                events.append((fc.detection_time_s,
                               DETECTION_EVENT.format(rotor=fc.detected_rotor)))
            for text in tick_events:
                events.append((t_s, text))
            set_command(thrust)
            applied = sim.rotor_commands_n
            append(_row(TickRow, (t_s, sim.state_vector, thrust,
                                  thrust if req is None else req, sim.rotor_thrusts_n,
                                  att.applied_n if att.rotor else 0.0, estimate,
                                  out.path_distance_m, any(out.saturated), int(out.mode),
                                  fc.detected_rotor)))
            step_period()
            reason = crash_reason()
            if reason:
                log.crashed, log.crash_reason = True, reason
                break
            if progress and sim.time_s >= next_progress:
                progress(sim.time_s, duration)
                next_progress += 1.0
        _fill(log, rows, sim, detector=attack_info == "detector")
        if sc.attack.phases:      # the schedule's moves, among the detector's verdicts
            end_s = sim.time_s
            log.events.extend((t, ATTACK_MOVE_EVENT.format(rotor=r) if r else ATTACK_RELEASE_EVENT)
                              for t, r in sim.attacker.moves if t <= end_s)
            log.events.sort(key=lambda e: e[0])
    finally:
        if gc_was_enabled:
            gc.enable()
    log.wall_time_s = time.perf_counter() - t0
    log.duration_s = duration
    if ctrl is not None:
        log.events.append((0.0, f"fallbacks: {ctrl.fallback_count}, "
                                f"saturated ticks: {ctrl.saturation_count}"))
    return log.finish()


def _fill(log: FlightLog, rows: list[TickRow], sim: Simulator, *,
          detector: bool) -> None:
    """The per-tick rows → the log's series (:data:`~tfl_mav.flightlog.flight.SERIES`).

    Done once after the flight so the loop appends one row a tick: the unwrapped yaw
    (ψ from the true quaternion, eq. (1)) and the true wrench (eq. (4)) are computed here, by
    the same float operations in the same order as per tick, so the values are identical.
    """
    if detector:
        log.detected_rotor = np.asarray([r.detected_rotor for r in rows], dtype=int)
    if not rows:
        return
    cols = TickRow._make(zip(*rows, strict=True))  # a column of the rows per field
    n = len(rows)
    x = _matrix(cols.state, 13)                    # (N, 13) true state, paper frame
    yaw_rad = []
    yaw_prev = None
    unwrapped = 0.0
    atan2, remainder, tau = math.atan2, math.remainder, math.tau
    for s in cols.state:
        # ψ = yaw_from_quaternion(q), written out (the same operations): 20 000 a flight
        w, qx, qy, qz = s[6], s[7], s[8], s[9]
        yaw = atan2(2 * (w * qz + qx * qy), 1 - 2 * (qy * qy + qz * qz))
        unwrapped = yaw if yaw_prev is None else unwrapped + remainder(yaw - yaw_prev, tau)
        yaw_prev = yaw
        yaw_rad.append(unwrapped)
    f = _matrix(cols.thrust_true_n, 4)             # (N, 4) true rotor thrusts
    f1, f2, f3, f4 = f.T
    ell, d = sim.params.arm_m, sim.params.drag_thrust_ratio_m
    data = log.data
    for key, value in (
            ("t_s", np.fromiter(cols.t_s, float, n)), ("position_m", x[:, 0:3]),
            ("velocity_mps", x[:, 3:6]), ("quaternion_wxyz", x[:, 6:10]),
            ("body_rates_radps", x[:, 10:13]), ("yaw_rad", yaw_rad),
            ("path_distance_m", np.fromiter(cols.path_distance_m, float, n)),
            ("thrust_cmd_n", _matrix(cols.thrust_cmd_n, 4)),
            ("thrust_req_n", _matrix(cols.thrust_req_n, 4)),
            ("thrust_true_n", f), ("attack_true_n", np.fromiter(cols.attack_true_n, float, n)),
            ("attack_estimate_n", np.fromiter(cols.attack_estimate_n, float, n)),
            ("uf_n", f1 + f2 + f3 + f4),
            ("torque_nm", np.stack([ell * (f4 - f2), ell * (f3 - f1), d * (f1 - f2 + f3 - f4)],
                                   axis=1)),
            ("saturated", np.fromiter(cols.saturated, float, n)),
            ("mode", np.fromiter(cols.mode, float, n))):
        data[key] = np.ascontiguousarray(value, dtype=float)
    if sim.estimator is not None:
        # The controller flew on the onboard estimate: its distance is the estimate's. The
        # log's is the truth's (as a flight log's /sim/truth/path_distance), the
        # controller's kept beside it.
        data["path_distance_estimated_m"] = data["path_distance_m"]
        data["path_distance_m"] = np.asarray(
            path_distances(scenario_path(sim.scenario), x[:, 0:3].tolist()), dtype=float)
    if sim.wind is not None:
        # The air does not depend on the flight: the same field replayed at the ticks' steps
        # (no per-tick cost), the wind each tick's true state met.
        sc = sim.scenario
        air = WindField(sc.wind, sc.run.seed, sim.physics_dt_s)
        data["wind_mps"] = air.series(np.arange(n) * sim.steps_per_control)


def _matrix(rows: tuple[Sequence[float], ...], width: int) -> np.ndarray:
    """(N, width) floats from N rows: one flat pass (``np.array`` of a tuple of lists looks
    at every row as a sequence first, several times slower; the same values)."""
    return np.fromiter(chain.from_iterable(rows), float, len(rows) * width).reshape(-1, width)
