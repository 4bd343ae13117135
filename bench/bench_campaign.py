"""Campaign throughput: flights per hour for each executor, and what each run costs on top.

Flies the same small campaign (the paper case, ``--runs`` short offline flights of
``--duration`` s sim) three ways: in this process one after another (the flight alone, no
executor), with the ``local`` executor (a forked process per run) and with the ``ray``
executor on a local Ray instance started here (its start-up is timed apart, as a cluster
would already be up). The per-run overhead is what a run costs beyond its flight:
``workers × wall / runs − mean in-process flight time``. Same flights in the same process
run, so the ratios hold on a loaded machine even when the absolute numbers drift.

    python bench/bench_campaign.py [--runs 24] [--duration 1.0] [--workers 2] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from harness.campaign import run_campaign
from harness.campaign.run import execute
from harness.campaign.spec import spec_from_dict


def _spec(runs: int, duration_s: float) -> Any:
    return spec_from_dict({"name": "bench", "base": "paper", "duration_s": duration_s,
                           "seeds": runs, "timeout_s": 600.0})


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=24, help="flights per executor (default 24)")
    ap.add_argument("--duration", type=float, default=1.0, help="sim s per flight (default 1)")
    ap.add_argument("--workers", type=int, default=2, help="runs at a time (default 2)")
    ap.add_argument("--no-ray", action="store_true", help="skip the Ray executor")
    ap.add_argument("--json", metavar="PATH", help="write the rows as JSON")
    args = ap.parse_args(argv)
    spec = _spec(args.runs, args.duration)
    n, w = args.runs, args.workers

    n_seq = max(2, n // 4)
    t0 = time.perf_counter()
    for run in spec.runs()[:n_seq]:
        execute(run)
    flight_s = (time.perf_counter() - t0) / n_seq

    rows: list[dict[str, Any]] = [{"executor": "in-process, sequential", "runs": n_seq,
                                   "workers": 1, "wall_s": round(flight_s * n_seq, 2),
                                   "flights_per_hour": round(3600 / flight_s),
                                   "overhead_per_run_ms": 0.0}]
    with tempfile.TemporaryDirectory() as tmp:
        s = run_campaign(spec, Path(tmp) / "local", workers=w, progress=False, report=False)
        rows.append(_row("local (forked process per run)", s, n, w, flight_s))
        if not args.no_ray:
            import ray

            t1 = time.perf_counter()
            ray.init(num_cpus=w, include_dashboard=False, logging_level="WARNING",
                     log_to_driver=False)
            init_s = time.perf_counter() - t1
            try:
                s = run_campaign(spec, Path(tmp) / "ray", executor="ray", workers=w,
                                 progress=False, report=False)
            finally:
                ray.shutdown()
            rows.append({**_row("ray (local instance)", s, n, w, flight_s),
                         "ray_init_s": round(init_s, 2)})
    print(f"{n} flights of {args.duration:g} s sim (paper case, rpm detection), {w} workers; "
          f"one flight alone: {flight_s:.3f} s wall")
    print(f"{'executor':34s} {'runs':>5s} {'wall s':>8s} {'flights/h':>10s} "
          f"{'overhead/run ms':>16s}")
    for r in rows:
        print(f"{r['executor']:34s} {r['runs']:5d} {r['wall_s']:8.2f} "
              f"{r['flights_per_hour']:10.0f} {r['overhead_per_run_ms']:16.1f}")
    if len(rows) == 3:
        print(f"Ray start-up (not in the wall time above): {rows[2]['ray_init_s']:.1f} s; "
              f"Ray costs {rows[2]['overhead_per_run_ms'] - rows[1]['overhead_per_run_ms']:+.1f}"
              f" ms per run vs the process pool")
    if args.json:
        Path(args.json).write_text(json.dumps({"flight_s": flight_s, "rows": rows}, indent=2))
    return 0


def _row(name: str, s: dict[str, Any], n: int, w: int, flight_s: float) -> dict[str, Any]:
    wall = s["wall_time_s"]
    assert s["flown_now"] == n, s
    return {"executor": name, "runs": n, "workers": w, "wall_s": round(wall, 2),
            "flights_per_hour": round(3600 * n / wall),
            "overhead_per_run_ms": round(1000 * (w * wall / n - flight_s), 1)}


if __name__ == "__main__":
    sys.exit(main())
