"""Relaxed-hover equilibria with one rotor pinned high (docs/relaxed-hover.md).

Mueller & D'Andrea's relaxed hover (ICRA 2014; IJRR 35(8), 2016) adapted to a rotor held at
f_stuck ∈ [m g/2, f_max] by an attacker instead of lost. Everything here is in the
*canonical* body frame of :mod:`tfl_mav.control.allocation`: the attacked rotor is rotor 2
(on −b2'), rotor 4 opposite it, and the yaw reaction sign d' = ±d. The model is the
simulator's (:mod:`tfl_mav.sitl.physics`, eq. (3), (4)):

    J ω̇ = τ − k_r ω − ω × J ω,   τ = (l (f4 − f2), l (f3 − f1), d (f1 − f2 + f3 − f4)),
    m v̇ = f_Σ R b3 − m g e3 − k_t v.

An equilibrium is a constant body rate ω̄ = Ω n̄ with rotor forces constant in the body:
then R ω̄ is constant inertially (d/dt (R ω̄) = R (ω̄ × ω̄) = 0), so the body spins at Ω
about an inertially fixed axis, which must be vertical, and the thrust axis b3 sweeps a
cone of half-angle θ about it (cos θ = n̄_z = b3 · n̄). The conditions are

    (E1) τ(f) = k_r ω̄ + ω̄ × J ω̄          (3 equations: the torque the rotors cannot
                                           balance is carried by ω̄ × J ω̄ and the drag)
    (E2) f_Σ n̄_z = m g                     (the mean thrust holds the weight)

with f2 = f_stuck fixed and f1, f3, f4 ∈ [0, f_max] free: three unknowns, one condition
beyond (E1), so the equilibria form a two-parameter family. :func:`solve` picks the member
with the widest control margin (every rotor as far as possible from 0 and f_max, the room
the attitude and position loops steer with). Numpy only (no scipy at run time).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

__all__ = ["Airframe", "Equilibrium", "Family", "airframe_from_scenario", "family",
           "linearise", "rates_for_torque", "reduced_model", "solve", "spin_eigenvalues",
           "vertical_range"]


class Airframe(NamedTuple):
    """The constants the equilibrium depends on (SI), canonical frame (attacked rotor = 2)."""

    mass_kg: float
    inertia_kgm2: tuple[float, float, float]    # (I_x', I_y', I_z) canonical body axes
    arm_m: float                                # l
    drag_m: float                               # d' = ±d: yaw reaction per N, canonical sign
    k_r: float                                  # rotational drag (N m s/rad)
    thrust_max_n: float
    gravity_mps2: float = 9.81
    k_t: float = 0.0                            # translational drag (N s/m): the drift only


class Equilibrium(NamedTuple):
    """One relaxed hover (canonical frame): rotor forces, body rate, the spin axis."""

    f_stuck_n: float
    thrusts_n: tuple[float, float, float, float]  # f1..f4 (N), f2 = f_stuck
    rates_radps: tuple[float, float, float]       # ω̄ = Ω n̄ (body, rad/s)
    spin_radps: float                             # Ω, signed: ω̄ = Ω n̄ with n̄_z > 0
    axis: tuple[float, float, float]              # n̄ (body, unit): the vertical, in the body
    total_n: float                                # f_Σ
    cone_rad: float                               # θ = arccos n̄_z: thrust axis to vertical
    radius_m: float                               # radius of the circle the centre of mass runs
    margin_n: float                               # min distance of f1, f3, f4 to 0 and f_max


def airframe_from_scenario(vehicle: object, rotor: int = 2, mass_scale: float = 1.0,
                           inertia_scale: float = 1.0) -> Airframe:
    """The canonical :class:`Airframe` of a scenario's ``vehicle`` section with ``rotor``
    attacked, its mass and inertia scaled (a model error: the controller's belief)."""
    from tfl_mav.control.allocation import canonical_frame

    v: object = vehicle
    fr = canonical_frame(rotor)
    ix, iy, iz = (float(c) * inertia_scale for c in v.inertia_kgm2)  # type: ignore[attr-defined]
    if fr.swap_xy:
        ix, iy = iy, ix
    return Airframe(float(v.mass_kg) * mass_scale, (ix, iy, iz),  # type: ignore[attr-defined]
                    float(v.arm_m), fr.d_sign * float(v.drag_thrust_ratio_m),  # type: ignore[attr-defined]
                    float(v.k_r), float(v.thrust_max_n),  # type: ignore[attr-defined]
                    float(v.gravity_mps2), float(v.k_t))  # type: ignore[attr-defined]


def torques(a: Airframe, f1: np.ndarray, f2: float, f3: np.ndarray, f4: np.ndarray
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Body torques (N m) of eq. (4) in the canonical frame (element-wise)."""
    ell, d = a.arm_m, a.drag_m
    return ell * (f4 - f2), ell * (f3 - f1), d * (f1 - f2 + f3 - f4)


def rates_for_torque(a: Airframe, tp: np.ndarray, tq: np.ndarray, tr: np.ndarray,
                     iterations: int = 12) -> np.ndarray:
    """ω (…, 3) solving (E1) τ = k_r ω + ω × J ω, element-wise, by Newton from the
    gyroscope-dominated guess ω_z = τ_r/k_r, ω_x = τ_q/((I_x − I_z) ω_z),
    ω_y = τ_p/((I_z − I_y) ω_z). (E1) is quadratic in ω and has other roots (very fast spins
    about x or y); the guess selects the branch a spin about the near-vertical z axis
    continues. Rows where Newton does not converge are NaN."""
    ix, iy, iz = a.inertia_kgm2
    kr = a.k_r
    tp, tq, tr = np.broadcast_arrays(*(np.asarray(x, dtype=float) for x in (tp, tq, tr)))
    wz = tr / kr
    # A guess on the small-tilt branch: the x, y balance with drag, ω_z fixed.
    det = kr * kr + (ix - iz) * (iz - iy) * wz * wz
    with np.errstate(all="ignore"):
        wx = (kr * tp - (iz - iy) * wz * tq) / det
        wy = (kr * tq - (ix - iz) * wz * tp) / det
    w = np.stack([wx, wy, wz], axis=-1)
    tau = np.stack([tp, tq, tr], axis=-1)
    jd = np.array([ix, iy, iz])
    for _ in range(iterations):
        jw = w * jd
        res = kr * w + np.cross(w, jw) - tau
        # d(ω × Jω)/dω = [ω]× J − [Jω]×
        x, y, z = w[..., 0], w[..., 1], w[..., 2]
        jac = np.empty((*w.shape[:-1], 3, 3))
        jac[..., 0, 0] = kr
        jac[..., 0, 1] = (iz - iy) * z
        jac[..., 0, 2] = (iz - iy) * y
        jac[..., 1, 0] = (ix - iz) * z
        jac[..., 1, 1] = kr
        jac[..., 1, 2] = (ix - iz) * x
        jac[..., 2, 0] = (iy - ix) * y
        jac[..., 2, 1] = (iy - ix) * x
        jac[..., 2, 2] = kr
        with np.errstate(all="ignore"):
            ok = np.isfinite(jac).all(axis=(-1, -2)) & (np.abs(np.linalg.det(
                np.where(np.isfinite(jac), jac, 0.0))) > 1e-300)
            safe = np.where(ok[..., None, None], jac, np.eye(3))
            step = np.linalg.solve(safe, res[..., None])[..., 0]
        w = w - step
    res = kr * w + np.cross(w, w * jd) - tau
    bad = ~(np.abs(res).max(axis=-1) <= 1e-9 * (1.0 + np.abs(tau).max(axis=-1)))
    w[bad] = np.nan
    return w


class Family(NamedTuple):
    """Equilibria of a grid of rotor forces (every array of one shape)."""

    f1: np.ndarray
    f3: np.ndarray
    f4: np.ndarray
    rates: np.ndarray      # (…, 3)
    vertical_n: np.ndarray  # f_Σ n̄_z: the mean vertical force of the spin (N)


def family(a: Airframe, f_stuck: float, f1: np.ndarray, f3: np.ndarray, f4: np.ndarray
           ) -> Family:
    """For rotor forces (f1, f_stuck, f3, f4): the spin (E1) makes and the vertical force
    f_Σ n̄_z (with n̄_z > 0 by the choice of Ω's sign) it holds."""
    f1, f3, f4 = np.broadcast_arrays(*(np.asarray(x, dtype=float) for x in (f1, f3, f4)))
    tp, tq, tr = torques(a, f1, f_stuck, f3, f4)
    w = rates_for_torque(a, tp, tq, tr)
    with np.errstate(all="ignore"):
        nz = np.abs(w[..., 2]) / np.linalg.norm(w, axis=-1)
    return Family(f1, f3, f4, w, (f1 + f_stuck + f3 + f4) * nz)


def _equilibrium(a: Airframe, f_stuck: float, f1: float, f3: float, f4: float) -> Equilibrium:
    w = rates_for_torque(a, *torques(a, np.array(f1), f_stuck, np.array(f3), np.array(f4)))
    w = [float(c) for c in w]
    norm = math.sqrt(w[0] ** 2 + w[1] ** 2 + w[2] ** 2)
    spin = math.copysign(norm, w[2])
    n = (w[0] / spin, w[1] / spin, w[2] / spin)
    total = f1 + f_stuck + f3 + f4
    cone = math.acos(min(1.0, n[2]))
    # The thrust's horizontal part, f_Σ sin θ, turns at Ω inertially: the centre of mass
    # runs a circle of radius a_h / (Ω √(Ω² + (k_t/m)²)) about its mean.
    a_h = total * math.sin(cone) / a.mass_kg
    damp = a.k_t / a.mass_kg
    radius = a_h / (abs(spin) * math.sqrt(spin * spin + damp * damp))
    fm = a.thrust_max_n
    margin = min(f1, f3, f4, fm - f1, fm - f3, fm - f4)
    return Equilibrium(f_stuck, (f1, f_stuck, f3, f4), (w[0], w[1], w[2]), spin, n, total,
                       cone, radius, margin)


def _roots(a: Airframe, f_stuck: float, f4: np.ndarray, delta: np.ndarray, weight: float,
           n_s: int = 81) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every (f4, δ, s) with f3 − f1 = δ, f1 + f3 = s at which f_Σ n̄_z = weight: the sign
    changes of f_Σ n̄_z − weight over s ∈ [0, 2 f_max] on an ``n_s`` grid, each refined by
    bisection (44 halvings: to 1e-12 of the bracket), all brackets at once."""
    fm = a.thrust_max_n
    s_grid = np.linspace(0.0, 2.0 * fm, n_s)
    F4, D, S = np.meshgrid(f4, delta, s_grid, indexing="ij")
    g = family(a, f_stuck, 0.5 * (S - D), 0.5 * (S + D), F4).vertical_n - weight
    with np.errstate(invalid="ignore"):
        change = (np.isfinite(g[..., :-1]) & np.isfinite(g[..., 1:])
                  & (np.sign(g[..., :-1]) != np.sign(g[..., 1:])))
    i, j, k = np.nonzero(change)
    f4b, db = F4[i, j, k], D[i, j, k]
    lo, hi, glo = S[i, j, k], S[i, j, k + 1], g[i, j, k]
    for _ in range(44):
        mid = 0.5 * (lo + hi)
        gm = family(a, f_stuck, 0.5 * (mid - db), 0.5 * (mid + db), f4b).vertical_n - weight
        same = (gm > 0.0) == (glo > 0.0)
        lo = np.where(same, mid, lo)
        glo = np.where(same, gm, glo)
        hi = np.where(same, hi, mid)
    return f4b, db, 0.5 * (lo + hi)


def _margin(a: Airframe, f1: np.ndarray, f3: np.ndarray, f4: np.ndarray) -> np.ndarray:
    fm = a.thrust_max_n
    return np.minimum.reduce([f1, f3, f4, fm - f1, fm - f3, fm - f4])


def solve(a: Airframe, f_stuck: float, weight_n: float | None = None,
          grid: int = 17, zooms: int = 4, symmetric: bool = False) -> Equilibrium | None:
    """The relaxed hover of ``a`` with rotor 2 pinned at ``f_stuck`` (N) that holds
    ``weight_n`` (default m g) with the widest control margin, or None if none exists.

    Search: for (f4, f3 − f1) on a ``grid`` × ``grid`` lattice over [0, f_max] × [−f_max,
    f_max], the sums f1 + f3 at which (E2) holds (:func:`_roots`), every rotor within
    [0, f_max]; the lattice is then narrowed ``zooms`` times about the best point (each
    time to 4 lattice steps wide). Deterministic (no random start). ``symmetric``: only
    f1 = f3 (τ̄_q = 0), a one-parameter search, ~10× faster; for the airframes of this
    project the full search lands there (docs/relaxed-hover.md)."""
    weight = a.mass_kg * a.gravity_mps2 if weight_n is None else float(weight_n)
    fm = a.thrust_max_n
    lo4, hi4, lod, hid = 0.0, fm, -fm, fm
    if symmetric:
        lod = hid = 0.0
    best = None
    for _ in range(zooms + 1):
        f4g = np.linspace(lo4, hi4, grid)
        dg = np.linspace(lod, hid, 1 if symmetric else grid)
        f4b, db, sb = _roots(a, f_stuck, f4g, dg, weight)
        f1, f3 = 0.5 * (sb - db), 0.5 * (sb + db)
        m = _margin(a, f1, f3, f4b)
        ok = np.isfinite(m) & (m >= 0.0)
        if not ok.any():
            break
        i = int(np.argmax(np.where(ok, m, -np.inf)))
        cand = _equilibrium(a, f_stuck, float(f1[i]), float(f3[i]), float(f4b[i]))
        if all(math.isfinite(c) for c in cand.rates_radps) and (
                best is None or cand.margin_n >= best.margin_n):
            best = cand
        s4, sd = 2.0 * (hi4 - lo4) / (grid - 1), 2.0 * (hid - lod) / (grid - 1)
        c4, cd = float(f4b[i]), float(db[i])
        lo4, hi4 = max(0.0, c4 - s4), min(fm, c4 + s4)
        if not symmetric:
            lod, hid = max(-fm, cd - sd), min(fm, cd + sd)
    return best


def vertical_range(a: Airframe, f_stuck: float, n: int = 33) -> tuple[float, float]:
    """(least, greatest) mean vertical force f_Σ n̄_z (N) a relaxed hover can make with
    rotor 2 at ``f_stuck`` and f1, f3, f4 ∈ [0, f_max] (an n³ lattice: the extremes to a
    lattice step). An equilibrium holding m g exists iff m g lies between them (the set of
    spins is connected on the branch :func:`rates_for_torque` follows); above the top the
    vehicle can only sink, below the bottom only climb."""
    g = np.linspace(0.0, a.thrust_max_n, n)
    f1, f3, f4 = np.meshgrid(g, g, g, indexing="ij")
    v = family(a, f_stuck, f1, f3, f4).vertical_n
    v = v[np.isfinite(v)]
    if v.size == 0:
        return math.nan, math.nan
    return float(v.min()), float(v.max())


def _rhs(a: Airframe, x: np.ndarray, f: Sequence[float]) -> np.ndarray:
    """(ω̇, ṅ) of the rotational dynamics with n = Rᵀ e_up, the vertical in the body:
    J ω̇ = τ − k_r ω − ω × J ω, ṅ = n × ω (an inertially fixed vector seen from the body)."""
    ix, iy, iz = a.inertia_kgm2
    w, n = x[0:3], x[3:6]
    tp, tq, tr = torques(a, np.array(f[0]), f[1], np.array(f[2]), np.array(f[3]))
    tau = np.array([float(tp), float(tq), float(tr)])
    jd = np.array([ix, iy, iz])
    wdot = (tau - a.k_r * w - np.cross(w, w * jd)) / jd
    return np.concatenate([wdot, np.cross(n, w)])


def linearise(a: Airframe, eq: Equilibrium, reduced: bool = True
              ) -> tuple[np.ndarray, np.ndarray]:
    """(A, B) of the rotational dynamics about ``eq`` (central differences of :func:`_rhs`).

    ``reduced`` (Mueller's reduced attitude): state (p, q, n_x, n_y), input (τ_p, τ_q) (N m),
    r held at its equilibrium value (its own dynamics are the slow drag pole −k_r/I_z,
    nearly decoupled); else state (p, q, r, n_x, n_y), the same inputs, n_z = √(1 − n_x² −
    n_y²) eliminated."""
    w0 = np.array(eq.rates_radps)
    n0 = np.array(eq.axis)
    full = np.concatenate([w0, n0])
    f0 = list(eq.thrusts_n)

    def g(x5: np.ndarray, u: np.ndarray) -> np.ndarray:
        nx, ny = x5[3], x5[4]
        x = np.array([x5[0], x5[1], x5[2], nx, ny, math.sqrt(max(0.0, 1 - nx * nx - ny * ny))])
        f = list(f0)
        # τ_p moves f4 (f4 = f2 + τ_p/l), τ_q moves f3 − f1 about the same sum.
        f[3] += u[0] / a.arm_m
        f[0] -= 0.5 * u[1] / a.arm_m
        f[2] += 0.5 * u[1] / a.arm_m
        d = _rhs(a, x, f)
        return np.array([d[0], d[1], d[2], d[3], d[4]])

    x0 = np.array([full[0], full[1], full[2], full[3], full[4]])
    u0 = np.zeros(2)
    h = 1e-6
    A = np.column_stack([(g(x0 + h * e, u0) - g(x0 - h * e, u0)) / (2 * h) for e in np.eye(5)])
    B = np.column_stack([(g(x0, u0 + h * e) - g(x0, u0 - h * e)) / (2 * h) for e in np.eye(2)])
    if reduced:
        keep = [0, 1, 3, 4]
        return A[np.ix_(keep, keep)], B[keep, :]
    return A, B


def reduced_model(inertia_kgm2: Sequence[float], k_r: float, rates: Sequence[float],
                  axis: Sequence[float]) -> tuple[np.ndarray, np.ndarray]:
    """(A, B) of the reduced attitude (p, q, n_x, n_y), inputs (τ_p, τ_q), about body rate
    ``rates`` and vertical-in-the-body ``axis`` with r held (n_z = √(1 − n_x² − n_y²)):

        I_x ṗ = τ_p − k_r p − (I_z − I_y) q r,   I_y q̇ = τ_q − k_r q − (I_x − I_z) p r,
        ṅ_x = n_y r − n_z q,                      ṅ_y = n_z p − n_x r.
    """
    ix, iy, iz = inertia_kgm2
    p, q, r = rates
    nx, ny, nz = axis
    a = np.array([[-k_r / ix, -(iz - iy) * r / ix, 0.0, 0.0],
                  [-(ix - iz) * r / iy, -k_r / iy, 0.0, 0.0],
                  [0.0, -nz, q * nx / nz, r + q * ny / nz],
                  [nz, 0.0, -r - p * nx / nz, -p * ny / nz]])
    b = np.array([[1.0 / ix, 0.0], [0.0, 1.0 / iy], [0.0, 0.0], [0.0, 0.0]])
    return a, b


def spin_eigenvalues(a: Airframe, eq: Equilibrium, reduced: bool = False) -> np.ndarray:
    """Eigenvalues (1/s) of the open-loop linearisation about ``eq`` (rotor forces held)."""
    A, _ = linearise(a, eq, reduced=reduced)
    return np.linalg.eigvals(A)
