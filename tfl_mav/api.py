"""tfl-mav's public API: fly your own controller, detector or attack — the one import needed.

::

    from tfl_mav.api import Environment

    arrays = Environment("paper").fly(duration_s=10.0)        # the TFL law, attack from rpm
    print(arrays.path_distance_m[-1], arrays.crashed)

Four protocols say what a part must do (structural: no base class to inherit):

* :class:`FlightSoftware` — everything between the sensors and the motors, one
  ``step(t_s, state, rpm, applied_n) -> TickResult`` a control tick. The project's
  :class:`~tfl_mav.controller.flight_computer.FlightComputer` is one.
* :class:`Controller` — the simpler form: ``reset(scenario)`` and
  ``update(t_s, state, rpm) -> 4 thrusts (N)``; :class:`ControllerSoftware` makes it flight
  software (with the project's attack detector, or yours).
* :class:`Detector` — ``update(t_s, rpm, applied_n)`` -> which rotor is attacked.
* :class:`Attack` — ``thrust_n(t_s, state) -> float``: the thrust the attacker forces on
  its ``rotor`` from ``start_s``.

:class:`Environment` flies any of them offline on the lockstep simulator and returns
:class:`FlightArrays`; ``tfl-mav fly --controller module:Name`` serves the same flight
software to a vehicle over MAVLink. Templates: docs/api.md; docs/examples/.

Frames and units (everywhere): the paper frame — inertial x, y, z with z **up**, body
front-left-up; SI units, named in every field (``_m``, ``_mps``, ``_radps``, ``_n``).
Rotors 1-4 in physical order: 1 front (+b1), 2 right (−b2), 3 back, 4 left.
"""

from __future__ import annotations

import inspect
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable

import numpy as np

from tfl_mav.control.safe.recovery import PathProjector
from tfl_mav.controller.flight_computer import FlightComputer, TickResult
from tfl_mav.controller.software import (
    ControllerSoftware,
    FlightSoftwareError,
    GuardedSoftware,
    load_flight_software,
    load_object,
    software_name,
    tick_result,
)
from tfl_mav.flightlog.metrics import detection_events, law_report
from tfl_mav.from_scenario import scenario_path
from tfl_mav.model.modes import Mode
from tfl_mav.model.state import State
from tfl_mav.scenario import Scenario, ScenarioError, apply_overrides, load_scenario

__all__ = ["Attack", "AttackSignal", "Controller", "ControllerSoftware", "Detection", "Detector",
           "Environment", "FlightArrays", "FlightSoftware", "FlightSoftwareError",
           "GuardedSoftware", "Mode", "Scenario", "ScenarioError", "State", "TickResult",
           "apply_overrides", "load_flight_software", "load_object", "load_scenario",
           "path_distance_m", "tick_result", "with_attack"]


@runtime_checkable
class FlightSoftware(Protocol):
    """Sensors in, rotor thrusts out, one control tick at a time.

    ``step(t_s, state, rpm, applied_n)``: ``t_s`` sim time (s) of ``state`` (the measured
    :class:`State`, paper frame); ``rpm`` the four ESC speeds (rpm) at that time;
    ``applied_n`` the four thrust commands (N) the motors held over the period that ended
    at ``t_s`` (what the rpm answer to). Returns a :class:`TickResult` (build one with
    :func:`tick_result`): at least ``thrust_n`` (4 thrusts, N, rotors 1-4), the mode and
    the attacked rotor it knows of (0: none). ``detected_rotor`` (0-4) and
    ``detection_time_s`` (s; NaN before) say what it found. The daemon may pass
    ``dt_s=`` (the real time since the last tick when states were skipped) to software
    whose ``step`` accepts it.
    """

    detected_rotor: int
    detection_time_s: float

    def step(self, t_s: float, state: State, rpm: Sequence[float],
             applied_n: Sequence[float]) -> TickResult: ...


@runtime_checkable
class Controller(Protocol):
    """The simple form of flight software (made one by :class:`ControllerSoftware`).

    ``reset(scenario)`` before each flight (the scenario: the vehicle, path, rates — the
    controller may read anything in it, and should not read the true mass it is meant not
    to know; ``scenario.controller.model_mass_scale`` says by how much its model is off).
    ``update(t_s, state, rpm)`` -> the four rotor thrusts (N, rotors 1-4; clamped to
    [0, f_max] before the motors). Optional: ``set_attack(rotor, estimate_n)`` is called
    every tick while the detector names a rotor (1-4, thrust from its rpm in N; rotor 0
    once it is over), and a ``mode`` attribute (:class:`Mode`) is logged when present.
    """

    def reset(self, scenario: Scenario) -> None: ...

    def update(self, t_s: float, state: State, rpm: Sequence[float]) -> Sequence[float]: ...


class Detection(Protocol):
    """What a :class:`Detector` answers each tick (the project's
    :class:`~tfl_mav.control.detect.detector.DetectorOutput` is one)."""

    detected_rotor: int          # 0: none, else 1-4 (stays set while the attack lasts)
    estimate_n: float            # the attacked rotor's thrust (N), NaN if unknown
    alarm: bool                  # True on the tick of detection only
    detection_time_s: float      # time of the alarm (s), NaN before


@runtime_checkable
class Detector(Protocol):
    """Finds the attacked rotor: ``update(t_s, rpm, applied_n) -> Detection`` every tick,
    from the ESC ``rpm`` against the commands ``applied_n`` (N) the motors held."""

    def update(self, time_s: float, rpm_measured: Sequence[float],
               thrust_cmd_n: Sequence[float]) -> Detection: ...


@runtime_checkable
class Attack(Protocol):
    """The attacker's thrust on one rotor: ``thrust_n(t_s, state) -> N`` with ``state`` the
    *true* state (paper frame), evaluated every physics step from ``start_s`` on; clamped to
    [0, f_max]. ``rotor`` (1-4) and ``start_s`` (s) default to the scenario's ``[attack]``
    when the object has none. A raised exception or a non-finite value fails the flight."""

    def thrust_n(self, t_s: float, state: State) -> float: ...


@dataclass(frozen=True, eq=False)
class FlightArrays:
    """One flight as arrays, one row per control tick (N rows; paper frame, SI units).

    ``t_s`` (N,) sim time; ``position_m``, ``velocity_mps`` (N, 3) and ``quaternion_wxyz``
    (N, 4; body FLU → inertial) and ``body_rates_radps`` (N, 3; p, q, r) are the *true*
    state; ``thrust_cmd_n`` (N, 4) what went to the motors, ``thrust_true_n`` (N, 4) what
    the rotors made, ``attack_true_n`` (N,) the attacked rotor's thrust (0: none);
    ``mode`` (N,) :class:`Mode` values; ``detected_rotor`` (N,) the software's detection
    (0: none); ``path_distance_m`` (N,) the true distance to the path's closest point,
    computed after the flight the same way for every flight software (so comparable),
    ``software_distance_m`` (N,) the distance the software itself reported (NaN: none).
    ``crashed``/``crash_reason``: the vehicle crashed; ``failure_reason``: the software
    or the attack failed (one line, None when not) and the flight ended there.
    """

    t_s: np.ndarray
    position_m: np.ndarray
    quaternion_wxyz: np.ndarray
    velocity_mps: np.ndarray
    body_rates_radps: np.ndarray
    thrust_cmd_n: np.ndarray
    thrust_true_n: np.ndarray
    attack_true_n: np.ndarray
    mode: np.ndarray
    detected_rotor: np.ndarray
    path_distance_m: np.ndarray
    software_distance_m: np.ndarray
    crashed: bool
    crash_reason: str
    failure_reason: str | None
    software: str
    attack_rotor: int
    attack_start_s: float
    detection_time_s: float
    events: tuple[tuple[float, str], ...] = ()
    log: Any = field(default=None, repr=False)   # the FlightLog behind it (summaries, plots)
    time_in_law_s: dict[str, float] = field(default_factory=dict)   # tfl, recovery, …
    law_switches: int = 0                  # switches between TFL and the safe law
    detections: tuple[tuple[float, int], ...] = ()   # every detection (time s, rotor 1-4)
    releases: tuple[tuple[float, int], ...] = ()     # every release (time s, rotor 1-4)

    @property
    def failed(self) -> bool:
        return self.failure_reason is not None


def path_distance_m(scenario: Scenario, position_m: np.ndarray) -> np.ndarray:
    """True distance (m) of each position (N, 3; paper frame) to the closest point of the
    scenario's path; NaN where no closest point is found (a diverged state)."""
    projector = PathProjector(scenario_path(scenario))
    out = np.full(len(position_m), math.nan)
    for i, p in enumerate(np.asarray(position_m, dtype=float).tolist()):
        if not all(math.isfinite(c) for c in p):
            projector.forget()          # a fresh global search once it is back
            continue
        proj = projector.project(p)
        if proj is not None:
            out[i] = proj[3]
    return out


def with_attack(sc: Scenario, attack: Any) -> Scenario:
    """``sc`` with the rotor and start time of ``attack`` (an :class:`Attack`; its own
    ``rotor``/``start_s``, else the scenario's); ``sc`` itself for None. TypeError or
    ScenarioError (one line) for an attack that cannot be flown."""
    if attack is None:
        return sc
    if not callable(getattr(attack, "thrust_n", None)):
        raise TypeError(f"attack: {software_name(attack)} has no thrust_n(t_s, state)")
    rotor = int(getattr(attack, "rotor", sc.attack.rotor))
    start = float(getattr(attack, "start_s", sc.attack.start_s))
    if not 1 <= rotor <= 4:
        raise ScenarioError("attack.rotor", f"the attack needs a rotor 1-4, got {rotor}"
                            " (give the attack a rotor attribute or set attack.rotor)")
    return sc.replace(**{"attack.rotor": rotor, "attack.start_s": start})


class AttackSignal:
    """An :class:`Attack` as the simulator's signal ``(t_s, x13) -> N``, guarded like flight
    software: its first exception or non-finite value is its ``failure_reason``."""

    def __init__(self, attack: Any, name: str) -> None:
        self.attack = attack
        self.name = name
        self.failure_reason: str | None = None

    def __call__(self, t_s: float, x: Sequence[float]) -> float:
        if self.failure_reason is not None:
            return math.nan
        state = State(x[0:3], x[3:6], x[6:10], x[10:13], round(t_s * 1e6))
        try:
            value = float(self.attack.thrust_n(t_s, state))
        except Exception as exc:  # a user's bug of any kind fails its flight, not ours
            why = f"raised {type(exc).__name__}: {exc}"
        else:
            if math.isfinite(value):
                return value
            why = f"returned a non-finite thrust ({value})"
        self.failure_reason = f"attack {self.name} failed at t = {t_s:.3f} s: " + \
            " ".join(why.split())[:200]
        return math.nan


class Environment:
    """A vehicle, a path, flight software and an attack, flown offline (lockstep, in process).

    ``scenario``: a :class:`Scenario`, or a built-in name / ``.toml`` path (``settings``:
    ``SECTION.KEY=VALUE`` overrides as ``--set`` takes them). ``flight_software``: None (the
    project's TFL flight computer), flight software, a :class:`Controller`, or a factory
    ``scenario -> either`` (a class taking the scenario) — a factory or a controller gives a
    fresh flight every :meth:`fly`. ``attack``: an :class:`Attack` replacing the scenario's
    signal (None: the scenario's). ``attack_info``: ``"detector"`` (found from ESC rpm, as
    in flight) or ``"oracle"`` (told, the paper's assumption; software without
    ``tell_attack`` is not told). Same scenario and seed → the same flight, bit for bit.
    """

    def __init__(self, scenario: Scenario | str = "paper", flight_software: Any = None,
                 attack: Any = None, *, attack_info: str = "detector",
                 settings: Sequence[str] = (), name: str | None = None) -> None:
        sc = load_scenario(scenario) if isinstance(scenario, str) else scenario
        sc = with_attack(apply_overrides(sc, list(settings)), attack)
        if attack_info not in ("detector", "oracle"):
            raise ValueError(f"attack_info: must be 'detector' or 'oracle', got {attack_info!r}")
        self.scenario = sc
        self.flight_software = flight_software
        self.attack = attack
        self.attack_info = attack_info
        self.name = name or ("tfl" if flight_software is None else software_name(flight_software))

    def _software(self) -> Any:
        """A flight software for one flight of the scenario (None: the built-in)."""
        fs, sc = self.flight_software, self.scenario
        if fs is None:
            return None
        if fs is FlightComputer:          # the built-in law, told or detecting as asked
            return FlightComputer(sc, attack_info=self.attack_info)
        if inspect.isclass(fs) or (callable(fs) and not hasattr(fs, "step")
                                   and not hasattr(fs, "update")):
            fs = fs(sc)                                    # a class or factory
        if hasattr(fs, "step"):
            return fs
        if hasattr(fs, "update") and hasattr(fs, "reset"):
            return ControllerSoftware(fs, sc, name=self.name,
                                      detector="builtin" if self.attack_info == "detector"
                                      else None)
        raise TypeError(f"flight_software: {software_name(fs)} has neither step() (flight "
                        "software) nor reset() and update() (a controller)")

    def fly(self, duration_s: float | None = None) -> FlightArrays:
        """Fly the scenario for ``duration_s`` (s; None: its ``run.duration_s``)."""
        from tfl_mav.offline import fly_offline

        sc = self.scenario
        software = self._software()
        guard = None if software is None else GuardedSoftware(
            software, name=self.name, thrust_max_n=sc.vehicle.thrust_max_n)
        signal = None if self.attack is None else AttackSignal(self.attack,
                                                               software_name(self.attack))

        def stop() -> bool:
            return (guard is not None and guard.failure_reason is not None) or \
                (signal is not None and signal.failure_reason is not None)

        log = fly_offline(sc, attack_info=self.attack_info, duration_s=duration_s,
                          flight_software=guard, attack_signal=signal,
                          stop=stop if guard is not None or signal is not None else None)
        failure = (signal.failure_reason if signal is not None else None) or \
            (guard.failure_reason if guard is not None else None)
        return _arrays(log, sc, self.name, failure)


def _arrays(log: Any, sc: Scenario, name: str, failure: str | None) -> FlightArrays:
    n = len(log["t_s"])

    def series(key: str, width: int) -> np.ndarray:
        value = log.data.get(key)
        if value is None or len(value) != n or n == 0:
            return np.zeros((n, width)) if width > 1 else np.zeros(n)
        return np.asarray(value, dtype=float)

    detected = (np.asarray(log.detected_rotor, dtype=int) if log.detected_rotor is not None
                and len(log.detected_rotor) == n else np.zeros(n, dtype=int))
    position = series("position_m", 3)
    t = series("t_s", 1)
    laws = law_report(t, series("mode", 1), detected if n else None)
    detections, releases = detection_events(t, detected)
    return FlightArrays(
        t_s=t, position_m=position, quaternion_wxyz=series("quaternion_wxyz", 4),
        velocity_mps=series("velocity_mps", 3), body_rates_radps=series("body_rates_radps", 3),
        thrust_cmd_n=series("thrust_cmd_n", 4), thrust_true_n=series("thrust_true_n", 4),
        attack_true_n=series("attack_true_n", 1), mode=series("mode", 1).astype(int),
        detected_rotor=detected, path_distance_m=path_distance_m(sc, position),
        software_distance_m=series("path_distance_m", 1), crashed=bool(log.crashed),
        crash_reason=log.crash_reason, failure_reason=failure, software=name,
        attack_rotor=sc.attack.rotor,
        attack_start_s=sc.attack.start_s if sc.attack.rotor else math.nan,
        detection_time_s=detections[0][0] if detections else math.nan,
        events=tuple(log.events), log=log, time_in_law_s=laws["time_in_law_s"],
        law_switches=laws["law_switches"], detections=tuple(detections),
        releases=tuple(releases))
