"""The MCAP file (and live server) under the recorder: channels, writes, flushes, failures.

:class:`McapOutput` knows nothing of what is recorded: it registers channels (JSON with a
JSON Schema, or Foxglove's protobuf well-known types), writes messages to the file and to
the live server (:mod:`~tfl_mav.flightlog.live`) alike, finishes a chunk and flushes the
file at least every ``flush_interval_s`` (re-writing the *latched* message, e.g. the path,
so it survives seeking), and turns the first write error into a stopped recording instead
of an exception (see :mod:`~tfl_mav.flightlog.recorder` for the policy).
"""

from __future__ import annotations

import atexit
import contextlib
import math
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from mcap.writer import LIBRARY_IDENTIFIER, CompressionType, IndexType

from tfl_mav import __version__
from tfl_mav.flightlog import foxglove as fg
from tfl_mav.flightlog import schemas
from tfl_mav.flightlog.mcapfast import FastWriter

__all__ = ["TIMELINES", "McapOutput", "RecorderError", "RecorderStats"]

TIMELINES = ("wall", "sim")
_SIM_LOG_TIME = ("sim timeline: before the flight the receipt time on the recorder clock; "
                 "from sim time 0 on, the wall clock at sim time 0 + sim time (publish_time), "
                 "ns (Unix epoch); wall time in the 'timeline' metadata")

_COMPRESSION = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4,
                "none": CompressionType.NONE}
MAX_NS = 2**63 - 1
ZSTD_LEVEL = 1
"""zstd level of the chunks. Why not the library's 3: on a flight's chunks (base64 frames,
JSON) level 1 compresses as well (18.5 % vs 19.0 % of the raw size) at ~60 % of the CPU;
lz4 costs about as much CPU as level 1 for files ~1.7x larger, none ~5x larger
(bench/recorder_replay.py --compression)."""


WRITE_PIECE_BYTES = 32 * 1024
"""The largest single write to the MCAP file. Why: the kernel here does not preempt
a task inside a system call (``PREEMPT_NONE``, the usual server setting), so a recorder
child writing a finished chunk (~0.3 MB compressed) in one ``write`` made a woken flight
process wait for the whole copy, even from a ``SCHED_IDLE`` child. In 32 KiB pieces the
flight waits ≤ one piece: the sim's and the daemon's runqueue waits fell ~30 % and the
lockstep loop ran 1-17 % faster in 6 of 6 alternated pairs (``/proc/<tid>/schedstat``)."""


class _PiecewiseWrites:
    """A binary file whose writes reach the kernel in pieces of at most
    :data:`WRITE_PIECE_BYTES` (same bytes, same order); everything else is the file's."""

    def __init__(self, f: Any) -> None:
        self._f = f

    def write(self, data: Any) -> int:
        f = self._f
        view = memoryview(data).cast("B")
        n = view.nbytes
        if n <= WRITE_PIECE_BYTES:
            return f.write(data)
        for i in range(0, n, WRITE_PIECE_BYTES):
            f.write(view[i:i + WRITE_PIECE_BYTES])
        return n

    def __getattr__(self, name: str) -> Any:
        return getattr(self._f, name)


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


class _NoFile:
    """The MCAP writer's methods, writing nothing (live view without a file)."""

    def __init__(self) -> None:
        self._ids = 0

    def register_schema(self, *_a: Any) -> int:
        self._ids += 1
        return self._ids

    register_channel = register_schema

    def add_message(self, *_a: Any) -> None:
        pass

    add_metadata = flush = finish = add_pair = add_same_time = add_message



class McapOutput:
    """One MCAP file (or none: ``path=None``) plus an optional live server; see the module
    docstring. Raises ValueError for a bad setting, :class:`RecorderError` if the file
    cannot be written or the live port cannot be bound."""

    def __init__(self, path: str | Path | None, *, clock: Callable[[], float] = time.time,
                 flush_interval_s: float = 1.0, profile: str = "tfl-mav",
                 compression: str = "zstd", chunk_size_bytes: int = 1 << 20,
                 live: tuple[str, int] | None = None, timeline: str = "wall") -> None:
        if not (math.isfinite(flush_interval_s) and flush_interval_s > 0.0):
            raise ValueError(f"flush_interval_s: must be > 0, got {flush_interval_s}")
        if timeline not in TIMELINES:
            raise ValueError(f"timeline: must be one of {', '.join(TIMELINES)}, "
                             f"got {timeline!r}")
        # "sim" (lockstep): once sim time is known, log_time = the wall clock at which sim
        # time started + sim time (publish_time), so a viewer's timeline is the flight's,
        # whatever speed the machine ran at, and files still sort by when they were flown
        self._timeline_sim = timeline == "sim"
        self._epoch_ns: int | None = None     # wall ns at sim time 0 (sim timeline only)
        self._sim_ns = 0
        self._sim_known = False
        if compression not in _COMPRESSION:
            raise ValueError(f"compression: must be one of {sorted(_COMPRESSION)}, "
                             f"got {compression!r}")
        self.file_path = Path(path) if path is not None else None
        self.clock = clock
        self.stats = RecorderStats()
        self.error: str | None = None
        self.last_bad_input: str | None = None
        self._interval_s = flush_interval_s
        self._schema_ids: dict[str, int] = {}
        self._channel_ids: dict[str, int] = {}
        self._live_channels: dict[int, Any] = {}
        self._latched: tuple[int, bytes] | None = None
        self._pending = 0
        self._open = True           # accepting messages
        self._closed = False
        self._lock = threading.RLock()
        self._live = None
        if live is not None:
            from tfl_mav.flightlog.live import LiveServer

            try:
                self._live = LiveServer(*live)
            except OSError as exc:
                raise RecorderError(str(exc)) from None
        if self.file_path is None:
            self._file: Any = None
            self._writer: Any = _NoFile()
            self._start_flusher(flush_interval_s)
            return
        try:
            self._file = _PiecewiseWrites(open(self.file_path, "wb"))  # noqa: SIM115 -- close()
        except OSError as exc:
            self._close_live()
            raise RecorderError(f"cannot write MCAP file {self.file_path}: "
                                f"{exc.strerror or exc}") from None
        try:
            self._writer = FastWriter(self._file, chunk_size=chunk_size_bytes,
                                      compression=_COMPRESSION[compression],
                                      zstd_level=ZSTD_LEVEL,
                                      index_types=IndexType.CHUNK | IndexType.MESSAGE
                                      | IndexType.METADATA)
            self._writer.start(profile, library=f"tfl-mav {__version__}; {LIBRARY_IDENTIFIER}")
            self._writer.add_metadata("tfl-mav", {
                "log_time": (_SIM_LOG_TIME if self._timeline_sim else
                             "receipt time on the recorder clock, ns (Unix epoch by default)"),
                "publish_time": "sim time, ns; 0 = not known yet",
                "world_frame": "ENU, z up (Foxglove world); body = base_link",
                "mavlink": "MAVLink 2, pymavlink ardupilotmega dialect",
                "version": __version__})
            self._file.flush()
        except OSError as exc:
            with contextlib.suppress(OSError):   # closing re-flushes and fails the same way
                self._file.close()
            self._close_live()
            raise RecorderError(f"cannot write MCAP file {self.file_path}: "
                                f"{exc.strerror or exc}") from None
        self._start_flusher(flush_interval_s)

    def _start_flusher(self, flush_interval_s: float) -> None:
        self._next_flush = time.monotonic() + flush_interval_s
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
            if was_open:
                try:
                    if self._timeline_sim:
                        self._writer.add_metadata("timeline", self._timeline_facts())
                    self._writer.finish()
                except Exception as exc:
                    self._failed(exc)
            try:
                if self._file is not None:
                    self._file.close()
            except OSError as exc:
                if self.error is None:
                    self._failed(exc)
        self._close_live()

    def _close_live(self) -> None:
        if self._live is not None:
            self._live.close()
            self._live = None

    def metadata(self, name: str, values: Mapping[str, str]) -> None:
        """A named MCAP metadata record (e.g. the scenario), strings only."""
        items = {str(k): str(v) for k, v in values.items()}
        with self._lock:
            if not self._open:
                self.stats.dropped += 1
                return
            try:
                self._writer.add_metadata(name, items)
            except Exception as exc:
                self._failed(exc)

    def _pub_ns(self) -> int:
        """publish_time of a re-written latched message (the recorder's sim time)."""
        return 0

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
                        "wall_time_s": f"{wall_s:.3f}",
                        "real_time_factor": f"{sim_s / wall_s:.3f}" if wall_s > 0 else "-"})
        return out

    def _bad(self, what: str) -> None:
        self.stats.bad_input += 1
        self.last_bad_input = what

    def _channel(self, topic: str, schema: Mapping[str, Any]) -> int:
        """Channel id of a JSON ``topic`` with JSON Schema ``schema``."""
        cid = self._channel_ids.get(topic)
        if cid is None:
            cid = self._register(topic, schema["title"], "jsonschema",
                                 schemas.schema_bytes(dict(schema)), "json")
        return cid

    def _fg_channel(self, topic: str, type_name: str) -> int:
        """Channel id of a protobuf ``topic`` of Foxglove's well-known type ``type_name``."""
        cid = self._channel_ids.get(topic)
        if cid is None:
            cid = self._register(topic, *fg.schema(type_name), "protobuf")
        return cid

    def _register(self, topic: str, schema_name: str, schema_encoding: str,
                  schema_data: bytes, message_encoding: str) -> int:
        """Register ``topic`` on first use, in the file and on the live server (0 if the
        file has failed)."""
        try:
            with self._lock:
                sid = self._schema_ids.get(schema_name)
                if sid is None:
                    sid = self._schema_ids[schema_name] = self._writer.register_schema(
                        schema_name, schema_encoding, schema_data)
                cid = self._channel_ids[topic] = self._writer.register_channel(
                    topic, message_encoding, sid)
        except Exception as exc:   # registering may finish a chunk, i.e. write
            self._failed(exc)
            return 0
        if self._live is not None:
            self._live_channels[cid] = self._live.channel(
                topic, schema_name, schema_encoding, schema_data, message_encoding)
        return cid

    def latch(self, channel_id: int, data: bytes, log_ns: int, pub_ns: int) -> None:
        """Write ``data`` now and again with every periodic flush (e.g. the path)."""
        self._latched = (channel_id, data)
        self._write(channel_id, data, log_ns, pub_ns)

    def _write(self, channel_id: int, data: bytes, log_ns: int, pub_ns: int) -> None:
        if not self._open:
            self.stats.dropped += 1
            return
        try:
            with self._lock:
                self._writer.add_message(channel_id, log_ns, data, pub_ns)
                self._pending += 1
                self.stats.messages += 1
            if self._live is not None and channel_id in self._live_channels:
                self._live_channels[channel_id].log(data, log_time=log_ns)
            if time.monotonic() >= self._next_flush:
                self._flush()
        except Exception as exc:
            self._failed(exc)

    def _write_many(self, items: tuple[tuple[int, bytes], ...], log_ns: int,
                    pub_ns: int) -> None:
        """Several (channel id, data) with the same times, under one lock."""
        if not self._open:
            self.stats.dropped += len(items)
            return
        try:
            with self._lock:
                self._writer.add_same_time(items, log_ns, pub_ns)
                self._pending += len(items)
                self.stats.messages += len(items)
            self._after_write(items, log_ns)
        except Exception as exc:
            self._failed(exc)

    def _after_write(self, items: tuple[tuple[int, bytes], ...], log_ns: int) -> None:
        """What follows every write of several messages: the live view, the periodic flush."""
        if self._live is not None:
            for cid, data in items:
                if cid in self._live_channels:
                    self._live_channels[cid].log(data, log_time=log_ns)
        if time.monotonic() >= self._next_flush:
            self._flush()

    def _write_pair(self, cid_a: int, data_a: bytes, cid_b: int, data_b: bytes, log_ns: int,
                    pub_ns: int) -> None:
        """Two messages with the same times (a frame's raw and decoded records)."""
        if not self._open:
            self.stats.dropped += 2
            return
        try:
            with self._lock:
                self._writer.add_pair(cid_a, data_a, cid_b, data_b, log_ns, pub_ns)
                self._pending += 2
                self.stats.messages += 2
            self._after_write(((cid_a, data_a), (cid_b, data_b)), log_ns)
        except Exception as exc:
            self._failed(exc)

    def _flush(self) -> None:
        """Finish the chunk in progress (with a fresh copy of the path) and flush the file."""
        with self._lock:
            if not self._open or self._pending == 0:
                return
            if self._latched is not None:
                cid, data = self._latched
                now_ns = self._now_ns()
                self._writer.add_message(cid, now_ns, data, self._pub_ns())
                self.stats.messages += 1
                if self._live is not None and cid in self._live_channels:
                    self._live_channels[cid].log(data, log_time=now_ns)
            self._writer.flush()
            self._pending = 0
            self.stats.flushes += 1
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
        self._open = False
        self.stats.write_errors += 1
        self.stats.dropped += 1
        if self.error is None:
            reason = getattr(exc, "strerror", None) or str(exc) or type(exc).__name__
            self.error = (f"MCAP write to {self.file_path} failed ({reason}); recording stopped, "
                          "the flight goes on; the file reads up to its last complete chunk "
                          "(tfl-mav inspect FILE --recover OUT)")
