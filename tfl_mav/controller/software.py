"""Flight software that is not ours: a simple controller made into flight software, a guard
around anything user-written, and finding either by name.

:class:`~tfl_mav.controller.flight_computer.FlightComputer` is the flight software tfl-mav ships:
one ``step(t_s, state, rpm, applied_n)`` a control tick, returning a
:class:`~tfl_mav.controller.flight_computer.TickResult`. Everything that flies a vehicle (the
offline runner, the MAVLink daemon) reads that result, so a user's software returns one too;
:func:`tick_result` builds it from the four thrusts and whatever else is known.

* :class:`ControllerSoftware` turns the simpler :class:`~tfl_mav.api.Controller` (``reset``,
  ``update -> 4 thrusts``) into flight software: it runs the project's attack detector on
  the ESC rpm (or the user's, or none), tells the controller what it found, and measures
  the path distance from the state the controller saw.
* :class:`GuardedSoftware` stands between any user-written flight software and the motors:
  an exception, a non-finite thrust or a wrong shape ends the flight as *failed* with one
  line naming the software, and never reaches a motor (the tick holds the applied
  command, in mode FALLBACK).
* :func:`load_flight_software` resolves ``"module:Name"`` (or a built-in name) into a
  factory ``scenario -> flight software``, with one-line errors.
"""

from __future__ import annotations

import importlib
import importlib.util
import inspect
import math
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from tfl_mav.control.detect.detector import DetectorOutput
from tfl_mav.control.safe.recovery import PathProjector
from tfl_mav.control.tfl.law_types import ControlOutput
from tfl_mav.controller.flight_computer import FlightComputer, TickResult
from tfl_mav.from_scenario import build_detector, scenario_path
from tfl_mav.model.modes import Mode
from tfl_mav.model.state import State
from tfl_mav.scenario import Scenario

__all__ = ["BUILTIN_SOFTWARE", "ControllerSoftware", "FlightSoftwareError", "GuardedSoftware",
           "SoftwareFactory", "load_flight_software", "load_object", "software_name",
           "tick_result"]

RPM_TO_RADPS = 2.0 * math.pi / 60.0
_ZERO4 = (0.0, 0.0, 0.0, 0.0)
_MAX_REASON = 200      # characters of an exception's text kept in the one-line reason

SoftwareFactory = Callable[[Scenario], Any]
"""``factory(scenario)`` -> a new flight software for one flight of that scenario."""

# Flight software by short name: the project's law and the baselines (tfl_mav.baselines).
BUILTIN_SOFTWARE: dict[str, str] = {
    "tfl": "tfl_mav.controller.flight_computer:FlightComputer",
    "se3": "tfl_mav.baselines.se3:GeometricController",
    "cascade": "tfl_mav.baselines.cascade:CascadeController",
}


class FlightSoftwareError(ValueError):
    """Bad flight software: an unloadable ``module:Name``, or a result that is not four
    finite thrusts. The message is one line and names the software."""


def tick_result(thrust_n: Sequence[float], *, mode: Mode | int = Mode.NOMINAL,
                path_distance_m: float = math.nan, attack_rotor: int = 0,
                attack_estimate_n: float = math.nan, new_detection: bool = False,
                detection: DetectorOutput | None = None, events: Sequence[str] = (),
                reason: str = "", requested_n: Sequence[float] | None = None) -> TickResult:
    """A :class:`TickResult` for flight software that has no TFL internals.

    ``thrust_n``: the four rotor thrusts to command (N, physical rotor order 1-4);
    ``mode``: :class:`~tfl_mav.model.modes.Mode`; ``path_distance_m``: the distance to the path
    the software measured (NaN: not measured); ``attack_rotor`` 1-4 (0: none known) and its
    thrust estimate (N); ``new_detection``: the detector alarmed on this tick. The TFL
    internals (ξ, η, μ …) are zeros.
    """
    thrust = [float(f) for f in thrust_n]
    total = sum(thrust)
    out = ControlOutput(thrust, Mode(int(mode)), [False] * 4, (_ZERO4, _ZERO4), _ZERO4,
                        (0.0, 0.0), float(path_distance_m), math.nan, math.nan, total,
                        math.nan, (0.0, 0.0), False, reason)
    req = list(thrust) if requested_n is None else [float(f) for f in requested_n]
    return TickResult(thrust, out, detection, int(attack_rotor), float(attack_estimate_n),
                      bool(new_detection), req, tuple(events))


def software_name(obj: Any) -> str:
    """``module:QualifiedName`` of a class, function or instance (for one-line reasons)."""
    target = obj if inspect.isclass(obj) or inspect.isroutine(obj) else type(obj)
    return f"{target.__module__}:{target.__qualname__}"


def _one_line(text: str) -> str:
    line = " ".join(str(text).split())
    return line if len(line) <= _MAX_REASON else line[:_MAX_REASON - 3] + "..."


class ControllerSoftware:
    """A :class:`~tfl_mav.api.Controller` as flight software (:class:`FlightSoftware`).

    Every tick: the detector (``detector="builtin"``: the project's
    :class:`~tfl_mav.control.detect.detector.AttackDetector` on the scenario's motor model; or
    any object with its ``update(t_s, rpm, applied_n)``; None: no detection) sees the ESC
    rpm against the applied command; while it names a rotor, a controller with
    ``set_attack(rotor, estimate_n)`` is told (rotor 1-4 and its thrust from rpm, N; rotor
    0 once the attack is over). Then ``controller.update(t_s, state, rpm)`` gives the four
    thrusts (N). The mode is the controller's ``mode`` attribute when it has one, else
    ATTACKED while a rotor is known and NOMINAL otherwise. The path distance is measured
    from ``state`` (the closest point of the scenario's path).

    With an oracle (``tell_attack``, offline only) the rotor is told instead of detected
    and its thrust read from its rpm (f = k_f ω²), as the flight computer does.
    """

    def __init__(self, controller: Any, scenario: Scenario, *, detector: Any = "builtin",
                 name: str | None = None) -> None:
        self.controller = controller
        self.name = name or software_name(controller)
        self.scenario = scenario
        controller.reset(scenario)
        self.detector = build_detector(scenario) if detector == "builtin" else detector
        self.k_f = scenario.vehicle.k_f
        self.projector = PathProjector(scenario_path(scenario))
        self._set_attack = getattr(controller, "set_attack", None)
        self._told_rotor = 0
        self.detected_rotor = 0
        self.detection_time_s = math.nan

    def tell_attack(self, rotor: int) -> None:
        """Oracle: rotor 1-4 is attacked from now on (0: none)."""
        self._told_rotor = rotor

    def step(self, t_s: float, state: State, rpm: Sequence[float],
             applied_n: Sequence[float], *, dt_s: float | None = None) -> TickResult:
        """One tick (``dt_s`` is accepted for the daemon and not used: the controller keeps
        its own time from ``t_s``)."""
        events: list[str] = []
        rotor, estimate, new, detection = 0, math.nan, False, None
        det = self.detector
        if det is not None:
            raw = det.update(t_s, rpm, applied_n)
            detection = _detector_output(raw)
            if detection.released:
                self.detected_rotor = 0
                events.append("rotor obeys its commands again: attack over")
                if self._set_attack is not None:
                    self._set_attack(0, math.nan)
            rotor, estimate = detection.detected_rotor, detection.estimate_n
            if rotor and detection.alarm:
                new = True
                self.detected_rotor = rotor
                self.detection_time_s = detection.detection_time_s
        elif self._told_rotor:
            rotor = self._told_rotor
            w = rpm[rotor - 1] * RPM_TO_RADPS
            estimate = self.k_f * w * w
        if rotor and self._set_attack is not None:
            self._set_attack(rotor, estimate)
        thrust = self.controller.update(t_s, state, rpm)
        thrust = _four_thrusts(thrust)
        proj = self.projector.project(tuple(state.position_m))
        dist = proj[3] if proj is not None else math.nan
        mode = getattr(self.controller, "mode", None)
        if mode is None:
            mode = Mode.ATTACKED if rotor else Mode.NOMINAL
        return tick_result(thrust, mode=mode, path_distance_m=dist, attack_rotor=rotor,
                           attack_estimate_n=estimate, new_detection=new,
                           detection=detection, events=events)


def _detector_output(raw: Any) -> DetectorOutput:
    """A user detector's answer as the project's :class:`DetectorOutput` (the daemon and
    the recorder read its fields)."""
    if isinstance(raw, DetectorOutput):
        return raw
    rotor = int(getattr(raw, "detected_rotor", 0) or 0)
    if not 0 <= rotor <= 4:
        raise FlightSoftwareError(f"detector returned detected_rotor = {rotor} (not 0-4)")
    return DetectorOutput(
        rotor, float(getattr(raw, "estimate_n", math.nan)),
        tuple(getattr(raw, "residuals_n", ())), tuple(getattr(raw, "cusum", ())),
        float(getattr(raw, "detection_time_s", math.nan)), bool(getattr(raw, "alarm", False)),
        int(getattr(raw, "rejected_samples", 0)), bool(getattr(raw, "released", False)))


def _four_thrusts(value: Any) -> list[float]:
    """Four finite floats from what a controller returned, else FlightSoftwareError
    saying what it was."""
    try:
        values = [float(f) for f in value]
    except (TypeError, ValueError):
        raise FlightSoftwareError(f"returned {type(value).__name__} {_one_line(repr(value))}"
                                  ", expected 4 rotor thrusts (N)") from None
    if len(values) != 4:
        raise FlightSoftwareError(f"returned {len(values)} thrusts, expected 4 (N, rotors 1-4)")
    bad = [i for i, f in enumerate(values) if not math.isfinite(f)]
    if bad:
        i = bad[0]
        raise FlightSoftwareError(f"returned a non-finite thrust for rotor {i + 1} "
                                  f"({values[i]})")
    return values


class GuardedSoftware:
    """Any flight software, guarded: what it returns reaches the motors only as four finite
    thrusts, clamped to [0, f_max] (what it asked stays in ``thrust_requested_n``).

    An exception, a non-finite value or a wrong shape *fails* the flight: ``failure_reason``
    becomes one line naming the software and what it did, ``on_failure(reason)`` is called
    once, and this tick and every later one hold the applied command (mode FALLBACK) — the
    offline runner stops there (``stop``), the daemon ends the run. ``step`` may return a
    :class:`TickResult`, any object with ``thrust_n`` (and optionally ``mode``,
    ``path_distance_m``, ``attack_rotor``, ``attack_estimate_n``), or the four thrusts.
    Other attributes (``detected_rotor``, ``tell_attack`` …) are the wrapped software's.
    """

    def __init__(self, software: Any, *, name: str | None = None, thrust_max_n: float,
                 on_failure: Callable[[str], None] | None = None) -> None:
        self.software = software
        self.name = name or getattr(software, "name", None) or software_name(software)
        self.thrust_max_n = float(thrust_max_n)
        self.on_failure = on_failure
        self.failure_reason: str | None = None
        step = software.step
        try:
            params = inspect.signature(step).parameters
            self._takes_dt = "dt_s" in params or any(
                p.kind is inspect.Parameter.VAR_KEYWORD for p in params.values())
        except (TypeError, ValueError):
            self._takes_dt = False
        self._step = step

    def __getattr__(self, name: str) -> Any:
        # only for attributes this class does not have: the wrapped software's
        if name == "software":
            raise AttributeError(name)
        return getattr(self.software, name)

    @property
    def detected_rotor(self) -> int:
        return int(getattr(self.software, "detected_rotor", 0) or 0)

    @property
    def detection_time_s(self) -> float:
        return float(getattr(self.software, "detection_time_s", math.nan))

    def failed(self) -> bool:
        return self.failure_reason is not None

    def step(self, t_s: float, state: State, rpm: Sequence[float],
             applied_n: Sequence[float], *, dt_s: float | None = None) -> TickResult:
        if self.failure_reason is not None:
            return self._hold(applied_n, self.failure_reason)
        try:
            if dt_s is not None and self._takes_dt:
                res = self._step(t_s, state, rpm, applied_n, dt_s=dt_s)
            else:
                res = self._step(t_s, state, rpm, applied_n)
            res = self._checked(res)
        except FlightSoftwareError as exc:
            return self._fail(t_s, str(exc), applied_n)
        except Exception as exc:  # a user's bug of any kind fails its flight, not ours
            return self._fail(t_s, f"raised {type(exc).__name__}: {exc}", applied_n)
        return res

    def _checked(self, res: Any) -> TickResult:
        if isinstance(res, TickResult):
            thrust = _four_thrusts(res.thrust_n)
        elif hasattr(res, "thrust_n"):
            thrust = _four_thrusts(res.thrust_n)
            res = tick_result(thrust, mode=getattr(res, "mode", Mode.NOMINAL),
                              path_distance_m=getattr(res, "path_distance_m", math.nan),
                              attack_rotor=getattr(res, "attack_rotor", 0),
                              attack_estimate_n=getattr(res, "attack_estimate_n", math.nan))
        else:
            thrust = _four_thrusts(res)
            res = tick_result(thrust)
        fmax = self.thrust_max_n
        clamped = [min(max(f, 0.0), fmax) for f in thrust]
        if clamped != res.thrust_n:
            res = res._replace(thrust_n=clamped,
                               thrust_requested_n=res.thrust_requested_n or thrust)
        return res

    def _fail(self, t_s: float, why: str, applied_n: Sequence[float]) -> TickResult:
        self.failure_reason = f"{self.name} failed at t = {t_s:.3f} s: {_one_line(why)}"
        if self.on_failure is not None:
            self.on_failure(self.failure_reason)
        return self._hold(applied_n, self.failure_reason)

    def _hold(self, applied_n: Sequence[float], why: str) -> TickResult:
        fmax = self.thrust_max_n
        hold = [min(max(float(f), 0.0), fmax) if math.isfinite(f) else 0.0 for f in applied_n]
        return tick_result(hold, mode=Mode.FALLBACK, reason=why, events=(why,))


def load_object(spec: str) -> Any:
    """The class or function ``spec`` names: a built-in name (:data:`BUILTIN_SOFTWARE`),
    ``module:Name`` or ``path/to/file.py:Name``; FlightSoftwareError (one line) if it
    cannot be loaded."""
    target = BUILTIN_SOFTWARE.get(spec, spec)
    module_name, sep, attr = target.partition(":")
    if not sep or not module_name or not attr:
        names = ", ".join(BUILTIN_SOFTWARE)
        raise FlightSoftwareError(f"unknown controller {spec!r}: expected one of {names}, "
                                  "MODULE:NAME or FILE.py:NAME")
    try:
        module = (_module_from_file(module_name) if module_name.endswith(".py")
                  else importlib.import_module(module_name))
    except (ImportError, OSError) as exc:
        raise FlightSoftwareError(f"controller {spec!r}: cannot import {module_name!r} "
                                  f"({_one_line(str(exc))})") from None
    except Exception as exc:
        raise FlightSoftwareError(f"controller {spec!r}: importing {module_name!r} raised "
                                  f"{type(exc).__name__}: {_one_line(str(exc))}") from None
    obj: Any = module
    for part in attr.split("."):
        if not hasattr(obj, part):
            raise FlightSoftwareError(f"controller {spec!r}: {module_name!r} has no {attr!r}")
        obj = getattr(obj, part)
    if not callable(obj):
        raise FlightSoftwareError(f"controller {spec!r}: {attr!r} is not a class or function")
    return obj


def load_flight_software(spec: str) -> tuple[str, SoftwareFactory]:
    """``(name, factory)`` for ``spec`` (:func:`load_object`). The class or function is
    called with the scenario if it takes one argument, else with none; what it makes is
    flight software (``step``) or a :class:`~tfl_mav.api.Controller` (``reset`` and
    ``update``, made flight software by :class:`ControllerSoftware`)."""
    obj = load_object(spec)
    name = spec
    if obj is FlightComputer:
        return name, lambda sc: FlightComputer(sc)
    takes_scenario = _takes_one_argument(obj)

    def factory(sc: Scenario) -> Any:
        made = obj(sc) if takes_scenario else obj()
        if hasattr(made, "step"):
            return made
        if hasattr(made, "update") and hasattr(made, "reset"):
            return ControllerSoftware(made, sc, name=name)
        raise FlightSoftwareError(f"controller {spec!r}: made a {type(made).__name__}, which "
                                  "has neither step() (flight software) nor reset() and "
                                  "update() (a controller)")
    return name, factory


def _module_from_file(path: str) -> Any:
    """The Python file ``path`` as a module (a user's controller need not be installed)."""
    file = Path(path)
    if not file.is_file():
        raise ImportError(f"no such file {path!r}")
    name = f"tfl_mav_user_{file.stem}"
    spec = importlib.util.spec_from_file_location(name, file)
    if spec is None or spec.loader is None:
        raise ImportError(f"cannot load {path!r} as Python")
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module          # what pickling and dataclasses look names up in
    spec.loader.exec_module(module)
    return module


def _takes_one_argument(obj: Any) -> bool:
    """Whether ``obj`` is called with the scenario (one required positional parameter)."""
    try:
        params = inspect.signature(obj).parameters.values()
    except (TypeError, ValueError):
        return False
    required = [p for p in params if p.default is inspect.Parameter.empty
                and p.kind in (p.POSITIONAL_ONLY, p.POSITIONAL_OR_KEYWORD)]
    return len(required) >= 1
