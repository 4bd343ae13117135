"""Lockstep speed of the simulated vehicle, against the bare ping-pong ceiling.

Measures, on this machine:

1. physics: µs per 1 ms RK4 step (``rk4_step`` alone) and per control tick of the
   simulator (motors + attacker + RK4 + sensors), the cost of building and packing one
   tick's state (ODOMETRY + ACTUATOR_OUTPUT_STATUS + ESC_TELEMETRY_1_TO_4), and the
   in-process per-tick breakdown of the whole lockstep loop (``--breakdown-only``: just
   these, no subprocesses);
2. lockstep: ticks/s of ``tfl-mav sim`` (a subprocess, 1 kHz physics and control) flown by
   the lockstep client of the tests (:class:`tfl_mav.tools.harness.pilot.Pilot`: our Link, hover
   commands), without and with ``--mcap`` recording;
3. the full loop: ``tfl-mav sim --mcap`` flown by ``tfl-mav fly --mcap`` (the controller
   daemon: law, detector, both MCAP recorders), ticks per wall second of the flight as the
   simulator reports it;
4. ceiling: a bare two-process pymavlink UDP ping-pong (ODOMETRY out, HIL_ACTUATOR_CONTROLS
   back, nothing else), and the same-run ratios of (2) and (3) to it;
5. A/B: the full loop again with the recorder children niced only
   (``TFL_MAV_RECORDER_IDLE=0``) and idle (the lockstep default,
   :mod:`tfl_mav.flightlog.child_priority`), alternating, ``--ab-rounds`` each.

6. ``--ab-tree DIR``: only the full loop, this checkout and another (e.g. a worktree of
   the commit before a change) alternating, ``--ab-pairs`` pairs, each in a fresh
   interpreter whose ``tfl_mav`` is that tree's: ticks/s, the per-pair ratio, and the
   MiB per flight-minute of both files of each flight.

Usage: ``python bench/bench_lockstep.py [--ticks N] [--json FILE] [--breakdown-only |
--no-breakdown] [--no-profile] [--ab-rounds N] [--ab-tree DIR [--ab-pairs N]]`` from the
repository root;
``--profile-vehicle FILE`` only profiles the sim process of (2) (cProfile, CPU timer) and
prints where its time goes.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import re
import socket
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as mav

from tfl_mav.tools.harness.pilot import Pilot, hover_controls
from tfl_mav.tools.harness.processes import LISTEN_RE, popen_sim

WARMUP_TICKS = 200


# ---------------------------------------------------------------------------- physics
def bench_physics(n_steps: int) -> dict[str, float]:
    from tfl_mav.scenario import load_scenario
    from tfl_mav.sitl.physics import mix, rk4_step
    from tfl_mav.sitl.vehicle import Vehicle

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
        vehicle.publish_state()         # the tick's 3 messages built and packed (unsent)
    publish_us = (time.perf_counter() - t0) / n_steps * 1e6
    vehicle.close()
    return {"rk4_step_us": rk4_us, "sim_tick_us": tick_us, "state_build_pack_us": publish_us}


def bench_breakdown(n_ticks: int) -> dict[str, float]:
    """µs per control tick of each piece of the lockstep loop, in-process, over a closed-loop
    hover flight (paper scenario, no attack): thread CPU time, mean of ``n_ticks``."""
    import copy

    from tfl_mav.controller.flight_computer import FlightComputer
    from tfl_mav.link.transport import Link
    from tfl_mav.model.frames import paper_from_odometry
    from tfl_mav.scenario import load_scenario
    from tfl_mav.sitl.vehicle import Vehicle

    to_state: Any = paper_from_odometry
    try:    # the daemon's path: the received tuple's fields, no attribute reads
        from tfl_mav.controller.daemon_intake import ODOMETRY_FIELDS
        from tfl_mav.model.frames import paper_from_odometry_fields

        def to_state(msg: Any) -> Any:
            return paper_from_odometry_fields(*msg[:ODOMETRY_FIELDS])
    except ImportError:     # an older tree
        pass

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
    # the receive paths (an older tree's Link receives itself)
    daemon_ingest, sim_ingest = (link.receiver.ingest if hasattr(link, "receiver")
                                 else link._ingest for link in (daemon_link, sim_link))
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
        msgs = report.build(applied_usec)     # (ODOMETRY, ACTUATOR_OUTPUT_STATUS, ESC)
        t1 = cpu()
        vehicle.control_link.send_many(msgs)
        t2 = cpu()
        raw = b"".join(sim_link._codec.pack(m, sim_link.packer) for m in msgs)
        t2b = cpu()
        out: list = []
        daemon_ingest(raw, sender, out)
        t3 = cpu()
        if len(out) != 3:
            raise RuntimeError(f"breakdown: parsed {len(out)} of the tick's 3 messages")
        odom_in, _aos_in, esc_in = out
        state = to_state(odom_in)
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
        sim_ingest(hil_bytes.pop(), sender, back)
        t8 = cpu()
        sim.set_command(res.thrust_n)
        applied = list(sim.rotor_commands_n)
        t9 = cpu()
        sim.step_control_period()
        t10 = cpu()
        sim.measure()                                  # once more, timed alone
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


def bench_vehicle(n_ticks: int, mcap: Path | None = None,
                  profile: Path | None = None) -> dict[str, float]:
    """``tfl-mav sim`` in a subprocess (recording to ``mcap`` if given), flown in lockstep
    by the Pilot. ``profile``: run the sim under cProfile (CPU timer, bench/profiling.py)
    and dump its stats there (the ticks/s are then the profiled ones)."""
    from tfl_mav.scenario import load_scenario

    sc = load_scenario("paper")
    duration_s = n_ticks / 1000.0
    extra = ["--mcap", str(mcap)] if mcap is not None else []
    args = ["--set", "attack.rotor=0", "--set", "initial.position_m=[0, 0, 5]", "--duration",
            f"{duration_s:g}", *extra]
    if profile is None:
        proc, address = popen_sim(args, "paper")
    else:
        proc = subprocess.Popen([sys.executable, _PROFILER, str(profile),
                                 "tfl_mav.tools.cli.main", "sim",
                                 "paper", "--listen", "127.0.0.1:0", *args],
                                stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        assert proc.stdout is not None
        match = LISTEN_RE.search(proc.stdout.readline())
        if match is None:
            proc.kill()
            raise RuntimeError(f"sim did not start: {proc.communicate()[0]}")
        address = (match.group(1), int(match.group(2)))
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
_PROGRESS_RE = re.compile(r"^progress ([\d.]+) ")
_PROFILER = str(Path(__file__).with_name("profiling.py"))


def bench_full_loop(n_ticks: int, out_dir: Path, scenario: str = "paper",
                    profile_dir: Path | None = None,
                    env_extra: dict[str, str] | None = None) -> dict[str, Any]:
    """``tfl-mav sim --mcap`` + ``tfl-mav fly --mcap`` (the daemon), as ``tfl-mav demo``
    runs them; ticks per wall second from the simulator's own count (the clock starts when
    the controller connects, so start-up is not counted).

    Also the CPU each of the four processes (sim, daemon, their recorder children) spent
    per tick, read from /proc on ``fly --progress``'s lines (one per sim second): the
    window from the first to the last line, so start-up and shutdown are not counted.
    ``profile_dir``: run sim and fly under cProfile (CPU timer) and the recorder children
    with ``TFL_MAV_PROFILE``, dumping ``sim.prof``, ``fly.prof``, ``recorder-PID.prof``."""
    from profiling import ProcessCPU  # bench/profiling.py, next to this file

    duration = f"{n_ticks / 1000.0:g}"
    env = dict(os.environ, **env_extra) if env_extra else None
    prefix: dict[str, list[str]] = {"sim": [], "fly": []}
    if profile_dir is not None:
        env = dict(env or os.environ, TFL_MAV_PROFILE=str(profile_dir))
        prefix = {role: [_PROFILER, str(profile_dir / f"{role}.prof"), "tfl_mav.tools.cli.main"]
                  for role in ("sim", "fly")}
    sim_cmd = [sys.executable, *(prefix["sim"] or ["-m", "tfl_mav.tools.cli"]), "sim", scenario,
               "--listen", "127.0.0.1:0", "--duration", duration,
               "--mcap", str(out_dir / "run.mcap")]
    proc = subprocess.Popen(sim_cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, env=env)
    fly = None
    try:
        assert proc.stdout is not None
        match = LISTEN_RE.search(proc.stdout.readline())
        if match is None:
            raise RuntimeError(f"sim did not start: {proc.communicate(timeout=20)}")
        fly = subprocess.Popen(
            [sys.executable, *(prefix["fly"] or ["-m", "tfl_mav.tools.cli"]), "fly", scenario,
             "--vehicle", f"{match.group(1)}:{match.group(2)}", "--duration", duration,
             "--mcap", str(out_dir / "ctl.mcap"), "--quiet", "--progress"],
            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, env=env)
        cpu = ProcessCPU({proc.pid: "sim", fly.pid: "daemon"})
        marks: list[tuple[float, dict[str, float]]] = []
        policies: dict[str, str] = {}
        fly_err: list[str] = []
        assert fly.stderr is not None
        for line in fly.stderr:
            m = _PROGRESS_RE.match(line)
            if m:
                marks.append((float(m.group(1)), cpu.snapshot()))
                if len(marks) == 1:
                    policies = cpu.child_policies()
            else:
                fly_err.append(line)
        fly.wait(timeout=600)
        out, err = proc.communicate(timeout=60)
    finally:
        for p in (proc, fly):
            if p is not None and p.poll() is None:
                p.kill()
    match = _SIM_RESULT_RE.search(out + err)
    if match is None:
        raise RuntimeError(f"no result line from sim (fly exit {fly.returncode}):\n{out}{err}"
                           f"{''.join(fly_err)}")
    ticks, wall = int(match.group(1)), float(match.group(3))
    cpu_us: dict[str, float] = {}
    if len(marks) >= 2:
        (t0, a), (t1, b) = marks[0], marks[-1]
        window_ticks = round((t1 - t0) * 1000.0)
        for label in b:
            role = label.split(" child")[0]
            name = f"{role} recorder child" if " child " in label else role
            cpu_us[name] = 1e6 * (b[label] - a.get(label, 0.0)) / max(1, window_ticks)
    return {"ticks": ticks, "seconds": wall, "ticks_per_s": ticks / wall,
            "real_time_factor": ticks / wall / 1000.0, "cpu_us_per_tick": cpu_us,
            "recorder_policy": policies}


def bench_ab(n_ticks: int, rounds: int, first: dict[str, Any]) -> dict[str, Any]:
    """The full loop with the recorder children niced only and idle, alternating
    (``rounds`` each, plus ``first``: the run with the default); medians of each and of
    the paired ratios idle / niced."""
    niced: list[float] = []
    idle: list[float] = [first["ticks_per_s"]]
    for _ in range(rounds):
        for env, out in (({"TFL_MAV_RECORDER_IDLE": "0"}, niced), ({}, idle)):
            with tempfile.TemporaryDirectory() as tmp:
                out.append(bench_full_loop(n_ticks, Path(tmp), env_extra=env)["ticks_per_s"])
    pairs = [i / n for n, i in zip(niced, idle[1:], strict=True)]
    return {"niced_ticks_per_s": niced, "idle_ticks_per_s": idle,
            "niced_median": statistics.median(niced), "idle_median": statistics.median(idle),
            "paired_gain_median": statistics.median(pairs)}


_FULL_LOOP_CHILD = """
import json, pathlib, sys, tempfile
import bench_lockstep as b
b._cores("compiled")
with tempfile.TemporaryDirectory() as d:
    r = b.bench_full_loop({ticks}, pathlib.Path(d))
    r["mcap_bytes"] = {{n: (pathlib.Path(d) / n).stat().st_size for n in ("run.mcap", "ctl.mcap")}}
# every module of the package from the tree measured (an editable install of another
# checkout maps tfl_mav.sitl and tfl_mav.tools to its own directories)
tree = pathlib.Path({tree!r})
elsewhere = sorted(n for n, m in sys.modules.items() if n.split(".")[0] == "tfl_mav"
                   and getattr(m, "__file__", None)
                   and not pathlib.Path(m.__file__).resolve().is_relative_to(tree))
assert not elsewhere, f"not from {{tree}}: {{elsewhere[:5]}}"
print(json.dumps(r))
"""


def full_loop_in(tree: Path, n_ticks: int) -> dict[str, Any]:
    """:func:`bench_full_loop` run by checkout ``tree`` (its bench and its ``tfl_mav`` first
    on the path, its directory the processes' working directory), in a fresh interpreter:
    the tree's own venv's if it has one (its editable install maps its own directories)."""
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(
        filter(None, (str(tree), str(tree / "bench"), os.environ.get("PYTHONPATH")))))
    python = tree / ".venv" / "bin" / "python"
    done = subprocess.run([str(python) if python.exists() else sys.executable,
                           "-c", _FULL_LOOP_CHILD.format(
        tree=str(tree.resolve()), ticks=n_ticks)], cwd=tree, env=env, capture_output=True,
        text=True, check=False)
    if done.returncode != 0:
        raise RuntimeError(f"full loop in {tree} failed: {done.stderr[-2000:]}")
    return json.loads(done.stdout.splitlines()[-1])


def bench_trees(n_ticks: int, pairs: int, other: Path) -> dict[str, Any]:
    """The full loop in ``other`` and in this checkout, alternating (``other`` first in
    each pair): ticks/s and MiB per flight-minute of each run, medians, per-pair ratios."""
    here = Path(__file__).resolve().parents[1]
    runs: dict[str, list[dict[str, Any]]] = {"other": [], "this": []}
    for _ in range(pairs):
        runs["other"].append(full_loop_in(other, n_ticks))
        runs["this"].append(full_loop_in(here, n_ticks))
    minutes = n_ticks / 1000.0 / 60.0
    out: dict[str, Any] = {"ticks": n_ticks, "pairs": pairs, "other_tree": str(other)}
    for key, rs in runs.items():
        out[key] = {"ticks_per_s": [r["ticks_per_s"] for r in rs],
                    "mib_per_min": [{n: b / 2**20 / minutes for n, b in r["mcap_bytes"].items()}
                                    for r in rs],
                    "cpu_us_per_tick": [r["cpu_us_per_tick"] for r in rs]}
        out[key]["median_ticks_per_s"] = statistics.median(out[key]["ticks_per_s"])
        out[key]["median_mib_per_min"] = statistics.median(
            sum(m.values()) for m in out[key]["mib_per_min"])
        for proc_name in rs[0]["cpu_us_per_tick"]:
            out[key].setdefault("median_cpu_us", {})[proc_name] = statistics.median(
                c[proc_name] for c in out[key]["cpu_us_per_tick"])
    ratios = [t / o for t, o in zip(out["this"]["ticks_per_s"], out["other"]["ticks_per_s"],
                                    strict=True)]
    out["pair_ratios"] = ratios
    out["pair_ratio_geomean"] = math.exp(sum(map(math.log, ratios)) / len(ratios))
    return out


def _print_trees(ab: dict[str, Any]) -> None:
    print(f"full loop, {ab['other_tree']} vs this checkout ({ab['pairs']} alternated pairs, "
          f"{ab['ticks']} ticks each; load {os.getloadavg()[0]:.2f})")
    for i, r in enumerate(ab["pair_ratios"]):
        o, t = ab["other"], ab["this"]
        print(f"  pair {i + 1}: {o['ticks_per_s'][i]:7.0f} → {t['ticks_per_s'][i]:7.0f} ticks/s"
              f"  ({r:.3f})   MiB/flight-min {sum(o['mib_per_min'][i].values()):5.1f} → "
              f"{sum(t['mib_per_min'][i].values()):5.1f}")
    print(f"  median ticks/s {ab['other']['median_ticks_per_s']:.0f} → "
          f"{ab['this']['median_ticks_per_s']:.0f}; per-pair geometric mean "
          f"{ab['pair_ratio_geomean']:.3f}")
    print(f"  median MiB per flight-minute (run.mcap + ctl.mcap) "
          f"{ab['other']['median_mib_per_min']:.1f} → {ab['this']['median_mib_per_min']:.1f}")
    for proc_name, us in ab["this"]["median_cpu_us"].items():
        print(f"  {proc_name:<40s} CPU µs/tick (median) "
              f"{ab['other']['median_cpu_us'].get(proc_name, math.nan):7.1f} → {us:7.1f}")


def profile_breakdown(n_ticks: int, cpu_us: dict[str, float]) -> dict[str, dict[str, float]]:
    """Where each process's CPU goes, per tick: the shares of a cProfile'd (CPU timer) run
    of the full loop, scaled to the unprofiled CPU per tick ``cpu_us`` (process → µs)."""
    from profiling import STARTUP, categorize

    out: dict[str, dict[str, float]] = {}
    with tempfile.TemporaryDirectory() as tmp, tempfile.TemporaryDirectory() as profs:
        bench_full_loop(n_ticks, Path(tmp), profile_dir=Path(profs))
        recorders = sorted(Path(profs).glob("recorder-*.prof"), key=lambda p: p.stat().st_size)
        # the vehicle's recorder sees more frames (GCS telemetry, truth): the bigger profile
        files = {"sim": (Path(profs) / "sim.prof", "sim"),
                 "daemon": (Path(profs) / "fly.prof", "daemon")}
        if len(recorders) == 2:
            files["daemon recorder child"] = (recorders[0], "recorder")
            files["sim recorder child"] = (recorders[1], "recorder")
        for name, (path, role) in files.items():
            if not path.exists() or name not in cpu_us:
                continue
            shares = categorize(path, role)
            shares.pop(STARTUP)
            total = sum(shares.values()) or 1.0
            out[name] = {k: cpu_us[name] * v / total for k, v in shares.items()}
    return out


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
    if not breakdown:
        return
    print("\nper-tick breakdown (µs, in-process, thread CPU time)")
    for name, us in breakdown.items():
        print(f"  {name:<{_WIDTH}}  {us:>11.1f} µs")
    print(f"  {'total':<{_WIDTH}}  {sum(breakdown.values()):>11.1f} µs")


def _cores(core: str) -> None:
    """Every process of the bench (subprocesses inherit it) on one kind of core (the
    recorder children too); compiled ones are built (or found in the cache)
    now, for every case flown, so no timed process waits for a compiler or flies Python
    until one is done."""
    os.environ["TFL_MAV_NATIVE"] = "sync" if core == "compiled" else "off"
    if core == "compiled":
        from tfl_mav.controller.flight_computer import FlightComputer
        from tfl_mav.scenario import load_scenario
        from tfl_mav.sitl.simulator import Simulator

        for sc in (load_scenario("paper"), load_scenario("paper").replace(
                **{"attack.rotor": 0})):
            FlightComputer(sc)
            Simulator(sc)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--ticks", type=int, default=20000,
                        help="lockstep ticks per network measurement (default 20000)")
    parser.add_argument("--json", metavar="FILE", help="also write the numbers as JSON")
    parser.add_argument("--breakdown-only", action="store_true",
                        help="only the in-process physics figures and per-tick breakdown")
    parser.add_argument("--no-breakdown", action="store_true",
                        help="skip the in-process per-piece breakdown")
    parser.add_argument("--no-profile", action="store_true",
                        help="skip the profiled run of the full loop (per-process breakdown)")
    parser.add_argument("--profile-vehicle", metavar="FILE",
                        help="only: fly the lockstep sim (Pilot, no MCAP) under cProfile, "
                             "dump the stats to FILE and print the top functions")
    parser.add_argument("--core", choices=("compiled", "python"), default="compiled",
                        help="the law's, the detector's and the RK4's cores in every process: "
                             "compiled to C (TFL_MAV_NATIVE=sync, built before anything is "
                             "timed; the default) or the generated Python (off)")
    parser.add_argument("--ab-rounds", type=int, default=2, metavar="N",
                        help="also fly the full loop N more times each with the recorder "
                             "children niced only (TFL_MAV_RECORDER_IDLE=0) and idle (the "
                             "lockstep default), alternating: the idle children's gain in "
                             "the same run (default 2; 0: skip)")
    parser.add_argument("--ab-tree", metavar="DIR", type=Path,
                        help="only: the full loop of checkout DIR and of this one, "
                             "alternating (see the module docstring)")
    parser.add_argument("--ab-pairs", type=int, default=6, metavar="N",
                        help="pairs for --ab-tree (default 6)")
    parser.add_argument("--role", help=argparse.SUPPRESS)
    parser.add_argument("--port-file", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.role == "pingpong-server":
        pingpong_server(args.port_file, args.ticks)
        return 0
    if args.ticks <= WARMUP_TICKS:
        parser.error(f"--ticks: must be > {WARMUP_TICKS}")
    if args.ab_tree:
        trees = bench_trees(args.ticks, args.ab_pairs, args.ab_tree)
        _print_trees(trees)
        if args.json:
            Path(args.json).write_text(json.dumps(trees, indent=2))
        return 0
    if args.breakdown_only and args.no_breakdown:
        parser.error("--breakdown-only and --no-breakdown exclude each other")
    if args.profile_vehicle:
        import pstats

        bench_vehicle(args.ticks, profile=Path(args.profile_vehicle))
        pstats.Stats(args.profile_vehicle).sort_stats("tottime").print_stats(30)
        return 0

    _cores(args.core)
    physics = bench_physics(20000)
    breakdown = {} if args.no_breakdown else bench_breakdown(3000)
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
    ab = bench_ab(args.ticks, args.ab_rounds, full) if args.ab_rounds > 0 else {}
    pingpong_after = bench_pingpong(args.ticks)     # before and after: the load drifts
    per_process = ({} if args.no_profile
                   else profile_breakdown(min(args.ticks, 4000), full["cpu_us_per_tick"]))
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
    if full.get("recorder_policy"):
        print("  recorder children's policy: " + ", ".join(
            f"{k.split(' ')[0]} {v}" for k, v in sorted(full["recorder_policy"].items())))
    if ab:
        print(f"\nfull loop, recorder children niced only vs idle ({len(ab['niced_ticks_per_s'])}"
              f" + {len(ab['idle_ticks_per_s'])} runs, alternating; ticks/s, median)")
        print(f"  {'niced only (TFL_MAV_RECORDER_IDLE=0)':<{_WIDTH}}  "
              f"{ab['niced_median']:>8.0f} ticks/s  ({ab['niced_median'] / ceiling:.2f})")
        print(f"  {'idle (lockstep default)':<{_WIDTH}}  "
              f"{ab['idle_median']:>8.0f} ticks/s  ({ab['idle_median'] / ceiling:.2f})")
        print(f"  {'paired gain, idle / niced (median)':<{_WIDTH}}  "
              f"{ab['paired_gain_median']:>8.2f}x")
    print("\nfull loop: CPU per tick of each process (µs, /proc utime+stime, steady state; "
          "split by a CPU-timer cProfile run's shares)")
    for proc_name, us in full["cpu_us_per_tick"].items():
        print(f"  {proc_name:<{_WIDTH}}  {us:>11.1f} µs")
        for part, part_us in per_process.get(proc_name, {}).items():
            print(f"    {part:<{_WIDTH - 2}}  {part_us:>11.1f} µs")
    print(f"  {'all four processes':<{_WIDTH}}  "
          f"{sum(full['cpu_us_per_tick'].values()):>11.1f} µs "
          f"(wall per tick {1e6 / full['ticks_per_s']:.0f} µs on {os.cpu_count()} cpus)")
    print("\nsame-run ratios to the bare ping-pong                    now    goal")
    print(f"  full lockstep loop (sim + daemon + both MCAP recorders)  {ratio_full:5.2f}  ≥ 0.5")
    print(f"  lockstep sim + bare client, no MCAP                      {ratio:5.2f}  ≥ 0.7")
    if args.json:
        Path(args.json).write_text(json.dumps({
            "ticks": args.ticks, "python": platform.python_version(), "cpus": os.cpu_count(),
            "physics": physics, "lockstep": vehicle, "lockstep_mcap": recorded,
            "breakdown_us": breakdown, "full_loop": full, "per_process_us": per_process,
            "pingpong": pingpong, "pingpong_after": pingpong_after, "recorder_idle_ab": ab,
            "ratio_lockstep_to_pingpong": ratio,
            "ratio_full_loop_to_pingpong": ratio_full}, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
