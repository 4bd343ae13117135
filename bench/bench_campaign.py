"""Campaign throughput: flights per hour for each executor, and what each run costs on top.

Flies the same small campaign (the paper case, ``--runs`` short offline flights of
``--duration`` s sim) three ways: in this process one after another (the flight alone, no
executor), with the ``local`` executor (a forked process per run) and with the ``ray``
executor on a local Ray instance started here (its start-up is timed apart, as a cluster
would already be up). The per-run overhead is what a run costs beyond its flight, measured
with one worker (so CPU contention on a shared machine does not count as overhead):
``wall / runs − mean in-process flight time`` of ``--overhead-runs`` tiny flights (0.02 s
sim). Same flights in the same process run, so the ratios hold on a loaded machine even when
the absolute numbers drift.

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

from tfl_mav.tools.harness.campaign import run_campaign
from tfl_mav.tools.harness.campaign.run import execute
from tfl_mav.tools.harness.campaign.spec import spec_from_dict


def _spec(runs: int, duration_s: float) -> Any:
    return spec_from_dict({"name": "bench", "base": "paper", "duration_s": duration_s,
                           "seeds": runs, "timeout_s": 600.0})


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=24, help="flights per executor (default 24)")
    ap.add_argument("--duration", type=float, default=1.0, help="sim s per flight (default 1)")
    ap.add_argument("--workers", type=int, default=2, help="runs at a time (default 2)")
    ap.add_argument("--overhead-runs", type=int, default=30,
                    help="tiny flights for the per-run overhead (default 30)")
    ap.add_argument("--no-ray", action="store_true", help="skip the Ray executor")
    ap.add_argument("--json", metavar="PATH", help="write the rows as JSON")
    args = ap.parse_args(argv)
    spec = _spec(args.runs, args.duration)
    n, w = args.runs, args.workers

    flight_s = _in_process(spec, max(2, n // 4))
    tiny = _spec(args.overhead_runs, 0.02)
    tiny_s = _in_process(tiny, args.overhead_runs)
    rows: list[dict[str, Any]] = [{"executor": "in-process, sequential", "runs": n,
                                   "workers": 1, "wall_s": round(flight_s * n, 2),
                                   "flights_per_hour": round(3600 / flight_s),
                                   "overhead_per_run_ms": 0.0}]
    executors = ["local"] if args.no_ray else ["local", "ray"]
    names = {"local": "local (forked process per run)", "ray": "ray (local instance)"}
    with tempfile.TemporaryDirectory() as tmp:
        for ex in executors:
            ray = None
            if ex == "ray":
                import ray

                t1 = time.perf_counter()
                ray.init(num_cpus=w, include_dashboard=False, logging_level="WARNING",
                         log_to_driver=False)
                init_s = time.perf_counter() - t1
            try:
                s = run_campaign(spec, Path(tmp) / ex, executor=ex, workers=w,
                                 progress=False, report=False)
                o = run_campaign(tiny, Path(tmp) / f"{ex}-tiny", executor=ex, workers=1,
                                 progress=False, report=False)
            finally:
                if ray is not None:
                    ray.shutdown()
            row = {"executor": names[ex], "runs": n, "workers": w, "wall_s": s["wall_time_s"],
                   "flights_per_hour": round(3600 * n / s["wall_time_s"]),
                   "overhead_per_run_ms": round(
                       1000 * (o["wall_time_s"] / args.overhead_runs - tiny_s), 1)}
            if ex == "ray":
                row["ray_init_s"] = round(init_s, 2)
            rows.append(row)
    print(f"{n} flights of {args.duration:g} s sim (paper case, rpm detection), {w} workers; "
          f"one flight alone: {flight_s:.3f} s wall")
    print(f"{'executor':34s} {'runs':>5s} {'wall s':>8s} {'flights/h':>10s} "
          f"{'overhead/run ms':>16s}")
    print(f"(overhead: 1 worker, {args.overhead_runs} flights of 0.02 s sim, "
          f"{1000 * tiny_s:.1f} ms each in-process)")
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


def _in_process(spec: Any, n: int) -> float:
    """Mean wall time of one flight (s), flown here, no executor."""
    t0 = time.perf_counter()
    for run in spec.runs()[:n]:
        execute(run)
    return (time.perf_counter() - t0) / n


if __name__ == "__main__":
    sys.exit(main())
