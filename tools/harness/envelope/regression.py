"""The regression rule: is a case's flight today worse than its baseline?

A case FAILS when

* it crashes (or the flight errors) and the baseline did not;
* its detected rotor differs from the baseline's, unless it is now the attacked rotor (a
  right detection where the baseline missed or named another rotor is an improvement);
* its max distance to the path over the last 10 s exceeds ``max(1.10 b, b + 0.05 mm)``,
  b the baseline's (the slack absorbs floating-point drift of a sub-millimetre flight
  without hiding a real loss); a non-finite distance where the baseline had one fails.

Improvements (a crash that no longer happens, a right detection, a distance below
``b − max(0.10 b, 0.05 mm)``) are reported, never fail. When either flight crashed the
distance is not compared: a crashed flight's is the distance before the crash, not a
tracking figure (a new crash fails by itself; a crash that became a flight off the path is
an improvement, whose distance the rewritten baseline then guards).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from tfl_mav.tools.harness.envelope.results import ERROR, CaseResult

__all__ = ["ABS_SLACK_M", "REL_SLACK", "Verdict", "judge", "worse_limit_m"]

REL_SLACK = 0.10
ABS_SLACK_M = 0.05e-3


@dataclass(frozen=True)
class Verdict:
    """``status``: "regressed" (fails), "improved", "same", or "new" (no baseline: fails,
    the baseline must be rewritten to take the case in); ``reasons`` in words."""

    status: str
    reasons: tuple[str, ...] = field(default=())

    @property
    def failed(self) -> bool:
        return self.status in ("regressed", "new")


def worse_limit_m(baseline_m: float) -> float:
    """The largest max distance that is not a regression against ``baseline_m``."""
    return max((1.0 + REL_SLACK) * baseline_m, baseline_m + ABS_SLACK_M)


def _finite(x: float | None) -> bool:
    return x is not None and math.isfinite(x)


def _mm(x: float | None) -> str:
    return f"{1000 * x:.3f} mm" if _finite(x) else "not finite"


def judge(now: CaseResult, baseline: CaseResult | None) -> Verdict:
    """Apply the rule (module docstring) to one case. Pure: no I/O, no flights."""
    if baseline is None:
        return Verdict("new", ("no baseline for this case: fly `tfl-mav envelope "
                               "--rewrite-baseline` to take it in",))
    if (baseline.base, tuple(baseline.settings)) != (now.base, tuple(now.settings)):
        return Verdict("new", ("the case changed since its baseline was flown: rewrite the "
                               "baseline",))
    worse: list[str] = []
    better: list[str] = []
    now_down = now.outcome in ("crashed", ERROR)
    base_down = baseline.outcome in ("crashed", ERROR)
    if now_down and not base_down:
        worse.append(f"{now.outcome} ({now.reason or 'no reason'}); the baseline "
                     f"{baseline.outcome}")
    elif base_down and not now_down:
        better.append(f"no longer {baseline.outcome}: {now.outcome}")
    if now.detected_rotor != baseline.detected_rotor:
        if now.detected_rotor == now.attack_rotor:
            better.append(f"detects rotor {now.detected_rotor} (baseline "
                          f"{baseline.detected_rotor})")
        else:
            worse.append(f"detected rotor {now.detected_rotor}, baseline "
                         f"{baseline.detected_rotor} (attacked: {now.attack_rotor})")
    if not (now_down or base_down) and _finite(baseline.max_distance_m):
        b = float(baseline.max_distance_m)  # type: ignore[arg-type]
        d = now.max_distance_m
        if not _finite(d):
            worse.append(f"max distance not finite, baseline {_mm(b)}")
        elif d > worse_limit_m(b):      # type: ignore[operator]
            worse.append(f"max distance {_mm(d)} > {_mm(worse_limit_m(b))} "
                         f"(baseline {_mm(b)})")
        elif d < b - max(REL_SLACK * b, ABS_SLACK_M):   # type: ignore[operator]
            better.append(f"max distance {_mm(d)}, baseline {_mm(b)}")
    elif not (now_down or base_down) and not _finite(baseline.max_distance_m) \
            and _finite(now.max_distance_m):
        better.append(f"max distance {_mm(now.max_distance_m)}, baseline not finite")
    if worse:
        return Verdict("regressed", tuple(worse + better))
    if better:
        return Verdict("improved", tuple(better))
    return Verdict("same")
