"""A PX4-style cascade: position P → velocity PID → attitude P → rate PID → allocation.

Source: the PX4 autopilot's multicopter controllers (PX4-Autopilot v1.14,
``src/modules/mc_pos_control/PositionControl/PositionControl.cpp``,
``src/modules/mc_att_control/AttitudeControl/AttitudeControl.cpp``,
``src/lib/rate_control/rate_control.cpp``, ``src/modules/control_allocator``), their
structure and default gains, written in this project's frame (z up, body FLU):

* position P: v_sp = v_ff + K_p (p_sp − p), K_p = (0.95, 0.95, 1.0) (MPC_XY_P, MPC_Z_P),
  |v_z| ≤ 3 m/s up, 1.5 m/s down (MPC_Z_VEL_MAX_UP/DN);
* velocity PID: a_sp = a_ff + K_vp e_v + ∫ K_vi e_v − K_vd v̇, K_vp = (1.8, 1.8, 4),
  K_vi = (0.4, 0.4, 2), K_vd = (0.2, 0.2, 0) (MPC_{XY,Z}_VEL_{P,I,D}_ACC), v̇ low-passed at
  5 Hz (MPC_VELD_LP), the integral frozen while the thrust is at a limit (PX4's anti-windup);
* thrust vector: b3_sp ∥ (a_x, a_y, g) tilted at most 45° (MPC_TILTMAX_AIR), collective
  thrust m̂ (g + a_z)/b3_z within [0.12, 1] × 4 f_max (MPC_THR_MIN/MAX); yaw set-point 0;
* attitude P on the quaternion error with PX4's reduced-attitude priority and yaw weight
  0.4 (MC_YAW_WEIGHT): gains (6.5, 6.5, 2.8) (MC_ROLL_P, MC_PITCH_P, MC_YAW_P), rates
  limited to 220, 220, 200 °/s;
* rate PID: PX4 normalises its torques to its actuators, so the gains are given here in
  angular acceleration with PX4's ratios: K_ω = 25 s⁻¹ (a rate loop ~4× the attitude
  loop's 6.5 rad/s), I/P = 1.33 s⁻¹ and D/P = 0.02 s (MC_ROLLRATE_I/P = 0.2/0.15,
  MC_ROLLRATE_D/P = 0.003/0.15), the integral reduced with the rate error as PX4 does
  (factor 1 − (e/400 °/s)²) and bounded; τ = Ĵ α;
* allocation: the inverse of eq. (4) for four rotors (yaw given up first when a rotor would
  saturate); once the detector names an attacked rotor, PX4's motor-failure mode
  (CA_FAILURE_MODE = 1: the failed motor's column removed from the effectiveness matrix)
  — the three others are allocated as if it made no thrust, keeping u_f, τ_p, τ_q and
  giving up τ_r (PX4 de-prioritises yaw; :func:`lost_rotor_allocation`). PX4 is not told
  the attacked rotor's thrust; neither is this allocation.

Model: the controller's (mass 2 % off, inertia 10 % off in the paper scenario, as TFL's).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from tfl_mav.baselines.reference import PathReference, controller_model
from tfl_mav.control.allocation import allocate_nominal
from tfl_mav.model.geometry import rotation_rows
from tfl_mav.model.modes import Mode
from tfl_mav.model.state import State
from tfl_mav.scenario import Scenario

__all__ = ["CascadeController", "lost_rotor_allocation"]

POS_P = (0.95, 0.95, 1.0)
VEL_P = (1.8, 1.8, 4.0)
VEL_I = (0.4, 0.4, 2.0)
VEL_D = (0.2, 0.2, 0.0)
VEL_UP_MAX, VEL_DOWN_MAX = 3.0, 1.5        # m/s
VEL_INT_MAX = 3.0                          # m/s² per axis of integral action
VELD_LP_HZ = 5.0
TILT_MAX_RAD = math.radians(45.0)
THR_MIN, THR_MAX = 0.12, 1.0               # of 4 f_max
ATT_P = (6.5, 6.5, 2.8)
YAW_WEIGHT = 0.4
RATE_MAX = (math.radians(220.0), math.radians(220.0), math.radians(200.0))
RATE_P = 25.0                              # rad/s² per rad/s
RATE_I = RATE_P * 0.2 / 0.15
RATE_D = RATE_P * 0.003 / 0.15
RATE_INT_MAX = 2.0 * RATE_P                # rad/s² (PX4: MC_RR_INT_LIM 0.3 / P 0.15 = 2 rad/s)
RATE_D_LP_HZ = 30.0


def _qmul(a: Sequence[float], b: Sequence[float]) -> tuple[float, float, float, float]:
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    return (aw * bw - ax * bx - ay * by - az * bz, aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx, aw * bz + ax * by - ay * bx + az * bw)


def _qinv(q: Sequence[float]) -> tuple[float, float, float, float]:
    return (q[0], -q[1], -q[2], -q[3])


def _qnorm(q: Sequence[float]) -> tuple[float, float, float, float]:
    n = math.sqrt(sum(c * c for c in q))
    return (q[0] / n, q[1] / n, q[2] / n, q[3] / n)


def _q_between(src: Sequence[float], dst: Sequence[float]) -> tuple[float, float, float, float]:
    """The shortest rotation taking unit ``src`` to unit ``dst`` (PX4's Quaternion(src, dst))."""
    cr = (src[1] * dst[2] - src[2] * dst[1], src[2] * dst[0] - src[0] * dst[2],
          src[0] * dst[1] - src[1] * dst[0])
    dt = src[0] * dst[0] + src[1] * dst[1] + src[2] * dst[2]
    if math.sqrt(sum(c * c for c in cr)) < 1e-5 and dt < 0.0:   # opposite: any normal axis
        axis = (1.0, 0.0, 0.0) if abs(src[0]) < 0.9 else (0.0, 1.0, 0.0)
        n = (src[1] * axis[2] - src[2] * axis[1], src[2] * axis[0] - src[0] * axis[2],
             src[0] * axis[1] - src[1] * axis[0])
        return _qnorm((0.0, *n))
    w = dt + math.sqrt(dt * dt + sum(c * c for c in cr))
    return _qnorm((w, *cr))


def _q_from_rows(R: Sequence[Sequence[float]]) -> tuple[float, float, float, float]:
    """Quaternion (w, x, y, z) of the rotation with rows ``R`` (Shepperd's method)."""
    tr = R[0][0] + R[1][1] + R[2][2]
    if tr > 0.0:
        s = 2.0 * math.sqrt(tr + 1.0)
        q = (0.25 * s, (R[2][1] - R[1][2]) / s, (R[0][2] - R[2][0]) / s, (R[1][0] - R[0][1]) / s)
    elif R[0][0] > R[1][1] and R[0][0] > R[2][2]:
        s = 2.0 * math.sqrt(1.0 + R[0][0] - R[1][1] - R[2][2])
        q = ((R[2][1] - R[1][2]) / s, 0.25 * s, (R[0][1] + R[1][0]) / s, (R[0][2] + R[2][0]) / s)
    elif R[1][1] > R[2][2]:
        s = 2.0 * math.sqrt(1.0 + R[1][1] - R[0][0] - R[2][2])
        q = ((R[0][2] - R[2][0]) / s, (R[0][1] + R[1][0]) / s, 0.25 * s, (R[1][2] + R[2][1]) / s)
    else:
        s = 2.0 * math.sqrt(1.0 + R[2][2] - R[0][0] - R[1][1])
        q = ((R[1][0] - R[0][1]) / s, (R[0][2] + R[2][0]) / s, (R[1][2] + R[2][1]) / s, 0.25 * s)
    return _qnorm(q)


def lost_rotor_allocation(arm_m: float, d_m: float, lost: int) -> np.ndarray:
    """(4 × 4) wrench (u_f, τ_p, τ_q, τ_r) → rotor thrusts with rotor ``lost`` (1-4) removed
    from the effectiveness matrix of eq. (4). Three rotors cannot make four independent
    axes; PX4 gives up yaw first, and in a "+" frame the three left make (u_f, τ_p, τ_q)
    exactly (two on one arm axis, one on the other: the 3 × 3 block is invertible), so
    this is that block's inverse and τ_r's column is 0. The lost rotor's row is 0."""
    ell = arm_m
    B = np.array([[1.0, 1.0, 1.0, 1.0], [0.0, -ell, 0.0, ell], [-ell, 0.0, ell, 0.0]])
    keep = [i for i in range(4) if i != lost - 1]
    P = np.zeros((4, 4))
    P[np.ix_(keep, [0, 1, 2])] = np.linalg.inv(B[:, keep])
    return P


class CascadeController:
    """The PX4-style cascade as a :class:`~tfl_mav.api.Controller` (see the module)."""

    def reset(self, scenario: Scenario) -> None:
        m = self.model = controller_model(scenario)
        self.ref = PathReference.for_scenario(scenario)
        self.dt = scenario.run.control_dt_s
        self.vel_int = [0.0, 0.0, 0.0]
        self.rate_int = [0.0, 0.0, 0.0]
        self.v_prev: tuple[float, ...] | None = None
        self.vdot = [0.0, 0.0, 0.0]
        self.w_prev: tuple[float, ...] | None = None
        self.wdot = [0.0, 0.0, 0.0]
        self.lost = 0
        self.mode = Mode.NOMINAL
        self.hover_share_n = m.mass_kg * m.gravity_mps2 / 4.0
        self._lost_inverse: np.ndarray | None = None
        self._thr_limited = False

    def set_attack(self, rotor: int, estimate_n: float) -> None:
        """The detector names ``rotor`` (0: none): PX4's motor-failure allocation drops it."""
        if rotor == self.lost:
            return
        self.lost = rotor
        m = self.model
        self._lost_inverse = (lost_rotor_allocation(m.arm_m, m.drag_thrust_ratio_m, rotor)
                              if rotor else None)
        self.mode = Mode.ATTACKED if rotor else Mode.NOMINAL

    @staticmethod
    def _lowpass(prev: list[float], new: Sequence[float], dt: float, hz: float) -> list[float]:
        a = dt / (dt + 1.0 / (2.0 * math.pi * hz))
        return [p + a * (n - p) for p, n in zip(prev, new, strict=True)]

    def _acceleration(self, state: State) -> list[float]:
        """Position P and velocity PID → the wanted acceleration (m/s², z up)."""
        p, v, dt = state.position_m, state.velocity_mps, self.dt
        ref = self.ref.at(p)
        if ref is None:
            p_sp, v_ff, a_ff = tuple(p), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0)
        else:
            p_sp, v_ff, a_ff = ref.position_m, ref.velocity_mps, ref.acceleration_mps2
        v_sp = [v_ff[i] + POS_P[i] * (p_sp[i] - p[i]) for i in range(3)]
        v_sp[2] = min(max(v_sp[2], -VEL_DOWN_MAX), VEL_UP_MAX)
        if self.v_prev is not None:
            raw = [(v[i] - self.v_prev[i]) / dt for i in range(3)]
            self.vdot = self._lowpass(self.vdot, raw, dt, VELD_LP_HZ)
        self.v_prev = tuple(v)
        e_v = [v_sp[i] - v[i] for i in range(3)]
        acc = [a_ff[i] + VEL_P[i] * e_v[i] + self.vel_int[i] - VEL_D[i] * self.vdot[i]
               for i in range(3)]
        if not self._thr_limited:                          # PX4's anti-windup
            for i in range(3):
                self.vel_int[i] = min(max(self.vel_int[i] + VEL_I[i] * e_v[i] * dt,
                                          -VEL_INT_MAX), VEL_INT_MAX)
        return acc

    def _thrust_and_attitude(self, acc: Sequence[float]
                             ) -> tuple[float, tuple[float, float, float, float]]:
        """PX4's thrust vector from the acceleration, and the attitude set-point (yaw 0)."""
        m = self.model
        g = m.gravity_mps2
        bz = [acc[0], acc[1], g]
        n = math.sqrt(bz[0] ** 2 + bz[1] ** 2 + bz[2] ** 2)
        bz = [c / n for c in bz]
        if bz[2] < math.cos(TILT_MAX_RAD):                 # ControlMath::limitTilt
            h = math.hypot(bz[0], bz[1])
            s = math.sin(TILT_MAX_RAD) / h
            bz = [bz[0] * s, bz[1] * s, math.cos(TILT_MAX_RAD)]
        total = m.mass_kg * (g + acc[2]) / bz[2]
        lo, hi = THR_MIN * 4.0 * m.thrust_max_n, THR_MAX * 4.0 * m.thrust_max_n
        self._thr_limited = not lo < total < hi
        total = min(max(total, lo), hi)
        y_c = (0.0, 1.0, 0.0)                              # yaw set-point 0
        bx = (y_c[1] * bz[2] - y_c[2] * bz[1], y_c[2] * bz[0] - y_c[0] * bz[2],
              y_c[0] * bz[1] - y_c[1] * bz[0])
        nx = math.sqrt(sum(c * c for c in bx))
        bx = (bx[0] / nx, bx[1] / nx, bx[2] / nx)
        by = (bz[1] * bx[2] - bz[2] * bx[1], bz[2] * bx[0] - bz[0] * bx[2],
              bz[0] * bx[1] - bz[1] * bx[0])
        rows = [[bx[i], by[i], bz[i]] for i in range(3)]
        return total, _q_from_rows(rows)

    def _rate_setpoint(self, q: Sequence[float], qd: Sequence[float]) -> list[float]:
        """PX4's AttitudeControl::update: reduced attitude first, yaw weighted."""
        R, Rd = rotation_rows(q), rotation_rows(qd)
        e_z = (R[0][2], R[1][2], R[2][2])
        e_z_d = (Rd[0][2], Rd[1][2], Rd[2][2])
        qd_red = _q_between(e_z, e_z_d)
        if abs(qd_red[1]) > 1.0 - 1e-5 or abs(qd_red[2]) > 1.0 - 1e-5:
            qd_red = tuple(qd)
        else:
            qd_red = _qmul(qd_red, q)
        q_mix = _qmul(_qinv(qd_red), qd)
        if q_mix[0] < 0.0:
            q_mix = (-q_mix[0], -q_mix[1], -q_mix[2], -q_mix[3])
        w0 = min(max(q_mix[0], -1.0), 1.0)
        w3 = min(max(q_mix[3], -1.0), 1.0)
        qd = _qmul(qd_red, (math.cos(YAW_WEIGHT * math.acos(w0)), 0.0, 0.0,
                            math.sin(YAW_WEIGHT * math.asin(w3))))
        qe = _qmul(_qinv(q), qd)
        if qe[0] < 0.0:
            qe = (-qe[0], -qe[1], -qe[2], -qe[3])
        return [min(max(2.0 * qe[i + 1] * ATT_P[i], -RATE_MAX[i]), RATE_MAX[i])
                for i in range(3)]

    def _torque(self, w_sp: Sequence[float], w: Sequence[float]) -> list[float]:
        """PX4's rate PID (in angular acceleration) times the model inertia (N m)."""
        dt = self.dt
        if self.w_prev is not None:
            raw = [(w[i] - self.w_prev[i]) / dt for i in range(3)]
            self.wdot = self._lowpass(self.wdot, raw, dt, RATE_D_LP_HZ)
        self.w_prev = tuple(w)
        J = self.model.inertia_kgm2
        tau = []
        for i in range(3):
            e = w_sp[i] - w[i]
            alpha = RATE_P * e + self.rate_int[i] - RATE_D * self.wdot[i]
            tau.append(J[i] * alpha)
            factor = max(0.0, 1.0 - (e / math.radians(400.0)) ** 2)
            self.rate_int[i] = min(max(self.rate_int[i] + factor * RATE_I * e * dt,
                                       -RATE_INT_MAX), RATE_INT_MAX)
        return tau

    def update(self, t_s: float, state: State, rpm: Sequence[float]) -> list[float]:
        m = self.model
        acc = self._acceleration(state)
        total, qd = self._thrust_and_attitude(acc)
        w_sp = self._rate_setpoint(state.quaternion_wxyz, qd)
        tp, tq, tr = self._torque(w_sp, state.body_rates_radps)
        if self._lost_inverse is None:
            return allocate_nominal(total, tp, tq, tr, m.arm_m, m.drag_thrust_ratio_m,
                                    m.thrust_max_n)
        f = (self._lost_inverse @ np.array([total, tp, tq, tr])).tolist()
        out = [min(max(x, 0.0), m.thrust_max_n) for x in f]
        out[self.lost - 1] = self.hover_share_n            # not ours: no thrust counted on
        return out
