"""The TFL law's tick for one flight as one generated function.

A tick of the law (paper §V) is ~1 000 floating-point operations spread over ~30 Python
calls; the calls, tuple packs and attribute reads cost more than the arithmetic. A path and
the model are fixed for a flight, so at start-up this module writes the tick — the state as
floats, R(q) and the canonical axes, the estimators' updates (:mod:`estimators`), the
output's Taylor rows from the model (eqs. (3), (9)), the closest-point projection (eq. (13),
Newton warm-started as :class:`compiled.CompiledPathTracker`), π's rates and α = s(y) with
Dφ (eqs. (8), (14), (15)), the ξ, η controllers (eqs. (23), (24)), the decoupling solve
(eq. (21)), the torques (eq. (3)) and, without motor lag, the rest: rotor allocation (eqs.
(4), (6)), saturation and the ṗ, q̇ prediction, the extension (eq. (9)), the gain switch
and the output record — as the body of one Python function: the straight-line pieces are
traced (:mod:`jetcode`) from the very functions the step-by-step law, the estimators and
the compiled tracker run (:mod:`law_math`, :mod:`estimators`, :func:`tracker.pi_rates`,
the path's σ and s; the attacked allocation from its own source through
:func:`kernelgen.traceable`), the loop, the checks and the bookkeeping are written here
around them. Same operations in the same order (up to exact rewrites: x/2ᵏ as x·2⁻ᵏ, a
negation folded into a constant factor), so the same numbers bit for bit. One tape holds
the middle after the Newton loop, so what the path makes constant (σ' = (1, ·, ·) on the
paper path, ∂s/∂y rows of 0 and 1) folds through π, Dφ and Cramer's rule, and operations
nothing reads are dropped; the temporaries then share locals (:func:`kernelgen.reuse_slots`).

After the prelude (which the step-by-step tick would have run the same way, estimators
included) the function changes nothing until the middle succeeds: every condition under
which the law would fall back (projection lost, tube margin, u_f too small, Dφ singular or
ill-conditioned, a non-finite result, an evaluation error) makes it return ``(None, the
prelude's results)``, and the law runs its step-by-step middle from there, whose fallbacks
and reasons are unchanged. On success it commits the tracker's state (λ, the expansion, π)
and returns the :class:`ControlOutput` (with motor lag: the middle's numbers, and the law's
own steps run the lag inverse and the rest).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from tfl_mav.control.allocation import allocate_attacked, allocate_nominal
from tfl_mav.control.path.compiled import (
    _NEWTON_ITERS,
    Y_NAMES,
    PathKernels,
    _arc,
    trace_pi,
    traced_sqrt,
)
from tfl_mav.control.path.jetcode import Sym, _text
from tfl_mav.control.path.kernelgen import compile_source, reuse_slots, trace_block, traceable
from tfl_mav.control.tfl import fused_native
from tfl_mav.control.tfl.estimators import (
    MassEstimator,
    RateDisturbanceObserver,
    dob_step,
    mass_blend,
    mass_filters,
)
from tfl_mav.control.tfl.law_math import (
    attacked_tau_r,
    b0_inverse,
    cofactors,
    cramer,
    linear_rhs,
    output_rows,
    rate_prediction,
    rotation,
    torques,
    yaw_tau_r,
)
from tfl_mav.control.tfl.law_types import ControlOutput, ModelParams
from tfl_mav.model.modes import Mode

__all__ = ["FusedTick", "build_fused"]

#: The generated tick's globals besides the math functions.
GLOBALS: dict[str, Any] = {
    "_isfinite": math.isfinite, "_arc": _arc, "_atan2": math.atan2, "_hypot": math.hypot,
    "_ndarray": np.ndarray, "_alloc_nom": allocate_nominal,
    "_yaw_tau_r": yaw_tau_r, "_new": tuple.__new__,
    "_ControlOutput": ControlOutput, "_inf": math.inf,
    "_NOMINAL": Mode.NOMINAL, "_ATTACKED": Mode.ATTACKED}

@dataclass(frozen=True)
class FusedTick:
    """The generated tick: ``fn(ctl, trk, state)`` → the tick's :class:`ControlOutput`;
    with motor lag (ü_f, q̇, τ_p, τ_q, cond Dφ, ξ rows, η, λ, distance, ψ, R's last row,
    rates, p, q, r, mass) for the law's tail; or (None, y, v, ψ, R's last row, rates, b1,
    b2, b3, p, q, r, mass) for the step-by-step middle (see module doc)."""

    fn: Callable[..., tuple[Any, ...] | None]
    source: str
    n_ops: int
    build_s: float
    #: The tick's arithmetic as one pure function, for :mod:`native` to compile
    #: (:mod:`fused_native`; empty when the estimators are the law's own calls).
    core_source: str = ""
    #: The tick calling that compiled core ``_core`` (see :meth:`with_core`).
    native_source: str = ""

    def with_core(self, core: Callable[..., tuple[float, ...] | None] | None = None
                  ) -> tuple[Callable[..., tuple[Any, ...] | None], dict[str, Any]]:
        """The tick calling ``_core`` (a compiled ``fused_core``) for its middle, and the
        globals it reads ``_core`` from (set it there when a build completes)."""
        namespace = {**GLOBALS, "_core": core, "_python_tick": self.fn}
        fn = compile_source("fused_tick", self.native_source, namespace)
        return fn, fn.__globals__


def _flat(rows: Any) -> list[Any]:
    return [x for row in rows for x in row]


def _newton_step(trace_sigma: Callable[..., list[Any]], lam_: list[Sym], y0: list[Sym]
                 ) -> list[Any]:
    """One Newton step of the projection, as compiled.CompiledPathTracker._project_compiled
    (the loop around it is written in :func:`build_fused`)."""
    tape = lam_[0].tape
    c0x, c0y, c0z, c1x, c1y, c1z, c2x, c2y, c2z = trace_sigma(lam_, 2)
    ex, ey, ez = y0[0] - c0x, y0[1] - c0y, y0[2] - c0z
    dg = 2.0 * (ex * c2x + ey * c2y + ez * c2z) - (c1x * c1x + c1y * c1y + c1z * c1z)
    step = -(ex * c1x + ey * c1y + ez * c1z)
    tape.raw("\n".join(f"    {ln}" for ln in (
        f"if not {_text(dg)} < 0.0:", "    return None",
        f"step = {_text(step)} / {_text(dg)}", "lam += step",
        "if not abs(lam - lam0) <= 0.05:", "    return None",
        "if abs(step) < 1e-9:", "    break")))
    return []


def _after_projection(model: ModelParams, trace_sigma: Callable[..., list[Any]],
                      trace_s: Callable[..., list[Any]], lam_: list[Sym], x: list[Sym],
                      y: list[Sym], z: list[Sym], s: list[Sym], b1: list[Sym], b2: list[Sym],
                      b3: list[Sym]) -> list[Any]:
    """The tick after the Newton loop, traced on one tape so that what the path makes
    constant (σ' = (1, ·, ·), ∂s/∂y = (·, 1, 0) …) folds through π, Dφ and Cramer's rule
    (only x·1, x·0, x ± 0, exact for the finite values of a tick that succeeds)."""
    lam = lam_[0]
    tape = lam.tape
    pc, qc, rc, mass, uf = s
    t = _text

    def raw(*lines: str) -> None:
        tape.raw("\n".join(f"    {ln}" for ln in lines))

    def local(name: str, value: Any) -> Sym:
        raw(f"{name} = {t(value)}")
        return tape.input(name)

    c = trace_sigma([lam], 5)
    raw(*(f"c{j} = {t(v)}" for j, v in enumerate(c)))
    cp = [tape.input(f"cp{j}") for j in range(18)]
    local("arc", tape.input("arc_m") + _arc(cp, c, lam - tape.input("lam0"), traced_sqrt))
    # compiled.CompiledPathTracker.virtual_output: slope, tube margin, distance.
    c0x, c0y, c0z, c1x, c1y, c1z = c[0:6]
    e0x, e0y, e0z = x[0] - c0x, y[0] - c0y, z[0] - c0z
    s1sq = c1x ** 2 + c1y ** 2 + c1z ** 2
    slope = -s1sq + 2.0 * (e0x * c[6] + e0y * c[7] + e0z * c[8])
    raw(f"if not ({t(s1sq)} > 0.0 and -{t(slope)} / {t(s1sq)} >= tube_min):",
        "    return None")
    local("distance", traced_sqrt(e0x ** 2 + e0y ** 2 + e0z ** 2))
    p1, p2, p3, p4 = trace_pi(c, x, y, z, [slope])
    a = trace_s(x, y, z)
    k = traced_sqrt(s1sq) / -slope
    jac = (a[10:13], a[13:16], (k * c1x, k * c1y, k * c1z))
    # law.TFLController._decoupling_solve, law_math.
    kx = [tape.input(f"kx{i}") for i in range(4)]
    ke = [tape.input(f"ke{i}") for i in range(3)]
    speed = tape.input("speed")
    r = linear_rhs(a[0:5], a[5:10], (None, p1, p2, p3, p4), kx, ke, speed)
    co0, co1, co2, det, norms = cofactors(jac, traced_sqrt)
    raw(f"if not {t(norms)} > 0:", "    return None",
        f"rel = abs({t(det)}) / {t(norms)}",
        "if not rel >= 1e-12:", "    return None",
        "cond = 1.0 / rel",
        "if not cond <= max_cond:", "    return None")
    inv = local("inv", 1.0 / det)
    udd, pdot, qdot = b0_inverse(cramer(jac, r, co0, co1, co2, inv), b1, b2, b3, mass, uf)
    udd, pdot, qdot = local("udd", udd), local("pdot", pdot), local("qdot", qdot)
    # The DOB's estimate (0.0 without it: x − 0.0 = x for every x).
    raw("if not (_isfinite(udd) and _isfinite(pdot) and _isfinite(qdot)):",
        "    return None",
        "pdot -= dsub_p",
        "qdot -= dsub_q")
    ixyz = [tape.input(n) for n in ("ix", "iy", "iz")]
    tau_p, tau_q = torques(pdot, qdot, pc, qc, rc, *ixyz, model.k_r)
    raw(f"tau_p = {t(tau_p)}", f"tau_q = {t(tau_q)}",
        *(f"xi{i}{j} = {t(v)}" for i, row in enumerate((a[0:4], a[5:9]))
          for j, v in enumerate(row)),
        f"eta1 = {t(p1)}", f"eta2 = {t(p2)}", f"eta3 = {t(p3)}")
    return []


def build_fused(model: ModelParams, kernels: PathKernels, *, dt_s: float | None = None,
                mass_est: MassEstimator | None = None,
                dob: RateDisturbanceObserver | None = None) -> FusedTick:
    """Generate the fused tick for ``model`` and the path of ``kernels``; with the period
    and the law's estimators (their constants fold in) their updates are generated too,
    else the tick calls the law's."""
    t0 = time.perf_counter()
    assert kernels.trace_sigma is not None and kernels.trace_s is not None
    trace_sigma, trace_s = kernels.trace_sigma, kernels.trace_s
    n_ops = 0

    def block(prefix: str, inputs: list[list[str]], trace: Callable[..., Any],
              outputs: list[str], indent: str = "    ") -> list[str]:
        nonlocal n_ops
        lines, n = trace_block(prefix, inputs, trace, outputs, indent)
        n_ops += n
        return lines

    model_rows = block(
        "m_", [["x0", "y0", "z0"], ["x1", "y1", "z1"], ["b1x", "b1y", "b1z"],
               ["b2x", "b2y", "b2z"], ["b3x", "b3y", "b3z"], ["pc", "qc", "rc", "uf", "duf",
                                                               "mass"]],
        lambda y, v, b1, b2, b3, s: _flat(output_rows(y, v, b1, b2, b3, *s, model.k_t,
                                                      model.gravity_mps2)),
        _flat(Y_NAMES))
    sigma2 = block("g_", [["lam"], ["x0", "y0", "z0"]],
                   lambda lam, y0: _newton_step(trace_sigma, lam, y0), [], " " * 8)
    after = block("t_", [["lam"], *Y_NAMES, ["pc", "qc", "rc", "mass", "uf"],
                         ["b1x", "b1y", "b1z"], ["b2x", "b2y", "b2z"], ["b3x", "b3y", "b3z"]],
                  lambda *g: _after_projection(model, trace_sigma, trace_s, *g), [])
    rot = block("q_", [["qw", "qx", "qy", "qz"]], lambda q: rotation(q, traced_sqrt),
                [f"r{i}{j}" for i in range(3) for j in range(3)])
    # As the tracker's isfinite(sum(tx) + sum(ty) + sum(tz)): the same additions.
    rows = " + ".join(f"({' + '.join(r)})" for r in Y_NAMES)
    # What the core reads of the controller and the tracker, read before it (plain reads:
    # σ's expansion at λ₀, when not kept from the last tick, is a pure kernel call).
    pre = [
        "uf = ctl.x13",
        "duf = ctl.x14",
        "cfg = ctl.cfg",
        "if not (uf >= cfg.min_thrust_n and uf > 0.0):",
        "    return None",
        "x0, y0, z0 = y",
        "x1, y1, z1 = v",
        "# The projection (eq. (13)): compiled.CompiledPathTracker._project_compiled.",
        "lam0 = trk.lam",
        "prev = trk._expansion",
        "fresh = prev is not None and prev[0] == lam0",
        "lp = trk._lam_prev",
        "lam = 2.0 * lam0 - lp if fresh and lp is not None else lam0",
        "cp = prev[1] if fresh else trk._sigma5((lam0,))",
        f"{', '.join(f'cp{j}' for j in range(18))} = cp",
        "arc_m = trk._arc_m",
        "tube_min = trk.min_tube_margin",
        "kx0, kx1, kx2, kx3 = ctl.k_xi",
        "ke0, ke1, ke2 = ctl.k_eta",
        "speed = cfg.speed_mps",
        "max_cond = cfg.max_cond",
        "if ctl._use_dob:",
        "    dob = ctl.dob",
        "    dsub_p, dsub_q = dob.d_p, dob.d_q",
        "else:",
        "    dsub_p = dsub_q = 0.0",
        "ix, iy, iz = ctl._ixyz",
    ]
    # The core: floats in, floats out (or None: the step-by-step tick takes over); in
    # Python it runs inline, compiled it is one call (:mod:`native`).
    core = [
        *(ln[4:] for ln in model_rows),
        f"if not _isfinite({rows}):",
        "    return None",
        f"for _ in range({_NEWTON_ITERS}):",
        *(ln[4:] for ln in sigma2),
        "else:",
        "    return None",
        *(ln[4:] for ln in after),
    ]
    post = [
        f"c = ({', '.join(f'c{j}' for j in range(18))})",
        "xi = ((xi00, xi01, xi02, xi03), (xi10, xi11, xi12, xi13))",
        "eta = (arc, eta1, eta2, eta3)",
        "trk._arc_m = arc",
        "trk._lam_prev = lam0",
        "trk.lam = lam",
        "trk._expansion = (lam, c)",
    ]
    before, att, after_att = _tail(model, block)
    bail = ("return (None, y, v, psi, (r20, r21, r22), rates, (b1x, b1y, b1z), (b2x, b2y, b2z), "
            "(b3x, b3y, b3z), pc, qc, rc, mass)")
    generated = dt_s is not None and mass_est is not None and dob is not None
    if generated:
        est, est_pieces = _estimators(block, dt_s, mass_est, dob)    # type: ignore[arg-type]
    else:
        est, est_pieces = ["    mass = ctl._update_estimators(v, (b3x, b3y, b3z), pc, qc)"], {}
    source = reuse_slots("\n".join([
        "def fused_tick(ctl, trk, s):",
        "    # The prelude: law.TFLController._prelude.",
        *(f"    {name} = s.{field}\n    if type({name}) is _ndarray:\n"
          f"        {name} = {name}.tolist()"
          for name, field in (("y", "position_m"), ("v", "velocity_mps"),
                              ("quat", "quaternion_wxyz"), ("rates", "body_rates_radps"))),
        "    qw, qx, qy, qz = quat",
        *rot,
        "    psi = _atan2(r10, r00)",
        "    if ctl.psi_ref is None:",
        "        ctl.psi_ref = psi",
        "    (m1, s1), (m2, s2) = ctl._axes",
        "    cols = ((r00, r10, r20), (r01, r11, r21))",
        "    col = cols[m1]",
        "    b1x, b1y, b1z = s1 * col[0], s1 * col[1], s1 * col[2]",
        "    col = cols[m2]",
        "    b2x, b2y, b2z = s2 * col[0], s2 * col[1], s2 * col[2]",
        "    b3x, b3y, b3z = r02, r12, r22",
        "    pc, qc, rc = s1 * rates[m1], s2 * rates[m2], rates[2]",
        *est,
        "    # The middle; on any bail the step-by-step tick takes over from here.",
        "    try:",
        *(f"        {ln.replace('return None', bail)}" for ln in pre + core + post),
        "    except (ValueError, ZeroDivisionError, OverflowError):",
        f"        {bail}",
        *before, *att, *after_att,
    ]) + "\n")
    fn = compile_source("fused_tick", source, GLOBALS)
    core_source = native_source = ""
    if generated:
        core_source, native_source = fused_native.sources(
            rot=rot, est=est_pieces, model_rows=model_rows, rows=rows, sigma2=sigma2,
            after=after, att=att, tail=before + after_att)
    return FusedTick(fn, source, n_ops, time.perf_counter() - t0, core_source, native_source)


def _clamped(indent: str, target: str, x: str, lo: float, hi: float) -> list[str]:
    """``target = estimators.clamp(x, lo, hi)`` for constant bounds, its two selects
    written out (a call costs more than the selects)."""
    return [f"{indent}{x} = {lo!r} if {lo!r} > {x} else {x}",
            f"{indent}{target} = {hi!r} if {hi!r} < {x} else {x}"]


def _estimators(block: Callable[..., list[str]], dt: float, me: MassEstimator,
                dob: RateDisturbanceObserver) -> tuple[list[str], dict[str, Any]]:
    """law.TFLController._update_estimators with the estimators' arithmetic traced (their
    constants folded) and their state read and written once; and the traced pieces, for
    the compiled core (:mod:`fused_native`)."""
    filters = block("e_", [["vx", "vy", "vz"], ["thrust"], ["b3x", "b3y", "b3z"],
                           ["lx", "ly", "lz"], ["phx", "phy", "phz"]],
                    lambda v, f, b3, vlp, phi: list(mass_filters(
                        dt, me.accel_tau_s, me.k_t, me.g, v, f[0], b3, vlp, phi)),
                    ["nlx", "nly", "nlz", "npx", "npy", "npz", "num", "den"], " " * 12)
    blend = block("h_", [["mass", "m_inst"]],
                  lambda g: [mass_blend(g[0], g[1], dt, me.ratio_tau_s)], ["blend"], " " * 20)
    a = dt / (dob.tau_s + dt)
    steps = block("o_", [["dp", "dq", "pc", "qc", "rp", "rq", "pp", "pq"]],
                  lambda g: [dob_step(g[0], g[2], g[4], g[6], dt, a),
                             dob_step(g[1], g[3], g[5], g[7], dt, a)], ["ndp", "ndq"], " " * 16)
    lo, hi, lim = me.lo, me.hi, dob.limit
    pieces = {"filters": filters, "blend": blend, "steps": steps, "dt": dt, "lo": lo, "hi": hi,
              "lim": lim, "min_den": me._min_den}
    return [
        "    # law.TFLController._update_estimators (estimators.MassEstimator.update, "
        "RateDisturbanceObserver.update)",
        "    if ctl._use_mass:",
        "        me = ctl.mass_est",
        "        lo_ = ctl._last_out",
        "        thrust = lo_[0] + lo_[1] + lo_[2] + lo_[3]",
        "        if me._v_lp is None:",
        f"            ctl.mass_kg = me.update({dt!r}, v, thrust, (b3x, b3y, b3z))",
        "        else:",
        "            vx, vy, vz = v",
        "            lx, ly, lz = me._v_lp",
        "            phx, phy, phz = me._phi_lp",
        *filters,
        "            me._v_lp = (nlx, nly, nlz)",
        "            me._phi_lp = (npx, npy, npz)",
        f"            if {me._min_den!r} <= den < _inf:",
        "                m_inst = num / den",
        "                mass = me.mass_kg",
        "                if -_inf < m_inst < _inf:",
        *blend,
        *_clamped("                    ", "me.mass_kg", "blend", lo, hi),
        "                    me.updates += 1",
        "            ctl.mass_kg = me.mass_kg",
        "    mass = ctl.mass_kg",
        "    if ctl._use_dob:",
        "        pred = ctl._pred",
        "        if pred is not None:",
        "            dob = ctl.dob",
        "            rprev = dob._prev",
        "            dob._prev = (pc, qc)",
        "            if rprev is not None:",
        "                pp, pq = pred",
        "                rp, rq = rprev",
        "                dp, dq = dob.d_p, dob.d_q",
        *steps,
        *_clamped("                ", "dob.d_p", "ndp", -lim, lim),
        *_clamped("                ", "dob.d_q", "ndq", -lim, lim),
    ], pieces


def _saturated(fmax: float) -> list[str]:
    """:func:`law_math.saturate` on the thrusts f0…f3 and the unbounded r0…r3 as selects
    (f_max + 1e-9 folded: the same addition), leaving the command in ``f`` and the flags
    in sat0…sat3."""
    hi = fmax + 1e-9
    return [
        *(f"    sat{i} = not -1e-9 <= r{i} <= {hi!r}" for i in range(4)),
        "    l0, l1, l2, l3 = ctl._last_out",
        "    f = [" + ", ".join(
            f"(0.0 if f{i} < 0.0 else ({fmax!r} if {fmax!r} < f{i} else f{i}))"
            f" if f{i} - f{i} == 0.0 else l{i}" for i in range(4)) + "]",
    ]


def _tail(model: ModelParams, block: Callable[..., list[str]]
          ) -> tuple[list[str], list[str], list[str]]:
    """The tick after the torques, as :meth:`law.TFLController.update` runs it on a tick
    without fallback: allocation ((4), (6) and the yaw loop), saturation and the ṗ, q̇
    prediction, the extension (9), the gain switch, the output record. With motor lag the
    function returns the middle's numbers and the law's own steps run the tail. Returned
    in three parts: before the attacked allocation, the allocation (which the compiled
    core computes itself), after it."""
    arm, kr, fmax = model.arm_m, model.k_r, model.thrust_max_n
    alloc = traceable(allocate_attacked)

    def attacked(g: list[Sym]) -> list[Any]:
        uf, tau_p, tau_q, a_n, d, inf = g
        tau_r = attacked_tau_r(uf, tau_p, a_n, arm, d)
        # The unbounded thrusts (for the saturation flags) with f_max = ∞ at run time.
        return [tau_r, *alloc(uf, tau_q, tau_r, a_n, arm, d, inf),
                *alloc(uf, tau_q, tau_r, a_n, arm, d, fmax, None)]

    att = block("a_", [["uf", "tau_p", "tau_q", "a_n", "d", "_inf"]], attacked,
                ["tau_r", "r0", "r1", "r2", "r3", "f0", "f1", "f2", "f3"], " " * 8)
    pred = block("p_", [["d0", "d1", "d2", "d3", "pc", "qc", "rc", "ix", "iy", "iz"]],
                 lambda g: rate_prediction(*g, kr, arm), ["pp", "pq"])
    return [
        "    # The tail: law.TFLController.update after the middle (motor lag: the law's).",
        "    if ctl.lag_inverter is not None:",
        "        return (udd, qdot, tau_p, tau_q, cond, xi, eta, lam, distance, psi,"
        " (r20, r21, r22), rates, pc, qc, rc, mass)",
        "    frame = ctl.frame",
        "    d = ctl._d",
        "    if frame is not None:",
        "        a_n = ctl.attack_estimate_n",
    ], att, [
        "        i0, i1, i2, i3 = ctl._inv_perm",
        "        if i0:",
        "            g = (f0, f1, f2, f3)",
        "            f0, f1, f2, f3 = g[i0], g[i1], g[i2], g[i3]",
        "            g = (r0, r1, r2, r3)",
        "            r0, r1, r2, r3 = g[i0], g[i1], g[i2], g[i3]",
        "        mode = _ATTACKED",
        "    else:",
        "        tau_r = _yaw_tau_r((r20, r21, r22), psi, ctl.psi_ref, pc, qc, rc, qdot, ctl.k_yaw,"
        f" (ix, iy, iz), {kr!r})",
        f"        r0, r1, r2, r3 = _alloc_nom(uf, tau_p, tau_q, tau_r, {arm!r}, d)",
        f"        f0, f1, f2, f3 = _alloc_nom(uf, tau_p, tau_q, tau_r, {arm!r}, d, {fmax!r}, None)",
        "        mode = _NOMINAL",
        "    # law.TFLController._saturate_and_apply (law_math.saturate written out)",
        *_saturated(fmax),
        "    p0, p1, p2, p3 = ctl._perm",
        "    if frame is not None:",
        "        f[p1] = a_n",
        "    if sat0 or sat1 or sat2 or sat3:",
        "        ctl.saturation_count += 1",
        "    applied_uf = f[0] + f[1] + f[2] + f[3]",
        "    d0, d1, d2, d3 = f[p0], f[p1], f[p2], f[p3]",
        *pred,
        "    ctl._pred = (pp, pq)",
        "    ctl._last_out = f",
        "    # law.TFLController._advance_extension, _settle",
        "    dt = ctl.dt",
        "    x13, x14 = uf, duf",
        "    if abs(applied_uf - uf) > 1e-9:",
        "        x13 = applied_uf",
        "        if (applied_uf - uf) * duf < 0:",
        "            x14 = 0.0",
        "    ctl.x13 = x13 + (dt * x14 + 0.5 * dt * dt * udd)",
        "    ctl.x14 = x14 + dt * udd",
        "    if ctl._use_switch and not ctl.fine:",
        "        settled = ctl._settled_s + dt if _hypot(xi[0][0], xi[1][0]) < cfg.settle_alpha"
        " else 0.0",
        "        ctl._settled_s = settled",
        "        if settled >= cfg.settle_time_s:",
        "            ctl._set_gains(fine=True)",
        "    iz_, arm_, den = ctl._mu2",
        "    dob = ctl.dob",
        "    return _new(_ControlOutput, (f, mode, [sat0, sat1, sat2, sat3], xi, eta,"
        " (psi, -rates[0] / iz_ - arm_ * rates[2] / den), distance, lam, cond, uf, mass,"
        " (dob.d_p, dob.d_q), ctl.fine, ''))",
    ]
