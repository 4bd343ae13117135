"""The state the controller receives every control tick: ODOMETRY, ACTUATOR_OUTPUT_STATUS,
ESC_TELEMETRY_1_TO_4, in that order, in one datagram (the ESC report completes the tick).

``ODOMETRY``: ``time_usec`` = the tick's sim time, LOCAL_NED pose and BODY_FRD twist of the
*measured* state (the scenario's seeded sensor noise), covariances σ² on the diagonal from
the scenario's noise levels, estimator MOCAP, quality 100.

``ESC_TELEMETRY_1_TO_4``: per ESC the true rotor speed as the ESC measures it (rpm, with the
scenario's rpm noise), battery voltage (cV), current (cA), consumed charge (mAh) and
temperature (°C) from :mod:`sitl.power`, and a message counter (the same for all four,
wrapping at 2¹⁶). Every field is clamped to its wire type.

``ACTUATOR_OUTPUT_STATUS`` says which command the rpm answer to (issue #12): ``time_usec`` =
the ``time_usec`` of the HIL_ACTUATOR_CONTROLS held over the period that just ended (0 =
none: before the first command, motors cut, disarmed), ``actuator[0..3]`` = the thrust
fractions actually driven (0 when cut), ``active`` = 0b1111 (PX4 streams the same message
for its outputs). A late, lost or reordered command is then never mistaken for a rotor that
disobeys.

The triple is built once per tick (:meth:`StateReport.update`) and kept, so a lockstep resend
sends the same messages again and the GCS telemetry can forward the tick's ESC message.
"""

from __future__ import annotations

from typing import Any

from sitl.power import PowerModel
from sitl.simulator import Simulator
from tfl_mav.frames import MAV_FRAME_BODY_FRD, MAV_FRAME_LOCAL_NED, odometry_from_paper
from tfl_mav.link.dialect import mav
from tfl_mav.scenario import SensorConfig

__all__ = ["StateReport"]

# ODOMETRY covariance arrays: upper triangle of a 6×6 matrix, row-major; diagonal indices.
_COV_DIAGONAL = (0, 6, 11, 15, 18, 20)
_ACTIVE = 0b1111          # ACTUATOR_OUTPUT_STATUS.active: outputs 1-4 in use
_PAD28 = (0.0,) * 28     # actuator[4..31]
_MOCAP = mav.MAV_ESTIMATOR_TYPE_MOCAP


def _u8(x: float) -> int:
    """Rounded and clamped to uint8."""
    r = round(x)
    return 0 if r < 0 else 255 if r > 255 else r


def _u16(x: float) -> int:
    """Rounded and clamped to ≤ 65535 (inputs here are ≥ 0: currents, charge, rpm)."""
    r = round(x)
    return 65535 if r > 65535 else r


class StateReport:
    """Builds and keeps the current tick's (ODOMETRY, ESC_TELEMETRY_1_TO_4)."""

    def __init__(self, sim: Simulator, power: PowerModel, sensors: SensorConfig) -> None:
        self.sim = sim
        self.power = power
        self._pose_cov = _covariance((sensors.position_noise_std_m,) * 3
                                     + (sensors.attitude_noise_std_rad,) * 3)
        self._vel_cov = _covariance((sensors.velocity_noise_std_mps,) * 3
                                    + (sensors.rate_noise_std_radps,) * 3)
        self._esc_count = 0
        self.latest: tuple[Any, Any, Any] | None = None
        """The last tick's (ODOMETRY, ACTUATOR_OUTPUT_STATUS, ESC_TELEMETRY_1_TO_4), or None
        before the first."""

    @property
    def esc(self) -> Any | None:
        """The last tick's ESC_TELEMETRY_1_TO_4, or None before the first tick."""
        return self.latest[-1] if self.latest is not None else None

    def update(self, applied_usec: int = 0) -> tuple[Any, Any, Any]:
        """Build the current tick's messages from the simulator and the power model;
        ``applied_usec``: time_usec of the command held over the period just ended (0:
        none)."""
        sim = self.sim
        m = sim.measured_floats       # float tuples: no arrays to build and convert back
        f = odometry_from_paper(m.position_m, m.velocity_mps, m.quaternion_wxyz,
                                m.body_rates_radps)
        odometry = mav.MAVLink_odometry_message(
            sim.time_usec, MAV_FRAME_LOCAL_NED, MAV_FRAME_BODY_FRD, f.x, f.y, f.z, f.q,
            f.vx, f.vy, f.vz, f.rollspeed, f.pitchspeed, f.yawspeed, self._pose_cov,
            self._vel_cov, 0, _MOCAP, 100)
        p = self.power.sample
        self._esc_count = count = (self._esc_count + 1) & 0xFFFF
        cv = min(65535, round(p.voltage_v * 100.0))
        t1, t2, t3, t4 = p.temperatures_c
        i1, i2, i3, i4 = p.currents_a
        c1, c2, c3, c4 = p.consumed_mah
        r1, r2, r3, r4 = sim.measured_rpm_floats
        esc = mav.MAVLink_esc_telemetry_1_to_4_message(
            [_u8(t1), _u8(t2), _u8(t3), _u8(t4)],
            [cv, cv, cv, cv],
            [_u16(i1 * 100.0), _u16(i2 * 100.0), _u16(i3 * 100.0), _u16(i4 * 100.0)],
            [_u16(c1), _u16(c2), _u16(c3), _u16(c4)],
            [_u16(r1), _u16(r2), _u16(r3), _u16(r4)],   # rpm: already ≥ 0
            [count, count, count, count])
        fmax = sim.thrust_max_n
        f1, f2, f3, f4 = sim.rotor_commands_n
        applied = mav.MAVLink_actuator_output_status_message(
            applied_usec, _ACTIVE, [f1 / fmax, f2 / fmax, f3 / fmax, f4 / fmax, *_PAD28])
        self.latest = (odometry, applied, esc)
        return self.latest


def _covariance(stds: tuple[float, ...]) -> list[float]:
    """ODOMETRY covariance array (21 floats, 6×6 upper triangle) with σ² on the diagonal."""
    cov = [0.0] * 21
    for index, std in zip(_COV_DIAGONAL, stds, strict=True):
        cov[index] = std * std
    return cov
