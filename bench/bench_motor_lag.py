"""Motor lag (#6): the attack-resilient law with first-order rotor lag τ_m.

Two parts:

1. **Over MAVLink** (``tfl-mav demo``: vehicle and controller as two processes, lockstep,
   detector on ESC rpm): the paper scenario with the controller's model off by the four
   ±2 % mass × ±10 % inertia corners, at τ_m = 20 ms and 50 ms, plus the controller's τ_m
   off by ±20 % at 20 ms. Prints converged/crashed, max and RMS path distance over the last
   10 s, detection latency, false alarms and the attacked rotor's estimate error.
2. **Sweep** (``--sweep``, in-process ``fly_offline``, same physics and controller, no
   network): max path distance over the last 10 s against τ_m = 0…80 ms, attacked and not
   (``attack.rotor = 0``), and a PNG of it (``--plot FILE``).

    python bench/bench_motor_lag.py                  # MAVLink table (≈ 6 min on 2 cores)
    python bench/bench_motor_lag.py --sweep --plot lag.png --json lag.json
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

CORNERS = [(0.98, 0.9), (0.98, 1.1), (1.02, 0.9), (1.02, 1.1)]
SWEEP_TAUS_MS = [0, 10, 20, 30, 40, 50, 60, 70, 80]


def demo_case(tau_s: float, mass_scale: float, inertia_scale: float,
              tau_scale: float = 1.0, duration_s: float = 30.0) -> dict:
    """One ``tfl-mav demo`` run; returns its JSON summary plus the case keys."""
    sets = {"vehicle.motor_time_constant_s": tau_s,
            "controller.model_mass_scale": mass_scale,
            "controller.model_inertia_scale": inertia_scale,
            "controller.motor_time_constant_scale": tau_scale}
    with tempfile.TemporaryDirectory(prefix="lagbench-") as out:
        cmd = [sys.executable, "-m", "tools.cli", "demo", "paper", "--out", out, "--json",
               "--no-plots", "--duration", str(duration_s)]
        for k, v in sets.items():
            cmd += ["--set", f"{k}={v}"]
        t0 = time.perf_counter()
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=900)
        wall = time.perf_counter() - t0
    try:
        summary = json.loads(proc.stdout)
    except json.JSONDecodeError:
        summary = {"crashed": True, "crash_reason": f"demo failed (exit {proc.returncode}): "
                                                     f"{proc.stderr.strip()[-200:]}"}
    summary.update(tau_ms=1000 * tau_s, mass_scale=mass_scale, inertia_scale=inertia_scale,
                   tau_scale=tau_scale, bench_wall_s=wall)
    return summary


def sweep_case(args: tuple[float, bool]) -> dict:
    """One offline flight for the sweep (runs in a worker process)."""
    from harness.offline import fly_offline
    from tfl_mav.flightlog.flight import summarize
    from tfl_mav.scenario import load_scenario

    tau_ms, attacked = args
    sc = load_scenario("paper").replace(**{"vehicle.motor_time_constant_s": tau_ms / 1000.0})
    if not attacked:
        sc = sc.replace(**{"attack.rotor": 0})
    m = summarize(fly_offline(sc, attack_info="detector"))
    return {"tau_ms": tau_ms, "attacked": attacked, "crashed": m["crashed"],
            "crash_reason": m.get("crash_reason", ""),
            "max_last_10s_m": m.get("max_path_distance_last_10s_m"),
            "rms_last_10s_m": m.get("rms_path_distance_last_10s_m")}


def _mm(x: float | None) -> str:
    return "-" if x is None or not math.isfinite(x) else f"{1000 * x:.3f}"


def print_demo_table(rows: list[dict]) -> None:
    print("| τ_m ms | model τ | mass × | J × | result | max last 10 s mm | rms mm | "
          "detect ms | false alarms | est. rms N |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        res = "CRASHED" if r.get("crashed") else "converged"
        lat = r.get("detection_latency_s")
        est = r.get("attack_estimate_rms_n")
        print(f"| {r['tau_ms']:.0f} | ×{r['tau_scale']:g} | {r['mass_scale']:g} | "
              f"{r['inertia_scale']:g} | {res} | {_mm(r.get('max_path_distance_last_10s_m'))}"
              f" | {_mm(r.get('rms_path_distance_last_10s_m'))} | "
              f"{'-' if lat is None else f'{1000 * lat:.1f}'} | {r.get('false_alarms', '-')} | "
              f"{'-' if est is None else f'{est:.4f}'} |")


def print_sweep_table(rows: list[dict]) -> None:
    print("| τ_m ms | attacked: max last 10 s mm | not attacked: max last 10 s mm |")
    print("|---|---|---|")
    by = {(r["tau_ms"], r["attacked"]): r for r in rows}
    for tau in SWEEP_TAUS_MS:
        cells = []
        for att in (True, False):
            r = by.get((tau, att))
            cells.append("-" if r is None else
                         "CRASHED" if r["crashed"] else _mm(r["max_last_10s_m"]))
        print(f"| {tau} | {cells[0]} | {cells[1]} |")


def plot_sweep(rows: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4))
    for att, style, label in ((True, "o-", "rotor 2 attacked (paper signal)"),
                              (False, "s--", "no attack")):
        pts = sorted((r["tau_ms"], r) for r in rows if r["attacked"] == att)
        ok = [(t, 1000 * r["max_last_10s_m"]) for t, r in pts if not r["crashed"]]
        bad = [t for t, r in pts if r["crashed"]]
        if ok:
            ax.semilogy(*zip(*ok, strict=True), style, label=label)
        if bad:
            ax.semilogy(bad, [1e3] * len(bad), "rx", ms=10,
                        label="crashed" if att else "crashed (no attack)")
    ax.axhline(10.0, color="grey", lw=0.8, ls=":")
    ax.text(1, 11, "1 cm requirement", fontsize=8, color="grey")
    ax.set_xlabel("motor time constant τ_m (ms)")
    ax.set_ylabel("max path distance, last 10 s (mm)")
    ax.set_title("Paper scenario, 2 %/10 % model error, lag-aware law, detector on rpm")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sweep", action="store_true",
                    help="offline sweep of τ_m 0-80 ms instead of the MAVLink table")
    ap.add_argument("--plot", metavar="FILE", help="with --sweep: write the PNG here")
    ap.add_argument("--json", metavar="FILE", help="write the rows as JSON")
    ap.add_argument("--duration", type=float, default=30.0, metavar="S",
                    help="sim seconds per MAVLink run (default 30)")
    ap.add_argument("--jobs", type=int, default=2, help="parallel runs (default 2)")
    args = ap.parse_args(argv)

    rows: list[dict] = []
    if args.sweep:
        cases = [(tau, att) for tau in SWEEP_TAUS_MS for att in (True, False)]
        with ProcessPoolExecutor(args.jobs) as pool:
            for i, r in enumerate(pool.map(sweep_case, cases), 1):
                rows.append(r)
                print(f"  [{i}/{len(cases)}] τ_m {r['tau_ms']} ms "
                      f"{'attacked' if r['attacked'] else 'nominal'}: "
                      f"{'CRASHED' if r['crashed'] else _mm(r['max_last_10s_m']) + ' mm'}",
                      file=sys.stderr, flush=True)
        print_sweep_table(rows)
        if args.plot:
            plot_sweep(rows, Path(args.plot))
            print(f"wrote {args.plot}")
    else:
        cases = ([(0.02, ms, js, 1.0) for ms, js in CORNERS]
                 + [(0.02, 1.02, 1.1, 0.8), (0.02, 1.02, 1.1, 1.2)]
                 + [(0.05, ms, js, 1.0) for ms, js in CORNERS])
        with ProcessPoolExecutor(args.jobs) as pool:
            futs = [pool.submit(demo_case, *c, duration_s=args.duration) for c in cases]
            for i, f in enumerate(futs, 1):
                r = f.result()
                rows.append(r)
                print(f"  [{i}/{len(cases)}] τ_m {r['tau_ms']:.0f} ms ×{r['tau_scale']:g}, "
                      f"m×{r['mass_scale']:g} J×{r['inertia_scale']:g}: "
                      f"{'CRASHED' if r.get('crashed') else 'converged'} "
                      f"({r['bench_wall_s']:.0f} s wall)", file=sys.stderr, flush=True)
        print_demo_table(rows)
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=2, default=str))
        print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
