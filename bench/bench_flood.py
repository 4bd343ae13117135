"""Lockstep speed of ``tfl-mav sim`` while its control port is flooded.

Three runs of ``tfl-mav sim`` (subprocess, lockstep, 1 kHz) flown by a minimal controller
(raw socket + pymavlink, hover commands, as in ``bench_lockstep.py``):

1. **baseline**: nobody else talks to the control port;
2. **non-peer flood**: a separate process sends valid-looking ``HIL_ACTUATOR_CONTROLS``
   (the controller's own sysid/compid, every tick's ``time_usec``, full thrust) from another
   socket as fast as loopback takes them; the link drops them by address (``foreign``);
3. **wrong-sysid flood from the peer's address**: the flooder process shares the
   controller's very socket (inherited file descriptor), so its datagrams carry the peer's
   address; the frames say sysid 99 and are dropped after decoding (``wrong_sysid``).

Runs 2 and 3 are repeated with ``--lockstep-timeout 0.02``: under a flood the kernel drops
datagrams when the vehicle's receive buffer is full, the controller's reply among them, and
the vehicle then waits its lockstep timeout (default 2 s) before it re-sends the state.

Reported: ticks/s, the stall factor (baseline ticks/s ÷ flooded ticks/s), flood datagrams
sent and how many the vehicle counted (the rest the kernel dropped when the socket's
receive buffer was full), and that the commands applied were the controller's only.
On a 2-core machine the flooder also takes CPU from the two flight processes; the factor
includes that, as it would on a real companion computer.

Usage: ``python bench/bench_flood.py [--ticks N] [--json FILE]`` from the repository root.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as mav

from tfl_mav.tools.harness.pilot import Pilot, hover_controls
from tfl_mav.tools.harness.processes import popen_sim

WARMUP_TICKS = 200
PILOT_SYSID, PILOT_COMPID = 1, 191
SHORT_TIMEOUT_S = 0.02      # a --lockstep-timeout that re-sends a lost state quickly
FLOOD_WRONG_SYSID = 99


# ---------------------------------------------------------------------------- flooder
def flooder(address: tuple[str, int], sysid: int, fd: int | None) -> None:
    """Send HIL_ACTUATOR_CONTROLS (full thrust, ticks 0..999) until SIGTERM; print the
    number of datagrams the kernel accepted."""
    stop = [False]
    signal.signal(signal.SIGTERM, lambda *_: stop.__setitem__(0, True))
    if fd is None:
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        sock.bind(("127.0.0.1", 0))
    else:
        sock = socket.socket(fileno=fd)
    mv = mav.MAVLink(None, sysid, PILOT_COMPID)
    frames = []
    for k in range(1000):
        frames.append(mav.MAVLink_hil_actuator_controls_message(
            k * 1000, [1.0] * 16, 128, 1).pack(mv))
        mv.seq = (mv.seq + 1) & 0xFF
    sent = errors = 0
    print("ready", flush=True)
    while not stop[0]:
        for f in frames:
            try:
                sock.sendto(f, address)
                sent += 1
            except OSError:
                errors += 1
    print(json.dumps({"sent": sent, "send_errors": errors}), flush=True)


def _start_flooder(address: tuple[str, int], sysid: int, sock: Any | None
                   ) -> subprocess.Popen:
    """The flooder process; ``sock`` (anything with ``fileno()``): send from that socket
    (shared with the pilot, so from the pinned address)."""
    args = [sys.executable, __file__, "--role", "flooder", "--target",
            f"{address[0]}:{address[1]}", "--sysid", str(sysid)]
    pass_fds: tuple[int, ...] = ()
    if sock is not None:
        args += ["--fd", str(sock.fileno())]
        pass_fds = (sock.fileno(),)
    proc = subprocess.Popen(args, stdout=subprocess.PIPE, text=True,
                            pass_fds=pass_fds)
    assert proc.stdout is not None
    if proc.stdout.readline().strip() != "ready":
        raise RuntimeError("flooder did not start")
    return proc


def _stop_flooder(proc: subprocess.Popen) -> dict[str, int]:
    proc.send_signal(signal.SIGTERM)
    out, _ = proc.communicate(timeout=10)
    return json.loads(out.strip().splitlines()[-1])


# ---------------------------------------------------------------------------- one run
def run(n_ticks: int, flood: str | None, lockstep_timeout_s: float = 2.0) -> dict[str, object]:
    """One lockstep run of ``n_ticks``; ``flood``: None, "foreign" or "wrong_sysid";
    ``lockstep_timeout_s``: the sim's ``--lockstep-timeout`` (state resent after it)."""
    from tfl_mav.scenario import load_scenario

    sc = load_scenario("paper")
    with tempfile.TemporaryDirectory() as tmp:
        out_json = Path(tmp) / "sim.json"
        proc, address = popen_sim(
            ["--set", "attack.rotor=0", "--set", "initial.position_m=[0, 0, 5]",
             "--duration", f"{n_ticks / 1000.0:g}", "--json", str(out_json),
             "--lockstep-timeout", f"{lockstep_timeout_s:g}"], "paper")
        flood_proc = None
        pilot = Pilot(address, sysid=PILOT_SYSID, compid=PILOT_COMPID)
        times = {"start": 0.0, "end": 0.0}

        def on_tick(k: int, _odom: object, _esc: object) -> None:
            nonlocal flood_proc
            if k == 0 and flood is not None:   # the peer is pinned by now
                # wrong_sysid: from the pilot's own socket (pinned address, other sysid)
                flood_proc = _start_flooder(
                    address, FLOOD_WRONG_SYSID if flood == "wrong_sysid" else PILOT_SYSID,
                    pilot.link if flood == "wrong_sysid" else None)
            if k + 1 == WARMUP_TICKS:
                times["start"] = time.perf_counter()
            if k + 1 == n_ticks:
                times["end"] = time.perf_counter()

        try:
            pilot.hello()
            # Answer every state, resends too (the Pilot does): a reply the kernel dropped
            # under the flood is resent by the vehicle after its lockstep timeout. Fly
            # until the vehicle's last word (HEARTBEAT POWEROFF).
            pilot.fly(None, hover_controls(sc), timeout_s=10.0, keep=False, on_tick=on_tick)
            elapsed = times["end"] - times["start"]
            flood_stats = _stop_flooder(flood_proc) if flood_proc is not None else {}
            flood_proc = None
            proc.communicate(timeout=30)
        finally:
            if flood_proc is not None:
                flood_proc.kill()
            if proc.poll() is None:
                proc.kill()
            pilot.close()
        if proc.returncode != 0:
            raise RuntimeError(f"sim exited with {proc.returncode}")
        sim = json.loads(out_json.read_text())
    measured = n_ticks - WARMUP_TICKS
    stats = sim.get("stats", sim)
    link = stats["control_link"]
    return {"flood": flood, "lockstep_timeout_s": lockstep_timeout_s, "ticks": measured,
            "seconds": elapsed,
            "ticks_per_s": measured / elapsed, "flood_sent": flood_stats.get("sent", 0),
            "flood_send_errors": flood_stats.get("send_errors", 0),
            "foreign": link["foreign"], "wrong_sysid": link["wrong_sysid"],
            "controls_applied": stats["controls_applied"],
            "rejected_controls": stats["rejected_controls"],
            "stale_controls": stats["stale_controls"],
            "lockstep_timeouts": stats["lockstep_timeouts"], "sim_ticks": stats["ticks"]}


# ---------------------------------------------------------------------------- main
def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--ticks", type=int, default=5000,
                        help="lockstep ticks per run (default 5000)")
    parser.add_argument("--json", metavar="FILE", help="also write the numbers as JSON")
    parser.add_argument("--role", help=argparse.SUPPRESS)
    parser.add_argument("--target", help=argparse.SUPPRESS)
    parser.add_argument("--sysid", type=int, help=argparse.SUPPRESS)
    parser.add_argument("--fd", type=int, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.role == "flooder":
        host, port = args.target.rsplit(":", 1)
        flooder((host, int(port)), args.sysid, args.fd)
        return 0
    if args.ticks <= WARMUP_TICKS:
        parser.error(f"--ticks: must be > {WARMUP_TICKS}")
    runs = [run(args.ticks, None), run(args.ticks, "foreign"), run(args.ticks, "wrong_sysid"),
            run(args.ticks, "foreign", SHORT_TIMEOUT_S),
            run(args.ticks, "wrong_sysid", SHORT_TIMEOUT_S)]
    base = runs[0]["ticks_per_s"]
    print(f"bench_flood ({args.ticks} ticks per run, python {platform.python_version()}, "
          f"{os.cpu_count()} cpus)")
    print(f"  {'run':<31} {'resend':>6} {'ticks/s':>8} {'stall':>7} {'flood sent':>11} "
          f"{'flood/s':>8} {'counted':>9} {'applied':>8} {'resends':>7}")
    names = {None: "baseline (no flood)", "foreign": "flood from a non-peer",
             "wrong_sysid": "flood from peer addr, sysid 99"}
    for r in runs:
        counted = r["foreign"] if r["flood"] == "foreign" else r["wrong_sysid"]
        rate = r["flood_sent"] / r["seconds"] if r["flood"] else 0.0
        r["stall_factor"] = base / r["ticks_per_s"]
        print(f"  {names[r['flood']]:<31} {r['lockstep_timeout_s']:5g}s "
              f"{r['ticks_per_s']:8.0f} {r['stall_factor']:6.2f}x {r['flood_sent']:11d} "
              f"{rate:8.0f} {counted:9d} {r['controls_applied']:8d} "
              f"{r['lockstep_timeouts']:7d}")
    print("  resend = the sim's --lockstep-timeout: a reply the kernel dropped (receive "
          "buffer full of flood) costs that long")
    ok = all(r["controls_applied"] == args.ticks and r["rejected_controls"] == 0
             and r["sim_ticks"] == args.ticks for r in runs)
    print("  every tick flew the controller's command only" if ok
          else "  FLOOD CHANGED THE FLIGHT")
    if args.json:
        Path(args.json).write_text(json.dumps({"ticks": args.ticks, "runs": runs}, indent=2))
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
