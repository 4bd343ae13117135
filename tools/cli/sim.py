"""``tfl-mav sim``: run the simulated vehicle as a MAVLink endpoint (see
:mod:`tfl_mav.sitl.vehicle`).

Loaded lazily by :mod:`tfl_mav.tools.cli.main` (``add_parser`` + ``run``). SIGINT and SIGTERM end
the run cleanly: the loop stops within ~50 ms, the peers get a last HEARTBEAT, the recorder (if any)
is closed, and the summary is printed.
"""

from __future__ import annotations

import argparse
import json
import math
import signal
import sys
import textwrap
import threading
from pathlib import Path
from typing import TYPE_CHECKING, Any

from tfl_mav.scenario import Scenario, ScenarioError, apply_overrides, load_scenario

if TYPE_CHECKING:
    from tfl_mav.link.transport import Address

__all__ = ["EXIT_CODES", "add_parser", "run"]

EXIT_OK, EXIT_CRASHED, EXIT_USAGE, EXIT_LINK = 0, 1, 2, 3
EXIT_SIGINT, EXIT_SIGTERM = 128 + signal.SIGINT, 128 + signal.SIGTERM
EXIT_CODES = {
    EXIT_OK: "the run completed its duration",
    EXIT_CRASHED: "the vehicle crashed (the reason is printed and sent as STATUSTEXT)",
    EXIT_USAGE: "usage or scenario error (bad option, bad --set, unknown scenario, "
                "unusable --key-file)",
    EXIT_LINK: "link or I/O error (port in use, unresolvable address, MCAP file not writable,"
               " the controller silent for --peer-timeout)",
    EXIT_SIGINT: "interrupted by SIGINT (Ctrl-C), after a clean shutdown",
    EXIT_SIGTERM: "terminated by SIGTERM, after a clean shutdown",
}

_SEVERITY = {0: "EMERGENCY", 1: "ALERT", 2: "CRITICAL", 3: "ERROR", 4: "WARNING",
             5: "NOTICE", 6: "INFO", 7: "DEBUG"}


def add_parser(sub: argparse._SubParsersAction) -> None:
    epilog = "exit codes:\n" + "\n".join(f"  {code:3d}  {text}"
                                          for code, text in EXIT_CODES.items())
    epilog += "\n\n" + textwrap.fill(
        "The vehicle waits for the controller's first HEARTBEAT on the control port before "
        "sim time starts (HEARTBEAT to the GCS meanwhile). Lockstep (default): each state is "
        "answered by HIL_ACTUATOR_CONTROLS with the same time_usec before physics advances. "
        "--realtime: physics follows the wall clock, the latest command is held, and no valid "
        "command for --command-timeout seconds cuts the motors (like a real ESC).", width=78)
    p = sub.add_parser(
        "sim", help="run the simulated quadrotor as a MAVLink endpoint on UDP",
        description="Simulate the quadrotor of SCENARIO and serve it over MAVLink 2 on UDP: "
                    "ODOMETRY + ESC_TELEMETRY_1_TO_4 every control tick to the controller, "
                    "HIL_ACTUATOR_CONTROLS back; GCS telemetry and MAV_CMD_INJECT_FAILURE on "
                    "the GCS port.",
        epilog=epilog, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("scenario", nargs="?", default="paper",
                   help="built-in scenario name or .toml path (default: paper)")
    p.add_argument("--listen", metavar="HOST:PORT",
                   help="control port to bind (default 127.0.0.1:14580 as PX4 SITL, "
                        "127.0.0.1:14540 with --legacy-ports; port 0 = any free)")
    p.add_argument("--controller", default="127.0.0.1:14540", metavar="HOST:PORT",
                   help="where the offboard API listens: the vehicle announces itself there "
                        "by HEARTBEAT until a controller answers (default 127.0.0.1:14540, "
                        "PX4's offboard port: `tfl-mav fly` or mavsdk udpin://:14540)")
    p.add_argument("--legacy-ports", action="store_true",
                   help="the old direction: bind 127.0.0.1:14540 and announce nowhere; the "
                        "controller sends first (tfl-mav fly --vehicle 127.0.0.1:14540)")
    p.add_argument("--gcs", default="127.0.0.1:14550", metavar="HOST:PORT|none",
                   help="send GCS telemetry to a ground station listening here and take its "
                        "commands (default 127.0.0.1:14550 as PX4: QGroundControl, MAVProxy "
                        "udpin:127.0.0.1:14550, mavsdk udpin://:14550); none = no GCS port")
    p.add_argument("--peer", metavar="HOST:PORT",
                   help="only accept this controller address, whatever its HEARTBEAT says "
                        "(default: the first sender that identifies as an offboard "
                        "controller and sends HIL_ACTUATOR_CONTROLS)")
    p.add_argument("--origin", metavar="LAT,LON,ALT",
                   help="where local (0,0,0) is on Earth, for GLOBAL_POSITION_INT and "
                        "HOME_POSITION (default 47.397742,8.545594,488: PX4 SITL's home)")
    p.add_argument("--keep-alive", action="store_true",
                   help="after a run ends (duration, crash), reset the vehicle and wait for "
                        "the next controller instead of exiting; SIGINT/SIGTERM end it")
    p.add_argument("--realtime", action="store_true",
                   help="pace physics by the wall clock instead of lockstep")
    p.add_argument("--duration", type=float, metavar="S",
                   help="sim seconds to run (default: the scenario's run.duration_s; "
                        "0 = until interrupted)")
    p.add_argument("--seed", type=int, metavar="N", help="override run.seed (sensor noise)")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", dest="settings",
                   help="override a scenario key, e.g. --set attack.rotor=3 "
                        "--set initial.position_m=[0,0,5] (VALUE in TOML syntax; a bare "
                        "word is a string); repeatable")
    p.add_argument("--mcap", metavar="FILE",
                   help="record all traffic and ground truth to an MCAP file")
    p.add_argument("--foxglove", metavar="[HOST:]PORT",
                   help="serve the same channels as --mcap live on a Foxglove WebSocket "
                        "(Foxglove: Open connection, ws://localhost:PORT); default off")
    p.add_argument("--json", metavar="FILE",
                   help="at exit, write the outcome and every counter as JSON to FILE")
    p.add_argument("--lockstep-timeout", type=float, default=2.0, metavar="S",
                   help="lockstep: wall seconds without a reply before reporting it "
                        "(default 2)")
    p.add_argument("--resend-interval", type=float, default=0.005, metavar="S",
                   help="lockstep: wall seconds without a reply before resending the state "
                        "(default 0.005: a lost datagram costs milliseconds; a spurious resend "
                        "is answered with the same command, never a second step)")
    p.add_argument("--peer-timeout", type=float, metavar="S",
                   help="end the flight (exit 3) when the controller has sent no command for "
                        "S wall seconds (default: wait for a restarted controller however "
                        "long; in real time the motors are cut after --command-timeout "
                        "anyway)")
    p.add_argument("--command-timeout", type=float, default=0.25, metavar="S",
                   help="real time: wall seconds without a valid command before the motors "
                        "are cut (default 0.25)")
    p.add_argument("--gcs-rate", type=float, default=50.0, metavar="HZ",
                   help="GCS telemetry rate, at most 50 Hz (default 50)")
    p.add_argument("--key-file", metavar="PATH",
                   help="MAVLink 2 signing key (64 hex digits or 32 raw bytes, mode 600): sign "
                        "everything and accept only frames signed with it, on both ports; "
                        "the controller needs the same file (docs/SIGNING.md)")
    p.add_argument("--no-failure-injection", action="store_true",
                   help="deny MAV_CMD_INJECT_FAILURE (the scenario's own attack still runs)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from tfl_mav.link.signing import load_key
    from tfl_mav.link.transport import parse_address
    from tfl_mav.sitl.gcs import Origin
    from tfl_mav.tools.cli.outputs import file_problem

    prog = "tfl-mav sim"
    try:
        scenario = apply_overrides(load_scenario(args.scenario), args.settings)
        if args.seed is not None:
            scenario = scenario.replace(**{"run.seed": args.seed})
    except ScenarioError as exc:
        print(f"{prog}: {exc}", file=sys.stderr)
        return EXIT_USAGE
    try:
        listen = parse_address(args.listen or ("127.0.0.1:14540" if args.legacy_ports
                                               else "127.0.0.1:14580"), "--listen")
        gcs = (parse_address(args.gcs, "--gcs")
               if args.gcs and args.gcs.lower() != "none" else None)
        peer = parse_address(args.peer, "--peer") if args.peer else None
        announce = (None if args.legacy_ports or peer is not None
                    else parse_address(args.controller, "--controller"))
        origin = Origin.parse(args.origin) if args.origin else Origin()
        duration = _duration(args.duration, scenario)
        key = load_key(args.key_file) if args.key_file else None
        live = None
        if args.foxglove:
            from tfl_mav.flightlog.live import parse_live_address

            live = parse_live_address(args.foxglove)
        args.live = live   # each flight's recorder serves it (--keep-alive: one at a time)
    except ValueError as exc:
        print(f"{prog}: {exc}", file=sys.stderr)
        return EXIT_USAGE

    for path, option in ((args.json, "--json"), (args.mcap, "--mcap")):
        problem = file_problem(path, option) if path else None
        if problem:
            print(f"{prog}: {problem}", file=sys.stderr)
            return EXIT_LINK
    extra = {"announce": announce, "origin": origin}
    flight = 1
    between: list[int] = []   # keep-alive: a signal between two flights ends the loop
    args.pending_signals = between
    previous = _install_signals(lambda signum, _f: between.append(signum))
    try:
        while True:
            mcap = _numbered(args.mcap, flight)
            code = _one_flight(args, scenario, listen, gcs, peer, duration, key, mcap, extra,
                               prog)
            listen = getattr(args, "bound_listen", listen)   # keep-alive: the same port
            if not args.keep_alive or code not in (EXIT_OK, EXIT_CRASHED):
                return code
            if between:
                return EXIT_SIGTERM if between[-1] == signal.SIGTERM else EXIT_SIGINT
            flight += 1
            print(f"{prog}: --keep-alive: vehicle reset; waiting for the next controller "
                  f"(flight {flight})", flush=True)
    finally:
        _restore_signals(previous)


def _numbered(path: str | None, flight: int) -> str | None:
    """--keep-alive: flight n > 1 records to ``STEM-n.SUFFIX`` next to ``path``."""
    if path is None or flight == 1:
        return path
    p = Path(path)
    return str(p.with_name(f"{p.stem}-{flight}{p.suffix}"))


def _one_flight(args: argparse.Namespace, scenario: Scenario, listen: Address,
                gcs: Address | None, peer: Address | None, duration: float,
                key: bytes | None, mcap: str | None, extra: dict[str, Any], prog: str) -> int:
    recorder = None
    live = getattr(args, "live", None)
    if mcap or live:
        recorder, code = _open_recorder(mcap, scenario, prog, live, duration,
                                        args.realtime)
        if recorder is None:
            return code
    try:
        return _fly(args, scenario, listen, gcs, peer, duration, key, recorder, prog, extra)
    finally:
        if recorder is not None:
            recorder.close()
            if recorder.error:   # the flight went on (flight before logging); say so
                print(f"{prog}: --mcap {mcap}: recording stopped early: "
                      f"{recorder.error}", file=sys.stderr)


def _fly(args: argparse.Namespace, scenario: Scenario, listen: Address,
         gcs: Address | None, peer: Address | None, duration: float, key: bytes | None,
         recorder: Any, prog: str, extra: dict[str, Any]) -> int:
    from tfl_mav.link.transport import LinkError
    from tfl_mav.sitl.vehicle import ExitStatus, Vehicle, truth_hook

    holder: dict[str, Vehicle] = {}

    def on_status(severity: int, text: str) -> None:
        t = holder["v"].sim.time_s if "v" in holder else 0.0
        print(f"sim [t={t:8.3f} s] {_SEVERITY.get(severity, severity)}: {text}",
              file=sys.stderr, flush=True)

    try:
        vehicle = Vehicle(
            scenario, listen=listen, gcs=gcs, peer=peer, realtime=args.realtime,
            lockstep_timeout_s=args.lockstep_timeout, command_timeout_s=args.command_timeout,
            resend_interval_s=args.resend_interval, **extra,
            gcs_rate_hz=args.gcs_rate, allow_failure_injection=not args.no_failure_injection,
            key=key, on_frame=recorder.on_frame if recorder is not None else None,
            on_truth=truth_hook(recorder) if recorder is not None else None,
            on_status=on_status,
            on_frames=recorder.on_frames if recorder is not None else None,
            peer_timeout_s=args.peer_timeout)
    except LinkError as exc:
        print(f"{prog}: {exc}", file=sys.stderr)
        return EXIT_LINK
    except ValueError as exc:
        print(f"{prog}: {exc}", file=sys.stderr)
        return EXIT_USAGE
    holder["v"] = vehicle
    args.bound_listen = vehicle.listen_address
    received: list[int] = []
    pending = getattr(args, "pending_signals", None)   # keep-alive: shared with the loop

    def on_signal(signum: int, _frame: Any) -> None:
        received.append(signum)
        if pending is not None and signum not in pending:
            pending.append(signum)   # even after this flight ended: the loop stops too
        vehicle.stop()

    previous = _install_signals(on_signal)
    for signum in pending or ():   # arrived while this flight was being built
        on_signal(signum, None)
    try:
        host, port = vehicle.listen_address
        mode = "real time" if args.realtime else "lockstep"
        run_cfg = scenario.run
        length = "until interrupted" if math.isinf(duration) else f"{duration:g} s"
        gcs_text = f", GCS -> {gcs[0]}:{gcs[1]}" if gcs else ""
        ann = extra.get("announce")
        if ann is not None:
            gcs_text += f", announcing to the controller at {ann[0]}:{ann[1]}"
        signed = ", MAVLink 2 signing on" if key is not None else ""
        print(f"{prog}: listening on {host}:{port} (control port), {mode}{signed}, scenario "
              f"{scenario.name!r}, physics {run_cfg.physics_hz:g} Hz, control "
              f"{1.0 / run_cfg.control_dt_s:g} Hz, {length}{gcs_text}; waiting for the "
              "controller's HEARTBEAT", flush=True)
        result = vehicle.run(duration)
    finally:
        _restore_signals(previous)
        vehicle.close()
    rtf = result.real_time_factor
    speed = f" ({rtf:.1f}x real time)" if math.isfinite(rtf) else ""
    print(f"{prog}: {result.status.value}: {result.reason}; {result.ticks} ticks, "
          f"{result.sim_time_s:.3f} s sim in {result.wall_time_s:.3f} s wall{speed}",
          flush=True)
    print(f"{prog}: {vehicle.stats.summary()}", flush=True)
    if result.status is ExitStatus.CRASHED:
        code = EXIT_CRASHED
    elif result.status is ExitStatus.STOPPED:
        code = EXIT_SIGTERM if received and received[-1] == signal.SIGTERM else EXIT_SIGINT
    elif result.status is ExitStatus.PEER_LOST:
        code = EXIT_LINK
    else:
        code = EXIT_OK
    if args.json:
        report = {"status": result.status.name.lower(), "reason": result.reason,
                  "exit_code": code, "ticks": result.ticks, "sim_time_s": result.sim_time_s,
                  "wall_time_s": result.wall_time_s,
                  "real_time_factor": rtf if math.isfinite(rtf) else None,
                  "scenario": scenario.name,
                  "mode": "realtime" if args.realtime else "lockstep",
                  "signed": key is not None,
                  "listen": [host, port], "stats": vehicle.stats.as_dict()}
        if recorder is not None:
            recorder.close()        # the file finished (or repaired) before it is reported
            if recorder.recording is not None:
                report["recording"] = recorder.recording
        from tfl_mav.tools.cli.outputs import write_text_atomic

        try:
            write_text_atomic(args.json, json.dumps(report, indent=2) + "\n")
        except OSError as exc:
            print(f"{prog}: --json: cannot write {args.json!r}: {exc.strerror}", file=sys.stderr)
            return EXIT_LINK
    return code


def _duration(value: float | None, scenario: Scenario) -> float:
    if value is None:
        return scenario.run.duration_s
    if not math.isfinite(value) or value < 0:
        raise ValueError(f"--duration: must be >= 0 seconds (0 = until interrupted), "
                         f"got {value}")
    return math.inf if value == 0 else value


def _open_recorder(path: str | None, scenario: Scenario, prog: str,
                   live: tuple[str, int] | None = None, duration: float = math.inf,
                   realtime: bool = False) -> tuple[Any, int]:
    """The MCAP recorder (``tfl_mav.flightlog.recorder_process``), imported only when asked
    for. It runs in a child process so recording costs the lockstep loop ~1 µs per call,
    and it finishes the file even if this process is killed. Returns (recorder, 0) or
    (None, exit code) after printing why. ``live``: also serve a Foxglove WebSocket there
    (from the recorder's child, off the loop's process)."""
    try:
        from tfl_mav.flightlog.recorder import RecorderError
        from tfl_mav.flightlog.recorder_process import RecorderProcess
    except ModuleNotFoundError as exc:
        print(f"{prog}: --mcap: the MCAP recorder is not available ({exc})", file=sys.stderr)
        return None, EXIT_USAGE
    from tfl_mav.model.airframe import rotor_xy_m

    v = scenario.vehicle
    try:
        recorder = RecorderProcess(path, rotor_xy_m=rotor_xy_m(v), thrust_max_n=v.thrust_max_n,
                                   live=live, realtime=realtime,
                                   timeline="wall" if realtime else "sim", prog=prog)
    except RecorderError as exc:
        print(f"{prog}: {'--mcap: ' if path and 'foxglove' not in str(exc) else ''}{exc}",
              file=sys.stderr)
        return None, EXIT_LINK
    from tfl_mav.control.path.paths import PathError
    from tfl_mav.from_scenario import scenario_path

    try:
        recorder.path(scenario_path(scenario).sample(800))   # what the 3-D view draws
    except PathError as exc:
        recorder.log("error", f"path not recorded: {exc}")
    # tools/cli/report.py rebuilds the scenario from "scenario_json" (Scenario.to_dict()).
    recorder.metadata("scenario", {"name": scenario.name, "role": "vehicle",
                                   "scenario_json": json.dumps(scenario.to_dict())})
    if math.isfinite(duration):   # tfl_mav.flightlog.metrics: a shorter log was interrupted
        recorder.metadata("run", {"duration_s": repr(duration)})
    return recorder, EXIT_OK


def _install_signals(handler: Any) -> dict[int, Any]:
    """SIGINT/SIGTERM → ``handler`` (main thread only; elsewhere Python forbids it)."""
    if threading.current_thread() is not threading.main_thread():
        return {}
    previous = {}
    for sig in (signal.SIGINT, signal.SIGTERM):
        previous[sig] = signal.signal(sig, handler)
    return previous


def _restore_signals(previous: dict[int, Any]) -> None:
    for sig, old in previous.items():
        signal.signal(sig, old)
