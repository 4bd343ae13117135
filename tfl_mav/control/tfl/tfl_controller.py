"""The transverse-feedback-linearizing path-following law (paper §V), nominal and attacked.

Structure used (docs/design.md, "The law"). With y the position and the dynamic extension
x13 = u_f, x14 = u̇_f (eq. (9)), the fourth derivative of the position is affine in the
*virtual inputs* w = (ü_f, ṗ, q̇):

    y⁽⁴⁾ = a₀(x) + B₀(x) w,   B₀ = [b3/m, −(u_f/m) b2, (u_f/m) b1]      (bᵢ = R eᵢ)

so for the virtual output φ(y) = (α1, α2, π) (eq. (14)), φ⁽⁴⁾ = L_f⁴φ + Dφ(y) B₀ w, where
L_f⁴φ is φ⁽⁴⁾ evaluated with y⁽⁴⁾ = a₀ (computed with Taylor jets by the path library) and Dφ
is φ's Jacobian. The paper's decoupling matrix (eq. (15)) is D = Dφ B₀ T with T the constant
map from (u_d, u_r, u_q) to w; solving eq. (21) for w first and then for the rotor commands
keeps one formula for both laws:

* attacked (rotor 2 in the canonical frame, see ``allocation``): τ_q from q̇, τ_r from ṗ via
  eq. (6) (τ_p = (u_f − τ_r/d) l/2 − 2lA), f2 = A (the *estimated* attack thrust); yaw is
  internal dynamics (μ1 = ψ, eq. (18)) — no Euler angle is used at all, so the law has no
  trouble with a vehicle spinning at tens of rad/s;
* nominal: τ_p, τ_q from ṗ, q̇, and τ_r from a second-order yaw loop (ψ held).

The ξ and η loops are eqs. (23) and (24) with repeated poles. The robust variant adds the
estimators of :mod:`estimators` and a one-time switch to faster poles once the vehicle has
settled on the path.

The tick is :func:`step.tfl_step`, explicit state and one pure step; :class:`TFLController`
holds its state, turns its codes into words and runs the motor-lag inverse around it. On the
compiled path tracker the step flies whole — compiled by the accelerator seam where it is
built, else as Python; on the reference jets (``compiled_path=False``, a path whose code
cannot be traced) the tracker's own virtual output stands in for :func:`step.project`.
"""

from __future__ import annotations

import math
import weakref
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from tfl_mav.accel import native
from tfl_mav.control.actuators import MotorLagInverter
from tfl_mav.control.allocation import RotorFrame, canonical_frame
from tfl_mav.control.path.compiled import CompiledPathTracker, make_tracker
from tfl_mav.control.path.paths import Path
from tfl_mav.control.path.projection import (
    PATH_START,
    VO,
    Kernels,
    PathState,
    Projected,
    lost_reason,
)
from tfl_mav.control.path.tracker import PathTracker
from tfl_mav.control.tfl import step
from tfl_mav.control.tfl.estimators import (
    DOB_START,
    TDOB_START,
    MassModel,
    MassState,
    mass_model,
    mass_start,
    mass_update,
)
from tfl_mav.control.tfl.law_types import ControlOutput, LawConfig, ModelParams, chain_gains
from tfl_mav.control.tfl.step import Fallback, Frame, TFLInputs, TFLParams, TFLState, settle
from tfl_mav.model.modes import Mode
from tfl_mav.model.state import State

__all__ = ["ControlOutput", "LawConfig", "ModelParams", "TFLController", "chain_gains"]

_NOMINAL, _ATTACKED, _FALLBACK = Mode.NOMINAL, Mode.ATTACKED, Mode.FALLBACK  # enum lookups
_new_output = tuple.__new__   # ControlOutput from its fields in order, no keyword parsing
_new_tuple = tuple.__new__
_ndarray = np.ndarray
_PATH_ERRORS = (ValueError, ZeroDivisionError, OverflowError)
# Why the law fell back, by code (str.format fields: uf, cond), but for Fallback.TUBE, whose
# words are the lost projection's (lost_reason). A table read once rather than a chain of
# ``reason == Fallback.X``: on Python 3.11 each is a class attribute read through
# ``EnumType.__getattr__``, 0.1 µs.
_FALLBACK_WORDS: dict[Fallback, str] = {
    Fallback.THRUST: "total thrust {uf:.2f} N too small: D(x) singular",
    Fallback.COND: "decoupling matrix ill-conditioned (cond {cond:.1e})",
    Fallback.NONFINITE: "non-finite control (numerical failure)",
}
# The translational observer's bound per axis (m/s²): three times the rotor drag of an 8 m/s
# wind (0.33 m/s² per m/s), far below what a sensor glitch differentiated would read.
TDOB_LIMIT_MPS2 = 8.0


def _floats(x: Sequence[float]) -> Sequence[float]:
    """``x`` with Python floats (``tolist`` of a numpy array; other sequences as they are)."""
    return x.tolist() if type(x) is _ndarray else x


def law_params(model: ModelParams, cfg: LawConfig, dt_s: float,
               tube_min: float) -> TFLParams:
    """The step's constants for ``model`` and ``cfg`` at a control period of ``dt_s``."""
    g = float(model.gravity_mps2)
    return TFLParams(
        float(dt_s), g, float(model.k_t), float(model.k_r), float(model.arm_m),
        float(model.thrust_max_n), float(model.inertia_kgm2[2]), float(cfg.speed_mps),
        float(cfg.min_thrust_n), float(cfg.max_cond), float(tube_min),
        float(cfg.settle_alpha), float(cfg.settle_time_s),
        bool(cfg.robust and cfg.mass_estimator), bool(cfg.robust and cfg.disturbance_observer),
        bool(cfg.robust and cfg.gain_switch),
        mass_model(float(model.mass_kg), g, float(model.k_t)),
        float(cfg.observer_tau_s), 500.0,
        bool(cfg.robust and cfg.translational_observer),
        float(cfg.translational_observer_tau_s), TDOB_LIMIT_MPS2,
        bool(cfg.translational_observer_vertical),
        chain_gains(cfg.xi_pole, 4), chain_gains(cfg.eta_pole, 3),  # type: ignore[arg-type]
        chain_gains(cfg.xi_pole_fine, 4), chain_gains(cfg.eta_pole_fine, 3),  # type: ignore[arg-type]
        chain_gains(cfg.yaw_pole, 2))  # type: ignore[arg-type]


def frame_numbers(model: ModelParams, frame: RotorFrame | None) -> Frame:
    """The step's view of the canonical frame for ``frame`` (None: the body axes).

    ``rot`` is a signed permutation, so b1' = ±b_m and p' = ±Ω_m: kept as (m, sign) pairs,
    which gives R' = R rotᵀ and Ω' = rot Ω exactly, without 3×3 products."""
    ix, iy, iz = (float(x) for x in model.inertia_kgm2)
    if frame is None:
        axes = ((0, 1.0), (1, 1.0))
        ixyz, d = (ix, iy, iz), float(model.drag_thrust_ratio_m)
        perm: tuple[int, ...] = (0, 1, 2, 3)
    else:
        picked = []
        for row in frame.rot[:2]:
            k = next(i for i, v in enumerate(row) if v)
            picked.append((k, float(row[k])))
        axes = (picked[0], picked[1])
        ixyz = (iy, ix, iz) if frame.swap_xy else (ix, iy, iz)
        d = model.drag_thrust_ratio_m * frame.d_sign
        perm = frame.perm
    (m1, s1), (m2, s2) = axes
    inv = tuple(perm.index(j) for j in range(4))
    return Frame(frame is not None, m1, s1, m2, s2, ixyz, d,
                 tuple(perm), inv,  # type: ignore[arg-type]
                 2 * model.inertia_kgm2[0] * d)


def initial_state(model: ModelParams) -> TFLState:
    """The law before its first tick: u_f at the model's hover thrust, nothing learnt."""
    hover = model.mass_kg * model.gravity_mps2
    return TFLState(hover, 0.0, mass_start(float(model.mass_kg)), DOB_START, TDOB_START, False,
                    (0.0, 0.0), (hover / 4.0,) * 4, False, 0.0, False, 0.0, PATH_START)


_NESTED = {TFLState._fields.index(name): kind for name, kind in (
    ("mass", step.MassState), ("dob", step.DobState), ("tdob", step.TdobState),
    ("path", PathState))}
_MASS = TFLState._fields.index("mass")     # track's new state built without _replace


def as_state(s: Any) -> TFLState:
    """A state the compiled step returned (plain nested tuples) as the NamedTuples."""
    if type(s) is TFLState:
        return s
    return TFLState(*(_NESTED[i](*x) if i in _NESTED else x for i, x in enumerate(s)))


def mass_observe(m: MassModel, s: MassState, dt_s: float, q: Sequence[float],
                 v: Sequence[float], thrust_n: float) -> MassState:
    """The mass estimator fed a tick another law flew (:meth:`TFLController.track`): b3,
    R's last column, from the attitude ``q`` (w, x, y, z) by the operations
    law_math.rotation computes it with, then :func:`mass_update` with the velocity ``v``
    (m/s) and the total thrust applied over the last period (N). Pure: the seam compiles
    it."""
    w, x, y, z = q
    n = math.sqrt(w * w + x * x + y * y + z * z)
    w, x, y, z = w / n, x / n, y / n, z / n
    b3 = (2 * (x * z + w * y), 2 * (y * z - w * x), 1 - 2 * (x * x + y * y))
    return mass_update(m, s, dt_s, v, thrust_n, b3)


class TFLController:
    """The TFL path-following law with a dynamic extension on the total thrust.

    Call :meth:`update` once per control period with the measured state; call
    :meth:`set_attack` when (and whenever) the attacked rotor and its thrust estimate are
    known. Outputs never contain NaN: any numerical failure falls back to a safe command
    (rates damped, thrust held) and says why.
    """

    def __init__(self, model: ModelParams, path: Path, cfg: LawConfig, dt_s: float, *,
                 compiled_path: bool = True, rpm_noise_std: float = 0.0) -> None:
        """``rpm_noise_std``: the ESC noise (rpm) the motor-lag inverse filters (with lag)."""
        self.model = model
        self._dt = dt_s
        self.tracker: PathTracker
        self.tracker, self.path_eval = make_tracker(path, compiled_path)
        self.cfg = cfg              # and the step's constants (``params``) with it
        self.state: Any = initial_state(model)
        self.attacked_rotor = 0
        self.attack_estimate_n = 0.0
        self.frame: RotorFrame | None = None
        self._frame = frame_numbers(model, None)
        self.saturation_count = 0
        self.fallback_count = 0
        self.lag_clamped_count = 0
        self.ticks = 0
        self.lag_inverter = (MotorLagInverter(model.k_f, model.thrust_max_n,
                                              model.motor_time_constant_s, dt_s)
                             if model.motor_time_constant_s > 0.0 else None)
        if self.lag_inverter is not None and rpm_noise_std > 0.0:
            self.lag_inverter.set_rpm_noise(rpm_noise_std)
        fmax = float(model.thrust_max_n)
        self._free = ((0.0, 0.0, 0.0, 0.0), (fmax, fmax, fmax, fmax))
        # The words of what last lost the path: the path's evaluation error (VO.FAILED's),
        # the reference tracker's reason (VO.REFERENCE's).
        self._failure = ""
        # The step on this path's kernels; compiled by the seam where it is built.
        self._linked_for: PathTracker | None = None     # the tracker the kernels are of
        self._kernels: Kernels | None = None
        self._step: Callable[..., Any] = step.tfl_step
        self._core: Callable[..., Any] | None = None
        self._track_core: Callable[..., Any] | None = None
        self._obtain_track_core()
        if type(self.tracker) is CompiledPathTracker:
            self._kernels = self.tracker.projection_kernels
            self._linked_for = self.tracker
            self._obtain_core()

    def _obtain_core(self) -> None:
        use_core = weakref.WeakMethod(self._use_core)    # a finished law is not kept

        def ready(core: Callable[..., Any]) -> None:
            use = use_core()
            if use is not None:
                use(core)

        example = (self.params, self.state, self._inputs((0.0,) * 3, (0.0,) * 3,
                                                         (1.0, 0.0, 0.0, 0.0), (0.0,) * 3,
                                                         *self._free, 0.0, False, False),
                   self._kernels)
        core = native.obtain_function(self._step, example, ready)
        if core is not None:
            ready(core)

    def _obtain_track_core(self) -> None:
        """:func:`mass_observe` compiled by the seam, for :meth:`track`."""
        use_track_core = weakref.WeakMethod(self._use_track_core)   # a finished law: not kept

        def ready(core: Callable[..., Any]) -> None:
            use = use_track_core()
            if use is not None:
                use(core)

        st = as_state(self.state)
        example = (self.params.mass, st.mass, 0.001, (1.0, 0.0, 0.0, 0.0), (0.0,) * 3, 1.0)
        core = native.obtain_function(mass_observe, example, ready)
        if core is not None:
            ready(core)

    def _use_core(self, core: Callable[..., Any]) -> None:
        self._core = core           # one reference store: atomic under the GIL

    def _use_track_core(self, core: Callable[..., Any]) -> None:
        self._track_core = core     # one reference store: atomic under the GIL

    def _inputs(self, y: Any, v: Any, quat: Any, rates: Any, lo: Any, hi: Any,
                lam_start: float, ok: bool, failed: bool) -> TFLInputs:
        return TFLInputs(y, v, quat, rates, self._frame, self.attack_estimate_n, lo, hi,
                         lam_start, ok, failed)

    # ------------------------------------------------------------------ the state
    @property
    def cfg(self) -> LawConfig:
        """The gains and switches; setting it (the flight computer's flyable speed) remakes
        the step's constants."""
        return self._cfg

    @cfg.setter
    def cfg(self, cfg: LawConfig) -> None:
        self._cfg = cfg
        self.params = law_params(self.model, cfg, self._dt, self.tracker.min_tube_margin)

    @property
    def dt(self) -> float:
        """The control period (s) the next tick integrates over; setting it (states were
        skipped: the real gap) changes the step's ``dt_s``."""
        return self._dt

    @dt.setter
    def dt(self, dt_s: float) -> None:
        self._dt = dt_s
        self.params = self.params._replace(dt_s=float(dt_s))

    @property
    def core(self) -> str:
        """What flies the law's arithmetic: ``compiled`` (the seam's build of the step),
        ``python`` (the step itself) or ``reference jets`` (the reference tracker)."""
        if self._linked_for is not self.tracker:
            return "reference jets"
        return "compiled" if self._core is not None else "python"

    def step_arguments(self, s: State, lam_start: float = 0.0, lam_start_ok: bool = False,
                       path_failed: bool = False
                       ) -> tuple[TFLParams, TFLState, TFLInputs, Kernels | None]:
        """``(params, state, inputs, kernels)``: what :func:`step.tfl_step` is called with
        for the measured state ``s`` (ENU, body FLU) now, with the rotors free (no motor-lag
        bound: 0 … f_max N each) and the path's projection kernels (None on the reference
        tracker) — to run, time or lower the pure step on its own. The last three are
        :class:`step.TFLInputs`'s fields of those names."""
        u = self._inputs(tuple(_floats(s.position_m)), tuple(_floats(s.velocity_mps)),
                         tuple(_floats(s.quaternion_wxyz)), tuple(_floats(s.body_rates_radps)),
                         *self._free, lam_start, lam_start_ok, path_failed)
        return self.params, as_state(self.state), u, self._kernels

    def _set(self, **fields: Any) -> None:
        self.state = as_state(self.state)._replace(**fields)

    @property
    def x13(self) -> float:
        """u_f (N), the dynamic extension's first state (eq. (9))."""
        return float(self.state.x13)

    @x13.setter
    def x13(self, value: float) -> None:
        self._set(x13=value)

    @property
    def x14(self) -> float:
        """u̇_f (N/s), the dynamic extension's second state (eq. (9))."""
        return float(self.state.x14)

    @x14.setter
    def x14(self, value: float) -> None:
        self._set(x14=value)

    @property
    def mass_kg(self) -> float:
        """The mass the law flies with (kg): the estimate when the estimator runs."""
        return float(self.state.mass.mass_kg)

    @property
    def mass_learnt_s(self) -> float:
        """How long the mass estimator has learnt (s of ticks it took a sample from)."""
        return float(self.state.mass.updates) * self._dt

    @property
    def fine(self) -> bool:
        """True once the law has switched to the fine ξ, η poles."""
        return self.state.fine

    @property
    def k_xi(self) -> tuple[float, ...]:
        """The ξ chain's gains now (eq. (23))."""
        return self.params.k_xi_fine if self.fine else self.params.k_xi

    @property
    def k_eta(self) -> tuple[float, ...]:
        """The η chain's gains now (eq. (24))."""
        return self.params.k_eta_fine if self.fine else self.params.k_eta

    @property
    def lam(self) -> float | None:
        """The path parameter of the closest point (None before the first projection)."""
        if self._linked_for is not self.tracker:
            return self.tracker.lam
        ps = self.state.path
        return ps.lam if ps.has_lam else None

    @property
    def has_motor_lag(self) -> bool:
        """Whether the motors lag (the model's time constant > 0): the law then commands
        through the motor-lag inverse (:mod:`~tfl_mav.control.actuators`)."""
        return self.lag_inverter is not None

    def invert_lag(self, thrust_n: Sequence[float], rotor_speed_radps: Sequence[float] | None,
                   pinned: int = 0) -> tuple[list[float], list[float]]:
        """Another law's thrusts (N, physical order) through this law's motor-lag inverse,
        which then knows what was commanded (its trend) when this law flies again: (the
        command to send, the mean the rotors deliver over the period) from the rotor speeds
        ω (rad/s). Rotor ``pinned`` (1-4; 0: none) is not ours to command: it passes as it
        is. Without motor lag: the thrusts, twice."""
        lag = self.lag_inverter
        if lag is None:
            return list(thrust_n), list(thrust_n)
        lag.reachable(rotor_speed_radps)
        inv = lag.invert(thrust_n)
        command, delivered = inv.command_n, list(inv.expected_mean_n)
        if pinned:
            command[pinned - 1] = thrust_n[pinned - 1]
            delivered[pinned - 1] = thrust_n[pinned - 1]
        return command, delivered

    def reset_lag_inverse(self) -> None:
        """Another law takes over (or this one after another): the demand inverted next is
        not a trend of the last one's (:meth:`.actuators.MotorLagInverter.reset`)."""
        if self.lag_inverter is not None:
            self.lag_inverter.reset()

    # ------------------------------------------------------------------ configuration
    def resume(self, thrust_n: Sequence[float], lam: float | None = None,
               thrust_rate_nps: float = 0.0) -> None:
        """Fly again, bumpless, from a state another law flew: the dynamic extension starts at
        the thrust now applied and its rate (x13 = Σ f N, x14 = ``thrust_rate_nps`` N/s,
        eq. (9); starting x14 at 0 while the other law's thrust was changing is a jerk the ξ
        chain then rings out), the rate observer, the ṗ, q̇ prediction and the lag inverse
        start afresh, and the path parameter moves to ``lam`` (the other law's projection;
        None keeps its own)."""
        s = as_state(self.state)
        ps = s.path
        if lam is not None:
            ps = ps._replace(has_lam=True, lam=lam)
            if self._linked_for is not self.tracker:
                self.tracker.lam = lam
        # The mass estimator has kept learning while the other law flew (:meth:`track`).
        # The translational observer keeps what it learnt (the air did not change with the
        # law), but not the velocity of the last tick it saw, ticks ago.
        self.state = s._replace(x13=sum(thrust_n), x14=thrust_rate_nps, dob=DOB_START,
                                tdob=s.tdob._replace(has_prev=False), has_pred=False,
                                last_out=tuple(thrust_n), path=ps)
        if self.lag_inverter is not None:
            self.lag_inverter.reset()

    def track(self, s: State, applied_n: Sequence[float]) -> None:
        """A tick another law flew: the mass estimator learns from it as from its own
        (:func:`~tfl_mav.control.tfl.estimators.mass_update` with the thrust that was applied
        over the last period, N, and the measured velocity and attitude). Newton's law holds
        whichever law commands, so at a hand-back the estimate and its filters are those of
        the vehicle now, not of the moment the other law took over (a stale LP(v) against
        today's v reads as an acceleration: the estimate jumped by 3 % and left a tail)."""
        p = self.params
        if not p.use_mass:
            return
        st = as_state(self.state)
        q, v, thrust = _floats(s.quaternion_wxyz), _floats(s.velocity_mps), float(sum(applied_n))
        core = self._track_core
        mass = core(p.mass, st.mass, p.dt_s, q, v, thrust) if core is not None else None
        if mass is None:        # not compiled, or declined (Python raises there): Python
            mass = mass_observe(p.mass, st.mass, p.dt_s, q, v, thrust)
        self.state = _new_tuple(TFLState, (*st[:_MASS], mass, *st[_MASS + 1:]))

    def settle_on(self, path_distance_m: float) -> None:
        """A tick another law flew ``path_distance_m`` (m) from the path: the one-time switch
        to the fine poles counts it as its own (:func:`~tfl_mav.control.tfl.step.settle`).
        A vehicle the safe law has held on the path is settled, and TFL resumes with the
        poles it would have had: on the coarse ones the safe law's last jerk (a spinning
        vehicle's nutation, (u_f/m)·|(p, q)| ≈ 0.08 m/s³) rings out as a 1 mm tail over the
        second the switch waits (j (3/p)³ e⁻³/6 at p = 2.5), on the fine ones (p = 8) as
        0.03 mm."""
        st = as_state(self.state)
        d = path_distance_m if math.isfinite(path_distance_m) else math.inf
        fine, settled = settle(self.params, st.fine, st.settled_s, d, self.params.dt_s)
        if fine != st.fine or settled != st.settled_s:
            self._set(fine=fine, settled_s=settled)

    def set_attack(self, rotor: int, estimate_n: float) -> None:
        """Declare rotor (1-4) attacked with the given thrust estimate (N); 0 = none.

        Bumpless: the ξ/η chains and the dynamic extension carry over; only the allocation
        changes (and the yaw loop is dropped). The baseline (``aware_of_attack = False``)
        ignores this.
        """
        if not self.cfg.aware_of_attack:
            return
        if not math.isfinite(estimate_n):
            return  # keep the previous estimate: never let a NaN into the law
        estimate_n = min(max(estimate_n, 0.0), self.model.thrust_max_n)
        if rotor != self.attacked_rotor:
            self.attacked_rotor = rotor
            self.frame = canonical_frame(rotor) if rotor else None
            self._frame = frame_numbers(self.model, self.frame)
            self._set(dob=DOB_START, has_pred=False)
            if self.lag_inverter is not None:
                self.lag_inverter.reset()
        self.attack_estimate_n = float(estimate_n)

    # ------------------------------------------------------------------ the law
    def update(self, s: State, rotor_speed_radps: Sequence[float] | None = None, *,
               dt_s: float | None = None, attack_n: float | None = None) -> ControlOutput:
        """Compute the rotor thrusts (N) for this control period from the measured state
        and, with motor lag, the measured rotor speeds ω (rad/s, from ESC rpm). ``dt_s``:
        the real time since the last tick when it is not one control period (a real-time
        daemon skipped states): the law's internal states integrate over it. ``attack_n``:
        the attacked rotor's thrust estimate this tick (N; the rotor is :meth:`set_attack`'s),
        clamped to [0, f_max], a NaN keeping the last one."""
        if attack_n is not None and self.cfg.aware_of_attack and attack_n == attack_n:
            fmax = self.model.thrust_max_n
            self.attack_estimate_n = (fmax if attack_n > fmax else
                                      (0.0 if attack_n < 0.0 else float(attack_n)))
        if dt_s is not None and dt_s != self._dt:
            period = self._dt
            self.dt = dt_s
            try:
                return self.update(s, rotor_speed_radps)
            finally:
                self.dt = period
        self.ticks += 1
        # As measured: a float64 array's numbers the compiled step reads in place (its
        # buffer); Python floats for the Python step, where numpy scalars (the simulator's
        # arrays) cost 3-5× per operation.
        y, v, quat, rates = s.position_m, s.velocity_mps, s.quaternion_wxyz, s.body_rates_radps
        lag = self.lag_inverter
        lo, hi = lag.reachable(rotor_speed_radps) if lag is not None else self._free
        st = self.state
        trk = self.tracker
        if self._linked_for is trk:
            lam_start, ok, failed = 0.0, False, False
            if not st.path.has_lam:         # no λ yet: a global search first
                lam_start, ok, failed = trk.start(_floats(y))
                self._failure = trk.failure
            core, kernels = self._core, self._kernels
            r = None
            if core is not None:
                r = core(self.params, st, TFLInputs(y, v, quat, rates, self._frame,
                                                    self.attack_estimate_n, lo, hi,
                                                    lam_start, ok, failed), kernels)
            if r is None:
                u = TFLInputs(_floats(y), _floats(v), _floats(quat), _floats(rates),
                              self._frame, self.attack_estimate_n, lo, hi, lam_start, ok,
                              failed)
                if core is not None and (u[0] is not y or u[1] is not v or u[2] is not quat
                                         or u[3] is not rates):
                    r = core(self.params, st, u, kernels)   # arrays, not of float64: as floats
            if r is None:       # not compiled, or the compiled step declined: Python decides
                st = as_state(st)
                try:
                    r = self._step(self.params, st, u, kernels)
                except _PATH_ERRORS as exc:
                    self._failure = str(exc)
                    r = self._step(self.params, st, u._replace(path_failed=True), kernels)
        else:
            r = self._reference_tick(as_state(st), _floats(y), _floats(v), _floats(quat),
                                     _floats(rates), lo, hi)
        new, out = r
        f, attacked, sat, xi, eta, mu, distance, lam, cond, uf, mass, dob, fine, reason, \
            code, margin, canon_rates, sat_any, demand = out
        if sat_any:
            self.saturation_count += 1
        command = list(f)
        if lag is not None:
            command, new = self._invert_lag(f, new, canon_rates)
        self.state = new
        text = ""
        if reason:
            self.fallback_count += 1
            mode = _FALLBACK
            text = self._reason_text(reason, code, distance, margin, uf, cond)
        else:
            mode = _ATTACKED if attacked else _NOMINAL
        # ControlOutput's fields in order, built as the tuple it is (a keyword call of a
        # named tuple costs more than a microsecond a tick).
        return _new_output(ControlOutput, (
            command, mode, list(sat), xi, eta, mu, distance, lam, cond, uf, mass, dob, fine,
            text, demand))

    def _reference_tick(self, st: TFLState, y: Any, v: Any, quat: Any, rates: Any, lo: Any,
                        hi: Any) -> tuple[Any, Any]:
        """The step with the reference tracker's virtual output for :func:`step.project`."""
        u = TFLInputs(y, v, quat, rates, self._frame, self.attack_estimate_n, lo, hi, 0.0,
                      False, False)
        seen = step.observe(self.params, st, u)
        vo = self.tracker.virtual_output(seen.rows)
        self._failure = vo.reason
        projected = Projected(VO.OK if vo.in_tube else VO.REFERENCE, vo.xi1, vo.xi2, vo.eta,
                              vo.jacobian, vo.lam, vo.distance_m, 0.0)
        return step.command(self.params, st, u, seen, projected, st.path)

    def _invert_lag(self, f: Sequence[float], new: Any, canon_rates: Any
                    ) -> tuple[list[float], Any]:
        """The motor-lag inverse of the step's thrusts (:mod:`actuators`): the command to
        send, and the state with the ṗ, q̇ prediction and the last output made from what
        the rotors will deliver."""
        assert self.lag_inverter is not None
        inv = self.lag_inverter.invert(f)
        command, delivered = inv.command_n, inv.expected_mean_n
        if self.frame is not None:
            p1 = self.frame.perm[1]
            command[p1] = f[p1]
            delivered[p1] = f[p1]
        if any(inv.clamped):
            self.lag_clamped_count += 1
        pred = step.predict(self.params, self._frame, tuple(delivered), canon_rates)
        new = as_state(new)._replace(pred=pred, last_out=tuple(delivered))
        return command, new

    def _reason_text(self, reason: Fallback, code: VO, distance: float, margin: float,
                     uf: float, cond: float) -> str:
        """Why the law fell back, in words."""
        words = _FALLBACK_WORDS.get(reason)
        if words is None:           # Fallback.TUBE: the lost projection's own words
            return "left the projection tube: " + lost_reason(code, distance, margin,
                                                               self._failure)
        return words.format(uf=uf, cond=cond)
