"""The state the controller receives every control tick: ODOMETRY, ACTUATOR_OUTPUT_STATUS,
ESC_TELEMETRY_1_TO_4, in that order, in one datagram (the ESC report completes the tick).

``ODOMETRY``: ``time_usec`` = the tick's sim time, LOCAL_NED pose and BODY_FRD twist of the
*measured* state (the scenario's seeded sensor noise), covariances σ² on the diagonal from
the scenario's noise levels, estimator MOCAP, quality 100.

``ESC_TELEMETRY_1_TO_4``: per ESC the true rotor speed as the ESC measures it (rpm, with the
scenario's rpm noise), battery voltage (cV), current (cA), consumed charge (mAh) and
temperature (°C) from :mod:`tfl_mav.sitl.power`, and a message counter (the same for all four,
wrapping at 2¹⁶). Every field is clamped to its wire type.

``ACTUATOR_OUTPUT_STATUS`` says which command the rpm answer to: ``time_usec`` =
the ``time_usec`` of the HIL_ACTUATOR_CONTROLS held over the period that just ended (0 =
none: before the first command, motors cut, disarmed), ``actuator[0..3]`` = the thrust
fractions actually driven (0 when cut), ``active`` = 0b1111 while a command (or the initial
hover) drives the motors, 0 while none does: cut, disarmed by the controller or by a GCS
(PX4 streams the same message for its outputs). A late, lost or reordered command is then
never mistaken for a rotor that disobeys, and ``active`` = 0 tells the controller that no
rotor obeys or disobeys anything (its detector pauses rather than judge stopped motors).

The triple is built once per tick (:meth:`StateReport.build`) and kept, so a lockstep resend
sends the same messages again and the GCS telemetry can forward the tick's ESC message.
"""

from __future__ import annotations

import math
import struct
from typing import Any

from tfl_mav.link.codec import Prepacked, prepacked_class, trim
from tfl_mav.link.dialect import mav
from tfl_mav.model.frames import MAV_FRAME_BODY_FRD, MAV_FRAME_LOCAL_NED
from tfl_mav.scenario import SensorConfig
from tfl_mav.sitl.estimator import EstimatorOutput
from tfl_mav.sitl.power import PowerModel
from tfl_mav.sitl.simulator import Simulator

__all__ = ["StateReport"]

# ODOMETRY covariance arrays: upper triangle of a 6×6 matrix, row-major; diagonal indices.
_COV_DIAGONAL = (0, 6, 11, 15, 18, 20)
_ACTIVE = 0b1111          # ACTUATOR_OUTPUT_STATUS.active: outputs 1-4 in use
_PAD28 = (0.0,) * 28     # ACTUATOR_OUTPUT_STATUS.actuator[4..31]
_MOCAP = mav.MAV_ESTIMATOR_TYPE_MOCAP
_GPS_INS = mav.MAV_ESTIMATOR_TYPE_GPS_INS
_SQRT1_2 = math.sqrt(0.5)
_new = tuple.__new__
_trim = trim
_round = float.__round__
_Odometry = prepacked_class(mav.MAVLINK_MSG_ID_ODOMETRY)
_Applied = prepacked_class(mav.MAVLINK_MSG_ID_ACTUATOR_OUTPUT_STATUS)
_Esc = prepacked_class(mav.MAVLINK_MSG_ID_ESC_TELEMETRY_1_TO_4)
# The wire formats (pymavlink's, little-endian, no padding) split where the values that
# change every tick end: a format is the concatenation of its parts' bytes.
_odometry_head = struct.Struct("<Q13f").pack          # time_usec .. yawspeed
_odometry_tail = struct.Struct("<42fBBBBb").pack      # covariances .. quality
_applied_head = struct.Struct("<QI4f").pack           # time_usec, active, actuator[0..3]
_esc_pack = mav.mavlink_map[mav.MAVLINK_MSG_ID_ESC_TELEMETRY_1_TO_4].unpacker.pack
assert (mav.mavlink_map[mav.MAVLINK_MSG_ID_ODOMETRY].unpacker.format
        == "<Qfff4fffffff21f21fBBBBb")
assert mav.mavlink_map[mav.MAVLINK_MSG_ID_ACTUATOR_OUTPUT_STATUS].unpacker.format == "<QI32f"


class StateReport:
    """Builds and keeps the current tick's (ODOMETRY, ACTUATOR_OUTPUT_STATUS,
    ESC_TELEMETRY_1_TO_4).

    The messages are :class:`~tfl_mav.link.codec.Prepacked`: the payload packed here
    straight from the simulator's floats (the values that change with one ``struct.pack``,
    ODOMETRY's constant tail packed once), so the link only frames it, into the bytes
    pymavlink's message with the same fields packs to (pymavlink's constructor and
    attribute-by-attribute packing were half the vehicle's non-physics cost per tick; the
    LiteMessage tuple of ~100 values, re-packed on every send, was most of what was left).
    """

    def __init__(self, sim: Simulator, power: PowerModel, sensors: SensorConfig) -> None:
        self.sim = sim
        self.power = power
        pose_cov = _covariance((sensors.position_noise_std_m,) * 3
                               + (sensors.attitude_noise_std_rad,) * 3)
        vel_cov = _covariance((sensors.velocity_noise_std_mps,) * 3
                              + (sensors.rate_noise_std_radps,) * 3)
        # ODOMETRY after yawspeed: covariances, frame ids, reset_counter, estimator, quality
        self._odometry_tail = (*pose_cov, *vel_cov, MAV_FRAME_LOCAL_NED, MAV_FRAME_BODY_FRD,
                               0, _MOCAP, 100)
        self._odometry_tail_bytes = _odometry_tail(*self._odometry_tail)
        self._esc_count = 0
        self.latest: tuple[Any, Any, Any] | None = None
        """The last tick's (ODOMETRY, ACTUATOR_OUTPUT_STATUS, ESC_TELEMETRY_1_TO_4) as
        Prepacked messages, or None before the first."""

    @property
    def esc(self) -> Any | None:
        """The last tick's ESC_TELEMETRY_1_TO_4, or None before the first tick."""
        return self.latest[-1] if self.latest is not None else None

    def build(self, applied_usec: int = 0, driven: bool = True
              ) -> tuple[Prepacked, Prepacked, Prepacked]:
        """Build (and keep as :attr:`latest`) the current tick's messages from the simulator
        and the power model; ``applied_usec``: time_usec of the command held over the period
        just ended (0: none); ``driven``: False while no command drives the motors (cut,
        disarmed: ACTUATOR_OUTPUT_STATUS.active 0). Immutable, and already packed: each is a
        :class:`~tfl_mav.link.codec.Prepacked`, its payload packed here with one
        ``struct.pack`` of the values that change (the constant tails packed once), the
        link only frames it; its fields read as the LiteMessage's would."""
        sim = self.sim
        # float tuples: no arrays to build and convert back, no State either
        (px, py, pz), (vx, vy, vz), (w, x, y, z), (p, q, r) = sim.measured_parts
        # tfl_mav.model.frames.odometry_from_paper written out (the same operations in the same
        # order): paper ENU/FLU → NED pose, body-FRD twist
        vb1 = (1 - 2 * (y * y + z * z)) * vx + 2 * (x * y + w * z) * vy + 2 * (x * z - w * y) * vz
        vb2 = 2 * (x * y - w * z) * vx + (1 - 2 * (x * x + z * z)) * vy + 2 * (y * z + w * x) * vz
        vb3 = 2 * (x * z + w * y) * vx + 2 * (y * z - w * x) * vy + (1 - 2 * (x * x + y * y)) * vz
        s = _SQRT1_2
        head = (sim.time_usec, py, px, -pz, s * (w + z), s * (x + y), s * (x - y), s * (w - z),
                vb1, -vb2, -vb3, p, -q, -r)
        if sim.estimate is None:
            odometry = _new(_Odometry, (_odometry_head(*head) + self._odometry_tail_bytes,
                                        head, self._odometry_tail))
        else:   # the onboard estimator's: its covariance, GPS_INS, this tick
            tail = _estimate_tail(sim.estimate, (w, x, y, z))
            odometry = _new(_Odometry, (_odometry_head(*head) + _odometry_tail(*tail), head,
                                        tail))
        volts, (i1, i2, i3, i4), (q1, q2, q3, q4), (t1, t2, t3, t4), _ = self.power.sample
        r1, r2, r3, r4 = sim.measured_rpm_floats
        self._esc_count = n = (self._esc_count + 1) & 0xFFFF
        # Written out, one round() a field (a list through map() and the range scans cost
        # as much again): voltage (cV), current (cA), consumed (mAh), rpm are ≥ 0 here and
        # clamped to uint16, temperature (°C) to uint8, only when out of range. The values
        # are floats: float.__round__ called directly is round() without its lookup of
        # __round__ (~2.5× cheaper, the same int, the same errors for NaN and inf).
        cv = _round(volts * 100.0)
        if cv > 65535:
            cv = 65535
        u16 = (_round(i1 * 100.0), _round(i2 * 100.0), _round(i3 * 100.0), _round(i4 * 100.0),
               _round(q1), _round(q2), _round(q3), _round(q4),
               _round(r1), _round(r2), _round(r3), _round(r4))
        if max(u16) > 65535:
            u16 = tuple([65535 if v > 65535 else v for v in u16])
        d1, d2, d3, d4 = _round(t1), _round(t2), _round(t3), _round(t4)
        if not (0 <= d1 <= 255 and 0 <= d2 <= 255 and 0 <= d3 <= 255 and 0 <= d4 <= 255):
            d1, d2, d3, d4 = [0 if v < 0 else 255 if v > 255 else v for v in (d1, d2, d3, d4)]
        values = (cv, cv, cv, cv, *u16, n, n, n, n, d1, d2, d3, d4)
        esc = _new(_Esc, (_trim(_esc_pack(*values)), values, ()))
        fmax = sim.thrust_max_n
        f1, f2, f3, f4 = sim.rotor_commands_n
        head = (applied_usec, _ACTIVE if driven else 0, f1 / fmax, f2 / fmax, f3 / fmax, f4 / fmax)
        # actuator[4..31] are zeros: the trimmed payload is the trimmed head's
        applied = _new(_Applied, (_trim(_applied_head(*head)), head, _PAD28))
        self.latest = (odometry, applied, esc)
        return self.latest

    def update(self, applied_usec: int = 0, driven: bool = True) -> tuple[Any, Any, Any]:
        """:meth:`build`, answered as pymavlink's message objects (mutable, e.g. for a
        test that restamps ``time_usec``); :attr:`latest` keeps the Prepacked messages."""
        return tuple(_pymavlink(msg) for msg in self.build(applied_usec, driven))  # type: ignore


def _pymavlink(msg: Prepacked) -> Any:
    """pymavlink's message with a Prepacked message's fields (packs to the same bytes)."""
    cls = mav.mavlink_map[msg.get_msgId()]
    return cls(**{name: getattr(msg, name) for name in msg.get_fieldnames()})


def _covariance(stds: tuple[float, ...]) -> list[float]:
    """ODOMETRY covariance array (21 floats, 6×6 upper triangle) with σ² on the diagonal."""
    cov = [0.0] * 21
    for index, std in zip(_COV_DIAGONAL, stds, strict=True):
        cov[index] = std * std
    return cov


def _estimate_tail(est: EstimatorOutput, q: tuple[float, float, float, float]
                   ) -> tuple[Any, ...]:
    """ODOMETRY's tail from the onboard estimate: the pose covariance (NED position: the
    paper frame's y, x, z variances; attitude FRD: its δθ about b1, b2, b3) and the twist
    covariance (body-FRD velocity: diag(Rᵀ Σ R) of the inertial variances; rates), frames,
    estimator GPS_INS."""
    w, x, y, z = q
    vx, vy, vz = est.velocity_var_m2ps2
    rows = ((1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)),
            (2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)),
            (2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)))
    body = [rows[0][i] ** 2 * vx + rows[1][i] ** 2 * vy + rows[2][i] ** 2 * vz
            for i in range(3)]
    px, py, pz = est.position_var_m2
    pose = _covariance_var((py, px, pz, *est.attitude_var_rad2))
    twist = _covariance_var((*body, *est.rate_var_rad2ps2))
    return (*pose, *twist, MAV_FRAME_LOCAL_NED, MAV_FRAME_BODY_FRD, 0, _GPS_INS, 100)


def _covariance_var(variances: tuple[float, ...]) -> list[float]:
    """ODOMETRY covariance array with these variances on the diagonal."""
    cov = [0.0] * 21
    for index, var in zip(_COV_DIAGONAL, variances, strict=True):
        cov[index] = var
    return cov
