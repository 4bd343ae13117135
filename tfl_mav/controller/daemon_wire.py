"""What the controller daemon (:mod:`tfl_mav.controller.daemon`) puts on the wire and hands its
recorder.

* :func:`command_message`: ``HIL_ACTUATOR_CONTROLS`` (``controls[0..3]`` = rotor thrust /
  f_max, ``time_usec`` echoing the state's, ``mode`` armed, ``flags`` bit 0 = lockstep);
* :func:`telemetry_messages`: ``NAMED_VALUE_FLOAT`` ``mode``, ``det_rotor``, ``atk_est_n``,
  ``path_m`` and ``DEBUG_FLOAT_ARRAY`` ``tfl`` (docs/design.md, "The wire");
* :func:`tick_state`: the controller's internals of one tick as the compact tuple the
  recorder's child names (:data:`TICK_FIELDS`) and encodes (``/controller/state``);
* :func:`applied_thrusts`: which command the vehicle held, from ACTUATOR_OUTPUT_STATUS;
* :class:`DaemonStats`, :class:`DaemonResult`: what a run counted and did; the waiting
  report's text (:func:`waiting_text`).

The messages are built as :class:`~tfl_mav.link.codec.LiteMessage` tuples in wire order and
packed by the link's codec with one ``struct.pack``: the same bytes as pymavlink's messages
with the same fields (tests/contract/test_codec.py), without pymavlink's constructors (a command and
the telemetry cost ~3× less to send).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

from tfl_mav.controller.flight_computer import TickResult
from tfl_mav.flightlog import schemas
from tfl_mav.link.codec import UNSENT, LiteMessage, lite_class
from tfl_mav.link.dialect import mav
from tfl_mav.model.modes import Mode

__all__ = ["LOCKSTEP_FLAG", "TICK_FIELDS", "TICK_SCHEMA", "DaemonResult", "DaemonStats",
           "applied_thrusts", "command_message", "motors_off", "telemetry_messages",
           "tick_state", "waiting_text"]

LOCKSTEP_FLAG = 1                 # HIL_ACTUATOR_CONTROLS.flags bit 0
_new = tuple.__new__
_Hil = lite_class(mav.MAVLINK_MSG_ID_HIL_ACTUATOR_CONTROLS)   # time_usec, flags, controls, mode
_NamedValueFloat = lite_class(mav.MAVLINK_MSG_ID_NAMED_VALUE_FLOAT)  # time_boot_ms, value, name
_DebugFloatArray = lite_class(mav.MAVLINK_MSG_ID_DEBUG_FLOAT_ARRAY)  # usec, array_id, name, data
_HIL_TAIL = (0.0,) * 12 + (mav.MAV_MODE_FLAG_SAFETY_ARMED, UNSENT)  # controls[4..15], mode
_TFL_ARRAY_LEN = 58                                                 # DEBUG_FLOAT_ARRAY.data


@dataclass
class DaemonStats:
    """Counters of one run (link counters are in ``link``)."""

    ticks: int = 0
    states: int = 0
    bad_states: int = 0
    esc_reports: int = 0
    bad_esc: int = 0
    ignored_messages: int = 0
    commands_sent: int = 0
    failsafes: int = 0
    recoveries: int = 0
    fallback_ticks: int = 0
    saturated_ticks: int = 0
    skipped_states: int = 0      # older states in a batch: the law ran on the newest only
    old_states: int = 0          # not newer than the last state controlled: dropped
    repeated_states: int = 0     # the last state again (lockstep resend): same command resent
    implausible_states: int = 0  # time too far ahead/behind the watermark: not controlled
    gap_ticks: int = 0           # ticks whose law integrated over more than one period
    degraded_episodes: int = 0   # runs of gaps, each ended by 1 s of sim time without one
    applied_from_history: int = 0  # applied command = our own copy (ACTUATOR_OUTPUT_STATUS)
    applied_from_wire: int = 0   # applied command = ACTUATOR_OUTPUT_STATUS.actuator × f_max
    applied_unknown: int = 0     # no ACTUATOR_OUTPUT_STATUS: last command sent assumed
    rebuilds: int = 0            # vehicle time went backwards: flight computer rebuilt
    law_errors: int = 0          # a tick the laws raised on: no command sent that tick
    motors_off_ticks: int = 0    # ticks the vehicle said no command drove its motors
    motors_off_periods: int = 0  # times that began (a GCS disarm, a cut, ...)
    link: dict[str, int] = field(default_factory=dict)


@dataclass
class DaemonResult:
    """What a run did, for the CLI summary and the demo."""

    reason: str
    sim_time_s: float
    wall_time_s: float
    detected_rotor: int
    detection_time_s: float
    attack_estimate_samples: int
    final_path_distance_m: float
    mode: str
    stats: DaemonStats

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


def command_message(time_usec: int, thrust_n: Sequence[float], thrust_max_n: float,
                    flags: int) -> LiteMessage:
    """HIL_ACTUATOR_CONTROLS answering the state of ``time_usec``: controls[0..3] = rotor
    thrust / f_max, controls[4..15] = 0, mode armed."""
    f1, f2, f3, f4 = thrust_n
    fmax = thrust_max_n
    return _new(_Hil, (time_usec, flags, f1 / fmax, f2 / fmax, f3 / fmax, f4 / fmax,
                       *_HIL_TAIL))


def telemetry_messages(time_usec: int, res: TickResult) -> list[LiteMessage]:
    """The controller's telemetry of one tick (the daemon sends it at ≤ 50 Hz of sim time),
    every value a float32 can carry (:func:`_f32`)."""
    out = res.law
    ms = (time_usec // 1000) & 0xFFFFFFFF
    det = res.detection
    est = det.estimate_n if det is not None else res.attack_estimate_n
    est = _f32(est, 0.0)
    dist = _f32(out.path_distance_m, -1.0)
    arr = [*out.xi[0], *out.xi[1], *out.eta[1:]]
    arr = [_f32(v, 0.0) for v in arr]
    arr += [0.0] * (_TFL_ARRAY_LEN - len(arr))
    return [
        *(_new(_NamedValueFloat, (ms, value, name, UNSENT))
          for name, value in ((b"mode", float(out.mode)),
                              (b"det_rotor", float(res.attack_rotor)),
                              (b"atk_est_n", est), (b"path_m", dist))),
        _new(_DebugFloatArray, (time_usec, 1, b"tfl", *arr[:_TFL_ARRAY_LEN], UNSENT))]


TICK_FIELDS = ("mode", "detected_rotor", "attack_estimate_n", "path_distance_m", "saturated",
               "rotor_thrust_cmd_n", "xi", "eta", "mass_estimate_kg", "fine_gains", "reason",
               "cusum")
"""Names of the values of :func:`tick_state`, in order (the recorder's ``controller_fields``)."""

TICK_SCHEMA = schemas.record_schema(
    "tfl_mav.ControllerState", "The controller's internals of one tick at sim time t_s", {
        "mode": {"type": "string", "description": "nominal, attacked, fallback or failsafe"},
        "detected_rotor": {"type": "integer", "minimum": 0, "maximum": 4,
                           "description": "rotor the detector isolated, 0 = none"},
        "attack_estimate_n": {"type": "number", "description": "estimated attack thrust (N)"},
        "path_distance_m": {"type": "number", "description": "distance to the path (m)"},
        "saturated": {"type": "boolean", "description": "a rotor command hit 0 or f_max"},
        "rotor_thrust_cmd_n": schemas.vec(4, "rotor thrust commands 1-4 (N)"),
        "eta": schemas.vec(None, "tangential chain η"),
        "mass_estimate_kg": {"type": "number", "description": "estimated mass (kg)"},
        "fine_gains": {"type": "boolean", "description": "fine gains engaged"},
        "reason": {"type": "string", "description": "why the law fell back, if it did"},
        "cusum": schemas.vec(None, "detector CUSUM statistic per rotor")}, [])
"""JSON Schema of ``/controller/state`` as the daemon records it (``xi``, the transversal
chains ξ1, ξ2 as two lists, is left untyped: Foxglove's JSON-schema reader takes no array of
arrays)."""


_MODE_NAMES = {mode: mode.name.lower() for mode in Mode}   # Enum.name is a Python property


def tick_state(res: TickResult) -> tuple[Any, ...]:
    """The controller's internals of one tick, compact: plain values in
    :data:`TICK_FIELDS` order (the recording child names them and encodes JSON).
    :meth:`~tfl_mav.controller.daemon.Daemon._control_newest` builds the same tuple written out
    (every tick): change both together."""
    out, det = res.law, res.detection
    est = det.estimate_n if det is not None else res.attack_estimate_n
    return (_MODE_NAMES[out.mode], res.attack_rotor, est, out.path_distance_m,
            any(out.saturated), res.thrust_n, out.xi, out.eta, out.mass_estimate_kg,
            out.fine_gains, out.reason, det.cusum if det is not None else ())


_F32_MAX = 3.4028234663852886e38


def _f32(value: float, unknown: float) -> float:
    """A telemetry float as the wire can carry it (float32): ``unknown`` for a value that is
    not finite or beyond float32's range (a state far outside any flight: the fuzzer sends
    them; packing it would raise, and the loop must not die)."""
    return value if math.isfinite(value) and abs(value) <= _F32_MAX else unknown


def applied_thrusts(msg: Any, history: dict[int, list[float]], hover: list[float] | None,
                    thrust_max_n: float, stats: DaemonStats) -> list[float]:
    """The thrusts (N) the vehicle held over the period that just ended, by
    ACTUATOR_OUTPUT_STATUS ``msg``: our own float64 copy of the command it names
    (``history``: time_usec → thrust_n), else its ``actuator[0..3]`` × f_max. ``hover``: the
    initial hover command while no state has been controlled yet, else None. Counted in
    ``stats`` (``applied_from_history``, ``applied_from_wire``)."""
    mine = history.get(msg.time_usec)
    if mine is not None and msg.time_usec != 0:
        stats.applied_from_history += 1
        return mine
    # time_usec 0: the command for t = 0, or none (before the first command: the initial
    # hover; motors cut; disarmed). The wire's thrusts say which; when they match our
    # float64 copy (to float32 precision) use the copy, so lockstep stays bit-identical.
    fmax = thrust_max_n
    wire = [min(max(float(a), 0.0), 1.0) * fmax if math.isfinite(a) else 0.0
            for a in msg.actuator[:4]]
    ref = mine if mine is not None else hover
    if ref is not None and all(abs(w - r) <= 1e-6 * fmax
                               for w, r in zip(wire, ref, strict=True)):
        stats.applied_from_history += 1
        return ref
    stats.applied_from_wire += 1
    return wire


_ACTIVE_ROTORS = 0b1111


def motors_off(msg: Any) -> bool:
    """ACTUATOR_OUTPUT_STATUS ``msg`` says no command drives the four motors (``active``
    clear: disarmed by a GCS or the controller, or cut; docs/design.md, "The wire")."""
    return not msg.active & _ACTIVE_ROTORS


def waiting_text(waited_s: float, link: Any, signed: bool) -> str:
    """Before the first state: what arrived on ``link`` and what to check."""
    st = link.stats
    host, port = link.peer or ("?", 0)
    text = (f"no vehicle state after {waited_s:.0f} s: {st.rx_frames} frames accepted, "
            f"{st.rejected} rejected from {host}:{port}")
    if signed:
        return text + (f" (signing: bad_signature {st.bad_signature}, unsigned {st.unsigned}, "
                       f"replayed {st.replayed}, bad_timestamp {st.bad_timestamp}); is the "
                       "vehicle running, with the same --key-file?")
    return text + "; is the vehicle running there (tfl-mav sim)?"
