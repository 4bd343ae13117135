"""MCAP recorder: every MAVLink frame, simulator ground truth and the scene, one file.

Channels (docs/design.md, "The flight log"):

* ``/mavlink/raw``: every frame the link saw, both directions, exact wire bytes
  (``tfl_mav.MavlinkFrame``): replayable byte for byte (``tfl-mav replay``).
* ``/mavlink/{sysid}/{compid}/{MSG}``: accepted rx frames and frames this process packed
  and sent, decoded *from their wire bytes* (JSON), at most one a channel every scene
  period of sim time (all before sim time is known; every STATUSTEXT); every frame stays in
  ``/mavlink/raw`` (``logread.mavlink_messages`` decodes them all).
* ``/sim/truth/state`` (every :meth:`Recorder.truth` call: the rigid body, the true rotor
  thrusts and the attack in one message) and ``/sim/truth/path_distance``, ``/tf``,
  ``/scene/vehicle`` (at most ``scene_hz`` in sim time); ``/scene/path`` (on
  :meth:`Recorder.path`, then again with every periodic flush so it survives seeking and
  reaches a viewer who connects late); ``/log`` (:meth:`Recorder.log` and every STATUSTEXT
  seen); ``/controller/state`` (:meth:`Recorder.controller`); ``/plot/...`` (the truth's
  and the controller record's numbers at up to ``scene_hz``, :mod:`plotchan`).

Encodings: truth, controller and raw frames are protobuf (:mod:`~tfl_mav.flightlog.protos`,
float64, NaN kept); decoded MAVLink is JSON with JSON Schemas generated from pymavlink's
definitions (:mod:`~tfl_mav.flightlog.schemas`); ``/tf``, the scene and ``/log`` are
Foxglove's well-known types (:mod:`~tfl_mav.flightlog.foxglove`); ``/plot/...`` ROS 2
``Float64MultiArray``. All written through Foxglove's SDK (:mod:`mcapout`).

What to draw is the caller's: ``rotor_xy_m`` (where the rotors sit in the body frame),
``thrust_max_n`` (the thrust scale), the path polyline (:meth:`Recorder.path`), and the
field names and schema of the controller's per-tick record (``controller_fields``,
``controller_schema``). The recorder knows no control law.

Live view: ``live=(host, port)`` (or a :class:`~tfl_mav.flightlog.live.LiveAddress`, whose
``estimate`` draws the vehicle from the controller's own state on the controller side) also
serves every channel on a Foxglove WebSocket (:mod:`~tfl_mav.flightlog.live`); ``path=None``
serves without a file.

Time: ``log_time`` is the receipt time on the recorder's ``clock`` (ns; frames use the
``time_s`` the link hook passes, so give the link the same clock: :meth:`Recorder.attach`
does); with ``timeline="sim"`` (lockstep), from the first message whose sim time is known
on, it is the receipt time of that message (the flight's wall-clock start) + sim time, so
a viewer shows the flight at its own pace, not the machine's; the ``timeline`` metadata
(written at close) keeps the wall clock: flight start, wall time, real-time factor. Sim
time is the latest of :meth:`set_sim_time`, the ``time_s`` given to
``truth``/``controller``/``log``, and ``time_usec`` of the messages in
``sim_time_messages`` (ODOMETRY and HIL_ACTUATOR_CONTROLS carry sim time), taken when they
pass, so a received state is on the timeline at its own time even before the caller reacts.

Crash safety: chunked, zstd (or lz4) compressed; the chunk in progress is finished and the
file flushed to the OS at least every ``flush_interval_s``: inline when messages keep
coming, from a small background thread when they stop. A SIGKILLed process loses at most
the last interval; everything before reads with a stream reader (``tfl-mav inspect
--recover``). A program that ends without :meth:`Recorder.close` (an uncaught exception)
still finishes the file, at exit. No fsync: an OS crash or power loss can lose more.
:class:`~tfl_mav.flightlog.recorder_process.RecorderProcess` runs the same recorder in a
child process, which also finishes the file when the flight process is killed.

Failure policy: an unwritable path (or a live port in use) raises :class:`RecorderError`
(an ``OSError``) at construction. After that nothing raises into the flight loop: a write
error (disk full) stops the recording, is counted (``stats.write_errors``) and described in
:attr:`Recorder.error`; later messages are counted as ``dropped``. Bad arguments to the
loop methods (wrong length, not a number, unknown direction) are counted
(``stats.bad_input``) and described in :attr:`Recorder.last_bad_input`.
"""

from __future__ import annotations

import math
import struct
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

from tfl_mav.flightlog import foxglove as fg
from tfl_mav.flightlog import plotchan, protos, schemas
from tfl_mav.flightlog.framerec import FrameRecorder
from tfl_mav.flightlog.mcapout import CHUNK_BYTES, MAX_NS, RecorderError, RecorderStats
from tfl_mav.flightlog.polyline import Polyline

__all__ = ["Recorder", "RecorderError", "RecorderStats"]

_MAX_PATH_POINTS = 2000
# The mean thrust axis's averaging time (s): a spinning vehicle (30-65 rad/s, a revolution
# every 0.1-0.2 s) sweeps its thrust round a cone; a first-order filter over 0.3 s leaves
# 1/√(1 + (Ω τ)²) of the cone's turning part (7 % at 50 rad/s: a 50° cone's mean drawn
# within ~5° of its axis) and follows the mean axis's own steering (~1 rad/s) with a lag of
# 0.3 s: what a person watching can follow.
MEAN_THRUST_TAU_S = 0.3
MEAN_THRUST_EVERY = 5       # drawn on every 5th scene (10 Hz at the default 50 Hz)
_DEFAULT_RECORD = schemas.record_schema("tfl_mav.Record", "a caller's record", {}, [])
_PACK = {n: struct.Struct(f"<{n}d").pack for n in (1, 3, 4)}


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


def _numbers(value: Any) -> list[float]:
    """The numbers in ``value`` (a number, bool, numpy value or nested sequence), flattened
    in order; [] for text or anything else."""
    t = type(value)
    if t is float or t is int or t is bool:
        return [float(value)]
    if t is str or value is None:
        return []
    if (t is tuple or t is list) and all(type(v) is float for v in value):
        return list(value)
    if isinstance(value, (bool, int, float)):      # numpy scalars and other numbers
        return [float(value)]
    if hasattr(value, "tolist"):
        value = value.tolist()
    if isinstance(value, (list, tuple)):
        out: list[float] = []
        for v in value:
            part = _numbers(v)
            if not part and not isinstance(v, (list, tuple)):
                return []               # mixed with text: not a plot
            out += part
        return out
    return []


class Recorder(FrameRecorder):
    """Writes one MCAP file; see the module docstring. Use as a context manager."""

    def __init__(self, path: str | Path | None, *, clock: Callable[[], float] = time.time,
                 flush_interval_s: float = 1.0, profile: str = "tfl-mav",
                 compression: str = "zstd", chunk_size_bytes: int = CHUNK_BYTES,
                 scene_hz: float = 50.0, rotor_xy_m: Sequence[Sequence[float]] = (),
                 thrust_max_n: float = 1.0, controller_fields: Sequence[str] = (),
                 controller_schema: Mapping[str, Any] | None = None,
                 sim_time_messages: Iterable[str] = ("ODOMETRY", "HIL_ACTUATOR_CONTROLS"),
                 live: tuple[str, int] | None = None, timeline: str = "wall") -> None:
        """Open ``path`` for writing (None: no file) and start the file.

        ``clock``: seconds, the receipt clock of ``log_time``. ``scene_hz``: max rate (sim
        time) of ``/tf``, ``/scene/vehicle``, ``/sim/truth/path_distance``, the plot
        channels and the decoded MAVLink channels. ``rotor_xy_m``: rotor positions (x, y)
        in the body frame (m), rotors 1..n, and ``thrust_max_n`` the thrust that draws a
        full-length arrow: drawing only (no rotors: no ``/scene/vehicle``).
        ``controller_fields``: the names of the values of a sequence given to
        :meth:`controller`; ``controller_schema``: that record's description
        (:func:`~tfl_mav.flightlog.schemas.record_schema`; its protobuf schema is made
        from it, :class:`~tfl_mav.flightlog.protos.RecordEncoder`). ``live``: also serve
        everything on a Foxglove WebSocket at (host, port). ``timeline``: "wall"
        (log_time = receipt time) or "sim" (lockstep: from sim time 0 on, log_time = the
        wall clock at sim time 0 + sim time; see the module docstring).
        Raises ValueError for a bad setting, :class:`RecorderError` if the file cannot be
        written or the live port cannot be bound.
        """
        if not (math.isfinite(scene_hz) and scene_hz > 0.0):
            raise ValueError(f"scene_hz: must be > 0, got {scene_hz}")
        rotors = [(float(x), float(y)) for x, y in rotor_xy_m]
        if not all(math.isfinite(x) and math.isfinite(y) for x, y in rotors) or (
                rotors and max(math.hypot(x, y) for x, y in rotors) <= 0.0):
            raise ValueError(f"rotor_xy_m: expected finite (x, y) pairs, got {rotor_xy_m!r}")
        if not thrust_max_n > 0.0:
            raise ValueError(f"thrust_max_n: must be > 0, got {thrust_max_n}")
        self._scene_period_s = 1.0 / scene_hz
        self._rotor_xy_m = rotors
        self._thrust_max_n = thrust_max_n
        self._controller_fields = tuple(controller_fields)
        self._ctl_schema = dict(controller_schema or _DEFAULT_RECORD)
        self._ctl = protos.RecordEncoder(self._ctl_schema, self._controller_fields)
        self._ctl_emit: Any = None
        self._init_frames(sim_time_messages, self._scene_period_s)
        self._last_scene_t = -math.inf
        # The thrust averaged over the last revolutions (N, world) and the sim time of its
        # last sample: the mean thrust axis the scene draws (a first-order filter of
        # f_Σ R e3 with MEAN_THRUST_TAU_S, sampled at the scene rate: 50 Hz is above twice
        # the fastest spin's 10 Hz, so the samples see the cone without aliasing it).
        self._mean_thrust_n: tuple[float, float, float] | None = None
        self._mean_thrust_t = -math.inf
        self._mean_thrust_count = -1       # scenes drawn (the first one draws the mean)
        self._truth_emit: Any = None
        self._wind_emit: Any = None
        self._polyline: Polyline | None = None
        # topic → (log, message head (plotchan.labels), number of values)
        self._plots: dict[str, tuple[Any, bytes, int]] = {}
        self._next_ctl_plot_s = -math.inf
        super().__init__(path, clock=clock, flush_interval_s=flush_interval_s, profile=profile,
                         compression=compression, chunk_size_bytes=chunk_size_bytes, live=live,
                         timeline=timeline)

    def attach(self, link: Any) -> None:
        """Hook this recorder into a :class:`~tfl_mav.link.transport.Link` and give the link
        the recorder's clock, so every ``log_time`` in the file is on one clock."""
        link.on_frame = self.on_frame
        link.clock = self.clock

    @property
    def sim_time_s(self) -> float:
        return self._sim_ns * 1e-9

    def set_sim_time(self, time_s: float) -> None:
        """Sim time (s) of what is recorded next."""
        try:
            ns = round(time_s * 1e9)
        except (TypeError, ValueError, OverflowError):
            self._bad(f"time_s: expected a finite number, got {time_s!r}")
            return
        if 0 <= ns <= MAX_NS:
            self._sim_ns = ns
            self._sim_known = True
        else:
            self._bad(f"time_s: out of range ({time_s})")

    def _proto_channel(self, topic: str, name: str) -> Any:
        return self._channels.get(topic) or self._channel(topic, *protos.schema(name),
                                                          "protobuf")

    # ------------------------------------------------------------------ ground truth, scene
    def truth(self, time_s: float, position_m: Sequence[float], velocity_mps: Sequence[float],
              quaternion_wxyz: Sequence[float], body_rates_radps: Sequence[float],
              rotor_thrust_n: Sequence[float], attack_rotor: int, attack_applied_n: float,
              attack_requested_n: float, wind_mps: Sequence[float] | None = None) -> None:
        """Simulator ground truth at sim time ``time_s`` (s), world frame ENU (z up):
        position (m), velocity (m/s), attitude quaternion body → world (w, x, y, z), body
        rates (rad/s), true rotor thrusts 1-4 (N), attacked rotor (1-4, 0 = none), applied
        and requested attack thrust (N); ``wind_mps``: the air's velocity (m/s, world
        frame), written to ``/sim/truth/wind`` when given (a flight in moving air). Also
        drives ``/tf``, ``/scene/vehicle`` and ``/sim/truth/path_distance`` at up to
        ``scene_hz``."""
        try:                 # the usual call: plain lists of the right lengths
            v = tuple(map(float, (time_s, *position_m, *velocity_mps, *quaternion_wxyz,
                                  *body_rates_radps, *rotor_thrust_n)))
            fast = (len(v) == 18 and len(position_m) == 3 and len(velocity_mps) == 3
                    and len(quaternion_wxyz) == 4 and len(body_rates_radps) == 3
                    and type(attack_rotor) is int
                    and 0 <= attack_rotor <= 4 and math.isfinite(v[0]))
        except (TypeError, ValueError):
            fast = False
        if fast:
            t, pos, vel, quat, rates, thrust = v[0], v[1:4], v[4:7], v[7:11], v[11:14], v[14:]
            rotor = attack_rotor
            try:
                applied, requested = float(attack_applied_n), float(attack_requested_n)
            except (TypeError, ValueError):
                fast = False
        if not fast:
            self._truth_checked(time_s, position_m, velocity_mps, quaternion_wxyz,
                                body_rates_radps, rotor_thrust_n, attack_rotor,
                                attack_applied_n, attack_requested_n)
        else:
            self._truth(t, pos, vel, quat, rates, thrust, rotor, applied, requested)
        if wind_mps is not None:
            self._wind(time_s, wind_mps)

    def _wind(self, time_s: Any, wind_mps: Any) -> None:
        """``/sim/truth/wind`` (``tfl_mav.TruthWind``), checked: bad input is counted."""
        try:
            t = float(time_s)
            w = _floats(wind_mps, 3, "wind_mps")
            if not math.isfinite(t):
                raise ValueError(f"time_s: not finite ({time_s})")
        except (TypeError, ValueError) as exc:
            self._bad(f"truth: {exc}")
            return
        emit = self._wind_emit
        if emit is None:
            emit = self._wind_emit = self._proto_channel("/sim/truth/wind", protos.TRUTH_WIND)
        self._write(emit, protos.truth_wind(t, w), self._now_ns())

    def _truth_checked(self, time_s: Any, position_m: Any, velocity_mps: Any,
                       quaternion_wxyz: Any, body_rates_radps: Any, rotor_thrust_n: Any,
                       attack_rotor: Any, attack_applied_n: Any,
                       attack_requested_n: Any) -> None:
        """:meth:`truth` of anything: checked, and what is wrong counted (bad input)."""
        try:
            t = float(time_s)
            if not math.isfinite(t):
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
        self._truth(t, pos, vel, quat, rates, thrust, rotor, applied, requested)

    def _truth(self, t: float, pos: Sequence[float], vel: Sequence[float],
               quat: Sequence[float], rates: Sequence[float], thrust: Sequence[float],
               rotor: int, applied: float, requested: float) -> None:
        self.set_sim_time(t)
        log_ns = self._now_ns()
        emit = self._truth_emit
        if emit is None:
            emit = self._truth_emit = self._proto_channel("/sim/truth/state",
                                                          protos.TRUTH_STATE)
        self._write(emit, protos.truth_state(t, pos, vel, quat, rates, thrust, rotor, applied,
                                             requested), log_ns)
        self._scene(t, log_ns, pos, quat, thrust, rotor, applied)

    def _mean_thrust_due(self, pos: Sequence[float]
                         ) -> tuple[Sequence[float], Sequence[float]] | None:
        """(position, mean thrust) on every MEAN_THRUST_EVERY-th scene, else None: the mean
        moves on the scale of τ, and a scene entity stays drawn until replaced, so drawing
        it at a fifth of the scene rate costs the recorder a fifth (~13 µs a drawing)."""
        self._mean_thrust_count += 1
        if self._mean_thrust_n is None or self._mean_thrust_count % MEAN_THRUST_EVERY:
            return None
        return pos, self._mean_thrust_n

    def _average_thrust(self, t: float, quat: Sequence[float], thrust: Sequence[float]) -> None:
        """One sample of the mean thrust: F̄ += (1 − e^{−Δt/τ}) (f_Σ R e3 − F̄)."""
        w, x, y, z = quat
        n2 = w * w + x * x + y * y + z * z
        if not (n2 > 0.0 and math.isfinite(n2)):
            return
        total = float(sum(thrust)) / n2        # R e3 of the unnormalised quaternion / |q|²
        f = (2.0 * (x * z + w * y) * total, 2.0 * (y * z - w * x) * total,
             (w * w - x * x - y * y + z * z) * total)
        if not all(map(math.isfinite, f)):
            return
        last, self._mean_thrust_t = self._mean_thrust_t, t
        mean = self._mean_thrust_n
        if mean is None or not t > last:
            if mean is None:
                self._mean_thrust_n = f
            return
        a = 1.0 - math.exp(-(t - last) / MEAN_THRUST_TAU_S)
        self._mean_thrust_n = (mean[0] + a * (f[0] - mean[0]), mean[1] + a * (f[1] - mean[1]),
                               mean[2] + a * (f[2] - mean[2]))

    def _scene(self, t: float, log_ns: int, pos: Sequence[float], quat: Sequence[float],
               thrust: Sequence[float], rotor: int, attack_n: float) -> None:
        """``/tf``, ``/scene/vehicle``, ``/sim/truth/path_distance`` and the truth's plot
        channels (:mod:`~tfl_mav.flightlog.plotchan`) at up to scene_hz."""
        # 1 µs slack so k·dt rounding does not push a sample to the next tick
        if self._last_scene_t <= t < self._last_scene_t + self._scene_period_s - 1e-6:
            return
        self._last_scene_t = t
        if not all(map(math.isfinite, (*pos, *quat, *thrust))):
            self._bad(f"truth: position/attitude/thrust not finite at t = {t} s; "
                      "scene not drawn")
            return
        items = [(self._fg_channel("/tf", "foxglove.FrameTransform"),
                  fg.frame_transform(log_ns, pos, quat))]
        self._average_thrust(t, quat, thrust)
        if self._rotor_xy_m:
            items.append((self._fg_channel("/scene/vehicle", "foxglove.SceneUpdate"),
                          fg.vehicle_scene(log_ns, self._rotor_xy_m, thrust,
                                           self._thrust_max_n, rotor,
                                           mean_thrust=self._mean_thrust_due(pos))))
        plots = [("/plot/truth/position_m", ("x_m", "y_m", "z_m"), pos),
                 ("/plot/truth/rotor_thrust_n", ("f1_n", "f2_n", "f3_n", "f4_n"), thrust),
                 ("/plot/truth/attack_n", ("applied_n",), (attack_n,))]
        if self._polyline is not None:
            distance = self._polyline.distance(pos)
            items.append((self._proto_channel("/sim/truth/path_distance",
                                              protos.PATH_DISTANCE),
                          protos.path_distance(t, distance)))
            plots.append(("/plot/truth/path_distance_m", ("distance_m",), (distance,)))
        for topic, names, values in plots:
            entry = self._plot_entry(topic, names)
            items.append((entry[0], entry[1] + _PACK[len(values)](*values)))
        self._write_many(tuple(items), log_ns)

    def _plot_entry(self, topic: str, names: Sequence[str]) -> tuple[Any, bytes, int]:
        """(log, message head, number of values) of a plot channel labelled ``names``."""
        entry = self._plots.get(topic)
        if entry is None or entry[2] != len(names):
            emit = entry[0] if entry is not None else self._channel(
                topic, plotchan.FLOAT64_MULTI_ARRAY, plotchan.SCHEMA_ENCODING,
                plotchan.SCHEMA_TEXT, plotchan.MESSAGE_ENCODING)
            entry = self._plots[topic] = (emit, plotchan.labels(names), len(names))
        return entry

    def _controller_plots(self, t: float, log_ns: int,
                          fields: Iterable[tuple[str, Any]]) -> None:
        """The controller record's numbers as plot channels, at up to scene_hz of sim time:
        ``/plot/controller/NAME`` per numeric field (a number, a flag as 0/1, or numbers
        nested in lists, flattened in order); text fields are the record's only."""
        self._next_ctl_plot_s = t + self._scene_period_s - 1e-6
        items = []
        for name, value in fields:
            flat = _numbers(value)
            if not flat:
                continue
            entry = self._plots.get(f"/plot/controller/{name}")
            if entry is None or entry[2] != len(flat):
                entry = self._plot_entry(f"/plot/controller/{name}", [name] if len(flat) == 1
                                         else [f"{name}[{i}]" for i in range(len(flat))])
            items.append((entry[0], plotchan.encode(entry[1], flat)))
        if items:
            self._write_many(tuple(items), log_ns)

    def path(self, points_m: Any) -> None:
        """The path as sampled points (N, 3) in m, world frame ENU: ``/scene/path`` now and with
        every periodic flush after. More than 2000 points are thinned evenly. Raises
        ValueError naming ``points_m`` if the array is not (N ≥ 2, 3) and finite (a setup
        call, not a loop call)."""
        poly = Polyline(points_m)
        pts = poly.points_m
        if len(pts) > _MAX_PATH_POINTS:
            step = math.ceil(len(pts) / _MAX_PATH_POINTS)
            pts = pts[::step] if (len(pts) - 1) % step == 0 else [*pts[::step], pts[-1]]
        log_ns = self._now_ns()
        data = fg.path_scene(log_ns, [list(map(float, p)) for p in pts])
        self._polyline = poly
        self.latch(self._fg_channel("/scene/path", "foxglove.SceneUpdate"), data, log_ns)

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
        self._write(self._fg_channel("/log", "foxglove.Log"),
                    fg.log_entry(log_ns, lvl, self._with_time(str(text)), source), log_ns)

    def controller(self, time_s: float, state: Mapping[str, Any] | Sequence[Any]) -> None:
        """The controller's record at sim time ``time_s`` (s) on ``/controller/state``
        (protobuf, :class:`~tfl_mav.flightlog.protos.RecordEncoder`): a sequence of values
        named by ``controller_fields`` (the compact per-tick form), or a mapping (a key the
        schema does not know extends it). numpy values are fine; None is left out."""
        try:
            t = float(time_s)
            if not math.isfinite(t):
                raise ValueError(f"time_s: not finite ({time_s})")
            if type(state) is tuple and len(state) == len(self._controller_fields):
                data = self._ctl.encode(t, state)           # the per-tick record
                fields: Iterable[tuple[str, Any]] = zip(self._controller_fields, state,
                                                        strict=True)
            elif isinstance(state, Mapping):
                state = {k: v for k, v in state.items() if k != "t_s"}
                if not state.keys() <= set(self._ctl.names):
                    self._extend_record(state)
                data = self._ctl.encode_map({**state, "t_s": t})
                fields = state.items()
            else:
                if len(state) != len(self._controller_fields):
                    raise ValueError(f"record: expected {len(self._controller_fields)} values "
                                     f"({', '.join(self._controller_fields)}), got "
                                     f"{len(state)}")
                data = self._ctl.encode(t, state)
                fields = zip(self._controller_fields, state, strict=True)
        except (TypeError, ValueError) as exc:
            self._bad(f"controller state: {exc}")
            return
        self.set_sim_time(t)
        log_ns = self._now_ns()
        emit = self._ctl_emit
        if emit is None:
            emit = self._ctl_emit = self._channel("/controller/state", self._ctl.name,
                                                  "protobuf", self._ctl.schema_data,
                                                  "protobuf")
        self._write(emit, data, log_ns)
        if t >= self._next_ctl_plot_s:
            self._controller_plots(t, log_ns, fields)

    def _extend_record(self, state: Mapping[str, Any]) -> None:
        """A mapping record with keys the schema does not know: the record's schema grows
        by them (kinds from their values) and the channel is made again with it."""
        kinds = {n: k for n, k, _ in self._ctl.fields}
        kinds.update({k: protos.kind_of(v) for k, v in state.items()
                      if k not in kinds and v is not None})
        self._ctl = protos.RecordEncoder(self._ctl_schema, self._controller_fields, kinds)
        self._channels.pop("/controller/state", None)
        self._ctl_emit = None
