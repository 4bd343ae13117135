"""Controllers side by side: the same scenario and seeds, the attack found from rpm by all.

Each controller flies through the public API (:class:`~tfl_mav.api.Environment`,
``attack_info="detector"``): ``tfl`` is the project's flight computer, ``se3`` and
``cascade`` the baselines (:mod:`tfl_mav.baselines`), anything else ``module:Name`` or
``file.py:Name``. Every flight is judged on the same numbers, computed here from its arrays
(the true path distance, computed after the flight the same way for all):

* crashed (and when), or failed (the software's one-line reason);
* max and RMS path distance over the last 10 s flown; the max over the whole flight after
  its first 5 s and the distance at its end (how far it escaped: a vehicle that climbs away
  from a rotor pinned above m g/2 ends hundreds of metres off, one that crashes where it
  crashed);
* time on path: the fraction of the *requested* duration spent within ``on_path_m`` of the
  path (a crash costs the rest of the flight);
* the commanded thrust range (N) and the detection (rotor, time).
"""

from __future__ import annotations

import csv
import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from tfl_mav.api import Environment, FlightArrays
from tfl_mav.controller.software import load_flight_software
from tfl_mav.scenario import Scenario

__all__ = ["DEFAULT_CONTROLLERS", "ON_PATH_M", "Result", "check_controllers", "fly_all",
           "plot", "result", "table", "write_csv"]

DEFAULT_CONTROLLERS = ("tfl", "se3", "cascade")
ON_PATH_M = 0.05          # "on the path": within 5 cm
WINDOW_S = 10.0


@dataclass(frozen=True)
class Result:
    """One flight's numbers (SI units in the names; NaN where a number does not exist)."""

    controller: str
    seed: int
    crashed: bool
    end_s: float                     # sim time of the last tick flown (s)
    reason: str                      # the crash or failure in words ("" when neither)
    max_distance_last_10s_m: float
    rms_distance_last_10s_m: float
    time_on_path_fraction: float
    thrust_min_n: float
    thrust_max_n: float
    detected_rotor: int
    detection_time_s: float
    max_distance_after_5s_m: float = math.nan   # the whole flight after its first 5 s
    final_distance_m: float = math.nan          # where it ended: the escape distance

    @property
    def failed(self) -> bool:
        return bool(self.reason) and not self.crashed


def result(controller: str, seed: int, flight: FlightArrays, duration_s: float,
           on_path_m: float = ON_PATH_M) -> Result:
    """The numbers of one flight (see the module docstring)."""
    t, dist = flight.t_s, flight.path_distance_m
    if len(t) == 0:
        return Result(controller, seed, flight.crashed, 0.0,
                      flight.crash_reason or flight.failure_reason or "", *[math.nan] * 5,
                      0, math.nan)
    late = t >= t[-1] - WINDOW_S
    d = dist[late]
    dt = flight.t_s[1] - flight.t_s[0] if len(t) > 1 else 0.0
    on = float(np.count_nonzero(dist <= on_path_m)) * dt / duration_s
    cmd = flight.thrust_cmd_n
    return Result(
        controller=controller, seed=seed, crashed=flight.crashed, end_s=float(t[-1]),
        reason=flight.crash_reason if flight.crashed else (flight.failure_reason or ""),
        max_distance_last_10s_m=float(np.nanmax(d)) if np.any(np.isfinite(d)) else math.nan,
        rms_distance_last_10s_m=float(math.sqrt(np.nanmean(d ** 2)))
        if np.any(np.isfinite(d)) else math.nan,
        time_on_path_fraction=min(on, 1.0), thrust_min_n=float(cmd.min()),
        thrust_max_n=float(cmd.max()), detected_rotor=int(flight.detected_rotor.max()),
        detection_time_s=float(flight.detection_time_s),
        max_distance_after_5s_m=_nanmax(dist[t >= 5.0]),
        final_distance_m=float(dist[-1]) if math.isfinite(dist[-1]) else _nanmax(dist[-10:]))


def _nanmax(x: np.ndarray) -> float:
    return float(np.nanmax(x)) if np.any(np.isfinite(x)) else math.nan


def check_controllers(names: Sequence[str]) -> None:
    """FlightSoftwareError (one line) for a name that is neither built in nor loadable."""
    for name in names:
        if name != "tfl":
            load_flight_software(name)


def fly_all(scenario: Scenario, controllers: Sequence[str], seeds: Sequence[int], *,
            duration_s: float | None = None, on_path_m: float = ON_PATH_M,
            progress: Any = None) -> tuple[list[Result], dict[str, FlightArrays]]:
    """Every controller on every seed; the results and each controller's first flight."""
    duration = scenario.run.duration_s if duration_s is None else duration_s
    results, first = [], {}
    for name in controllers:
        software = None if name == "tfl" else load_flight_software(name)[1]
        for seed in seeds:
            sc = scenario.replace(**{"run.seed": int(seed)})
            flight = Environment(sc, software, name=name).fly(duration)
            results.append(result(name, int(seed), flight, duration, on_path_m))
            first.setdefault(name, flight)
            if progress is not None:
                progress(results[-1])
    return results, first


def _fmt(x: float, spec: str = ".3g") -> str:
    return "-" if not math.isfinite(x) else format(x, spec)


def table(results: Sequence[Result]) -> str:
    """One line per controller (over its seeds: crashes counted, the worst max, the mean
    RMS and time on path, the widest thrust range, the first detection)."""
    head = (f"{'controller':<12} {'crashed':>9} {'max 10s m':>10} {'rms 10s m':>10} "
            f"{'max >5s m':>10} {'escape m':>9} "
            f"{'on path':>8} {'thrust N':>13} {'detection':>16}")
    lines = [head, "-" * len(head)]
    names = list(dict.fromkeys(r.controller for r in results))
    for name in names:
        rs = [r for r in results if r.controller == name]
        n_crash = sum(r.crashed for r in rs)
        crashed = f"{n_crash}/{len(rs)}"
        if n_crash:
            crashed += f" @{min(r.end_s for r in rs if r.crashed):.1f}s"
        worst = max((r.max_distance_last_10s_m for r in rs), default=math.nan)
        rms = float(np.mean([r.rms_distance_last_10s_m for r in rs]))
        on = float(np.mean([r.time_on_path_fraction for r in rs]))
        lo, hi = min(r.thrust_min_n for r in rs), max(r.thrust_max_n for r in rs)
        det = [r for r in rs if r.detected_rotor]
        detection = (f"rotor {det[0].detected_rotor} @{det[0].detection_time_s:.3f}s"
                     if det else "none")
        whole = max((r.max_distance_after_5s_m for r in rs), default=math.nan)
        escape = max((r.final_distance_m for r in rs), default=math.nan)
        lines.append(f"{name:<12} {crashed:>9} {_fmt(worst):>10} {_fmt(rms):>10} "
                     f"{_fmt(whole):>10} {_fmt(escape):>9} "
                     f"{100 * on:>7.1f}% {f'[{lo:.2f}, {hi:.2f}]':>13} {detection:>16}")
        for r in rs:
            if r.failed:
                lines.append(f"  seed {r.seed}: FAILED: {r.reason}")
    return "\n".join(lines)


def write_csv(results: Sequence[Result], path: Path) -> None:
    """One row per flight (controller, seed)."""
    rows = [asdict(r) for r in results]
    with open(path, "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=list(rows[0]) if rows else ["controller"])
        writer.writeheader()
        writer.writerows(rows)


def plot(flights: dict[str, FlightArrays], path: Path, title: str) -> None:
    """Path distance vs time for each controller (its first seed), the attack underneath."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (top, bottom) = plt.subplots(2, 1, sharex=True, figsize=(9, 6),
                                      gridspec_kw={"height_ratios": [3, 1]})
    for name, f in flights.items():
        line, = top.semilogy(f.t_s, np.maximum(f.path_distance_m, 1e-6), label=name, lw=1.2)
        if f.crashed or f.failure_reason:
            top.plot(f.t_s[-1:], np.maximum(f.path_distance_m[-1:], 1e-6), "x",
                     color=line.get_color(), ms=10, mew=2)
        bottom.plot(f.t_s, f.attack_true_n, color=line.get_color(), lw=1.0)
    top.axhline(ON_PATH_M, color="0.6", ls=":", lw=1)
    top.set_ylabel("path distance (m)")
    top.set_title(f"{title}: path distance (x = crashed or failed)")
    top.legend(loc="upper right")
    top.grid(True, which="both", alpha=0.3)
    bottom.set_ylabel("attack (N)")
    bottom.set_xlabel("sim time (s)")
    bottom.grid(True, alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)

