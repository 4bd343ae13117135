"""Fuzz both UDP endpoints: ≥ 100 000 hostile datagrams each, over loopback.

The vehicle (``tfl_mav.sitl.vehicle.Vehicle``, lockstep) and the daemon
(``tfl_mav.controller.daemon.Daemon``)
each run in a thread on a real UDP socket; the fuzzer is their pinned peer and flies them in
lockstep while it sends random bytes, mutated frames (with and without a recomputed CRC),
truncated and oversize datagrams, MAVLink 1, unknown ids, wrong sysids and targets, garbage
commands, non-finite and out-of-range controls, bad and absurd states. The generators, the
reference model of the counters and the invariants are in ``tests/fuzz.py``.

Per endpoint and category the table gives: datagrams sent, rejections counted by reason,
frames accepted, and whether every batch's counters matched the model exactly. Below it:
crashes, NaN/inf reaching physics or a motor command, and inputs per second.

Usage: ``python bench/bench_fuzz.py [--n N] [--seed S] [--json FILE]`` from the repository
root. Exit status 1 if any invariant failed.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
import warnings
from pathlib import Path

from tfl_mav.tools.harness import fuzz

_SHORT = {"garbage": "garb", "mavlink1": "v1", "truncated": "trunc", "bad_flags": "flags",
          "bad_crc": "crc", "bad_signature": "sig", "malformed": "malf", "unknown_id": "unk",
          "foreign": "foreign", "wrong_sysid": "sysid", "no_peer": "nopeer",
          "rejected_controls": "ctl_rej", "stale_controls": "stale",
          "commands_not_for_us": "not_us", "commands_denied": "denied",
          "commands_unsupported": "unsup", "bad_states": "bad_state"}


def _progress(label: str):
    last = [0.0]

    def report(done: int, total: int) -> None:
        now = time.monotonic()
        if now - last[0] > 1.0 or done >= total:
            last[0] = now
            print(f"\r{label}: {done}/{total}", end="", file=sys.stderr, flush=True)
            if done >= total:
                print(file=sys.stderr)
    return report


def _table(r: fuzz.EndpointReport) -> str:
    rows = [("category", "sent", "arrived", "rejected", "accepted", "exact", "rejections")]
    for name, c in r.categories.items():
        reasons = fuzz.reject_reasons(c, r.endpoint)
        text = " ".join(f"{_SHORT.get(k, k)}={v}" for k, v in reasons.most_common())
        exact = "yes" if c.mismatched_batches == 0 else f"NO ({c.mismatched_batches})"
        if c.lost_batches:
            exact += f", {c.lost_batches} lost"
        rows.append((name, str(c.sent), str(c.arrived), str(fuzz.rejected_total(c,
                     r.endpoint)), str(c.counted.get("rx_frames", 0)), exact, text))
    total_sent = sum(c.sent for c in r.categories.values())
    total_rej = sum(fuzz.rejected_total(c, r.endpoint) for c in r.categories.values())
    total_acc = sum(c.counted.get("rx_frames", 0) for c in r.categories.values())
    total_arr = sum(c.arrived for c in r.categories.values())
    bad = sum(c.mismatched_batches for c in r.categories.values())
    rows.append(("TOTAL", str(total_sent), str(total_arr), str(total_rej), str(total_acc),
                 "yes" if bad == 0 else f"NO ({bad})", ""))
    widths = [max(len(row[i]) for row in rows) for i in range(6)]
    lines = []
    for row in rows:
        lines.append("  " + "  ".join(row[i].rjust(widths[i]) if i else row[i].ljust(widths[i])
                                      for i in range(6)) + "  " + row[6])
    nan = r.nan_to_physics if r.endpoint == "vehicle" else r.nan_to_motors
    what = "ticks with NaN/inf in physics" if r.endpoint == "vehicle" else \
        "HIL_ACTUATOR_CONTROLS non-finite or outside [0, 1]"
    lines.append(f"  crashes: {len(r.crashes)}   {what}: {nan}   non-finite floats sent: "
                 f"{len(r.nonfinite_tx)}   skipped (run-ending commands): "
                 f"{sum(c.skipped for c in r.categories.values())}")
    lines.append(f"  {r.ticks} lockstep ticks, {r.elapsed_s:.1f} s, "
                 f"{r.inputs_per_s:.0f} inputs/s, run completed: {r.completed}")
    for m in r.mismatches:
        lines.append(f"  MISMATCH {m}")
    for c in r.crashes:
        lines.append(f"  CRASH {c}")
    return "\n".join(lines)


def _as_json(r: fuzz.EndpointReport) -> dict:
    return {
        "endpoint": r.endpoint, "seed": r.seed, "sent": r.sent, "ticks": r.ticks,
        "elapsed_s": r.elapsed_s, "inputs_per_s": r.inputs_per_s, "completed": r.completed,
        "crashes": r.crashes, "nan_to_physics": r.nan_to_physics,
        "nan_to_motors": r.nan_to_motors, "nonfinite_tx": r.nonfinite_tx,
        "mismatches": r.mismatches,
        "categories": {name: {"sent": c.sent, "arrived": c.arrived,
                              "rejected": fuzz.rejected_total(c, r.endpoint),
                              "counted": dict(c.counted), "expected": dict(c.expected),
                              "batches": c.batches, "mismatched_batches": c.mismatched_batches,
                              "lost_batches": c.lost_batches, "skipped": c.skipped}
                       for name, c in r.categories.items()},
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--n", type=int, default=100_000,
                        help="hostile datagrams per endpoint (default 100000)")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--json", metavar="FILE", help="also write the results as JSON")
    args = parser.parse_args()
    if args.n < 1:
        parser.error("--n: must be >= 1")
    # Absurd (finite) states overflow inside the control law by design of the test: the
    # daemon must turn that into a finite command, which is what is checked.
    warnings.simplefilter("ignore", RuntimeWarning)
    reports = [fuzz.fuzz_vehicle(args.n, args.seed, progress=_progress("vehicle")),
               fuzz.fuzz_daemon(args.n, args.seed, progress=_progress("daemon"))]
    print(f"bench_fuzz (seed {args.seed}, python {platform.python_version()}, "
          f"{os.cpu_count()} cpus)")
    ok = True
    for r in reports:
        print(f"\n{r.endpoint}: {r.sent} hostile datagrams")
        print(_table(r))
        ok &= (r.completed and not r.crashes and not r.mismatches and r.nan_to_physics == 0
               and r.nan_to_motors == 0 and not r.nonfinite_tx)
    if args.json:
        Path(args.json).write_text(json.dumps([_as_json(r) for r in reports], indent=2))
    print("\nall invariants hold" if ok else "\nINVARIANT VIOLATED")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
