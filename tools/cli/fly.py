"""``tfl-mav fly``: run the offboard controller daemon against a vehicle
(:mod:`tfl_mav.controller.daemon`).

SIGINT/SIGTERM stop the loop cleanly and finish the MCAP file. Exit codes: 0 the run
ended (duration reached or the vehicle powered off), 1 the vehicle crashed, 2 usage or
scenario error, 3 link or file error, 130/143 interrupted.
"""

from __future__ import annotations

import argparse
import collections
import json
import math
import signal
import sys
import threading
import time
from collections.abc import Callable
from typing import Any

from tfl_mav.controller.daemon import TICK_FIELDS, TICK_SCHEMA, Daemon
from tfl_mav.controller.feasibility import check_scenario
from tfl_mav.link.signing import load_key
from tfl_mav.link.transport import LinkError, parse_address
from tfl_mav.scenario import ScenarioError, apply_overrides, load_scenario
from tfl_mav.tools.cli.args import duration_s
from tfl_mav.tools.cli.outputs import EXIT_IO, file_problem, write_text_atomic

__all__ = ["StartingRecorder", "add_parser", "open_recorder", "run"]


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "fly", help="run the TFL controller daemon against a vehicle over MAVLink",
        description="Fly SCENARIO's path with the TFL law as an offboard MAVLink controller: "
                    "ODOMETRY + ESC_TELEMETRY_1_TO_4 in, HIL_ACTUATOR_CONTROLS out. The "
                    "attack is found from ESC rpm; nobody tells the controller.",
        epilog="exit codes: 0 run over, 1 vehicle crashed, 2 usage/scenario error, "
               "3 link/file error (or the vehicle went silent for --peer-timeout), "
               "130/143 interrupted (after a clean shutdown)")
    p.add_argument("scenario", nargs="?", default="paper",
                   help="built-in scenario name or .toml path (default: paper); must match "
                        "the vehicle's")
    p.add_argument("--vehicle", metavar="HOST:PORT",
                   help="the vehicle's control port (default 127.0.0.1:14580, PX4 SITL's; "
                        "127.0.0.1:14540 for `tfl-mav sim --legacy-ports`)")
    p.add_argument("--bind", metavar="HOST:PORT",
                   help="local address (default: 127.0.0.1:14540, PX4's offboard API port "
                        "where the vehicle announces itself, when --vehicle is not given; "
                        "else an ephemeral port)")
    p.add_argument("--key-file", metavar="PATH",
                   help="MAVLink 2 signing key (64 hex digits or 32 raw bytes, mode 600), the "
                        "same file as the vehicle's: sign everything, accept only frames "
                        "signed with it (docs/SIGNING.md)")
    p.add_argument("--mcap", metavar="FILE", help="record every frame and the controller's "
                                                  "state to this MCAP file")
    p.add_argument("--foxglove", metavar="[HOST:]PORT",
                   help="serve the same channels live on a Foxglove WebSocket (open Foxglove, "
                        "Open connection, ws://localhost:PORT); default off")
    p.add_argument("--realtime", action="store_true",
                   help="the vehicle runs in real time (commands not flagged lockstep)")
    p.add_argument("--duration", type=duration_s, metavar="S",
                   help="sim seconds to fly (default: the scenario's run.duration_s)")
    p.add_argument("--peer-timeout", type=float, metavar="S",
                   help="after the flight started, end it (exit 3) when no vehicle state has "
                        "come for S wall seconds (default: 10 with --realtime; in lockstep "
                        "wait for a restarted vehicle however long; 0 = never)")
    p.add_argument("--state-timeout", type=float, default=0.5, metavar="S",
                   help="wall seconds without vehicle state before FAILSAFE (default 0.5)")
    p.add_argument("--controller", metavar="MODULE:NAME",
                   help="fly this flight software instead of the TFL law: tfl, se3, cascade, "
                        "MODULE:NAME or FILE.py:NAME (a Controller or FlightSoftware of "
                        "tfl_mav.api, docs/api.md); one that raises or returns NaN ends the "
                        "run (exit 1)")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", dest="settings",
                   help="override a scenario key (TOML value), repeatable")
    p.add_argument("--summary-json", metavar="FILE", help="write the run summary as JSON")
    p.add_argument("--quiet", action="store_true", help="no event lines on stderr")
    p.add_argument("--progress", action="store_true",
                   help="print 'progress T DURATION DISTANCE' on stderr every sim second "
                        "(machine-readable; tfl-mav demo draws its progress bar from it)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    prog = "tfl-mav fly"
    try:
        scenario = apply_overrides(load_scenario(args.scenario), args.settings)
        vehicle = parse_address(args.vehicle or "127.0.0.1:14580", "--vehicle")
        bind = (parse_address(args.bind, "--bind") if args.bind
                else None if args.vehicle else ("127.0.0.1", 14540))
        key = load_key(args.key_file) if args.key_file else None
        pt = args.peer_timeout
        if pt is not None and not (pt == 0 or (math.isfinite(pt) and pt > args.state_timeout)):
            raise ValueError(f"--peer-timeout: must be 0 (never) or more than --state-timeout "
                             f"({args.state_timeout:g} s), got {pt}")
        live = None
        if args.foxglove:
            from tfl_mav.flightlog.live import parse_live_address

            live = parse_live_address(args.foxglove)
        failures: list[str] = []
        software = (_software(args.controller, scenario, failures, lambda: daemon.stop())
                    if args.controller else None)
    except (ScenarioError, ValueError, LinkError) as exc:
        print(f"{prog}: {exc}", file=sys.stderr)
        return 2
    for path, option in ((args.summary_json, "--summary-json"), (args.mcap, "--mcap")):
        if path and (problem := file_problem(path, option)):
            print(f"{prog}: {problem}", file=sys.stderr)
            return 3
    for warning in check_scenario(scenario):
        print(f"tfl-mav fly: warning: {warning}", file=sys.stderr)
    # The recorder's child starts beside the controller's warm-up and never delays the
    # first command (a restarted daemon has 0.25 s before the vehicle cuts its motors).
    recorder = (StartingRecorder(scenario, args.mcap, live, args.realtime)
                if args.mcap or live else None)
    if recorder is not None and not args.realtime:
        recorder.wait_started()     # lockstep: nothing to gain, keep the old order exactly

    def on_event(level: str, text: str, t: float) -> None:
        if not args.quiet:
            print(f"fly [t={t:8.3f} s] {level.upper()}: {text}", file=sys.stderr, flush=True)
        if recorder is not None:
            recorder.log(level if level != "critical" else "error", text, t)

    duration = args.duration if args.duration is not None else scenario.run.duration_s
    next_progress = [0.0]

    def on_tick(t: float, record: tuple[Any, ...]) -> None:
        if recorder is not None:
            recorder.controller(t, record)
        if args.progress and t >= next_progress[0]:
            next_progress[0] = t + 1.0
            print(f"progress {t:.3f} {duration:.3f} {record[_DISTANCE]:.3e}",
                  file=sys.stderr, flush=True)

    def hold_start() -> bool:
        """A vehicle waiting at t = 0 waits for the recorder too (it costs nothing there);
        one that fails to start ends the run, as it always did."""
        assert recorder is not None
        if recorder.start_error:
            daemon.stop()
        return recorder.starting

    try:
        daemon = Daemon(scenario, vehicle=vehicle, bind=bind, realtime=args.realtime,
                        state_timeout_s=args.state_timeout, key=key,
                        silence_end_s=_silence_end_s(args),
                        on_tick=_tick_hook(recorder, args.progress, on_tick),
                        on_event=on_event,
                        hold_start=hold_start if recorder is not None else None,
                        flight_software=software)
    except (LinkError, ValueError) as exc:
        print(f"{prog}: {exc}", file=sys.stderr)
        if recorder is not None:
            recorder.close()
        return 3
    if recorder is not None:
        recorder.attach(daemon.link)
    if recorder is not None and recorder.start_error:   # it failed while we warmed up
        print(f"{prog}: {recorder.start_error}", file=sys.stderr)
        daemon.close()
        recorder.close()
        return 3
    got: dict[str, int] = {}

    def on_signal(signum: int, _frame: Any) -> None:
        got["signal"] = signum
        daemon.stop()

    previous = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        if not args.quiet:
            print(f"{prog}: controlling {vehicle[0]}:{vehicle[1]} from "
                  f"{daemon.link.local_address[1]}, scenario {scenario.name!r}"
                  f"{', MAVLink 2 signing on' if key is not None else ''}"
                  + (f", law core {daemon.computer.controller.core}" if software is None
                     else f", controller {args.controller}"),
                  file=sys.stderr, flush=True)
        result = daemon.run(duration)
    finally:
        for s, h in previous.items():
            signal.signal(s, h)
        daemon.close()
        if recorder is not None:
            recorder.close()
            if recorder.error:
                print(f"{prog}: recording stopped early: {recorder.error}", file=sys.stderr)
    summary = result.as_dict()
    if recorder is not None and recorder.recording is not None:
        summary["recording"] = recorder.recording
    io_error = ""
    if args.summary_json:
        try:
            write_text_atomic(args.summary_json, json.dumps(_clean(summary), indent=2))
        except OSError as exc:
            io_error = (f"{prog}: --summary-json {args.summary_json}: cannot write "
                        f"({exc.strerror or exc}); the file was left as it was")
    if not args.quiet:
        det = (f"rotor {result.detected_rotor} at {result.detection_time_s:.3f} s"
               if result.detected_rotor else "no attack detected")
        dist = result.final_path_distance_m
        print(f"{prog}: {result.reason} at t={result.sim_time_s:.3f} s; {det}; final path "
              f"distance {dist:.2e} m; {result.stats.ticks} ticks, "
              f"{result.stats.failsafes} failsafes, rejected "
              f"{sum(v for k, v in result.stats.link.items() if k not in _OK_COUNTERS)}"
              + _degraded(result.stats), file=sys.stderr)
    recording = summary.get("recording") or {}
    if not io_error and recording.get("write_error"):   # a full disk: a file error
        io_error = (f"{prog}: --mcap {args.mcap}: the recording stopped on a write error; "
                    + ("what was written reads" if recording.get("readable")
                       else "`tfl-mav inspect --recover` saves what reads"))
    if io_error:
        print(io_error, file=sys.stderr)
        return EXIT_IO
    if failures:
        print(f"{prog}: {failures[0]}", file=sys.stderr)
        return 1
    if "signal" in got:
        return 128 + got["signal"]
    if "silent" in result.reason:
        return 3   # the vehicle vanished without its goodbye: a link failure
    return 1 if "crashed" in result.reason else 0


def _degraded(st: Any) -> str:
    """The summary's word on real time: only when the loop fell behind."""
    if not st.gap_ticks:
        return ""
    return (f"; degraded real time: {st.gap_ticks} gaps integrated, {st.skipped_states} "
            f"states skipped in {st.degraded_episodes} episode"
            f"{'s' if st.degraded_episodes != 1 else ''}")


_DISTANCE = TICK_FIELDS.index("path_distance_m")


def _software(spec: str, scenario: Any, failures: list[str],
              stop: Callable[[], None]) -> Callable[[Any], Any]:
    """The daemon's flight software factory for ``--controller SPEC``: the user's software
    behind the guard, which ends the run on its first failure (one line in ``failures``).
    ValueError (one line) if SPEC cannot be loaded or made."""
    from tfl_mav.controller.software import (
        FlightSoftwareError,
        GuardedSoftware,
        load_flight_software,
    )

    name, factory = load_flight_software(spec)

    def failed(reason: str) -> None:
        failures.append(reason)
        stop()

    def make(sc: Any) -> Any:
        return GuardedSoftware(factory(sc), name=name, thrust_max_n=sc.vehicle.thrust_max_n,
                               on_failure=failed)
    try:
        make(scenario)          # made once before the vehicle waits: errors say so now
    except FlightSoftwareError:
        raise
    except Exception as exc:
        raise ValueError(f"--controller {spec}: making it raised {type(exc).__name__}: "
                         f"{' '.join(str(exc).split())[:200]}") from None
    return make


def _tick_hook(recorder: Any, progress: bool,
               on_tick: Callable[[float, tuple[Any, ...]], None]) -> Any:
    """The daemon's ``on_tick``: none when nothing reads the tick record (no recorder, no
    progress: the daemon then builds none), the recorder's own ``controller`` once it is up
    (lockstep: started before the daemon), else ``on_tick``."""
    if recorder is None and not progress:
        return None
    if recorder is not None and not progress and not recorder.starting:
        return recorder.controller
    return on_tick


def open_recorder(scenario: Any, mcap: str | None, live: tuple[str, int] | None,
                  clock: Callable[[], float] = time.time, realtime: bool = False) -> Any:
    """The controller's recorder: a :class:`~tfl_mav.flightlog.recorder_process.
    RecorderProcess` (a child process: the daemon hands it raw datagrams and compact tick
    tuples, the child decodes and encodes), told what to draw: the airframe's rotors, the
    path, the names and schema of :func:`~tfl_mav.controller.daemon.tick_state`. The live view draws
    the vehicle from the controller's state estimate (it has no truth; see
    :mod:`~tfl_mav.flightlog.live`). Raises OSError (a RecorderError) if the file or the
    live port is unusable, PathError for a bad path."""
    from tfl_mav.flightlog.live import EstimateScene, LiveAddress
    from tfl_mav.flightlog.recorder_process import RecorderProcess
    from tfl_mav.from_scenario import scenario_path
    from tfl_mav.model.airframe import rotor_xy_m

    path = scenario_path(scenario).sample(800)
    rotors = rotor_xy_m(scenario.vehicle)
    if live is not None:
        live = LiveAddress(live[0], live[1],
                           EstimateScene(rotors, scenario.vehicle.thrust_max_n))
    rec = RecorderProcess(mcap, rotor_xy_m=rotors,
                          thrust_max_n=scenario.vehicle.thrust_max_n,
                          controller_fields=TICK_FIELDS, controller_schema=TICK_SCHEMA,
                          live=live, clock=clock, realtime=realtime,
                          timeline="wall" if realtime else "sim", prog="tfl-mav fly")
    rec.metadata("scenario", {"name": scenario.name, "role": "controller",
                              "toml": json.dumps(scenario.to_dict())})
    rec.path(path)
    return rec


class StartingRecorder:
    """:func:`open_recorder` started on a thread, so the daemon's warm-up and first command
    never wait for the recorder's child (a fresh interpreter: 0.3-2 s on a loaded machine).

    Until the child is up and has the backlog, calls are buffered in order with their
    wall-clock stamps (kept through the recorder's clock). The *starting* thread hands the
    backlog over in small slices with a pause between them, so neither the loop thread nor
    the GIL pays for seconds of backlog at once (handing it over from the loop stalled it
    for tens of ms and crashed real-time flights); only when the buffer is empty do calls
    go to the recorder directly, so the order is kept. ``start_error``: why it did not
    start (the flight goes on unrecorded)."""

    _SLICE = 128                   # calls handed over per slice ...
    _PAUSE_S = 0.002               # ... then the GIL is left to the loop this long
    _BUFFER_MAX = 500_000          # ~80 s of a 1 kHz flight: beyond it, calls are dropped

    def __init__(self, scenario: Any, mcap: str | None, live: tuple[str, int] | None,
                 realtime: bool = False) -> None:
        self._realtime = realtime
        self._rec: Any = None
        self._direct = False       # backlog handed over: calls go straight to the recorder
        self._lock = threading.Lock()
        self._buffer: collections.deque[tuple[float, str, tuple[Any, ...]]] = (
            collections.deque())
        self._stamp: float | None = None
        self._links: list[Any] = []
        self.dropped = 0
        self.start_error: str | None = None
        self._thread = threading.Thread(target=self._start, args=(scenario, mcap, live),
                                        name="recorder-start", daemon=True)
        self._thread.start()

    def _start(self, scenario: Any, mcap: str | None, live: tuple[str, int] | None) -> None:
        from tfl_mav.control.path.paths import PathError

        try:
            self._rec = open_recorder(scenario, mcap, live, clock=self._clock,
                                      realtime=self._realtime)
        except (OSError, PathError, ScenarioError) as exc:
            self.start_error = str(exc)
        self._hand_over(pause_s=self._PAUSE_S)

    def _hand_over(self, pause_s: float) -> None:
        buf, rec = self._buffer, self._rec
        while True:
            with self._lock:
                if not buf:
                    self._direct = rec is not None
                    if self._direct:
                        self._go_direct()
                    return
                part = [buf.popleft() for _ in range(min(self._SLICE, len(buf)))]
                # Pause only while a backlog is left: calls keep coming (several a tick at
                # 1 kHz), so a pause after every slice would always find one more buffered
                # and the hand-over would never end.
                backlog = len(buf) >= self._SLICE
            if rec is not None:
                for stamp, name, args in part:
                    self._stamp = stamp
                    getattr(rec, name)(*args)
                self._stamp = None
            if pause_s and backlog:
                time.sleep(pause_s)

    def _go_direct(self) -> None:
        """From now on the hot calls skip this wrapper: the attached links' frame hook and
        :meth:`on_frame`/:meth:`controller` are the recorder's own (a call through an old
        reference still reaches it, in order, through :meth:`_call`)."""
        rec = self._rec
        rec.clock = time.time                   # no backlog left to stamp (see _clock)
        self.on_frame = rec.on_frame            # type: ignore[method-assign]
        self.controller = rec.controller        # type: ignore[method-assign]
        for link in self._links:
            link.on_frame = rec.on_frame
            link.on_frames = getattr(rec, "on_frames", None)   # one hand-off a datagram

    def attach(self, link: Any) -> None:
        """Record ``link``'s frames (its ``on_frame`` hook; once the child is up, the
        recorder's own)."""
        with self._lock:
            self._links.append(link)
            link.on_frame = self.on_frame
            if self._direct:                    # up already (lockstep: before the daemon)
                link.on_frames = getattr(self._rec, "on_frames", None)

    @property
    def direct(self) -> bool:
        """The child is up and the backlog handed over: calls go straight to the recorder."""
        return self._direct

    @property
    def recorder(self) -> Any:
        """The recorder once it is up (:func:`open_recorder`'s), else None."""
        return self._rec

    @property
    def starting(self) -> bool:
        """The child is not up yet (or its backlog not yet handed over)."""
        return self._thread.is_alive()

    def wait_started(self) -> None:
        self._thread.join()

    def _clock(self) -> float:
        return self._stamp if self._stamp is not None else time.time()

    def _call(self, name: str, args: tuple[Any, ...]) -> None:
        if not self._direct:
            with self._lock:
                if not self._direct:
                    if len(self._buffer) >= self._BUFFER_MAX:
                        self.dropped += 1
                    else:
                        self._buffer.append((time.time(), name, args))
                    return
        getattr(self._rec, name)(*args)

    def on_frame(self, direction: str, raw: bytes, msg: Any, time_s: float) -> None:
        self._call("on_frame", (direction, bytes(raw), msg, time_s))

    def controller(self, time_s: float, record: tuple[Any, ...]) -> None:
        self._call("controller", (time_s, record))

    def log(self, level: str, text: str, time_s: float | None = None) -> None:
        self._call("log", (level, text, time_s))

    @property
    def error(self) -> str | None:
        if self.start_error:
            return self.start_error
        err = self._rec.error if self._rec is not None else None
        return err or (f"{self.dropped} calls dropped while the recorder started"
                       if self.dropped else None)

    @property
    def recording(self) -> dict[str, Any] | None:
        """How the file ended (:attr:`RecorderProcess.recording`), None if it never started."""
        return self._rec.recording if self._rec is not None else None

    def close(self) -> None:
        """Wait for the start and the hand-over, then finish the file."""
        self._thread.join()
        self._hand_over(pause_s=0.0)      # anything buffered since (the loop has ended)
        if self._rec is not None:
            self._rec.close()


_SILENCE_END_S = 10.0   # real time: no state this long after the flight started = vehicle gone


def _silence_end_s(args: argparse.Namespace) -> float | None:
    """--peer-timeout as the daemon's ``silence_end_s`` (None: wait for ever)."""
    if args.peer_timeout is None:
        return _SILENCE_END_S if args.realtime else None
    return args.peer_timeout or None
_OK_COUNTERS = {"rx_datagrams", "rx_bytes", "rx_frames", "tx_frames", "tx_bytes"}


def _clean(obj: Any) -> Any:
    """JSON-safe copy: non-finite floats become null (JSON has no NaN)."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: _clean(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_clean(v) for v in obj]
    return obj
