"""A flight as time series, and the summary metrics every tool prints.

The offline runner fills a :class:`FlightLog` sample by sample; ``inspect``/``report``
rebuild one from an MCAP file. :func:`summarize` turns either into the same metrics, so a
number in the demo summary and the same number recomputed from the log agree by construction;
the verdict numbers (convergence, detection, saturation) come from
:mod:`tfl_mav.flightlog.metrics`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from tfl_mav.flightlog import metrics
from tfl_mav.model.modes import Mode

__all__ = ["FlightLog", "summarize"]

SERIES = (
    "t_s",                      # sim time (s)
    "position_m",               # (N,3) true position, paper frame z up
    "velocity_mps",             # (N,3)
    "body_rates_radps",         # (N,3) (p, q, r)
    "yaw_rad",                  # (N,) ψ, unwrapped
    "path_distance_m",          # (N,) distance to the path
    "thrust_cmd_n",             # (N,4) commanded rotor thrusts (after saturation)
    "thrust_req_n",             # (N,4) what the law asked for, before clamping to [0, f_max]
                                # (may be empty: logs that predate it, or read from MCAP)
    "thrust_true_n",            # (N,4) true rotor thrusts
    "attack_true_n",            # (N,) applied attack thrust (0 when none)
    "attack_estimate_n",        # (N,) controller's estimate (NaN when none)
    "uf_n",                     # (N,) total thrust u_f
    "torque_nm",                # (N,3) (τ_p, τ_q, τ_r) from the true thrusts
    "saturated",                # (N,) any rotor command saturated
    "mode",                     # (N,) int(tfl_mav.model.modes.Mode)
)



@dataclass
class FlightLog:
    """Time series of one flight (lists while recording, arrays after :meth:`finish`)."""

    data: dict[str, Any] = field(default_factory=lambda: {k: [] for k in SERIES})
    crashed: bool = False
    crash_reason: str = ""
    attack_rotor: int = 0
    attack_start_s: float = math.nan
    thrust_max_n: float = 8.0
    wall_time_s: float = 0.0
    path_points_m: np.ndarray | None = None
    events: list[tuple[float, str]] = field(default_factory=list)
    # For the verdict (tfl_mav.flightlog.metrics): the requested length, whether the run
    # was cut short, and the controller's detected rotor per sample (None: not recorded).
    duration_s: float | None = None
    interrupted: bool = False
    detected_rotor: np.ndarray | None = None
    # The flight's logs end before the flight did (a recorder killed, a full disk): one
    # entry a file, {"file", "role" ("vehicle"/"controller"), "at_s", "reason"}; None: whole.
    log_cut: list[dict[str, Any]] | None = None

    def append(self, **sample: Any) -> None:
        for k, v in sample.items():
            self.data[k].append(v)

    def append_row(self, row: tuple[Any, ...]) -> None:
        """One sample, values in :data:`SERIES` order (the offline loop's per-tick call:
        no keyword dict built every tick)."""
        data = self.data
        for key, value in zip(SERIES, row, strict=True):
            data[key].append(value)

    def finish(self) -> FlightLog:
        for k in SERIES:
            self.data[k] = np.asarray(self.data[k], dtype=float)
        return self

    def __getitem__(self, key: str) -> np.ndarray:
        return self.data[key]


def _last_window(t: np.ndarray, window_s: float) -> np.ndarray:
    return t >= (t[-1] - window_s) if len(t) else np.zeros(0, dtype=bool)


def summarize(log: FlightLog) -> dict[str, Any]:
    """The metrics of the ``offline --json`` contract (SI units in every name)."""
    t = log["t_s"]
    dist = log["path_distance_m"]
    if len(t) == 0:
        return {"crashed": log.crashed, "crash_reason": log.crash_reason, "sim_time_s": 0.0}
    last = _last_window(t, 10.0)
    cmd = log["thrust_cmd_n"]
    req = log.data.get("thrust_req_n")
    if req is not None and len(req) == len(t):
        cmd = req       # a request outside [0, f_max] must show: it is a violation
    att = log["attack_true_n"]
    attacked = att[log["attack_true_n"] > -1] if len(att) else att
    active = t >= log.attack_start_s if math.isfinite(log.attack_start_s) else np.zeros_like(t,
                                                                                          bool)
    rates = log["body_rates_radps"]

    def f(x: float) -> float | None:
        return float(x) if math.isfinite(x) else None

    return {
        "crashed": bool(log.crashed),
        "crash_reason": log.crash_reason,
        "sim_time_s": float(t[-1]),
        "final_path_distance_m": f(dist[-1]),
        "max_path_distance_last_10s_m": f(np.max(dist[last])),
        "rms_path_distance_last_10s_m": f(math.sqrt(float(np.mean(dist[last] ** 2)))),
        "thrust_min_n": float(np.min(cmd)),
        "thrust_max_n": float(np.max(cmd)),
        "saturated_fraction": metrics.saturated_fraction(log["saturated"]),
        "attack_rotor": log.attack_rotor,
        "attack_min_n": f(np.min(attacked[active])) if np.any(active) else None,
        "attack_max_n": f(np.max(attacked[active])) if np.any(active) else None,
        "max_yaw_rate_radps": float(np.max(np.abs(rates[:, 2]))),
        "fallback_fraction": float(np.mean(log["mode"] == int(Mode.FALLBACK))),
        **metrics.law_report(t, log["mode"], log.detected_rotor),
        "wall_time_s": round(log.wall_time_s, 3),
        "real_time_factor": round(float(t[-1]) / log.wall_time_s, 2) if log.wall_time_s else None,
        **metrics.flight_verdict(log),
    }
