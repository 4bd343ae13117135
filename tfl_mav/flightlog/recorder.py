"""MCAP recorder: every MAVLink frame, simulator ground truth and Foxglove scene, one file.

Channels (JSON messages, one JSON Schema per channel, see :mod:`tfl_mav.flightlog.schemas`):

* ``/mavlink/raw``: every frame the link saw, both directions, exact wire bytes (base64),
  with ``direction`` and ``accepted``: replayable byte for byte (``tfl-mav replay``).
* ``/mavlink/{sysid}/{compid}/{MSG}``: each accepted rx frame and each frame this process
  packed and sent, decoded *from its wire bytes* (float32 rounding and all).
* ``/sim/truth/state``, ``/sim/truth/attack``, ``/sim/truth/thrusts`` (every
  :meth:`Recorder.truth` call) and ``/sim/truth/path_distance``, ``/tf``,
  ``/scene/vehicle`` (at most ``scene_hz`` in sim time); ``/scene/path`` (on
  :meth:`Recorder.path`, then again with every periodic flush so it survives seeking);
  ``/log`` (:meth:`Recorder.log` and every STATUSTEXT seen); ``/controller/state``.

Time: ``log_time`` is the receipt time on the recorder's ``clock`` (ns; frames use the
``time_s`` the link hook passes, so give the link the same clock: :meth:`Recorder.attach`
does). ``publish_time`` is **sim time** (ns): the latest of :meth:`set_sim_time`, the
``time_s`` given to ``truth``/``controller``/``log``, and ``time_usec`` of the messages in
``sim_time_messages`` (ODOMETRY and HIL_ACTUATOR_CONTROLS carry sim time), taken
when they pass, so a received state is stamped with its own time even before the caller
reacts. 0 until a sim time is known.

Crash safety: chunked, zstd (or lz4) compressed; the chunk in progress is finished and the
file flushed to the OS at least every ``flush_interval_s``: inline when messages keep
coming, from a small background thread when they stop. A SIGKILLed process loses at most
the last interval; everything before reads with a stream reader (``tfl-mav inspect
--recover``). A program that ends without :meth:`Recorder.close` (an uncaught exception)
still finishes the file, at exit. No fsync: an OS crash or power loss can lose more.
:class:`~tfl_mav.flightlog.recorder_process.RecorderProcess` runs the same recorder in a
child process, which also finishes the file when the flight process is killed.

Failure policy: an unwritable path raises :class:`RecorderError` (an ``OSError``) at
construction. After that nothing raises into the flight loop: a write error (disk full)
stops the recording, is counted (``stats.write_errors``) and described in
:attr:`Recorder.error`; later messages are counted as ``dropped``. Bad arguments to the
loop methods (wrong length, not a number, unknown direction) are counted
(``stats.bad_input``) and described in :attr:`Recorder.last_bad_input`. NaN/inf (and None)
are never written (JSON has no NaN, Foxglove wants no null in a number field): such values
are left out and listed in ``_nonfinite``.
"""

from __future__ import annotations

import atexit
import base64
import contextlib
import json
import math
import threading
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from mcap.writer import LIBRARY_IDENTIFIER, CompressionType, IndexType, Writer

from tfl_mav import __version__
from tfl_mav.flightlog import foxglove as fg
from tfl_mav.flightlog import schemas
from tfl_mav.flightlog.polyline import Polyline
from tfl_mav.link.dialect import mav
from tfl_mav.link.payload import PayloadDecoder

__all__ = ["Recorder", "RecorderError", "RecorderStats"]

_COMPRESSION = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4,
                "none": CompressionType.NONE}
_MAX_NS = 2**63 - 1
_STATUSTEXT_ID = mav.MAVLINK_MSG_ID_STATUSTEXT
_MAX_PATH_POINTS = 2000


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


def _jsonable(obj: Any) -> Any:
    """``default`` hook of the encoder: numpy arrays/scalars, tuples-likes, bytes."""
    if hasattr(obj, "tolist"):
        return obj.tolist()
    if isinstance(obj, (bytes, bytearray)):
        return base64.b64encode(obj).decode("ascii")
    if isinstance(obj, Iterable):
        return list(obj)
    raise TypeError(f"{type(obj).__name__} is not JSON serialisable")


def _all_finite(value: Any) -> bool:
    """No NaN, inf or None anywhere in ``value`` (JSON would need null for them)."""
    if isinstance(value, float):
        return math.isfinite(value)
    if value is None:
        return False
    if isinstance(value, Mapping):
        return all(_all_finite(v) for v in value.values())
    if isinstance(value, (list, tuple)):
        try:                                        # flat list of numbers: the usual case
            return all(map(math.isfinite, value))
        except (TypeError, OverflowError):
            return all(_all_finite(v) for v in value)
    if hasattr(value, "tolist"):
        return _all_finite(value.tolist())
    return True


def _drop_nonfinite(obj: Mapping[str, Any], prefix: str = "",
                    dropped: list[str] | None = None) -> dict[str, Any]:
    """A copy of ``obj`` without NaN/inf/None: such a value, or a list holding one, is left
    out and its dotted key listed under ``_nonfinite`` (see :mod:`schemas`)."""
    top = dropped is None
    dropped = [] if dropped is None else dropped
    out: dict[str, Any] = {}
    for k, v in obj.items():
        if isinstance(v, Mapping):
            out[k] = _drop_nonfinite(v, f"{prefix}{k}.", dropped)
        elif _all_finite(v):
            out[k] = v
        else:
            dropped.append(f"{prefix}{k}")
    if top and dropped:
        out[schemas.NONFINITE_KEY] = dropped
    return out


def _floats(values: Any, n: int, field: str) -> list[float]:
    """``n`` floats from a sequence or array; ValueError naming ``field`` otherwise."""
    seq = values.tolist() if hasattr(values, "tolist") else values
    try:
        out = [float(v) for v in seq]
    except (TypeError, ValueError):
        raise ValueError(f"{field}: expected {n} numbers, got {values!r}") from None
    if len(out) != n:
        raise ValueError(f"{field}: expected {n} values, got {len(out)}")
    return out


@dataclass
class _MavChannel:
    channel_id: int
    name: str
    sim_time: bool          # time_usec of this message is sim time
    statustext: bool
    nonfinite: bool = False  # NaN/inf seen on this channel: check before encoding


class Recorder:
    """Writes one MCAP file; see the module docstring. Use as a context manager."""

    def __init__(self, path: str | Path, *, clock: Callable[[], float] = time.time,
                 flush_interval_s: float = 1.0, profile: str = "tfl-mav",
                 compression: str = "zstd", chunk_size_bytes: int = 1 << 20,
                 scene_hz: float = 50.0, arm_m: float = 0.2656, thrust_max_n: float = 8.0,
                 sim_time_messages: Iterable[str] = ("ODOMETRY", "HIL_ACTUATOR_CONTROLS"),
                 ) -> None:
        """Open ``path`` for writing and start the file.

        ``clock``: seconds, the receipt clock of ``log_time``. ``scene_hz``: max rate (sim
        time) of ``/tf``, ``/scene/vehicle`` and ``/sim/truth/path_distance``. ``arm_m``,
        ``thrust_max_n``: vehicle geometry and thrust scale for drawing only.
        Raises ValueError for a bad setting, :class:`RecorderError` if the file cannot be
        written.
        """
        if not (math.isfinite(flush_interval_s) and flush_interval_s > 0.0):
            raise ValueError(f"flush_interval_s: must be > 0, got {flush_interval_s}")
        if compression not in _COMPRESSION:
            raise ValueError(f"compression: must be one of {sorted(_COMPRESSION)}, "
                             f"got {compression!r}")
        if not (math.isfinite(scene_hz) and scene_hz > 0.0):
            raise ValueError(f"scene_hz: must be > 0, got {scene_hz}")
        if not (arm_m > 0.0 and thrust_max_n > 0.0):
            raise ValueError(f"arm_m, thrust_max_n: must be > 0, got {arm_m}, {thrust_max_n}")
        self.file_path = Path(path)
        self.clock = clock
        self.stats = RecorderStats()
        self.error: str | None = None
        self.last_bad_input: str | None = None
        self._interval_s = flush_interval_s
        self._scene_period_s = 1.0 / scene_hz
        self._arm_m = arm_m
        self._thrust_max_n = thrust_max_n
        self._sim_time_ids = {mav_id for mav_id, cls in mav.mavlink_map.items()
                              if cls.msgname in set(sim_time_messages)
                              and "time_usec" in cls.fieldnames}
        self._encode = json.JSONEncoder(separators=(",", ":"), default=_jsonable).encode
        self._decoder = PayloadDecoder()
        self._schema_ids: dict[str, int] = {}
        self._channel_ids: dict[str, int] = {}
        self._mav_channels: dict[tuple[int, int, int], _MavChannel] = {}
        self._sim_ns = 0
        self._sim_known = False
        self._last_scene_t = -math.inf
        self._polyline: Polyline | None = None
        self._path_data: bytes | None = None
        self._path_cid = 0
        self._pending = 0
        self._open = True           # accepting messages
        self._closed = False
        self._lock = threading.RLock()
        try:
            self._file = open(self.file_path, "wb")  # noqa: SIM115 -- closed in close()
        except OSError as exc:
            raise RecorderError(f"cannot write MCAP file {self.file_path}: "
                                f"{exc.strerror or exc}") from None
        try:
            self._writer = Writer(self._file, chunk_size=chunk_size_bytes,
                                  compression=_COMPRESSION[compression],
                                  index_types=IndexType.CHUNK | IndexType.MESSAGE
                                  | IndexType.METADATA)
            self._writer.start(profile, library=f"tfl-mav {__version__}; {LIBRARY_IDENTIFIER}")
            self._writer.add_metadata("tfl-mav", {
                "log_time": "receipt time on the recorder clock, ns (Unix epoch by default)",
                "publish_time": "sim time, ns; 0 = not known yet",
                "world_frame": "paper frame = ENU, z up (Foxglove world); body = base_link",
                "mavlink": "MAVLink 2, pymavlink ardupilotmega dialect",
                "version": __version__})
            self._file.flush()
        except OSError as exc:
            with contextlib.suppress(OSError):   # closing re-flushes and fails the same way
                self._file.close()
            raise RecorderError(f"cannot write MCAP file {self.file_path}: "
                                f"{exc.strerror or exc}") from None
        self._next_flush = time.monotonic() + flush_interval_s
        self._stop = threading.Event()
        self._flusher = threading.Thread(target=self._flush_loop, name="mcap-flush",
                                         daemon=True)
        self._flusher.start()
        atexit.register(self.close)     # an exception that ends the program still finishes

    # ------------------------------------------------------------------ lifecycle
    def __enter__(self) -> Recorder:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def attach(self, link: Any) -> None:
        """Hook this recorder into a :class:`~tfl_mav.link.transport.Link` and give the link
        the recorder's clock, so every ``log_time`` in the file is on one clock."""
        link.on_frame = self.on_frame
        link.clock = self.clock

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
                    self._writer.finish()
                except Exception as exc:
                    self._failed(exc)
            try:
                self._file.close()
            except OSError as exc:
                if self.error is None:
                    self._failed(exc)

    @property
    def sim_time_s(self) -> float:
        return self._sim_ns * 1e-9

    def set_sim_time(self, time_s: float) -> None:
        """Sim time (s) for ``publish_time`` of what is recorded next."""
        try:
            ns = round(time_s * 1e9)
        except (TypeError, ValueError, OverflowError):
            self._bad(f"time_s: expected a finite number, got {time_s!r}")
            return
        if 0 <= ns <= _MAX_NS:
            self._sim_ns = ns
            self._sim_known = True
        else:
            self._bad(f"time_s: out of range ({time_s})")

    # ------------------------------------------------------------------ link hook
    def on_frame(self, direction: str, raw: bytes, msg: Any, time_s: float) -> None:
        """The :class:`~tfl_mav.link.transport.Link` frame hook (``on_frame``): record one
        frame. ``msg`` is the decoded message, or None for a rejected rx frame or a
        ``send_raw`` tx frame; only whether it is None matters, the fields are decoded
        from ``raw``. ``time_s`` is the receipt time (s) on the recorder's clock."""
        try:
            log_ns = min(max(int(time_s * 1e9), 0), _MAX_NS)
        except (TypeError, ValueError, OverflowError):
            log_ns = self._now_ns()
        st = self.stats
        if direction == "rx":
            st.frames_rx += 1
        elif direction == "tx":
            st.frames_tx += 1
        else:
            self._bad(f"direction: expected 'rx' or 'tx', got {direction!r}")
            return
        data = base64.b64encode(raw).decode("ascii")
        if msg is None:
            if direction == "rx":
                st.frames_rejected += 1
            accepted = "false" if direction == "rx" else "true"
            self._write(self._raw_channel(),
                        f'{{"direction":"{direction}","accepted":{accepted},'
                        f'"len":{len(raw)},"data":"{data}"}}'.encode(), log_ns, self._sim_ns)
            return
        msgid = raw[7] | raw[8] << 8 | raw[9] << 16
        sysid, compid = raw[5], raw[6]
        chan = self._mav_channels.get((sysid, compid, msgid))
        if chan is None:
            chan = self._new_mav_channel(sysid, compid, msgid)
        fields = self._decoder.fields(raw, msgid) if chan is not None else None
        if fields is not None and chan.sim_time:
            usec = fields["time_usec"]
            if usec * 1000 <= _MAX_NS:
                self._sim_ns = usec * 1000
                self._sim_known = True
        pub_ns = self._sim_ns
        name = chan.name if chan is not None else f"#{msgid}"
        self._write(self._raw_channel(),
                    f'{{"direction":"{direction}","accepted":true,"name":"{name}",'
                    f'"msgid":{msgid},"sysid":{sysid},"compid":{compid},"seq":{raw[4]},'
                    f'"len":{len(raw)},"data":"{data}"}}'.encode(), log_ns, pub_ns)
        if fields is None:
            self._bad(f"frame: {name} (#{msgid}) did not decode from its wire bytes")
            return
        self._write(chan.channel_id, self._dumps_mav(fields, chan), log_ns, pub_ns)
        if chan.statustext:
            self._write(self._channel("/log", schemas.FOXGLOVE_SCHEMAS["foxglove.Log"]),
                        self._dumps(fg.log_entry(log_ns,
                                                 fg.mav_severity_to_level(fields["severity"]),
                                                 self._with_time(fields["text"]),
                                                 f"mavlink/{sysid}/{compid} {direction}")),
                        log_ns, pub_ns)

    # ------------------------------------------------------------------ ground truth, scene
    def truth(self, time_s: float, position_m: Sequence[float], velocity_mps: Sequence[float],
              quaternion_wxyz: Sequence[float], body_rates_radps: Sequence[float],
              rotor_thrust_n: Sequence[float], attack_rotor: int, attack_applied_n: float,
              attack_requested_n: float) -> None:
        """Simulator ground truth at sim time ``time_s`` (s), paper frame (ENU, z up):
        position (m), velocity (m/s), attitude quaternion body → world (w, x, y, z), body
        rates (rad/s), true rotor thrusts 1-4 (N), attacked rotor (1-4, 0 = none), applied
        and requested attack thrust (N). Also drives ``/tf``, ``/scene/vehicle`` and
        ``/sim/truth/path_distance`` at up to ``scene_hz``."""
        try:
            if not math.isfinite(time_s):
                raise ValueError(f"time_s: not finite ({time_s})")
            pos = _floats(position_m, 3, "position_m")
            vel = _floats(velocity_mps, 3, "velocity_mps")
            quat = _floats(quaternion_wxyz, 4, "quaternion_wxyz")
            rates = _floats(body_rates_radps, 3, "body_rates_radps")
            thrust = _floats(rotor_thrust_n, 4, "rotor_thrust_n")
            rotor = int(attack_rotor)
            if rotor != attack_rotor or not 0 <= rotor <= 4:
                raise ValueError(f"attack_rotor: expected 0-4, got {attack_rotor!r}")
            applied, requested = float(attack_applied_n), float(attack_requested_n)
        except (TypeError, ValueError) as exc:
            self._bad(f"truth: {exc}")
            return
        self.set_sim_time(time_s)
        log_ns, pub_ns = self._now_ns(), self._sim_ns
        t = float(time_s)
        self._write(self._channel("/sim/truth/state", schemas.TRUTH_STATE),
                    self._dumps({"t_s": t, "position_m": pos, "velocity_mps": vel,
                                 "quaternion_wxyz": quat, "body_rates_radps": rates}),
                    log_ns, pub_ns)
        self._write(self._channel("/sim/truth/attack", schemas.TRUTH_ATTACK),
                    self._dumps({"t_s": t, "rotor": rotor, "active": rotor != 0,
                                 "applied_n": applied, "requested_n": requested}),
                    log_ns, pub_ns)
        self._write(self._channel("/sim/truth/thrusts", schemas.TRUTH_THRUSTS),
                    self._dumps({"t_s": t, "thrust_n": thrust, "attack_rotor": rotor}),
                    log_ns, pub_ns)
        # 1 µs slack so k·dt rounding does not push a sample to the next tick
        if self._last_scene_t <= t < self._last_scene_t + self._scene_period_s - 1e-6:
            return
        self._last_scene_t = t
        if not all(map(math.isfinite, pos + quat + thrust)):
            self._bad(f"truth: position/attitude/thrust not finite at t = {t} s; "
                      "scene not drawn")
            return
        self._write(self._channel("/tf", schemas.FOXGLOVE_SCHEMAS["foxglove.FrameTransform"]),
                    self._dumps(fg.frame_transform(log_ns, pos, quat)), log_ns, pub_ns)
        self._write(self._channel("/scene/vehicle",
                                  schemas.FOXGLOVE_SCHEMAS["foxglove.SceneUpdate"]),
                    self._dumps(fg.vehicle_scene(log_ns, self._arm_m, thrust,
                                                 self._thrust_max_n, rotor)), log_ns, pub_ns)
        if self._polyline is not None:
            self._write(self._channel("/sim/truth/path_distance", schemas.PATH_DISTANCE),
                        self._dumps({"t_s": t, "distance_m": self._polyline.distance(pos)}),
                        log_ns, pub_ns)

    def path(self, points_m: Any) -> None:
        """The path as sampled points (N, 3) in m, paper frame: ``/scene/path`` now and with
        every periodic flush after. More than 2000 points are thinned evenly. Raises
        ValueError naming ``points_m`` if the array is not (N ≥ 2, 3) and finite (a setup
        call, not a loop call)."""
        poly = Polyline(points_m)
        pts = poly.points_m
        if len(pts) > _MAX_PATH_POINTS:
            step = math.ceil(len(pts) / _MAX_PATH_POINTS)
            pts = pts[::step] if (len(pts) - 1) % step == 0 else [*pts[::step], pts[-1]]
        log_ns = self._now_ns()
        data = self._dumps(fg.path_scene(log_ns, [list(map(float, p)) for p in pts]))
        self._path_cid = self._channel("/scene/path",
                                       schemas.FOXGLOVE_SCHEMAS["foxglove.SceneUpdate"])
        self._polyline = poly
        self._path_data = data
        self._write(self._path_cid, data, log_ns, self._sim_ns)

    # ------------------------------------------------------------------ logs, controller
    def log(self, level: int | str, text: str, time_s: float | None = None, *,
            source: str = "tfl-mav") -> None:
        """A ``foxglove.Log`` on ``/log``: ``level`` 0-5 or a name (debug, info, warning,
        error, fatal), ``time_s`` the sim time of the event (s) if known."""
        if isinstance(level, str):
            lvl = fg.LOG_LEVELS.get(level.lower())
        else:
            lvl = level if isinstance(level, int) and 0 <= level <= 5 else None
        if lvl is None:
            self._bad(f"level: expected 0-5 or one of {sorted(fg.LOG_LEVELS)}, got {level!r}")
            lvl = fg.LOG_LEVELS["unknown"]
        if time_s is not None:
            self.set_sim_time(time_s)
        log_ns = self._now_ns()
        self._write(self._channel("/log", schemas.FOXGLOVE_SCHEMAS["foxglove.Log"]),
                    self._dumps(fg.log_entry(log_ns, lvl, self._with_time(str(text)),
                                             source)), log_ns, self._sim_ns)

    def controller(self, time_s: float, state: Mapping[str, Any]) -> None:
        """Free-form controller state at sim time ``time_s`` (s) on ``/controller/state``.
        Keys the tools and the layout read (typed in the schema): ``mode`` (str),
        ``detected_rotor`` (int 0-4), ``attack_estimate_n``, ``path_distance_m`` (float),
        ``saturated`` (bool), ``rotor_thrust_cmd_n`` (4 floats); any other key is kept as
        is. numpy values are fine; NaN/inf/None values are left out (``_nonfinite``)."""
        try:
            t = float(time_s)
            if not math.isfinite(t):
                raise ValueError(f"time_s: not finite ({time_s})")
            data = self._dumps({**state, "t_s": t})
        except (TypeError, ValueError) as exc:
            self._bad(f"controller state: {exc}")
            return
        self.set_sim_time(t)
        self._write(self._channel("/controller/state", schemas.CONTROLLER_STATE), data,
                    self._now_ns(), self._sim_ns)

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

    # ------------------------------------------------------------------ internals
    def _now_ns(self) -> int:
        try:
            return min(max(int(self.clock() * 1e9), 0), _MAX_NS)
        except (TypeError, ValueError, OverflowError):
            return 0

    def _with_time(self, text: str) -> str:
        return f"[t={self._sim_ns * 1e-9:.3f}s] {text}" if self._sim_known else text

    def _bad(self, what: str) -> None:
        self.stats.bad_input += 1
        self.last_bad_input = what

    def _dumps(self, obj: Mapping[str, Any]) -> bytes:
        """Compact JSON of a message; NaN/inf/None are left out (``_nonfinite`` lists them).
        The second pass runs only when the fast one printed NaN/Infinity/null (or such
        text)."""
        s = self._encode(obj)
        if "NaN" in s or "Infinity" in s or "null" in s:
            s = self._encode(_drop_nonfinite(obj))
        return s.encode()

    def _dumps_mav(self, fields: dict[str, Any], chan: _MavChannel) -> bytes:
        """:meth:`_dumps` that remembers per channel whether NaN shows up (ODOMETRY's
        unknown covariances do, every frame), to skip the wasted first pass."""
        if chan.nonfinite:
            clean = _drop_nonfinite(fields)
            chan.nonfinite = schemas.NONFINITE_KEY in clean
            return self._encode(clean).encode()
        s = self._encode(fields)
        if "NaN" in s or "Infinity" in s:
            chan.nonfinite = True
            s = self._encode(_drop_nonfinite(fields))
        return s.encode()

    def _schema_id(self, schema: dict[str, Any]) -> int:
        name = schema["title"]
        sid = self._schema_ids.get(name)
        if sid is None:
            sid = self._schema_ids[name] = self._writer.register_schema(
                name, "jsonschema", schemas.schema_bytes(schema))
        return sid

    def _channel(self, topic: str, schema: dict[str, Any]) -> int:
        """Channel id of ``topic``, registered on first use (0 if the file has failed)."""
        cid = self._channel_ids.get(topic)
        if cid is None:
            try:
                with self._lock:
                    cid = self._channel_ids[topic] = self._writer.register_channel(
                        topic, "json", self._schema_id(schema))
            except Exception as exc:   # registering may finish a chunk, i.e. write
                self._failed(exc)
                return 0
        return cid

    def _raw_channel(self) -> int:
        cid = self._channel_ids.get("/mavlink/raw")
        return cid if cid is not None else self._channel("/mavlink/raw", schemas.RAW_FRAME)

    def _new_mav_channel(self, sysid: int, compid: int, msgid: int) -> _MavChannel | None:
        cls = mav.mavlink_map.get(msgid)
        if cls is None:
            return None
        cid = self._channel(f"/mavlink/{sysid}/{compid}/{cls.msgname}",
                            schemas.mavlink_schema(msgid))
        chan = _MavChannel(cid, cls.msgname, msgid in self._sim_time_ids,
                           msgid == _STATUSTEXT_ID)
        self._mav_channels[(sysid, compid, msgid)] = chan
        return chan

    def _write(self, channel_id: int, data: bytes, log_ns: int, pub_ns: int) -> None:
        if not self._open:
            self.stats.dropped += 1
            return
        try:
            with self._lock:
                self._writer.add_message(channel_id, log_ns, data, pub_ns)
                self._pending += 1
                self.stats.messages += 1
            if time.monotonic() >= self._next_flush:
                self._flush()
        except Exception as exc:
            self._failed(exc)

    def _flush(self) -> None:
        """Finish the chunk in progress (with a fresh copy of the path) and flush the file."""
        with self._lock:
            if not self._open or self._pending == 0:
                return
            if self._path_data is not None:
                self._writer.add_message(self._path_cid, self._now_ns(),
                                         self._path_data, self._sim_ns)
                self.stats.messages += 1
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
