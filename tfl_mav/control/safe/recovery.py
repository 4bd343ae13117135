"""A safe reduced-attitude law: a dead rotor, a take-over from an unknown state, a lost path.

Why another law. The TFL attacked law (:mod:`tfl_mav.control.tfl.tfl_controller`) needs τ_p
of both signs from the rotor opposite the attacked one: f4 = A + τ_p/l (canonical frame, see
:mod:`tfl_mav.control.allocation`). With A ≈ 0 (a dead rotor, or the paper's signal
clamped to 0 while 3.2 < z < 6.2) f4 ≥ 0 allows τ_p ≥ 0 only, so the law's τ_p demand is
physically out of reach and the vehicle flips within seconds. This law never asks for τ_p.

The idea is Mueller & D'Andrea's relaxed hover (ICRA 2014, "Stability and control of a
quadrocopter despite the complete loss of one, two, or three propellers"): with f4 = A the
pair 2-4 makes no roll torque, and the yaw torque d(f1 + f3 − 2A) is unbalanced, so the
vehicle spins about b3 at r̄ = d(u_f − 4A)/k_r (≈ 63 rad/s at A = 0 for the paper
vehicle). One does not control its yaw; one controls only the *direction* of the thrust
axis b3 — a two-DoF reduced attitude — and the total thrust. In body axes let
h = Rᵀ n_des (n_des the wanted thrust direction, inertial); b3 = n_des means h = (0, 0, 1).
Linearised about the spin (h3 ≈ 1, r ≈ const):

    ḣ1 = r h2 − q,  ḣ2 = p − r h1,
    I_x ṗ = τ_p − k_r p − (I_z − I_y) q r,  I_y q̇ = τ_q − k_r q − (I_x − I_z) p r.

With r ≠ 0 this 4-state system is controllable from τ_q = l(f3 − f1) alone (the spin carries
the body axes round, so one torque axis reaches both tilt directions). A discrete LQR on
the zero-order-hold model at the control period (so a 250 Hz loop is designed for what it
is; :mod:`lqr`, numpy only) gives the gain; it is recomputed when the measured r moves
by more than 0.5 rad/s (gain scheduling on r). τ_p stays an input with a cost 100× τ_q's:
it is needed only when the spin is slow (right after a take-over), and its one-sided range
is clipped.

With four healthy rotors (a take-over, a lost projection) the same reduced attitude is
flown with a PD on (−h2, h1) through both torques and a yaw-rate damper.

The outer loop is a PID on position towards a target: the closest point of the path with
its velocity (speed × tangent) and centripetal acceleration, or a held point (altitude hold,
velocity zero). Its poles are a triple one at −ω_p: k_p = 3ω_p², k_d = 3ω_p, k_i = ω_p³
(:func:`~tfl_mav.control.safe.safe_step.pid_gains`). With three rotors ω_p is 3 rad/s where
the controller's measurements are clean and the motors prompt, lowered with the motor lag
(ω_p τ_m ≤ 0.1) and as the attack leaves the side rotors less of the weight
(:func:`~tfl_mav.control.safe.safe_step.outer_loop_omega`,
:func:`~tfl_mav.control.safe.safe_step.attack_omega`); 1.25 rad/s with noisy measurements
and with four rotors (under the 10 rad/s attitude loop). The position error a dead rotor
leaves is the acceleration the loop does not feed forward over k_p: 2.8 mm on the paper path
at 1.25 rad/s, 0.08 mm at 3. The integral is what makes the law precise: the steady forces it
does not model (the model's mass error Δm g, drag, the spinning attitude loop's bias) are a
constant acceleration demand, which a PD alone leaves as an offset Δm g/k_p and the integral
removes. It is held as the acceleration it has learnt (k_i ∫e, m/s²), so a pole that moves
leaves it as it is. It learns only what holds the vehicle off its target: within
``INTEGRAL_BAND_M`` of it, or farther once the vehicle has settled (conditional
integration, :func:`~tfl_mav.control.safe.safe_step.accel_demand`). Fed on the approach after
a take-over a metre off the path, it banked a debt the loop paid back as a 0.15 m overshoot,
and the paper's zero-attack stretch was handed back to TFL 40-60 mm off. The integral is
bounded (±``MAX_INTEGRAL_G`` g) and frozen while the demand is limited or the allocation
cannot make it (anti-windup, :func:`~tfl_mav.control.safe.safe_step.integrated`).
The wanted acceleration is limited to a 30° tilt and ±0.5 g vertically — a safe law does not
chase the path hard — and to what the rotors can make: vertically within ± the climb the
most thrust allows (a heavy airframe on two side rotors climbs at 0.1-0.2 g; a dive at
0.5 g it cannot arrest was a crash from half a metre), horizontally within the tilt the
vertical demand leaves.

Thrust requests are feasible by construction: the three-rotor allocation gives up τ_p (the
opposite rotor within [0, f_max]) before τ_q, and τ_q before u_f, so what the law asks for
is what the rotors can do (``RecoveryOutput.clamped`` says where it had to give up).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any, NamedTuple

import numpy as np

from tfl_mav.accel import native
from tfl_mav.control.allocation import RotorFrame, canonical_frame
from tfl_mav.control.path.compiled import PathKernels, compile_path
from tfl_mav.control.path.jetcode import TraceError
from tfl_mav.control.path.jets import Jet
from tfl_mav.control.path.paths import Path
from tfl_mav.control.safe import safe_step
from tfl_mav.control.safe.lqr import dlqr, dlqr_zoh_many, zoh
from tfl_mav.control.safe.safe_step import (
    MAX_INTEGRAL_G,
    MAX_TILT_RAD,
    MAX_VERTICAL_G,
    POS_OMEGA,
    SafeParams,
    SafeState,
)
from tfl_mav.model.state import State

__all__ = ["MAX_INTEGRAL_G", "MAX_TILT_RAD", "MAX_VERTICAL_G", "POS_OMEGA", "PathProjector",
           "RecoveryLaw", "RecoveryOutput", "forget_gain_schedules", "gain_schedule",
           "projector_sigma2", "reference_sigma2", "spin_model"]

# LQR weights on (h1, h2, p, q) and (τ_p, τ_q): Bryson's rule with 0.1 of h (≈ 6°),
# 10 rad/s of p, q and 0.2 N m of τ_q; τ_p costs 100× (one-sided, only for a slow spin).
# With motor lag the τ_q weight grows (:func:`lqr_r`).
_new_output = tuple.__new__     # a named tuple made without its Python __new__ frame
LQR_MAX_SPIN_RADPS = 150.0   # gain schedule range (see RecoveryLaw.spin_gains)
LQR_Q = (100.0, 100.0, 0.01, 0.01)
LQR_R = (2500.0, 25.0)
SPIN_SWING_HZ = 10.0         # the rate τ_q must swing at: the ~60 rad/s spin of a dead rotor


def lqr_r(motor_time_constant_s: float) -> tuple[float, float]:
    """The input weights for rotors of time constant τ_m (s): LQR_R × (1 + (2π f τ_m)²).

    τ_q is fixed in the body, which spins at ~60 rad/s, so the rotors must swing it at
    f ≈ 10 Hz; a first-order lag cuts that swing by √(1 + (2π f τ_m)²) (3.3× at 50 ms). The
    weight grows by the square, so the law asks for no more swing than a lagging rotor
    makes: with the weight of ideal rotors it asks for what a 30 ms rotor cannot do and the
    vehicle falls; with this one it flies 0-50 ms."""
    tau = motor_time_constant_s if motor_time_constant_s > 0.0 else 0.0
    scale = 1.0 + (2.0 * math.pi * SPIN_SWING_HZ * tau) ** 2
    return LQR_R[0] * scale, LQR_R[1] * scale


Sigma2 = Callable[[tuple[float]], Sequence[float]]
Gains = tuple[tuple[float, float, float, float], tuple[float, float, float, float]]  # K, 2×4
GainKey = tuple[int, bool]     # (spin rate in 0.5 rad/s steps, I_x' > I_y')
_SCHEDULES: dict[tuple[float, ...], dict[GainKey, Gains]] = {}   # whole schedules, by model
_PARTIAL: dict[tuple[float, ...], dict[GainKey, Gains]] = {}     # blocks met so far, by model
GAIN_BLOCK = 32    # spin-rate steps (16 rad/s) designed together when first met (lazy law)


def spin_model(rr: float, ix: float, iy: float, iz: float,
               kr: float) -> tuple[np.ndarray, np.ndarray]:
    """(A, B) of the reduced attitude (h1, h2, p, q) linearised about the spin ``rr``
    (rad/s), inputs (τ_p, τ_q) (N m); inertias (kg m²) and the rotational drag ``kr``."""
    a = np.array([[0.0, rr, 0.0, -1.0],
                  [-rr, 0.0, 1.0, 0.0],
                  [0.0, 0.0, -kr / ix, -(iz - iy) * rr / ix],
                  [0.0, 0.0, -(ix - iz) * rr / iy, -kr / iy]])
    b = np.array([[0.0, 0.0], [0.0, 0.0], [1.0 / ix, 0.0], [0.0, 1.0 / iy]])
    return a, b


def gain_schedule(inertia_kgm2: Sequence[float], k_r: float, dt_s: float,
                  motor_time_constant_s: float = 0.0) -> dict[GainKey, Gains]:
    """Every gain :meth:`RecoveryLaw.spin_gains` can ask for (|r| ≤ LQR_MAX_SPIN_RADPS, either
    canonical inertia order), designed at once by :func:`lqr.dlqr_zoh_many` — the same
    gains bit for bit as one at a time, ~0.1 ms apiece instead of ~1 ms, so a flight never
    designs one mid-air (an overrun at 1 kHz). Cached by model within a process (the daemon
    builds a warm-up flight computer and then the real one; a sweep builds thousands)."""
    ix, iy, iz = (float(x) for x in inertia_kgm2)
    r_w = lqr_r(motor_time_constant_s)
    cache_key = (ix, iy, iz, float(k_r), float(dt_s), *r_w)
    sched = _SCHEDULES.get(cache_key)
    if sched is not None:
        return sched
    top = round(LQR_MAX_SPIN_RADPS * 2.0)
    sched = {}
    for ixc, iyc in dict.fromkeys(((ix, iy), (iy, ix))):
        sched.update(_design_steps(ixc, iyc, iz, float(k_r), float(dt_s), -top, top + 1,
                                   r_w))
    _SCHEDULES[cache_key] = sched
    _PARTIAL[cache_key] = dict(sched)
    return sched


def forget_gain_schedules() -> None:
    """Drop the gains this process designed (they are kept by model: a sweep over many
    airframes would keep every one); the next law of a model designs them afresh."""
    _SCHEDULES.clear()
    _PARTIAL.clear()


def _design_steps(ixc: float, iyc: float, iz: float, k_r: float, dt_s: float, lo: int,
                  hi: int, r_weights: tuple[float, float] = LQR_R) -> dict[GainKey, Gains]:
    """The gains of spin-rate steps lo … hi−1 (0.5 rad/s each) in one inertia order, by
    stacked calls (:func:`lqr.dlqr_zoh_many`: item by item the same operations, so the same
    gains bit for bit whatever else is in the stack); a step whose design fails is left out
    (:meth:`RecoveryLaw.spin_gains` then designs it alone and reports the failure)."""
    steps = np.arange(lo, hi)
    # spin_model for every step at once (the same IEEE operations, element-wise).
    rr = steps / 2.0
    a = np.zeros((len(steps), 4, 4))
    a[:, 0, 1], a[:, 0, 3] = rr, -1.0
    a[:, 1, 0], a[:, 1, 2] = -rr, 1.0
    a[:, 2, 2], a[:, 2, 3] = -k_r / ixc, -(iz - iyc) * rr / ixc
    a[:, 3, 2], a[:, 3, 3] = -(ixc - iz) * rr / iyc, -k_r / iyc
    b = np.repeat(spin_model(0.0, ixc, iyc, iz, k_r)[1][None], len(steps), 0)
    gains = dlqr_zoh_many(a, b, np.diag(LQR_Q), np.diag(r_weights), dt_s)
    order = ixc > iyc
    return {(k, order): (tuple(g[0].tolist()), tuple(g[1].tolist()))
            for k, g in zip(steps.tolist(), gains, strict=True) if g is not None}


def reference_sigma2(path: Path) -> Sigma2:
    """σ's Taylor coefficients (σ, σ', σ''/2, j-major) at λ by the reference jets: the
    generic evaluation the compiled ``sigma2`` kernel (:mod:`compiled`) is tested against."""
    def sigma2(lam: tuple[float]) -> tuple[float, ...]:
        comps = [v.c if isinstance(v, Jet) else (float(v), 0.0, 0.0)
                 for v in path.sigma(Jet.variable(lam[0], order=2))]
        return tuple(comps[i][j] for j in range(3) for i in range(3))

    return sigma2


def projector_sigma2(path: Path, kernels: PathKernels | None = None,
                     compiled_path: bool = True) -> tuple[Sigma2, str]:
    """The σ evaluation the projector uses and a note: the compiled kernel (``kernels``, or
    traced now) when the path's code traces, else the reference jets (the note says why)."""
    if not compiled_path:
        return reference_sigma2(path), "reference jets"
    try:
        return (kernels if kernels is not None else compile_path(path)).sigma2.fn, "compiled"
    except TraceError as exc:
        return reference_sigma2(path), f"reference jets ({exc})"


def _floats(x: Sequence[float]) -> Sequence[float]:
    """``x`` with Python floats (``tolist`` of a numpy array; other sequences as they are)."""
    return x.tolist() if type(x) is np.ndarray else x


class PathProjector:
    """Closest point of a path, kept between calls (Newton on ⟨y − σ(λ), σ'(λ)⟩ = 0:
    :func:`~tfl_mav.control.safe.safe_step.closest_point` linked to this path's σ kernel).

    σ, σ' and σ'' come exactly from one ``sigma2`` evaluation a step — the compiled kernel
    the TFL tracker uses, or the reference jets (:func:`projector_sigma2`): a warm-started
    tick costs two or three evaluations of a few dozen float operations. (Central
    differences of σ, as the projector once did, needed three σ calls a step and carried ~1e-7 of
    rounding noise in σ'' with a 1e-4 step.)
    """

    def __init__(self, path: Path, sigma2: Sigma2 | None = None,
                 evaluation: str = "given", *, source: str | None = None) -> None:
        """``source``: the generated source of ``sigma2`` (a compiled path kernel's): then
        the accelerator seam compiles the projection with it inlined — the same bits; the
        Python evaluates until it is built, and wherever the C declines."""
        self.path = path
        if sigma2 is None:
            sigma2, evaluation = projector_sigma2(path)
        self.evaluation = evaluation        # "compiled" | "reference jets (why)" | "given"
        self.sigma2 = sigma2                        # what the safe law's step is given
        self.lowerable = source is not None         # the seam can compile them
        self._closest_c: Callable[..., Any] | None = None
        self.lam: float | None = None
        if self.lowerable:
            def ready(core: Callable[..., Any]) -> None:
                self._closest_c = core

            core = native.obtain_function(safe_step.closest_point,
                                         (sigma2, 0.0, (0.0, 0.0, 0.0)), ready)
            if core is not None:
                ready(core)

    def start(self, y: Sequence[float]) -> None:
        """λ from a global search: the nearest of 2001 points along the path."""
        yx, yy, yz = y
        lo, hi = self.path.lam_range
        lam_grid = np.linspace(lo, hi, 2001)
        x, sy, z = self.path.sigma(lam_grid)
        d2 = (x - yx) ** 2 + (sy - yy) ** 2 + (z - yz) ** 2
        self.lam = float(lam_grid[int(np.argmin(d2))])

    def forget(self) -> None:
        """Drop λ: the next projection starts with a global search (the vehicle may be
        anywhere: after a held point, or a stretch off the path)."""
        self.lam = None

    def project(self, y: Sequence[float]) -> tuple[tuple[float, float, float],
                                                   tuple[float, float, float],
                                                   tuple[float, float, float],
                                                   float] | None:
        """(point, unit tangent, curvature vector κN, distance) or None if not found."""
        if self.lam is None:
            self.start(y)
        fast = self._closest_c
        out = fast(self.sigma2, self.lam, y) if fast is not None else None
        if out is None:
            yx, yy, yz = y
            out = safe_step.closest_point(self.sigma2, self.lam, (yx, yy, yz))
        found, self.lam, point, tangent, curvature, dist = out
        return (point, tangent, curvature, dist) if found else None


class RecoveryOutput(NamedTuple):
    """One decision of the recovery law (physical rotor order, N; a named tuple: one is
    made every safe-law tick)."""

    requested_n: list[float]     # what the law asks for: within [0, f_max] by construction
    thrust_n: list[float]        # the same thrusts (the attacked rotor: its estimate)
    tilt_error_rad: float        # angle between b3 and the wanted thrust direction
    path_distance_m: float       # NaN when holding a point without a path
    uf_n: float
    clamped: tuple[bool, bool, bool, bool]   # a rotor's unconstrained demand left [0, f_max]


class RecoveryLaw:
    """Reduced-attitude + position law for 4, or 3 (one at A, opposite held at A) rotors."""

    def __init__(self, mass_kg: float, inertia_kgm2: Sequence[float], arm_m: float,
                 drag_thrust_ratio_m: float, k_t: float, k_r: float, thrust_max_n: float,
                 gravity_mps2: float, dt_s: float, path: Path | None,
                 speed_mps: float, *, kernels: PathKernels | None = None,
                 compiled_path: bool = True, design_gains: bool = True,
                 motor_time_constant_s: float = 0.0,
                 noisy_measurements: bool = False, thrust_known: bool = True) -> None:
        self.mass_kg = mass_kg
        self.inertia = tuple(inertia_kgm2)
        self.arm_m = arm_m
        self.d_m = drag_thrust_ratio_m
        self.k_t = k_t
        self.k_r = k_r
        self.fmax = thrust_max_n
        self.g = gravity_mps2
        self.dt = dt_s
        self.speed = speed_mps
        # The path's compiled σ kernel (the TFL tracker's ``kernels`` when given: traced once).
        self.projector = None
        if path is not None:
            sig, note = projector_sigma2(path, kernels, compiled_path)
            source = kernels.sigma2.source if kernels is not None and note == "compiled" \
                else None
            self.projector = PathProjector(path, sig, note, source=source)
        self.hold_m: list[float] | None = None    # held point (None: follow the path)
        # The LQR gains: the whole schedule designed now (``design_gains``: a real-time
        # flight never designs mid-air), or a block of GAIN_BLOCK steps when a spin rate of
        # it is first met (offline: a flight meets a few blocks, ~3 ms each, not the 38 of
        # the schedule); the same gains either way, shared by every law of this model.
        ix, iy, iz = (float(x) for x in inertia_kgm2)
        self._r_weights = lqr_r(motor_time_constant_s)
        self._model_key = (ix, iy, iz, float(k_r), float(dt_s), *self._r_weights)
        self._gains: dict[GainKey, Gains] = (
            dict(gain_schedule(inertia_kgm2, k_r, dt_s, motor_time_constant_s)) if design_gains
            else _PARTIAL.setdefault(self._model_key, {}))
        self._frames: dict[int, RotorFrame] = {}
        self._inverse_perm: dict[int, tuple[int, int, int, int]] = {}
        self._rot6: dict[int, tuple[int, ...]] = {}       # the canonical rotation's rows 1-2
        self._step_model = (mass_kg, k_t, gravity_mps2, arm_m, thrust_max_n)
        # k_i ∫ position error (m/s², inertial): the integral action's state. It carries over
        # between take-overs of one flight: the steady force it has learnt (the model's mass
        # error) is the same force the next time.
        self.integral_mps2 = [0.0, 0.0, 0.0]
        # v − v_target low-passed and the filter's age (accel_demand's settled test); each
        # start begins it again: a law that starts has not settled.
        self.drift_mps: tuple[float, float, float] = (0.0, 0.0, 0.0)
        self.drift_age_s = 0.0
        self.attack_lp_n = 0.0      # the attack low-passed (safe_step.attack_omega's)
        omega_p = safe_step.outer_loop_omega(motor_time_constant_s, noisy_measurements)
        # The attacked tick: safe_step's pure step, on this path's σ, compiled by the seam
        # where it is built (the projection's kernel must be generated code to be inlined).
        self._safe = SafeParams(self._step_model, speed_mps, dt_s, omega_p,
                                self.projector is not None, thrust_known,
                                (*self.inertia, float(k_r), float(drag_thrust_ratio_m)))
        self._sigma2 = self.projector.sigma2 if self.projector is not None \
            else safe_step.no_path
        self._tick_c: Callable[..., Any] | None = None
        if self.projector is None or self.projector.lowerable:
            def ready(core: Callable[..., Any]) -> None:
                self._tick_c = core

            core = native.obtain_function(safe_step.safe_tick,
                                          (self._safe, _STATE0, _INPUTS0, self._sigma2), ready)
            if core is not None:
                ready(core)

    # ------------------------------------------------------------------ targets
    def hold(self, position_m: Sequence[float]) -> None:
        """Hold this point (altitude hold, velocity zero) instead of the path."""
        self.hold_m = [float(c) for c in position_m]
        self.drift_age_s = 0.0

    def follow_path(self, lam: float | None = None, *, search: bool = False) -> None:
        """Fly the path (no held point). ``lam``: start the closest-point search at this
        path parameter (the law that flew until now: its λ is the vehicle's); ``search``: a
        fresh global search instead (the vehicle may be anywhere after a held point). Left
        alone, λ is the one this law last flew with — seconds ago, perhaps another bend."""
        self.hold_m = None
        self.drift_age_s = 0.0
        if self.projector is not None:
            if search:
                self.projector.forget()
            elif lam is not None and math.isfinite(lam):
                self.projector.lam = float(lam)

    @property
    def core(self) -> str:
        """What flies the attacked tick's arithmetic: ``compiled`` (the seam's build of
        :func:`safe_step.safe_tick`) or ``python`` (the step itself)."""
        return "compiled" if self._tick_c is not None else "python"

    @property
    def holding(self) -> bool:
        """Whether the law holds a point (told to, or the path lost) rather than the path."""
        return self.hold_m is not None

    @property
    def path_lam(self) -> float | None:
        """λ of the path point this law last flew to (None: no path, or none found yet)."""
        return self.projector.lam if self.projector is not None else None

    def closest_path_point(self, y: Sequence[float]) -> tuple[tuple[float, float, float],
                                                              tuple[float, float, float],
                                                              tuple[float, float, float],
                                                              float] | None:
        """The path point closest to ``y`` (m), warm-started from this law's λ and kept as
        its λ — another law flying the path this law would fly back to (the spin law):
        (point, unit tangent, curvature vector κN, distance m), None without a path or a
        closest point."""
        return self.projector.project(y) if self.projector is not None else None

    def distance_to_path(self, y: Sequence[float]) -> float:
        """The distance (m) from ``y`` to the path (from this law's λ; a global search when
        it has none, as before it first flies), NaN without a path or a closest point; λ is
        dropped after it (the law, if it flies, searches afresh)."""
        proj = self.projector
        if proj is None:
            return math.nan
        found = proj.project(y)
        proj.forget()
        return found[3] if found is not None else math.nan

    # ------------------------------------------------------------------ gains
    def spin_gains(self, r: float, ix: float, iy: float) -> Gains:
        """The LQR gain K (2×4: (τ_p, τ_q) from (h1, h2, p, q)) the attacked tick flies at
        the spin rate ``r`` (rad/s, about b3) with the canonical frame's inertias ``ix``,
        ``iy`` (kg m²): the schedule's step nearest ``r`` (0.5 rad/s steps, clamped to
        ±LQR_MAX_SPIN_RADPS), its block designed now if this model has not met it yet."""
        # Gains are scheduled on the spin rate in 0.5 rad/s steps; beyond ±LQR_MAX_SPIN the
        # airframe has long come apart (the simulator ends a run at 300 rad/s), so a measured
        # rate out there (a glitch, a fuzzed message) uses the edge's gains: bounded cache,
        # and no overflow in expm.
        r = min(max(r, -LQR_MAX_SPIN_RADPS), LQR_MAX_SPIN_RADPS) if math.isfinite(r) else 0.0
        key = (round(r * 2.0), ix > iy)
        k = self._gains.get(key)
        if k is not None:
            return k
        top = round(LQR_MAX_SPIN_RADPS * 2.0)
        lo = key[0] // GAIN_BLOCK * GAIN_BLOCK
        self._gains.update(_design_steps(ix, iy, self.inertia[2], self.k_r, self.dt,
                                         max(lo, -top), min(lo + GAIN_BLOCK, top + 1),
                                         self._r_weights))
        k = self._gains.get(key)
        if k is not None:
            return k
        a, b = spin_model(key[0] / 2.0, ix, iy, self.inertia[2], self.k_r)
        ad, bd = zoh(a, b, self.dt)
        k = dlqr(ad, bd, np.diag(LQR_Q), np.diag(self._r_weights))
        gains = self._gains[key] = (tuple(k[0].tolist()), tuple(k[1].tolist()))
        return gains

    # ------------------------------------------------------------------ the law
    def update(self, s: State, attacked_rotor: int = 0, attack_n: float = 0.0, *,
               mass_kg: float | None = None) -> RecoveryOutput:
        """Rotor thrusts for this period; ``attacked_rotor`` 0 = four healthy rotors.
        ``mass_kg``: the vehicle's mass as estimated now (the TFL side's estimator, which
        learns whichever law flies); the model's otherwise. The integral then has only the
        rest to learn — and it cannot learn where the allocation gives up (frozen: at the
        paper path's top bend a dead rotor's spin slows with the thrust and it does), so
        a 5 % mass error left a 0.1 m offset there (Δm g / k_p).

        R(q) is written out as the nine entries :func:`~tfl_mav.model.geometry.rotation_rows`
        computes."""
        if mass_kg is not None and mass_kg != self.mass_kg and mass_kg > 0.0:
            self.mass_kg = mass_kg
            m = self._step_model = (mass_kg, *self._step_model[1:])
            sp = self._safe      # SafeParams with the new model, built as the tuple it is
            self._safe = _new_output(SafeParams, (m, *sp[1:]))
        if attacked_rotor:
            return self._three_rotor(s, attacked_rotor, attack_n)
        out = safe_step.healthy_tick(self._safe, self._state(s), (
            _floats(s.position_m), _floats(s.velocity_mps), _floats(s.quaternion_wxyz),
            _floats(s.body_rates_radps)), self._sigma2)
        return self._keep(out)

    def _state(self, s: State) -> SafeState:
        """The pure step's state from this law's (λ from a global search the first time)."""
        proj, hold = self.projector, self.hold_m
        if proj is not None and hold is None and proj.lam is None:
            proj.start(_floats(s.position_m))
        return _new_output(SafeState, (
            proj.lam if proj is not None and proj.lam is not None else 0.0,
            hold is not None, _ZERO3 if hold is None else hold,
            self.integral_mps2, self.drift_mps, self.drift_age_s, self.attack_lp_n))

    def _keep(self, out: tuple[Any, ...]) -> RecoveryOutput:
        """Keep the pure step's new state as this law's; its output as a RecoveryOutput."""
        (lam, holding, hold_m, integral, self.drift_mps, self.drift_age_s,
         self.attack_lp_n), \
            (f, tilt_err, dist, uf, clamped) = out
        proj = self.projector
        if proj is not None and self.hold_m is None:
            proj.lam = lam
        if holding and self.hold_m is None:
            self.hold_m = list(hold_m)
        self.integral_mps2 = list(integral)
        f = list(f)
        return _new_output(RecoveryOutput, (f, list(f), tilt_err, dist, uf, tuple(clamped)))

    def _three_rotor(self, s: State, attacked_rotor: int, attack_n: float) -> RecoveryOutput:
        """The three-rotor tick: the LQR gain for the canonical spin rate, then the pure
        :func:`~tfl_mav.control.safe.safe_step.safe_tick` (compiled where it is built) from the
        law's state, written back."""
        fr = self._frames.get(attacked_rotor)
        if fr is None:
            fr = self._frames[attacked_rotor] = canonical_frame(attacked_rotor)
            # canonical rotor i is physical fr.perm[i]: physical j is canonical inv[j]
            self._inverse_perm[attacked_rotor] = tuple(fr.perm.index(j) for j in range(4))
            self._rot6[attacked_rotor] = (*fr.rot[0], *fr.rot[1])
        r20, r21, r22 = fr.rot[2]
        rates = p, q, r = _floats(s.body_rates_radps)
        ix, iy = self.inertia[0], self.inertia[1]
        ixc, iyc = (iy, ix) if fr.swap_xy else (ix, iy)
        gains = self.spin_gains(0 + r20 * p + r21 * q + r22 * r, ixc, iyc)
        state = self._state(s)
        core = self._tick_c
        out = core(self._safe, state, (s.position_m, s.velocity_mps, s.quaternion_wxyz,
                                       rates, attack_n, self._rot6[attacked_rotor],
                                       self._inverse_perm[attacked_rotor], gains),
                   self._sigma2) if core is not None else None
        if out is None:       # the C bails where Python raises: raise here
            out = safe_step.safe_tick(self._safe, state, (
                _floats(s.position_m), _floats(s.velocity_mps), _floats(s.quaternion_wxyz),
                rates, attack_n, self._rot6[attacked_rotor], self._inverse_perm[attacked_rotor],
                gains), self._sigma2)
        return self._keep(out)


_ZERO3 = (0.0, 0.0, 0.0)
# safe_tick's arguments' shapes, for the seam's lowering.
_STATE0 = (0.0, False, _ZERO3, _ZERO3, _ZERO3, 0.0, 0.0)
_INPUTS0 = (_ZERO3, _ZERO3, (1.0, 0.0, 0.0, 0.0), _ZERO3, 0.0, (0,) * 6, (0,) * 4,
            ((0.0,) * 4, (0.0,) * 4))
