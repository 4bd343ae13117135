"""Faults on the control link: loss rates survived and recovery times after restarts.

Real processes (``tfl-mav sim`` and ``tfl-mav fly``, real UDP on loopback) with the fault
relay of :mod:`tfl_mav.tools.harness.relay` in between, the paper scenario throughout:

1. **real time** through the relay at 0-20 % loss per direction with 0-2 ms jitter:
   converged (not crashed, path distance over the last ``--window`` s below ``--tol``),
   that maximum, the vehicle's command timeouts (motors cut) and controls applied/stale;
2. **lockstep** through the same relay: completed, the vehicle's lockstep timeouts (each one
   a resend of the state after ``--lockstep-timeout``) and ticks per wall second;
3. **daemon restart** (real time, no relay): SIGKILL the daemon at ``--kill-at`` s of sim
   time; times from the kill to the vehicle cutting its motors, from the restart (same
   ``--bind`` address) to the first command applied, and to being back within 5 cm and
   1 cm of the path, or the crash that ended the flight;
4. **vehicle restart** (lockstep, no relay): SIGKILL the vehicle; times from the kill to the
   daemon's FAILSAFE, and from a new ``tfl-mav sim`` on the same port to the daemon's
   "control resumed".

The flight is measured from the vehicle's GCS telemetry (``LOCAL_POSITION_NED`` at 50 Hz,
the vehicle's own state, not the controller's view), so measuring costs the loop nothing.
Progress lines go to stderr. Usage (from the repository root)::

    python bench/bench_faults.py [--quick] [--json FILE]
"""

from __future__ import annotations

import argparse
import json
import math
import re
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from tfl_mav.control.path.paths import PathTracker
from tfl_mav.from_scenario import scenario_path
from tfl_mav.link.dialect import mav, new_mavlink
from tfl_mav.scenario import load_scenario
from tfl_mav.tools.harness.ports import free_udp_port
from tfl_mav.tools.harness.processes import Proc, raise_priority, start_sim, start_sim_on
from tfl_mav.tools.harness.relay import Faults, Relay

LOSS_RATES = (0.0, 0.01, 0.02, 0.05, 0.10, 0.15, 0.20)


def log(text: str) -> None:
    print(f"bench_faults: {text}", file=sys.stderr, flush=True)


@dataclass
class Track:
    """The vehicle's position from its GCS telemetry: (wall s, sim s, path distance m)."""

    samples: list[tuple[float, float, float]] = field(default_factory=list)

    def distance_after(self, wall_s: float) -> list[tuple[float, float]]:
        return [(w, d) for w, _t, d in self.samples if w >= wall_s]

    def max_last(self, window_s: float) -> float:
        """Largest path distance over the last ``window_s`` of sim time (inf if none)."""
        if not self.samples:
            return math.inf
        t_end = self.samples[-1][1]
        worst = max(d for _w, t, d in self.samples if t >= t_end - window_s)
        return worst if math.isfinite(worst) else math.inf

    def first_within(self, tol_m: float, after_wall_s: float) -> float | None:
        """Wall time from which the distance stays below ``tol_m`` to the end of the track."""
        first = None
        for w, _t, d in self.samples:
            if w < after_wall_s:
                continue
            first = (w if first is None else first) if d < tol_m else None
        return first


class GcsListener:
    """A ground station on a thread: collects ``LOCAL_POSITION_NED`` (NED → paper frame,
    z up) and turns each into the true distance to the scenario's path."""

    def __init__(self, scenario: str = "paper") -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(0.1)
        self.port = self.sock.getsockname()[1]
        self.tracker = PathTracker(scenario_path(load_scenario(scenario)))
        self.track = Track()
        self._stop = threading.Event()
        self._parser = new_mavlink(250, 190)
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    @property
    def address(self) -> str:
        return f"127.0.0.1:{self.port}"

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                data = self.sock.recv(65535)
            except TimeoutError:
                continue
            except OSError:
                return
            now = time.monotonic()
            try:
                msgs = self._parser.parse_buffer(data) or []
            except Exception:
                continue
            for m in msgs:
                if m.get_msgId() == mav.MAVLINK_MSG_ID_LOCAL_POSITION_NED:
                    pos = (m.y, m.x, -m.z)            # NED → ENU/paper frame, z up
                    if all(math.isfinite(c) for c in pos):
                        out = self.tracker.evaluate([[c, 0.0, 0.0, 0.0, 0.0] for c in pos])
                        self.track.samples.append((now, m.time_boot_ms / 1000.0,
                                                   out.distance_m))

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2)
        self.sock.close()


def _sim_report(path: Path) -> dict[str, Any]:
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return {}


# ---------------------------------------------------------------------------- runs
def realtime_through_relay(loss: float, jitter_s: float, duration_s: float, *, seed: int = 0,
                           window_s: float = 1.0, tol_m: float = 0.02, in_order: bool = False,
                           delay_s: float = 0.0) -> dict[str, Any]:
    """The paper scenario in real time through the relay (``loss``, ``delay_s`` and
    ``jitter_s`` in both directions; ``in_order``: jitter never reorders)."""
    faults = Faults(drop=loss, jitter_s=jitter_s, delay_s=delay_s, in_order=in_order)
    with tempfile.TemporaryDirectory() as tmp:
        sim_json = Path(tmp) / "sim.json"
        gcs = GcsListener()
        sim, port = start_sim(["--realtime", "--duration", str(duration_s), "--gcs",
                               gcs.address, "--json", str(sim_json)])
        try:
            with Relay(("127.0.0.1", port), to_vehicle=faults, to_daemon=faults,
                       seed=seed) as relay:
                raise_priority(relay.native_thread_id or 0)
                fly = Proc(["fly", "paper", "--realtime", "--quiet", "--vehicle",
                            f"127.0.0.1:{relay.listen_address[1]}", "--duration",
                            str(duration_s)], realtime=True)
                sim_code = sim.wait(duration_s + 60)
                fly.wait(30)
                relay_stats = relay.stats.as_dict()
        finally:
            sim.close()
            gcs.close()
        rep = _sim_report(sim_json)
    st = rep.get("stats", {})
    crashed = sim_code == 1
    max_last = gcs.track.max_last(window_s)
    return {"mode": "realtime", "loss": loss, "jitter_ms": 1000 * jitter_s,
            "delay_ms": 1000 * delay_s, "in_order": in_order,
            "duration_s": duration_s, "crashed": crashed,
            "reason": rep.get("reason", ""), "sim_time_s": rep.get("sim_time_s"),
            "converged": (not crashed) and max_last < tol_m,
            "max_distance_last_s_m": max_last, "window_s": window_s,
            "command_timeouts": st.get("command_timeouts"),
            "controls_applied": st.get("controls_applied"),
            "stale_controls": st.get("stale_controls"), "ticks": st.get("ticks"),
            "relay": relay_stats}


def lockstep_through_relay(loss: float, jitter_s: float, duration_s: float, *,
                           lockstep_timeout_s: float = 0.01, seed: int = 0) -> dict[str, Any]:
    """The paper scenario in lockstep through the relay: every lost datagram costs one
    ``lockstep_timeout_s`` and a resend of the state."""
    faults = Faults(drop=loss, jitter_s=jitter_s)
    with tempfile.TemporaryDirectory() as tmp:
        sim_json = Path(tmp) / "sim.json"
        sim, port = start_sim(["--duration", str(duration_s), "--lockstep-timeout",
                               str(lockstep_timeout_s), "--json", str(sim_json)])
        try:
            with Relay(("127.0.0.1", port), to_vehicle=faults, to_daemon=faults,
                       seed=seed) as relay:
                fly = Proc(["fly", "paper", "--quiet", "--vehicle",
                            f"127.0.0.1:{relay.listen_address[1]}", "--duration",
                            str(duration_s), "--state-timeout", "5"])
                sim_code = sim.wait(600)
                fly_code = fly.wait(30)
        finally:
            sim.close()
        rep = _sim_report(sim_json)
    st = rep.get("stats", {})
    wall = rep.get("wall_time_s") or math.nan
    return {"mode": "lockstep", "loss": loss, "jitter_ms": 1000 * jitter_s,
            "duration_s": duration_s, "completed": sim_code == 0 and fly_code == 0,
            "reason": rep.get("reason", ""), "ticks": st.get("ticks"),
            "lockstep_timeouts": st.get("lockstep_timeouts"),
            "stale_controls": st.get("stale_controls"),
            "ticks_per_s": (st.get("ticks") or 0) / wall if wall else math.nan,
            "wall_time_s": wall}


def daemon_restart(kill_at_s: float, duration_s: float, scenario: str = "paper",
                   sets: Sequence[str] = ()) -> dict[str, Any]:
    """Real time, no relay: SIGKILL the daemon at ``kill_at_s`` of sim time and restart it
    at once on the same ``--bind`` address. ``sets``: ``--set`` overrides for both."""
    bind = f"127.0.0.1:{free_udp_port()}"
    gcs = GcsListener(scenario)
    sets = [a for kv in sets for a in ("--set", kv)]
    sim, port = start_sim(["--realtime", "--duration", str(duration_s), "--gcs", gcs.address,
                           *sets], scenario)
    fly_args = ["fly", scenario, *sets, "--realtime", "--progress", "--vehicle",
                f"127.0.0.1:{port}", "--bind", bind, "--duration", str(duration_s)]
    out: dict[str, Any] = {"kill_at_s": kill_at_s}
    try:
        fly = Proc(fly_args, realtime=True)
        fly.wait_for(rf"^progress {math.floor(kill_at_s)}\.", duration_s + 30)
        t_kill = fly.kill()
        t_restart = time.monotonic()
        fly2 = Proc(fly_args, realtime=True)
        t_cut, m = sim.wait_for(r"\[t=\s*([\d.]+) s\].*motors cut", 10.0, after=t_kill)
        out["kill_sim_time_s"] = float(m.group(1))
        out["kill_to_cut_s"] = t_cut - t_kill
        try:
            t_resume, m = sim.wait_for(r"\[t=\s*([\d.]+) s\].*commands resumed", 10.0,
                                       after=t_kill)
            out["restart_to_first_command_s"] = t_resume - t_restart
            out["motors_off_s"] = t_resume - t_cut
        except TimeoutError:
            out["restart_to_first_command_s"] = None
        code = sim.wait(duration_s + 30)
        try:
            fly2.wait(5)
        except subprocess.TimeoutExpired:   # it never got a state: the vehicle fell first
            fly2.close()
        out["crashed"] = code == 1
        out["crash"] = (re.search(r"crashed: (.*)", sim.text()) or [None, ""])[1]
        for tol in (0.05, 0.01):
            t_in = gcs.track.first_within(tol, t_restart)
            out[f"restart_to_within_{round(tol * 100)}cm_s"] = (
                t_in - t_restart if t_in is not None and not out["crashed"] else None)
        after = gcs.track.distance_after(t_kill)
        out["max_distance_after_kill_m"] = max((d for _w, d in after), default=None)
        out["final_distance_m"] = gcs.track.samples[-1][2] if gcs.track.samples else None
    finally:
        sim.close()
        gcs.close()
    return out


def vehicle_restart(kill_after_s: float, second_flight_s: float,
                    state_timeout_s: float = 0.3) -> dict[str, Any]:
    """Lockstep, no relay, paper scenario: SIGKILL the vehicle once the attack is detected,
    start a new one on the same port; the daemon keeps running."""
    out: dict[str, Any] = {"state_timeout_s": state_timeout_s}
    sim, port = start_sim(["--duration", "0"])
    sim2 = None
    fly = Proc(["fly", "paper", "--vehicle", f"127.0.0.1:{port}", "--duration", "1000",
                "--state-timeout", str(state_timeout_s)])
    try:
        fly.wait_for(r"ATTACK on rotor", 30)
        time.sleep(kill_after_s)
        t_kill = sim.kill()
        t_fs, _ = fly.wait_for(r"FAILSAFE", 10, after=t_kill)
        out["kill_to_failsafe_s"] = t_fs - t_kill
        t_start = time.monotonic()
        sim2 = start_sim_on(port, ["--duration", str(second_flight_s)])
        t_listen = time.monotonic()
        t_rec, _ = fly.wait_for(r"control resumed", 10, after=t_kill)
        out["new_vehicle_start_to_resumed_s"] = t_rec - t_start
        out["new_vehicle_listening_to_resumed_s"] = t_rec - t_listen
        code = sim2.wait(120)
        out["second_flight_crashed"] = code == 1
        fly.wait_for(r"vehicle powered off|crashed", 10, after=t_rec)
        m = re.findall(r"final path distance ([\d.e+-]+|nan) m", fly.text())
        out["second_flight_final_distance_m"] = float(m[-1]) if m else None
        fly.wait(30)
    finally:
        for p in (sim, sim2, fly):
            if p is not None:
                p.close()
    return out


# ---------------------------------------------------------------------------- main
def _fmt(v: Any, spec: str = "") -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "-"
    if isinstance(v, bool):
        return "yes" if v else "no"
    return format(v, spec)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=12.0,
                    help="real-time flight, sim s (default 12; the paper scenario converges "
                         "from 3.85 m off the path in about 9 s)")
    ap.add_argument("--lockstep-duration", type=float, default=5.0)
    ap.add_argument("--lockstep-timeout", type=float, default=0.01)
    ap.add_argument("--jitter-ms", type=float, default=2.0)
    ap.add_argument("--window", type=float, default=2.0, help="convergence window, sim s")
    ap.add_argument("--tol", type=float, default=0.02, help="convergence tolerance, m")
    ap.add_argument("--kill-at", type=float, default=10.0, help="daemon kill, sim s")
    ap.add_argument("--losses", type=float, nargs="+", default=list(LOSS_RATES))
    ap.add_argument("--quick", action="store_true", help="loss 0, 5, 20 %% only")
    ap.add_argument("--json", metavar="FILE")
    args = ap.parse_args()
    losses = [0.0, 0.05, 0.20] if args.quick else args.losses
    jitter = args.jitter_ms / 1000.0
    rows_rt, rows_ls = [], []
    for loss in losses:
        for jit in sorted({0.0, jitter}):
            log(f"real time, loss {100 * loss:g} %, jitter {1000 * jit:g} ms ...")
            r = realtime_through_relay(loss, jit, args.duration, window_s=args.window,
                                       tol_m=args.tol)
            log(f"  converged {r['converged']}, max last {args.window:g} s "
                f"{_fmt(r['max_distance_last_s_m'], '.4f')} m, {r['reason']}")
            rows_rt.append(r)
    for loss in losses:
        log(f"lockstep, loss {100 * loss:g} %, jitter {args.jitter_ms:g} ms ...")
        r = lockstep_through_relay(loss, jitter, args.lockstep_duration,
                                   lockstep_timeout_s=args.lockstep_timeout)
        log(f"  completed {r['completed']}, {r['ticks_per_s']:.0f} ticks/s")
        rows_ls.append(r)
    log("daemon restart ...")
    dr = daemon_restart(args.kill_at, args.kill_at + 8.0)
    log(f"  {dr}")
    log("vehicle restart ...")
    vr = vehicle_restart(1.0, 10.0)
    log(f"  {vr}")

    print(f"Real time through the relay, paper scenario, {args.duration:g} s "
          f"(converged = not crashed and max distance over the last {args.window:g} s "
          f"< {100 * args.tol:g} cm)")
    print("| loss % | jitter ms | converged | max dist last s (m) | command timeouts | "
          "controls applied | stale controls | end |")
    print("|---|---|---|---|---|---|---|---|")
    for r in rows_rt:
        print(f"| {100 * r['loss']:g} | {r['jitter_ms']:g} | {_fmt(r['converged'])} | "
              f"{_fmt(r['max_distance_last_s_m'], '.4f')} | {_fmt(r['command_timeouts'])} | "
              f"{_fmt(r['controls_applied'])}/{_fmt(r['ticks'])} | "
              f"{_fmt(r['stale_controls'])} | {r['reason'][:60]} |")
    print(f"\nLockstep through the relay, {args.lockstep_duration:g} s, jitter "
          f"{args.jitter_ms:g} ms, --lockstep-timeout {args.lockstep_timeout:g} s")
    print("| loss % | completed | lockstep timeouts | stale controls | ticks/s |")
    print("|---|---|---|---|---|")
    for r in rows_ls:
        print(f"| {100 * r['loss']:g} | {_fmt(r['completed'])} | "
              f"{_fmt(r['lockstep_timeouts'])} | {_fmt(r['stale_controls'])} | "
              f"{_fmt(r['ticks_per_s'], '.0f')} |")
    print("\nRecovery")
    print("| event | time |")
    print("|---|---|")
    for key, value in (*dr.items(), *vr.items()):
        spec = ".3f" if isinstance(value, float) else ""
        print(f"| {key} | {_fmt(value, spec)} |")
    if args.json:
        with open(args.json, "w", encoding="utf-8") as fh:
            json.dump({"realtime": rows_rt, "lockstep": rows_ls, "daemon_restart": dr,
                       "vehicle_restart": vr, "args": vars(args)}, fh, indent=2,
                      default=lambda o: None)
    return 0


if __name__ == "__main__":
    sys.exit(main())
