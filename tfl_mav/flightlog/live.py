"""The live view: a Foxglove WebSocket server (Foxglove's own SDK) on the recorder's channels.

The Foxglove app connects with "Open connection" → ``ws://HOST:PORT`` (subprotocol
``foxglove.websocket.v1``) and sees the channels the recorder writes to its file: the
server is a second sink of the recorder's ``foxglove.Context`` (the file is the first), so
one ``log`` call feeds both. It runs inside the recorder (in the recorder's child process
for ``sim``/``fly``), so the flight loop never waits for a viewer: the server's own threads
send, and a slow viewer loses messages, not the loop's time.

The scene is advertised before anyone connects. foxglove-sdk (checked on 0.30.3) advertises a
channel created while a viewer is connected *before* it records the channel for that viewer
(``ConnectedClient::advertise_channels``: send, then insert), so a viewer that subscribes at
once (Foxglove does, for every topic its layout shows) can be refused ("Unknown channel ID",
a status message) and then never gets that channel: a vehicle missing for the whole flight.
Channels that exist when a viewer connects are recorded before its messages are read, so
``/tf``, ``/scene/vehicle``, ``/scene/path`` and ``/log`` (Foxglove's well-known types, fixed
schemas) are created with the server; the recorder's later ``channel()`` for one of them
gets that channel back. Channels first seen mid-flight (MAVLink and record topics) still
depend on the SDK; a viewer refused one sees the status error and recovers by reconnecting.

Who draws the vehicle: on the simulator's side the recorder's ``truth`` calls fill ``/tf``
and ``/scene/vehicle``. The controller (``tfl-mav fly --foxglove``) has no truth, so its
address carries an :class:`EstimateScene` and this server draws the vehicle itself from what
the controller knows: ``/tf`` is the **controller's state estimate** (the ODOMETRY it flies
from, converted exactly as the daemon converts it), not the true pose, and
``/scene/vehicle`` shows its commanded rotor thrusts and the rotor its detector isolated
(from ``/controller/state``), so the 3-D panel moves with the controller's own view.
"""

from __future__ import annotations

import json
from types import SimpleNamespace
from typing import Any, NamedTuple

__all__ = ["SCENE_TOPICS", "EstimateScene", "LiveAddress", "LiveServer", "parse_live_address"]

#: Advertised from the start (see the module docstring): topic → Foxglove schema name.
SCENE_TOPICS = {"/tf": "foxglove.FrameTransform", "/scene/vehicle": "foxglove.SceneUpdate",
                "/scene/path": "foxglove.SceneUpdate", "/log": "foxglove.Log"}


class EstimateScene(NamedTuple):
    """What a controller's live view needs to draw the vehicle from its own estimate: the
    rotors' positions (body FLU: x forward, y left; m) and the thrust scale (N)."""

    rotor_xy_m: tuple[tuple[float, float], ...]
    thrust_max_n: float


class LiveAddress(NamedTuple):
    """Where to serve, and who draws the vehicle: ``estimate=None`` the recorder's truth
    (the simulator); an :class:`EstimateScene` this server, from the controller's
    estimate. A tuple, so it travels as ``live=`` through the recorder (and its child
    process) to ``LiveServer(*live)`` unchanged."""

    host: str
    port: int
    estimate: EstimateScene | None = None


def parse_live_address(text: str, option: str = "--foxglove") -> tuple[str, int]:
    """``[HOST:]PORT`` → (host, port); host defaults to 127.0.0.1. ValueError naming
    ``option`` otherwise."""
    host, _, port_text = text.rpartition(":")
    host = host.strip("[]") or "127.0.0.1"
    try:
        port = int(port_text)
    except ValueError:
        raise ValueError(f"{option}: expected [HOST:]PORT, got {text!r}") from None
    if not 0 < port < 65536:
        raise ValueError(f"{option}: port must be 1-65535, got {port}")
    return host, port


class LiveServer:
    """One Foxglove WebSocket server on (host, port), the scene channels already advertised;
    raises OSError (one line) if the port cannot be bound."""

    def __init__(self, host: str, port: int, estimate: EstimateScene | None = None,
                 name: str = "tfl-mav", context: Any = None) -> None:
        import foxglove

        from tfl_mav.flightlog import foxglove as fg

        self._fg = foxglove
        # the recorder's context (its file is the other sink), else this server's own
        self._context = context if context is not None else foxglove.Context()
        # before the server accepts anyone: no viewer can see these advertised too early
        self._channels: dict[str, tuple[tuple[str, str, bytes, str], Any]] = {}
        self.estimate: _EstimateDrawer | None = None
        for topic, type_name in SCENE_TOPICS.items():
            self.channel(topic, *fg.schema(type_name), "protobuf")
        self.estimate = (_EstimateDrawer(estimate, self._channels["/tf"][1],
                                         self._channels["/scene/vehicle"][1])
                         if estimate is not None else None)
        try:
            self._server = foxglove.start_server(name=name, host=host, port=port,
                                                 context=self._context)
        except Exception as exc:          # FoxgloveError (a RuntimeError), bad host, ...
            reason = str(exc).split(": ", 1)[-1] if "bind" in str(exc) else str(exc)
            raise OSError(f"--foxglove {host}:{port}: cannot serve the live view "
                          f"({reason})") from None
        self.port = self._server.port

    def channel(self, topic: str, schema_name: str, schema_encoding: str, schema_data: bytes,
                message_encoding: str) -> Any:
        """A channel advertised to every viewer (and written to the context's file);
        ``.log(data, log_ns)`` publishes. The same topic with the same schema is the same
        channel (the scene's, made at start). On a controller's server (``estimate``) the
        ODOMETRY and ``/controller/state`` channels also feed its drawing of the vehicle."""
        key = (schema_name, schema_encoding, bytes(schema_data), message_encoding)
        known = self._channels.get(topic)
        if known is not None and known[0] == key:
            return known[1]
        ch = self._fg.Channel(topic, message_encoding=message_encoding,
                              schema=self._fg.Schema(name=schema_name, encoding=schema_encoding,
                                                     data=schema_data),
                              context=self._context).base
        drawer = self.estimate
        if drawer is not None:
            if topic.startswith("/mavlink/") and topic.endswith("/ODOMETRY"):
                ch = _Tee(ch, drawer.odometry)
            elif topic == "/controller/state" and message_encoding == "protobuf":
                from tfl_mav.flightlog.protos import message_class

                drawer.record_class = message_class(schema_name, bytes(schema_data))
                ch = _Tee(ch, drawer.controller)
        self._channels[topic] = (key, ch)
        return ch

    def close(self) -> None:
        self._server.stop()


class _Tee:
    """A channel whose messages are also shown to ``see(data, log_ns)`` after publishing."""

    __slots__ = ("_channel", "_see")

    def __init__(self, channel: Any, see: Any) -> None:
        self._channel, self._see = channel, see

    def log(self, data: bytes, log_time: int, sink_id: int | None = None) -> None:
        self._channel.log(data, log_time, sink_id)
        self._see(data, log_time)


class _EstimateDrawer:
    """``/tf`` and ``/scene/vehicle`` from the controller's view (see the module docstring),
    at most every ``PERIOD_NS`` of log time, from the decoded ODOMETRY (JSON, at most 50 Hz
    of sim time) and the latest controller record (protobuf, parsed only per drawing). A
    message it cannot use (a non-finite field left out of the JSON, another frame, not a
    unit quaternion) is counted in ``errors``
    with its reason in ``last_error``, and the next one is tried: the recorder never sees
    an exception from here."""

    PERIOD_NS = 20_000_000      # 50 Hz: the recorder's own scene rate (``scene_hz``)

    def __init__(self, scene: EstimateScene, tf: Any, vehicle: Any) -> None:
        self._scene, self._tf, self._vehicle = scene, tf, vehicle
        self._next_ns = 0
        self._record: bytes | None = None
        self.record_class: Any = None     # the protobuf class of /controller/state
        self._thrust_n = [0.0] * len(scene.rotor_xy_m)
        self._detected = 0
        self.drawn = 0
        self.errors = 0
        self.last_error: str | None = None

    def controller(self, data: bytes, log_ns: int) -> None:
        self._record = data             # parsed only when the vehicle is drawn

    def odometry(self, data: bytes, log_ns: int) -> None:
        if log_ns < self._next_ns:
            return
        from tfl_mav.flightlog import foxglove as fg
        from tfl_mav.model.frames import paper_from_odometry

        try:
            state = paper_from_odometry(SimpleNamespace(**json.loads(data)))
            self._take_record()
        except (ValueError, TypeError, AttributeError) as exc:    # JSONDecodeError too
            self.errors += 1
            self.last_error = f"{type(exc).__name__}: {exc}"
            return
        self._next_ns = log_ns + self.PERIOD_NS
        self._tf.log(fg.frame_transform(log_ns, state.position_m, state.quaternion_wxyz),
                     log_ns)
        self._vehicle.log(fg.vehicle_scene(log_ns, self._scene.rotor_xy_m, self._thrust_n,
                                           self._scene.thrust_max_n, self._detected,
                                           label="detected"), log_ns)
        self.drawn += 1

    def _take_record(self) -> None:
        """The latest controller record's commanded thrusts (N) and detected rotor; a field
        missing keeps the previous value."""
        if self._record is None or self.record_class is None:
            return
        from google.protobuf.message import DecodeError

        from tfl_mav.flightlog.protos import to_dict

        data, self._record = self._record, None
        try:
            rec = to_dict(self.record_class.FromString(data))
        except DecodeError as exc:
            raise ValueError(f"controller record: {exc}") from None
        thrust = rec.get("rotor_thrust_cmd_n")
        if isinstance(thrust, list) and len(thrust) == len(self._thrust_n):
            self._thrust_n = [float(f) for f in thrust]
        rotor = rec.get("detected_rotor")
        if isinstance(rotor, int) and 0 <= rotor <= len(self._thrust_n):
            self._detected = rotor
