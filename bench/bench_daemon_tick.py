"""The controller daemon's lockstep tick outside the flight computer, in-process.

A real :class:`~tfl_mav.controller.daemon.Daemon` (paper scenario, rotor 2 attacked) is fed a real
simulator's states, packed by our Link into the datagram the vehicle sends (ODOMETRY +
ACTUATOR_OUTPUT_STATUS + ESC_TELEMETRY_1_TO_4), closed loop: its commands drive the
simulator. Per tick, thread CPU time of what the daemon's loop does with one datagram,
split into

* ``receive``: the link's ``Receiver.ingest`` (framing, checks, decode; no ``recvfrom``);
* ``intake``: the message handlers (ODOMETRY → paper-frame State, ESC completes the state,
  classification);
* ``tick``: ``_control_newest`` (applied command, the flight computer, the command packed
  and sent on loopback, telemetry, the recorder's tick record), and of it the flight
  computer's ``step`` alone; ``outside the flight computer`` = all of it but ``step``.

Each figure is the median over ``--blocks`` blocks of ``--ticks`` ticks of one flight (a
loaded machine slows some blocks; the median reads near an idle one). The timers cost a few
tenths of a µs each and are in every figure alike. Runs on older trees (``Daemon``, the
link's receive path, the daemon's intake handlers, ``Daemon._control_newest``), for
before/after:
``PYTHONPATH=OTHER_TREE python bench/bench_daemon_tick.py``.

Usage: ``python bench/bench_daemon_tick.py [--ticks N] [--blocks B] [--json FILE]``.
"""

from __future__ import annotations

import argparse
import json
import socket
import statistics
import time
from typing import Any


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--ticks", type=int, default=500, help="ticks per block")
    ap.add_argument("--blocks", type=int, default=8)
    ap.add_argument("--json", help="write the figures to this file")
    args = ap.parse_args()

    from tfl_mav.controller.daemon import Daemon
    from tfl_mav.link.transport import Link
    from tfl_mav.scenario import load_scenario
    try:
        from tfl_mav.sitl.vehicle import Vehicle
    except ImportError:                       # an older tree: the vehicle in tfl_mav/sim
        from tfl_mav.sim.vehicle import Vehicle  # type: ignore[no-redef]

    sc = load_scenario("paper")
    vehicle = Vehicle(sc, listen=("127.0.0.1", 0))
    sim = vehicle.sim
    packer = Link.listen(("127.0.0.1", 0), src_system=1, src_component=1,
                         peer=("127.0.0.1", 9))
    sink = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)   # the daemon's commands land here
    sink.bind(("127.0.0.1", 0))
    sink.setblocking(False)
    daemon = Daemon(sc, vehicle=sink.getsockname())
    link = daemon.link
    link.peer_sysid = 1
    sender = link.peer
    cpu = time.thread_time
    fc = daemon.computer
    step_s = [0.0]
    inner_step = fc.step

    def timed_step(*a: Any, **k: Any) -> Any:
        t0 = cpu()
        res = inner_step(*a, **k)
        step_s[0] += cpu() - t0
        return res

    fc.step = timed_step                      # type: ignore[method-assign]
    records: list[Any] = []
    daemon.on_tick = lambda t, rec: records.append(rec)
    intake = getattr(daemon, "intake", None)  # an older tree's daemon handles them itself
    handlers = daemon._handlers if intake is None else intake.handlers
    handle = daemon._handle if intake is None else intake.handle
    # the receive path: the link's receiver (an older tree's Link receives itself)
    ingest = link.receiver.ingest if hasattr(link, "receiver") else link._ingest
    rows: dict[str, list[float]] = {k: [] for k in (
        "receive (link ingest, 3 frames)", "intake (handlers: frames, classify)",
        "tick (control_newest, flight computer included)", "flight computer step",
        "outside the flight computer (receive + intake + tick - step)")}
    applied_usec = 0
    for _ in range(args.blocks):
        acc = [0.0, 0.0, 0.0]
        step_s[0] = 0.0
        for _ in range(args.ticks):
            msgs = vehicle.report.build(applied_usec)
            raw = b"".join(packer._codec.pack(m, packer.packer) for m in msgs)
            out: list[Any] = []
            t0 = cpu()
            ingest(raw, sender, out)
            t1 = cpu()
            for msg in out:
                handler = handlers.get(type(msg))
                if handler is None:
                    handle(msg)
                else:
                    handler(msg)
            t2 = cpu()
            daemon._control_newest()
            t3 = cpu()
            acc[0] += t1 - t0
            acc[1] += t2 - t1
            acc[2] += t3 - t2
            applied_usec = sim.time_usec
            try:
                while True:
                    sink.recv(4096)
            except BlockingIOError:
                pass
            sim.set_command(daemon._last_cmd)
            sim.step_control_period()
            records.clear()
        n = args.ticks
        for key, value in zip(rows, (acc[0], acc[1], acc[2], step_s[0],
                                     acc[0] + acc[1] + acc[2] - step_s[0]), strict=True):
            rows[key].append(value / n * 1e6)
    if daemon.stats.ticks != args.blocks * args.ticks:
        raise RuntimeError(f"bench: {daemon.stats.ticks} ticks controlled, expected "
                           f"{args.blocks * args.ticks} ({daemon.stats})")
    daemon.close()
    vehicle.close()
    packer.close()
    sink.close()
    figures = {k: statistics.median(v) for k, v in rows.items()}
    print(f"daemon lockstep tick, thread CPU µs per tick (median of {args.blocks} blocks of "
          f"{args.ticks} ticks; paper scenario, in-process, loopback send)")
    for k, v in figures.items():
        print(f"  {k:<62} {v:8.2f} µs")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(figures, fh, indent=1)


if __name__ == "__main__":
    main()
