"""``tfl-mav relay``: the command line of the UDP fault relay
(:mod:`tfl_mav.tools.harness.relay`)."""

from __future__ import annotations

import argparse
import json
import math
import signal
import sys
from typing import Any

from tfl_mav.link.transport import parse_address
from tfl_mav.tools.harness.relay import Faults, Relay, RelayError

__all__ = ["add_parser", "run"]


# ---------------------------------------------------------------------------- CLI
def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "relay", help="UDP fault relay between controller and vehicle (drop, duplicate, "
                      "reorder, delay)",
        description="Forward MAVLink datagrams between a controller (which sends to --listen) "
                    "and a vehicle's control port (--vehicle), dropping, duplicating, "
                    "reordering and delaying them with seeded randomness. Point `tfl-mav fly "
                    "--vehicle` at the relay's listen address.",
        epilog="exit codes: 0 duration reached, 2 usage error, 3 cannot bind, "
               "130/143 interrupted (after printing the counters)")
    p.add_argument("--vehicle", required=True, metavar="HOST:PORT",
                   help="the vehicle's control port (tfl-mav sim --listen)")
    p.add_argument("--listen", default="127.0.0.1:0", metavar="HOST:PORT",
                   help="where the controller sends (default 127.0.0.1:0 = any free port; "
                        "the first stdout line says which)")
    p.add_argument("--drop", type=float, default=0.0, metavar="P",
                   help="probability a datagram is dropped")
    p.add_argument("--duplicate", type=float, default=0.0, metavar="P",
                   help="probability a datagram is sent twice")
    p.add_argument("--reorder", type=float, default=0.0, metavar="P",
                   help="probability a datagram is swapped with the next one")
    p.add_argument("--delay-ms", type=float, default=0.0, metavar="MS",
                   help="fixed one-way delay (ms)")
    p.add_argument("--jitter-ms", type=float, default=0.0, metavar="MS",
                   help="extra one-way delay, uniform in [0, MS]")
    p.add_argument("--in-order", action="store_true",
                   help="jitter never reorders (first in, first out per direction)")
    p.add_argument("--direction", choices=("both", "to-vehicle", "to-daemon"), default="both",
                   help="which direction the faults apply to (default both)")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument("--duration", type=float, default=0.0, metavar="S",
                   help="wall seconds to run (default 0 = until interrupted)")
    p.add_argument("--json", metavar="FILE", help="at exit, write the counters as JSON")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    prog = "tfl-mav relay"
    try:
        vehicle = parse_address(args.vehicle, "--vehicle")
        listen = parse_address(args.listen, "--listen")
        faults = Faults(drop=args.drop, duplicate=args.duplicate, reorder=args.reorder,
                        delay_s=args.delay_ms / 1000.0, jitter_s=args.jitter_ms / 1000.0,
                        in_order=args.in_order)
        if not (math.isfinite(args.duration) and args.duration >= 0):
            raise ValueError(f"--duration: must be >= 0 s, got {args.duration}")
    except ValueError as exc:
        print(f"{prog}: {exc}", file=sys.stderr)
        return 2
    none = Faults()
    to_vehicle = faults if args.direction in ("both", "to-vehicle") else none
    to_daemon = faults if args.direction in ("both", "to-daemon") else none
    try:
        relay = Relay(vehicle, listen=listen, to_vehicle=to_vehicle, to_daemon=to_daemon,
                      seed=args.seed)
    except RelayError as exc:
        print(f"{prog}: {exc}", file=sys.stderr)
        return 3
    got: list[int] = []

    def on_signal(signum: int, _frame: Any) -> None:
        got.append(signum)
        relay.request_stop()   # not stop(): a signal handler must not join its own thread

    previous = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        host, port = relay.listen_address
        bhost, bport = relay.vehicle_side_address
        print(f"{prog}: listening on {host}:{port} -> vehicle {relay.vehicle[0]}:"
              f"{relay.vehicle[1]} from {bhost}:{bport}; to vehicle: "
              f"{to_vehicle.describe()}; to daemon: {to_daemon.describe()}; seed {args.seed}",
              flush=True)
        stats = relay.run(args.duration if args.duration > 0 else math.inf)
    finally:
        for s, h in previous.items():
            signal.signal(s, h)
        relay.close()
    print(f"{prog}: {stats.summary()}", flush=True)
    if args.json:
        try:
            with open(args.json, "w", encoding="utf-8") as fh:
                json.dump(stats.as_dict(), fh, indent=2)
        except OSError as exc:
            print(f"{prog}: --json: cannot write {args.json!r}: {exc.strerror}",
                  file=sys.stderr)
            return 3
    return 128 + got[-1] if got else 0
