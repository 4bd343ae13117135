"""A flight's verdict numbers, computed one way for every tool (one source of truth).

``tfl-mav demo``, ``report``, ``inspect``, ``offline`` and the campaigns all get
detection, false alarms, saturation and convergence from here, on the same data, so they
agree exactly (tests/test_metrics_agree.py flies a demo and compares all three).

* **Convergence** (:func:`converged`): the flight converged when the distance to the path
  ‖y‖_γ stayed ≤ ``bound_m`` over the last ``window_s`` of sim time. Defaults 2 cm over
  10 s. *Clipping rule*: a flight shorter than twice the window is judged on its second
  half (``window = min(window_s, length / 2)``), so a short flight is never judged on its
  first metres of transient. A crashed, interrupted (shorter than its requested duration)
  or empty flight, or one with a non-finite distance in the window, never converged. A
  flight whose vehicle log was cut short (``FlightLog.log_cut``) is not judged: the
  verdict is False and says where the log ends and why.
* **Detection** (:func:`detection`) from the controller's per-tick ``detected_rotor``
  (``/controller/state``): an *alarm* is a rising edge 0 → rotor. The detection is the
  first alarm at or after the attack start; a *false alarm* is an alarm before the attack
  starts, with no attack at all, or naming another rotor than the attacked one.
* **Saturation** (:func:`saturated_fraction`): the fraction of control ticks on which the
  controller's allocation saturated (its ``saturated`` flag). Ticks with no controller
  record are unknown, not "unsaturated": without the controller's log the fraction is None.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

__all__ = [
    "DEFAULT_BOUND_M",
    "DEFAULT_WINDOW_S",
    "Convergence",
    "converged",
    "detection",
    "detection_events",
    "detection_from_alarms",
    "flight_verdict",
    "law_report",
    "law_text",
    "median",
    "saturated_fraction",
]

DEFAULT_WINDOW_S = 10.0
DEFAULT_BOUND_M = 0.02


@dataclass(frozen=True)
class Convergence:
    """The verdict of :func:`converged` and what it was judged on."""

    converged: bool
    bound_m: float
    window_s: float                 # the window actually used (after clipping)
    max_distance_m: float | None    # max ‖y‖_γ over that window (None: no finite sample)
    reason: str                     # "converged (≤ 0.020 m over the last 10.0 s)" or why not

    def as_dict(self) -> dict[str, Any]:
        return {f"convergence_{k}" if k != "converged" else k: v
                for k, v in asdict(self).items()}


def converged(t_s: Sequence[float] | np.ndarray, distance_m: Sequence[float] | np.ndarray, *,
              bound_m: float = DEFAULT_BOUND_M, window_s: float = DEFAULT_WINDOW_S,
              duration_s: float | None = None, crashed: bool = False,
              interrupted: bool = False, dt_s: float = 0.0) -> Convergence:
    """Did the flight converge? See the module docstring for the rule.

    ``duration_s``: the requested flight length; a log ending more than 1.5 ``dt_s`` (control
    periods) short of it was interrupted. ``crashed``/``interrupted``: what the caller knows.
    """
    t = np.asarray(t_s, dtype=float)
    d = np.asarray(distance_m, dtype=float)
    length = float(t[-1] - t[0]) if len(t) else 0.0
    window = min(window_s, length / 2.0)

    def verdict(ok: bool, max_d: float | None, reason: str) -> Convergence:
        return Convergence(ok, bound_m, window, max_d, reason)

    if len(t) == 0:
        return verdict(False, None, "not converged: no samples")
    last = d[t >= t[-1] - window]
    max_d = float(np.max(last)) if np.all(np.isfinite(last)) else None
    if crashed:
        return verdict(False, max_d, "not converged: the vehicle crashed")
    # The last sample may be one period before the end (the state the last command
    # answered): 1.5 periods of slack, so only a genuinely shortened run counts.
    ended_early = (duration_s is not None
                   and float(t[-1]) < duration_s - 1.5 * max(dt_s, 1e-6))
    if interrupted or ended_early:
        of = f" of {duration_s:g} s" if duration_s is not None else ""
        return verdict(False, max_d, f"not converged: interrupted at t = {t[-1]:.3f} s{of}")
    if max_d is None:
        return verdict(False, None, "not converged: path distance not finite (diverged)")
    over = f"over the last {window:.1f} s"
    if max_d <= bound_m:
        return verdict(True, max_d, f"converged (≤ {bound_m:g} m {over})")
    return verdict(False, max_d, f"not converged: {max_d:.4f} m > {bound_m:g} m {over}")


def detection(t_s: Sequence[float], detected_rotor: Sequence[int], attack_rotor: int,
              attack_start_s: float | None) -> dict[str, Any]:
    """Detection metrics from the controller's per-tick ``detected_rotor`` (0 = none).

    ``attack_rotor`` 0 = no attack; ``attack_start_s`` None when unknown (then every alarm
    is judged only by its rotor). Keys: detected_rotor, detection_time_s,
    detection_latency_s, detection_correct (None without an attack), false_alarms,
    missed_detection.
    """
    alarms = []
    prev = 0
    for t, r in zip(t_s, detected_rotor, strict=True):
        r = int(r or 0)
        if r and not prev:
            alarms.append((float(t), r))
        prev = r
    return detection_from_alarms(alarms, attack_rotor, attack_start_s)


def detection_from_alarms(alarms: Sequence[tuple[float, int]], attack_rotor: int,
                          attack_start_s: float | None) -> dict[str, Any]:
    """:func:`detection` from the alarms themselves, (time s, rotor 1-4) in order — what an
    offline flight's events hold (no per-tick series)."""
    start = attack_start_s if attack_start_s is not None and math.isfinite(
        attack_start_s) else None
    late = [a for a in alarms if attack_rotor and (start is None or a[0] >= start - 1e-9)]
    first = late[0] if late else None
    false_alarms = sum(1 for a in alarms
                       if not attack_rotor or a[1] != attack_rotor
                       or (start is not None and a[0] < start - 1e-9))
    return {
        "detected_rotor": first[1] if first else 0,
        "detection_time_s": first[0] if first else None,
        "detection_latency_s": (first[0] - start if first and start is not None else None),
        "detection_correct": (bool(first and first[1] == attack_rotor) if attack_rotor
                              else None),
        "false_alarms": false_alarms,
        "missed_detection": bool(attack_rotor) and first is None,
    }


# The flight log's mode (tfl_mav.model.modes.Mode) → the law that flew: TFL (nominal,
# attacked, and its own fallback damping), the safe law (recovery, lost_rotor), or nothing
# (failsafe: the daemon had no state).
_LAW_OF_MODE = {0: "tfl", 1: "tfl", 2: "tfl", 3: "failsafe", 4: "recovery", 5: "lost_rotor",
                6: "spin"}
LAWS = ("tfl", "recovery", "lost_rotor", "spin", "failsafe")


def detection_events(t_s: Sequence[float], detected_rotor: Sequence[int]
                     ) -> tuple[list[tuple[float, int]], list[tuple[float, int]]]:
    """Every detection and every release of the controller's per-tick ``detected_rotor``
    (0 = none), as (time s, rotor 1-4): a change from a to b releases a (if any) and
    detects b (if any)."""
    detections: list[tuple[float, int]] = []
    releases: list[tuple[float, int]] = []
    prev = 0
    for t, r in zip(t_s, detected_rotor, strict=True):
        r = int(r or 0)
        if r != prev:
            if prev:
                releases.append((float(t), prev))
            if r:
                detections.append((float(t), r))
        prev = r
    return detections, releases


def law_report(t_s: Sequence[float] | np.ndarray, mode: Sequence[float] | np.ndarray,
               detected_rotor: Sequence[int] | None = None) -> dict[str, Any]:
    """Which law flew, from the per-tick mode: the time in each law (s), the share of the
    flight a law other than TFL flew (the safe law, the spin law), the number of switches
    between TFL, the safe law and the spin law, and —
    with the controller's detections — every detection and release (time s, rotor).

    Each tick counts for the period until the next one (the last: the median period)."""
    t = np.asarray(t_s, dtype=float)
    m = np.asarray(mode, dtype=float)
    n = min(len(t), len(m))
    t, m = t[:n], m[:n]
    out: dict[str, Any] = {}
    if n == 0:
        return {"time_in_law_s": dict.fromkeys(LAWS, 0.0), "safe_law_fraction": None,
                "law_switches": 0}
    dt = np.diff(t)
    dt = np.append(dt, median(dt) if len(dt) else 0.0)
    known = np.isfinite(m)
    codes = np.where(known, m, -1).astype(int)
    times = dict.fromkeys(LAWS, 0.0)
    for code, law in _LAW_OF_MODE.items():
        times[law] += float(np.sum(dt[codes == code]))
    total = sum(times.values())
    # The law flying, by tick: TFL 0, the safe law 1 (four or three rotors: one law), the
    # spin law 2; a failsafe tick (no state) keeps the law before it.
    group = np.select([codes <= 2, (codes == 4) | (codes == 5), codes == 6], [0, 1, 2], -1)
    group = group[group >= 0]
    switches = int(np.count_nonzero(group[1:] != group[:-1])) if len(group) > 1 else 0
    out["time_in_law_s"] = {k: round(v, 6) for k, v in times.items()}
    out["safe_law_fraction"] = ((times["recovery"] + times["lost_rotor"] + times["spin"])
                                / total if total > 0 else None)
    out["law_switches"] = switches
    if detected_rotor is not None and len(detected_rotor) >= n:
        det, rel = detection_events(t, list(detected_rotor)[:n])
        out["detections"] = [[round(a, 6), b] for a, b in det]
        out["releases"] = [[round(a, 6), b] for a, b in rel]
    return out


def law_text(m: dict[str, Any]) -> str:
    """A summary's law report in one line: time in each law, switches, detections and
    releases ('' when the summary has none)."""
    times = m.get("time_in_law_s")
    if not times:
        return ""
    parts = [f"{law} {times[law]:.1f} s" for law in LAWS if times.get(law)]
    text = ", ".join(parts) or "none"
    text += f"; {m.get('law_switches', 0)} switches"
    for key, word in (("detections", "detected"), ("releases", "released")):
        events = m.get(key) or []
        if events:
            shown = ", ".join(f"rotor {r} at {t:.2f} s" for t, r in events[:4])
            more = f" (+{len(events) - 4} more)" if len(events) > 4 else ""
            text += f"; {word} {shown}{more}"
    return text


def saturated_fraction(flags: Sequence[float] | np.ndarray) -> float | None:
    """Fraction of ticks with a saturated allocation; NaN entries (no controller record
    for that tick) are left out; None when no tick is known."""
    f = np.asarray(flags, dtype=float)
    known = f[np.isfinite(f)]
    return float(np.mean(known != 0.0)) if len(known) else None


def median(x: np.ndarray) -> float:
    """``np.median`` to the bit (the middle two averaged as it does), without the
    ``numpy.ma`` import it triggers (~12 ms of every ``tfl-mav offline`` start-up)."""
    n = len(x)
    k = n // 2
    if n % 2:
        return float(np.partition(x, k)[k])
    part = np.partition(x, (k - 1, k))
    return float((part[k - 1] + part[k]) / 2.0)


def flight_verdict(log: Any, *, bound_m: float = DEFAULT_BOUND_M,
                   window_s: float = DEFAULT_WINDOW_S) -> dict[str, Any]:
    """Convergence and (if the controller's detections are in the log) detection of a
    :class:`~tfl_mav.flightlog.flight.FlightLog`: the keys every summary carries."""
    t = log["t_s"]
    dt = median(np.diff(t)) if len(t) > 1 else 0.0
    conv = converged(t, log["path_distance_m"], bound_m=bound_m, window_s=window_s,
                     duration_s=log.duration_s, crashed=log.crashed,
                     interrupted=log.interrupted, dt_s=dt)
    cut = next((c for c in log.log_cut or () if c.get("role") == "vehicle"), None)
    if cut is not None and not log.crashed:
        # the truth stops where the log does, not where the flight did: no verdict on it
        at = cut.get("at_s")
        of = f" of {log.duration_s:g} s" if log.duration_s is not None else ""
        where = f" at t = {at:.3f} s{of}" if at is not None else ""
        conv = Convergence(False, bound_m, conv.window_s, conv.max_distance_m,
                           f"not judged: the vehicle's log {cut['file']} was cut short"
                           f"{where} ({cut['reason']})")
    out = {**conv.as_dict(), "convergence": conv.reason}
    if log.log_cut:
        out["log_cut_short"] = log.log_cut
    if log.detected_rotor is not None:
        start = log.attack_start_s if math.isfinite(log.attack_start_s) else None
        out.update(detection(t, log.detected_rotor, log.attack_rotor, start))
    return out
