"""Attack detection, isolation and estimation from ESC rpm (pure math: no sockets, no files).

Each control tick compares each rotor's measured speed with the speed its command should
produce through the same motor model the vehicle has (``f = k_f ω²``, command clamped to
[0, f_max], optional first-order lag on ω with time constant τ_m, held over the control
period). An attacker who forces a rotor's thrust makes that rotor's speed leave the model.

* **Residual** (rpm): the distance from ``ω_meas`` to the band of speeds the motor can have
  if its true τ_m is anywhere within a factor ``1 + time_constant_tolerance`` of the
  model's (five lag models run side by side; the band collapses to one speed when the
  command is steady or τ_m = 0). It is normalised by the propagated std: ESC noise σ (plus
  the uint16 rpm quantisation of ESC_TELEMETRY_1_TO_4) and, with lag, the uncertainty of
  the band's start (taken from the first, noisy, measurement) decaying at the lag's rate.
  ``z`` is then at most N(0, 1)-sized while the rotor obeys its command.
* **Detection**: a two-sided CUSUM per rotor, ``S⁺ ← max(0, S⁺ + z − k)``, ``S⁻ ← max(0,
  S⁻ − z − k)``; alarm when a statistic reaches ``h``. Each sample's contribution is capped
  at ``k + h/min_ticks`` so one glitch can never alarm: at least ``min_ticks`` consecutive
  anomalous samples are needed. Gaussian false-alarm rate (Siegmund's approximation,
  ARL₀ ≈ e^{2k(h+1.166)}/(2k²)): k = 2, h = 8 gives ~10¹⁵ ticks per statistic.
* **Isolation**: the rotor with the largest statistic on the alarm tick. Latched, but it
  follows the attacker: the other rotors' statistics keep running, and when one
  of them alarms the attacker has moved (MAV_CMD_INJECT_FAILURE on another rotor) and the
  verdict moves with it (a new alarm). The latched rotor is released with evidence: the
  flight computer commands it a probe thrust away from its estimate, and when its speed
  follows that command (|z| < k) for ``RELEASE_TICKS`` ticks in a row it obeys its commands
  again — the attack stopped — and the verdict returns to 0 (``released``). If it was only
  a coincidence (an attacker holding the probe value) the next deviation alarms again.
* **Estimation**: the attacked rotor's thrust from its own rpm, ``k_f ω²`` clamped to
  [0, f_max]; a non-finite sample holds the last estimate, so no NaN leaves after detection.
* **Motors not driven** (:meth:`AttackDetector.set_motors_off`: the vehicle says no command
  drives them — disarmed, cut): a rotor that is not being driven neither obeys nor disobeys,
  so there is no evidence either way. The motor model still follows the applied command
  (zero), so it is right when the motors are driven again, but the statistics stay at 0: no
  alarm, no move, no release, and the verdict of before (latched rotor, its detection time)
  stands. The estimate still comes from the latched rotor's rpm.

The law is :mod:`detector_step`'s state and pure step; :class:`AttackDetector` holds the
state and calls the step — compiled through the accelerator seam where it is built, the
Python function otherwise: the same bits either way.
"""

from __future__ import annotations

import math
import weakref
from collections.abc import Sequence
from dataclasses import dataclass, field, fields
from typing import Any

from tfl_mav.accel import native
from tfl_mav.control.detect.detector_step import (
    N_MODELS,
    N_ROTORS,
    RADPS_TO_RPM,
    RELEASE_TICKS,
    RPM_VALID_LIMIT,
    DetectorOutput,
    DetectorParams,
    DetectorState,
    detector_step,
    initial_state,
    motors_driven,
)

__all__ = ["RELEASE_TICKS", "RPM_QUANTISATION_STD", "RPM_VALID_LIMIT", "AttackDetector",
           "DetectorConfig", "DetectorOutput"]

# ESC_TELEMETRY_1_TO_4 carries rpm as uint16: rounding adds uniform noise of std 1/√12 rpm.
RPM_QUANTISATION_STD = 1.0 / math.sqrt(12.0)
_ALARM_TOL = 1e-9  # relative slack so min_ticks capped increments reach h despite rounding


def _param(default: float, unit: str = "", *, lo: float | None = None,
           hi: float | None = None, lo_open: bool = False, doc: str = "") -> Any:
    """A config field with its bounds in the metadata (checked in ``__post_init__``)."""
    meta = {"unit": unit, "lo": lo, "hi": hi, "lo_open": lo_open, "doc": doc}
    return field(default=default, metadata=meta)


@dataclass(frozen=True, slots=True)
class DetectorConfig:
    """Tuning of the detector, and the scenario's ``[detector]`` section (one type for both).

    σ-denominated values are in units of the residual's std."""

    rpm_noise_std: float = _param(0.0, "rpm", lo=0.0, hi=1000.0,
                                  doc="ESC rpm noise std the detector assumes (besides the "
                                      "uint16 quantisation); in a scenario 0 = the vehicle's")
    cusum_drift_sigma: float = _param(2.0, "sigma", lo=0.0, lo_open=True, hi=100.0,
                                      doc="CUSUM drift k: shifts below k are ignored")
    cusum_threshold_sigma: float = _param(8.0, "sigma", lo=0.0, lo_open=True, hi=1e4,
                                          doc="CUSUM threshold h")
    min_ticks: int = _param(3, "ticks", lo=1, hi=1000,
                            doc="fewest consecutive anomalous samples that can alarm")
    enabled: bool = True
    model_time_constant_scale: float = _param(1.0, lo=0.0, hi=10.0,
                                              doc="model tau = scale * motor tau")
    time_constant_tolerance: float = _param(0.3, lo=0.0, hi=4.0,
                                            doc="true tau within model tau x/÷ (1 + this)")

    def __post_init__(self) -> None:
        for f in fields(self):
            key, value = f"DetectorConfig.{f.name}", getattr(self, f.name)
            if isinstance(f.default, bool):
                if not isinstance(value, bool):
                    raise ValueError(f"{key}: must be true or false, got {value!r}")
            else:
                _check(key, value, f.metadata, integer=isinstance(f.default, int))


def _check(key: str, value: object, meta: object, *, integer: bool) -> None:
    m = dict(meta)  # type: ignore[call-overload]
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ValueError(f"{key}: must be a number, got {value!r}")
    if integer and not isinstance(value, int):
        raise ValueError(f"{key}: must be an integer, got {value!r}")
    if not math.isfinite(value):
        raise ValueError(f"{key}: must be finite, got {value!r}")
    lo, hi = m["lo"], m["hi"]
    if lo is not None and (value <= lo if m["lo_open"] else value < lo):
        raise ValueError(f"{key}: must be {'>' if m['lo_open'] else '>='} {lo}, got {value!r}")
    if hi is not None and value > hi:
        raise ValueError(f"{key}: must be <= {hi}, got {value!r}")


_ZERO4 = (0.0,) * N_ROTORS
# The compiled step, once built (one per process, whatever the number of detectors).
_compiled: dict[str, Any] = {"core": None}


class AttackDetector:
    """Per-rotor motor-model residual + two-sided CUSUM; see the module docstring.

    ``k_f`` N/(rad/s)², ``thrust_max_n`` N, ``motor_time_constant_s`` the vehicle's τ_m (s;
    the model uses ``config.model_time_constant_scale`` × it), ``dt_s`` the control period
    (s; the lag is propagated over the elapsed ``time_s``, and over ``dt_s`` for a tick whose
    time is not finite). Holds :class:`~tfl_mav.control.detect.detector_step.DetectorState` and
    calls :func:`~tfl_mav.control.detect.detector_step.detector_step`.
    """

    def __init__(self, k_f: float, thrust_max_n: float, motor_time_constant_s: float,
                 dt_s: float, config: DetectorConfig | None = None) -> None:
        for name, value, lo_open in (("k_f", k_f, True), ("thrust_max_n", thrust_max_n, True),
                                     ("motor_time_constant_s", motor_time_constant_s, False),
                                     ("dt_s", dt_s, True)):
            _check(name, value, {"lo": 0.0, "hi": None, "lo_open": lo_open}, integer=False)
        self.config = cfg = config if config is not None else DetectorConfig()
        self.k_f = float(k_f)
        self.thrust_max_n = float(thrust_max_n)
        self.tau_s = float(motor_time_constant_s) * cfg.model_time_constant_scale
        self.sigma_rpm = math.hypot(cfg.rpm_noise_std, RPM_QUANTISATION_STD)
        self.k = cfg.cusum_drift_sigma
        self.h = cfg.cusum_threshold_sigma
        self.z_cap = self.k + self.h / cfg.min_ticks
        tol = 1.0 + cfg.time_constant_tolerance
        sig2 = self.sigma_rpm ** 2
        omega_max = math.sqrt(self.thrust_max_n / self.k_f)
        self.params = DetectorParams(
            self.k_f, self.thrust_max_n, float(dt_s), self.tau_s > 0.0,
            tuple(self.tau_s * tol ** (j / 2) for j in range(-(N_MODELS // 2),
                                                            N_MODELS // 2 + 1)),
            sig2, math.sqrt(sig2 + 0.0), (omega_max * RADPS_TO_RPM) ** 2, self.k, self.z_cap,
            self.h * (1.0 - _ALARM_TOL), cfg.enabled)
        self.state: DetectorState = initial_state()
        self._out = DetectorOutput(0, math.nan, _ZERO4, _ZERO4, math.nan, False)
        self._core: Any = None
        self._attach()

    def _attach(self) -> None:
        """The compiled step: now if it is built (this process, the cache, or
        ``TFL_MAV_NATIVE=sync``), else when a background build completes (``auto``)."""
        if native.mode() == "off":
            return
        if _compiled["core"] is not None:
            self._core = _compiled["core"]
            return
        use_core = weakref.WeakMethod(self._use_core)    # a finished detector is not kept

        def ready(core: Any) -> None:
            _compiled["core"] = core
            use = use_core()
            if use is not None:
                use(core)

        example = (self.params, self.state, (0.0, _ZERO4, _ZERO4))
        core = native.obtain_function(detector_step, example, ready)
        if core is not None:
            ready(core)

    def _use_core(self, core: Any) -> None:
        self._core = core           # one reference store: atomic under the GIL

    def update(self, time_s: float, rpm_measured: Sequence[float],
               thrust_cmd_n: Sequence[float]) -> DetectorOutput:
        """One control tick.

        ``rpm_measured``: the four ESC speeds (rpm) sampled at ``time_s`` (s);
        ``thrust_cmd_n``: the four thrust commands (N) applied during the control period that
        ended at ``time_s``. A non-finite (or beyond ±10⁶ rpm) rpm sample is skipped for that
        rotor (counted). A non-finite ``time_s`` is taken as one ``dt_s`` after the previous
        tick (counted); a ``time_s`` not after the previous one (a duplicate or out-of-order
        sample) rejects the whole update (counted) and returns the previous verdict. Raises
        ValueError only for a wrong number of values.
        """
        if len(rpm_measured) != N_ROTORS:
            raise ValueError(f"rpm_measured: expected 4 values, got {len(rpm_measured)}")
        if len(thrust_cmd_n) != N_ROTORS:
            raise ValueError(f"thrust_cmd_n: expected 4 values, got {len(thrust_cmd_n)}")
        core = self._core
        r = core(self.params, self.state, (time_s, rpm_measured, thrust_cmd_n)) \
            if core is not None else None
        if r is None:       # no compiled step, or it declined: the Python step, same state
            r = detector_step(self.params, self.state, (
                float(time_s), tuple(map(float, rpm_measured)), tuple(map(float, thrust_cmd_n))))
        self.state, self._out = r
        return self._out

    def set_motors_off(self, off: bool) -> None:
        """The vehicle says whether a command drives its motors (ACTUATOR_OUTPUT_STATUS
        ``active``): while ``off``, :meth:`update` judges nothing (module docstring). Every
        statistic starts from zero when they are driven again."""
        self.state = motors_driven(self.state, bool(off))

    @property
    def output(self) -> DetectorOutput:
        """The latest verdict (what :meth:`update` last returned)."""
        return self._out

    @property
    def compiled(self) -> bool:
        """True when the step runs compiled."""
        return self._core is not None

    # The state's counts and verdict, as the detector's attributes.
    motors_off = property(lambda self: self.state.motors_off)
    detected_rotor = property(lambda self: self.state.detected_rotor)
    detection_time_s = property(lambda self: self.state.detection_time_s)
    estimate_n = property(lambda self: self.state.estimate_n)
    rejected_samples = property(lambda self: self.state.rejected)
    moves = property(lambda self: self.state.moves)
    releases = property(lambda self: self.state.releases)
    paused_ticks = property(lambda self: self.state.paused_ticks)
