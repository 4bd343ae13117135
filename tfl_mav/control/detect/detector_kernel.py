"""The detector's four-rotor tick as generated code: one rotor's template,
expanded for the four rotors (:class:`detector.AttackDetector` runs it every tick).

:func:`rotors_source` writes it as a method-like function on the detector's state
(``self``), or — ``pure=True`` — as one pure function of that state's numbers returning the
new state, which :mod:`native` compiles to C (:mod:`detector_native`). Both are the same
lines of the same template, so the same floating-point operations in the same order.
"""

from __future__ import annotations

import linecache
import math
from collections.abc import Callable
from typing import Any

__all__ = ["BAND_PAD", "N_MODELS", "RADPS_TO_RPM", "RPM_TO_RADPS", "STATE", "python_kernel",
           "rotors_source"]

RPM_TO_RADPS = 2.0 * math.pi / 60.0
RADPS_TO_RPM = 60.0 / (2.0 * math.pi)
# The band of 5 models (τ spaced geometrically over [τ/(1+tol), τ(1+tol)]) is widened by this
# fraction of its width on each side: ω(t; τ) is not monotone in τ under a varying command,
# and on random sines, chirps and 0↔f_max square waves (τ = 5-80 ms, tol = 0.3) the response
# for any τ in the range never left the band widened by 0.1 (0.25 keeps a margin).
BAND_PAD = 0.25
N_MODELS = 5   # lag models of the band (τ spaced geometrically)

# One rotor's tick; ``{i}`` is the rotor (0-3). Expanded for the four rotors into one function
# on first use: straight-line float code on locals (no per-rotor loop, list or index on the hot
# path), the constants as literals. min/max and the clamps are written as the comparisons
# the builtins make (the same results).
_PROPAGATE = """\
    if lagged:      # the lag solution with the command held
        c = c{i}
        c = 0.0 if c < 0.0 else c
        c = sqrt((fmax if fmax < c else c) / k_f)
        w{i}_0 = c + (w{i}_0 - c) * e0
        w{i}_1 = c + (w{i}_1 - c) * e1
        w{i}_2 = c + (w{i}_2 - c) * e2
        w{i}_3 = c + (w{i}_3 - c) * e3
        w{i}_4 = c + (w{i}_4 - c) * e4
        v{i} *= e44                     # the slowest model forgets slowest
"""
_NEAREST_IN_BAND = """\
        lo = w{i}_0
        lo = w{i}_1 if w{i}_1 < lo else lo
        lo = w{i}_2 if w{i}_2 < lo else lo
        lo = w{i}_3 if w{i}_3 < lo else lo
        lo = w{i}_4 if w{i}_4 < lo else lo
        hi = w{i}_0
        hi = w{i}_1 if w{i}_1 > hi else hi
        hi = w{i}_2 if w{i}_2 > hi else hi
        hi = w{i}_3 if w{i}_3 > hi else hi
        hi = w{i}_4 if w{i}_4 > hi else hi
        pad = {BAND_PAD!r} * (hi - lo)
        wm = r{i} * {RPM_TO_RADPS!r}
        w = lo - pad
        w = w if w > wm else wm
        lim = hi + pad
        w = lim if lim < w else w       # nearest speed in the band
        z = (r{i} - w * {RADPS_TO_RPM!r}) / sqrt(sig2 + v{i})
"""
# Without lag the band is the command's speed alone (lo = hi, no pad: nearest is that speed)
# and the start's variance stays 0: its std is sqrt(σ² + 0), once.
_INSTANT = """\
        c = c{i}
        c = 0.0 if c < 0.0 else c
        w = sqrt((fmax if fmax < c else c) / k_f)
        wm = r{i} * {RPM_TO_RADPS!r}
        z = (r{i} - w * {RADPS_TO_RPM!r}) / sd
"""
_CUSUM = """\
        zc = ncap if ncap > z else z
        zc = cap if cap < zc else zc
        s = h{i} + zc - k
        h{i} = s if s > 0.0 else 0.0
        s = l{i} - zc - k
        l{i} = s if s > 0.0 else 0.0
        z{i} = z
        m{i} = r{i}
        q{i} = k_f * (wm * wm - w * w)
"""
_SKIP_NAN = """\
    if r{i} != r{i}:                    # NaN: skipped (counted)
        {reject}
    else:
"""


def _four(fmt: str, sep: str = ", ") -> str:
    return sep.join(fmt.format(i=i) for i in range(4))


_STATE = ("_s_hi", "h"), ("_s_lo", "l"), ("_z", "z"), ("_rpm", "m"), ("_resid", "q")
_TOP = f"""\
{_four("    x{i} = h{i} if h{i} > l{i} else l{i}", chr(10))}
{{latched}}
    if d:
{_four("        x{i} = 0.0 if d == {i} + 1 else x{i}", chr(10))}
    top = x0
{"".join(f"    top = x{i} if x{i} > top else top{chr(10)}" for i in range(1, 4))}\
"""


#: The detector's per-rotor state tuples: (attribute, the template's name, the pure
#: function's parameter).
STATE = (("_s_hi", "h", "s_hi"), ("_s_lo", "l", "s_lo"), ("_z", "z", "zs"),
         ("_rpm", "m", "rpm"), ("_resid", "q", "resid"))
_VAR = ("_var", "v", "var")


def rotors_source(lagged: bool, pure: bool = False) -> str:
    """The source of ``_rotors_lagged(det, r0…r3, c0…c3, decay) -> top`` (``decay``: the
    models' exp(−dt/τ_j), None on the first tick) or ``_rotors_instant(det, r0…r3, c0…c3)
    -> top``: the four rotors' tick on ``det``'s state, returning the largest statistic
    among the rotors that may alarm (the latched rotor left out as a 0: statistics are
    ≥ 0). ``pure``: ``rotors_core(<the state's numbers>, d, r0…r3, c0…c3[, decay]) ->
    (top, rejected samples, the new state tuples)``, writing nothing."""
    consts = {"BAND_PAD": BAND_PAD, "RPM_TO_RADPS": RPM_TO_RADPS,
              "RADPS_TO_RPM": RADPS_TO_RPM}
    state = list(STATE)
    band = ", ".join(f"w{i}_{j}" for i in range(4) for j in range(N_MODELS))
    rotor_args = "r0, r1, r2, r3, c0, c1, c2, c3"
    if lagged:
        state += [_VAR]
        if pure:
            head = f"""\
def rotors_core(band, sig2, {', '.join(p for _, _, p in state)}, k, cap, k_f, d, {rotor_args},
                decay):
    {band} = band
    lagged = decay is not None
    if lagged:
        e0, e1, e2, e3, e4 = decay
        e44 = e4 * e4
"""
        else:
            head = f"""\
def _rotors_lagged(self, {rotor_args}, decay):
    {band} = self._band
    sig2 = self._sig2
    lagged = decay is not None
    if lagged:
        fmax = self.thrust_max_n
        e0, e1, e2, e3, e4 = decay
        e44 = e4 * e4
"""
        rotor = _PROPAGATE + _SKIP_NAN + _NEAREST_IN_BAND + _CUSUM
        tail = "" if pure else f"    self._band = ({band})\n"
    else:
        if pure:
            head = f"""\
def rotors_core(sd, {', '.join(p for _, _, p in state)}, k, cap, k_f, d, {rotor_args}):
"""
        else:
            head = f"""\
def _rotors_instant(self, {rotor_args}):
    fmax = self.thrust_max_n
    sd = self._sd0
"""
        rotor = _SKIP_NAN + _INSTANT + _CUSUM
        tail = ""
    if pure:
        head = head.replace("(band, sig2,", "(band, sig2, fmax,").replace("(sd,", "(sd, fmax,")
        loads = "".join(f"    {_four(v + '{i}')} = {p}\n" for _, v, p in state)
        params = "    ncap = -cap\n    nrej = 0.0\n"
        reject, latched = "nrej += 1.0", ""
        results = ", ".join(f"({_four(v + '{i}')})" for _, v, _ in state)
        end = (f"    return (top, nrej{', (' + band + ')' if lagged else ''}, {results})\n")
    else:
        loads = "".join(f"    {_four(v + '{i}')} = self.{attr}\n" for attr, v, _ in state)
        params = "    k = self.k\n    cap = self.z_cap\n    ncap = -cap\n    k_f = self.k_f\n"
        reject, latched = "self.rejected_samples += 1", "    d = self.detected_rotor"
        end = "    return top\n"
    stores = "" if pure else "".join(f"    self.{attr} = ({_four(v + '{i}')})\n"
                                     for attr, v, _ in state)
    source = (head + loads + params
              + "".join(rotor.format(i=i, reject=reject, **consts) for i in range(4))
              + tail + stores + _TOP.format(latched=latched).replace("\n\n", "\n") + end)
    return source.replace("sqrt(", "_sqrt(") if pure else source


_KERNELS: dict[bool, Callable[..., float]] = {}


def python_kernel(lagged: bool) -> Callable[..., float]:
    """The generated kernel, compiled on first use (a process flies one kind: ~2 ms each)."""
    fn = _KERNELS.get(lagged)
    if fn is None:
        src = rotors_source(lagged)
        name = f"<tfl_mav.control.detect.detector._rotors_{'lagged' if lagged else 'instant'}>"
        linecache.cache[name] = (len(src), None, src.splitlines(True), name)  # tracebacks
        scope: dict[str, Any] = {"sqrt": math.sqrt}
        exec(compile(src, name, "exec"), scope)  # our own template
        fn = _KERNELS[lagged] = scope[name[len("<tfl_mav.control.detect.detector."):-1]]
    return fn
