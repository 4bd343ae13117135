"""The safe law's three-rotor step as one pure function, compiled where a compiler is.

:func:`lost_rotor_step` is the inner part of
:meth:`~tfl_mav.control.safe.recovery.RecoveryLaw.update`
with a rotor attacked: from the outer loop's wanted acceleration to the canonical rotor
thrusts — the thrust direction n, the reduced attitude h = Rᵀ n, the canonical LQR torques
and the saturation-aware three-rotor allocation (Mueller & D'Andrea's relaxed hover; the
module docstring of :mod:`recovery` says why). It is plain Python the accelerator seam
compiles, inlined in the safe law's whole tick (:func:`~tfl_mav.control.safe.safe_step.safe_tick`)
with :func:`thrust_direction`, which the four-rotor law calls too: the very same source flies
as Python and, compiled mechanically, as C — the same operations in the same order, the same
bits (``tests/contract/test_native.py``). Where the C bails (an operation Python would raise on) the
Python runs and raises, as it would have.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

__all__ = ["STEP_EXAMPLE", "lost_rotor_step", "thrust_direction"]


def thrust_direction(acc: Sequence[float], vel: Sequence[float], quat: Sequence[float],
                     mass_kg: float, k_t: float, gravity_mps2: float
                     ) -> tuple[float, float, float, float, float]:
    """The wanted thrust F = m (a + g e₃) + k_t v, its direction n and the reduced attitude
    h = Rᵀ n: (tilt error rad — the angle between b3 and n —, u_f N — F's component along
    b3, never negative —, h₀, h₁, h₂). ``acc`` m/s² and ``vel`` m/s (paper frame, z up),
    ``quat`` the normalised attitude (w, x, y, z). One copy for the four-rotor law and the
    three-rotor step."""
    a0, a1, a2 = acc
    v0, v1, v2 = vel
    qw, qx, qy, qz = quat
    F0 = mass_kg * a0 + k_t * v0
    F1 = mass_kg * a1 + k_t * v1
    F2 = mass_kg * (a2 + gravity_mps2) + k_t * v2
    fn = math.sqrt(F0 ** 2 + F1 ** 2 + F2 ** 2)
    n0, n1, n2 = (F0 / fn, F1 / fn, F2 / fn) if fn > 1e-9 else (0.0, 0.0, 1.0)
    # h = Rᵀ n, R's rows as rotation_rows builds them
    h0 = ((1 - 2 * (qy * qy + qz * qz)) * n0 + (2 * (qx * qy + qw * qz)) * n1
          + (2 * (qx * qz - qw * qy)) * n2)
    h1 = ((2 * (qx * qy - qw * qz)) * n0 + (1 - 2 * (qx * qx + qz * qz)) * n1
          + (2 * (qy * qz + qw * qx)) * n2)
    h2 = ((2 * (qx * qz + qw * qy)) * n0 + (2 * (qy * qz - qw * qx)) * n1
          + (1 - 2 * (qx * qx + qy * qy)) * n2)
    c = h2 if h2 < 1.0 else 1.0
    tilt_err = math.acos(c if c > -1.0 else -1.0)
    # Thrust along b3: the component of F there; never negative (upside down: idle).
    uf = fn * h2
    uf = 0.0 if uf < 0.0 else uf
    return tilt_err, uf, h0, h1, h2


def lost_rotor_step(acc: Sequence[float], vel: Sequence[float], quat: Sequence[float],
                    rates: Sequence[float], rot: Sequence[float], gains: Sequence[float],
                    model: Sequence[float], attack_n: float) -> tuple[float, ...]:
    """One three-rotor tick in the canonical frame of the attacked rotor.

    ``acc``: the wanted acceleration (m/s², paper frame z up); ``vel``: velocity (m/s);
    ``quat``: the normalised attitude (w, x, y, z); ``rates``: body rates (p, q, r) (rad/s);
    ``rot``: the canonical frame's integer rotation, its first two rows (6 numbers);
    ``gains``: the LQR gain K, 2×4 row-major, on (h1', h2', p', q'); ``model``: (m kg, k_t
    N s/m, g m/s², l m, f_max N); ``attack_n``: the attacked rotor's thrust estimate (N).

    Returns (tilt error rad, u_f N, the canonical thrusts f1..f4 N, the side rotors' demand
    made as asked: 1.0 or 0.0, and the unconstrained demands of f1, f3, f4 N)."""
    p, q, r = rates
    r00, r01, r02, r10, r11, r12 = rot
    k00, k01, k02, k03, k10, k11, k12, k13 = gains
    m, k_t, g, ell, fmax = model
    tilt_err, uf, h0, h1, h2 = thrust_direction(acc, vel, quat, m, k_t, g)
    # Canonical components (as sum() over the integer rotation: the same roundings).
    x0 = 0 + r00 * h0 + r01 * h1 + r02 * h2
    x1 = 0 + r10 * h0 + r11 * h1 + r12 * h2
    x2 = 0 + r00 * p + r01 * q + r02 * r
    x3 = 0 + r10 * p + r11 * q + r12 * r
    tau_p = -(k00 * x0 + k01 * x1 + k02 * x2 + k03 * x3)
    tau_q = -(k10 * x0 + k11 * x1 + k12 * x2 + k13 * x3)
    an = 0.0 if attack_n < 0.0 else attack_n          # min(max(A, 0), f_max)
    an = fmax if fmax < an else an
    f4 = an + tau_p / ell
    s13 = uf - an - f4
    half = 0.5 * tau_q / ell
    f4c = 0.0 if f4 < 0.0 else f4
    f4c = fmax if fmax < f4c else f4c
    s13_free = uf - an - f4c
    s13c = 0.0 if s13_free < 0.0 else s13_free
    s13c = 2.0 * fmax if 2.0 * fmax < s13c else s13c
    mid = 0.5 * s13c
    bound = mid if mid <= 0.5 * fmax else fmax - mid   # max(−b, min(b, half))
    halfc = half if half < bound else bound
    halfc = halfc if halfc > -bound else -bound
    # The opposite rotor's τ_p is given up by design (f₄ pinned at 0 with A = 0 is the
    # normal case); the side rotors carry u_f and τ_q, what the outer loop asked for.
    made = 1.0 if s13c == s13_free and halfc == half else 0.0
    return (tilt_err, uf, mid - halfc, an, mid + halfc, f4c, made,
            0.5 * s13 - half, 0.5 * s13 + half, f4)


#: Arguments shaped as :func:`~tfl_mav.control.safe.safe_step.safe_tick` passes them.
STEP_EXAMPLE = ((0.0,) * 3, (0.0,) * 3, (1.0, 0.0, 0.0, 0.0), (0.0,) * 3, (0,) * 6,
                (0.0,) * 8, (0.0,) * 5, 0.0)
