"""The simulated vehicle's lockstep tick, piece by piece, in-process.

Each piece of what ``tfl_mav.sitl.vehicle.Vehicle`` does per control tick, timed alone on the
paper scenario (rotor 2 attacked, 1 kHz physics and control): µs per call, the *minimum*
over ``--blocks`` blocks of ``--calls`` calls, so a shared, loaded machine reads close to
an idle one (a mean would charge other processes' time slices to whichever piece ran).
The control link sends to a local sink socket (real ``sendto``), frames come in through
the link's own receive path (``Link.receiver.ingest``, no ``recvfrom``). The daemon's
telemetry (4 NAMED_VALUE_FLOAT + DEBUG_FLOAT_ARRAY, one datagram at ≤ 50 Hz of sim time) is
timed per datagram.

Then the tick as the vehicle's own lockstep loop runs it (``Vehicle.fly``), with the
controller's replies already queued on the socket (so no wait: what is left is the
vehicle's CPU), a GCS port and the daemon's telemetry every 20 ticks, without and with a
recorder's hand-off (``on_frame``/``on_truth`` appending to a queue, as
``RecorderProcess`` does): per tick, the whole tick, and the **critical path**, from the
``recv`` that brought the reply to the next state's ``send_many`` returning (the link's two
methods timed from outside, so older revisions measure the same thing). Only the critical
path delays the controller; the rest runs while it computes.

Usage: ``python bench/bench_vehicle_tick.py [--calls N] [--blocks N] [--json FILE]`` from the
repository root; it runs on any revision with the same public API (before/after tables).
"""

from __future__ import annotations

import argparse
import collections
import itertools
import json
import platform
import socket
import statistics
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from tfl_mav.link.dialect import mav, new_mavlink
from tfl_mav.scenario import load_scenario
from tfl_mav.sitl.physics import rk4_stepper
from tfl_mav.sitl.vehicle import Vehicle, truth_hook


class _Sink:
    def truth(self, *args: Any) -> None:
        pass


def _telemetry_datagram() -> bytes:
    """What the daemon sends the vehicle at ≤ 50 Hz (tfl_mav.controller.daemon._telemetry)."""
    packer = new_mavlink(1, 191)
    msgs = [*(mav.MAVLink_named_value_float_message(7, name, 1.0)
              for name in (b"mode", b"det_rotor", b"atk_est_n", b"path_m")),
            mav.MAVLink_debug_float_array_message(7000, b"tfl", 1, [0.1] * 58)]
    return b"".join(bytes(m.pack(packer)) for m in msgs)


class _Recorder:
    """What RecorderProcess's hooks do on the hot path: a tuple appended to a queue."""

    def __init__(self) -> None:
        self.queue: collections.deque[Any] = collections.deque(maxlen=100_000)

    def on_frame(self, direction: str, raw: bytes, msg: Any, time_s: float) -> None:
        self.queue.append((0, time_s, direction, bytes(raw), msg is not None))

    def truth(self, *args: Any) -> None:
        self.queue.append((1, time.time(), args))


def measure_clock(ticks: int, blocks: int, record: bool) -> dict[str, float]:
    """µs per tick through the vehicle's lockstep loop with the replies pre-queued: the minimum
    over ``blocks`` of the median tick (state sent to state sent) and of the median
    critical path (reply received to state sent)."""
    from tfl_mav.tools.harness.pilot import hover_fraction

    sc = load_scenario("paper").replace(**{"attack.rotor": 0,
                                           "initial.position_m": [0.0, 0.0, 5.0]})
    rec = _Recorder()
    sink = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sink.bind(("127.0.0.1", 0))
    sink.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 22)
    sink.setblocking(False)
    vehicle = Vehicle(sc, listen=("127.0.0.1", 0), gcs=sink.getsockname(),
                      peer=sink.getsockname(), resend_interval_s=1.0, lockstep_timeout_s=5.0,
                      on_frame=rec.on_frame if record else None,
                      on_truth=truth_hook(rec) if record else None)
    vehicle._flying = vehicle._confirmed = vehicle._controller_seen = True
    ctl = vehicle.control_link
    ctl.peer_sysid = 1
    packer = new_mavlink(1, 191)
    fraction = hover_fraction(sc)
    telemetry = _telemetry_datagram()
    marks: list[tuple[int, float]] = []   # (0: recv returned, 1: state sent, time)
    recv, send_many = ctl.recv, ctl.send_many
    clock = time.perf_counter

    def timed_recv(*args: Any, **kw: Any) -> Any:
        out = recv(*args, **kw)
        marks.append((0, clock()))
        return out

    def timed_send_many(msgs: Any) -> int:
        n = send_many(msgs)
        marks.append((1, clock()))
        return n

    # the block's replies wait on the socket: room for them (default buffers hold ~200)
    ctl._sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 22)
    ctl.recv = timed_recv              # type: ignore[method-assign]
    ctl.send_many = timed_send_many    # type: ignore[method-assign]
    # the loop (an older tree's clock drives the vehicle from outside)
    fly = vehicle.fly if hasattr(vehicle, "fly") else vehicle.clock.run
    whole, critical = float("inf"), float("inf")
    for _ in range(blocks):
        k0 = vehicle.stats.ticks
        for k in range(k0, k0 + ticks):   # the replies, queued before the clock runs
            sink.sendto(bytes(mav.MAVLink_hil_actuator_controls_message(
                k * 1000, [fraction] * 4 + [0.0] * 12, 128, 1).pack(packer)),
                vehicle.listen_address)
            if k % 20 == 0:
                sink.sendto(telemetry, vehicle.listen_address)
        marks.clear()
        watchdog = threading.Timer(60.0, vehicle.stop)   # a lost reply would wait forever
        watchdog.start()
        status, reason = fly(k0 + ticks)
        watchdog.cancel()
        if vehicle.stats.ticks != k0 + ticks:
            raise RuntimeError(f"clock run ended early: {status} {reason}")
        gaps = [b[1] - a[1] for a, b in itertools.pairwise(marks) if a[0] == 0 and b[0] == 1]
        sent = [t for kind, t in marks if kind == 1]
        # the median tick (a mean would charge other processes' time slices to it)
        whole = min(whole, statistics.median(b - a for a, b in itertools.pairwise(sent)) * 1e6)
        critical = min(critical, statistics.median(gaps) * 1e6)
        rec.queue.clear()
        try:
            while True:
                sink.recv(65535)
        except BlockingIOError:
            pass
    sink.close()
    vehicle.close()
    return {"whole tick": whole, "critical path": critical}


def measure(calls: int, blocks: int) -> dict[str, float]:
    sc = load_scenario("paper")
    vehicle = Vehicle(sc, listen=("127.0.0.1", 0))
    sim, ctl = vehicle.sim, vehicle.control_link
    sink = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sink.bind(("127.0.0.1", 0))
    sink.setblocking(False)
    ctl.peer = sink.getsockname()
    ctl.peer_sysid = 1
    # the receive path (an older tree's Link receives itself)
    ctl_ingest = ctl.receiver.ingest if hasattr(ctl, "receiver") else ctl._ingest
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
            ctl_ingest(raw, ctl.peer, out)
            for msg in out:
                vehicle.held.time_usec = -1
                vehicle.dispatch(msg, 0)
        return run

    # One RK4 step of the simulator's airframe through the physics module's public stepper
    # (compiled as the simulator flies it), at hover thrust over one physics period.
    rk4 = rk4_stepper(sim.params)
    x = list(sim.state_vector)
    hover = (sc.vehicle.mass_kg * sc.vehicle.gravity_mps2, 0.0, 0.0, 0.0)
    h = sim.physics_dt_s
    pieces: dict[str, Callable[[], Any]] = {
        "RK4 step alone": lambda: rk4(x, hover, h),
        "simulator control tick (attack, motors, RK4, sensors)": sim.step_control_period,
        "sensor sampling alone": sim.measure,
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
    for record in (False, True):
        label = "with a recorder's hand-off" if record else "no recorder"
        clocked = measure_clock(100, max(args.blocks, args.calls // 100), record)
        result[f"lockstep clock, {label}: whole tick"] = clocked["whole tick"]
        result[f"lockstep clock, {label}: reply → next state sent"] = clocked["critical path"]
    print(f"bench_vehicle_tick (python {platform.python_version()}, min of {args.blocks} "
          f"blocks of {args.calls} calls)")
    for name, us in result.items():
        print(f"  {name:<68}  {us:>8.2f} µs")
    if args.json:
        Path(args.json).write_text(json.dumps({"python": platform.python_version(),
                                               "us": result}, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
