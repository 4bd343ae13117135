"""``tfl-mav replay RUN.mcap --to HOST:PORT``: re-send recorded MAVLink frames over UDP.

Reads ``/mavlink/raw`` in recorded order (damaged files up to the damage) and sends each
frame's exact wire bytes as one datagram, keeping the recorded spacing of ``log_time``
divided by ``--speed`` (0 = as fast as possible). ``--direction`` picks what the recording
process received (``rx``), sent (``tx``) or both; rejected frames are re-sent too (they are
part of what crossed the wire) unless ``--accepted-only``. A frame that arrived inside a
multi-frame datagram is sent on its own.
"""

from __future__ import annotations

import argparse
import math
import socket
import sys
import time

from tfl_mav.flightlog.logread import LogReader, raw_frames
from tfl_mav.link.transport import parse_address

__all__ = ["add_parser", "replay", "run"]


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "replay", help="re-send the MAVLink frames of an MCAP log over UDP",
        description="Re-send the exact wire bytes recorded on /mavlink/raw, one datagram per "
                    "frame, with the recorded timing scaled by --speed.")
    p.add_argument("mcap", help="recorded .mcap file")
    p.add_argument("--to", required=True, metavar="HOST:PORT", help="destination (UDP)")
    p.add_argument("--speed", type=float, default=1.0,
                   help="time scale: 1 = as recorded, 2 = twice as fast, 0 = no waiting")
    p.add_argument("--direction", choices=("rx", "tx", "both"), default="both",
                   help="frames the recording process received, sent, or both (default)")
    p.add_argument("--accepted-only", action="store_true",
                   help="skip frames the recording link rejected")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    try:
        target = parse_address(args.to, "--to")
        if not (math.isfinite(args.speed) and args.speed >= 0.0):
            raise ValueError(f"--speed: must be >= 0, got {args.speed}")
    except ValueError as exc:
        print(f"tfl-mav replay: {exc}", file=sys.stderr)
        return 2
    try:
        sent, nbytes, elapsed_s, error = replay(args.mcap, target, speed=args.speed,
                                                direction=args.direction,
                                                accepted_only=args.accepted_only)
    except OSError as exc:
        print(f"tfl-mav replay: {exc}", file=sys.stderr)
        return 3
    print(f"replay: sent {sent} frames ({nbytes} bytes) to {target[0]}:{target[1]} "
          f"in {elapsed_s:.3f} s")
    if error and sent == 0:
        print(f"tfl-mav replay: {args.mcap}: not a readable MCAP file ({error})",
              file=sys.stderr)
        return 3
    if error:
        print(f"replay: the log ends early ({error}); sent what was readable", file=sys.stderr)
    return 0


def replay(path: str, target: tuple[str, int], *, speed: float = 1.0,
           direction: str = "both", accepted_only: bool = False
           ) -> tuple[int, int, float, str | None]:
    """Send the recorded frames; returns (frames sent, bytes sent, seconds, read error)."""
    reader = LogReader(path)        # raw_frames reads it again: the error is the same
    sent = nbytes = 0
    t0_wall = time.perf_counter()
    t0_log: int | None = None
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        for m, raw, tx, rejected in raw_frames(path, reader):
            if direction != "both" and (direction == "tx") != tx:
                continue
            if accepted_only and rejected:
                continue
            if speed > 0.0:
                if t0_log is None:
                    t0_log = m.log_time_ns
                due = t0_wall + (m.log_time_ns - t0_log) * 1e-9 / speed
                wait = due - time.perf_counter()
                if wait > 0.0:
                    time.sleep(wait)
            try:
                nbytes += sock.sendto(raw, target)
                sent += 1
            except OSError as exc:
                raise OSError(f"cannot send to {target[0]}:{target[1]}: {exc.strerror}") \
                    from None
    return sent, nbytes, time.perf_counter() - t0_wall, reader.error
