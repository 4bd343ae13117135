"""The vehicle's sensors (``[sensors] model = "realistic"``): what an autopilot measures.

Sampled from the true state at control ticks (the simulator's ``_measure``), in the paper
frame (inertial ENU, z up; body FLU), seeded by ``run.seed`` on a stream of their own:

* **IMU** every control tick (``control_hz``: 1 kHz by default, within the 250–1000 Hz of
  flight IMUs): accelerometer = the specific force f_b = Rᵀ (Δv/Δt − g) over the tick (what
  an IMU's delta-velocity output averages) + bias + white noise; gyroscope = Ω + bias +
  white noise; each bias a random walk (the Gauss–Markov-free model of PX4's EKF2 and
  RotorPy's ``sensors/imu.py``), started at a random turn-on bias.
* **GPS** (``gps_hz``, default 10 Hz): position and velocity + white noise, delivered
  ``gps_latency_s`` (default 100 ms) after the instant it measured.
* **Barometer** (50 Hz): altitude + white noise.
* **Magnetometer** (50 Hz): the earth's field (unit vector, 60° inclination, pointing north
  = +y and down) in body axes + white noise.

The noise levels (:class:`ImuNoise`) are of a current MEMS IMU under a multirotor's
vibration (ICM-42688-class densities; PX4's EKF2 defaults EKF2_GYR_NOISE, EKF2_ACC_NOISE are
the same order, more conservative). The GPS defaults are an RTK receiver's (2 cm, 5 cm/s):
with a standard receiver's metre, no estimator holds a path to centimetres.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

from tfl_mav.scenario import SensorConfig

__all__ = ["MAG_FIELD_ENU", "GpsSample", "ImuNoise", "ImuSample", "SensorSuite"]

_STREAM = 0x53454E53          # "SENS": a stream of its own under run.seed
_INCLINATION_RAD = math.radians(60.0)
MAG_FIELD_ENU = (0.0, math.cos(_INCLINATION_RAD), -math.sin(_INCLINATION_RAD))
BARO_HZ = 50.0
MAG_HZ = 50.0


class ImuNoise(NamedTuple):
    """White noise per sample and bias random walks of the IMU, and its turn-on biases."""

    gyro_std_radps: float = 3.0e-3         # per sample at 1 kHz
    accel_std_mps2: float = 5.0e-2         # per sample at 1 kHz
    gyro_bias_walk_radps_sqrts: float = 1.0e-4
    accel_bias_walk_mps2_sqrts: float = 1.0e-3
    gyro_bias_turn_on_radps: float = 5.0e-3
    accel_bias_turn_on_mps2: float = 5.0e-2
    baro_std_m: float = 0.10
    mag_std: float = 0.01                  # in units of the field's magnitude


DEFAULT_NOISE = ImuNoise()


class ImuSample(NamedTuple):
    """One IMU sample, body FLU: specific force (m/s²) and angular rate (rad/s)."""

    time_s: float
    accel_mps2: tuple[float, float, float]
    gyro_radps: tuple[float, float, float]


class GpsSample(NamedTuple):
    """A GPS fix: measured at ``time_s``, position (m) and velocity (m/s), paper frame."""

    time_s: float
    position_m: tuple[float, float, float]
    velocity_mps: tuple[float, float, float]


def _rotate_t(q: Sequence[float], v: Sequence[float]) -> tuple[float, float, float]:
    """Rᵀ(q) v: an inertial vector in body axes."""
    qw, qx, qy, qz = q
    x, y, z = v
    r11 = 1.0 - 2.0 * (qy * qy + qz * qz)
    r21 = 2.0 * (qx * qy + qw * qz)
    r31 = 2.0 * (qx * qz - qw * qy)
    r12 = 2.0 * (qx * qy - qw * qz)
    r22 = 1.0 - 2.0 * (qx * qx + qz * qz)
    r32 = 2.0 * (qy * qz + qw * qx)
    r13 = 2.0 * (qx * qz + qw * qy)
    r23 = 2.0 * (qy * qz - qw * qx)
    r33 = 1.0 - 2.0 * (qx * qx + qy * qy)
    return (r11 * x + r21 * y + r31 * z, r12 * x + r22 * y + r32 * z,
            r13 * x + r23 * y + r33 * z)


class SensorSuite:
    """The realistic sensors of one flight; :meth:`sample` once per control tick."""

    def __init__(self, cfg: SensorConfig, seed: int, gravity_mps2: float,
                 noise: ImuNoise = DEFAULT_NOISE) -> None:
        self.cfg = cfg
        self.noise = noise
        self.gravity_mps2 = gravity_mps2
        self._rng = np.random.default_rng((seed, _STREAM))
        self._imu_rng = np.random.default_rng((seed, _STREAM, 1))
        self._imu_block: list[list[float]] = []
        z = self._rng.standard_normal(6).tolist()
        self.gyro_bias_radps = [noise.gyro_bias_turn_on_radps * c for c in z[0:3]]
        self.accel_bias_mps2 = [noise.accel_bias_turn_on_mps2 * c for c in z[3:6]]
        self._gps_period_s = 1.0 / cfg.gps_hz
        self._next_gps_s = 0.0
        self._next_baro_s = 0.0
        self._next_mag_s = 0.0
        self._in_flight: deque[tuple[float, GpsSample]] = deque()   # (delivery s, fix)
        self._last_v: tuple[float, ...] | None = None
        self._last_t = 0.0
        # the sensors' last output, for a GCS (HIGHRES_IMU, GPS_RAW_INT)
        self.last_imu: ImuSample | None = None
        self.last_gps: GpsSample | None = None
        self.last_baro_m = math.nan
        self.last_mag: tuple[float, float, float] = (math.nan,) * 3   # type: ignore[assignment]

    def _imu_noise(self) -> list[float]:
        """The IMU's 12 normals of this sample (accel 3, gyro 3, bias walks 6), drawn a
        thousand samples at a time (its own stream: the other sensors draw from theirs)."""
        block = self._imu_block
        if not block:
            block = self._imu_block = self._imu_rng.standard_normal((1000, 12)).tolist()
            block.reverse()
        return block.pop()

    def sample(self, t_s: float, x: Sequence[float]
               ) -> tuple[ImuSample, list[GpsSample], float | None,
                          tuple[float, float, float] | None]:
        """The sensors at sim time ``t_s`` from the true state ``x`` (13 floats): the IMU
        sample, the GPS fixes delivered now (measured ``gps_latency_s`` earlier), and the
        barometer's altitude (m) and magnetometer's field (body) when they sample now."""
        nz = self.noise
        dt = t_s - self._last_t
        g = self.gravity_mps2
        v = (x[3], x[4], x[5])
        if self._last_v is None or dt <= 0.0:
            acc = (0.0, 0.0, 0.0)
            dt_walk = 0.0
        else:
            lv = self._last_v
            acc = ((v[0] - lv[0]) / dt, (v[1] - lv[1]) / dt, (v[2] - lv[2]) / dt)
            dt_walk = dt
        self._last_v, self._last_t = v, t_s
        q = x[6:10]
        f_b = _rotate_t(q, (acc[0], acc[1], acc[2] + g))     # a − g, g = (0, 0, −g)
        z = self._imu_noise()
        sg = nz.gyro_bias_walk_radps_sqrts * math.sqrt(dt_walk)
        sa = nz.accel_bias_walk_mps2_sqrts * math.sqrt(dt_walk)
        bg, ba = self.gyro_bias_radps, self.accel_bias_mps2
        for i in range(3):
            bg[i] += sg * z[6 + i]
            ba[i] += sa * z[9 + i]
        accel = tuple(f_b[i] + ba[i] + nz.accel_std_mps2 * z[i] for i in range(3))
        gyro = tuple(x[10 + i] + bg[i] + nz.gyro_std_radps * z[3 + i] for i in range(3))
        imu = ImuSample(t_s, accel, gyro)   # type: ignore[arg-type]
        self.last_imu = imu
        eps = 1e-9
        if t_s + eps >= self._next_gps_s:
            self._next_gps_s += self._gps_period_s
            zg = self._rng.standard_normal(6).tolist()
            sp, sv = self.cfg.gps_position_noise_std_m, self.cfg.gps_velocity_noise_std_mps
            fix = GpsSample(t_s, (x[0] + sp * zg[0], x[1] + sp * zg[1], x[2] + 1.5 * sp * zg[2]),
                            (v[0] + sv * zg[3], v[1] + sv * zg[4], v[2] + sv * zg[5]))
            self._in_flight.append((t_s + self.cfg.gps_latency_s, fix))
        fixes = []
        while self._in_flight and self._in_flight[0][0] <= t_s + eps:
            fixes.append(self._in_flight.popleft()[1])
        if fixes:
            self.last_gps = fixes[-1]
        baro = mag = None
        if t_s + eps >= self._next_baro_s:
            self._next_baro_s += 1.0 / BARO_HZ
            baro = self.last_baro_m = x[2] + nz.baro_std_m * float(self._rng.standard_normal())
        if t_s + eps >= self._next_mag_s:
            self._next_mag_s += 1.0 / MAG_HZ
            m = _rotate_t(q, MAG_FIELD_ENU)
            zm = self._rng.standard_normal(3).tolist()
            mag = self.last_mag = (m[0] + nz.mag_std * zm[0], m[1] + nz.mag_std * zm[1],
                                   m[2] + nz.mag_std * zm[2])
        return imu, fixes, baro, mag
