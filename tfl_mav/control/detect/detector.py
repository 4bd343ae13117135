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
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, fields
from typing import Any, NamedTuple

from tfl_mav.control.detect import detector_native
from tfl_mav.control.detect.detector_kernel import (
    N_MODELS,
    RADPS_TO_RPM,
    RPM_TO_RADPS,
    python_kernel,
)

__all__ = ["RPM_QUANTISATION_STD", "AttackDetector", "DetectorConfig", "DetectorOutput"]

# ESC_TELEMETRY_1_TO_4 carries rpm as uint16: rounding adds uniform noise of std 1/√12 rpm.
RPM_QUANTISATION_STD = 1.0 / math.sqrt(12.0)
# A speed beyond any ESC's range is a corrupt sample, not a rotor state (rejected like NaN).
RPM_VALID_LIMIT = 1.0e6
_ALARM_TOL = 1e-9  # relative slack so min_ticks capped increments reach h despite rounding
# Consecutive obeying samples that release a latched rotor: 50 ticks (50 ms at 1 kHz) of
# |z| < k is a false-release probability of ~P(|N(0,1)| < 2)^50 ≈ 0.1 for a rotor whose
# speed merely sits near the probe by chance, and none while it is held elsewhere.
RELEASE_TICKS = 50


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


class DetectorOutput(NamedTuple):
    """The detector's verdict after one tick (a named tuple: made every tick, and a tuple
    is built several times faster than a frozen dataclass)."""

    detected_rotor: int                  # 0 = none, else 1-4 (latched)
    estimate_n: float                    # attacked rotor's thrust from its rpm (N); NaN before
    residuals_n: tuple[float, ...]       # k_f (ω_meas² − ω_model²) per rotor (N), ω_model the
                                         # nearest speed of the lag band; for logs
    cusum: tuple[float, ...]             # larger one-sided statistic (σ); sign + = faster
    detection_time_s: float              # time of the alarm tick (s); NaN before
    alarm: bool                          # True only on the tick of detection
    rejected_samples: int = 0            # non-finite rpm/command samples and bad updates
    released: bool = False               # True only on the tick a latched rotor was released


_ZERO4 = (0.0, 0.0, 0.0, 0.0)
_isfinite = math.isfinite
_new = tuple.__new__


class AttackDetector:
    """Per-rotor motor-model residual + two-sided CUSUM; see the module docstring.

    ``k_f`` N/(rad/s)², ``thrust_max_n`` N, ``motor_time_constant_s`` the vehicle's τ_m (s;
    the model uses ``config.model_time_constant_scale`` × it), ``dt_s`` the control period
    (s; the lag is propagated over the elapsed ``time_s``, and over ``dt_s`` for a tick whose
    time is not finite).
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
        self.dt_s = float(dt_s)
        self.tau_s = float(motor_time_constant_s) * cfg.model_time_constant_scale
        self.sigma_rpm = math.hypot(cfg.rpm_noise_std, RPM_QUANTISATION_STD)
        self.k = cfg.cusum_drift_sigma
        self.h = cfg.cusum_threshold_sigma
        self.z_cap = self.k + self.h / cfg.min_ticks
        self._omega_max = math.sqrt(self.thrust_max_n / self.k_f)
        tol = 1.0 + cfg.time_constant_tolerance
        self._taus = tuple(self.tau_s * tol ** (j / 2) for j in range(-2, 3))
        self._sig2 = self.sigma_rpm ** 2
        self._rotors = python_kernel(self.tau_s > 0.0)   # the four rotors' tick (generated)
        # the compiled lagged tick itself (detector_native.attach sets it): update calls it
        # directly, state in and out (what detector_native's caller does, written out)
        self._core: Any = None
        self._sd0 = math.sqrt(self._sig2 + 0.0)   # the residual's std without lag
        self._h_alarm = self.h * (1.0 - _ALARM_TOL)
        # The per-rotor state as float tuples, rotor-major (read and rewritten whole each
        # tick by _rotors): per rotor the speed (rad/s) each model of the band predicts
        # (τ/tol … τ·tol), the variance of the band's start (rpm², decays with the lag), the
        # CUSUM statistics, the last residuals, normalised residual (σ, for isolation ties)
        # and finite rpm sample (for the estimate).
        self._band: tuple[float, ...] = (0.0,) * (4 * N_MODELS)
        self._var = self._s_hi = self._s_lo = self._resid = self._z = self._rpm = _ZERO4
        # exp(−dt/τ_j) per elapsed dt: the sim's tick times are float sums, so dt takes a
        # handful of values a bit apart (14 in the paper flight): each computed once.
        self._decays: dict[float, tuple[float, ...]] = {}
        self._cmd = _ZERO4              # last valid command (N)
        self._last_time: float | None = None
        self.rejected_samples = 0
        self.detected_rotor = 0
        self.detection_time_s = math.nan
        self.estimate_n = math.nan
        self._obey = 0
        self.moves = 0
        self.releases = 0
        self.motors_off = False         # the vehicle says no command drives the motors
        self.paused_ticks = 0           # ticks judged nothing because of that
        self._out = DetectorOutput(0, math.nan, _ZERO4, _ZERO4, math.nan, False)
        detector_native.attach(self, self.tau_s > 0.0)    # compiled, where it can be

    # ------------------------------------------------------------------ model
    def _omega_target(self, thrust_n: float) -> float:
        """Steady speed (rad/s) for a command, clamped like the motor clamps it."""
        return math.sqrt(min(max(thrust_n, 0.0), self.thrust_max_n) / self.k_f)

    def _start(self, rpm: Sequence[float], cmd: Sequence[float]) -> None:
        """First tick with lag: the motor state from the measurement (ω before any lag
        acts)."""
        band, var = [], []
        for i in range(4):
            if not math.isnan(rpm[i]):
                w, v = max(rpm[i], 0.0) * RPM_TO_RADPS, self.sigma_rpm ** 2
            else:           # unknown start: the model is as uncertain as the rotor's range
                w, v = self._omega_target(cmd[i]), (self._omega_max * RADPS_TO_RPM) ** 2
            band += [w] * N_MODELS
            var.append(v)
        self._band, self._var = tuple(band), tuple(var)

    # ------------------------------------------------------------------ update
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

        Runs every tick, so the four rotors' model, residual and CUSUM are straight-line
        float code (generated once from one rotor's template: :func:`_rotors_source`); the
        isolation runs only on a tick whose largest statistic reaches ``h``. The same
        floating-point operations, in the same order, as the step-by-step form
        (the golden flights are bit-identical).
        """
        if len(rpm_measured) != 4:
            raise ValueError(f"rpm_measured: expected 4 values, got {len(rpm_measured)}")
        if len(thrust_cmd_n) != 4:
            raise ValueError(f"thrust_cmd_n: expected 4 values, got {len(thrust_cmd_n)}")
        t = float(time_s)
        last = self._last_time
        if not _isfinite(t):
            self.rejected_samples += 1
            t = last + self.dt_s if last is not None else 0.0
        elif last is not None and t <= last:
            self.rejected_samples += 1
            return self._reissue(alarm=False)
        lim = RPM_VALID_LIMIT
        r0, r1, r2, r3 = map(float, rpm_measured)      # float() each, in C
        if not (-lim <= r0 <= lim and -lim <= r1 <= lim and -lim <= r2 <= lim
                and -lim <= r3 <= lim):                 # NaN fails too
            r0, r1, r2, r3 = (r if -lim <= r <= lim else math.nan for r in (r0, r1, r2, r3))
        c0, c1, c2, c3 = map(float, thrust_cmd_n)
        if _isfinite(c0 + c1 + c2 + c3):        # a finite sum: all four finite
            self._cmd = (c0, c1, c2, c3)
        else:
            cmd = list(self._cmd)           # the last valid command per rotor
            for i, f in enumerate((c0, c1, c2, c3)):
                if math.isfinite(f):
                    cmd[i] = f
                else:       # the vehicle rejects a non-finite command and keeps the last one
                    self.rejected_samples += 1
            self._cmd = cmd_t = tuple(cmd)
            c0, c1, c2, c3 = cmd_t
        self._last_time = t
        if self.tau_s <= 0.0:           # no lag: the speed is the command's, every tick
            top = self._rotors(self, r0, r1, r2, r3, c0, c1, c2, c3)
        else:
            decay = None
            if last is None:
                self._start((r0, r1, r2, r3), (c0, c1, c2, c3))
            else:
                dt = t - last
                decay = self._decays.get(dt)
                if decay is None:
                    if len(self._decays) >= 1024:   # a clock with many distinct periods
                        self._decays.clear()
                    decay = self._decays[dt] = tuple(math.exp(-dt / tau_j)
                                                     for tau_j in self._taus)
            core = self._core
            if core is None:        # no compiled tick: the Python one
                top = self._rotors(self, r0, r1, r2, r3, c0, c1, c2, c3, decay)
            elif (r := core(self._band, self._sig2, self.thrust_max_n, self._s_hi, self._s_lo,
                            self._z, self._rpm, self._resid, self._var, self.k, self.z_cap,
                            self.k_f, self.detected_rotor, r0, r1, r2, r3, c0, c1, c2, c3,
                            decay)) is None:    # it declined: the Python tick, same state
                top = python_kernel(True)(self, r0, r1, r2, r3, c0, c1, c2, c3, decay)
            else:
                (top, nrej, self._band, self._s_hi, self._s_lo, self._z, self._rpm,
                 self._resid, self._var) = r
                if nrej:
                    self.rejected_samples += int(nrej)

        alarm = False
        released = False
        d = self.detected_rotor
        if self.motors_off:     # no evidence either way: the statistics stay at zero
            self.paused_ticks += 1
            self._s_hi = self._s_lo = _ZERO4
            self._obey = 0
        elif self.config.enabled:
            if top >= self._h_alarm:
                if d:
                    self.moves += 1             # the attacker moved
                s_his, s_los, zs = self._s_hi, self._s_lo, self._z
                _, _, rotor = max((max(s_his[i], s_los[i]), abs(zs[i]), i + 1)
                                  for i in range(4) if i + 1 != d)
                self._latch(rotor, t)
                alarm = True
            elif d:
                self._obey = self._obey + 1 if abs(self._z[d - 1]) < self.k else 0
                if self._obey >= RELEASE_TICKS:             # it follows its commands again
                    self.releases += 1
                    self.detected_rotor = 0
                    self.estimate_n = math.nan
                    self._s_hi = self._s_lo = _ZERO4
                    released = True
        d = self.detected_rotor
        if d:
            w = self._rpm[d - 1]
            w = (0.0 if w < 0.0 else w) * RPM_TO_RADPS     # max(w, 0.0), NaN and -0.0 alike
            f = self.k_f * w * w
            fmax = self.thrust_max_n
            self.estimate_n = fmax if fmax < f else f      # min(f, fmax), alike
        # _reissue, written out (every tick)
        h0, h1, h2, h3 = self._s_hi
        l0, l1, l2, l3 = self._s_lo
        # DetectorOutput(...) without its generated Python __new__: all eight fields
        self._out = out = _new(DetectorOutput, (
            d, self.estimate_n, self._resid,
            (h0 if h0 >= l0 else -l0, h1 if h1 >= l1 else -l1, h2 if h2 >= l2 else -l2,
             h3 if h3 >= l3 else -l3), self.detection_time_s, alarm, self.rejected_samples,
            released))
        return out

    def set_motors_off(self, off: bool) -> None:
        """The vehicle says whether a command drives its motors (ACTUATOR_OUTPUT_STATUS
        ``active``): while ``off``, :meth:`update` judges nothing (module docstring). Every
        statistic starts from zero when they are driven again."""
        self.motors_off = bool(off)
        self._s_hi = self._s_lo = _ZERO4
        self._obey = 0

    def _latch(self, rotor: int, t: float) -> None:
        self.detected_rotor = rotor
        self.detection_time_s = t
        self._obey = 0
        self._s_hi = self._s_lo = _ZERO4   # a fresh start: the old rotor's evidence is spent

    def _reissue(self, alarm: bool, released: bool = False) -> DetectorOutput:
        h0, h1, h2, h3 = self._s_hi
        l0, l1, l2, l3 = self._s_lo
        cusum = (h0 if h0 >= l0 else -l0, h1 if h1 >= l1 else -l1,
                 h2 if h2 >= l2 else -l2, h3 if h3 >= l3 else -l3)
        self._out = out = DetectorOutput(self.detected_rotor, self.estimate_n, self._resid,
                                         cusum, self.detection_time_s, alarm,
                                         self.rejected_samples, released)
        return out

    @property
    def output(self) -> DetectorOutput:
        """The latest verdict (what :meth:`update` last returned)."""
        return self._out
