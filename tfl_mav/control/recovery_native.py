"""The safe law's lost-rotor tick compiled to C (issue #13, :mod:`tfl_mav.native`).

:meth:`recovery.RecoveryLaw.update` with a rotor lost and the path followed — the projection's
Newton loop on σ (traced from the path's own code, as the compiled σ kernel is), the outer
loop's acceleration demand, the thrust direction, the canonical LQR torques and the
three-rotor allocation — is laid out here as one pure function (:func:`core_source`): the
same operations in the order :meth:`RecoveryLaw.update`, :meth:`PathProjector.project` and
:meth:`RecoveryLaw._accel_demand` make them, ``math.hypot`` called as CPython's own. The
gains are looked up (or designed) in Python first, the permutation to physical rotors is
applied after. Every other case — four healthy rotors, a held point, a projection that has
no start yet or fails, anything that would raise — runs :meth:`RecoveryLaw.update` itself.
"""

from __future__ import annotations

import weakref
from collections.abc import Callable
from typing import Any

import numpy as np

from tfl_mav import native
from tfl_mav.control.kernelgen import trace_block
from tfl_mav.control.recovery import (
    _KD,
    _KP,
    _TAN_MAX_TILT,
    LQR_MAX_SPIN_RADPS,
    MAX_VERTICAL_G,
    RecoveryLaw,
    RecoveryOutput,
)

__all__ = ["attach", "core_source"]

_C = ("c0x", "c0y", "c0z", "c1x", "c1y", "c1z", "c2x", "c2y", "c2z")


def core_source(trace_sigma: Callable[..., list[Any]]) -> str:
    """``recovery_core(…) -> (λ, tilt error, distance, u_f, requested, clipped)`` (canonical
    rotor order) or None, for the path whose σ ``trace_sigma`` traces."""
    sigma, _ = trace_block("s_", [["lam"]], lambda g: trace_sigma(g, 2), list(_C), " " * 8)
    i4, i8 = " " * 4, " " * 8
    at = [f"{i4}{ln[8:]}" for ln in sigma]       # σ at the converged λ, one level up
    lines = [
        "def recovery_core(pos, vel, quat, rates, lam, speed, g, mass, k_t, ix, iy, iz, ell,"
        " fmax, rot, gains, attack_n):",
        f"{i4}qw, qx, qy, qz = quat",
        f"{i4}nq = _sqrt(qw * qw + qx * qx + qy * qy + qz * qz)",
        f"{i4}qw0 = qw / nq",
        f"{i4}qx0 = qx / nq", f"{i4}qy0 = qy / nq", f"{i4}qz0 = qz / nq",
        f"{i4}qw = qw0", f"{i4}qx = qx0", f"{i4}qy = qy0", f"{i4}qz = qz0",
        f"{i4}yx, yy, yz = pos", f"{i4}v0, v1, v2 = vel", f"{i4}p, q, r = rates",
        # PathProjector.project
        f"{i4}for _ in range(8):",
        *sigma,
        f"{i8}ex = yx - c0x", f"{i8}ey = yy - c0y", f"{i8}ez = yz - c0z",
        f"{i8}gr = ex * c1x + ey * c1y + ez * c1z",
        f"{i8}dg = 2.0 * (ex * c2x + ey * c2y + ez * c2z) - (c1x * c1x + c1y * c1y + c1z * c1z)",
        f"{i8}step = -gr / dg if dg < 0.0 else -0.1 * _copysign(1.0, gr)",
        f"{i8}step = -0.5 if step < -0.5 else (0.5 if step > 0.5 else step)",
        f"{i8}lam += step",
        f"{i8}if abs(step) < 1e-9:", f"{i8}    break",
        f"{i4}if not _isfinite(lam):", f"{i8}return None",
        *at,
        f"{i4}s1sq = c1x * c1x + c1y * c1y + c1z * c1z",
        f"{i4}if not s1sq > 0.0:", f"{i8}return None",
        f"{i4}s1 = _sqrt(s1sq)",
        f"{i4}tx = c1x / s1", f"{i4}ty = c1y / s1", f"{i4}tz = c1z / s1",
        f"{i4}d2x = 2.0 * c2x", f"{i4}d2y = 2.0 * c2y", f"{i4}d2z = 2.0 * c2z",
        f"{i4}a = d2x * tx + d2y * ty + d2z * tz",
        f"{i4}ex = yx - c0x", f"{i4}ey = yy - c0y", f"{i4}ez = yz - c0z",
        f"{i4}k0 = (d2x - a * tx) / s1sq", f"{i4}k1 = (d2y - a * ty) / s1sq",
        f"{i4}k2 = (d2z - a * tz) / s1sq",
        f"{i4}dist = _sqrt(ex * ex + ey * ey + ez * ez)",
        # RecoveryLaw._accel_demand (following the path)
        f"{i4}sp = speed", f"{i4}sp2 = sp * sp",
        f"{i4}a0 = {_KP!r} * (c0x - yx) + {_KD!r} * (sp * tx - v0) + sp2 * k0",
        f"{i4}a1 = {_KP!r} * (c0y - yy) + {_KD!r} * (sp * ty - v1) + sp2 * k1",
        f"{i4}a2 = {_KP!r} * (c0z - yz) + {_KD!r} * (sp * tz - v2) + sp2 * k2",
        f"{i4}lim = {MAX_VERTICAL_G!r} * g",
        f"{i4}az = a2 if a2 < lim else lim",
        f"{i4}az = az if az > -lim else -lim",
        f"{i4}ah = _hypot(a0, a1)",
        f"{i4}amax = (g + az) * {_TAN_MAX_TILT!r}",
        f"{i4}if ah > amax:", f"{i8}a0 *= amax / ah", f"{i8}a1 *= amax / ah",
        # RecoveryLaw.update, a rotor lost
        f"{i4}F0 = mass * a0 + k_t * v0", f"{i4}F1 = mass * a1 + k_t * v1",
        f"{i4}F2 = mass * (az + g) + k_t * v2",
        f"{i4}fn = _sqrt(F0 ** 2 + F1 ** 2 + F2 ** 2)",
        f"{i4}n0 = F0 / fn if fn > 1e-9 else 0.0", f"{i4}n1 = F1 / fn if fn > 1e-9 else 0.0",
        f"{i4}n2 = F2 / fn if fn > 1e-9 else 1.0",
        f"{i4}h0 = ((1 - 2 * (qy * qy + qz * qz)) * n0 + (2 * (qx * qy + qw * qz)) * n1"
        " + (2 * (qx * qz - qw * qy)) * n2)",
        f"{i4}h1 = ((2 * (qx * qy - qw * qz)) * n0 + (1 - 2 * (qx * qx + qz * qz)) * n1"
        " + (2 * (qy * qz + qw * qx)) * n2)",
        f"{i4}h2 = ((2 * (qx * qz + qw * qy)) * n0 + (2 * (qy * qz - qw * qx)) * n1"
        " + (1 - 2 * (qx * qx + qy * qy)) * n2)",
        f"{i4}cc = h2 if h2 < 1.0 else 1.0",
        f"{i4}tilt = _acos(cc if cc > -1.0 else -1.0)",
        f"{i4}uf = fn * h2", f"{i4}uf = 0.0 if uf < 0.0 else uf",
        f"{i4}(r00, r01, r02), (r10, r11, r12), (r20, r21, r22) = rot",
        f"{i4}x0 = 0 + r00 * h0 + r01 * h1 + r02 * h2",
        f"{i4}x1 = 0 + r10 * h0 + r11 * h1 + r12 * h2",
        f"{i4}x2 = 0 + r00 * p + r01 * q + r02 * r",
        f"{i4}x3 = 0 + r10 * p + r11 * q + r12 * r",
        f"{i4}(k00, k01, k02, k03), (k10, k11, k12, k13) = gains",
        f"{i4}tau_p = -(k00 * x0 + k01 * x1 + k02 * x2 + k03 * x3)",
        f"{i4}tau_q = -(k10 * x0 + k11 * x1 + k12 * x2 + k13 * x3)",
        f"{i4}an = 0.0 if attack_n < 0.0 else attack_n",
        f"{i4}an = fmax if fmax < an else an",
        f"{i4}f4 = an + tau_p / ell", f"{i4}s13 = uf - an - f4", f"{i4}half = 0.5 * tau_q / ell",
        f"{i4}f4c = 0.0 if f4 < 0.0 else f4", f"{i4}f4c = fmax if fmax < f4c else f4c",
        f"{i4}s13c = uf - an - f4c", f"{i4}s13c = 0.0 if s13c < 0.0 else s13c",
        f"{i4}s13c = 2.0 * fmax if 2.0 * fmax < s13c else s13c",
        f"{i4}mid = 0.5 * s13c",
        f"{i4}bound = mid if mid <= 0.5 * fmax else fmax - mid",
        f"{i4}halfc = half if half < bound else bound",
        f"{i4}halfc = halfc if halfc > -bound else -bound",
        f"{i4}return (lam, tilt, dist, uf, (0.5 * s13 - half, an, 0.5 * s13 + half, f4),"
        " (mid - halfc, an, mid + halfc, f4c))",
    ]
    return "\n".join(lines) + "\n"


def _native_update(rec: RecoveryLaw, namespace: dict[str, Any]
                   ) -> Callable[..., RecoveryOutput | None]:
    """``RecoveryLaw.update``'s compiled form, or None where the Python one must run.

    Runs every lost-rotor tick (#13): what depends on the attacked rotor only (its frame's
    rotation, the swapped inertias, the inverse permutation) is looked up once per rotor,
    and :meth:`RecoveryLaw._lqr`'s cache hit is written out (a rate within
    ±``LQR_MAX_SPIN_RADPS`` is its own clamp; anything else goes through ``_lqr``)."""
    per_rotor: dict[int, tuple[Any, ...]] = {}
    gains_cache = rec._gains
    lqr = rec._lqr
    spin_max = LQR_MAX_SPIN_RADPS
    ndarray = np.ndarray

    def update(s: Any, attacked_rotor: int, attack_n: float) -> RecoveryOutput | None:
        core = namespace["_core"]
        proj = rec.projector
        consts = per_rotor.get(attacked_rotor)
        if consts is None:
            fr = rec._frames.get(attacked_rotor)
            if core is None or fr is None:
                return None
            ix, iy, _ = rec.inertia
            ixc, iyc = (iy, ix) if fr.swap_xy else (ix, iy)
            consts = per_rotor[attacked_rotor] = (fr.rot, *fr.rot[2], ixc, iyc, ixc > iyc,
                                                  *rec._inverse_perm[attacked_rotor])
        if core is None or rec.hold_m is not None or proj is None or proj.lam is None:
            return None
        rot, r20, r21, r22, ixc, iyc, swapped, j0, j1, j2, j3 = consts
        rates = s.body_rates_radps
        if type(rates) is ndarray:
            rates = rates.tolist()
        p, q, r = rates
        w = 0 + r20 * p + r21 * q + r22 * r
        gains = gains_cache.get((round(w * 2.0), swapped)) if -spin_max <= w <= spin_max \
            else None
        if gains is None:
            gains = lqr(w, ixc, iyc)
        ix, iy, iz = rec.inertia
        res = core(s.position_m, s.velocity_mps, s.quaternion_wxyz, (p, q, r), proj.lam,
                   rec.speed, rec.g, rec.mass_kg, rec.k_t, ix, iy, iz, rec.arm_m, rec.fmax,
                   rot, gains, attack_n)
        if res is None:
            return None
        lam, tilt, dist, uf, req, f = res
        proj.lam = lam
        return RecoveryOutput([req[j0], req[j1], req[j2], req[j3]],
                              [f[j0], f[j1], f[j2], f[j3]], tilt, dist, uf)
    return update


def attach(rec: RecoveryLaw, trace_sigma: Callable[..., list[Any]] | None) -> None:
    """Give ``rec`` the compiled lost-rotor tick for its path (``trace_sigma``: the path's
    traced σ; None: nothing to compile), now or when a background build completes."""
    if trace_sigma is None or rec.projector is None or native.mode() == "off":
        return
    namespace: dict[str, Any] = {"_core": None}
    rec.native = _native_update(rec, namespace)
    ref = weakref.ref(rec)

    def ready(core: Callable[..., Any]) -> None:
        if ref() is not None:
            namespace["_core"] = core

    core = native.obtain(core_source(trace_sigma), ready)
    if core is not None:
        ready(core)
