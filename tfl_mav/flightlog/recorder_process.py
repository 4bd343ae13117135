"""The :class:`~tfl_mav.flightlog.recorder.Recorder` API with the work in a child process.

Why: recording costs several µs of CPU per frame in-process (records + MCAP), a large
share of a 1 kHz lockstep tick. Here the flight process only stamps each call with its
clock and appends a tuple to a queue: raw datagrams as ``bytes``, the controller's record
as the caller's compact tuple, no dict building and no encoding on the control path. A
background thread pickles the queue in batches (every ``batch_s``, while the flight loop
waits for its peer) and sends it over a pipe to a child that runs a real ``Recorder``
with that clock reading as ``log_time``, on the other core: it decodes the frames, names
the record's fields, encodes the records, writes the file and feeds the live
Foxglove server (``live=``). The messages are the ones an in-process recording writes
(only the periodic copies of ``/scene/path`` follow the child's flush timing).

Batch entry: :meth:`RecorderProcess.on_frames` (direction, raws, msgs, time_s) takes a
whole datagram's frames (or any frames of one direction and one receipt time) as one
queue item, for a link that hands them over once per datagram; :meth:`on_frame` (the
link's per-frame hook) works as before, and both write the same messages.

Crash safety is better than in-process: if the flight process dies (even SIGKILL) the
child reads end-of-file and *finishes* the file. Queued calls reach the child within
``batch_s`` (a background thread sends a batch that went stale). The child ignores SIGINT
and SIGTERM so a Ctrl-C or ``kill`` of the process group still lets the parent close it.
It runs at a lower priority than the flight (:mod:`~tfl_mav.flightlog.child_priority`).

Backpressure: if the queue grows past ``batch_max`` × :data:`BACKLOG_BATCHES` calls (the
sender thread starved),
the flight thread sends inline; if the child falls behind, the pipe fills and the flight
process waits. Not in real time (``realtime=True``): there the flight thread only ever
appends, and past ``batch_max`` × 64 queued calls drops them (counted in ``dropped``) — a
real-time loop that waits for its recorder misses its deadlines. The child runs
:data:`NICE_INCREMENT` nicer than its parent and, in lockstep where the system lets it
be promoted back, at ``SCHED_IDLE`` until it first falls behind (:attr:`priority`).
Errors never raise into the loop: :attr:`error` reports the child's write error, or that
the child died (later calls are counted in ``dropped``); :attr:`stats` is the child's
final :class:`~tfl_mav.flightlog.recorder.RecorderStats`, filled in by :meth:`close`.
"""

from __future__ import annotations

import atexit
import collections
import contextlib
import multiprocessing
import os
import pickle
import select
import signal
import struct
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any

from tfl_mav.flightlog.child_priority import NICE_INCREMENT, Priority
from tfl_mav.flightlog.mcaprepair import CUT_METADATA
from tfl_mav.flightlog.recorder import Recorder, RecorderError, RecorderStats

__all__ = ["BEHIND_S", "NICE_INCREMENT", "RecorderProcess"]

_FRAME, _TRUTH, _PATH, _LOG, _CONTROLLER, _SIM_TIME, _METADATA, _CLOSE, _FRAMES = range(9)
_START_TIMEOUT_S = 30.0
_CLOSE_TIMEOUT_S = 60.0
BEHIND_S = 0.25
"""A batch's send that has waited this long for room in the pipe: the child is behind (a
lockstep flight's backpressure makes it wait ~10 ms; a child starved by other programs
waits seconds), and an idle child is promoted (:mod:`~tfl_mav.flightlog.child_priority`)."""
_POLL_MS = 50                   # how often a waiting send reports how long it has waited


BACKLOG_BATCHES = 2
"""Calls queued in the flight process (in batches of ``batch_max``) before its own thread
sends them: what a SIGKILL of the flight process can lose besides a batch being written.
At ~3 calls a tick, 2 × 512 calls are ~0.35 s of a flight (8 lost up to 1.4 s when a
loaded machine starved the sender thread); an idle sender sends ~100 calls every
``batch_s``, so the flight thread sends only when starved."""

_REPAIR_TIMEOUT_S = 600.0      # a repair reads the whole file: ~1 min for a 1 GB log


def _stderr_line(text: str) -> None:
    with contextlib.suppress(OSError, ValueError):
        print(text, file=sys.stderr, flush=True)


def run_repair(path: str | Path, reason: str) -> dict[str, Any]:
    """Repair ``path`` in place (:mod:`~tfl_mav.flightlog.mcaprepair`) in a process of
    its own (its own session: it finishes even if the flight's process group is killed; at
    the recorder's lower priority), and return its result (``readable`` etc.)."""
    import json

    try:
        proc = subprocess.Popen([sys.executable, "-m", "tfl_mav.flightlog.mcaprepair",
                                 str(path), reason], stdout=subprocess.PIPE,
                                stderr=subprocess.PIPE, text=True, start_new_session=True)
    except OSError as exc:
        return {"readable": False, "error": f"repair did not start: {exc.strerror or exc}"}
    Priority(proc.pid)          # niced; never idle: close() may wait for it
    try:
        out, err = proc.communicate(timeout=_REPAIR_TIMEOUT_S)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.communicate()
        return {"readable": False, "error": f"repair took over {_REPAIR_TIMEOUT_S:g} s"}
    try:
        return dict(json.loads(out.strip().splitlines()[-1]))
    except (ValueError, IndexError):
        tail = (err.strip().splitlines() or ["no output"])[-1]
        return {"readable": False, "error": f"repair failed ({tail})"}


def _plain(x: Any) -> Any:
    return x.tolist() if hasattr(x, "tolist") else x


def _child_main(conn: Connection, results: Connection, path: str | None,
                kwargs: dict[str, Any]) -> None:
    """The child: one Recorder whose clock is the parent's stamp of the call at hand.

    ``TFL_MAV_PROFILE=DIR`` in the environment: run under cProfile and dump the stats to
    ``DIR/recorder-PID.prof`` (bench/bench_lockstep.py's per-process breakdown)."""
    prof_dir = os.environ.get("TFL_MAV_PROFILE")
    if not prof_dir:
        _child_loop(conn, results, path, kwargs)
        return
    import cProfile

    prof = cProfile.Profile(time.process_time)     # CPU, not wall: 4 processes share 2 cores
    try:
        prof.runcall(_child_loop, conn, results, path, kwargs)
    finally:
        prof.dump_stats(os.path.join(prof_dir, f"recorder-{os.getpid()}.prof"))


def _child_loop(conn: Connection, results: Connection, path: str | None,
                kwargs: dict[str, Any]) -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    now = [0.0]
    try:
        rec = Recorder(path, clock=lambda: now[0], **kwargs)
    except (OSError, ValueError) as exc:
        with contextlib.suppress(OSError):      # a parent already gone hears nothing
            results.send(("fail", isinstance(exc, OSError), str(exc)))
        return
    reported = False
    orphaned = False
    try:
        try:
            results.send(("ok",))
        except OSError:                 # the parent died while this child started
            orphaned = True
        while not orphaned:
            try:
                data = conn.recv_bytes()
            except (EOFError, OSError):     # the parent is gone (perhaps mid-message):
                orphaned = True             # finish the file anyway
                break
            if not handle_batch(rec, data, now):
                break
            if rec.error and not reported:
                with contextlib.suppress(OSError):
                    results.send(("error", rec.error))
                reported = True
    finally:
        if orphaned:        # the file ends where the flight's process did: say so in it
            rec.metadata(CUT_METADATA, {
                "complete": "false",
                "reason": "the flight process ended without closing the recording "
                          "(killed?)",
                "last_sim_time_s": f"{rec.sim_time_s:.6f}"})
        rec.close()
        with contextlib.suppress(OSError):
            results.send(("done", rec.error, rec.last_bad_input, rec.stats.as_dict(),
                          rec.repair))


def handle_batch(rec: Recorder, data: bytes, now: list[float]) -> bool:
    """Apply one pickled batch of calls to ``rec`` (``now[0]``: the stamp of the call at
    hand, the recorder's clock). False when the batch ends with close."""
    items = pickle.loads(data)
    i, n = 0, len(items)
    while i < n:
        item = items[i]
        op, now[0] = item[0], item[1]
        i += 1
        if op == _FRAME:              # a run of frames in one call (the hot path)
            j = i
            while j < n and items[j][0] == _FRAME:
                j += 1
            now[0] = items[j - 1][1]
            rec.on_frames(items[i - 1:j])
            i = j
        elif op == _FRAMES:           # one datagram's frames: (_FRAMES, t, dir, raws, ok)
            ok = item[4]
            rec.on_frames([(None, now[0], item[2], raw, True if ok is None else ok[k])
                           for k, raw in enumerate(item[3])])
        elif op == _TRUTH:
            rec.truth(*item[2])
        elif op == _CONTROLLER:
            rec.controller(item[2], item[3])
        elif op == _LOG:
            rec.log(item[2], item[3], item[4], source=item[5])
        elif op == _SIM_TIME:
            rec.set_sim_time(item[2])
        elif op == _PATH:
            try:
                rec.path(item[2])
            except ValueError as exc:
                rec.log("error", f"path not recorded: {exc}")
        elif op == _METADATA:
            rec.metadata(item[2], item[3])
        elif op == _CLOSE:
            return False
    return True


def _write_message(fd: int, data: bytes, waited: Callable[[float], None]) -> None:
    """``Connection.send_bytes``'s framing (a 4-byte big-endian length, then the bytes) on
    the non-blocking pipe ``fd``; while the pipe is full, wait in ``poll`` and tell
    ``waited`` how long so far (every ``_POLL_MS``). Raises ``OSError`` if the child is
    gone (``BrokenPipeError``)."""
    n = len(data)
    header = struct.pack("!i", n) if n < 0x7FFFFFFF else struct.pack("!iQ", -1, n)
    poller = None
    t0 = 0.0
    for piece in (header, data):            # the payload is not copied to prepend the header
        view = memoryview(piece)
        while view:
            try:
                view = view[os.write(fd, view):]
                continue
            except BlockingIOError:
                pass
            if poller is None:
                poller = select.poll()
                poller.register(fd, select.POLLOUT)
                t0 = time.monotonic()
            poller.poll(_POLL_MS)
            waited(time.monotonic() - t0)


class RecorderProcess:
    """Same methods as :class:`~tfl_mav.flightlog.recorder.Recorder`; the recording runs in
    a child process (see the module docstring). ``batch_s``: longest a call waits in the
    parent before it is sent; ``batch_max``: calls per batch. Other keywords go to the
    child's ``Recorder``. Raises :class:`RecorderError` if the file cannot be written."""

    def __init__(self, path: str | Path | None, *, clock: Callable[[], float] = time.time,
                 batch_s: float = 0.01, batch_max: int = 512, realtime: bool = False,
                 prog: str = "tfl-mav", say: Callable[[str], None] | None = None,
                 **recorder_kw: Any) -> None:
        self.file_path = Path(path) if path is not None else None
        self._prog = prog
        self._say = say or _stderr_line
        self._sent_sim_s: float | None = None    # sim time of the last call sent to the child
        self._lost_lock = threading.Lock()
        self._lost_seen = False                  # the child died before finishing the file
        self._repair: dict[str, Any] | None = None
        self._write_failed = False               # the child reported a write error
        self.clock = clock
        self.stats = RecorderStats()
        self.last_bad_input: str | None = None
        self._error: str | None = None
        self._batch_s = batch_s
        self._backlog_max = BACKLOG_BATCHES * batch_max
        # Real time: the flight thread never waits for the child; past this many
        # queued calls (seconds of a 1 kHz flight) new ones are dropped and counted.
        self._realtime_max = 64 * batch_max if realtime else 0
        self._room = self._realtime_max or self._backlog_max   # 0: closed or child gone
        self._queue: collections.deque[tuple[Any, ...]] = collections.deque()
        self._send_lock = threading.Lock()
        self._alive = True
        self._done = False          # the child reported the file finished ("done")
        self._closed = False
        ctx = multiprocessing.get_context("spawn")   # no inherited sockets or threads
        child_conn, self._conn = ctx.Pipe(duplex=False)
        os.set_blocking(self._conn.fileno(), False)     # _write_message waits in poll
        self._results, child_results = ctx.Pipe(duplex=False)
        self._proc = ctx.Process(target=_child_main, name="tfl-mav-recorder",
                                 args=(child_conn, child_results,
                                       str(path) if path is not None else None, recorder_kw))
        self._proc.start()
        self.priority = Priority(self._proc.pid)   # from here: its imports are nicer too
        child_conn.close()
        child_results.close()
        try:
            if not self._results.poll(_START_TIMEOUT_S):
                raise EOFError
            reply = self._results.recv()
        except (EOFError, OSError):
            self._proc.kill()
            self._proc.join()
            raise RecorderError(f"recorder process for {path or 'the live view'} did not "
                                f"start (exit code {self._proc.exitcode})") from None
        if reply[0] == "fail":
            self._proc.join()
            raise (RecorderError if reply[1] else ValueError)(reply[2])
        if not realtime:                # idle only where backpressure can wait for it
            self.priority.go_idle()
        self._stop = threading.Event()
        self._sender = threading.Thread(target=self._send_stale, name="mcap-batch",
                                        daemon=True)
        self._sender.start()
        self._watcher = threading.Thread(target=self._watch, name="recorder-watch",
                                         daemon=True)
        self._watcher.start()
        # at exit, close before multiprocessing joins the child (which waits for our EOF)
        atexit.register(self.close)

    # ------------------------------------------------------------------ lifecycle
    def __enter__(self) -> RecorderProcess:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def attach(self, link: Any) -> None:
        """Hook into a Link and give it this recorder's clock (one clock per file)."""
        link.on_frame = self.on_frame
        link.clock = self.clock

    @property
    def pid(self) -> int:
        """The recorder child's process id (the OS's)."""
        return self._proc.pid

    @property
    def error(self) -> str | None:
        """The child's write error, or why the child is gone; None while all is well."""
        if self._error is None and self._alive:
            self._poll_results()
        return self._error

    def close(self) -> None:
        """Send what is queued, let the child finish the file, collect its stats."""
        if self._closed:
            return
        self._closed = True
        self._room = 0
        atexit.unregister(self.close)
        self._stop.set()
        self._sender.join()
        self.priority.promote()      # from now on the user waits for the child
        self._queue.append((_CLOSE, self.clock()))
        self._send()
        deadline = time.monotonic() + _CLOSE_TIMEOUT_S
        while self._alive and time.monotonic() < deadline:
            self._poll_results(timeout_s=0.5)   # "done" (or end-of-file) ends the wait
        self._proc.join(5.0)
        if self._proc.is_alive():
            # A child that said "done" has finished and closed the file; a niced child on a
            # loaded machine may just be slow to exit. Only one that never said so failed.
            self._proc.kill()
            self._proc.join(5.0)
            if not self._done:
                self._set_error("recorder process did not finish the file in time")
        if not self._done:
            self._lost()                # the file was never finished: repair it now
        self._watcher.join(_REPAIR_TIMEOUT_S)
        self._conn.close()
        self._results.close()

    @property
    def recording(self) -> dict[str, Any] | None:
        """How the file ended, for a run's summary (None without a file): ``path``,
        ``complete`` (the child finished it after the last call), ``write_error`` (the
        recording stopped because a write failed: a full disk), ``readable`` (by any MCAP
        reader: True for a finished file, else the repair's read-back), and for a file cut
        short ``reason``, ``last_sim_time_s`` (where it now ends), ``died_at_sim_s`` (sim
        time of the last call the child took, if it died) and the ``repair``'s figures.
        Final after :meth:`close`."""
        if self.file_path is None:
            return None
        out: dict[str, Any] = {"path": str(self.file_path),
                               "complete": self._done and not self._lost_seen
                               and self._error is None,
                               "write_error": self._write_failed}
        rep = self._repair
        if out["complete"]:
            out["readable"] = True
            return out
        out["reason"] = self._error or "unknown"
        if self._lost_seen:     # where the flight was when its recorder died
            out["died_at_sim_s"] = self._sent_sim_s
        if rep is not None:
            out.update(readable=bool(rep.get("readable")),
                       last_sim_time_s=rep.get("last_sim_time_s"),
                       repair={k: rep.get(k) for k in ("repaired", "messages", "kept_bytes",
                                                       "cut_bytes", "error")})
        else:
            out["readable"] = self._done    # a child that finished it after a write error
        return out

    # ------------------------------------------------------------------ a child that dies
    def _watch(self) -> None:
        """Background: the moment the child exits before :meth:`close` asked it to, say so
        and repair the file (:meth:`_lost`)."""
        from multiprocessing.connection import wait

        while not self._closed:
            if wait([self._proc.sentinel], 0.2):
                break
        else:
            return
        if not self._closed:    # only close() ends the child; anything else killed it
            self._lost()

    def _lost(self) -> None:
        """The child is gone and the file is not finished: say so at once (one line), then
        make the file readable in place in a process of its own
        (:mod:`~tfl_mav.flightlog.mcaprepair`, proved by reading it back), and say where it
        now ends."""
        with self._lost_lock:
            if self._lost_seen:
                return
            self._lost_seen = True
        self._proc.join(1.0)        # reaped: its exit code says how it ended
        code = self._proc.exitcode
        how = (f"killed by {signal.Signals(-code).name}" if code is not None and code < 0
               else f"exit code {code}" if code is not None else "gone")
        at = (f" at sim t = {self._sent_sim_s:.3f} s" if self._sent_sim_s is not None
              else "")
        self._alive = False
        self._room = 0
        self._error = f"recorder process for {self.file_path} died ({how}){at}"
        self._say(f"{self._prog}: recording cut short: the recorder process for "
                  f"{self.file_path or 'the live view'} died ({how}){at}; the flight goes "
                  "on unrecorded" + ("; repairing the file" if self.file_path else ""))
        if self.file_path is None:
            return
        rep = run_repair(self.file_path, f"recorder process died ({how}){at}")
        self._repair = rep
        if rep.get("readable"):
            last = rep.get("last_sim_time_s")
            self._error += (f"; the file is repaired and ends at sim t = {last:.3f} s"
                            if last is not None else "; the file is repaired")
            self._say(f"{self._prog}: {self.file_path}: repaired, readable by any MCAP "
                      f"reader; it ends at "
                      + (f"sim t = {last:.3f} s" if last is not None else "its start")
                      + f" ({rep.get('messages', 0)} messages)")
        else:
            self._error += f"; the file could not be repaired ({rep.get('error')})"
            self._say(f"{self._prog}: {self.file_path}: could not be repaired "
                      f"({rep.get('error')}); `tfl-mav inspect {self.file_path} --recover "
                      "OUT.mcap` saves what reads")

    # ------------------------------------------------------------------ the Recorder API
    # The hot calls (on_frame, on_frames, truth, controller) are one Python call each: a
    # tuple of plain values (bytes, floats, lists, the caller's record) appended when the
    # queue has room (``_room``: 0 once closed or the child is gone); ``_put`` is only the
    # full/dropped case.
    def on_frame(self, direction: str, raw: bytes, msg: Any, time_s: float) -> None:
        """The link's frame hook: one frame (``msg`` None: rejected, or a raw send)."""
        item = (_FRAME, time_s, direction, bytes(raw), msg is not None)
        q = self._queue
        if len(q) < self._room:
            q.append(item)
        else:
            self._put(item)

    def on_frames(self, direction: str, raws: Sequence[bytes], msgs: Sequence[Any] | None,
                  time_s: float) -> None:
        """Many frames of one direction at one receipt time ``time_s`` (e.g. one datagram's):
        as many :meth:`on_frame` calls, in one queue item. ``msgs``: each frame's decoded
        message or None (rejected), as :meth:`on_frame`'s ``msg``; None: all accepted."""
        ok = None
        if msgs is not None:
            for m in msgs:
                if m is None:
                    ok = tuple([m is not None for m in msgs])
                    break
        item = (_FRAMES, time_s, direction, tuple(map(bytes, raws)), ok)
        q = self._queue
        if len(q) < self._room:
            q.append(item)
        else:
            self._put(item)

    def truth(self, time_s: float, position_m: Sequence[float], velocity_mps: Sequence[float],
              quaternion_wxyz: Sequence[float], body_rates_radps: Sequence[float],
              rotor_thrust_n: Sequence[float], attack_rotor: int, attack_applied_n: float,
              attack_requested_n: float, wind_mps: Sequence[float] | None = None) -> None:
        args: tuple[Any, ...] = (time_s, position_m, velocity_mps, quaternion_wxyz,
                                 body_rates_radps, rotor_thrust_n, attack_rotor,
                                 attack_applied_n, attack_requested_n)
        if wind_mps is not None:
            args = (*args, wind_mps)
        if not (type(position_m) is list and type(velocity_mps) is list
                and type(quaternion_wxyz) is list and type(body_rates_radps) is list
                and type(rotor_thrust_n) is list and type(attack_rotor) is int
                and type(attack_applied_n) is float and type(attack_requested_n) is float
                and type(wind_mps) in (tuple, list, type(None))):
            args = tuple(map(_plain, args))     # numpy arrays and scalars: plain values
        item = (_TRUTH, self.clock(), args)
        q = self._queue
        if len(q) < self._room:
            q.append(item)
        else:
            self._put(item)

    def path(self, points_m: Any) -> None:
        from tfl_mav.flightlog.polyline import Polyline

        Polyline(points_m)       # same ValueError as Recorder.path, raised here
        self._put((_PATH, self.clock(), _plain(points_m)))

    def log(self, level: int | str, text: str, time_s: float | None = None, *,
            source: str = "tfl-mav") -> None:
        self._put((_LOG, self.clock(), level, str(text), time_s, source))

    def controller(self, time_s: float, state: Mapping[str, Any] | Sequence[Any]) -> None:
        """Queue the caller's record as it is (a compact tuple of plain values is cheapest
        to pickle); the child names its fields (``controller_fields``) and encodes it."""
        item = (_CONTROLLER, self.clock(), time_s, state)
        q = self._queue
        if len(q) < self._room:
            q.append(item)
        else:
            self._put(item)

    def set_sim_time(self, time_s: float) -> None:
        self._put((_SIM_TIME, self.clock(), time_s))

    def metadata(self, name: str, values: Mapping[str, str]) -> None:
        self._put((_METADATA, self.clock(), name, {str(k): str(v) for k, v in values.items()}))

    # ------------------------------------------------------------------ internals
    def _put(self, item: tuple[Any, ...]) -> None:
        if not self._alive or self._closed:
            self.stats.dropped += 1
            return
        q = self._queue
        if len(q) < self._room:
            q.append(item)
        elif self._realtime_max:        # real time: never wait, drop and count
            self.stats.dropped += 1
        else:                           # the sender thread is starved: send here
            q.append(item)
            self._send()

    def _send(self) -> None:
        with self._send_lock:
            q = self._queue
            items = [q.popleft() for _ in range(len(q))]
            if not items:
                return
            if not self._alive:
                self.stats.dropped += len(items)
                return
            try:
                _write_message(self._conn.fileno(),
                               pickle.dumps(items, protocol=pickle.HIGHEST_PROTOCOL),
                               self._behind)
                for item in reversed(items):    # where the flight is: for a cut log's word
                    op = item[0]
                    if op == _TRUTH:
                        self._sent_sim_s = item[2][0]
                        break
                    if op in (_CONTROLLER, _SIM_TIME):
                        self._sent_sim_s = item[2]
                        break
            except (OSError, ValueError, pickle.PicklingError) as exc:
                self.stats.dropped += len(items)
                self._set_error(f"recorder process for {self.file_path} is gone ({exc}); "
                                "the flight goes on unrecorded")

    def _behind(self, waited_s: float) -> None:
        """A send has waited ``waited_s`` for room in the pipe (the child is behind)."""
        if waited_s >= BEHIND_S:
            self.priority.promote()

    def _send_stale(self) -> None:
        """Background: send what is queued every ``batch_s`` (the batch hand-off)."""
        while not self._stop.wait(self._batch_s):
            if self._queue:
                self._send()

    def _poll_results(self, timeout_s: float = 0.0) -> bool:
        try:
            if not self._results.poll(timeout_s):
                return False
            reply = self._results.recv()
        except (EOFError, OSError):
            self._set_error(f"recorder process for {self.file_path} is gone")
            return False
        if reply[0] == "error":
            self._error = reply[1]
            self._write_failed = True
        elif reply[0] == "done":
            _, error, bad, stats, repair = reply
            if repair is not None:
                self._repair = repair
            self._error = error if self._write_failed and error else (self._error or error)
            self.last_bad_input = bad
            dropped = self.stats.dropped
            self.stats = RecorderStats(**stats)
            self.stats.dropped += dropped
            self._alive = False
            self._room = 0
            self._done = True
        return True

    def _set_error(self, text: str) -> None:
        self._alive = False
        self._room = 0
        if self._error is None:
            self._error = text
