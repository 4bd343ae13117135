"""The attitude numbers the supervisor's take-over and hand-back tests read.

The TFL law is started from hover, still, in every scenario; a state far from that is one
nobody has shown it converges from (:mod:`tfl_mav.controller.supervisor` holds the tests and
says how the limits were measured). :func:`tilt_rad` is the tilt those tests read.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

__all__ = ["A_HANDBACK_N", "HANDBACK_TILT_RAD", "TAKEOVER_RATE_RADPS", "TAKEOVER_SPEED_FACTOR",
           "TAKEOVER_SPEED_FLOOR_MPS", "TAKEOVER_TILT_RAD", "floats", "tilt_rad"]

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
