"""Offline flight table for the TFL controller.

Flies, in-process on the sitl physics at 1 kHz with the controller sampled at 1 kHz:
the paper scenario with an exact model (plain and robust law), the four ±2 % mass × ±10 %
inertia corners with sensor noise (velocity 0.01 m/s, body rates 0.005 rad/s), an attack on
each rotor 1–4, the circle / helix / figure-eight scenarios, and the baseline that ignores
the attack. Prints one row per flight; ``--json FILE`` writes the rows.

    python bench/bench_offline.py [--jobs 2] [--json out.json] [--only corners]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from typing import Any

from tfl_mav.flightlog.flight import summarize
from tfl_mav.offline import fly_offline
from tfl_mav.scenario import load_scenario

NOISE = {"sensors.velocity_noise_std_mps": 0.01, "sensors.rate_noise_std_radps": 0.005}


def cases() -> list[tuple[str, str, str, dict[str, Any]]]:
    """(group, label, scenario, overrides)."""
    out: list[tuple[str, str, str, dict[str, Any]]] = [
        ("exact", "paper law, exact model", "paper-exact", {}),
        ("exact", "robust law, exact model", "paper-exact", {"controller.law": "robust"}),
    ]
    for dm in (0.98, 1.02):
        for dj in (0.9, 1.1):
            out.append(("corners", f"mass x{dm:.2f}, inertia x{dj:.1f}, noise", "paper",
                        {"controller.model_mass_scale": dm,
                         "controller.model_inertia_scale": dj, **NOISE}))
    out.append(("corners", "paper law, mass x1.02, inertia x1.1", "paper",
                {"controller.law": "paper"}))
    for rotor in (1, 2, 3, 4):
        out.append(("rotors", f"rotor {rotor} attacked", "paper", {"attack.rotor": rotor}))
    for name in ("circle", "helix", "figure8", "nominal"):
        out.append(("paths", name, name, {}))
    out.append(("baseline", "ignores the attack", "paper",
                {"controller.aware_of_attack": False}))
    return out


def run_case(case: tuple[str, str, str, dict[str, Any]]) -> dict[str, Any]:
    group, label, name, overrides = case
    sc = load_scenario(name).replace(**overrides)
    log = fly_offline(sc)
    m = summarize(log)
    return {"group": group, "case": label, "scenario": name, "overrides": overrides, **m}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--jobs", type=int, default=2, help="parallel flights (default 2)")
    ap.add_argument("--json", metavar="FILE", help="write the rows as JSON")
    ap.add_argument("--only", help="run one group: exact, corners, rotors, paths, baseline")
    args = ap.parse_args(argv)
    todo = [c for c in cases() if args.only in (None, c[0])]
    t0 = time.perf_counter()
    with ProcessPoolExecutor(max_workers=args.jobs) as pool:
        rows = list(pool.map(run_case, todo))
    hdr = (f"{'case':44s} {'crashed':>7s} {'final mm':>9s} {'max10s mm':>9s} {'rms10s mm':>9s} "
           f"{'f range N':>11s} {'sat %':>6s} {'|r| max':>7s} {'RTF':>5s}")
    print(hdr)
    print("-" * len(hdr))
    def mm(row: dict[str, Any], key: str) -> str:
        v = row.get(key)
        return f"{1000 * v:9.3f}" if v is not None else f"{'-':>9s}"

    for r in rows:
        rng = f"{r['thrust_min_n']:.2f}-{r['thrust_max_n']:.2f}"
        print(f"{r['case']:44s} {r['crashed']!s:>7s} {mm(r, 'final_path_distance_m')} "
              f"{mm(r, 'max_path_distance_last_10s_m')} {mm(r, 'rms_path_distance_last_10s_m')} "
              f"{rng:>11s} {100 * r['saturated_fraction']:6.2f} "
              f"{r['max_yaw_rate_radps']:7.1f} {r.get('real_time_factor', 0):5.2f}")
    print(f"\n{len(rows)} flights in {time.perf_counter() - t0:.0f} s wall")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(rows, fh, indent=2)
    return 0


if __name__ == "__main__":
    sys.exit(main())
