"""The live view: a Foxglove WebSocket server (Foxglove's own SDK) fed the recorder's bytes.

The Foxglove app connects with "Open connection" → ``ws://HOST:PORT`` (subprotocol
``foxglove.websocket.v1``) and sees the channels the recorder writes to its file, with the
same schemas and the same message bytes. It runs inside the recorder (in the recorder's
child process for ``sim``/``fly``), so the flight loop never waits for a viewer: the
server's own threads send, and a slow viewer loses messages, not the loop's time.
"""

from __future__ import annotations

from typing import Any

__all__ = ["LiveServer", "parse_live_address"]


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
    """One Foxglove WebSocket server on (host, port); raises OSError (one line) if the port
    cannot be bound."""

    def __init__(self, host: str, port: int, name: str = "tfl-mav") -> None:
        import foxglove

        self._fg = foxglove
        self._context = foxglove.Context()      # this server's channels only
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
        """A channel advertised to every viewer; ``.log(data, log_time=ns)`` publishes."""
        return self._fg.Channel(topic, message_encoding=message_encoding,
                                schema=self._fg.Schema(name=schema_name,
                                                       encoding=schema_encoding,
                                                       data=schema_data),
                                context=self._context)

    def close(self) -> None:
        self._server.stop()
