"""Rotations without frames: quaternions (w, x, y, z), rotation matrices, ZYX Euler angles.

Used alike by the physics (``sitl``), the control law and the wire conversion
(:mod:`tfl_mav.model.frames`), so each formula exists once. A quaternion maps body → world;
R(q) is the matrix of the same rotation; the Euler chart is the paper's ZYX
(§III, eq. (1): R = Rz(ψ) Ry(θ) Rx(φ)).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

__all__ = ["euler_to_quaternion", "euler_zyx_from_rotation", "quaternion_from_rotation",
           "quaternion_multiply", "rotation_from_euler_zyx", "rotation_from_quaternion",
           "rotation_rows", "yaw_from_quaternion"]


def rotation_rows(q: Sequence[float]) -> list[list[float]]:
    """R(q) as nested float lists (rows), the quaternion normalised first.

    Plain float arithmetic: the control law calls this every tick, where numpy's per-call
    cost dominates a 3×3 matrix.
    """
    w, x, y, z = q
    n = math.sqrt(w * w + x * x + y * y + z * z)
    w, x, y, z = w / n, x / n, y / n, z / n
    return [
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ]


def rotation_from_quaternion(q: Sequence[float]) -> np.ndarray:
    """3×3 rotation of a unit quaternion (w, x, y, z); the quaternion is normalised first."""
    return np.array(rotation_rows([float(c) for c in q]))


def yaw_from_quaternion(q: Sequence[float]) -> float:
    """ψ (rad) of the ZYX chart, from the quaternion directly: atan2(R₁₀, R₀₀)."""
    w, x, y, z = q
    return math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))


def euler_to_quaternion(phi: float, theta: float, psi: float) -> np.ndarray:
    """ZYX Euler angles (eq. (1): R = Rz(ψ) Ry(θ) Rx(φ)) → (w, x, y, z)."""
    cr, sr = math.cos(phi / 2), math.sin(phi / 2)
    cp, sp = math.cos(theta / 2), math.sin(theta / 2)
    cy, sy = math.cos(psi / 2), math.sin(psi / 2)
    return np.array([
        cy * cp * cr + sy * sp * sr,
        cy * cp * sr - sy * sp * cr,
        cy * sp * cr + sy * cp * sr,
        sy * cp * cr - cy * sp * sr,
    ])


def quaternion_multiply(a: Sequence[float], b: Sequence[float]) -> np.ndarray:
    """Hamilton product a ⊗ b of (w, x, y, z) quaternions; R(a ⊗ b) = R(a) R(b)."""
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    return np.array([
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    ])


def quaternion_from_rotation(R: np.ndarray) -> np.ndarray:
    """Unit quaternion (w, x, y, z), w ≥ 0, of a rotation matrix (Shepperd's method).

    Picks the largest of 1 + trace and the diagonal terms as the pivot, so it stays
    accurate for every rotation (including 180° ones, where w → 0).
    """
    R = np.asarray(R, dtype=float)
    m00, m11, m22 = R[0, 0], R[1, 1], R[2, 2]
    tr = m00 + m11 + m22
    if tr >= max(m00, m11, m22):
        s = 2.0 * math.sqrt(1.0 + tr)
        q = np.array([0.25 * s, (R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s,
                      (R[1, 0] - R[0, 1]) / s])
    elif m00 >= m11 and m00 >= m22:
        s = 2.0 * math.sqrt(1.0 + m00 - m11 - m22)
        q = np.array([(R[2, 1] - R[1, 2]) / s, 0.25 * s, (R[0, 1] + R[1, 0]) / s,
                      (R[0, 2] + R[2, 0]) / s])
    elif m11 >= m22:
        s = 2.0 * math.sqrt(1.0 + m11 - m00 - m22)
        q = np.array([(R[0, 2] - R[2, 0]) / s, (R[0, 1] + R[1, 0]) / s, 0.25 * s,
                      (R[1, 2] + R[2, 1]) / s])
    else:
        s = 2.0 * math.sqrt(1.0 + m22 - m00 - m11)
        q = np.array([(R[1, 0] - R[0, 1]) / s, (R[0, 2] + R[2, 0]) / s,
                      (R[1, 2] + R[2, 1]) / s, 0.25 * s])
    q /= np.linalg.norm(q)
    return -q if q[0] < 0 else q


def rotation_from_euler_zyx(phi: float, theta: float, psi: float) -> np.ndarray:
    """R = Rz(ψ) Ry(θ) Rx(φ) (eq. (1)), angles in rad.

    The same chart serves both frames: for R_enu_flu it gives the paper's (φ, θ, ψ); for
    R_ned_frd it gives the aerospace (roll, pitch, yaw) that MAVLink's ATTITUDE carries.
    """
    cf, sf = math.cos(phi), math.sin(phi)
    ct, st = math.cos(theta), math.sin(theta)
    cp, sp = math.cos(psi), math.sin(psi)
    return np.array([
        [cp * ct, cp * st * sf - sp * cf, cp * st * cf + sp * sf],
        [sp * ct, sp * st * sf + cp * cf, sp * st * cf - cp * sf],
        [-st, ct * sf, ct * cf],
    ])


def euler_zyx_from_rotation(R: np.ndarray) -> tuple[float, float, float]:
    """(φ, θ, ψ) in rad of R = Rz(ψ) Ry(θ) Rx(φ); θ ∈ [−π/2, π/2], φ, ψ ∈ (−π, π].

    At the chart's singularity (|θ| = π/2, gimbal lock) only φ ∓ ψ is defined; φ = 0 is
    returned there and ψ carries the whole rotation about the vertical.
    """
    R = np.asarray(R, dtype=float)
    s = -R[2, 0]
    theta = math.asin(max(-1.0, min(1.0, s)))
    if abs(s) > 1.0 - 1e-12:
        # cos θ = 0: R[0,1] = −sin(ψ ∓ φ), R[1,1] = cos(ψ ∓ φ); with φ = 0 both give ψ.
        return 0.0, theta, math.atan2(-R[0, 1], R[1, 1])
    return math.atan2(R[2, 1], R[2, 2]), theta, math.atan2(R[1, 0], R[0, 0])
