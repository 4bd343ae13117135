"""The live view: a Foxglove WebSocket server (Foxglove's own SDK) fed the recorder's bytes.

The Foxglove app connects with "Open connection" → ``ws://HOST:PORT`` (subprotocol
``foxglove.websocket.v1``) and sees the channels the recorder writes to its file, with the
same schemas and the same message bytes. It runs inside the recorder (in the recorder's
child process for ``sim``/``fly``), so the flight loop never waits for a viewer: the
server's own threads send, and a slow viewer loses messages, not the loop's time.

The scene is advertised before anyone connects. foxglove-sdk (checked on 0.30.3) advertises a
channel created while a viewer is connected *before* it records the channel for that viewer
(``ConnectedClient::advertise_channels``: send, then insert), so a viewer that subscribes at
once (Foxglove does, for every topic its layout shows) can be refused ("Unknown channel ID",
a status message) and then never gets that channel: a vehicle missing for the whole flight.
Channels that exist when a viewer connects are recorded before its messages are read, so
``/tf``, ``/scene/vehicle``, ``/scene/path`` and ``/log`` (Foxglove's well-known types, fixed
schemas) are created with the server; the recorder's later ``channel()`` for one of them
gets that channel back. Channels first seen mid-flight (MAVLink and JSON topics) still
depend on the SDK; a viewer refused one sees the status error and recovers by reconnecting.
"""

from __future__ import annotations

from typing import Any

__all__ = ["SCENE_TOPICS", "LiveServer", "parse_live_address"]

#: Advertised from the start (see the module docstring): topic → Foxglove schema name.
SCENE_TOPICS = {"/tf": "foxglove.FrameTransform", "/scene/vehicle": "foxglove.SceneUpdate",
                "/scene/path": "foxglove.SceneUpdate", "/log": "foxglove.Log"}


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

    def __init__(self, host: str, port: int, name: str = "tfl-mav") -> None:
        import foxglove

        from tfl_mav.flightlog import foxglove as fg

        self._fg = foxglove
        self._context = foxglove.Context()      # this server's channels only
        # before the server accepts anyone: no viewer can see these advertised too early
        self._channels: dict[str, tuple[tuple[str, str, bytes, str], Any]] = {}
        for topic, type_name in SCENE_TOPICS.items():
            self.channel(topic, *fg.schema(type_name), "protobuf")
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
        """A channel advertised to every viewer; ``.log(data, log_time=ns)`` publishes. The
        same topic with the same schema is the same channel (the scene's, made at start)."""
        key = (schema_name, schema_encoding, bytes(schema_data), message_encoding)
        known = self._channels.get(topic)
        if known is not None and known[0] == key:
            return known[1]
        ch = self._fg.Channel(topic, message_encoding=message_encoding,
                              schema=self._fg.Schema(name=schema_name, encoding=schema_encoding,
                                                     data=schema_data),
                              context=self._context)
        self._channels[topic] = (key, ch)
        return ch

    def close(self) -> None:
        self._server.stop()
