"""The TFL law's arithmetic (paper §V) as plain functions of their arguments.

Plain functions of floats and tuples, the pieces :func:`tfl_mav.control.tfl.step.tfl_step`
is made of; the accelerator seam inlines them into the compiled tick, the same operations in
the same order.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

__all__ = ["attacked_tau_r", "b0_inverse", "cofactors", "cramer", "held_rate_command",
           "linear_rhs", "output_rows",
           "rate_prediction", "rotation", "saturate", "solve3", "torques", "yaw_tau_r"]

V3 = Sequence[Any]


def rotation(q: V3) -> tuple[Any, ...]:
    """R(q) row by row (9 values) of the quaternion (w, x, y, z), normalised first: the same
    operations as :func:`tfl_mav.model.geometry.rotation_rows`, as one flat tuple."""
    w, x, y, z = q
    n = math.sqrt(w * w + x * x + y * y + z * z)
    w, x, y, z = w / n, x / n, y / n, z / n
    return (1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
            2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
            2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y))


def output_rows(y: V3, v: V3, b1: V3, b2: V3, b3: V3, pc: Any, qc: Any, rc: Any, uf: Any,
                duf: Any, mass: Any, k_t: Any, gravity: Any, dist: V3
                ) -> tuple[tuple[Any, ...], ...]:
    """Taylor rows (y, ẏ, ÿ/2, y⃛/6, a₀/24) of the output y = x_q (eq. (5)) from the
    model (eq. (3)) with the extension x13 = u_f, x14 = u̇_f (eq. (9)): ÿ = (u_f/m) b3
    − g e3 − (k_t/m) ẏ + d, and a₀ = y⁽⁴⁾ at ü_f = ṗ = q̇ = 0 (the drift L_f⁴ of
    eq. (10)). ``dist`` is d, an unmodelled acceleration held constant over the horizon
    (m/s², the translational observer's; zeros: the paper's model)."""
    kt = k_t / mass
    ufm = uf / mass
    dufm = duf / mass
    dufm2 = 2.0 * duf / mass
    pr, qr = pc * rc, qc * rc
    pq2 = pc * pc + qc * qc
    b1x, b1y, b1z = b1
    b2x, b2y, b2z = b2
    b3x, b3y, b3z = b3
    vx, vy, vz = v
    # x, y, z written out (this runs every tick); the same operations as one loop.
    yddx = ufm * b3x - kt * vx + dist[0]
    yddy = ufm * b3y - kt * vy + dist[1]
    yddz = ufm * b3z - kt * vz - gravity + dist[2]
    db3x = qc * b1x - pc * b2x
    db3y = qc * b1y - pc * b2y
    db3z = qc * b1z - pc * b2z
    ydddx = dufm * b3x + ufm * db3x - kt * yddx
    ydddy = dufm * b3y + ufm * db3y - kt * yddy
    ydddz = dufm * b3z + ufm * db3z - kt * yddz
    a0x = dufm2 * db3x + ufm * (pr * b1x + qr * b2x - pq2 * b3x) - kt * ydddx
    a0y = dufm2 * db3y + ufm * (pr * b1y + qr * b2y - pq2 * b3y) - kt * ydddy
    a0z = dufm2 * db3z + ufm * (pr * b1z + qr * b2z - pq2 * b3z) - kt * ydddz
    return ((y[0], vx, yddx / 2.0, ydddx / 6.0, a0x / 24.0),
            (y[1], vy, yddy / 2.0, ydddy / 6.0, a0y / 24.0),
            (y[2], vz, yddz / 2.0, ydddz / 6.0, a0z / 24.0))


def linear_rhs(xi1: V3, xi2: V3, eta: V3, kx: V3, ke: V3, speed: Any
               ) -> tuple[Any, Any, Any]:
    """v − L_f⁴φ: the linear ξ, η controllers (eqs. (23), (24), the η chain about the
    path speed) less the drift of (α1, α2, π)."""
    v_xi1 = -(kx[0] * xi1[0] + kx[1] * xi1[1] + kx[2] * xi1[2] + kx[3] * xi1[3])
    v_xi2 = -(kx[0] * xi2[0] + kx[1] * xi2[1] + kx[2] * xi2[2] + kx[3] * xi2[3])
    v_eta = -(ke[0] * (eta[1] - speed) + ke[1] * eta[2] + ke[2] * eta[3])
    return v_xi1 - xi1[4], v_xi2 - xi2[4], v_eta - eta[4]


def cofactors(A: Sequence[V3]) -> tuple[Any, ...]:
    """(co0, co1, co2, det, row-norm product) of a 3×3 matrix, for Cramer's rule."""
    (a, b_, c), (d, e, f), (g, h, i) = A
    co0 = e * i - f * h
    co1 = f * g - d * i
    co2 = d * h - e * g
    det = a * co0 + b_ * co1 + c * co2
    norms = (math.sqrt(a * a + b_ * b_ + c * c) * math.sqrt(d * d + e * e + f * f)
             * math.sqrt(g * g + h * h + i * i))
    return co0, co1, co2, det, norms


def cramer(A: Sequence[V3], b: V3, co0: Any, co1: Any, co2: Any, inv: Any
           ) -> tuple[Any, Any, Any]:
    """x with A x = b, given the first-row cofactors and ``inv`` = 1/det."""
    (a, b_, c), (d, e, f), (g, h, i) = A
    x0 = (b[0] * co0 + b[1] * (c * h - b_ * i) + b[2] * (b_ * f - c * e)) * inv
    x1 = (b[0] * co1 + b[1] * (a * i - c * g) + b[2] * (c * d - a * f)) * inv
    x2 = (b[0] * co2 + b[1] * (b_ * g - a * h) + b[2] * (a * e - b_ * d)) * inv
    return x0, x1, x2


def solve3(A: Sequence[Sequence[float]], b: Sequence[float]
           ) -> tuple[tuple[float, float, float], float]:
    """Solve a 3×3 system by Cramer's rule; returns (x, |det| relative to the row norms),
    x = 0 when that is below 1e-12."""
    co0, co1, co2, det, norms = cofactors(A)
    rel = abs(det) / norms if norms > 0 else 0.0
    x = (0.0, 0.0, 0.0)
    if not rel < 1e-12:
        x = cramer(A, b, co0, co1, co2, 1.0 / det)
    return x, rel


def b0_inverse(z: V3, b1: V3, b2: V3, b3: V3, mass: Any, uf: Any) -> tuple[Any, Any, Any]:
    """w = (ü_f, ṗ, q̇) with B₀ w = z, B₀ = [b3/m, −(u_f/m) b2, (u_f/m) b1] (orthogonal
    columns; u_f > 0)."""
    z0, z1, z2 = z
    udd = mass * (z0 * b3[0] + z1 * b3[1] + z2 * b3[2])
    pdot = -mass / uf * (z0 * b2[0] + z1 * b2[1] + z2 * b2[2])
    qdot = mass / uf * (z0 * b1[0] + z1 * b1[1] + z2 * b1[2])
    return udd, pdot, qdot


def torques(pdot: Any, qdot: Any, pc: Any, qc: Any, rc: Any, ix: Any, iy: Any, iz: Any,
            kr: Any) -> tuple[Any, Any]:
    """τ_p, τ_q for the demanded ṗ, q̇ by Euler's equation with rate damping (eq. (3))."""
    return (ix * pdot + kr * pc + (iz - iy) * qc * rc,
            iy * qdot + kr * qc + (ix - iz) * pc * rc)


def attacked_tau_r(uf: Any, tau_p: Any, attack_n: Any, arm: Any, d: Any) -> Any:
    """τ_r from τ_p with f₂ = A (eq. (6))."""
    return d * (uf - 2.0 * (tau_p + 2.0 * arm * attack_n) / arm)


def yaw_tau_r(r2: V3, psi_e: float, psi_ref: float, pc: float, qc: float, rc: float,
              qdot: float, k_yaw: V3, ixyz: V3, kr: float) -> float:
    """τ_r of the nominal law's yaw loop ψ̈ = −k₁ψ̇ − k₀(ψ − ψ_ref), exact through the
    Euler chart (eq. (2)); ``r2`` is R's last row, ψ_e = atan2(R₁₀, R₀₀) (floats only)."""
    ix, iy, iz = ixyz
    phi_e = math.atan2(r2[1], r2[2])
    th_e = -math.asin(max(-1.0, min(1.0, r2[0])))
    sph, cph = math.sin(phi_e), math.cos(phi_e)
    cth, sth = math.cos(th_e), math.sin(th_e)
    dphi = pc + (qc * sph + rc * cph) * sth / cth
    dth = qc * cph - rc * sph
    dpsi = (qc * sph + rc * cph) / cth
    err = math.remainder(psi_e - psi_ref, math.tau)
    psi_dd = -k_yaw[1] * dpsi - k_yaw[0] * err
    drift = (qc * cph * dphi - rc * sph * dphi) / cth + (qc * sph + rc * cph) * sth \
        * dth / (cth * cth)
    rdot = ((psi_dd - drift) * cth - qdot * sph) / cph
    return iz * rdot + kr * rc + (iy - ix) * pc * qc


def held_rate_command(pdot: float, qdot: float, rc: float, dt: float, ixyz: V3
                      ) -> tuple[float, float]:
    """The (ṗ, q̇) to command (rad/s²) for a torque held over a tick of ``dt`` s while the
    body spins at r = ``rc`` rad/s under it, given the law's (ṗ, q̇) at the tick's start.

    The continuous law's (ṗ, q̇) turn the thrust axis towards a direction fixed over the
    tick, so in (b1, b2) they turn by −r·t. The acceleration a held torque gives turns by
    −(1 − I_z/I)·r·t only: eq. (3)'s gyroscopic terms ṗ = … − ((I_z − I_y)/I_x) q r,
    q̇ = … − ((I_x − I_z)/I_y) p r, I = (I_x + I_y)/2. Turning the command by the
    difference over half a tick, (I_z/I)·r·dt/2, makes the tick's mean acceleration the
    law's mean to O(dt²); held as it is, the tilt lags the demand by that angle (0.013 rad
    at 1 kHz with the yaw spinning at 40 rad/s: 0.2-0.5 mm on the paper path's bends)."""
    half = dt * rc * ixyz[2] / (ixyz[0] + ixyz[1])
    ch, sh = math.cos(half), math.sin(half)
    return ch * pdot + sh * qdot, ch * qdot - sh * pdot


def saturate(f: Sequence[float], raw: Sequence[float], last: Sequence[float], fmax: float
             ) -> tuple[list[float], list[bool]]:
    """(f clipped to [0, f_max], saturated flags of the unbounded thrusts ``raw``); a
    non-finite thrust (f − f is NaN) keeps the ``last`` command (floats only)."""
    hi = fmax + 1e-9
    sat = [not -1e-9 <= raw[k] <= hi for k in range(4)]
    return [(0.0 if f[k] < 0.0 else (fmax if fmax < f[k] else f[k])) if f[k] - f[k] == 0.0
            else last[k] for k in range(4)], sat


def rate_prediction(d0: Any, d1: Any, d2: Any, d3: Any, pc: Any, qc: Any, rc: Any, ix: Any,
                    iy: Any, iz: Any, kr: Any, arm: Any) -> tuple[Any, Any]:
    """ṗ, q̇ the model predicts (eq. (3)) for the thrusts d0…d3 canonical rotors 1-4
    deliver: τ_p' = l (f₄' − f₂'), τ_q' = l (f₃' − f₁')."""
    return ((arm * (d3 - d1) - kr * pc - (iz - iy) * qc * rc) / ix,
            (arm * (d2 - d0) - kr * qc - (ix - iz) * pc * rc) / iy)
