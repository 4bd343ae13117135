"""Real time, for real: the flight held on a busy machine.

Real processes (``tfl-mav sim --realtime`` and ``tfl-mav fly --realtime``, both with
``--mcap`` on, real UDP on loopback), 1 kHz control, beside a CPU hog (a busy-loop
subprocess; on a 2-core machine it takes one core):

1. **false alarms**: ``--flights`` nominal flights of ``--nominal-s`` s each; a false alarm is
   a flight whose daemon reports an attack (there is none); also crashes, the vehicle's
   overruns, late controls, command timeouts and command age p50/p99 (sim time when applied
   − the command's time_usec, from the vehicle's ``--json``);
2. **loss**: the paper scenario through ``tfl-mav relay`` (its own process, like a user's)
   at 0/5/10/20 % drop with ``--jitter-ms`` of jitter in both directions, for the
   scenario's own duration (30 s: its second dead-rotor stretch ends at ~18 s, and the law
   itself — offline, no real time at all — is still 122 mm off at 10-20 s); the largest path
   distance over the last ``min(10 s, half the flight)`` from the vehicle's own GCS
   telemetry (``LOCAL_POSITION_NED``), converged if ≤ 2 cm;
3. **start-up**: ``tfl-mav fly --realtime`` against a scripted vehicle already in flight
   (states at 1 kHz, t = 4 s on): process start → controller built → first HEARTBEAT →
   first command, with and without ``--mcap``; and the import cost (``-X importtime``) of
   ``tfl_mav.tools.cli.fly`` in a fresh interpreter (scipy is not imported in flight: the safe
   law's LQR is ``tfl_mav/control/safe/lqr.py``);
4. **restart**: SIGKILL the daemon mid-flight and restart it on the same ``--bind``
   (:func:`bench_faults.daemon_restart`); the new daemon's flight computer takes over
   (recovery law when the state is not benign): restart → first command, motors-off time,
   time back within 5/1 cm, final distance.

Progress lines go to stderr. Usage (from the repository root)::

    python bench/bench_realtime.py [--flights N] [--nominal-s S] [--paper-s S] [--json FILE]
"""

from __future__ import annotations

import argparse
import json
import re
import subprocess
import sys
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from bench_faults import GcsListener, _fmt, daemon_restart

from tfl_mav.link.transport import Link
from tfl_mav.scenario import load_scenario
from tfl_mav.sitl.power import PowerModel
from tfl_mav.sitl.simulator import Simulator
from tfl_mav.sitl.state_report import StateReport
from tfl_mav.tools.harness.processes import CLI, LISTEN_RE, START_TIMEOUT_S, Proc, start_sim

LOSSES = (0.0, 0.05, 0.10, 0.20)
TOL_M = 0.02


def log(text: str) -> None:
    print(f"bench_realtime: {text}", file=sys.stderr, flush=True)


class CpuHog:
    """A busy-loop subprocess (one core), ended by its own pid."""

    def __init__(self) -> None:
        self.proc = subprocess.Popen([sys.executable, "-c", "while True: pass"])

    def close(self) -> None:
        self.proc.kill()
        self.proc.wait(5)


def _read_json(path: Path) -> dict[str, Any]:
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return {}


def _vehicle_figures(rep: dict[str, Any]) -> dict[str, Any]:
    st = rep.get("stats", {})
    age = st.get("command_age_ms", {}) or {}
    return {"overruns": st.get("overruns"), "late_controls": st.get("late_controls"),
            "command_timeouts": st.get("command_timeouts"),
            "controls_applied": st.get("controls_applied"), "ticks": st.get("ticks"),
            "age_p50_ms": age.get("p50"), "age_p99_ms": age.get("p99"),
            "age_max_ms": age.get("max")}


def flight(scenario: str, duration_s: float, *, loss: float = 0.0, jitter_s: float = 0.0,
           seed: int = 0, mcap: bool = True, fly_args: Sequence[str] = ()) -> dict[str, Any]:
    """One real-time flight with MCAP on both sides, through the relay when ``loss`` or
    ``jitter_s``; the vehicle's figures, the daemon's summary, the true path distance."""
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        gcs = GcsListener(scenario)
        sim_mcap = ["--mcap", str(d / "run.mcap")] if mcap else []
        sim, port = start_sim(["--realtime", "--duration", str(duration_s), "--gcs",
                               gcs.address, "--json", str(d / "sim.json"), *sim_mcap],
                              scenario)
        relay = None
        try:
            target = port
            if loss or jitter_s:
                # Its own process at the loop's priority, as a user runs it: a relay thread
                # in this process shares a GIL with the GCS listener and output readers, is
                # stalled for tens of ms, and then releases a shuffled burst (one receive
                # time, independent jitter): reordering no real network does.
                relay = Proc(["relay", "--vehicle", f"127.0.0.1:{port}", "--drop", str(loss),
                              "--jitter-ms", str(1000 * jitter_s), "--seed", str(seed)],
                             realtime=True)
                _, m = relay.wait_for(LISTEN_RE.pattern, START_TIMEOUT_S)
                target = int(m.group(2))
            fly = Proc(["fly", scenario, "--realtime", "--quiet", "--vehicle",
                        f"127.0.0.1:{target}", "--duration", str(duration_s),
                        *(["--mcap", str(d / "ctl.mcap")] if mcap else []), *fly_args,
                        "--summary-json", str(d / "fly.json")],
                       realtime=True)
            code = sim.wait(duration_s + 90)
            try:
                fly.wait(30)
            except subprocess.TimeoutExpired:
                fly.close()
        finally:
            if relay is not None:
                relay.stop()
            sim.close()
            gcs.close()
        rep, summ = _read_json(d / "sim.json"), _read_json(d / "fly.json")
    window = min(10.0, duration_s / 2.0)
    max_last = gcs.track.max_last(window)
    stats = summ.get("stats", {})
    return {"scenario": scenario, "duration_s": duration_s, "loss": loss,
            "jitter_ms": 1000 * jitter_s, "crashed": code == 1,
            "reason": rep.get("reason", ""), "detected_rotor": summ.get("detected_rotor"),
            "detection_time_s": summ.get("detection_time_s"),
            "window_s": window, "max_distance_window_m": max_last,
            "converged": code != 1 and max_last <= TOL_M,
            "daemon": {k: stats.get(k) for k in ("ticks", "skipped_states", "old_states",
                                                  "implausible_states", "gap_ticks",
                                                  "rebuilds", "law_errors")},
            **_vehicle_figures(rep)}


def startup(extra: Sequence[str] = (), scenario: str = "paper",
            t_state_usec: int = 4_000_000) -> dict[str, Any]:
    """Wall seconds from starting ``tfl-mav fly --realtime`` to: the controller built (its
    "controlling" line), its first HEARTBEAT, its first command — against a scripted vehicle
    that is already flying (a restart: states at 1 kHz from ``t_state_usec`` as soon as the
    controller is known), at the loop's priority."""
    sc = load_scenario(scenario)
    sim = Simulator(sc)
    v = sc.vehicle
    power = PowerModel(drag_thrust_ratio_m=v.drag_thrust_ratio_m, k_f=v.k_f)
    power.step(sim.motors.omega_radps, 0.0)
    report = StateReport(sim, power, sc.sensors)
    link = Link.listen(("127.0.0.1", 0), src_system=1, src_component=1)
    host, port = link.local_address
    t0 = time.monotonic()
    fly = Proc(["fly", scenario, "--realtime", "--vehicle", f"{host}:{port}", "--duration",
                "1000", *extra], realtime=True)
    heartbeat = first = None
    t_usec, next_state = t_state_usec, 0.0
    try:
        while first is None and time.monotonic() - t0 < 60:
            now = time.monotonic()
            if link.peer is not None and now >= next_state:
                odom, applied, esc = report.update(0)
                odom.time_usec = t_usec
                link.send_many([odom, applied, esc])
                t_usec += 1000
                next_state = now + 0.001
            for m in link.recv(0.0005):
                kind = m.get_type()
                if kind == "HEARTBEAT" and heartbeat is None:
                    heartbeat = time.monotonic()
                elif kind == "HIL_ACTUATOR_CONTROLS":
                    first = time.monotonic()
    finally:
        fly.close()
        link.close()
    built = [t for t, line in fly.lines if "controlling" in line]
    return {"options": " ".join(extra) or "-",
            "built_s": built[0] - t0 if built else None,
            "heartbeat_s": heartbeat - t0 if heartbeat else None,
            "first_command_s": first - t0 if first else None}


def import_costs() -> dict[str, float]:
    """Cumulative import seconds of ``tfl_mav.tools.cli.fly`` in a fresh interpreter (``python -X
    importtime``), and the interpreter's whole run."""
    t0 = time.monotonic()
    err = subprocess.run([sys.executable, "-X", "importtime", "-c",
                          "import tfl_mav.tools.cli.fly"], capture_output=True,
                         text=True, check=False).stderr
    wall = time.monotonic() - t0
    out = {"interpreter_wall_s": wall}
    for name in ("tfl_mav.tools.cli.fly", "numpy"):
        m = re.search(rf"\|\s*(\d+) \|\s*{re.escape(name)}$", err, re.M)
        out[f"{name}_s"] = int(m.group(1)) / 1e6 if m else None
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--flights", type=int, default=10, help="nominal flights (false alarms)")
    ap.add_argument("--nominal-s", type=float, default=20.0)
    ap.add_argument("--paper-s", type=float, default=None,
                    help="paper flight length (default: the scenario's, 30 s)")
    ap.add_argument("--jitter-ms", type=float, default=2.0)
    ap.add_argument("--kill-at", type=float, default=4.0)
    ap.add_argument("--restart-s", type=float, default=12.0)
    ap.add_argument("--no-hog", action="store_true")
    ap.add_argument("--skip", nargs="*", default=[],
                    choices=("nominal", "loss", "startup", "restart"))
    ap.add_argument("--json", metavar="FILE")
    args = ap.parse_args()
    if args.paper_s is None:
        args.paper_s = load_scenario("paper").run.duration_s
    hog = None if args.no_hog else CpuHog()
    out: dict[str, Any] = {"hog": hog is not None, "cli": CLI}
    t0 = time.monotonic()
    try:
        if "nominal" not in args.skip:
            runs = []
            for k in range(args.flights):
                r = flight("nominal", args.nominal_s, seed=k)
                log(f"nominal {k + 1}/{args.flights}: rotor {r['detected_rotor']}, "
                    f"crashed {r['crashed']}, age p99 {r['age_p99_ms']} ms")
                runs.append(r)
            out["nominal"] = runs
        if "loss" not in args.skip:
            out["loss"] = []
            for loss in LOSSES:
                r = flight("paper", args.paper_s, loss=loss, jitter_s=args.jitter_ms / 1000)
                log(f"loss {loss:.0%}: max {r['max_distance_window_m']:.4f} m over the "
                    f"last {r['window_s']:g} s, crashed {r['crashed']}")
                out["loss"].append(r)
        if "startup" not in args.skip:
            out["imports"] = import_costs()
            out["startup"] = []
            for extra in ([], ["--mcap", str(Path(tempfile.gettempdir()) / "bench_rt.mcap")]):
                for _ in range(2):
                    r = startup(extra)
                    log(f"start-up {r}")
                    out["startup"].append(r)
        if "restart" not in args.skip:
            out["restart"] = []
            for sc in ("nominal", "paper"):
                r = daemon_restart(args.kill_at, args.restart_s, sc)
                r["scenario"] = sc
                log(f"restart {sc}: {r}")
                out["restart"].append(r)
    finally:
        if hog is not None:
            hog.close()
    out["wall_s"] = time.monotonic() - t0
    _print(out, args)
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=2, default=str))
    return 0


def _print(out: dict[str, Any], args: argparse.Namespace) -> None:
    hog = "beside a CPU hog" if out["hog"] else "no hog"
    print(f"bench_realtime: 1 kHz control, MCAP on both sides, {hog}, "
          f"{out['wall_s']:.0f} s wall")
    runs = out.get("nominal")
    if runs:
        alarms = sum(1 for r in runs if r["detected_rotor"])
        crashes = sum(1 for r in runs if r["crashed"])
        print(f"\nfalse alarms: {alarms} in {len(runs)} nominal flights of "
              f"{args.nominal_s:g} s ({crashes} crashed)")
        print(f"{'flight':>6} {'overruns':>8} {'late':>6} {'timeouts':>8} {'age p50':>8} "
              f"{'age p99':>8} {'age max':>8} {'skipped':>7} {'gaps':>5}")
        for k, r in enumerate(runs):
            print(f"{k + 1:>6} {_fmt(r['overruns']):>8} {_fmt(r['late_controls']):>6} "
                  f"{_fmt(r['command_timeouts']):>8} {_fmt(r['age_p50_ms'], '.1f'):>8} "
                  f"{_fmt(r['age_p99_ms'], '.1f'):>8} {_fmt(r['age_max_ms'], '.1f'):>8} "
                  f"{_fmt(r['daemon']['skipped_states']):>7} "
                  f"{_fmt(r['daemon']['gap_ticks']):>5}")
    if out.get("loss"):
        print(f"\npaper scenario, {args.paper_s:g} s, {args.jitter_ms:g} ms jitter both ways")
        print(f"{'loss':>5} {'converged':>9} {'max last':>10} {'window':>6} {'crashed':>7} "
              f"{'rotor':>5} {'age p50':>8} {'age p99':>8} {'overruns':>8} {'timeouts':>8}")
        for r in out["loss"]:
            print(f"{r['loss']:>5.0%} {_fmt(r['converged']):>9} "
                  f"{_fmt(r['max_distance_window_m'] * 1000, '.2f'):>8}mm "
                  f"{r['window_s']:>5g}s {_fmt(r['crashed']):>7} "
                  f"{_fmt(r['detected_rotor']):>5} {_fmt(r['age_p50_ms'], '.1f'):>8} "
                  f"{_fmt(r['age_p99_ms'], '.1f'):>8} {_fmt(r['overruns']):>8} "
                  f"{_fmt(r['command_timeouts']):>8}")
    if out.get("startup"):
        imp = out["imports"]
        print(f"\nstart-up of `tfl-mav fly --realtime` against a vehicle in flight (s); "
              "imports in a fresh interpreter: tfl_mav.tools.cli.fly "
              f"{_fmt(imp['tfl_mav.tools.cli.fly_s'], '.3f')}"
              f" (numpy {_fmt(imp['numpy_s'], '.3f')}), interpreter run "
              f"{imp['interpreter_wall_s']:.3f}")
        print(f"{'options':>28} {'built':>7} {'heartbeat':>9} {'1st cmd':>8}")
        for r in out["startup"]:
            print(f"{r['options'][-28:]:>28} {_fmt(r['built_s'], '.3f'):>7} "
                  f"{_fmt(r['heartbeat_s'], '.3f'):>9} {_fmt(r['first_command_s'], '.3f'):>8}")
    if out.get("restart"):
        print(f"\ndaemon SIGKILLed at {args.kill_at:g} s, restarted on the same --bind")
        print(f"{'scenario':>8} {'1st cmd':>8} {'motors off':>10} {'to 5 cm':>8} "
              f"{'to 1 cm':>8} {'max after':>9} {'final':>9} {'crashed':>7}")
        for r in out["restart"]:
            print(f"{r['scenario']:>8} {_fmt(r.get('restart_to_first_command_s'), '.2f'):>7}s "
                  f"{_fmt(r.get('motors_off_s'), '.2f'):>9}s "
                  f"{_fmt(r.get('restart_to_within_5cm_s'), '.2f'):>7}s "
                  f"{_fmt(r.get('restart_to_within_1cm_s'), '.2f'):>7}s "
                  f"{_fmt(r.get('max_distance_after_kill_m'), '.3f'):>8}m "
                  f"{_fmt(r.get('final_distance_m'), '.4f'):>8}m {_fmt(r.get('crashed')):>7}")


if __name__ == "__main__":
    sys.exit(main())
