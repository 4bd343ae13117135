"""The MCAP file (and live server) under the recorder: channels, writes, flushes, failures.

:class:`McapOutput` knows nothing of what is recorded. Everything goes through Foxglove's
SDK: one ``foxglove.Context`` per recorder, its channels (``foxglove.Channel``), the MCAP
file as one sink of that context (``foxglove.open_mcap``) and, with ``live=``, the
WebSocket server as another (:mod:`~tfl_mav.flightlog.live`), so one ``log`` call writes
the file and feeds the live view. It finishes the chunk in progress and flushes the file
(the SDK's ``flush``) at least every ``flush_interval_s``, re-writing the *latched*
message (e.g. the path) first so it survives seeking, and turns the first write error into
a stopped recording instead of an exception (see :mod:`~tfl_mav.flightlog.recorder`).

Every call into the SDK's writer is made under one lock: the SDK writes to our Python file
object (:class:`PiecewiseFile`: write errors seen, writes in pieces) while holding its own lock, so
a flush on the background thread and a ``log`` on the loop's thread, each waiting for what
the other holds (the SDK's lock, the GIL), would deadlock.

``publish_time`` is the SDK's: the log time. Sim time is in the records themselves
(``t_s``, MAVLink ``time_usec``) and, in lockstep, on the timeline (see ``timeline``).
"""

from __future__ import annotations

import atexit
import contextlib
import math
import os
import re
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import foxglove
from foxglove.mcap import MCAPCompression, MCAPWriteOptions

from tfl_mav import __version__

__all__ = ["TIMELINES", "McapOutput", "RecorderError", "RecorderStats"]

TIMELINES = ("wall", "sim")
_SIM_LOG_TIME = ("sim timeline: before the flight the receipt time on the recorder clock; "
                 "from sim time 0 on, the wall clock at sim time 0 (flight_start_ns in the "
                 "'timeline' metadata) + sim time, ns (Unix epoch)")

_COMPRESSION = {"zstd": MCAPCompression.Zstd, "lz4": MCAPCompression.Lz4, "none": None}
MAX_NS = 2**63 - 1
ZSTD_LEVEL = 1
"""zstd level of the chunks (the SDK compresses in Rust, inline in the thread that logs):
the recorder children's CPU is what they take from the lockstep loop, and level 3 made
files only slightly smaller for more CPU."""

CHUNK_BYTES = 1 << 20
"""Uncompressed size of a chunk (a flush ends one sooner, at least every
``flush_interval_s``). 4 MiB compressed no better on a flight's messages (same MiB per
flight-minute in bench/recorder_replay.py), and a file cut short loses less with small ones."""

FLUSH_SIM_NS = 500_000_000
"""Sim time between flushes, whatever the wall clock does: a lockstep flight runs several
times faster than real time, and a file cut short (its writer killed) should lose at most
~0.5 s of *flight*, not ``flush_interval_s`` × the speed-up. The latched copy of the path
is only re-written on the wall-clock flush (it is large, and a viewer needs it per wall
second, not per flight second)."""

WRITE_PIECE_BYTES = 32 * 1024
"""The largest single write to the MCAP file. Why: the kernel here does not preempt
a task inside a system call (``PREEMPT_NONE``, the usual server setting), so a recorder
child writing a finished chunk (~0.3 MB compressed) in one ``write`` made a woken flight
process wait for the whole copy, even from a ``SCHED_IDLE`` child. In 32 KiB pieces the
flight waits ≤ one piece."""


class PiecewiseFile:
    """The binary file the SDK writes: writes reach the kernel in pieces of at most
    :data:`WRITE_PIECE_BYTES`, and the first failing write is kept in :attr:`error` (the
    SDK only logs it) and reported to ``on_error``."""

    def __init__(self, f: Any, on_error: Callable[[BaseException], None]) -> None:
        self._f = f
        self._on_error = on_error
        self.error: BaseException | None = None

    def write(self, data: Any) -> int:
        f = self._f
        view = memoryview(data).cast("B")
        n = view.nbytes
        try:
            for i in range(0, n, WRITE_PIECE_BYTES):
                f.write(view[i:i + WRITE_PIECE_BYTES])
        except OSError as exc:
            self._error(exc)
            raise
        return n

    def seek(self, *args: Any) -> int:
        try:
            return self._f.seek(*args)
        except OSError as exc:
            self._error(exc)
            raise

    def tell(self) -> int:
        return self._f.tell()

    def flush(self) -> None:
        try:
            self._f.flush()
        except OSError as exc:
            self._error(exc)
            raise

    def _error(self, exc: OSError) -> None:
        if self.error is None:
            self.error = exc
            self._on_error(exc)

    def close(self) -> None:
        self._f.close()


_OS_ERROR = re.compile(r"os error (\d+)")


def error_reason(exc: BaseException) -> str:
    """A write error in words a user reads: the OS's own text (``No space left on
    device``) for an ``OSError``, or for an error the SDK's Rust writer raises with the OS
    error number in its text; else the exception's type and first line."""
    text = getattr(exc, "strerror", None)
    if text:
        return str(text)
    m = _OS_ERROR.search(str(exc))
    if m:
        return os.strerror(int(m.group(1)))
    first = (str(exc).strip().splitlines() or [""])[0][:120]
    return f"{type(exc).__name__}: {first}" if first else type(exc).__name__


_SDK_QUIET = False


def _quiet_sdk() -> None:
    """The SDK's own log at errors only, once per process, before its first sink: a failing
    write is reported once by :class:`McapOutput` in words (:func:`error_reason`), not also
    as the writer's raw ``McapError(Io(...))`` warning on stderr. ``foxglove.set_log_level``
    also configures the root logger (``logging.basicConfig``, at that level): the root
    logger is put back as it was, so the program's own warnings still show."""
    global _SDK_QUIET
    if _SDK_QUIET:
        return
    _SDK_QUIET = True
    import logging

    root = logging.getLogger()
    handlers, level = list(root.handlers), root.level
    try:
        foxglove.set_log_level("ERROR")
    except Exception:       # an SDK without it: its default stays
        return
    finally:
        for h in list(root.handlers):
            if h not in handlers:
                root.removeHandler(h)
        root.setLevel(level)


class RecorderError(OSError):
    """The recording cannot start (path not writable); the message names the path."""


@dataclass
class RecorderStats:
    messages: int = 0           # MCAP messages written, all channels
    frames_rx: int = 0          # rx frames recorded (accepted + rejected)
    frames_tx: int = 0
    frames_rejected: int = 0    # rx frames the link rejected (raw channel only)
    flushes: int = 0
    write_errors: int = 0       # 0 or 1: the first error stops the recording
    dropped: int = 0            # messages not written: file failed or already closed
    bad_input: int = 0          # loop-method calls refused or partly refused

    def as_dict(self) -> dict[str, int]:
        return asdict(self)


class McapOutput:
    """One MCAP file (or none: ``path=None``) plus an optional live server; see the module
    docstring. Raises ValueError for a bad setting, :class:`RecorderError` if the file
    cannot be written or the live port cannot be bound."""

    def __init__(self, path: str | Path | None, *, clock: Callable[[], float] = time.time,
                 flush_interval_s: float = 1.0, profile: str = "tfl-mav",
                 compression: str = "zstd", chunk_size_bytes: int = CHUNK_BYTES,
                 live: tuple[str, int] | None = None, timeline: str = "wall") -> None:
        if not (math.isfinite(flush_interval_s) and flush_interval_s > 0.0):
            raise ValueError(f"flush_interval_s: must be > 0, got {flush_interval_s}")
        if timeline not in TIMELINES:
            raise ValueError(f"timeline: must be one of {', '.join(TIMELINES)}, "
                             f"got {timeline!r}")
        if compression not in _COMPRESSION:
            raise ValueError(f"compression: must be one of {sorted(_COMPRESSION)}, "
                             f"got {compression!r}")
        # "sim" (lockstep): once sim time is known, log_time = the wall clock at which sim
        # time started + sim time, so a viewer's timeline is the flight's, whatever speed
        # the machine ran at, and files still sort by when they were flown
        self._timeline_sim = timeline == "sim"
        self._epoch_ns: int | None = None     # wall ns at sim time 0 (sim timeline only)
        self._sim_ns = 0
        self._sim_known = False
        self.file_path = Path(path) if path is not None else None
        self.clock = clock
        self.stats = RecorderStats()
        self.error: str | None = None
        self.repair: dict[str, Any] | None = None    # a failed file's repair (mcaprepair)
        self.error_reason = ""
        self._error_head = ""
        self.last_bad_input: str | None = None
        self._interval_s = flush_interval_s
        self._channels: dict[str, Any] = {}      # topic → its channel's log(data, ns)
        self._latched: tuple[Any, bytes] | None = None
        self._pending = 0
        self._open = True           # accepting messages
        self._closed = False
        self._lock = threading.RLock()
        _quiet_sdk()
        self._context = foxglove.Context()     # this recorder's channels and sinks only
        self._live = None
        self._file: PiecewiseFile | None = None
        self._writer: Any = None
        if self.file_path is not None:
            try:
                f = open(self.file_path, "wb")  # noqa: SIM115 -- closed in close()
            except OSError as exc:
                raise RecorderError(f"cannot write MCAP file {self.file_path}: "
                                    f"{exc.strerror or exc}") from None
            self._file = PiecewiseFile(f, self._failed)
            try:
                self._writer = foxglove.open_mcap(
                    self._file, context=self._context, writer_options=MCAPWriteOptions(
                        compression=_COMPRESSION[compression], profile=profile,
                        chunk_size=chunk_size_bytes, compression_level=ZSTD_LEVEL,
                        compression_threads=0))
                self._writer.write_metadata("tfl-mav", {
                    "log_time": (_SIM_LOG_TIME if self._timeline_sim else
                                 "receipt time on the recorder clock, ns (Unix epoch by "
                                 "default)"),
                    "publish_time": "= log_time; sim time is in the records (t_s, "
                                    "time_usec) and on a sim timeline",
                    "world_frame": "ENU, z up (Foxglove world); body = base_link",
                    "mavlink": "MAVLink 2, pymavlink ardupilotmega dialect",
                    "library": f"tfl-mav {__version__}; foxglove-sdk",
                    "version": __version__})
                self._writer.flush()
                if self._file.error is not None:
                    raise self._file.error
            except Exception as exc:
                with contextlib.suppress(Exception):
                    f.close()
                cause = self._file.error or exc
                reason = getattr(cause, "strerror", None) or str(cause)
                raise RecorderError(f"cannot write MCAP file {self.file_path}: "
                                    f"{reason}") from None
        if live is not None:
            from tfl_mav.flightlog.live import LiveServer

            try:
                self._live = LiveServer(*live, context=self._context)
            except OSError as exc:
                self._close_file()
                raise RecorderError(str(exc)) from None
        self._next_flush = time.monotonic() + flush_interval_s
        self._next_flush_sim_ns = FLUSH_SIM_NS
        self._stop = threading.Event()
        self._flusher = threading.Thread(target=self._flush_loop, name="mcap-flush",
                                         daemon=True)
        self._flusher.start()
        atexit.register(self.close)     # an exception that ends the program still finishes

    def __enter__(self) -> Any:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        """Finish the file (summary, indexes). Idempotent; never raises on I/O errors
        (see :attr:`error`). Later calls to the loop methods are counted as dropped.
        Not from a signal handler (it could interrupt a write): set a flag there and close
        after the loop."""
        if self._closed:
            return
        self._closed = True
        atexit.unregister(self.close)
        self._stop.set()
        self._flusher.join()
        with self._lock:
            was_open, self._open = self._open, False
            if was_open and self._writer is not None and self._timeline_sim:
                try:
                    self._writer.write_metadata("timeline", self._timeline_facts())
                except Exception as exc:
                    self._failed(exc)
            self._close_file()
        if self._live is not None:
            self._live.close()
            self._live = None

    def _close_file(self) -> None:
        """Finish the file (the SDK writes the summary) and close it, failed or not."""
        if self._writer is not None:
            try:
                self._writer.close()
            except Exception as exc:
                if self.error is None:
                    self._failed(exc)
            self._writer = None
        if self._file is not None:
            try:
                self._file.close()
            except OSError as exc:
                if self.error is None:
                    self._failed(exc)
            self._file = None
            if self.error is not None and self.file_path is not None:
                self._repair()

    def _repair(self) -> None:
        """A file whose writing failed (disk full) has no summary: make what was written
        readable in place (:mod:`~tfl_mav.flightlog.mcaprepair`, read back to prove it)."""
        from tfl_mav.flightlog.mcaprepair import repair

        try:
            rep = repair(self.file_path, f"writing failed: {self.error_reason}").as_dict()
        except OSError as exc:
            rep = {"readable": False, "error": exc.strerror or str(exc)}
        self.repair = rep
        if rep.get("readable"):
            last = rep.get("last_sim_time_s")
            self.error = self._error_head + (
                f"; what was written reads (repaired, ends at sim t = {last:.3f} s)"
                if last is not None else "; what was written reads (repaired)")
        else:
            self.error = self._error_head + (
                f"; the file could not be repaired ({rep.get('error')}): "
                f"`tfl-mav inspect {self.file_path} --recover OUT.mcap` saves what reads")

    def metadata(self, name: str, values: Mapping[str, str]) -> None:
        """A named MCAP metadata record (e.g. the scenario), strings only."""
        items = {str(k): str(v) for k, v in values.items()}
        with self._lock:
            if not self._open:
                self.stats.dropped += 1
                return
            if self._writer is None:
                return
            try:
                self._writer.write_metadata(name, items)
            except Exception as exc:
                self._failed(exc)

    def _now_ns(self) -> int:
        """log_time of a message written now: the clock's, or on the sim timeline."""
        try:
            wall = min(max(int(self.clock() * 1e9), 0), MAX_NS)
        except (TypeError, ValueError, OverflowError):
            wall = 0
        return self._on_timeline(wall) if self._timeline_sim else wall

    def _on_timeline(self, wall_ns: int) -> int:
        """``wall_ns`` (a receipt time) as log_time: itself while sim time is unknown (before
        the flight) or on a wall timeline, else flight start + sim time."""
        if not (self._timeline_sim and self._sim_known):
            return wall_ns
        if self._epoch_ns is None:
            self._epoch_ns = wall_ns - self._sim_ns
        return min(max(self._epoch_ns + self._sim_ns, 0), MAX_NS)

    def _timeline_facts(self) -> dict[str, str]:
        """The ``timeline`` metadata written at close: where the wall clock went."""
        try:
            wall_end = float(self.clock())    # the recorder's clock: the close's own stamp
        except (TypeError, ValueError):
            wall_end = math.nan
        sim_s = self._sim_ns * 1e-9
        out = {"log_time": "sim", "sim_time_s": f"{sim_s:.6f}",
               "wall_end_unix_s": f"{wall_end:.6f}"}
        if self._epoch_ns is not None:
            wall_s = wall_end - self._epoch_ns * 1e-9
            out.update({"flight_start_unix_s": f"{self._epoch_ns * 1e-9:.6f}",
                        "flight_start_ns": str(self._epoch_ns),
                        "wall_time_s": f"{wall_s:.3f}",
                        "real_time_factor": f"{sim_s / wall_s:.3f}" if wall_s > 0 else "-"})
        return out

    def _bad(self, what: str) -> None:
        self.stats.bad_input += 1
        self.last_bad_input = what

    def _channel(self, topic: str, schema_name: str, schema_encoding: str,
                 schema_data: bytes, message_encoding: str) -> Any:
        """The ``log(data, log_ns)`` of ``topic``'s channel, made on first use (in the file
        and on the live server alike); None if it cannot be made."""
        emit = self._channels.get(topic)
        if emit is not None:
            return emit
        try:
            with self._lock:
                if self._live is not None:
                    ch = self._live.channel(topic, schema_name, schema_encoding, schema_data,
                                            message_encoding)
                else:
                    ch = foxglove.Channel(topic, message_encoding=message_encoding,
                                          schema=foxglove.Schema(name=schema_name,
                                                                 encoding=schema_encoding,
                                                                 data=schema_data),
                                          context=self._context).base
                emit = self._channels[topic] = ch.log
        except Exception as exc:
            self._failed(exc)
            return None
        return emit

    def latch(self, emit: Any, data: bytes, log_ns: int) -> None:
        """Write ``data`` now and again with every periodic flush (e.g. the path)."""
        self._latched = (emit, data)
        self._write(emit, data, log_ns)

    def _write(self, emit: Any, data: bytes, log_ns: int) -> None:
        if not self._open or emit is None:
            self.stats.dropped += 1
            return
        try:
            with self._lock:
                emit(data, log_ns)
                self._pending += 1
                self.stats.messages += 1
            if time.monotonic() >= self._next_flush:
                self._flush()
            elif self._sim_ns >= self._next_flush_sim_ns:
                self._flush(wall=False)
        except Exception as exc:
            self._failed(exc)

    def _write_many(self, items: tuple[tuple[Any, bytes], ...], log_ns: int) -> None:
        """Several (channel, data) with the same log time, under one lock."""
        if not self._open:
            self.stats.dropped += len(items)
            return
        try:
            with self._lock:
                for emit, data in items:
                    emit(data, log_ns)
                self._pending += len(items)
                self.stats.messages += len(items)
            if time.monotonic() >= self._next_flush:
                self._flush()
            elif self._sim_ns >= self._next_flush_sim_ns:
                self._flush(wall=False)
        except Exception as exc:
            self._failed(exc)

    def _write_timed(self, items: list[tuple[Any, bytes, int]]) -> None:
        """Several (channel, data, log time), in order, under one lock."""
        if not items:
            return
        if not self._open:
            self.stats.dropped += len(items)
            return
        try:
            with self._lock:
                for emit, data, log_ns in items:
                    emit(data, log_ns)
                self._pending += len(items)
                self.stats.messages += len(items)
            if time.monotonic() >= self._next_flush:
                self._flush()
            elif self._sim_ns >= self._next_flush_sim_ns:
                self._flush(wall=False)
        except Exception as exc:
            self._failed(exc)

    def _flush(self, wall: bool = True) -> None:
        """Finish the chunk in progress and flush the file; ``wall``: the wall-clock flush,
        which also writes a fresh copy of the latched message (the path)."""
        with self._lock:
            self._next_flush_sim_ns = self._sim_ns + FLUSH_SIM_NS
            if not self._open or self._pending == 0:
                return
            if wall and self._latched is not None:
                emit, data = self._latched
                emit(data, self._now_ns())
                self.stats.messages += 1
            if self._writer is not None:
                self._writer.flush()
            self._pending = 0
            self.stats.flushes += 1
            if wall:
                self._next_flush = time.monotonic() + self._interval_s

    def _flush_loop(self) -> None:
        """Background flush for when the loop goes quiet (no writes, nothing flushes)."""
        while not self._stop.wait(self._interval_s / 4.0):
            if self._pending and time.monotonic() >= self._next_flush:
                try:
                    self._flush()
                except Exception as exc:
                    self._failed(exc)

    def _failed(self, exc: BaseException) -> None:
        """First write error: stop recording, keep the reason; never raise."""
        if self.error is not None:
            return
        self._open = False
        self.stats.write_errors += 1
        self.stats.dropped += 1
        self.error_reason = error_reason(exc)
        self._error_head = (f"MCAP write to {self.file_path} failed ({self.error_reason}); "
                            "recording stopped, the flight goes on")
        self.error = (self._error_head + "; the file reads up to its last complete chunk "
                      f"(`tfl-mav inspect {self.file_path} --recover OUT.mcap`)")
