"""The simulated vehicle's lockstep tick, piece by piece, in-process (issue #13).

Each piece of what ``sitl.vehicle.Vehicle`` does per control tick, timed alone on the
paper scenario (rotor 2 attacked, 1 kHz physics and control): µs per call, the *minimum*
over ``--blocks`` blocks of ``--calls`` calls, so a shared, loaded machine reads close to
an idle one (a mean would charge other processes' time slices to whichever piece ran).
The control link sends to a local sink socket (real ``sendto``), frames come in through
the link's own ``_ingest`` (no ``recvfrom``). The daemon's telemetry (4 NAMED_VALUE_FLOAT +
DEBUG_FLOAT_ARRAY, one datagram at ≤ 50 Hz of sim time) is timed per datagram.

Usage: ``python bench/bench_vehicle_tick.py [--calls N] [--blocks N] [--json FILE]`` from the
repository root; it runs on any revision with the same public API (before/after tables).
"""

from __future__ import annotations

import argparse
import json
import platform
import socket
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from sitl.vehicle import Vehicle, truth_hook
from tfl_mav.link.dialect import mav, new_mavlink
from tfl_mav.scenario import load_scenario


class _Sink:
    def truth(self, *args: Any) -> None:
        pass


def _telemetry_datagram() -> bytes:
    """What the daemon sends the vehicle at ≤ 50 Hz (tfl_mav.daemon._telemetry)."""
    packer = new_mavlink(1, 191)
    msgs = [*(mav.MAVLink_named_value_float_message(7, name, 1.0)
              for name in (b"mode", b"det_rotor", b"atk_est_n", b"path_m")),
            mav.MAVLink_debug_float_array_message(7000, b"tfl", 1, [0.1] * 58)]
    return b"".join(bytes(m.pack(packer)) for m in msgs)


def measure(calls: int, blocks: int) -> dict[str, float]:
    sc = load_scenario("paper")
    vehicle = Vehicle(sc, listen=("127.0.0.1", 0))
    sim, ctl = vehicle.sim, vehicle.control_link
    sink = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sink.bind(("127.0.0.1", 0))
    sink.setblocking(False)
    ctl.peer = sink.getsockname()
    ctl.peer_sysid = 1
    vehicle._flying = vehicle._confirmed = True
    sim.set_command([sc.vehicle.mass_kg * sc.vehicle.gravity_mps2 / 4.0] * 4)
    hil = bytes(mav.MAVLink_hil_actuator_controls_message(
        0, [0.34] * 4 + [0.0] * 12, 128, 1).pack(new_mavlink(1, 191)))
    telemetry = _telemetry_datagram()
    truth = truth_hook(_Sink())

    def drain() -> None:
        try:
            while True:
                sink.recv(65535)
        except BlockingIOError:
            pass

    def receive(raw: bytes) -> Callable[[], None]:
        def run() -> None:
            out: list[Any] = []
            ctl._ingest(raw, ctl.peer, out)
            for msg in out:
                vehicle.held.time_usec = -1
                vehicle.dispatch(msg, 0)
        return run

    x = list(sim.state_vector)
    pieces: dict[str, Callable[[], Any]] = {
        "RK4 step alone": lambda: sim._rk4(x, 10.8, 0.0, 0.0, 0.0, 1e-3),
        "simulator control tick (attack, motors, RK4, sensors)": sim.step_control_period,
        "sensor sampling alone": sim._measure,
        "power model": lambda: vehicle.power.step(sim.motors.omega_radps, sim.control_dt_s),
        "crash check": sim.crash_reason,
        "vehicle.step (tick + power + crash check)": vehicle.step,
        "truth hook (recorder call excluded)": lambda: truth(sim),
        "state messages built": lambda: vehicle.report.build(5),
        "state packed + sent (one datagram)": lambda: ctl.send_many(vehicle.report.latest),
        "HIL_ACTUATOR_CONTROLS received + applied": receive(hil),
        "daemon telemetry datagram received (5 frames)": receive(telemetry),
    }
    out: dict[str, float] = {}
    for name, fn in pieces.items():
        best = float("inf")
        for _ in range(blocks):
            t0 = time.perf_counter()
            for _ in range(calls):
                fn()
            best = min(best, (time.perf_counter() - t0) / calls * 1e6)
            drain()
        out[name] = best
    sink.close()
    vehicle.close()
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--calls", type=int, default=2000, help="calls per block")
    parser.add_argument("--blocks", type=int, default=7, help="blocks; the fastest counts")
    parser.add_argument("--json", metavar="FILE", help="also write the numbers as JSON")
    args = parser.parse_args()
    if args.calls < 1 or args.blocks < 1:
        parser.error("--calls and --blocks: must be ≥ 1")
    result = measure(args.calls, args.blocks)
    print(f"bench_vehicle_tick (python {platform.python_version()}, min of {args.blocks} "
          f"blocks of {args.calls} calls)")
    for name, us in result.items():
        print(f"  {name:<55}  {us:>8.2f} µs")
    if args.json:
        Path(args.json).write_text(json.dumps({"python": platform.python_version(),
                                               "us": result}, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
