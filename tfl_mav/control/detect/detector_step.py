"""The attack detector's law: explicit state and one pure step (:func:`detector_step`).

Plain Python over NamedTuples — floats, the counts as ints, the flags as bools; per-rotor
helpers, loops over the rotors and the lag models, a rotor's item read by its number — and
the only form the law is written in: :class:`~tfl_mav.control.detect.detector.AttackDetector`
holds the state and calls the step, compiled to C through the accelerator seam
(:func:`tfl_mav.accel.native.obtain_function`: the helpers inlined, the loops unrolled, the
tuples one float each — the same operations in the same order, the same bits, the same
types) where it is built, this very function otherwise. What the law does is said in
:mod:`detector`'s module docstring.
"""

from __future__ import annotations

import math
from typing import NamedTuple

__all__ = ["BAND_PAD", "N_MODELS", "N_ROTORS", "RADPS_TO_RPM", "RELEASE_TICKS",
           "RPM_TO_RADPS", "RPM_VALID_LIMIT", "DetectorOutput", "DetectorParams", "DetectorState",
           "RotorState",
           "detector_step", "initial_state"]

RPM_TO_RADPS = 2.0 * math.pi / 60.0
RADPS_TO_RPM = 60.0 / (2.0 * math.pi)
N_ROTORS = 4
N_MODELS = 5   # lag models of the band (τ spaced geometrically)
# The band of models (τ over [τ/(1+tol), τ(1+tol)]) is widened by this fraction of its width
# on each side: ω(t; τ) is not monotone in τ under a varying command, and on random sines,
# chirps and 0↔f_max square waves (τ = 5-80 ms, tol = 0.3) the response for any τ in the
# range never left the band widened by 0.1 (0.25 keeps a margin).
BAND_PAD = 0.25
# A speed beyond any ESC's range is a corrupt sample, not a rotor state (rejected like NaN).
RPM_VALID_LIMIT = 1.0e6
# Consecutive obeying samples that release a latched rotor: 50 ticks (50 ms at 1 kHz) of
# |z| < k is a false-release probability of ~P(|N(0,1)| < 2)^50 ≈ 0.1 for a rotor whose
# speed merely sits near the probe by chance, and none while it is held elsewhere.
RELEASE_TICKS = 50


class DetectorParams(NamedTuple):
    """The detector's constants (the motor model's and the tuning's, derived once)."""

    k_f: float                  # thrust coefficient, N/(rad/s)²
    thrust_max_n: float         # f_max (N): the motor clamps its command to [0, f_max]
    dt_s: float                 # control period (s): a tick whose time is not finite
    lagged: bool                # τ_m > 0: the band of lag models; else the command's speed
    taus_s: tuple[float, ...]   # the N_MODELS models' τ (s), τ/(1+tol) … τ(1+tol)
    sig2_rpm2: float            # σ² of one rpm sample (noise and uint16 quantisation), rpm²
    sd0_rpm: float              # √(σ² + 0): the residual's std without lag (rpm)
    var_unknown_rpm2: float     # an unknown start's variance: (ω_max in rpm)²
    k: float                    # CUSUM drift k (σ)
    z_cap: float                # one sample's largest contribution, k + h/min_ticks (σ)
    h_alarm: float              # the threshold h, less a relative 1e-9 of rounding slack (σ)
    enabled: bool               # False: the statistics run, no verdict is ever made


class RotorState(NamedTuple):
    """One rotor's part of the state."""

    band_radps: tuple[float, ...]   # the speed each lag model predicts (rad/s)
    var_rpm2: float                 # the variance of the band's start, decaying with the lag
    s_hi: float                     # CUSUM S⁺ (σ)
    s_lo: float                     # CUSUM S⁻ (σ)
    z: float                        # the last normalised residual (σ): isolation's ties
    rpm: float                      # the last valid rpm sample: the estimate's
    resid_n: float                  # k_f (ω_meas² − ω_model²) (N), for logs


class DetectorState(NamedTuple):
    """Everything the detector remembers between ticks."""

    rotors: tuple[RotorState, ...]
    cmd_n: tuple[float, ...]        # the last valid command per rotor (N)
    last_time_s: float
    started: bool                   # a tick was taken
    detected_rotor: int             # 0 = none, else 1-4 (latched)
    detection_time_s: float         # NaN before
    estimate_n: float               # the latched rotor's thrust from its rpm (N); NaN before
    obey: int                       # consecutive samples of the latched rotor obeying
    rejected: int                   # non-finite rpm/command samples and bad updates
    moves: int                      # alarms on another rotor while one was latched
    releases: int
    paused_ticks: int               # ticks judged nothing: the motors were not driven
    motors_off: bool                # the vehicle says no command drives the motors


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


def initial_state() -> DetectorState:
    rotor = RotorState((0.0,) * N_MODELS, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    return DetectorState((rotor,) * N_ROTORS, (0.0,) * N_ROTORS, 0.0, False, 0, math.nan,
                         math.nan, 0, 0, 0, 0, 0, False)


def omega_target(p: DetectorParams, thrust_n: float) -> float:
    """Steady speed (rad/s) for a command, clamped like the motor clamps it."""
    return math.sqrt(min(max(thrust_n, 0.0), p.thrust_max_n) / p.k_f)


def _cusum(p: DetectorParams, s_hi: float, s_lo: float, z: float) -> tuple[float, float]:
    """S⁺ ← max(0, S⁺ + z − k), S⁻ ← max(0, S⁻ − z − k), z capped at ±z_cap."""
    zc = min(max(z, -p.z_cap), p.z_cap)
    return max(0.0, s_hi + zc - p.k), max(0.0, s_lo - zc - p.k)


def _judged(p: DetectorParams, rs: RotorState, rpm: float, w_radps: float, wm_radps: float,
            sd_rpm: float) -> RotorState:
    """A valid sample judged against the model speed ``w_radps``."""
    z = (rpm - w_radps * RADPS_TO_RPM) / sd_rpm
    s_hi, s_lo = _cusum(p, rs.s_hi, rs.s_lo, z)
    return RotorState(rs.band_radps, rs.var_rpm2, s_hi, s_lo, z, rpm,
                      p.k_f * (wm_radps * wm_radps - w_radps * w_radps))


def _rotor_instant(p: DetectorParams, rs: RotorState, rpm: float, cmd_n: float,
                   valid: bool) -> RotorState:
    """No lag: the model speed is the command's."""
    if valid:
        rs = _judged(p, rs, rpm, omega_target(p, cmd_n), rpm * RPM_TO_RADPS, p.sd0_rpm)
    return rs


def _rotor_lagged(p: DetectorParams, rs: RotorState, rpm: float, cmd_n: float, valid: bool,
                  first: bool, decay: tuple[float, ...]) -> RotorState:
    """The band of lag models: started from the measurement on the first tick, else each
    model's lag solution with the command held (``decay``: exp(−dt/τ_j)); a valid sample
    is judged against the nearest speed of the padded band."""
    band, var = rs.band_radps, rs.var_rpm2
    if first:       # ω before any lag acts; an unknown start is as uncertain as the range
        w0 = max(rpm, 0.0) * RPM_TO_RADPS if valid else omega_target(p, cmd_n)
        band = (w0,) * N_MODELS
        var = p.sig2_rpm2 if valid else p.var_unknown_rpm2
    else:
        c = omega_target(p, cmd_n)
        band = tuple(c + (band[j] - c) * decay[j] for j in range(N_MODELS))
        var = var * (decay[N_MODELS - 1] * decay[N_MODELS - 1])  # the slowest forgets slowest
    rs = RotorState(band, var, rs.s_hi, rs.s_lo, rs.z, rs.rpm, rs.resid_n)
    if valid:
        lo, hi = min(band), max(band)
        pad = BAND_PAD * (hi - lo)
        wm = rpm * RPM_TO_RADPS
        w = min(max(wm, lo - pad), hi + pad)            # the nearest speed of the band
        rs = _judged(p, rs, rpm, w, wm, math.sqrt(p.sig2_rpm2 + var))
    return rs


def _isolate(rotors: tuple[RotorState, ...], latched: int) -> int:
    """The rotor with the largest statistic, ties to the larger |z| then the later rotor,
    the latched one left out: ``max((max(S⁺, S⁻), |z|, i))`` over the others."""
    best, best_abs, rotor = 0.0, 0.0, 0
    for i in range(N_ROTORS):
        r = rotors[i]
        m, a = max(r.s_hi, r.s_lo), abs(r.z)
        if latched != i + 1 and (rotor == 0 or m > best or (m == best and a >= best_abs)):
            best, best_abs, rotor = m, a, i + 1
    return rotor


def _fresh(rotors: tuple[RotorState, ...]) -> tuple[RotorState, ...]:
    """The rotors with their statistics at zero (the band and the samples kept)."""
    return tuple(RotorState(r.band_radps, r.var_rpm2, 0.0, 0.0, r.z, r.rpm, r.resid_n)
                 for r in rotors)


def motors_driven(state: DetectorState, off: bool) -> DetectorState:
    """The state once the vehicle says whether a command drives the motors: every
    statistic from zero either way."""
    return state._replace(rotors=_fresh(state.rotors), obey=0, motors_off=off)


def detector_step(p: DetectorParams, s: DetectorState,
                  inputs: tuple[float, tuple[float, ...], tuple[float, ...]]
                  ) -> tuple[DetectorState, DetectorOutput]:
    """One control tick: ``inputs`` = (time_s (s), the four ESC speeds (rpm) sampled then,
    the four thrust commands (N) applied over the period that ended then).

    Returns the new state and the verdict (:class:`DetectorOutput`). A non-finite time is
    one ``dt_s`` after the last tick; a time not after the last one rejects the whole tick
    (the state kept, the verdict reissued)."""
    t, rpm, cmd_in = inputs
    rejected = s.rejected
    rotors, cmd, detected = s.rotors, s.cmd_n, s.detected_rotor
    estimate, detection_time, obey = s.estimate_n, s.detection_time_s, s.obey
    moves, releases, paused = s.moves, s.releases, s.paused_ticks
    last, started = s.last_time_s, s.started
    alarm, released = False, False
    take = True
    if not math.isfinite(t):
        rejected += 1
        t = last + p.dt_s if started else 0.0
    elif started and t <= last:         # a duplicate or out-of-order sample
        rejected += 1
        take = False
    if take:
        lim = RPM_VALID_LIMIT
        valid = tuple(-lim <= rpm[i] <= lim for i in range(N_ROTORS))     # NaN fails too
        for i in range(N_ROTORS):
            if not valid[i]:
                rejected += 1
            if not math.isfinite(cmd_in[i]):    # the vehicle keeps the last command
                rejected += 1
        cmd = tuple(cmd_in[i] if math.isfinite(cmd_in[i]) else cmd[i] for i in range(N_ROTORS))
        if p.lagged:
            decay = (1.0,) * N_MODELS
            if started:
                dt = t - last
                decay = tuple(math.exp(-dt / tau) for tau in p.taus_s)
            rotors = tuple(_rotor_lagged(p, rotors[i], rpm[i], cmd[i], valid[i], not started,
                                         decay) for i in range(N_ROTORS))
        else:
            rotors = tuple(_rotor_instant(p, rotors[i], rpm[i], cmd[i], valid[i])
                           for i in range(N_ROTORS))
        last, started = t, True
        if s.motors_off:                # no evidence either way: the statistics stay at 0
            paused += 1
            rotors = _fresh(rotors)
            obey = 0
        elif p.enabled:
            top = max(0.0 if detected == i + 1 else max(rotors[i].s_lo, rotors[i].s_hi)
                      for i in range(N_ROTORS))
            if top >= p.h_alarm:
                if detected:
                    moves += 1                  # the attacker moved
                detected = _isolate(rotors, detected)
                detection_time = t
                obey = 0
                rotors = _fresh(rotors)         # a fresh start: the old evidence is spent
                alarm = True
            elif detected:
                z = rotors[detected - 1].z
                obey = obey + 1 if abs(z) < p.k else 0
                if obey >= RELEASE_TICKS:       # it follows its commands again
                    releases += 1
                    detected = 0
                    estimate = math.nan
                    rotors = _fresh(rotors)
                    released = True
        if detected:
            w = max(rotors[detected - 1].rpm, 0.0) * RPM_TO_RADPS
            estimate = min(p.k_f * w * w, p.thrust_max_n)
    state = DetectorState(rotors, cmd, last, started, detected, detection_time, estimate,
                          obey, rejected, moves, releases, paused, s.motors_off)
    cusum = tuple(r.s_hi if r.s_hi >= r.s_lo else -r.s_lo for r in rotors)
    return state, DetectorOutput(detected, estimate, tuple(r.resid_n for r in rotors), cusum,
                                 detection_time, alarm, rejected, released)
