"""What the vehicle says about itself: HEARTBEAT, STATUSTEXT and the GCS telemetry.

**HEARTBEAT** (:class:`FlightStatus`): ``MAV_TYPE_QUADROTOR``, ``MAV_AUTOPILOT_PX4``,
``base_mode`` = CUSTOM_MODE_ENABLED | HIL_ENABLED | SAFETY_ARMED (armed: the controller's last
applied command says so and no GCS disarmed the vehicle), ``custom_mode`` = PX4's encoding of
the main mode (OFFBOARD: ``6 << 16``; MAVProxy shows ``OFFBOARD``, mavsdk ``Offboard``),
``system_status`` STANDBY before the flight, ACTIVE during it, EMERGENCY while the motors are
cut or after a crash, POWEROFF at the end. Who sends it when is the caller's business (the
clocks on the control port, :class:`GcsTelemetry` on the GCS port).

**GCS telemetry** (:class:`GcsTelemetry`, paced by sim time in lockstep, by the wall clock
in real time): ``ATTITUDE``,
``LOCAL_POSITION_NED`` (both NED/FRD from the same measured state as ODOMETRY),
``GLOBAL_POSITION_INT`` (the same position about the configurable :class:`Origin`, flat-earth
approximation: metres-scale flights, error ≪ 1 mm per km),
``ACTUATOR_OUTPUT_STATUS`` (``actuator[0..3]`` = commanded thrust / f_max, ``active`` 0b1111, 0
while no command drives the motors), ``SYS_STATUS``
(battery from :mod:`tfl_mav.sitl.power`; ``errors_count1..4`` = rejected controls, lockstep
timeouts, command timeouts, stale controls; present/enabled/health bits only for what the simulator
models: rate gyro, attitude (AHRS), external position (motion capture), motor outputs and
battery) and the latest ``ESC_TELEMETRY_1_TO_4`` (so a GCS sees the
attacked rotor's rpm) at ``gcs_rate_hz`` (≤ 50 Hz, one datagram each time), HEARTBEAT at
1 Hz with ``HOME_POSITION``. A new message for the GCS goes in :meth:`GcsTelemetry.messages`.

**STATUSTEXT** (:class:`StatusText`): every one goes to both peers that are known (ASCII;
longer than 50 characters → MAVLink 2 chunks with a shared ``id``, at most 8); repeats of one reason
can be rate-limited to one a second (wall), with the count of those suppressed.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

from tfl_mav.link.codec import UNSENT, lite_class
from tfl_mav.link.dialect import mav
from tfl_mav.link.statustext import split as split_statustext
from tfl_mav.link.transport import Link
from tfl_mav.model.frames import odometry_from_paper
from tfl_mav.model.geometry import rotation_rows
from tfl_mav.sitl.clock import HeldCommand
from tfl_mav.sitl.power import PowerModel
from tfl_mav.sitl.results import VehicleStats
from tfl_mav.sitl.simulator import Simulator
from tfl_mav.sitl.state_report import StateReport

__all__ = ["FlightStatus", "GcsTelemetry", "Origin", "StatusText", "home_position",
           "sensor_messages"]

_ARMED = mav.MAV_MODE_FLAG_SAFETY_ARMED
_STATUS_MIN_INTERVAL_S = 1.0   # per-reason rate limit of repeated STATUSTEXTs (wall time)
# What the simulator models (tfl_mav.sitl.simulator: rates, attitude, mocap position;
# tfl_mav.sitl.motors;
# tfl_mav.sitl.power). Nothing else is claimed: a bit set here with no model behind it is a lie a
# GCS acts on (MAVProxy announced "fence breach" for a geofence that was never there).
_SENSORS = (mav.MAV_SYS_STATUS_SENSOR_3D_GYRO | mav.MAV_SYS_STATUS_AHRS
            | mav.MAV_SYS_STATUS_SENSOR_VISION_POSITION
            | mav.MAV_SYS_STATUS_SENSOR_MOTOR_OUTPUTS | mav.MAV_SYS_STATUS_SENSOR_BATTERY)

# PX4 custom_mode: main mode in bits 16-23, sub mode in bits 24-31 (PX4 px4_custom_mode.h).
PX4_MAIN_OFFBOARD = 6
PX4_MAIN_MODE_NAMES = {1: "MANUAL", 2: "ALTCTL", 3: "POSCTL", 4: "AUTO", 5: "ACRO",
                       6: "OFFBOARD", 7: "STABILIZED", 8: "RATTITUDE"}
EARTH_RADIUS_M = 6_378_137.0   # WGS-84 equatorial radius
# The telemetry as the codec's wire tuples (tfl_mav.link.codec.lite_class): the bytes of
# pymavlink's messages with the same fields, without their constructors.
_new = tuple.__new__
_Attitude = lite_class(mav.MAVLINK_MSG_ID_ATTITUDE)
_LocalPosition = lite_class(mav.MAVLINK_MSG_ID_LOCAL_POSITION_NED)
_GlobalPosition = lite_class(mav.MAVLINK_MSG_ID_GLOBAL_POSITION_INT)
_Applied = lite_class(mav.MAVLINK_MSG_ID_ACTUATOR_OUTPUT_STATUS)
_SysStatus = lite_class(mav.MAVLINK_MSG_ID_SYS_STATUS)
_ACTIVE = 0b1111      # ACTUATOR_OUTPUT_STATUS.active: outputs 1-4 driven (0 when none is)
_PAD28_UNSENT = (0.0,) * 28 + (UNSENT,)     # actuator[4..31], then the frame item
_EXTENDED_UNSENT = (0, 0, 0, UNSENT)         # SYS_STATUS *_extended, then the frame item


@dataclass(frozen=True)
class Origin:
    """Where local NED (0, 0, 0) is on Earth. Default: PX4 SITL's default home (Zurich)."""

    lat_deg: float = 47.397742
    lon_deg: float = 8.545594
    alt_m: float = 488.0

    @classmethod
    def parse(cls, text: str, field: str = "--origin") -> Origin:
        """``"LAT,LON,ALT"`` (degrees, degrees, metres AMSL); ValueError naming ``field``."""
        parts = text.split(",")
        try:
            lat, lon, alt = (float(p) for p in parts)
        except ValueError:
            raise ValueError(f"{field}: expected LAT,LON,ALT (degrees, degrees, metres), "
                             f"got {text!r}") from None
        if not (-90 < lat < 90 and -180 <= lon <= 180 and math.isfinite(alt)):
            raise ValueError(f"{field}: latitude in (-90, 90), longitude in [-180, 180] and "
                             f"a finite altitude, got {text!r}")
        return cls(lat, lon, alt)

    def global_of(self, north_m: float, east_m: float, down_m: float
                  ) -> tuple[float, float, float]:
        """(lat °, lon °, alt m AMSL) of a local NED point (flat Earth about the origin)."""
        lat = self.lat_deg + math.degrees(north_m / EARTH_RADIUS_M)
        lon = self.lon_deg + math.degrees(
            east_m / (EARTH_RADIUS_M * math.cos(math.radians(self.lat_deg))))
        return lat, lon, self.alt_m - down_m


def home_position(origin: Origin, time_usec: int) -> Any:
    """HOME_POSITION: the origin, local (0, 0, 0)."""
    return mav.MAVLink_home_position_message(
        round(origin.lat_deg * 1e7), round(origin.lon_deg * 1e7), round(origin.alt_m * 1000),
        0.0, 0.0, 0.0, [1.0, 0.0, 0.0, 0.0], 0.0, 0.0, 0.0, time_usec)


@dataclass
class FlightStatus:
    """What HEARTBEAT reports: armed, mode and ``MAV_STATE_*``.

    ``armed``: the controller's last applied mode bit; ``killed``: a GCS disarmed the
    vehicle (motors off until a GCS arms again, :mod:`tfl_mav.sitl.ground`).
    """

    armed: bool = False
    system_status: int = mav.MAV_STATE_STANDBY
    killed: bool = False
    main_mode: int = PX4_MAIN_OFFBOARD

    @property
    def motors_armed(self) -> bool:
        return self.armed and not self.killed

    def heartbeat(self) -> Any:
        base_mode = (mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | mav.MAV_MODE_FLAG_HIL_ENABLED
                     | (_ARMED if self.motors_armed else 0))
        return mav.MAVLink_heartbeat_message(mav.MAV_TYPE_QUADROTOR, mav.MAV_AUTOPILOT_PX4,
                                             base_mode, self.main_mode << 16,
                                             self.system_status, 3)


class StatusText:
    """STATUSTEXT to the controller and the GCS, whichever have a peer; counted in ``stats``.

    ``on_status(severity, text)`` sees every text that goes out (after rate limiting).
    """

    def __init__(self, links: Sequence[Link | None], stats: VehicleStats,
                 on_status: Callable[[int, str], None] | None = None) -> None:
        self.links = tuple(link for link in links if link is not None)
        self.stats = stats
        self.on_status = on_status
        self._last_s: dict[str, float] = {}       # reason → wall time it last went out
        self._suppressed: dict[str, int] = {}     # reason → repeats held back since
        self._chunk_id = 0                        # last MAVLink 2 STATUSTEXT.id used

    def send(self, severity: int, text: str, *, key: str | None = None) -> None:
        """Send ``text`` (chunked past 50 characters).

        With ``key``, repeats of the same reason within 1 s (wall) are suppressed and
        counted; the next one that goes out says how many were suppressed.
        """
        if key is not None:
            now = time.monotonic()
            last = self._last_s.get(key)
            if last is not None and now - last < _STATUS_MIN_INTERVAL_S:
                self.stats.statustexts_suppressed += 1
                self._suppressed[key] = self._suppressed.get(key, 0) + 1
                return
            self._last_s[key] = now
            skipped = self._suppressed.pop(key, 0)
            if skipped:
                text += f" (+{skipped} suppressed)"
        self.stats.statustexts_sent += 1
        if self.on_status is not None:
            self.on_status(severity, text)
        msgs = self.messages(severity, text)
        for link in self.links:
            if link.peer is not None:
                for msg in msgs:
                    link.send(msg)

    def messages(self, severity: int, text: str) -> list[Any]:
        """``text`` as STATUSTEXT messages: one with ``id`` 0 (up to 50 characters,
        exactly 50 included: no terminator needed), or the chunks of
        :func:`tfl_mav.link.statustext.split` sharing a fresh ``id`` (a full last chunk
        gets its empty terminator; the receivers' :class:`~tfl_mav.link.statustext.
        Reassembler` takes the same chunk limit)."""
        chunks = split_statustext(text.replace("°", " deg"))
        if len(chunks) == 1:
            return [mav.MAVLink_statustext_message(severity, chunks[0], 0, 0)]
        self._chunk_id = self._chunk_id % 0xFFFF + 1
        return [mav.MAVLink_statustext_message(severity, c, self._chunk_id, i)
                for i, c in enumerate(chunks)]


class GcsTelemetry:
    """The GCS port's periodic traffic: telemetry every ``period_s`` and HEARTBEAT (with
    HOME_POSITION) every second.

    ``sim_time`` (lockstep): both are paced by sim time, as everything in PX4's lockstep
    SITL is: the GCS gets one datagram per ``period_s`` of flight whatever the run's speed
    (a slow run sends no more per tick than a fast one, the stream is the same on any
    machine), HEARTBEAT and telemetry in one datagram. A lockstep run stalled by its
    controller still sends HEARTBEAT once a wall second, so a GCS does not call the link
    lost. Otherwise (real time) both follow the wall clock, which is then sim time anyway.
    """

    def __init__(self, link: Link, period_s: float, *, sim: Simulator, power: PowerModel,
                 stats: VehicleStats, held: HeldCommand, flight: FlightStatus,
                 report: StateReport, origin: Origin | None = None,
                 sim_time: bool = False) -> None:
        self.link = link
        self.origin = origin or Origin()
        self.period_s = period_s
        self.sim = sim
        self.power = power
        self.stats = stats
        self.held = held
        self.flight = flight
        self.report = report
        self.sim_time = sim_time
        self._next_s = 0.0             # time the next telemetry datagram is due
        self._next_heartbeat_s = 0.0   # time the next HEARTBEAT is due
        self._heartbeat_wall_s = -math.inf   # lockstep: wall time of the last HEARTBEAT
        self._period_usec = max(1, round(period_s * 1e6))   # lockstep: sim µs
        self._next_usec = 0
        self._next_heartbeat_usec = 0
        if sim_time:   # called every lockstep tick: the sim-time pacing without a call more
            self.periodic = self._periodic_sim   # type: ignore[method-assign]

    def periodic(self) -> None:
        """Send what is due now, if anything."""
        if self.sim_time:
            self._periodic_sim()
            return
        now = time.monotonic()
        if now < self._next_s:
            return
        self._next_s = max(self._next_s + self.period_s, now)
        if now >= self._next_heartbeat_s:
            self.link.send_many([self.flight.heartbeat(),
                                 home_position(self.origin, self.sim.time_usec)])
            self._next_heartbeat_s = max(self._next_heartbeat_s + 1.0, now)
        self.link.send_many(self.messages())

    def _periodic_sim(self) -> None:
        # whole microseconds of sim time: a float sum of periods would drift off the ticks
        t = self.sim.time_usec
        if t < self._next_usec:
            if time.monotonic() - self._heartbeat_wall_s >= 1.0:   # stalled: keep alive
                self._heartbeat_wall_s = time.monotonic()
                self.link.send(self.flight.heartbeat())
            return
        self._next_usec = max(self._next_usec + self._period_usec, t)
        msgs = self.messages()
        if t >= self._next_heartbeat_usec:
            msgs[:0] = [self.flight.heartbeat(), home_position(self.origin, t)]
            self._next_heartbeat_usec = max(self._next_heartbeat_usec + 1_000_000, t)
            self._heartbeat_wall_s = time.monotonic()
        self.link.send_many(msgs)

    def messages(self) -> list[Any]:
        """One telemetry datagram's messages, from the current tick's measured state."""
        sim = self.sim
        m = sim.measured_floats     # the same numbers as sim.measured, without its arrays
        t_ms = int(sim.time_s * 1000.0) & 0xFFFFFFFF
        f = odometry_from_paper(m.position_m, m.velocity_mps, m.quaternion_wxyz,
                                m.body_rates_radps)
        roll, pitch, yaw = _euler_zyx(rotation_rows(f.q))
        ve, vn, vu = m.velocity_mps
        v_ned = (vn, ve, -vu)               # enu_to_ned, as floats
        fmax = sim.thrust_max_n
        c1, c2, c3, c4 = sim.rotor_commands_n
        p = self.power.sample
        st = self.stats
        links = [s for s in (st.control_link, st.gcs_link) if s is not None]
        rx = sum(s.rx_datagrams for s in links)
        rejected = sum(s.rejected for s in links)
        sensors_health = _SENSORS & ~(mav.MAV_SYS_STATUS_SENSOR_MOTOR_OUTPUTS
                                      if self.held.motors_cut or self.flight.killed else 0)
        lat, lon, alt = self.origin.global_of(f.x, f.y, f.z)
        heading_cdeg = round(math.degrees(yaw) * 100.0) % 36000
        # wire order (pymavlink's ordered_fieldnames), the frame item last
        msgs: list[Any] = [
            _new(_Attitude, (t_ms, roll, pitch, yaw, f.rollspeed, f.pitchspeed, f.yawspeed,
                             UNSENT)),
            _new(_LocalPosition, (t_ms, f.x, f.y, f.z, float(v_ned[0]), float(v_ned[1]),
                                  float(v_ned[2]), UNSENT)),
            _new(_GlobalPosition, (
                t_ms, round(lat * 1e7), round(lon * 1e7), round(alt * 1000.0),
                round(-f.z * 1000.0), _cm(v_ned[0]), _cm(v_ned[1]), _cm(v_ned[2]),
                heading_cdeg, UNSENT)),
            _new(_Applied, (sim.time_usec, _ACTIVE if self.held.driven else 0, c1 / fmax,
                            c2 / fmax, c3 / fmax, c4 / fmax, *_PAD28_UNSENT)),
            _new(_SysStatus, (
                _SENSORS, _SENSORS, sensors_health, 0,
                min(65535, round(p.voltage_v * 1000.0)),
                min(32767, round(p.total_current_a * 100.0)),
                min(10000, round(10000.0 * rejected / rx)) if rx else 0,   # drop_rate_comm
                min(65535, rejected),                                      # errors_comm
                min(65535, st.rejected_controls), min(65535, st.lockstep_timeouts),
                min(65535, st.command_timeouts), min(65535, st.stale_controls),
                max(0, min(100, round(p.remaining_pct))),                  # battery_remaining
                *_EXTENDED_UNSENT)),
        ]
        esc = self.report.esc
        if esc is not None:
            msgs.append(esc)   # this tick's ESC_TELEMETRY_1_TO_4: rpm
        if sim.sensors is not None:   # realistic sensors: what they measured, as PX4 sends
            msgs.extend(sensor_messages(sim, self.origin))
        return msgs


# ISA at sea level: the barometer's altitude as the pressure a GCS shows
_P0_HPA, _T0_K, _LAPSE_KPM, _BARO_EXP = 1013.25, 288.15, 0.0065, 5.25588
_HIGHRES_FIELDS = 0b1_1101_1111_1111     # acc, gyro, mag xyz, abs pressure, alt, temperature
_GPS_FIX_RTK_FIXED = 6
_GPS_FIX_3D = 3


def sensor_messages(sim: Simulator, origin: Origin) -> list[Any]:
    """HIGHRES_IMU (the last IMU sample, magnetometer and barometer, body FRD) and
    GPS_RAW_INT (the last fix delivered) of the realistic sensors
    (:mod:`tfl_mav.sitl.sensors`): a GCS's raw sensor view beside the estimate's ATTITUDE and
    LOCAL_POSITION_NED."""
    suite = sim.sensors
    assert suite is not None
    out: list[Any] = []
    imu = suite.last_imu
    if imu is not None:
        ax, ay, az = imu.accel_mps2
        gx, gy, gz = imu.gyro_radps
        mx, my, mz = suite.last_mag
        alt = suite.last_baro_m
        pressure = _P0_HPA * (1.0 - _LAPSE_KPM * alt / _T0_K) ** _BARO_EXP \
            if math.isfinite(alt) else 0.0
        # FLU → FRD: y and z change sign
        out.append(mav.MAVLink_highres_imu_message(
            round(imu.time_s * 1e6), ax, -ay, -az, gx, -gy, -gz,
            mx, -my, -mz, pressure, 0.0, alt if math.isfinite(alt) else 0.0, 15.0,
            _HIGHRES_FIELDS, 0))
    fix = suite.last_gps
    if fix is not None:
        e, n, u = fix.position_m
        ve, vn, _vu = fix.velocity_mps
        lat, lon, alt_m = origin.global_of(n, e, -u)
        h_acc = sim.scenario.sensors.gps_position_noise_std_m
        rtk = h_acc <= 0.05
        out.append(mav.MAVLink_gps_raw_int_message(
            round(fix.time_s * 1e6), _GPS_FIX_RTK_FIXED if rtk else _GPS_FIX_3D,
            round(lat * 1e7), round(lon * 1e7), round(alt_m * 1000.0),
            70, 100, min(65534, round(math.hypot(vn, ve) * 100.0)),
            round(math.degrees(math.atan2(ve, vn)) * 100.0) % 36000, 20,
            round(alt_m * 1000.0), round(h_acc * 1000.0), round(1.5 * h_acc * 1000.0),
            round(sim.scenario.sensors.gps_velocity_noise_std_mps * 1000.0), 0, 0))
    return out


def _euler_zyx(rows: list[list[float]]) -> tuple[float, float, float]:
    """:func:`~tfl_mav.model.geometry.euler_zyx_from_rotation` of R given as float rows: the
    same operations on the same numbers (so the same angles), without building an array
    (this runs with every GCS telemetry datagram)."""
    s = -rows[2][0]
    theta = math.asin(max(-1.0, min(1.0, s)))
    if abs(s) > 1.0 - 1e-12:
        return 0.0, theta, math.atan2(-rows[0][1], rows[1][1])
    return math.atan2(rows[2][1], rows[2][2]), theta, math.atan2(rows[1][0], rows[0][0])


def _cm(v_mps: float) -> int:
    """m/s → cm/s clamped to int16 (GLOBAL_POSITION_INT's velocity fields)."""
    return max(-32768, min(32767, round(float(v_mps) * 100.0)))
