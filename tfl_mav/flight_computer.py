"""The flight computer: one control tick, written once, for every way tfl-mav flies.

``step(t, state, rpm, applied)`` runs the attack detector on the ESC rpm against the command
the vehicle *applied*, switches the TFL law to the attacked rotor when the detector (or an
oracle) says so, evaluates the law and returns the rotor thrusts to send, with the internals
worth logging. The daemon (:mod:`tfl_mav.daemon`) is link ↔ flight computer ↔ recorder; the
offline runner (:mod:`harness.offline`) is simulator ↔ the same flight computer; so a fix to
the tick is a fix everywhere.

How the computer learns of the attack (``attack_info``):

* ``"detector"`` — from ESC rpm alone (:mod:`tfl_mav.control.detector`), as in flight;
* ``"oracle"`` — the paper's assumption (§III): the caller says which rotor is attacked
  (:meth:`FlightComputer.tell_attack`), and its thrust is read from its measured speed,
  f = k_f ω² (§VI).

Nothing non-finite ever leaves :meth:`FlightComputer.step`: thrusts are clamped to
[0, f_max] and a NaN becomes 0 N.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

from tfl_mav.build import build_controller, build_detector
from tfl_mav.control.detector import AttackDetector, DetectorOutput
from tfl_mav.control.law import ControlOutput, TFLController
from tfl_mav.modes import Mode
from tfl_mav.scenario import Scenario
from tfl_mav.state import State

__all__ = ["ATTACK_INFO", "FlightComputer", "TickResult"]

ATTACK_INFO = ("detector", "oracle")
RPM_TO_RADPS = 2.0 * math.pi / 60.0   # ESC rpm → rotor speed ω (rad/s)


@dataclass(frozen=True)
class TickResult:
    """One control decision.

    ``thrust_n``: the rotor thrusts to command (N, physical rotor order 1-4, each in
    [0, f_max]); ``law``: the law's internals; ``detection``: the detector's view this tick
    (None with an oracle); ``attack_estimate_n``: the attacked rotor's thrust the law used
    (NaN when no attack is known); ``new_detection``: the detector alarmed on this tick.
    """

    thrust_n: list[float]
    law: ControlOutput
    detection: DetectorOutput | None
    attack_rotor: int
    attack_estimate_n: float
    new_detection: bool

    @property
    def mode(self) -> Mode:
        return self.law.mode


class FlightComputer:
    """Detector + TFL law for one flight of one scenario. See the module docstring."""

    def __init__(self, scenario: Scenario, *, attack_info: str = "detector") -> None:
        if attack_info not in ATTACK_INFO:
            raise ValueError(f"attack_info: must be one of {', '.join(ATTACK_INFO)}, "
                             f"got {attack_info!r}")
        self.scenario = scenario
        self.attack_info = attack_info
        self.controller: TFLController = build_controller(scenario)
        self.detector: AttackDetector | None = (build_detector(scenario)
                                                if attack_info == "detector" else None)
        self.thrust_max_n = scenario.vehicle.thrust_max_n
        self.k_f = self.controller.model.k_f
        self._told_rotor = 0
        self.detected_rotor = 0
        self.detection_time_s = math.nan

    def tell_attack(self, rotor: int) -> None:
        """Oracle only: rotor 1-4 is attacked from now on (0: none)."""
        if self.attack_info != "oracle":
            raise RuntimeError("tell_attack: this flight computer detects attacks itself")
        self._told_rotor = rotor

    def step(self, t_s: float, state: State, rpm: Sequence[float],
             applied_n: Sequence[float], *, dt_s: float | None = None) -> TickResult:
        """One control tick.

        ``t_s``: sim time of ``state`` (s); ``rpm``: measured ESC rpm of rotors 1-4 at that
        time; ``applied_n``: the rotor thrust commands (N) the vehicle held over the period
        that ended at ``t_s`` — what the rpm answers to, not what was last sent. ``dt_s``:
        the time since the last tick when it is not one control period (a real-time daemon
        that skipped states): the law's internal states integrate over it.
        """
        ctrl = self.controller
        detection = None
        new = False
        estimate = math.nan
        rotor = 0
        if self.detector is not None:
            detection = self.detector.update(t_s, rpm, applied_n)
            if detection.detected_rotor:
                rotor, estimate = detection.detected_rotor, detection.estimate_n
                if detection.alarm:
                    new = True
                    self.detected_rotor = rotor
                    self.detection_time_s = detection.detection_time_s
                ctrl.set_attack(rotor, estimate)
        elif self._told_rotor:
            rotor = self._told_rotor
            w = rpm[rotor - 1] * RPM_TO_RADPS
            estimate = self.k_f * w * w
            ctrl.set_attack(rotor, estimate)
        omega = [r * RPM_TO_RADPS for r in rpm]
        if dt_s is None:
            out = ctrl.update(state, omega)
        else:
            period = ctrl.dt
            ctrl.dt = dt_s
            try:
                out = ctrl.update(state, omega)
            finally:
                ctrl.dt = period
        fmax = self.thrust_max_n
        thrust = [min(max(f, 0.0), fmax) if math.isfinite(f) else 0.0
                  for f in out.rotor_thrust_n]
        return TickResult(thrust, out, detection, rotor, estimate, new)
