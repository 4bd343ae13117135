"""The attack-class envelope: each failure family flown offline, with its bound.

Every case is the paper scenario (or the circle) with ``--set`` overrides, flown in-process by
:func:`tfl_mav.offline.fly_offline` with the attack found from ESC rpm (``detector``), as
the daemon does. For each case the table gives whether it crashed (and why), the path
distance over the last ``--window`` s (max), the maximum |yaw rate|, the modes the flight
computer flew, and the bound the case is meant to meet:

* ``ok ≤ B``: not crashed and the last-window path distance ≤ B (m);
* ``infeasible``: the pre-flight check (:func:`tfl_mav.controller.feasibility.check_scenario`)
  must warn; the flight itself only has to end safely (no crash).

Usage (from the repository root; a case takes ~1-2 × its sim time on an idle core)::

    python bench/bench_envelope.py [--only NAME ...] [--duration S] [--json FILE]
"""

from __future__ import annotations

import argparse
import json
import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from tfl_mav.flightlog.flight import summarize
from tfl_mav.model.modes import Mode
from tfl_mav.offline import fly_offline
from tfl_mav.scenario import apply_overrides, load_scenario


@dataclass
class Case:
    name: str
    scenario: str
    settings: list[str]
    bound_m: float | None               # last-window path distance bound; None = infeasible
    injections: list[tuple[float, int, int]] = field(default_factory=list)  # (t, rotor, type)
    note: str = ""


DEAD = ["attack.signal=off"]
CASES: list[Case] = [
    Case("dead rotor t=0, paper", "paper", DEAD, 0.5, note="A = 0 from t = 0"),
    Case("dead rotor t=5, paper", "paper", [*DEAD, "attack.start_s=5.0"], 0.5),
    Case("dead rotor t=0, circle", "circle", [*DEAD, "attack.start_s=0.0"], 0.5),
    Case("dead rotor t=5, circle", "circle", DEAD, 0.5),
    Case("constant 5 N rotor 2", "paper", ["attack.signal=constant", "attack.value_n=5.0"],
         None, note="5 N > 4.85 N: the top bend needs u_f < 2A"),
    Case("paper 1 m/s", "paper", ["path.speed_mps=1.0"], None,
         note="A reaches 4 N > 3.2 N allowed at 1 m/s"),
    Case("paper 250 Hz control", "paper", ["run.control_hz=250.0"], 0.05),
    Case("lag 20 ms + 100 rpm, no attack", "paper",
         ["attack.rotor=0", "vehicle.motor_time_constant_s=0.02", "vehicle.rpm_noise_std=100"],
         0.01),
    Case("lag 50 ms + 100 rpm, no attack", "paper",
         ["attack.rotor=0", "vehicle.motor_time_constant_s=0.05", "vehicle.rpm_noise_std=100"],
         0.01),
    Case("sensor noise x10", "paper",
         ["sensors.velocity_noise_std_mps=0.1", "sensors.rate_noise_std_radps=0.05"], 0.01),
    Case("paper 2 m/s, no attack", "paper", ["path.speed_mps=2.0", "attack.rotor=0"], None,
         note="flown at the highest feasible speed, 1.13 m/s"),
    Case("paper 250 Hz, A never dead", "paper-exact",
         ["run.control_hz=250.0", "attack.signal=2 + 0.5*sin(t)"], 0.002,
         note="bound speed x hold period = 2 mm"),
    Case("gyro range 2000 deg/s", "paper", ["sensors.gyro_range_radps=34.9"], 0.005),
    Case("attacker moves rotor 2->3", "paper",
         ["attack.signal=constant", "attack.value_n=1.5"], 0.05,
         injections=[(12.0, 3, 4)], note="INJECT_FAILURE on rotor 3 (WRONG) at 12 s"),
]


def _warnings(sc: Any) -> list[str]:
    try:
        from tfl_mav.controller.feasibility import check_scenario
    except ImportError:
        return []
    return check_scenario(sc)


def run_case(case: Case, duration_s: float, window_s: float) -> dict[str, Any]:
    sc = apply_overrides(load_scenario(case.scenario), [*case.settings,
                                                         f"run.duration_s={duration_s}"])
    warnings = _warnings(sc)
    pending = sorted(case.injections)

    def hook(sim: Any) -> None:
        while pending and sim.time_s >= pending[0][0] - 1e-9:
            _, rotor, kind = pending.pop(0)
            sim.inject_failure(rotor, kind)

    t0 = time.perf_counter()
    log = fly_offline(sc, attack_info="detector", hook=hook)
    wall = time.perf_counter() - t0
    s = summarize(log)
    t = log["t_s"]
    last = t >= t[-1] - window_s
    dist = log["path_distance_m"][last]
    dmax = float(np.max(dist)) if len(dist) else math.nan
    modes = sorted({str(Mode(int(m))) for m in np.unique(log["mode"])})
    crashed = bool(log.crashed)
    if case.bound_m is None:
        met = bool(warnings) and not crashed
        bound = "infeasible: warned, no crash"
    else:
        met = (not crashed) and sim_full(t, duration_s) and dmax <= case.bound_m
        bound = f"ok <= {case.bound_m * 1000:g} mm"
    return {"case": case.name, "crashed": crashed, "crash_reason": log.crash_reason,
            "sim_time_s": float(t[-1]), "max_dist_last_m": dmax,
            "max_yaw_rate_radps": s["max_yaw_rate_radps"], "modes": modes,
            "warnings": warnings, "bound": bound, "met": met, "wall_s": round(wall, 1)}


def sim_full(t: np.ndarray, duration_s: float) -> bool:
    return bool(len(t)) and t[-1] >= duration_s - 0.01


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=30.0, help="sim seconds per case")
    ap.add_argument("--window", type=float, default=10.0, help="last window for the bound (s)")
    ap.add_argument("--only", nargs="*", default=None, help="case-name substrings to run")
    ap.add_argument("--json", metavar="FILE")
    args = ap.parse_args(argv)
    rows = []
    print(f"{'case':34s} {'result':44s} {'dist last':>10s} {'|r|max':>7s} {'bound':28s} met  "
          f"modes")
    for case in CASES:
        if args.only and not any(o in case.name for o in args.only):
            continue
        r = run_case(case, args.duration, args.window)
        rows.append(r)
        res = ("CRASH " + r["crash_reason"])[:44] if r["crashed"] else "flew"
        if r["warnings"]:
            res += f" ({len(r['warnings'])} warning)"
        d = r["max_dist_last_m"]
        print(f"{r['case']:34s} {res:44s} {d * 1000:8.1f}mm {r['max_yaw_rate_radps']:7.1f} "
              f"{r['bound']:28s} {'yes' if r['met'] else 'NO ':4s} {','.join(r['modes'])}",
              flush=True)
        for w in r["warnings"]:
            print(f"    warning: {w}")
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
