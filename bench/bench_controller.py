"""Controller cost per evaluation and the offline real-time factor.

    python bench/bench_controller.py [--scenario paper] [--ticks 5000] [--json FILE]

Times ``TFLController.update`` alone (median and p90 µs over a closed-loop flight, so the
projection is warm-started as in real use), the physics step, and the whole offline loop.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time

from sitl.simulator import Simulator
from tfl_mav.build import build_controller
from tfl_mav.scenario import load_scenario
from tfl_mav.state import State


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenario", default="paper")
    ap.add_argument("--ticks", type=int, default=5000)
    ap.add_argument("--json", metavar="FILE")
    args = ap.parse_args(argv)
    rows = []
    for law in ("robust", "paper"):
        sc = load_scenario(args.scenario).replace(**{"controller.law": law})
        sim, ctrl = Simulator(sc), build_controller(sc)
        ctl_s, phys_s = [], []
        t_all = time.perf_counter()
        for _ in range(args.ticks):
            m = sim.measured
            if sim.attack.rotor:
                ctrl.set_attack(sim.attack.rotor, sim.attack.applied_n)
            st = State(m.position_m, m.velocity_mps, m.quaternion_wxyz,
                               m.body_rates_radps)
            t0 = time.perf_counter()
            out = ctrl.update(st)
            t1 = time.perf_counter()
            sim.set_command(out.rotor_thrust_n)
            sim.step_control_period()
            phys_s.append(time.perf_counter() - t1)
            ctl_s.append(t1 - t0)
        wall = time.perf_counter() - t_all
        ctl_s.sort()
        rows.append({"law": law, "controller_median_us": 1e6 * statistics.median(ctl_s),
                     "controller_p90_us": 1e6 * ctl_s[int(0.9 * len(ctl_s))],
                     "physics_per_tick_us": 1e6 * statistics.median(phys_s),
                     "offline_rtf": args.ticks * sim.control_dt_s / wall})
    print(f"{'law':8s} {'ctl median µs':>13s} {'ctl p90 µs':>10s} {'physics µs':>10s} "
          f"{'offline RTF':>11s}")
    for r in rows:
        print(f"{r['law']:8s} {r['controller_median_us']:13.1f} {r['controller_p90_us']:10.1f} "
              f"{r['physics_per_tick_us']:10.1f} {r['offline_rtf']:11.2f}")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(rows, fh, indent=2)
    return 0


if __name__ == "__main__":
    sys.exit(main())
