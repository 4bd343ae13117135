"""The link's receive path, alone: one lockstep tick's datagrams received and decoded.

The datagrams are a real tick's (paper scenario, hover, after 0.5 s of flight): the vehicle's
state (ODOMETRY + ACTUATOR_OUTPUT_STATUS + ESC_TELEMETRY_1_TO_4, one datagram, what the daemon
reads) and the daemon's command (HIL_ACTUATOR_CONTROLS, what the vehicle reads), packed by
our Link. Measured per datagram in thread CPU time, min over many short blocks (readable
on a loaded machine):

* ``ingest`` (the receive path, ``Link.receiver``): framing, checks, decode, counters (no socket);
* ``recv``: the datagram sent on loopback beforehand (untimed), then ``recv(timeout_s)`` as
  the daemon calls it: the waiting ``recvfrom``, ``ingest``, the drain's "anything else?"
  check; and ``recv(drain=False)`` as the lockstep vehicle calls it.

Runs on older revisions too (only ``Link`` and its receive path), for before/after:
``cd OTHER_CHECKOUT && python /path/to/bench/bench_link_rx.py`` with that checkout's venv.

Usage: ``python bench/bench_link_rx.py [--n N] [--blocks B] [--json FILE]``.
"""

from __future__ import annotations

import argparse
import json
import socket
import time
from typing import Any


def _tick_datagrams() -> tuple[bytes, bytes]:
    from pymavlink.dialects.v20 import ardupilotmega as mav

    from tfl_mav.link.transport import Link
    from tfl_mav.scenario import load_scenario
    from tfl_mav.sitl.vehicle import Vehicle

    sc = load_scenario("paper").replace(**{"attack.rotor": 0})
    vehicle = Vehicle(sc, listen=("127.0.0.1", 0))
    sim = vehicle.sim
    hover = [sc.vehicle.mass_kg * sc.vehicle.gravity_mps2 / 4.0] * 4
    sim.set_command(hover)
    for _ in range(500):
        sim.step_control_period()
    msgs = vehicle.report.build(sim.time_usec - 1000)
    vehicle.close()
    packer = Link.listen(("127.0.0.1", 0), src_system=1, src_component=1,
                         peer=("127.0.0.1", 9))
    state = b"".join(packer._codec.pack(m, packer.packer) for m in msgs)
    hil = mav.MAVLink_hil_actuator_controls_message(
        sim.time_usec, [h / sc.vehicle.thrust_max_n for h in hover] + [0.0] * 12, 128, 1)
    command = bytes(hil.pack(packer.packer))
    packer.close()
    return state, command


def _min_block_us(fn: Any, n: int, blocks: int) -> float:
    best = float("inf")
    for _ in range(blocks):
        best = min(best, fn(n) / n * 1e6)
    return best


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--n", type=int, default=300, help="datagrams per block")
    ap.add_argument("--blocks", type=int, default=60)
    ap.add_argument("--json", help="write the figures to this file")
    args = ap.parse_args()

    from tfl_mav.link.transport import Link

    state, command = _tick_datagrams()
    tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    tx.bind(("127.0.0.1", 0))
    sender = tx.getsockname()
    rx = Link.listen(("127.0.0.1", 0), src_system=1, src_component=191, peer=sender,
                     peer_sysid=1)
    dest = rx.local_address
    # the receive path (an older revision's Link receives itself)
    rx_ingest = rx.receiver.ingest if hasattr(rx, "receiver") else rx._ingest
    rows: dict[str, float] = {}

    for name, dgram, n_frames in (("state (3 frames), daemon side", state, 3),
                                  ("command (1 frame), vehicle side", command, 1)):
        def ingest(n: int, dgram: bytes = dgram, n_frames: int = n_frames) -> float:
            out: list[Any] = []
            t0 = time.thread_time()
            for _ in range(n):
                rx_ingest(dgram, sender, out)
                out.clear()
            dt = time.thread_time() - t0
            assert rx.stats.rejected == 0 and rx.stats.rx_frames % n_frames == 0
            return dt

        def recv(n: int, dgram: bytes = dgram, drain: bool = True) -> float:
            total = 0.0
            for _ in range(n):
                tx.sendto(dgram, dest)
                t0 = time.thread_time()
                got = rx.recv(0.05, drain=drain)
                total += time.thread_time() - t0
                assert got
            return total

        rows[f"ingest: {name}"] = _min_block_us(ingest, args.n, args.blocks)
        rows[f"recv(0.05): {name}"] = _min_block_us(recv, args.n, args.blocks)
        rows[f"recv(0.05, drain=False): {name}"] = _min_block_us(
            lambda n, dgram=dgram: recv(n, dgram, drain=False), args.n, args.blocks)
    rx.close()
    tx.close()
    print("link receive path, thread CPU µs per datagram (min over blocks of "
          f"{args.n}; loopback, unsigned)")
    for k, v in rows.items():
        print(f"  {k:<58} {v:8.2f} µs")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(rows, fh, indent=1)


if __name__ == "__main__":
    main()
