"""MCAP recorder: every MAVLink frame, simulator ground truth and the scene, one file.

Channels (docs/design.md, "The flight log"):

* ``/mavlink/raw``: every frame the link saw, both directions, exact wire bytes (base64),
  with ``direction`` and ``accepted``: replayable byte for byte (``tfl-mav replay``).
* ``/mavlink/{sysid}/{compid}/{MSG}``: accepted rx frames and frames this process packed
  and sent, decoded *from their wire bytes* (float32 rounding and all), at most one a
  channel every scene period of sim time (all before sim time is known; every STATUSTEXT);
  every frame stays in ``/mavlink/raw`` (``logread.mavlink_messages`` decodes them all).
* ``/sim/truth/state``, ``/sim/truth/attack``, ``/sim/truth/thrusts`` (every
  :meth:`Recorder.truth` call) and ``/sim/truth/path_distance``, ``/tf``,
  ``/scene/vehicle`` (at most ``scene_hz`` in sim time); ``/scene/path`` (on
  :meth:`Recorder.path`, then again with every periodic flush so it survives seeking and
  reaches a viewer who connects late); ``/log`` (:meth:`Recorder.log` and every STATUSTEXT
  seen); ``/controller/state`` (:meth:`Recorder.controller`).

Encodings: MAVLink, truth and controller channels are JSON with JSON Schemas
(:mod:`~tfl_mav.flightlog.schemas`, MAVLink ones generated from pymavlink's definitions);
``/tf``, the scene and ``/log`` are Foxglove's well-known types as protobuf, built with
Foxglove's SDK (:mod:`~tfl_mav.flightlog.foxglove`).

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
(written at close) keeps the wall clock: flight start, wall time, real-time factor.
``publish_time`` is **sim time** (ns): the latest of :meth:`set_sim_time`, the
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

Failure policy: an unwritable path (or a live port in use) raises :class:`RecorderError`
(an ``OSError``) at construction. After that nothing raises into the flight loop: a write
error (disk full) stops the recording, is counted (``stats.write_errors``) and described in
:attr:`Recorder.error`; later messages are counted as ``dropped``. Bad arguments to the
loop methods (wrong length, not a number, unknown direction) are counted
(``stats.bad_input``) and described in :attr:`Recorder.last_bad_input`. NaN/inf (and None)
are never written to a JSON channel: such values are left out and listed in
``_nonfinite`` (:mod:`~tfl_mav.flightlog.jsonenc`).
"""

from __future__ import annotations

import math
import struct
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

from tfl_mav.flightlog import foxglove as fg
from tfl_mav.flightlog import plotchan, schemas
from tfl_mav.flightlog.framerec import FrameRecorder
from tfl_mav.flightlog.jsonenc import RecordFormat, _numbers_json
from tfl_mav.flightlog.jsonobj import encode as _encode_obj
from tfl_mav.flightlog.mcapout import MAX_NS, RecorderError, RecorderStats
from tfl_mav.flightlog.polyline import Polyline
from tfl_mav.flightlog.recordplan import record_plan

__all__ = ["Recorder", "RecorderError", "RecorderStats"]

_MAX_NS = MAX_NS
_MAX_PATH_POINTS = 2000
_MAX_RECORD_PLANS = 4             # controller record shapes precompiled (then: the dict path)


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


_PACK1, _PACK3, _PACK4 = (struct.Struct(f"<{n}d").pack for n in (1, 3, 4))


def _pack_floats(values: Sequence[float]) -> bytes:
    return plotchan.encode(b"", values)


def _numbers(value: Any) -> list[float]:
    """The numbers in ``value`` (a number, bool, numpy value or nested sequence), flattened
    in order; [] for text or anything else."""
    t = type(value)
    if t is float or t is int or t is bool:
        return [float(value)]
    if t is str or value is None:
        return []
    if t is tuple or t is list:
        if all(type(v) is float for v in value):     # the usual record: floats, flat
            return list(value)
    elif isinstance(value, (bool, int, float)):      # numpy scalars and other numbers
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


_TRUTH_STATE = RecordFormat([("t_s", 0), ("position_m", 3), ("velocity_mps", 3),
                             ("quaternion_wxyz", 4), ("body_rates_radps", 3)])
_TRUTH_ATTACK = {active: RecordFormat([("t_s", 0), ("rotor", 0), ("active", active),
                                        ("applied_n", 0), ("requested_n", 0)])
                 for active in ("true", "false")}
_TRUTH_THRUSTS = RecordFormat([("t_s", 0), ("thrust_n", 4), ("attack_rotor", 0)])
_DEFAULT_RECORD = schemas.record_schema("tfl_mav.Record", "a caller's record", {}, [])


class Recorder(FrameRecorder):
    """Writes one MCAP file; see the module docstring. Use as a context manager."""

    def __init__(self, path: str | Path | None, *, clock: Callable[[], float] = time.time,
                 flush_interval_s: float = 1.0, profile: str = "tfl-mav",
                 compression: str = "zstd", chunk_size_bytes: int = 1 << 20,
                 scene_hz: float = 50.0, rotor_xy_m: Sequence[Sequence[float]] = (),
                 thrust_max_n: float = 1.0, controller_fields: Sequence[str] = (),
                 controller_schema: Mapping[str, Any] | None = None,
                 sim_time_messages: Iterable[str] = ("ODOMETRY", "HIL_ACTUATOR_CONTROLS"),
                 live: tuple[str, int] | None = None, timeline: str = "wall") -> None:
        """Open ``path`` for writing (None: no file) and start the file.

        ``clock``: seconds, the receipt clock of ``log_time``. ``scene_hz``: max rate (sim
        time) of ``/tf``, ``/scene/vehicle`` and ``/sim/truth/path_distance``.
        ``rotor_xy_m``: rotor positions (x, y) in the body frame (m), rotors 1..n, and
        ``thrust_max_n`` the thrust that draws a full-length arrow: drawing only (no
        rotors: no ``/scene/vehicle``). ``controller_fields``: the names of the values of
        a sequence given to :meth:`controller`; ``controller_schema``: the JSON Schema of
        that record (:func:`~tfl_mav.flightlog.schemas.record_schema`). ``live``: also
        serve everything on a Foxglove WebSocket at (host, port). ``timeline``: "wall"
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
        self._controller_schema = dict(controller_schema or _DEFAULT_RECORD)
        self._init_frames(sim_time_messages, self._scene_period_s)
        self._dumps = self._json.dumps
        self._last_scene_t = -math.inf
        self._truth_cids: tuple[int, int, int] | None = None
        self._truth_c: Any = None          # frames_c ``records`` (when built)
        self._truth_layouts: dict[bool, Any] = {}
        # record plans of the shapes seen (recordplan), [plan, checked]; by shape
        self._ctl_plans: list[list[Any]] = []
        self._ctl_shapes: dict[tuple[Any, ...], Any] = {}
        self._ctl_cid = 0
        self._polyline: Polyline | None = None
        # topic → channel id, message head (plotchan.labels), number of values
        self._plots: dict[str, tuple[int, bytes, int]] = {}
        self._next_ctl_plot_s = -math.inf
        self._truth_plots: tuple[tuple[int, bytes], ...] | None = None
        self._ctl_plot_plan: list[tuple[int, int, bytes, Any, bool]] | None = None
        super().__init__(path, clock=clock, flush_interval_s=flush_interval_s, profile=profile,
                         compression=compression, chunk_size_bytes=chunk_size_bytes, live=live,
                         timeline=timeline)

    def attach(self, link: Any) -> None:
        """Hook this recorder into a :class:`~tfl_mav.link.transport.Link` and give the link
        the recorder's clock, so every ``log_time`` in the file is on one clock."""
        link.on_frame = self.on_frame
        link.clock = self.clock

    def _pub_ns(self) -> int:
        return self._sim_ns

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

    # ------------------------------------------------------------------ ground truth, scene
    def truth(self, time_s: float, position_m: Sequence[float], velocity_mps: Sequence[float],
              quaternion_wxyz: Sequence[float], body_rates_radps: Sequence[float],
              rotor_thrust_n: Sequence[float], attack_rotor: int, attack_applied_n: float,
              attack_requested_n: float) -> None:
        """Simulator ground truth at sim time ``time_s`` (s), world frame ENU (z up):
        position (m), velocity (m/s), attitude quaternion body → world (w, x, y, z), body
        rates (rad/s), true rotor thrusts 1-4 (N), attacked rotor (1-4, 0 = none), applied
        and requested attack thrust (N). Also drives ``/tf``, ``/scene/vehicle`` and
        ``/sim/truth/path_distance`` at up to ``scene_hz``."""
        try:                 # the hot path: plain values, all finite, channels known
            fast = (self._truth_cids is not None and len(position_m) == 3
                    and len(velocity_mps) == 3 and len(quaternion_wxyz) == 4
                    and len(body_rates_radps) == 3 and len(rotor_thrust_n) == 4
                    and type(attack_rotor) is int and 0 <= attack_rotor <= 4)
            if fast:
                vals = tuple(map(float, (time_s, *position_m, *velocity_mps, *quaternion_wxyz,
                                         *body_rates_radps, attack_applied_n,
                                         attack_requested_n, *rotor_thrust_n)))
        except (TypeError, ValueError):
            fast = False
        log_ns = None
        if (fast and self._truth_c is not None and self._live is None and self._open
                and math.isfinite(sum(vals))):     # NaN/inf: left out by the Python path
            self.set_sim_time(vals[0])     # the C path: three records in one call
            log_ns = self._now_ns()
            if self._truth_records(log_ns, (*vals, attack_rotor), attack_rotor != 0):
                self._scene(vals[0], log_ns, vals[1:4], vals[7:11], vals[16:20],
                            attack_rotor, vals[14])
                return
        parts = _numbers_json((*vals, attack_rotor)) if fast else None
        if parts is not None:
            self.set_sim_time(vals[0])
            log_ns = self._now_ns() if log_ns is None else log_ns
            state_cid, attack_cid, thrusts_cid = self._truth_cids
            self._write_many((
                (state_cid, _TRUTH_STATE.bfmt % tuple(parts[:14])),
                (attack_cid, _TRUTH_ATTACK["true" if attack_rotor else "false"].bfmt
                 % (parts[0], parts[20], parts[14], parts[15])),
                (thrusts_cid, _TRUTH_THRUSTS.bfmt % (parts[0], *parts[16:20], parts[20]))),
                log_ns, self._sim_ns)
            self._scene(vals[0], log_ns, vals[1:4], vals[7:11], vals[16:20], attack_rotor,
                        vals[14])
            return
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
        log_ns, pub_ns = self._now_ns() if log_ns is None else log_ns, self._sim_ns
        t = float(time_s)
        # precompiled JSON (byte-identical); the dict encoder for NaN/inf (left out)
        self._write(self._channel("/sim/truth/state", schemas.TRUTH_STATE),
                    _TRUTH_STATE.encode((t, *pos, *vel, *quat, *rates))
                    or self._dumps({"t_s": t, "position_m": pos, "velocity_mps": vel,
                                    "quaternion_wxyz": quat, "body_rates_radps": rates}),
                    log_ns, pub_ns)
        self._write(self._channel("/sim/truth/attack", schemas.TRUTH_ATTACK),
                    _TRUTH_ATTACK["true" if rotor != 0 else "false"].encode(
                        (t, rotor, applied, requested))
                    or self._dumps({"t_s": t, "rotor": rotor, "active": rotor != 0,
                                    "applied_n": applied, "requested_n": requested}),
                    log_ns, pub_ns)
        self._write(self._channel("/sim/truth/thrusts", schemas.TRUTH_THRUSTS),
                    _TRUTH_THRUSTS.encode((t, *thrust, rotor))
                    or self._dumps({"t_s": t, "thrust_n": thrust, "attack_rotor": rotor}),
                    log_ns, pub_ns)
        self._truth_cids = (self._channel_ids.get("/sim/truth/state", 0),
                            self._channel_ids.get("/sim/truth/attack", 0),
                            self._channel_ids.get("/sim/truth/thrusts", 0))
        self._setup_truth_c()
        self._scene(t, log_ns, pos, quat, thrust, rotor, applied)

    def _c_ready(self, fn: Any) -> None:
        super()._c_ready(fn)
        self._setup_truth_c()

    def _setup_truth_c(self) -> None:
        """The truth records' C path, once the channels and the compiled module exist."""
        records = getattr(getattr(self._frames_c, "__self__", None), "records", None)
        if (records is not None and getattr(self, "_truth_cids", None) is not None
                and getattr(self._writer, "_fast", False)):
            # the hot path's values: t, position, velocity, quaternion, rates, applied,
            # requested, thrusts 1-4, rotor (indices 0, 1-3, 4-6, 7-10, 11-13, 14, 15,
            # 16-19, 20)
            state_cid, attack_cid, thrusts_cid = self._truth_cids
            self._truth_layouts = {active: (
                (state_cid, _TRUTH_STATE.pieces, tuple(range(14))),
                (attack_cid, _TRUTH_ATTACK["true" if active else "false"].pieces,
                 (0, 20, 14, 15)),
                (thrusts_cid, _TRUTH_THRUSTS.pieces, (0, 16, 17, 18, 19, 20)))
                for active in (False, True)}
            self._truth_c = records

    def _truth_records(self, log_ns: int, values: tuple[Any, ...], active: bool) -> bool:
        """The three truth records by the C path; False (nothing written) for values it
        does not print (NaN/inf: the Python path leaves them out)."""
        w = self._writer
        try:
            with self._lock:
                n = self._truth_c(w.chunk, w.end_chunk, w.chunk_limit, log_ns, self._sim_ns,
                                  values, self._truth_layouts[active], _encode_obj)
                if n is None:
                    return False
                self._pending += n
                self.stats.messages += n
            if time.monotonic() >= self._next_flush:
                self._flush()
        except Exception as exc:
            self._failed(exc)
        return True

    def _scene(self, t: float, log_ns: int, pos: Sequence[float], quat: Sequence[float],
               thrust: Sequence[float], rotor: int, attack_n: float) -> None:
        """``/tf``, ``/scene/vehicle``, ``/sim/truth/path_distance`` and the truth's plot
        channels (:mod:`~tfl_mav.flightlog.plotchan`) at up to scene_hz."""
        pub_ns = self._sim_ns
        # 1 µs slack so k·dt rounding does not push a sample to the next tick
        if self._last_scene_t <= t < self._last_scene_t + self._scene_period_s - 1e-6:
            return
        self._last_scene_t = t
        if not all(map(math.isfinite, (*pos, *quat, *thrust))):
            self._bad(f"truth: position/attitude/thrust not finite at t = {t} s; "
                      "scene not drawn")
            return
        self._write(self._fg_channel("/tf", "foxglove.FrameTransform"),
                    fg.frame_transform(log_ns, pos, quat), log_ns, pub_ns)
        if self._rotor_xy_m:
            self._write(self._fg_channel("/scene/vehicle", "foxglove.SceneUpdate"),
                        fg.vehicle_scene(log_ns, self._rotor_xy_m, thrust, self._thrust_max_n,
                                         rotor), log_ns, pub_ns)
        distance = None
        if self._polyline is not None:
            distance = self._polyline.distance(pos)
            self._write(self._channel("/sim/truth/path_distance", schemas.PATH_DISTANCE),
                        self._dumps({"t_s": t, "distance_m": distance}), log_ns, pub_ns)
        heads = self._truth_plots
        if heads is None or (distance is None) != (len(heads) == 3):
            heads = self._truth_plots = self._truth_plot_heads(distance is not None)
        (c1, h1), (c2, h2), (c3, h3) = heads[:3]
        x, y, z = pos
        f1, f2, f3, f4 = thrust
        items = ((c1, h1 + _PACK3(x, y, z)), (c2, h2 + _PACK4(f1, f2, f3, f4)),
                 (c3, h3 + _PACK1(attack_n)))
        if distance is not None:
            c4, h4 = heads[3]
            items += ((c4, h4 + _PACK1(distance)),)
        self._write_many(items, log_ns, pub_ns)

    def _truth_plot_heads(self, distance: bool) -> tuple[tuple[int, bytes], ...]:
        """(channel id, message head) of the truth's plot channels, registered now."""
        out = []
        for topic, names in (("/plot/truth/position_m", ("x_m", "y_m", "z_m")),
                             ("/plot/truth/rotor_thrust_n", ("f1_n", "f2_n", "f3_n", "f4_n")),
                             ("/plot/truth/attack_n", ("applied_n",)),
                             ("/plot/truth/path_distance_m", ("distance_m",)))[:4 if distance
                                                                              else 3]:
            entry = self._plots.get(topic)
            if entry is None:
                cid = self._register(topic, plotchan.FLOAT64_MULTI_ARRAY,
                                     plotchan.SCHEMA_ENCODING, plotchan.SCHEMA_TEXT,
                                     plotchan.MESSAGE_ENCODING)
                entry = self._plots[topic] = (cid, plotchan.labels(names), len(names))
            out.append((entry[0], entry[1]))
        return tuple(out)

    def _controller_tuple_plots(self, t: float, log_ns: int, state: Sequence[Any]) -> None:
        """:meth:`_controller_plots` of the compact record, by a plan made from the first
        one (which field, how to pack it): the same messages, a few µs instead of ~16 per
        sample; a record of another shape takes the general path (and a new plan)."""
        plan = self._ctl_plot_plan
        items = []
        if plan is not None:
            try:
                for i, cid, head, pack, flat in plan:
                    v = state[i]
                    items.append((cid, head + (pack(*_numbers(v)) if flat else
                                               pack(*v) if type(v) in (list, tuple) else
                                               pack(v))))
            except (TypeError, struct.error, IndexError):
                plan = None
        if plan is None:
            self._controller_plots(t, log_ns, zip(self._controller_fields, state,
                                                  strict=True))
            self._ctl_plot_plan = self._plot_plan(state)
            return
        self._next_ctl_plot_s = t + self._scene_period_s - 1e-6
        self._write_many(tuple(items), log_ns, self._sim_ns)

    def _plot_plan(self, state: Sequence[Any]) -> list[tuple[int, int, bytes, Any, bool]]:
        """For each numeric field of a compact record (channels registered by
        :meth:`_controller_plots`): (index, channel id, head, pack, nested)."""
        plan = []
        for i, (name, value) in enumerate(zip(self._controller_fields, state, strict=True)):
            entry = self._plots.get(f"/plot/controller/{name}")
            if entry is None:
                continue
            nested = not (type(value) in (int, float, bool) or (
                type(value) in (list, tuple) and all(type(v) is float for v in value)))
            plan.append((i, entry[0], entry[1], struct.Struct(f"<{entry[2]}d").pack, nested))
        return plan

    def _controller_plots(self, t: float, log_ns: int,
                          fields: Iterable[tuple[str, Any]]) -> None:
        """The controller record's numbers as plot channels, at up to scene_hz of sim time:
        ``/plot/controller/NAME`` per numeric field (a number, a flag as 0/1, or numbers
        nested in lists, flattened in order); text fields are the JSON channel's."""
        self._next_ctl_plot_s = t + self._scene_period_s - 1e-6
        pub_ns = self._sim_ns
        plots = self._plots
        items = []
        for name, value in fields:
            flat = _numbers(value)
            if not flat:
                continue
            topic = f"/plot/controller/{name}"
            entry = plots.get(topic)
            if entry is not None and entry[2] == len(flat):     # the usual case: one write
                items.append((entry[0], entry[1] + _pack_floats(flat)))
                continue
            self._plot(topic, [name] if len(flat) == 1 else [f"{name}[{i}]"
                                                             for i in range(len(flat))],
                       flat, log_ns, pub_ns)
        if items:
            self._write_many(tuple(items), log_ns, pub_ns)

    def _plot(self, topic: str, names: Sequence[str], values: Sequence[float], log_ns: int,
              pub_ns: int) -> None:
        """One sample of a plot channel (a Float64MultiArray labelled ``names``)."""
        entry = self._plots.get(topic)
        if entry is None or entry[2] != len(values):
            cid = self._register(topic, plotchan.FLOAT64_MULTI_ARRAY, plotchan.SCHEMA_ENCODING,
                                 plotchan.SCHEMA_TEXT, plotchan.MESSAGE_ENCODING) \
                if entry is None else entry[0]
            entry = self._plots[topic] = (cid, plotchan.labels(names), len(values))
        self._write(entry[0], plotchan.encode(entry[1], values), log_ns, pub_ns)

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
        self.latch(self._fg_channel("/scene/path", "foxglove.SceneUpdate"), data, log_ns,
                   self._sim_ns)

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
                    fg.log_entry(log_ns, lvl, self._with_time(str(text)), source),
                    log_ns, self._sim_ns)

    def controller(self, time_s: float, state: Mapping[str, Any] | Sequence[Any]) -> None:
        """The controller's record at sim time ``time_s`` (s) on ``/controller/state``:
        a sequence of values named by ``controller_fields`` (the compact per-tick form), or
        a mapping. numpy values are fine; NaN/inf/None values are left out
        (``_nonfinite``)."""
        if self._ctl_plans and type(time_s) is float and not isinstance(state, Mapping):
            for entry in self._ctl_plans:           # the hot path: a record plan
                data = entry[0](state, time_s)
                if data is None:
                    continue
                if not entry[1]:                    # its first record: checked once
                    if data != self._dumps({**dict(zip(self._controller_fields, state,
                                                       strict=True)), "t_s": time_s}):
                        self._ctl_plans.remove(entry)
                        break
                    entry[1] = True
                self.set_sim_time(time_s)
                log_ns = self._now_ns()
                self._write(self._ctl_cid, data, log_ns, self._sim_ns)
                if time_s >= self._next_ctl_plot_s:
                    self._controller_tuple_plots(time_s, log_ns, state)
                return
        record = state
        try:
            t = float(time_s)
            if not math.isfinite(t):
                raise ValueError(f"time_s: not finite ({time_s})")
            if not isinstance(state, Mapping):
                if len(state) != len(self._controller_fields):
                    raise ValueError(f"record: expected {len(self._controller_fields)} values "
                                     f"({', '.join(self._controller_fields)}), got "
                                     f"{len(state)}")
                state = dict(zip(self._controller_fields, state, strict=True))
            data = self._dumps({**state, "t_s": t})
        except (TypeError, ValueError) as exc:
            self._bad(f"controller state: {exc}")
            return
        self.set_sim_time(t)
        log_ns = self._now_ns()
        self._write(self._channel("/controller/state", self._controller_schema), data,
                    log_ns, self._sim_ns)
        if t >= self._next_ctl_plot_s:
            self._controller_plots(t, log_ns, state.items())
        if isinstance(record, Mapping) or len(self._ctl_shapes) >= _MAX_RECORD_PLANS:
            return
        shape = tuple((type(v), len(v)) if type(v) in (list, tuple) else type(v)
                      for v in record)
        if shape not in self._ctl_shapes:           # a new shape: precompile it once
            plan = self._ctl_shapes[shape] = record_plan(self._controller_fields, record)
            if plan is not None:
                self._ctl_plans.append([plan, False])
                self._ctl_cid = self._channel_ids.get("/controller/state", 0)

    # ------------------------------------------------------------------ internals
