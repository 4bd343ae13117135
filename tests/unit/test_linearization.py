"""The property the paper proves, checked on the law itself: ξ⁽⁴⁾ = v (§V, eq. (22)).

With the regular feedback of eq. (21) applied, the virtual output φ = (α1, α2, π) of
eq. (14) obeys φ⁽⁴⁾ = (v^ξ1, v^ξ2, v^η) *exactly*, at every state where the decoupling
matrix D(x) (eq. (15)) is invertible, for the nominal model and for the attacked one
(f_k = A on any rotor k). This test checks that identity on random states without flying:

1. Build the plain law of §V on an exact model (scenario ``paper-exact``: law "paper", no
   mass or inertia error, ideal motors), put the dynamic extension (eq. (9)) at a random
   x13 = u_f, x14 = u̇_f, and evaluate the law once on a random state near the §VI path.
2. Read back what the law commanded: the rotor thrusts (→ the body torques, through the
   airframe's mixer, eq. (4), less the turn the law gives a torque held over its period:
   :func:`continuous_torques`) and u_d = ü_f (from its extension update
   x14 ← x14 + Δt·u_d, exact to rounding when nothing saturates); recompute the auxiliary
   inputs v from its ξ, η (``ControlOutput.xi``/``.eta``) and its gains, eqs. (23), (24).
3. Differentiate the *physics* (``tfl_mav.sitl.physics.derivative``, the plant, written
   independently of the law with quaternions and rotor thrusts) along the closed loop:
   thrust u_f(t) = x13 + x14 t + u_d t²/2, torques held. Evaluating ``derivative`` on
   truncated power series (the small class below) and Picard-iterating gives the exact
   Taylor coefficients of the trajectory — "Taylor integration", no step size. Torques
   held constant lose nothing: y⁽⁴⁾(0) depends on the torques only through Ω̇(0).
4. Push the true position series through the path's jet code (``PathTracker.evaluate``,
   whose jets test_paths.py checks against finite differences) and compare φ⁽⁴⁾(0) with v.

Why the tolerance is what it is: steps 1-4 are exact algebra done in floating point, so the
only error is rounding. The largest numbers in play are |L_f⁴φ| and |v| (tens) and the
3×3 solve of eq. (21) can amplify rounding by cond(Dφ·B₀) ≲ 10³ on these states (B₀'s
columns scale as 1/m and u_f/m); with ~10² flops per quantity that is
10³ · 10² · 2.2e-16 ≈ 2e-11 relative. We allow 1e-10 relative to the largest term (which
reaches ~10³ m/s⁴ near the path's bends); measured: ≤ 3e-14. Modelling errors are far
above that: a 0.01 % inertia error in the law's model already moves φ⁽⁴⁾ by ~3e-5
relative (see :func:`test_a_model_error_breaks_the_identity`), and a mass error shows
already in ξ (orders 0-3), which must equal the true T(x) of eq. (17).

The series integrator is itself checked against the physics the ordinary way
(:func:`test_series_integration_matches_finite_differences_of_the_physics`): central
second differences of the acceleration ÿ = derivative(x)[3:6] along an RK4 trajectory.
"""

from __future__ import annotations

import math
import random
from collections.abc import Sequence

import pytest

from tfl_mav.build import build_controller
from tfl_mav.control.tfl.law_math import held_rate_command
from tfl_mav.model.geometry import euler_to_quaternion
from tfl_mav.model.modes import Mode
from tfl_mav.model.state import State
from tfl_mav.scenario import Scenario, apply_overrides, load_scenario
from tfl_mav.sitl.physics import RigidBodyParams, derivative, mix

EPS = 2.2e-16


# ----------------------------------------------------------------------------- series
class Series:
    """Truncated power series Σ c_k tᵏ (k ≤ order): just what ``derivative`` uses (+ − × ÷float)."""

    __slots__ = ("c",)

    def __init__(self, c: Sequence[float]) -> None:
        self.c = list(c)

    @staticmethod
    def _lift(o: object, n: int) -> list[float]:
        return o.c if isinstance(o, Series) else [float(o)] + [0.0] * (n - 1)  # type: ignore[arg-type]

    def __add__(self, o: object) -> Series:
        b = self._lift(o, len(self.c))
        return Series([x + y for x, y in zip(self.c, b, strict=True)])

    __radd__ = __add__

    def __sub__(self, o: object) -> Series:
        b = self._lift(o, len(self.c))
        return Series([x - y for x, y in zip(self.c, b, strict=True)])

    def __rsub__(self, o: object) -> Series:
        return -self + o

    def __neg__(self) -> Series:
        return Series([-x for x in self.c])

    def __mul__(self, o: object) -> Series:
        if not isinstance(o, Series):
            return Series([x * float(o) for x in self.c])  # type: ignore[arg-type]
        a, b = self.c, o.c
        return Series([sum(a[i] * b[k - i] for i in range(k + 1)) for k in range(len(a))])

    __rmul__ = __mul__

    def __truediv__(self, o: float) -> Series:
        return Series([x / o for x in self.c])


def taylor_of_trajectory(p: RigidBodyParams, x0: Sequence[float], uf: Sequence[float],
                         torques: Sequence[float], order: int) -> list[list[float]]:
    """Taylor coefficients (order 0..``order``) of the 13 physics states at t = 0.

    ``uf`` = coefficients of u_f(t); torques constant. Picard iteration on series: each pass
    makes one more coefficient exact, so ``order`` passes give all of them exactly.
    """
    n = order + 1
    u = Series(list(uf) + [0.0] * (n - len(uf)))
    xs = [Series([xi] + [0.0] * order) for xi in x0]
    for _ in range(order):
        f = derivative(p, xs, (u, *torques))  # type: ignore[arg-type]
        xs = [Series([xi] + [fi.c[k] / (k + 1) for k in range(order)])
              for xi, fi in zip(x0, f, strict=True)]
    return [s.c for s in xs]


# ----------------------------------------------------------------------------- set-up
def exact_scenario() -> Scenario:
    """The §VI vehicle and path with the plain §V law on an exact model."""
    return apply_overrides(load_scenario("paper-exact"), ["controller.motor_time_constant_scale=0"])


def true_params(sc: Scenario) -> RigidBodyParams:
    v = sc.vehicle
    return RigidBodyParams(v.mass_kg, v.inertia_kgm2, v.arm_m, v.drag_thrust_ratio_m, v.k_t,
                           v.k_r, v.gravity_mps2)


def random_state(rng: random.Random) -> tuple[State, float, float, float]:
    """A state near the §VI path (paper frame), plus x13 = u_f (N), x14 = u̇_f (N/s), A (N).

    Within 5 cm of the path (its tightest radius of curvature is 0.24 m, so the projection
    of eq. (13) is well defined), roll/pitch within ±0.6 rad (far from gimbal lock,
    Assumption 1), any yaw, rates up to 1.5 rad/s, u_f around hover (m g ≈ 10.8 N).
    """
    lam = rng.uniform(-math.pi, math.pi)
    on_path = (lam, math.cos(lam), 8.0 - 4.0 * math.cos(lam))
    pos = [c + rng.uniform(-0.05, 0.05) for c in on_path]
    vel = [rng.uniform(-1.0, 1.0) for _ in range(3)]
    q = euler_to_quaternion(rng.uniform(-0.6, 0.6), rng.uniform(-0.6, 0.6),
                            rng.uniform(-math.pi, math.pi))
    rates = [rng.uniform(-1.5, 1.5) for _ in range(3)]
    return (State(pos, vel, [float(c) for c in q], rates), rng.uniform(8.0, 14.0),
            rng.uniform(-3.0, 3.0), rng.uniform(1.0, 3.0))


def continuous_torques(p: RigidBodyParams, state: State, tau_p: float, tau_q: float,
                       dt: float) -> tuple[float, float]:
    """The (τ_p, τ_q) of the continuous law from those it commanded for a period ``dt``.

    The law turns its (ṗ, q̇) by (I_z/I)·r·dt/2 so that a torque held over the period
    gives the continuous law's mean acceleration (``law_math.held_rate_command``, a
    discretisation, not eq. (21)); eq. (22) is the continuous law's claim, so the turn is
    undone here (the same function at −r) before the physics is differentiated."""
    ix, iy, iz = p.inertia_kgm2
    pr, qr, rr = state.body_rates_radps
    pdot = (tau_p - p.k_r * pr - (iz - iy) * qr * rr) / ix
    qdot = (tau_q - p.k_r * qr - (ix - iz) * pr * rr) / iy
    pdot, qdot = held_rate_command(pdot, qdot, -rr, dt, p.inertia_kgm2)
    return (ix * pdot + p.k_r * pr + (iz - iy) * qr * rr,
            iy * qdot + p.k_r * qr + (ix - iz) * pr * rr)


def check_one(sc: Scenario, rotor: int, rng: random.Random) -> tuple[float, float] | None:
    """One random state: returns (|φ⁽⁴⁾ − v|_∞, scale), or None when the law saturated a
    rotor (then it cannot deliver w, and eq. (22) is not claimed)."""
    state, uf, duf, a_n = random_state(rng)
    ctrl = build_controller(sc)
    ctrl.x13, ctrl.x14 = uf, duf
    if rotor:
        ctrl.set_attack(rotor, a_n)
    out = ctrl.update(state)
    assert out.mode == (Mode.ATTACKED if rotor else Mode.NOMINAL), out.reason
    if any(out.saturated):
        return None
    u_d = (ctrl.x14 - duf) / ctrl.dt                   # ü_f the law commanded, eq. (9)
    assert ctrl.x13 == pytest.approx(uf + ctrl.dt * duf + 0.5 * ctrl.dt ** 2 * u_d, abs=1e-12)

    p = true_params(sc)
    f = out.rotor_thrust_n
    if rotor:
        assert f[rotor - 1] == a_n                       # the attacker's rotor, not ours
    wrench = mix(p, f)
    assert wrench[0] == pytest.approx(uf, abs=1e-12)   # the rotors deliver x13 now
    wrench = (wrench[0], *continuous_torques(p, state, wrench[1], wrench[2], ctrl.dt),
              wrench[3])
    x0 = [*state.position_m, *state.velocity_mps, *state.quaternion_wxyz,
          *state.body_rates_radps]
    coeffs = taylor_of_trajectory(p, x0, (uf, duf, 0.5 * u_d), wrench[1:], order=4)
    true_taylor = [coeffs[i][:5] for i in range(3)]

    # The true ξ, η jets along the closed-loop physics.
    path_out = ctrl.tracker.evaluate(true_taylor)
    assert path_out.in_tube
    true_xi1 = path_out.alpha[0].derivatives()
    true_xi2 = path_out.alpha[1].derivatives()
    true_eta = path_out.pi.derivatives()

    # The law's ξ, η (orders 0-3) are T(x) of eq. (17): they must be the true ones.
    law_xi1, law_xi2 = out.xi
    for law, true in ((law_xi1, true_xi1), (law_xi2, true_xi2), (out.eta, true_eta)):
        assert list(law) == pytest.approx(true[:4], rel=1e-9, abs=1e-9)

    # Auxiliary inputs of eqs. (23), (24), from the law's own ξ, η and gains.
    kx, ke = ctrl.k_xi, ctrl.k_eta
    v = (-sum(k * x for k, x in zip(kx, law_xi1, strict=True)),
         -sum(k * x for k, x in zip(kx, law_xi2, strict=True)),
         -(ke[0] * (out.eta[1] - ctrl.cfg.speed_mps) + ke[1] * out.eta[2]
           + ke[2] * out.eta[3]))
    phi4 = (true_xi1[4], true_xi2[4], true_eta[4])
    err = max(abs(a - b) for a, b in zip(phi4, v, strict=True))
    scale = max(1.0, *(abs(x) for x in v), *(abs(x) for x in phi4))
    return err, scale


# ----------------------------------------------------------------------------- tests
@pytest.mark.parametrize("rotor", [0, 1, 2, 3, 4], ids=["nominal", "A1", "A2", "A3", "A4"])
def test_linearized_outputs_are_chains_of_integrators(rotor):
    """φ⁽⁴⁾ = v (eq. (22)) to rounding on 30 random states, nominal and each rotor attacked."""
    sc = exact_scenario()
    rng = random.Random(1000 + rotor)
    checked = 0
    for _ in range(40):
        res = check_one(sc, rotor, rng)
        if res is None:
            continue
        err, scale = res
        assert err <= 1e-10 * scale, f"|φ⁽⁴⁾ − v| = {err:.3e} (scale {scale:.1f})"
        checked += 1
        if checked == 30:
            break
    assert checked == 30, f"only {checked} of 40 random states left every rotor unsaturated"


def test_a_model_error_breaks_the_identity():
    """The check has teeth: a 0.01 % inertia error in the law's model moves φ⁽⁴⁾ off v by
    ~1e-5 relative, 10⁵ × the tolerance (the law turns ṗ, q̇ into torques through J,
    eq. (3))."""
    sc = apply_overrides(exact_scenario(), ["controller.model_inertia_scale=1.0001"])
    rng = random.Random(7)
    results = [r for r in (check_one(sc, 2, rng) for _ in range(10)) if r is not None]
    assert results
    assert min(err / scale for err, scale in results) > 1e-6


def test_series_integration_matches_finite_differences_of_the_physics():
    """The Taylor coefficients above are the physics' own derivatives.

    y⁽⁴⁾ = d²/dt² ÿ(x(t)). The central difference D(h) = [ÿ(h) − 2ÿ(0) + ÿ(−h)]/h² of the
    acceleration along an RK4 trajectory (u_f(t) integrated exactly) expands as
    D(h) = y⁽⁴⁾ + (h²/12) y⁽⁶⁾ + (h⁴/360) y⁽⁸⁾ + O(h⁶). We subtract the h² term (y⁽⁶⁾ from
    the series) and allow twice the h⁴ term plus 1e-8 m/s⁴ for the rest: rounding in ÿ is
    ~10 ε (u_f/m) per sample (the attitude enters scaled by the thrust), times 4/h², ≈ 1e-9
    at h = 3 ms, and RK4's local error O(h⁵)/h² is below that. So the series' y⁽⁴⁾ (tens
    to hundreds of m/s⁴) must match the physics to ~1e-8 relative, and its y⁽⁶⁾ to ~1e-3.
    """
    sc = exact_scenario()
    p = true_params(sc)
    rng = random.Random(3)
    h = 3e-3
    for _ in range(5):
        state, uf, duf, _ = random_state(rng)
        u_d = rng.uniform(-20.0, 20.0)
        torques = [rng.uniform(-0.05, 0.05) for _ in range(3)]
        x0 = [*state.position_m, *state.velocity_mps, *state.quaternion_wxyz,
              *state.body_rates_radps]
        coeffs = taylor_of_trajectory(p, x0, (uf, duf, 0.5 * u_d), torques, order=8)

        def thrust(t: float, uf=uf, duf=duf, u_d=u_d) -> float:
            return uf + duf * t + 0.5 * u_d * t * t

        def accel(x: Sequence[float], t: float, torques=torques) -> list[float]:
            return derivative(p, x, (thrust(t), *torques))[3:6]

        def rk4(x: list[float], t0: float, dt: float, torques=torques) -> list[float]:
            def f(xx, tt):
                return derivative(p, xx, (thrust(tt), *torques))
            k1 = f(x, t0)
            k2 = f([a + 0.5 * dt * b for a, b in zip(x, k1, strict=True)], t0 + 0.5 * dt)
            k3 = f([a + 0.5 * dt * b for a, b in zip(x, k2, strict=True)], t0 + 0.5 * dt)
            k4 = f([a + dt * b for a, b in zip(x, k3, strict=True)], t0 + dt)
            return [a + dt / 6.0 * (b + 2.0 * c + 2.0 * d + e)
                    for a, b, c, d, e in zip(x, k1, k2, k3, k4, strict=True)]

        a_plus = accel(rk4(x0, 0.0, h), h)
        a_minus = accel(rk4(x0, 0.0, -h), -h)
        a_zero = accel(x0, 0.0)
        for i in range(3):
            fd = (a_plus[i] - 2.0 * a_zero[i] + a_minus[i]) / (h * h)
            y4, y6, y8 = (math.factorial(k) * coeffs[i][k] for k in (4, 6, 8))
            tol = 2.0 * h ** 4 / 360.0 * abs(y8) + 1e-8
            assert abs(fd - y4 - h * h / 12.0 * y6) <= tol, (i, fd, y4, tol)


def test_decoupling_check_fires_as_thrust_vanishes():
    """det D ∝ x13² (eq. (16)): as u_f → 0 the law must refuse to invert D and fall back
    with finite, in-range rotor commands instead of dividing by ~0."""
    sc = exact_scenario()
    state, _, _, a_n = random_state(random.Random(11))
    fmax = sc.vehicle.thrust_max_n
    for rotor in (0, 2):
        for uf in (0.3, 1e-3, 0.0):
            ctrl = build_controller(sc)
            ctrl.x13, ctrl.x14 = uf, 0.0
            if rotor:
                ctrl.set_attack(rotor, a_n)
            out = ctrl.update(state)
            assert out.mode == Mode.FALLBACK, (rotor, uf)
            assert "D(x) singular" in out.reason
            assert all(math.isfinite(f) and 0.0 <= f <= fmax for f in out.rotor_thrust_n)
            assert ctrl.fallback_count == 1
    # Just above the threshold the law still answers.
    ctrl = build_controller(sc)
    ctrl.x13 = 2.0 * ctrl.cfg.min_thrust_n
    assert "singular" not in ctrl.update(state).reason
