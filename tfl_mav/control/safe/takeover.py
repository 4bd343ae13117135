"""When the TFL law may fly a state: the take-over and hand-back tests of the flight computer.

The TFL law is started from hover, still, in every scenario; a state far from that is one
nobody has shown it converges from (:mod:`tfl_mav.controller.flight_computer` says how the limits
were measured). :func:`not_benign` says why a state may not be taken over by the TFL law (a
controller restarted mid-flight, or the safe law flying back); :func:`calm_fail` is the
stricter attitude test a hand-back from the safe law must also pass. Both read the state's
floats (a numpy array's as ``tolist``), and run on every safe-law tick.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from tfl_mav.model.state import State

__all__ = ["A_HANDBACK_N", "HANDBACK_TILT_RAD", "TAKEOVER_RATE_RADPS", "TAKEOVER_SPEED_FACTOR",
           "TAKEOVER_SPEED_FLOOR_MPS", "TAKEOVER_TILT_RAD", "calm_fail", "floats",
           "not_benign", "tilt_rad"]

TAKEOVER_TILT_RAD = math.radians(30.0)
TAKEOVER_RATE_RADPS = 2.0
TAKEOVER_SPEED_FACTOR = 2.0      # TFL takes over up to this × path speed
TAKEOVER_SPEED_FLOOR_MPS = 0.5   # … never below this (a slow path; velocity noise at rest)
HANDBACK_TILT_RAD = math.radians(20.0)
# Hand back when TFL can make τ_p ∈ [−lA, l(f_max − A)] of both signs with this margin on
# A (N): −0.16 N m at A = 0.6 N, a roll acceleration of 80 rad/s² on the paper vehicle.
A_HANDBACK_N = 0.6


def floats(x: Sequence[float]) -> Sequence[float]:
    """``x`` with Python floats (``tolist`` of a numpy array; other sequences as they are)."""
    return x.tolist() if type(x) is np.ndarray else x


def tilt_rad(q: Sequence[float]) -> float:
    """Angle between b3 and the vertical: acos of R₂₂ of the normalised quaternion, by the
    very operations :func:`~tfl_mav.model.geometry.rotation_rows` computes R₂₂ with (the other
    eight entries are not needed)."""
    w, x, y, z = floats(q)
    n = math.sqrt(w * w + x * x + y * y + z * z)
    x, y = x / n, y / n
    return math.acos(max(-1.0, min(1.0, 1 - 2 * (x * x + y * y))))


def not_benign(state: State, rotor: int, speed_mps: float) -> str:
    """Why ``state`` is not one the TFL law may be started from ('' if it is); ``rotor``:
    the attacked rotor (0: none), ``speed_mps``: the path speed flown. The yaw rate is not
    tested: yaw is the TFL law's internal dynamics (eq. (25)), and it flies a start spinning
    at 10 rad/s as it flies one at rest."""
    tilt = tilt_rad(state.quaternion_wxyz)
    p, q, r = floats(state.body_rates_radps)
    speed = math.sqrt(sum(c * c for c in floats(state.velocity_mps)))
    vmax = max(TAKEOVER_SPEED_FLOOR_MPS, TAKEOVER_SPEED_FACTOR * speed_mps)
    if not all(math.isfinite(c) for c in (tilt, p, q, r, speed)):
        return "state not finite"
    if tilt > TAKEOVER_TILT_RAD:
        return f"tilted {math.degrees(tilt):.0f} deg"
    if speed > vmax:
        return f"moving at {speed:.1f} m/s (TFL takes over below {vmax:.1f} m/s)"
    if math.hypot(p, q) > TAKEOVER_RATE_RADPS:
        return f"rolling/pitching at {math.hypot(p, q):.1f} rad/s"
    return ""


def calm_fail(state: State) -> bool:
    """True while the attitude is not calm enough to hand back to the TFL law (tilt and
    roll/pitch rate; a yaw spin is its internal dynamics)."""
    tilt = tilt_rad(state.quaternion_wxyz)
    p, q, _ = floats(state.body_rates_radps)
    return tilt > HANDBACK_TILT_RAD or math.hypot(p, q) > TAKEOVER_RATE_RADPS
