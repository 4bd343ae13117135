"""Lockstep over a lossy link: what a lost datagram costs.

A ``tfl-mav sim`` subprocess (hover, no attack) is flown by the test pilot
(:class:`tfl_mav.tools.harness.pilot.Pilot`) through the fault relay
(:class:`tfl_mav.tools.harness.relay.Relay`), first
with no loss, then dropping ``--drop`` of the datagrams in *each* direction. The vehicle
resends its state after ``--resend-interval`` without a reply, so each loss should cost
about that interval, not the 2 s give-up timeout. Prints the wall time of each and their
ratio (same run, same machine state; the machine is shared, so run it a few times).

    python bench/bench_lockstep_loss.py [--ticks 2000] [--drop 0.01] [--json out.json]
"""

from __future__ import annotations

import argparse
import json

from tfl_mav.tools.harness.lossy import fly_through_relay


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--ticks", type=int, default=2000)
    ap.add_argument("--drop", type=float, default=0.01)
    ap.add_argument("--resend-interval", type=float, default=0.005)
    ap.add_argument("--json", metavar="PATH")
    args = ap.parse_args()
    clean = fly_through_relay(args.ticks, 0.0, args.resend_interval)
    lossy = fly_through_relay(args.ticks, args.drop, args.resend_interval)
    if lossy["lost_datagrams"]:
        lossy["ms_per_loss"] = 1000 * (lossy["wall_s"] - clean["wall_s"]) / lossy[
            "lost_datagrams"]
    ratio = lossy["wall_s"] / clean["wall_s"]
    print(f"{'drop':>6} {'ticks':>6} {'wall s':>8} {'lost':>5} {'ms/loss':>8}")
    for r in (clean, lossy):
        per = f"{r['ms_per_loss']:.1f}" if r["ms_per_loss"] is not None else "-"
        print(f"{r['drop']:6.3f} {r['ticks']:6d} {r['wall_s']:8.3f} {r['lost_datagrams']:5d} "
              f"{per:>8}")
    print(f"lossy / lossless wall time: {ratio:.2f}x (resend interval "
          f"{1000 * args.resend_interval:g} ms)")
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"clean": clean, "lossy": lossy, "ratio": ratio}, f, indent=2)


if __name__ == "__main__":
    main()
