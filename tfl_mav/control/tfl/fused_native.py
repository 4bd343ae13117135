"""The fused tick's arithmetic as one pure function, and the tick that calls it compiled.

:mod:`fused` writes the law's tick as Python: attribute reads, the arithmetic, attribute
writes, interleaved. Compiled to C (:mod:`native`) only pure arithmetic pays, so here the
same traced pieces — R(q) and the canonical axes, ψ = atan2(R₁₀, R₀₀), the estimators'
updates, the model's Taylor rows (eqs. (3), (9)), the projection's Newton loop (eq. (13)),
π, α, Dφ and the ξ/η controllers (eqs. (8), (14), (15), (23), (24)), the decoupling solve and
the torques (eqs. (21), (3)) and the attacked allocation (eqs. (4), (6)) — are laid out as
``fused_core(…)``: the controller's and the tracker's state in as numbers and sequences,
every new value out, nothing written. The calling tick reads the state, makes one call,
writes what changed and runs the rest of the tail in Python (the permutation, saturation,
the ṗ/q̇ prediction, the extension (9), the gain switch, the output record).

Every line of the core is a line of the Python tick (the same traced text), so the core does
the Python tick's operations in its order; what differs is only how values move: the
canonical axes are selects on m ∈ {0, 1} instead of tuple indexing, and a DOB that is off
subtracts 0.0 (x − 0.0 = x for every x). Whenever the core cannot finish — the first tick
of the estimators, a fallback of the middle, an operation that would raise in Python,
anything that is not a number — it returns None and the Python tick runs the whole tick
from the start (the core wrote nothing), deciding exactly as before.
"""

from __future__ import annotations

import textwrap
import weakref
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any

from tfl_mav.accel import native
from tfl_mav.control.path.compiled import _NEWTON_ITERS

if TYPE_CHECKING:
    from tfl_mav.control.tfl.fused import FusedTick

__all__ = ["CORE_ARGS", "attach_native", "sources"]

#: ``fused_core``'s parameters, in the order the calling tick passes them.
CORE_ARGS = ("pos", "vel", "quat", "rates", "axes", "use_mass", "vlp", "phl", "me_mass",
             "ctl_mass", "last_out", "use_dob", "pred", "rprev", "dp", "dq", "uf", "duf",
             "min_thrust", "lam0", "lam", "cp", "arc_m", "tube_min", "k_xi", "k_eta", "speed",
             "max_cond", "ixyz", "attacked", "a_n", "d")

_RESULTS = ("psi", "r20", "r21", "r22", "pc", "qc", "rc", "mass", "v_lp", "phi_lp", "nmass",
            "upd", "ndp", "ndq", "lam", "expansion", "arc", "distance", "cond", "udd", "pdot",
            "qdot", "tau_p", "tau_q", "xi", "eta", "tau_r", "r0", "r1", "r2", "r3", "f0", "f1",
            "f2", "f3")


def _at(lines: Sequence[str], indent: str) -> list[str]:
    """``lines`` (one block, uniformly indented) re-indented to ``indent``."""
    text = textwrap.dedent("\n".join(lines))
    return [indent + ln if ln.strip() else ln for ln in text.split("\n")]


def _clamp(indent: str, x: str, lo: float, hi: float) -> list[str]:
    """As fused._clamped, into ``x`` itself."""
    return [f"{indent}{x} = {lo!r} if {lo!r} > {x} else {x}",
            f"{indent}{x} = {hi!r} if {hi!r} < {x} else {x}"]


def _core(rot: list[str], est: dict[str, Any], model_rows: list[str], rows: str,
          sigma2: list[str], after: list[str], att: list[str]) -> str:
    i4, i8, i12 = " " * 4, " " * 8, " " * 12
    sel = [f"{i4}b{n}{a} = s{n} * ({r}0 if m{n} == 0.0 else {r}1)"
           for n in (1, 2) for a, r in zip("xyz", ("r0", "r1", "r2"), strict=True)]
    body = [
        "x0, y0, z0 = pos", "x1, y1, z1 = vel", "qw, qx, qy, qz = quat", "wp, wq, wr = rates",
        "(m1, s1), (m2, s2) = axes",
    ]
    lines = [f"def fused_core({', '.join(CORE_ARGS)}):", *(i4 + ln for ln in body),
             *_at(rot, i4),
             f"{i4}psi = _atan2(r10, r00)",
             f"{i4}if not ((m1 == 0.0 or m1 == 1.0) and (m2 == 0.0 or m2 == 1.0)):",
             f"{i8}return None",
             *sel,
             f"{i4}b3x = r02", f"{i4}b3y = r12", f"{i4}b3z = r22",
             f"{i4}pc = s1 * (wp if m1 == 0.0 else wq)",
             f"{i4}qc = s2 * (wp if m2 == 0.0 else wq)",
             f"{i4}rc = wr",
             # law.TFLController._update_estimators, as fused._estimators
             f"{i4}if use_mass:",
             f"{i8}lx, ly, lz = vlp", f"{i8}phx, phy, phz = phl",
             f"{i8}l0, l1, l2, l3 = last_out", f"{i8}thrust = l0 + l1 + l2 + l3",
             f"{i8}vx = x1", f"{i8}vy = y1", f"{i8}vz = z1",
             *_at(est["filters"], i8),
             f"{i8}nmass = me_mass", f"{i8}upd = 0.0",
             f"{i8}if {est['min_den']!r} <= den < _inf:",
             f"{i12}m_inst = num / den",
             f"{i12}mass = me_mass",
             f"{i12}if -_inf < m_inst < _inf:",
             *_at(est["blend"], i12 + i4),
             f"{i12}    nmass = blend",
             *_clamp(i12 + i4, "nmass", est["lo"], est["hi"]),
             f"{i12}    upd = 1.0",
             f"{i8}mass = nmass",
             f"{i4}else:",
             *(f"{i8}{n} = 0.0" for n in ("nlx", "nly", "nlz", "npx", "npy", "npz", "nmass",
                                          "upd")),
             f"{i8}mass = ctl_mass",
             f"{i4}ndp = dp", f"{i4}ndq = dq",
             f"{i4}if use_dob:",
             f"{i8}if pred is not None:",
             f"{i12}if rprev is not None:",
             f"{i12}    pp, pq = pred", f"{i12}    rp, rq = rprev",
             *_at(est["steps"], i12 + i4),
             *_clamp(i12 + i4, "ndp", -est["lim"], est["lim"]),
             *_clamp(i12 + i4, "ndq", -est["lim"], est["lim"]),
             # the middle, as fused.build_fused's pre and core
             f"{i4}if not (uf >= min_thrust and uf > 0.0):", f"{i8}return None",
             f"{i4}dsub_p = 0.0", f"{i4}dsub_q = 0.0",
             f"{i4}if use_dob:", f"{i8}dsub_p = ndp", f"{i8}dsub_q = ndq",
             f"{i4}ix, iy, iz = ixyz",
             f"{i4}kx0, kx1, kx2, kx3 = k_xi", f"{i4}ke0, ke1, ke2 = k_eta",
             f"{i4}{', '.join(f'cp{j}' for j in range(18))} = cp",
             *_at(model_rows, i4),
             f"{i4}if not _isfinite({rows}):", f"{i8}return None",
             f"{i4}for _ in range({_NEWTON_ITERS}):",
             *_at(sigma2, i8),
             f"{i4}else:", f"{i8}return None",
             *_at(after, i4),
             # the attacked allocation, as fused._tail
             *(f"{i4}{n} = 0.0" for n in ("tau_r", "r0", "r1", "r2", "r3", "f0", "f1", "f2",
                                          "f3")),
             f"{i4}if attacked:",
             *_at(att, i8)]
    results = ", ".join(
        "(nlx, nly, nlz)" if n == "v_lp" else "(npx, npy, npz)" if n == "phi_lp" else
        f"(lam, ({', '.join(f'c{j}' for j in range(18))}))" if n == "expansion" else
        "((xi00, xi01, xi02, xi03), (xi10, xi11, xi12, xi13))" if n == "xi" else
        "(arc, eta1, eta2, eta3)" if n == "eta" else n for n in _RESULTS)
    lines.append(f"{i4}return ({results})")
    return "\n".join(lines) + "\n"


_TICK_HEAD = f"""\
def fused_tick(ctl, trk, s):
    # The projection's start (compiled.CompiledPathTracker._project_compiled).
    lam0 = trk.lam
    prev = trk._expansion
    fresh = prev is not None and prev[0] == lam0
    lp = trk._lam_prev
    lam = 2.0 * lam0 - lp if fresh and lp is not None else lam0
    if fresh:
        cp = prev[1]
    else:
        try:
            cp = trk._sigma5((lam0,))
        except (ValueError, ZeroDivisionError, OverflowError):
            return _python_tick(ctl, trk, s)
    me = ctl.mass_est
    dob = ctl.dob
    cfg = ctl.cfg
    use_mass = ctl._use_mass
    use_dob = ctl._use_dob
    pred = ctl._pred
    rprev = dob._prev
    r = _core(s.position_m, s.velocity_mps, s.quaternion_wxyz, s.body_rates_radps, ctl._axes,
              use_mass, me._v_lp, me._phi_lp, me.mass_kg, ctl.mass_kg, ctl._last_out,
              use_dob, pred, rprev, dob.d_p, dob.d_q, ctl.x13, ctl.x14, cfg.min_thrust_n,
              lam0, lam, cp, trk._arc_m, trk.min_tube_margin, ctl.k_xi, ctl.k_eta,
              cfg.speed_mps, cfg.max_cond, ctl._ixyz,
              ctl.frame is not None and ctl.lag_inverter is None, ctl.attack_estimate_n,
              ctl._d)
    if r is None:       # the core wrote nothing: the Python tick decides, from the start
        return _python_tick(ctl, trk, s)
    {", ".join(_RESULTS)} = r
    # What the prelude and the estimators write (law.TFLController._prelude,
    # _update_estimators), then the tracker's commit.
    if ctl.psi_ref is None:
        ctl.psi_ref = psi
    if use_mass:
        me._v_lp = v_lp
        me._phi_lp = phi_lp
        me.mass_kg = nmass
        if upd:
            me.updates += 1
        ctl.mass_kg = nmass
    if use_dob and pred is not None:
        dob._prev = (pc, qc)
        if rprev is not None:
            dob.d_p = ndp
            dob.d_q = ndq
    trk._arc_m = arc
    trk._lam_prev = lam0
    trk.lam = lam
    trk._expansion = expansion
    rates = s.body_rates_radps
    if type(rates) is _ndarray:
        rates = rates.tolist()
    uf = ctl.x13
    duf = ctl.x14
    ix, iy, iz = ctl._ixyz
"""


def sources(*, rot: list[str], est: dict[str, Any], model_rows: list[str], rows: str,
            sigma2: list[str], after: list[str], att: list[str], tail: list[str]
            ) -> tuple[str, str]:
    """(``fused_core``'s source, the calling tick's source) from :func:`fused.build_fused`'s
    traced pieces; ``tail`` is the Python tick's tail without the attacked allocation."""
    return (_core(rot, est, model_rows, rows, sigma2, after, att),
            _TICK_HEAD + "\n".join(tail) + "\n")


def attach_native(ctl: Any, fused: FusedTick) -> None:
    """Fly ``ctl`` (a :class:`law.TFLController` flying ``fused.fn``) on the compiled core
    (:mod:`native`): now if it is cached or ``TFL_MAV_NATIVE=sync``, else (``auto``) when a
    background build completes. The compiled core gives the same bits, so when the switch
    happens changes nothing but the speed. What holds the GIL for long (the translation,
    compiling the calling tick) happens here, before the flight."""
    if native.mode() == "off" or not fused.core_source:
        return
    tick, namespace = fused.with_core(None)
    python_tick, ref = ctl._fused, weakref.ref(ctl)

    def ready(core: Callable[..., Any]) -> None:
        namespace["_core"] = core
        target = ref()
        if target is not None and target._fused is python_tick:
            target._fused = tick        # one reference store: atomic under the GIL

    core = native.obtain(fused.core_source, ready)
    if core is not None:
        ready(core)
