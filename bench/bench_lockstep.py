"""Lockstep speed of the simulated vehicle, against the bare ping-pong ceiling.

Measures, on this machine:

1. physics: µs per 1 ms RK4 step (``rk4_step`` alone) and per control tick of the
   simulator (motors + attacker + RK4 + sensors), the cost of building and packing one
   tick's state (ODOMETRY + ACTUATOR_OUTPUT_STATUS + ESC_TELEMETRY_1_TO_4), and the
   in-process per-tick breakdown of the whole lockstep loop (``--breakdown-only``: just
   these, no subprocesses);
2. lockstep: ticks/s of ``tfl-mav sim`` (a subprocess, 1 kHz physics and control) flown by
   the lockstep client of the tests (:class:`harness.pilot.Pilot`: our Link, hover
   commands), without and with ``--mcap`` recording;
3. the full loop: ``tfl-mav sim --mcap`` flown by ``tfl-mav fly --mcap`` (the controller
   daemon: law, detector, both MCAP recorders), ticks per wall second of the flight as the
   simulator reports it;
4. ceiling: a bare two-process pymavlink UDP ping-pong (ODOMETRY out, HIL_ACTUATOR_CONTROLS
   back, nothing else), and issue #13's same-run ratios of (2) and (3) to it.

Usage: ``python bench/bench_lockstep.py [--ticks N] [--breakdown-only] [--json FILE]`` from
the repository root.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import re
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from pymavlink.dialects.v20 import ardupilotmega as mav

from harness.pilot import Pilot, hover_controls
from harness.processes import CLI, popen_sim

WARMUP_TICKS = 200


# ---------------------------------------------------------------------------- physics
def bench_physics(n_steps: int) -> dict[str, float]:
    from sitl.physics import mix, rk4_step
    from sitl.vehicle import Vehicle
    from tfl_mav.scenario import load_scenario

    sc = load_scenario("paper").replace(**{"attack.rotor": 0})
    vehicle = Vehicle(sc, listen=("127.0.0.1", 0))
    sim = vehicle.sim
    hover = [sc.vehicle.mass_kg * sc.vehicle.gravity_mps2 / 4.0] * 4
    x = list(sim.state.as_list())
    wrench = mix(sim.params, hover)
    t0 = time.perf_counter()
    for _ in range(n_steps):
        x = rk4_step(sim.params, x, wrench, 1e-3)
    rk4_us = (time.perf_counter() - t0) / n_steps * 1e6

    sim.set_command(hover)
    t0 = time.perf_counter()
    for _ in range(n_steps):
        sim.step_control_period()
    tick_us = (time.perf_counter() - t0) / n_steps * 1e6

    vehicle.control_link.peer = None   # build and pack only; nothing is sent
    t0 = time.perf_counter()
    for _ in range(n_steps):
        vehicle._publish_state()        # the tick's 3 messages built and packed (unsent)
    publish_us = (time.perf_counter() - t0) / n_steps * 1e6
    vehicle.close()
    return {"rk4_step_us": rk4_us, "sim_tick_us": tick_us, "state_build_pack_us": publish_us}


def bench_breakdown(n_ticks: int) -> dict[str, float]:
    """µs per control tick of each piece of the lockstep loop, in-process, over a closed-loop
    hover flight (paper scenario, no attack): thread CPU time, mean of ``n_ticks``."""
    import copy

    from sitl.vehicle import Vehicle
    from tfl_mav.flight_computer import FlightComputer
    from tfl_mav.frames import paper_from_odometry
    from tfl_mav.link.transport import Link
    from tfl_mav.scenario import load_scenario

    sc = load_scenario("paper").replace(**{"attack.rotor": 0})
    vehicle = Vehicle(sc, listen=("127.0.0.1", 0))
    sim, report = vehicle.sim, vehicle.report
    vehicle.control_link.peer = None                  # pack only: counted unsent
    fc = FlightComputer(sc, attack_info="detector")
    detector = copy.deepcopy(fc.detector)
    daemon_link = Link.listen(("127.0.0.1", 0), src_system=1, src_component=191,
                              peer=("127.0.0.1", 9))
    sim_link = Link.listen(("127.0.0.1", 0), src_system=1, src_component=1,
                           peer=("127.0.0.1", 9))
    sender = ("127.0.0.1", 9)
    acc: dict[str, float] = dict.fromkeys(
        ("physics + motors + attacker", "sensor sampling", "state messages built",
         "pack ODOMETRY + AOS + ESC (Link)", "parse ODOMETRY + AOS + ESC (Link)",
         "frame conversion (paper_from_odometry)", "detector", "law + detector (step)",
         "pack HIL_ACTUATOR_CONTROLS (Link)", "parse HIL_ACTUATOR_CONTROLS (Link)"), 0.0)
    cpu = time.thread_time
    applied = list(sim.rotor_commands_n)
    hil_bytes: list[bytes] = []
    daemon_link._sock.close()                         # never sends; pack through send()
    daemon_link._sendto = lambda raw, msg: hil_bytes.append(raw) or len(raw)  # type: ignore
    applied_usec = 0
    for _ in range(n_ticks):
        t0 = cpu()
        msgs = report.update(applied_usec)    # (ODOMETRY, ACTUATOR_OUTPUT_STATUS, ESC)
        t1 = cpu()
        vehicle.control_link.send_many(msgs)
        t2 = cpu()
        raw = b"".join(m.pack(sim_link.packer) for m in msgs)
        t2b = cpu()
        out: list = []
        daemon_link._ingest(raw, sender, out)
        t3 = cpu()
        if len(out) != 3:
            raise RuntimeError(f"breakdown: parsed {len(out)} of the tick's 3 messages")
        odom_in, _aos_in, esc_in = out
        state = paper_from_odometry(odom_in)
        t4 = cpu()
        rpm = [float(r) for r in esc_in.rpm]
        detector.update(sim.time_s, rpm, applied)
        t5 = cpu()
        res = fc.step(sim.time_s, state, rpm, applied)
        t6 = cpu()
        applied_usec = odom_in.time_usec             # the command this tick answers
        hil = mav.MAVLink_hil_actuator_controls_message(
            applied_usec, [f / sc.vehicle.thrust_max_n for f in res.thrust_n]
            + [0.0] * 12, 128, 1)
        t6b = cpu()
        daemon_link.send(hil)
        t7 = cpu()
        back: list = []
        sim_link._ingest(hil_bytes.pop(), sender, back)
        t8 = cpu()
        sim.set_command(res.thrust_n)
        applied = list(sim.rotor_commands_n)
        t9 = cpu()
        sim.step_control_period()
        t10 = cpu()
        sim._measure()                                 # once more, timed alone
        t11 = cpu()
        acc["state messages built"] += t1 - t0
        acc["pack ODOMETRY + AOS + ESC (Link)"] += t2 - t1
        acc["parse ODOMETRY + AOS + ESC (Link)"] += t3 - t2b
        acc["frame conversion (paper_from_odometry)"] += t4 - t3
        acc["detector"] += t5 - t4
        acc["law + detector (step)"] += t6 - t5
        acc["pack HIL_ACTUATOR_CONTROLS (Link)"] += t7 - t6b
        acc["parse HIL_ACTUATOR_CONTROLS (Link)"] += t8 - t7
        acc["physics + motors + attacker"] += (t10 - t9) - (t11 - t10)
        acc["sensor sampling"] += t11 - t10
    vehicle.close()
    sim_link.close()
    return {k: 1e6 * v / n_ticks for k, v in acc.items()}


# ---------------------------------------------------------------------------- clients
def _client_socket() -> socket.socket:
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", 0))
    sock.settimeout(10.0)
    return sock


def lockstep_client(address: tuple[str, int], n_ticks: int, scenario: object
                    ) -> dict[str, float]:
    """Fly ``n_ticks`` hover ticks against a lockstep vehicle with the tests' Pilot; the
    first ``WARMUP_TICKS`` are not timed."""
    with Pilot(address) as pilot:
        pilot.hello()
        hover = hover_controls(scenario)
        pilot.fly(WARMUP_TICKS, hover, timeout_s=10.0, keep=False)
        t_start = time.perf_counter()
        pilot.fly(n_ticks - WARMUP_TICKS, hover, timeout_s=10.0, keep=False)
        elapsed = time.perf_counter() - t_start
    measured = n_ticks - WARMUP_TICKS
    return {"ticks": measured, "seconds": elapsed, "ticks_per_s": measured / elapsed}


def pingpong_server(port_file: str, n_ticks: int) -> None:
    """The 'vehicle' half of the ping-pong: ODOMETRY out, wait for the matching reply."""
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", 0))
    Path(port_file).write_text(str(sock.getsockname()[1]))
    mv = mav.MAVLink(None, 1, 1)
    _, peer = sock.recvfrom(65535)          # the client's hello
    cov = [0.0] * 21
    for k in range(n_ticks):
        t = k * 1000
        odom = mav.MAVLink_odometry_message(t, 1, 12, 0.3, 1.5, -0.5,
                                            [math.sqrt(0.5), 0.0, 0.0, math.sqrt(0.5)],
                                            0.0, 0.0, 0.0, 0.0, 0.0, 0.0, cov, cov, 0, 6, 100)
        sock.sendto(odom.pack(mv), peer)
        while True:
            data = sock.recv(65535)
            msgs = mv.parse_buffer(data) or ()
            if any(m.get_msgId() == 93 and m.time_usec == t for m in msgs):
                break
    sock.close()


def bench_pingpong(n_ticks: int) -> dict[str, float]:
    tmp = tempfile.TemporaryDirectory()
    port_file = Path(tmp.name) / "pingpong.port"
    proc = subprocess.Popen([sys.executable, __file__, "--role", "pingpong-server",
                             "--port-file", str(port_file), "--ticks", str(n_ticks)])
    try:
        deadline = time.monotonic() + 20
        while not port_file.exists() or not port_file.read_text():
            if time.monotonic() > deadline or proc.poll() is not None:
                raise RuntimeError("ping-pong server did not start")
            time.sleep(0.01)
        address = ("127.0.0.1", int(port_file.read_text()))
        sock = _client_socket()
        mv = mav.MAVLink(None, 1, 191)
        sock.sendto(b"hello", address)
        controls = [0.34] * 4 + [0.0] * 12
        ticks = 0
        t_start = 0.0
        while ticks < n_ticks:
            data = sock.recv(65535)
            for msg in mv.parse_buffer(data) or ():
                if msg.get_msgId() == 331:
                    reply = mav.MAVLink_hil_actuator_controls_message(msg.time_usec, controls,
                                                                      128, 1)
                    sock.sendto(reply.pack(mv), address)
                    ticks += 1
                    if ticks == WARMUP_TICKS:
                        t_start = time.perf_counter()
        elapsed = time.perf_counter() - t_start
        sock.close()
        proc.wait(timeout=10)
    finally:
        if proc.poll() is None:
            proc.kill()
        tmp.cleanup()
    measured = n_ticks - WARMUP_TICKS
    return {"ticks": measured, "seconds": elapsed, "ticks_per_s": measured / elapsed}


def bench_vehicle(n_ticks: int, mcap: Path | None = None) -> dict[str, float]:
    """``tfl-mav sim`` in a subprocess (recording to ``mcap`` if given), flown in lockstep
    by the Pilot."""
    from tfl_mav.scenario import load_scenario

    sc = load_scenario("paper")
    duration_s = n_ticks / 1000.0
    extra = ["--mcap", str(mcap)] if mcap is not None else []
    proc, address = popen_sim(["--set", "attack.rotor=0", "--set",
                               "initial.position_m=[0, 0, 5]", "--duration",
                               f"{duration_s:g}", *extra], "paper")
    try:
        result = lockstep_client(address, n_ticks, sc)
        out, _ = proc.communicate(timeout=20)
    finally:
        if proc.poll() is None:
            proc.kill()
    if proc.returncode != 0:
        raise RuntimeError(f"sim exited with {proc.returncode}: {out}")
    result["real_time_factor"] = result["ticks_per_s"] / 1000.0
    return result


_SIM_RESULT_RE = re.compile(r"(\d+) ticks, ([\d.]+) s sim in ([\d.]+) s wall")


def bench_full_loop(n_ticks: int, out_dir: Path, scenario: str = "paper") -> dict[str, float]:
    """``tfl-mav sim --mcap`` + ``tfl-mav fly --mcap`` (the daemon), as ``tfl-mav demo``
    runs them; ticks per wall second from the simulator's own count (the clock starts when
    the controller connects, so start-up is not counted)."""
    duration = f"{n_ticks / 1000.0:g}"
    proc, address = popen_sim(["--duration", duration, "--mcap", str(out_dir / "run.mcap")],
                              scenario)
    try:
        fly = subprocess.run([*CLI, "fly", scenario, "--vehicle", f"{address[0]}:{address[1]}",
                              "--duration", duration, "--mcap", str(out_dir / "ctl.mcap"),
                              "--quiet"], capture_output=True, text=True, timeout=600)
        out, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    match = _SIM_RESULT_RE.search(out + err)
    if match is None:
        raise RuntimeError(f"no result line from sim (fly exit {fly.returncode}):\n{out}{err}"
                           f"{fly.stderr}")
    ticks, wall = int(match.group(1)), float(match.group(3))
    return {"ticks": ticks, "seconds": wall, "ticks_per_s": ticks / wall,
            "real_time_factor": ticks / wall / 1000.0}


# ---------------------------------------------------------------------------- main
_WIDTH = 62


def _print_in_process(physics: dict[str, float], breakdown: dict[str, float]) -> None:
    rows = [
        ("physics: RK4 step (1 ms, rk4_step alone)", physics["rk4_step_us"]),
        ("physics: simulator control tick (motors+attacker+RK4+sensors)",
         physics["sim_tick_us"]),
        ("vehicle: build + pack ODOMETRY + AOS + ESC_TELEMETRY",
         physics["state_build_pack_us"]),
    ]
    for name, us in rows:
        print(f"  {name:<{_WIDTH}}  {us:>11.1f} µs")
    print("\nper-tick breakdown (µs, in-process, thread CPU time)")
    for name, us in breakdown.items():
        print(f"  {name:<{_WIDTH}}  {us:>11.1f} µs")
    print(f"  {'total':<{_WIDTH}}  {sum(breakdown.values()):>11.1f} µs")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--ticks", type=int, default=20000,
                        help="lockstep ticks per network measurement (default 20000)")
    parser.add_argument("--json", metavar="FILE", help="also write the numbers as JSON")
    parser.add_argument("--breakdown-only", action="store_true",
                        help="only the in-process physics figures and per-tick breakdown")
    parser.add_argument("--role", help=argparse.SUPPRESS)
    parser.add_argument("--port-file", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.role == "pingpong-server":
        pingpong_server(args.port_file, args.ticks)
        return 0
    if args.ticks <= WARMUP_TICKS:
        parser.error(f"--ticks: must be > {WARMUP_TICKS}")

    physics = bench_physics(20000)
    breakdown = bench_breakdown(3000)
    if args.breakdown_only:
        _print_in_process(physics, breakdown)
        if args.json:
            Path(args.json).write_text(json.dumps(
                {"python": platform.python_version(), "cpus": os.cpu_count(),
                 "physics": physics, "breakdown_us": breakdown}, indent=2))
        return 0
    pingpong = bench_pingpong(args.ticks)
    vehicle = bench_vehicle(args.ticks)
    with tempfile.TemporaryDirectory() as tmp:
        recorded = bench_vehicle(args.ticks, Path(tmp) / "run.mcap")
        recorded["mcap_bytes"] = (Path(tmp) / "run.mcap").stat().st_size
    with tempfile.TemporaryDirectory() as tmp:
        full = bench_full_loop(args.ticks, Path(tmp))
    pingpong_after = bench_pingpong(args.ticks)     # before and after: the load drifts
    ceiling = 0.5 * (pingpong["ticks_per_s"] + pingpong_after["ticks_per_s"])
    ratio = vehicle["ticks_per_s"] / ceiling
    ratio_full = full["ticks_per_s"] / ceiling
    print(f"bench_lockstep ({args.ticks} ticks, python {platform.python_version()}, "
          f"{os.cpu_count()} cpus)")
    _print_in_process(physics, breakdown)
    rows = [
        ("ceiling: bare pymavlink UDP ping-pong (mean of before/after)",
         f"{ceiling:.0f} ticks/s"),
        ("lockstep: tfl-mav sim + harness Pilot (our Link), no MCAP",
         f"{vehicle['ticks_per_s']:.0f} ticks/s"),
        ("lockstep with sim --mcap (recorder child process)",
         f"{recorded['ticks_per_s']:.0f} ticks/s"),
        ("full loop: sim --mcap + fly --mcap (daemon, law, detector)",
         f"{full['ticks_per_s']:.0f} ticks/s"),
        ("full loop: real-time factor at 1 kHz", f"{full['real_time_factor']:.2f}x"),
    ]
    print("\nlockstep over UDP")
    for name, value in rows:
        print(f"  {name:<{_WIDTH}}  {value:>14}")
    print("\nissue #13 (same-run ratios to the bare ping-pong)        now    goal")
    print(f"  full lockstep loop (sim + daemon + both MCAP recorders)  {ratio_full:5.2f}  ≥ 0.5")
    print(f"  lockstep sim + bare client, no MCAP                      {ratio:5.2f}  ≥ 0.7")
    if args.json:
        Path(args.json).write_text(json.dumps({
            "ticks": args.ticks, "python": platform.python_version(), "cpus": os.cpu_count(),
            "physics": physics, "lockstep": vehicle, "lockstep_mcap": recorded,
            "breakdown_us": breakdown, "full_loop": full, "pingpong": pingpong,
            "pingpong_after": pingpong_after,
            "ratio_lockstep_to_pingpong": ratio,
            "ratio_full_loop_to_pingpong": ratio_full}, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
