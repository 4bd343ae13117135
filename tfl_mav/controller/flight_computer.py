"""The flight computer: one control tick, written once, for every way tfl-mav flies.

``step(t, state, rpm, applied)`` runs the attack detector on the ESC rpm against the command
the vehicle *applied*, switches the TFL law to the attacked rotor when the detector (or an
oracle) says so, evaluates the law and returns the rotor thrusts to send, with the internals
worth logging. The daemon (:mod:`tfl_mav.controller.daemon`) is link ↔ flight computer ↔ recorder;
the offline runner (:mod:`tfl_mav.offline`) is simulator ↔ the same flight computer; so a
fix to
the tick is a fix everywhere.

How the computer learns of the attack (``attack_info``):

* ``"detector"`` — from ESC rpm alone (:mod:`tfl_mav.control.detect.detector`), as in flight;
* ``"oracle"`` — the paper's assumption (§III): the caller says which rotor is attacked
  (:meth:`FlightComputer.tell_attack`), and its thrust is read from its measured speed,
  f = k_f ω² (§VI).

Which law flies is the supervisor's decision (:mod:`tfl_mav.controller.supervisor`, a pure
step with the rules and the physics that sizes them; ``controller.supervisor`` = ``auto``,
``tfl`` or ``safe``): **TFL** (``nominal``/``attacked``) wherever it holds the path, the
three-rotor **lost_rotor** law where the attacked rotor leaves TFL no roll torque of one sign
and that lasts (a dead rotor, a long zero-attack stretch) or the attack is more than the others
balance, the four-rotor **recovery** law for a first state TFL is not started from or a tick
TFL has no answer for (:mod:`tfl_mav.control.safe.recovery` says why a second law exists). The
hand-back is bumpless: TFL's dynamic extension starts at the thrust applied, its path parameter
at the safe law's, its estimators keep what they learnt (their filters restart).

The attacked rotor's thrust goes to the laws through a Kalman filter over its measured speed
when the ESCs are noisy (:mod:`tfl_mav.control.detect.attack_estimate`), with its uncertainty
to the supervisor.

Before the law: with sensor noise in the scenario the state is filtered with the
model (:mod:`tfl_mav.control.state_filter`; noise-free flights skip it); a yaw rate at the
gyro's range (``sensors.gyro_range_radps``) is replaced by the model's; a path speed the
vehicle cannot fly is lowered once to the highest feasible one
(:func:`~tfl_mav.controller.feasibility.feasible_speed_mps`), said on the first tick.

Every switch produces an event in words (:attr:`TickResult.events`, the daemon sends them as
STATUSTEXT). Nothing non-finite ever leaves :meth:`FlightComputer.step`: thrusts are clamped
to [0, f_max] and a NaN becomes 0 N.
"""

from __future__ import annotations

import math
import threading
import weakref
from collections.abc import Callable, Sequence
from typing import Any, NamedTuple

import numpy as np

from tfl_mav.accel import native
from tfl_mav.control.detect.attack_estimate import (
    ATTACK_START,
    AttackParams,
    attack_params,
    attack_update,
)
from tfl_mav.control.detect.detector import AttackDetector, DetectorOutput
from tfl_mav.control.safe.recovery import RecoveryLaw
from tfl_mav.control.safe.takeover import A_HANDBACK_N, TAKEOVER_TILT_RAD
from tfl_mav.control.safe.takeover import floats as _floats
from tfl_mav.control.spin.cone import CONE_START, ConeInputs, ConeLaw, ConeState, cone_params
from tfl_mav.control.spin.law import SpinLaw
from tfl_mav.control.spin.law import initial_state as spin_initial_state
from tfl_mav.control.spin.step import SpinInputs, SpinState
from tfl_mav.control.spin.step import hover_at as spin_hover_at
from tfl_mav.control.state_filter import StateFilter, YawRateModel
from tfl_mav.control.tfl.tfl_controller import ControlOutput, TFLController
from tfl_mav.control.tfl.thrust_trend import ThrustTrend, thrust_trend
from tfl_mav.controller.feasibility import feasible_speed_mps, path_demand
from tfl_mav.controller.supervisor import (
    Law,
    Start,
    SupervisorInputs,
    SupervisorState,
    Why,
    describe,
    initial_state,
    supervise,
    supervisor_params,
)
from tfl_mav.from_scenario import (
    build_controller,
    build_detector,
    detector_config,
    model_params,
    noisy_measurements,
    outdoors,
    scenario_path,
    spin_params_for,
)
from tfl_mav.model.modes import Mode
from tfl_mav.model.state import State
from tfl_mav.scenario import Scenario

__all__ = ["ATTACK_INFO", "TAKEOVER_TILT_RAD", "FlightComputer", "TickResult"]

ATTACK_INFO = ("detector", "oracle")
RPM_TO_RADPS = 2.0 * math.pi / 60.0   # ESC rpm → rotor speed ω (rad/s)
# The spin laws built in this process, by (vehicle, controller, period, rotor): a sweep flies
# thousands of flights of a few airframes.
_SPIN_LAWS: dict[tuple[object, ...], SpinLaw] = {}
_SPIN_BUILDING: set[tuple[object, ...]] = set()
_SPIN_LOCK = threading.Lock()
_NO_SPIN: dict[tuple[object, ...], str] = {}   # … and why none could be built


def _build_spin_law(key: tuple[object, ...], sc: object, rotor: int) -> SpinLaw | None:
    """Build the spin law (its table, its compiled step) into the shared table; None (the
    reason kept) where the airframe has no relaxed hover with that rotor pinned
    (:func:`~tfl_mav.control.spin.law.build`)."""
    try:
        params = spin_params_for(sc, rotor)  # type: ignore[arg-type]
    except ValueError as exc:
        _NO_SPIN[key] = str(exc)
        return None
    law = _SPIN_LAWS[key] = SpinLaw(params)
    return law
MASS_TRUSTED_S = 1.0    # the safe law flies the estimated mass once it has learnt this long


class TickResult(NamedTuple):
    """One control decision (a named tuple: one is made every tick).

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
    thrust_requested_n: list[float] | None = None   # what the law asked (may leave [0, f_max])
    events: tuple[str, ...] = ()                    # law switches etc., in words

    @property
    def mode(self) -> Mode:
        return self.law.mode


_new = tuple.__new__
_MODE_TEXT = {m: str(m) for m in Mode}    # formatting an enum costs µs: once, here
_FALLBACK, _LOST_ROTOR, _RECOVERY = Mode.FALLBACK, Mode.LOST_ROTOR, Mode.RECOVERY
# The safe law's reason, by mode and whole degrees of tilt error (acos: 0-180°): a float
# formatted every tick costs more than the rest of the output.
_TILT_TEXT = {m: tuple(f"{_MODE_TEXT[m]}: tilt error {d} deg" for d in range(181))
              for m in (_LOST_ROTOR, _RECOVERY)}
_RAD_TO_DEG = 180.0 / math.pi     # math.degrees multiplies by this very constant
_NAN = math.nan
_ZERO2, _ZERO4 = (0.0, 0.0), (0.0, 0.0, 0.0, 0.0)
_ZERO_XI = (_ZERO4, _ZERO4)
_sqrt, _acos, _hypot, _isfinite = math.sqrt, math.acos, math.hypot, math.isfinite
_STAY, _NO_START = int(Why.STAY), int(Start.NONE)     # read every tick: plain ints
_OUTPUT_DEFAULTS = tuple(ControlOutput._field_defaults[f] for f in ControlOutput._fields[15:])
_TFL, _SPIN = int(Law.TFL), int(Law.SPIN)
_ndarray = np.ndarray


class FlightComputer:
    """Detector + TFL law for one flight of one scenario. See the module docstring."""

    def __init__(self, scenario: Scenario, *, attack_info: str = "detector",
                 design_gains: bool = True, spin_build: str = "sync") -> None:
        """``design_gains``: design the safe law's whole LQR gain schedule now (a real-time
        flight never designs one mid-air), or False: a block at a time when first met
        (offline: no deadline; the same gains, a fraction of the start-up). ``spin_build``:
        how the spin law's table is made when first needed, "sync" (deterministic) or
        "async" (a real-time flight: on a thread, the safe law flies until it is ready)."""
        if spin_build not in ("sync", "async"):
            raise ValueError(f"spin_build: must be 'sync' or 'async', got {spin_build!r}")
        if attack_info not in ATTACK_INFO:
            raise ValueError(f"attack_info: must be one of {', '.join(ATTACK_INFO)}, "
                             f"got {attack_info!r}")
        self.scenario = scenario
        self.attack_info = attack_info
        self._pending_events: list[str] = []
        self.speed_mps = self._flyable_speed(scenario)
        self.controller: TFLController = build_controller(scenario, speed_mps=self.speed_mps)
        self.detector: AttackDetector | None = (build_detector(scenario)
                                                if attack_info == "detector" else None)
        self.thrust_max_n = scenario.vehicle.thrust_max_n
        mp = model_params(scenario)     # the laws' model of the vehicle
        self.k_f = mp.k_f
        self._told_rotor = 0
        self.detected_rotor = 0
        self.detection_time_s = math.nan
        self.recovery = RecoveryLaw(mp.mass_kg, mp.inertia_kgm2, mp.arm_m,
                                    mp.drag_thrust_ratio_m, mp.k_t, mp.k_r, mp.thrust_max_n,
                                    mp.gravity_mps2, scenario.run.control_dt_s,
                                    scenario_path(scenario), self.speed_mps,
                                    kernels=getattr(self.controller.tracker, "kernels", None),
                                    compiled_path=self.controller.path_eval == "compiled",
                                    design_gains=design_gains,
                                    motor_time_constant_s=mp.motor_time_constant_s,
                                    noisy_measurements=noisy_measurements(scenario),
                                    thrust_known=not outdoors(scenario))
        self._weight_n = mp.mass_kg * mp.gravity_mps2
        self._spin_from_n = self._weight_n - 2.0   # 2A above it: the spin law is built
        # Which law flies: the supervisor's constants and state (supervisor.py).
        mode = scenario.controller.supervisor
        self.supervisor = supervisor_params(mode, self._weight_n, mp.thrust_max_n,
                                            self.speed_mps, a_handback_n=A_HANDBACK_N)
        self._sup: SupervisorState = initial_state(mode)
        self._last_safe_thrust: Sequence[float] = [mp.mass_kg * mp.gravity_mps2 / 4.0] * 4
        self._delivered: list[float] | None = None   # the safe law's last tick's thrusts (N)
        # The safe law's total thrust and its rate (N, N/s): where TFL's dynamic extension
        # starts at a hand-back (x13, x14).
        self._trend = ThrustTrend(0.0, 0.0, 0)
        # The spin law for a rotor pinned above m g/2 (control/spin): built when needed.
        self.spin_enabled = True
        self.spin_build = spin_build
        self._spin_state: SpinState | None = None
        self._spin_laws: dict[int, SpinLaw] = {}      # by attacked rotor, once built
        self._said_no_spin = False
        # Why no spin law can be built, by attacked rotor (said once, with the numbers).
        self._no_spin: dict[int, str] = {}
        # The coning hover (control/spin/cone) flown where no relaxed hover holds m g.
        self._cone_laws: dict[int, ConeLaw] = {}
        self._cone_state: ConeState | None = None
        self._climbing = False         # said: the attack is more than the weight allows
        self._hover_share_n = mp.mass_kg * mp.gravity_mps2 / 4.0
        self._probe_high_n = min(self._hover_share_n + 1.5, self.thrust_max_n)
        self._probe_n = self._hover_share_n   # the attacked rotor's probe command (N)
        # The attacked rotor's thrust through a filter when the ESCs are noisy
        # (attack_estimate); a noise-free speed is the thrust itself.
        rpm_std = detector_config(scenario).rpm_noise_std
        self.attack_filter: AttackParams | None = (
            attack_params(mp.k_f, mp.thrust_max_n, mp.motor_time_constant_s,
                          scenario.run.control_dt_s, rpm_std) if rpm_std > 0.0 else None)
        self._attack_state = ATTACK_START
        self._attack_rotor = 0
        sens = scenario.sensors
        trans = sens.position_noise_std_m > 0.0 or sens.velocity_noise_std_mps > 0.0
        rot = sens.rate_noise_std_radps > 0.0
        # Noisy sensors: fuse with the model (state_filter). Gated on the scenario's noise so
        # a noise-free flight is untouched (bit-identical), not merely close.
        self.state_filter: StateFilter | None = (
            StateFilter(mp, scenario.run.control_dt_s,
                        position_std_m=sens.position_noise_std_m,
                        velocity_std_mps=sens.velocity_noise_std_mps,
                        rate_std_radps=sens.rate_noise_std_radps,
                        translation=trans, rotation=rot) if trans or rot else None)
        # A gyro saturates at its range (the attacked vehicle spins near 60 rad/s, beyond
        # 2000 deg/s): past it the yaw rate comes from the model (state_filter).
        self.gyro_range_radps = sens.gyro_range_radps
        self.yaw_model = (YawRateModel(mp, self.k_f, sens.gyro_range_radps)
                          if sens.gyro_range_radps > 0.0 else None)
        self._needs_omega = (self.state_filter is not None or self.yaw_model is not None
                             or self.controller.has_motor_lag)
        self.internal_errors = 0   # ticks a law raised (held the last command)
        self._last_t: float | None = None
        self._supervise_core: Callable[..., Any] | None = None
        self._obtain_supervisor()

    @property
    def law_name(self) -> str:
        """The law flying: "tfl" | "recovery" | "lost_rotor"."""
        return Law(self._sup.law).name.lower()

    @property
    def supervisor_state(self) -> SupervisorState:
        """The supervisor's state: the law flying, switches, the time in each law."""
        return self._sup

    @property
    def switches(self) -> int:
        return self._sup.switches

    @property
    def yaw_rate_substituted_ticks(self) -> int:
        """Ticks whose yaw rate came from the model (the gyro at its range)."""
        return self.yaw_model.substituted_ticks if self.yaw_model is not None else 0

    def _flyable_speed(self, sc: Scenario) -> float:
        """The path speed to fly: the scenario's, or the highest the vehicle can fly when the
        path's bends ask for more than the rotors can give (feasibility); said in words."""
        try:
            s_ok = feasible_speed_mps(sc)
        except Exception:  # an unusable path is reported by the law's own checks
            return sc.path.speed_mps
        if s_ok < sc.path.speed_mps:
            d = path_demand(sc)
            self._pending_events.append(
                f"path at {sc.path.speed_mps:g} m/s needs {-d.min_vertical_mps2:.1f} m/s^2 "
                f"downward at its tightest bend (more than the rotors can give): "
                f"flying it at {s_ok:.2f} m/s, the highest speed the vehicle can")
        return s_ok

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

        The tick composes pure steps: the detector and the attack estimate, the law the
        supervisor chose, the supervisor (:func:`~tfl_mav.controller.supervisor.supervise`),
        and — on a take-over — the safe law on this very tick.

        A numerical failure inside a law (an input no flight produces: the fuzzer finds
        them) never escapes: the tick holds the applied command, in mode FALLBACK, and says
        why — the daemon's loop must not die.
        """
        try:
            ctrl = self.controller
            if type(rpm) is np.ndarray:          # the simulator's: floats are 3-5× cheaper
                rpm = rpm.tolist()
            events: list[str] = []
            detection = None
            new = False
            estimate = math.nan
            rotor = 0
            detector = self.detector
            if detector is not None:
                detection = detector.update(t_s, rpm, applied_n)
                if detection.released:
                    self.detected_rotor = 0
                    events.append("rotor obeys its commands again: attack over, four-rotor law")
                rotor = detection.detected_rotor
                if rotor:
                    estimate = detection.estimate_n
                    if detection.alarm:
                        new = True
                        self.detected_rotor = rotor
                        self.detection_time_s = detection.detection_time_s
            elif self._told_rotor:
                rotor = self._told_rotor
                w = rpm[rotor - 1] * RPM_TO_RADPS
                estimate = self.k_f * w * w
            # ω (rad/s) for the state filter, the yaw-rate model and the law's lag inverse; the
            # law reads it only with motor lag (TFLController.update), so nothing else needs it.
            omega = [r * RPM_TO_RADPS for r in rpm] if self._needs_omega else None
            spread = 0.0
            if self.attack_filter is not None:
                estimate, spread = self._estimate(rotor, estimate, rpm, detection)
            if rotor != ctrl.attacked_rotor:     # the allocation changes; the estimate
                ctrl.set_attack(rotor, estimate if rotor else 0.0)   # goes with every tick
            last = self._last_t
            if last is None:
                dt = ctrl.dt
            else:                      # max(t − last, 0) or the period (a NaN stays NaN)
                dt = t_s - last
                if not (dt > 0.0 or dt != dt):
                    dt = ctrl.dt
            self._last_t = t_s
            if self.state_filter is not None:
                # The thrusts that acted over the last period: what the ESCs report (f = k_f ω²),
                # the attacked rotor's included.
                k_f = self.k_f
                state = self.state_filter.update(state, [k_f * w * w for w in omega], dt)
            if self.yaw_model is not None:
                state = self.yaw_model.update(state, omega, dt, events)
            sup = self._sup
            if sup.ticks == 0:
                events[:0] = self._pending_events
                sup = self._decide(0.0, rotor, estimate, spread, None, _NAN, state, events,
                                   first=True)
            if sup.law == _TFL:
                self._delivered = None
                out = ctrl.update(state, omega, dt_s=dt_s,
                                  attack_n=estimate if rotor else None)
                sup = self._decide(dt, rotor, estimate, spread, out, _NAN, state, events)
                if sup.law == _TFL:
                    return self._result(out.rotor_thrust_n, None, out, detection, rotor,
                                        estimate, new, events)
            if sup.law == _SPIN:
                return self._fly_spin(dt, state, rotor, estimate, spread, rpm, events,
                                      detection, new)
            return self._fly_safe(dt, state, rotor, estimate, spread, omega, events,
                                  detection, new)
        except (ArithmeticError, ValueError, np.linalg.LinAlgError) as exc:
            return self._failed(exc, applied_n)

    def _estimate(self, rotor: int, raw_n: float, rpm: Sequence[float],
                  detection: DetectorOutput | None) -> tuple[float, float]:
        """The attacked rotor's thrust A (N) for the laws and its standard deviation σ_A (N)
        (:mod:`~tfl_mav.control.detect.attack_estimate`): the filter over the rotor's
        measured speed with the motor-lag model and the ESC noise; without noise (no
        filter: the tick does not call this) the measured speed is the truth (σ_A = 0)
        and A = k_f ω²."""
        est = self.attack_filter
        if est is None:
            return raw_n, 0.0
        if not rotor or not math.isfinite(raw_n):
            self._attack_state = ATTACK_START
            return raw_n, 0.0
        w = rpm[rotor - 1] * RPM_TO_RADPS
        if self._attack_rotor != rotor:
            self._attack_rotor = rotor
            self._attack_state = ATTACK_START
        self._attack_state, a_n, std_n = attack_update(est, self._attack_state, w)
        return a_n, std_n

    def _failed(self, exc: BaseException, applied_n: Sequence[float]) -> TickResult:
        """A law raised: hold the applied command, in mode FALLBACK, and say why."""
        self.internal_errors += 1
        fmax = self.thrust_max_n
        hold = [min(max(f, 0.0), fmax) if math.isfinite(f) else 0.0 for f in applied_n]
        zero4 = (0.0, 0.0, 0.0, 0.0)
        why = f"internal error ({type(exc).__name__}: {exc}); last command held"
        out = ControlOutput(
            rotor_thrust_n=hold, mode=Mode.FALLBACK, saturated=[False] * 4,
            xi=(zero4, zero4), eta=zero4, mu=(0.0, 0.0), path_distance_m=math.nan,
            lam=math.nan, cond_d=math.nan, thrust_n=sum(hold),
            mass_estimate_kg=self.controller.mass_kg, disturbance_radps2=(0.0, 0.0),
            fine_gains=False, reason=why, demand_n=tuple(hold))
        return TickResult(hold, out, None, 0, math.nan, False, list(hold), (why,))

    def _spin_ready(self, rotor: int, estimate: float) -> bool:
        """The spin law is built for ``rotor`` (its table is made once the attack comes
        within 1 N of m g/2: ~3 s of computing, so not for every attack). ``spin_build``
        "sync" builds it there and then (offline, lockstep: no deadline, deterministic);
        "async" on a background thread, used once ready (real time: no tick waits)."""
        if rotor in self._spin_laws or rotor in self._cone_laws:   # built: only ever for
            return self.spin_enabled                               # mode auto, spin enabled
        # the attack well below m g/2 first: what an attacked TFL tick finds, cheapest
        if not (rotor and 2.0 * estimate > self._spin_from_n) \
                or self.supervisor.mode != 0 or not self.spin_enabled:
            return False
        key = self._spin_key(rotor)
        if key in _SPIN_LAWS:
            self._spin_laws[rotor] = _SPIN_LAWS[key]
            return True
        if key in _NO_SPIN:
            return self._cone_instead(rotor, _NO_SPIN[key])
        if self.spin_build == "sync":
            law = _build_spin_law(key, self.scenario, rotor)
            if law is None:
                return self._cone_instead(rotor, _NO_SPIN[key])
            self._spin_laws[rotor] = law
            return True
        with _SPIN_LOCK:
            if key not in _SPIN_BUILDING:
                _SPIN_BUILDING.add(key)
                sc = self.scenario
                threading.Thread(target=_build_spin_law, args=(key, sc, rotor),
                                 name="tfl-mav-spin-law", daemon=True).start()
        return False

    def _cone_instead(self, rotor: int, why: str) -> bool:
        """No spin law for ``rotor`` (``why``): the coning hover flies in its place."""
        self._no_spin[rotor] = why
        self._cone_laws[rotor] = self._cone_law(rotor)
        return True

    def _cone_law(self, rotor: int) -> ConeLaw:
        sc = self.scenario
        c = sc.controller
        return ConeLaw(cone_params(sc.vehicle, rotor, sc.run.control_dt_s,
                                   mass_scale=c.model_mass_scale,
                                   inertia_scale=c.model_inertia_scale))

    def _spin_key(self, rotor: int) -> tuple[object, ...]:
        sc = self.scenario
        return (repr(sc.vehicle), repr(sc.controller), sc.run.control_dt_s, rotor)

    def _fly_spin(self, dt: float, state: State, rotor: int, estimate: float, spread: float,
                  rpm: Sequence[float], events: list[str], detection: DetectorOutput | None,
                  new: bool) -> TickResult:
        """A tick of the spin law (:func:`~tfl_mav.control.spin.step.spin_step`): the mean
        axis steered towards the closest path point moving at the path speed, the pinned
        rotor's thrust read from its rpm; then the supervisor, and the output."""
        spin = self._spin_laws.get(rotor)
        y = _floats(state.position_m)
        rates = tuple(_floats(state.body_rates_radps))
        w = rpm[rotor - 1] * RPM_TO_RADPS
        stuck = self.k_f * w * w
        found = self.recovery.closest_path_point(y)
        if found is None:
            point, tangent, curvature, dist = tuple(y), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), _NAN
        else:
            point, tangent, curvature, dist = found
        sp = self.speed_mps
        target = (tuple(point), (sp * tangent[0], sp * tangent[1], sp * tangent[2]),
                  (sp * sp * curvature[0], sp * sp * curvature[1], sp * sp * curvature[2]))
        if spin is None or not spin_hover_at(spin.params.table, stuck).exists:
            thrust, clipped, reason = self._fly_cone(rotor, stuck, state, rates, target,
                                                     events)
        else:
            if self._spin_state is None:
                self._spin_state = spin_initial_state(spin.params, rates, stuck)
            inputs = SpinInputs(tuple(y), tuple(_floats(state.velocity_mps)),
                                tuple(_floats(state.quaternion_wxyz)), rates, stuck, *target)
            self._spin_state, out = spin.step(self._spin_state, inputs)
            thrust, clipped = list(out.thrusts_n), out.clipped
            reason = (f"spin: {out.spin_radps:.0f} rad/s, cone "
                      f"{math.degrees(out.cone_rad):.0f} deg")
        if self.controller.has_motor_lag:
            command, _ = self.controller.invert_lag(thrust, [r * RPM_TO_RADPS for r in rpm],
                                                    rotor)
            self._last_safe_thrust = list(thrust)
            thrust = command
        else:
            self._last_safe_thrust = thrust
        self._delivered = None
        self._decide(dt, rotor, estimate, spread, None, dist, state, events)
        if self._sup.law != Law.SPIN:
            self._spin_state = None
            self._cone_state = None
        law = ControlOutput(
            list(thrust), Mode.SPIN, [clipped] * 4, _ZERO_XI, _ZERO4, _ZERO2, dist,
            _NAN, _NAN, sum(thrust), self.controller.mass_kg, _ZERO2, False, reason,
            tuple(thrust))
        return self._result(thrust, None, law, detection, rotor, estimate, new, events)

    def _fly_cone(self, rotor: int, stuck: float, state: State, rates: tuple[float, ...],
                  target: tuple[tuple[float, ...], ...], events: list[str]
                  ) -> tuple[list[float], bool, str]:
        """A tick of the coning hover (:mod:`~tfl_mav.control.spin.cone`), flown where no
        relaxed hover holds m g at the pinned thrust; said once, with its numbers."""
        cone = self._cone_laws.get(rotor)
        if cone is None:
            cone = self._cone_laws[rotor] = self._cone_law(rotor)
        if self._cone_state is None:
            self._cone_state = CONE_START
        inputs = ConeInputs(tuple(_floats(state.position_m)),
                            tuple(_floats(state.velocity_mps)),
                            tuple(_floats(state.quaternion_wxyz)), rates, stuck,
                            *target)  # type: ignore[arg-type]
        self._cone_state, out = cone.step(self._cone_state, inputs)
        if not self._said_no_spin:
            self._said_no_spin = True
            why = self._no_spin.get(rotor, f"no relaxed hover holds m g with rotor {rotor} "
                                           f"at {stuck:.2f} N")
            events.append(f"spin: {why}; flying a coning hover instead: the thrust tilted "
                          f"{math.degrees(out.tilt_rad):.0f} deg so that its vertical part "
                          f"is the weight, swung round the vertical at "
                          f"{abs(cone.params.rate_radps):.0f} rad/s (a {out.drift_m:.2f} m circle "
                          "about the path)")
        reason = (f"spin: coning hover, tilt {math.degrees(out.tilt_rad):.0f} deg, circle "
                  f"{out.drift_m:.2f} m")
        return list(out.thrusts_n), out.clipped, reason

    def _obtain_supervisor(self) -> None:
        """The supervisor's step compiled by the seam (the same decisions, bit for bit:
        tests/contract/test_composition_seam.py), used once it is built; Python until then."""
        use_core = weakref.WeakMethod(self._use_supervise_core)   # a finished one: not kept

        def ready(core: Callable[..., Any]) -> None:
            use = use_core()
            if use is not None:
                use(core)

        example = (self.supervisor, self._sup, _new(SupervisorInputs, (
            0.0, 0, _NAN, 0.0, False, False, _ZERO4, _NAN, (1.0, 0.0, 0.0, 0.0),
            (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), _NAN, False)))
        core = native.obtain_function(supervise, example, ready)
        if core is not None:
            ready(core)

    def _use_supervise_core(self, core: Callable[..., Any]) -> None:
        self._supervise_core = core     # one reference store: atomic under the GIL

    def _decide(self, dt: float, rotor: int, estimate: float, spread: float,
                out: ControlOutput | None, safe_distance_m: float, state: State,
                events: list[str], *, first: bool = False) -> SupervisorState:
        """One supervisor step; start the law it chose as it says; the words for it.

        ``out``: the TFL law's output if it flew this tick; ``safe_distance_m``: the safe
        law's distance to the path if it flew (NaN: not, or holding a point); ``first``: the
        first tick (the distance to the path is searched for). What the supervisor is told
        goes as :class:`SupervisorInputs`' fields in order, a plain tuple (the compiled step
        reads them by position; named only where Python reads them); the state's vectors
        as they are (the step reads any sequence of floats)."""
        if out is None:
            tfl_flew = answer = False
            demand = _ZERO4
        else:
            tfl_flew, answer = True, out.mode is not _FALLBACK
            demand = out.demand_n or _ZERO4
        fields = (dt, rotor, estimate, spread, tfl_flew, answer, demand, safe_distance_m,
                  state.quaternion_wxyz, state.body_rates_radps, state.velocity_mps,
                  self.recovery.distance_to_path(_floats(state.position_m)) if first else _NAN,
                  self._spin_ready(rotor, estimate) if rotor else False)
        old = self._sup
        core = self._supervise_core
        r = core(self.supervisor, old, fields) if core is not None else None
        if r is None:        # not compiled yet, or declined (Python raises there): Python
            r = supervise(self.supervisor, old, _new(SupervisorInputs, fields))
        self._sup, (law, why, start) = r
        if why != _STAY:
            inputs = _new(SupervisorInputs, fields)
            distance = inputs.safe_distance_m
            text = describe(why, law, rotor=rotor, attack_n=estimate, inputs=inputs,
                            since_s=old.since_s + inputs.dt_s, distance_m=distance)
            if text and (law != old.law or why == Why.FOLLOW):
                events.append(text)
        if start == _NO_START:
            return self._sup
        rec = self.recovery
        if start == Start.SAFE_HOLD:
            rec.hold(state.position_m)
        elif start == Start.SAFE_PATH:
            if rec.holding:                    # after a held point: we may be far away
                rec.follow_path(search=True)
            elif out is not None:              # from TFL: its λ is where the vehicle is
                rec.follow_path(out.lam)
            else:
                rec.follow_path(search=True)
        if (start in (Start.SAFE_HOLD, Start.SAFE_PATH)
                and old.law in (Law.TFL, Law.SPIN)) or start == Start.SPIN:
            self.controller.reset_lag_inverse()   # the old law's demand is not a trend
        elif start == Start.TFL_RESUME:
            self._resume_tfl()
        return self._sup

    def _resume_tfl(self) -> None:
        """Back to TFL, bumpless: its dynamic extension starts at the thrust now applied
        and its rate, its path parameter at the safe law's, its estimators keep what they
        learnt."""
        self.controller.resume(self._last_safe_thrust, self.recovery.path_lam,
                               self._trend.rate_nps)

    def _fly_safe(self, dt: float, state: State, rotor: int, estimate: float, spread: float,
                  omega: list[float] | None, events: list[str],
                  detection: DetectorOutput | None, new: bool) -> TickResult:
        """A tick of the safe law (recovery or lost_rotor), then the supervisor, and the
        output."""
        rec = self.recovery
        finite = _isfinite(estimate)
        a_n = estimate if rotor and finite else 0.0
        if rotor and finite and (2.0 * estimate > self._weight_n) is not self._climbing:
            self._say_if_climbing(rotor, estimate, events)
        # An attacked rotor is never ours to command: with one known, the safe law flies the
        # other three whichever way it was entered (a take-over of an attacked vehicle too).
        flying = self._sup
        ctrl = self.controller
        if self._delivered is not None:   # the last tick was this law's: TFL's estimator
            ctrl.track(state, self._delivered)   # learns from what acted over it
        # The estimated mass once it has learnt for a second (its first samples, from a
        # restart or a fall, are what the model says better than the estimate does).
        mass_kg = ctrl.mass_kg
        mass = mass_kg if ctrl.mass_learnt_s >= MASS_TRUSTED_S else None
        out = rec.update(state, rotor, a_n, mass_kg=mass)
        dist = out.path_distance_m
        ctrl.settle_on(dist)
        self._last_safe_thrust = out.thrust_n
        # (A tick after another law's — TFL, the spin — starts the trend afresh.)
        self._trend = thrust_trend(self._trend if self._delivered is not None else None,
                                   sum(out.thrust_n), dt)
        if flying.law != _TFL:      # a take-over this tick is judged from the next one
            self._decide(dt, rotor, estimate, spread, None, dist, state, events)
        thrust = out.thrust_n
        # What the rotors deliver over the coming period (N): the demand, or with motor lag
        # the lag model's mean for the command sent (the attacked rotor: its estimate) —
        # what TFL's own step feeds its estimator with; never the ESC's noisy sample.
        delivered = list(thrust)
        if ctrl.has_motor_lag:      # the motor-lag inverse, as the TFL law flies it (the
            # attacked rotor is not ours to command)
            thrust, delivered = ctrl.invert_lag(thrust, omega, rotor)
        self._delivered = delivered if self._sup.law != _TFL else None
        # the output; after a hand-back this tick is still the safe law's
        mode = _LOST_ROTOR if rotor else _RECOVERY
        deg = out.tilt_error_rad * _RAD_TO_DEG
        reason = (_TILT_TEXT[mode][round(deg)] if 0.0 <= deg <= 180.0
                  else f"{_MODE_TEXT[mode]}: tilt error {deg:.0f} deg")
        # ControlOutput's fields in order (rotor_thrust_n … demand_n), built as the tuple it
        # is; the fields after them, if any, at their defaults
        law = _new(ControlOutput, (
            list(thrust), mode, list(out.clamped), _ZERO_XI, _ZERO4, _ZERO2, dist, _NAN, _NAN,
            out.uf_n, mass_kg, _ZERO2, False, reason, tuple(out.requested_n),
            *_OUTPUT_DEFAULTS))
        return self._result(thrust, out.requested_n, law, detection, rotor, estimate, new,
                            events)

    def _say_if_climbing(self, rotor: int, estimate: float, events: list[str]) -> None:
        """Say it when the attack makes the vehicle climb whatever the others do (and when
        that ends): keeping the attitude needs the opposite rotor at A, so u_f ≥ 2A, more
        than the weight once A > m g/2. No law can hold the path or the altitude there."""
        w = self._weight_n
        if not self._climbing and 2.0 * estimate > w:
            self._climbing = True
            events.append(f"lost_rotor: rotor {rotor} at {estimate:.2f} N: keeping the attitude "
                          f"takes {2.0 * estimate:.1f} N of thrust, more than the weight "
                          f"({w:.1f} N); the vehicle climbs away from the path")
        elif self._climbing and 2.0 * estimate < w - 2.0 * A_HANDBACK_N:
            self._climbing = False
            events.append(f"lost_rotor: rotor {rotor} at {estimate:.2f} N: the vehicle can "
                          "hold its altitude again")

    def _result(self, thrust: Sequence[float], requested: Sequence[float] | None,
                out: ControlOutput, detection: DetectorOutput | None, rotor: int,
                estimate: float, new: bool, events: list[str]) -> TickResult:
        """The command to send: each thrust min(max(f, 0), f_max), a NaN → 0 N; what the law
        asked (``requested``; None: the same as ``thrust``) with a NaN → 0 N."""
        fmax = self.thrust_max_n
        f1, f2, f3, f4 = thrust
        # One chained test passes four thrusts in range (comparisons are False for NaN).
        if 0.0 <= f1 <= fmax and 0.0 <= f2 <= fmax and 0.0 <= f3 <= fmax \
                and 0.0 <= f4 <= fmax:
            applied = [f1, f2, f3, f4]
            if requested is None:
                requested = applied
        else:
            applied = [(fmax if fmax < f else (0.0 if f < 0.0 else f)) if math.isfinite(f)
                       else 0.0 for f in thrust]
            if requested is None:
                requested = thrust
        r1, r2, r3, r4 = requested
        if _isfinite(r1 + r2 + r3 + r4):        # a finite sum: all four finite
            req = [r1, r2, r3, r4]
        else:
            req = [r if math.isfinite(r) else 0.0 for r in requested]
        if rotor and self.detector is not None:
            # The attacked rotor's command is not ours to use: send it a probe away from its
            # estimate, so that a rotor the attacker lets go shows it by following (detector).
            # The probe keeps its level while the estimate stays 0.5 N away from it: a
            # probe that flips as the estimate crosses hover + 1 N sweeps a lagging rotor's
            # model band over the attacker's thrust, and the detector, seeing the rotor
            # "follow", released it (a false release, re-detected 9 ms later: 95 mm).
            est = estimate if _isfinite(estimate) else 0.0
            probe = self._probe_n
            if not abs(probe - est) > 0.5:
                hover = self._hover_share_n
                probe = self._probe_n = (hover if abs(hover - est) > 1.0
                                         else self._probe_high_n)
            applied[rotor - 1] = probe
        # TickResult(...) without its generated Python __new__ (every tick): all fields
        return _new(TickResult, (applied, out, detection, rotor, estimate, new, req,
                                 tuple(events)))
