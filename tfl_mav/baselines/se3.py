"""Geometric tracking control on SE(3): the baseline without attack handling.

Source: T. Lee, M. Leok, N. H. McClamroch, "Geometric tracking control of a quadrotor UAV
on SE(3)", IEEE CDC 2010, pp. 5420-5425 (eqs. (15)-(19) for the force and moment; §V for
the gains). Written in this project's frame (inertial z **up**, body FLU, thrust along +b3;
the paper has z down and thrust along −b3, so the sign of g e3 flips):

    e_x = x − x_d,   e_v = v − v_d
    F_d = −k_x e_x − k_v e_v + m g e3 + m ẍ_d,        f = F_d · R e3                 (15)
    b3_d = F_d/‖F_d‖,  b2_d = b3_d × b1_c/‖·‖,  b1_d = b2_d × b3_d,  R_d = [b1_d b2_d b3_d]
    e_R = ½ (R_dᵀ R − Rᵀ R_d)^∨,   e_Ω = Ω − Rᵀ R_d Ω_d                            (10, 11)
    M = −k_R e_R − k_Ω e_Ω + Ω × J Ω − J (Ω̂ Rᵀ R_d Ω_d − Rᵀ R_d Ω̇_d)                (16)

with the heading b1_c = (1, 0, 0) (yaw held at 0, as the nominal TFL law holds it). The
reference (x_d, v_d, ẍ_d) is the shared closest-point reference
(:mod:`~tfl_mav.baselines.reference`). Lee's Ω_d needs x_d to its fourth derivative, which a
closest-point reference does not have: here Ω_d comes from Ḟ_d with ë_x from the model (the
thrust now applied, no differentiated sensor), the reference's jerk and Ω̇_d taken as 0
(its acceleration s²κN changes slowly). Without Ω_d the attitude loop lags the force
direction and the paper's gains limit-cycle at 0.3 m; with it the paper path is flown
within 1.5 cm. Gains: the paper's §V, k_x = 16 m, k_v = 5.6 m (a translational loop at
ω = 4 rad/s, ζ = 0.7), and its k_R = 8.81, k_Ω = 2.54 for J ≈ 0.083 kg m², scaled by the
mean inertia (J̄/0.0834) so the attitude loop has the paper's dynamics on this vehicle.
m and J are the controller's model (2 %/10 % off in the paper scenario); no integral, no
estimator — as published; the one addition is a limit on the wanted acceleration
(:func:`limit_acceleration`) so that it can start as far from the path as TFL does.
Allocation: the exact inverse of eq. (4) for four rotors
(:func:`~tfl_mav.control.allocation.allocate_nominal`: yaw torque given up first when a
rotor would saturate, then clipped to [0, f_max]). It is told of an attack and ignores
it: it has no thrust-loss behaviour.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

from tfl_mav.baselines.reference import PathReference, controller_model
from tfl_mav.control.allocation import allocate_nominal
from tfl_mav.control.safe.recovery import MAX_TILT_RAD, MAX_VERTICAL_G
from tfl_mav.model.geometry import rotation_rows
from tfl_mav.model.modes import Mode
from tfl_mav.model.state import State
from tfl_mav.scenario import Scenario

__all__ = ["GeometricController", "limit_acceleration"]

# Lee, Leok, McClamroch 2010, §V: gains for m = 4.34 kg, J = diag(0.0820, 0.0845, 0.1377).
K_X_PER_KG = 16.0          # k_x / m (1/s²)
K_V_PER_KG = 5.6           # k_v / m (1/s)
K_R_PAPER = 8.81           # N m / rad
K_OMEGA_PAPER = 2.54       # N m s / rad
J_MEAN_PAPER = (0.0820 + 0.0845 + 0.1377) / 3.0


def limit_acceleration(a: Sequence[float], g: float) -> tuple[float, float, float]:
    """The wanted acceleration (m/s²) within what the rotors can fly from far off the path:
    vertical within ±``MAX_VERTICAL_G`` g, horizontal within (g + a_z) tan ``MAX_TILT_RAD``
    — the project's safe law's limits (:mod:`tfl_mav.control.safe.recovery`). Lee et al. assume
    unbounded thrust; with 4 × 8 N the unlimited law flips the vehicle from 3.85 m off the
    paper path within 1 s. Near the path the limits are inactive: the law is the paper's."""
    lim = MAX_VERTICAL_G * g
    az = min(max(a[2], -lim), lim)
    ah = math.hypot(a[0], a[1])
    amax = (g + az) * math.tan(MAX_TILT_RAD)
    k = amax / ah if ah > amax else 1.0
    return (a[0] * k, a[1] * k, az)


def _cross(a: Sequence[float], b: Sequence[float]) -> tuple[float, float, float]:
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


class GeometricController:
    """Lee et al.'s SE(3) controller as a :class:`~tfl_mav.api.Controller`."""

    mode = Mode.NOMINAL

    def reset(self, scenario: Scenario) -> None:
        m = self.model = controller_model(scenario)
        self.ref = PathReference.for_scenario(scenario)
        self.k_x = K_X_PER_KG * m.mass_kg
        self.k_v = K_V_PER_KG * m.mass_kg
        scale = sum(m.inertia_kgm2) / 3.0 / J_MEAN_PAPER
        self.k_r = K_R_PAPER * scale
        self.k_omega = K_OMEGA_PAPER * scale
        self.b1_c = (1.0, 0.0, 0.0)
        self.attacked_rotor = 0

    def set_attack(self, rotor: int, estimate_n: float) -> None:
        """Told, and ignored: the published controller has no thrust-loss behaviour."""
        self.attacked_rotor = rotor

    def update(self, t_s: float, state: State, rpm: Sequence[float]) -> list[float]:
        m = self.model
        x, v, w = state.position_m, state.velocity_mps, state.body_rates_radps
        ref = self.ref.at(x)
        if ref is None:                       # no reference (a diverged state): hold level
            xd, vd, ad = tuple(x), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0)
        else:
            xd, vd, ad = ref.position_m, ref.velocity_mps, ref.acceleration_mps2
        mass, g = m.mass_kg, m.gravity_mps2
        acc = limit_acceleration([(-self.k_x * (x[i] - xd[i]) - self.k_v * (v[i] - vd[i]))
                                  / mass + ad[i] for i in range(3)], g)
        fd = [mass * acc[0], mass * acc[1], mass * (acc[2] + g)]
        R = rotation_rows(state.quaternion_wxyz)          # body → inertial, rows
        b3 = (R[0][2], R[1][2], R[2][2])
        f = fd[0] * b3[0] + fd[1] * b3[1] + fd[2] * b3[2]
        nf = math.sqrt(fd[0] * fd[0] + fd[1] * fd[1] + fd[2] * fd[2])
        b3d = (fd[0] / nf, fd[1] / nf, fd[2] / nf)
        c = _cross(b3d, self.b1_c)
        nc = math.sqrt(c[0] * c[0] + c[1] * c[1] + c[2] * c[2])
        b2d = (c[0] / nc, c[1] / nc, c[2] / nc)
        b1d = _cross(b2d, b3d)
        # Ω_d from the rate of F_d: Ḟ_d = −k_x ė_x − k_v ë_x with ė_x = e_v and ë_x from the
        # model (the thrust now applied, f b3/m − g e3 − ẍ_d): no differentiated sensor.
        # The reference's jerk and Ω̇_d are taken as 0.
        a_now = [f * b3[i] / mass - ad[i] for i in range(3)]
        a_now[2] -= g
        dfd = [-self.k_x * (v[i] - vd[i]) - self.k_v * a_now[i] for i in range(3)]
        k3 = sum(b3d[i] * dfd[i] for i in range(3))
        db3 = [(dfd[i] - k3 * b3d[i]) / nf for i in range(3)]
        dc = _cross(db3, self.b1_c)
        k2 = sum(b2d[i] * dc[i] for i in range(3))
        db2 = [(dc[i] - k2 * b2d[i]) / nc for i in range(3)]
        db1 = [a1 + a2 for a1, a2 in zip(_cross(db2, b3d), _cross(b2d, db3), strict=True)]
        omega_d = (sum(db2[i] * b3d[i] for i in range(3)), sum(db3[i] * b1d[i] for i in range(3)),
                   sum(db1[i] * b2d[i] for i in range(3)))
        Rd = [[b1d[i], b2d[i], b3d[i]] for i in range(3)]  # rows of [b1d b2d b3d]
        # e_R = ½ (R_dᵀ R − Rᵀ R_d)^∨ ; (R_dᵀ R)_ij = Σ_k Rd[k][i] R[k][j]
        a = [[sum(Rd[k][i] * R[k][j] for k in range(3)) for j in range(3)] for i in range(3)]
        e_r = (0.5 * (a[2][1] - a[1][2]), 0.5 * (a[0][2] - a[2][0]), 0.5 * (a[1][0] - a[0][1]))
        # Rᵀ R_d Ω_d = aᵀ Ω_d
        wd = [sum(a[j][i] * omega_d[j] for j in range(3)) for i in range(3)]
        e_w = [w[i] - wd[i] for i in range(3)]
        J = m.inertia_kgm2
        jw = (J[0] * w[0], J[1] * w[1], J[2] * w[2])
        gyro = _cross(w, jw)
        ww = _cross(w, wd)                                # Ω̂ Rᵀ R_d Ω_d
        tau = [-self.k_r * e_r[i] - self.k_omega * e_w[i] + gyro[i] - J[i] * ww[i]
               for i in range(3)]
        return allocate_nominal(f, tau[0], tau[1], tau[2], m.arm_m, m.drag_thrust_ratio_m,
                                m.thrust_max_n)
