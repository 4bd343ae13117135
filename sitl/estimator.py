"""The vehicle's onboard estimator: an error-state extended Kalman filter in the spirit of
PX4's EKF2 (Solà, "Quaternion kinematics for the error-state Kalman filter", 2017, §5–7).

Nominal state (paper frame: inertial ENU z up, body FLU): position p (m), velocity v (m/s),
attitude q (body → inertial, wxyz), accelerometer bias b_a (m/s²), gyro bias b_g (rad/s).
Error state, 15: δp, δv, δθ (a local rotation, q ← q ⊗ q{δθ}), δb_a, δb_g.

* **Predict** on every IMU sample (specific force f_m, rate ω_m, interval Δt):
  a = R (f_m − b_a) + g,  p ← p + v Δt + ½ a Δt²,  v ← v + a Δt,  q ← q ⊗ q{(ω_m − b_g) Δt};
  P ← F P Fᵀ + Q with F = ∂δx⁺/∂δx (Solà eq. 269: δv gains −R [f_m − b_a]× δθ Δt − R δb_a Δt,
  δθ is rotated by R{(ω_m − b_g)Δt}ᵀ and loses δb_g Δt) and Q the IMU's white noise and
  bias walks over Δt.
* **Fuse** (sequential scalar updates, then the error injected and P reset by
  G = I − [½δθ]×): GPS
  position and velocity; barometric altitude; the magnetometer's field in body axes
  (h = Rᵀ m, ∂h/∂δθ = [Rᵀ m]×). Each fusion passes an innovation gate first (χ² of the
  normalised innovation below :data:`GATE_SIGMA`² per component), as EKF2's innovation
  consistency checks do.
* **Delay**: a GPS fix arrives ``gps_latency_s`` after the instant it measured. EKF2 runs
  the whole filter that far behind and predicts forward with an output observer; here the
  fix is compared with the estimate *of its own instant* (a ring buffer of the nominal
  state), and the correction is applied now — the error treated as constant over the delay,
  which holds while the delay (0.1 s) is short against the error's time constants (seconds).
* **Reset**: :data:`GPS_RESET_AFTER` fixes in a row refused by the gate (on any axis: a
  refused axis is left to drift) reset position and
  velocity to the GPS (EKF2's reset after its GPS timeout), so a filter that has become
  overconfident cannot drift away from the fixes for good.

:meth:`ErrorStateEkf.output` is what the vehicle sends as ODOMETRY: the estimate of now
(position, velocity, attitude, the bias-corrected gyro rate) and its covariance.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

from tfl_mav.sitl.sensors import MAG_FIELD_ENU, GpsSample, ImuNoise, ImuSample

__all__ = ["EKF_COVARIANCE_HZ", "GATE_SIGMA", "GPS_RESET_AFTER", "ErrorStateEkf", "EstimatorOutput"]

GATE_SIGMA = 5.0
GPS_RESET_AFTER = 5             # consecutive fixes refused (any axis; 0.5 s at 10 Hz): reset
EKF_COVARIANCE_HZ = 100.0       # the covariance's rate, EKF2's (the IMU's: the control tick's)
_HISTORY_S = 1.0


class EstimatorOutput(NamedTuple):
    """The estimate of now (paper frame) and the variances ODOMETRY carries."""

    position_m: tuple[float, float, float]
    velocity_mps: tuple[float, float, float]
    quaternion_wxyz: tuple[float, float, float, float]
    body_rates_radps: tuple[float, float, float]
    position_var_m2: tuple[float, float, float]
    velocity_var_m2ps2: tuple[float, float, float]
    attitude_var_rad2: tuple[float, float, float]       # δθ about b1, b2, b3
    rate_var_rad2ps2: tuple[float, float, float]


def _skew(v: Sequence[float]) -> np.ndarray:
    x, y, z = v
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def _rot(q: np.ndarray) -> np.ndarray:
    w, x, y, z = q
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def _qmul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    return np.array([aw * bw - ax * bx - ay * by - az * bz,
                     aw * bx + ax * bw + ay * bz - az * by,
                     aw * by - ax * bz + ay * bw + az * bx,
                     aw * bz + ax * by - ay * bx + az * bw])


def _qexp(theta: np.ndarray) -> np.ndarray:
    """q{θ}: the unit quaternion of the rotation vector θ (rad)."""
    angle = float(np.linalg.norm(theta))
    if angle < 1e-12:
        return np.array([1.0, *(0.5 * theta)])
    s = math.sin(0.5 * angle) / angle
    return np.array([math.cos(0.5 * angle), *(s * theta)])


class ErrorStateEkf:
    """The filter; one :meth:`predict` per IMU sample, a fusion per other measurement."""

    def __init__(self, x0: Sequence[float], gravity_mps2: float, noise: ImuNoise,
                 gps_position_std_m: float, gps_velocity_std_mps: float,
                 cov_every: int = 1) -> None:
        # the nominal state as float lists (numpy only for the covariance and fusions)
        self.p = [float(c) for c in x0[0:3]]
        self.v = [float(c) for c in x0[3:6]]
        self.q = [float(c) for c in x0[6:10]]
        self.ba = [0.0, 0.0, 0.0]
        self.bg = [0.0, 0.0, 0.0]
        self.noise = noise
        # initial uncertainty: aligned on the ground (position and attitude to a few cm and
        # a degree), the turn-on biases unknown
        sd = np.array([0.02] * 3 + [0.05] * 3 + [0.02] * 3
                      + [noise.accel_bias_turn_on_mps2] * 3
                      + [noise.gyro_bias_turn_on_radps] * 3)
        self.P = np.diag(sd * sd)
        self._r_gps = np.diag([gps_position_std_m ** 2] * 2 + [(1.5 * gps_position_std_m) ** 2]
                              + [gps_velocity_std_mps ** 2] * 3)
        self._h_gps = np.zeros((6, 15))
        self._h_gps[0:6, 0:6] = np.eye(6)
        self._h_baro = np.zeros((1, 15))
        self._h_baro[0, 2] = 1.0
        self._r_baro = np.array([[noise.baro_std_m ** 2]])
        self._r_mag = np.eye(3) * noise.mag_std ** 2
        self._mag = np.array(MAG_FIELD_ENU)
        self._rate = tuple(float(c) for c in x0[10:13])
        self._g = gravity_mps2
        self.cov_every = cov_every
        self._acc = [0.0] * 8        # ΣΔt, ΣΔt², Σf Δt (3), Σω Δt (3) since the last P step
        self._pending = 0
        self._f = np.eye(15)
        self._eye3 = np.eye(3)
        idx = np.arange(3)
        self._iv, self._it, self._iba, self._ibg = 3 + idx, 6 + idx, 9 + idx, 12 + idx
        self._last_t: float | None = None
        self._history: deque[tuple[float, np.ndarray, np.ndarray]] = deque()
        self._gps_refused = 0                # consecutive fixes the gate refused whole
        self.resets = 0                      # position/velocity resets to the GPS
        self.rejected = 0                    # measurements the gate refused
        self.fused = 0
        self._variances()

    # ---------------------------------------------------------------- predict
    def predict(self, imu: ImuSample) -> None:
        """The nominal state over one IMU interval (floats, every sample); the covariance
        every :attr:`cov_every` samples over their accumulated interval, as EKF2 runs its
        covariance on down-sampled IMU data (delta angle, delta velocity)."""
        if self._last_t is None:
            self._last_t = imu.time_s
            g = imu.gyro_radps
            self._rate = (g[0] - self.bg[0], g[1] - self.bg[1], g[2] - self.bg[2])
            self._remember(imu.time_s)
            self._variances()
            return
        dt = imu.time_s - self._last_t
        self._last_t = imu.time_s
        if dt <= 0.0:
            return
        ba, bg = self.ba, self.bg
        fx, fy, fz = (imu.accel_mps2[0] - ba[0], imu.accel_mps2[1] - ba[1],
                      imu.accel_mps2[2] - ba[2])
        wx, wy, wz = (imu.gyro_radps[0] - bg[0], imu.gyro_radps[1] - bg[1],
                      imu.gyro_radps[2] - bg[2])
        qw, qx, qy, qz = self.q
        r11 = 1.0 - 2.0 * (qy * qy + qz * qz)
        r12 = 2.0 * (qx * qy - qw * qz)
        r13 = 2.0 * (qx * qz + qw * qy)
        r21 = 2.0 * (qx * qy + qw * qz)
        r22 = 1.0 - 2.0 * (qx * qx + qz * qz)
        r23 = 2.0 * (qy * qz - qw * qx)
        r31 = 2.0 * (qx * qz - qw * qy)
        r32 = 2.0 * (qy * qz + qw * qx)
        r33 = 1.0 - 2.0 * (qx * qx + qy * qy)
        ax = r11 * fx + r12 * fy + r13 * fz
        ay = r21 * fx + r22 * fy + r23 * fz
        az = r31 * fx + r32 * fy + r33 * fz - self._g
        px, py, pz = self.p
        vx, vy, vz = self.v
        hdt2 = 0.5 * dt * dt
        self.p = [px + vx * dt + ax * hdt2, py + vy * dt + ay * hdt2, pz + vz * dt + az * hdt2]
        self.v = [vx + ax * dt, vy + ay * dt, vz + az * dt]
        # q ⊗ q{ω Δt}
        tx, ty, tz = wx * dt, wy * dt, wz * dt
        angle = math.sqrt(tx * tx + ty * ty + tz * tz)
        if angle < 1e-12:
            dw, k = 1.0, 0.5
        else:
            dw, k = math.cos(0.5 * angle), math.sin(0.5 * angle) / angle
        dx, dy, dz = k * tx, k * ty, k * tz
        nw = qw * dw - qx * dx - qy * dy - qz * dz
        nx = qw * dx + qx * dw + qy * dz - qz * dy
        ny = qw * dy - qx * dz + qy * dw + qz * dx
        nz_ = qw * dz + qx * dy - qy * dx + qz * dw
        n = math.sqrt(nw * nw + nx * nx + ny * ny + nz_ * nz_)
        self.q = [nw / n, nx / n, ny / n, nz_ / n]
        self._rate = (wx, wy, wz)
        acc = self._acc
        acc[0] += dt
        acc[1] += dt * dt
        acc[2] += fx * dt
        acc[3] += fy * dt
        acc[4] += fz * dt
        acc[5] += tx
        acc[6] += ty
        acc[7] += tz
        self._pending += 1
        if self._pending >= self.cov_every:
            self._propagate_covariance()
        self._remember(imu.time_s)

    def _propagate_covariance(self) -> None:
        """P ← F P Fᵀ + Q over the accumulated interval T = ΣΔt (mean specific force,
        summed rotation, the white noise of every sample: Σ(σΔt)²)."""
        t, t2, sfx, sfy, sfz, tx, ty, tz = self._acc
        self._acc = [0.0] * 8
        self._pending = 0
        if t <= 0.0:
            return
        nz = self.noise
        r = _rot(np.array(self.q))
        f_mean = np.array([sfx / t, sfy / t, sfz / t])
        f = self._f
        f[0:3, 3:6] = self._eye3 * t
        f[3:6, 6:9] = -(r @ _skew(f_mean)) * t
        f[3:6, 9:12] = -r * t
        f[6:9, 6:9] = _rot(_qexp(np.array([tx, ty, tz]))).T
        f[6:9, 12:15] = -self._eye3 * t
        pp = f @ self.P @ f.T
        pp[self._iv, self._iv] += nz.accel_std_mps2 ** 2 * t2
        pp[self._it, self._it] += nz.gyro_std_radps ** 2 * t2
        pp[self._iba, self._iba] += nz.accel_bias_walk_mps2_sqrts ** 2 * t
        pp[self._ibg, self._ibg] += nz.gyro_bias_walk_radps_sqrts ** 2 * t
        self.P = 0.5 * (pp + pp.T)
        self._variances()

    def _variances(self) -> None:
        d = np.diag(self.P).tolist()
        sg = self.noise.gyro_std_radps ** 2
        self._var = (tuple(d[0:3]), tuple(d[3:6]), tuple(d[6:9]),
                     (sg + d[12], sg + d[13], sg + d[14]))

    def _remember(self, t_s: float) -> None:
        h = self._history
        h.append((t_s, self.p, self.v))       # the lists are replaced, never changed
        while h and h[0][0] < t_s - _HISTORY_S:
            h.popleft()

    # ---------------------------------------------------------------- fuse
    def _fuse(self, h: np.ndarray, innovation: np.ndarray, r: np.ndarray) -> bool:
        """Fuse a measurement with independent components (diagonal ``r``) one component
        at a time, as EKF2 does (scalar updates: no matrix inverse): K = P hᵀ/s,
        P ← P − K (h P), the error δx accumulated, then injected once. A component whose
        normalised innovation fails the gate is skipped (counted); False if all were."""
        if self._pending:
            self._propagate_covariance()
        if not np.all(np.isfinite(innovation)):
            self.rejected += len(innovation)
            return False
        pm = self.P
        dx = np.zeros(15)
        used = 0
        for i in range(len(innovation)):
            hi = h[i]
            ph = pm @ hi
            s = float(hi @ ph) + float(r[i, i])
            nu = float(innovation[i]) - float(hi @ dx)
            if nu * nu > GATE_SIGMA ** 2 * s:
                self.rejected += 1
                continue
            k = ph / s
            dx += k * nu
            pm = pm - np.outer(k, ph)
            used += 1
        if not used:
            return False
        pm = 0.5 * (pm + pm.T)
        self.p = (np.asarray(self.p) + dx[0:3]).tolist()
        self.v = (np.asarray(self.v) + dx[3:6]).tolist()
        q = _qmul(np.asarray(self.q), _qexp(dx[6:9]))
        self.q = (q / np.linalg.norm(q)).tolist()
        self.ba = (np.asarray(self.ba) + dx[9:12]).tolist()
        self.bg = (np.asarray(self.bg) + dx[12:15]).tolist()
        # the reset of the attitude error's covariance, G = I − [½δθ]× (Solà eq. 287)
        g = self._eye3 - _skew(0.5 * dx[6:9])
        pm[6:9, :] = g @ pm[6:9, :]
        pm[:, 6:9] = pm[:, 6:9] @ g.T
        self.P = pm
        self._variances()
        self.fused += 1
        return True

    def fuse_gps(self, fix: GpsSample) -> bool:
        """A fix measured at ``fix.time_s`` (possibly in the past): against the estimate of
        that instant, the correction applied now (module doc)."""
        p_then, v_then = self.p, self.v
        for t, p, v in reversed(self._history):
            if t <= fix.time_s + 1e-9:
                p_then, v_then = p, v
                break
        innovation = np.array([fix.position_m[i] - p_then[i] for i in range(3)]
                              + [fix.velocity_mps[i] - v_then[i] for i in range(3)])
        refused_before = self.rejected
        fused = self._fuse(self._h_gps, innovation, self._r_gps)
        if self.rejected == refused_before:
            self._gps_refused = 0
            return fused
        self._gps_refused += 1       # a fix refused in part: its refused axes drift
        if self._gps_refused >= GPS_RESET_AFTER:
            # The filter has talked itself out of the GPS (overconfident, drifting): as
            # EKF2 does after its timeout, reset position and velocity to the fix (carried
            # to now by the estimate's own motion since) with the fix's uncertainty.
            self.p = [self.p[i] + innovation[i] for i in range(3)]
            self.v = [self.v[i] + innovation[3 + i] for i in range(3)]
            pm = self.P.copy()
            pm[0:6, :] = 0.0
            pm[:, 0:6] = 0.0
            pm[0:6, 0:6] = self._r_gps
            self.P = pm
            self._variances()
            self._gps_refused = 0
            self.resets += 1
        return fused

    def fuse_baro(self, altitude_m: float) -> bool:
        return self._fuse(self._h_baro, np.array([altitude_m - self.p[2]]), self._r_baro)

    def fuse_mag(self, field_body: Sequence[float]) -> bool:
        predicted = _rot(np.asarray(self.q)).T @ self._mag
        h = np.zeros((3, 15))
        h[:, 6:9] = _skew(predicted)
        return self._fuse(h, np.asarray(field_body) - predicted, self._r_mag)

    # ---------------------------------------------------------------- output
    def output(self) -> EstimatorOutput:
        pv, vv, av, rv = self._var
        return EstimatorOutput(tuple(self.p), tuple(self.v), tuple(self.q),  # type: ignore[arg-type]
                               self._rate, pv, vv, av, rv)
