"""The recorder's MAVLink frames: ``/mavlink/raw`` and ``/mavlink/{sysid}/{compid}/{MSG}``.

Every frame goes to ``/mavlink/raw``: a ``tfl_mav.MavlinkFrames`` message per datagram (the
frames of one direction and one receipt time: their wire bytes, sent or received, which
ones the link refused; :mod:`~tfl_mav.flightlog.protos`): nothing is lost, and ``tfl-mav
replay`` re-sends them byte for byte. One message a datagram rather than a frame: an MCAP
message costs ~47 bytes besides its data (a 31-byte record header, a 16-byte message index
entry), as much as a small frame. An accepted frame is also decoded from its
wire bytes (float32 rounding and all) onto its message's channel as JSON (JSON Schema from
pymavlink's definitions, :mod:`~tfl_mav.flightlog.schemas`), at most one a channel every
decoded period of sim time (every one before sim time is known, and every STATUSTEXT):
the rate a person looks at. ``logread.mavlink_messages`` decodes all of a message's frames
from ``/mavlink/raw`` on read. See :mod:`~tfl_mav.flightlog.recorder` for the time stamps.

Why the hot path is small: frames are most of what a recorder child does (4-5 a 1 ms tick
per side). For a (direction, sysid, compid, msgid) seen before, a frame costs a dict
lookup and the sim time read from the payload when the message carries it (one
``unpack``); a datagram one raw record and one SDK ``log`` call; the decoded record only
when its period is due.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

import msgspec

from tfl_mav.flightlog import foxglove as fg
from tfl_mav.flightlog import protos, schemas
from tfl_mav.flightlog.mcapout import MAX_NS, McapOutput
from tfl_mav.link.dialect import mav
from tfl_mav.link.payload import PayloadDecoder
from tfl_mav.link.statustext import Reassembler

__all__ = ["FrameRecorder", "fields_json"]

_STATUSTEXT_ID = mav.MAVLINK_MSG_ID_STATUSTEXT
_USEC = struct.Struct("<Q")
_encode_json = msgspec.json.Encoder().encode


def fields_json(fields: dict[str, Any]) -> bytes:
    """A decoded message's fields as JSON; a float that is not finite (or a list holding
    one) is left out and its key listed in ``_nonfinite`` (Foxglove's JSON reader takes no
    null; the raw frame keeps the wire value)."""
    bad = None
    for k, v in fields.items():
        if type(v) is float:
            if not math.isfinite(v):
                bad = (bad or []) + [k]
        elif type(v) is list and v and type(v[0]) is float and not all(
                map(math.isfinite, v)):
            bad = (bad or []) + [k]
    if bad:
        fields = {k: v for k, v in fields.items() if k not in bad}
        fields[schemas.NONFINITE_KEY] = bad
    return _encode_json(fields)


@dataclass
class _MavChannel:
    emit: Any                   # the decoded channel's log(data, ns)
    name: str
    msgid: int
    statustext: bool
    usec_at: int                # where time_usec (sim time) sits in the frame; -1: not here
    next_ns: int = -1           # sim time (ns) from which the next decoded record is due


def _usec_offset(cls: Any) -> int:
    """Offset of ``time_usec`` in the frame (10-byte header + its wire position), or -1."""
    if "time_usec" not in cls.fieldnames:
        return -1
    sizes = {"char": 1, "uint8_t": 1, "int8_t": 1, "uint16_t": 2, "int16_t": 2,
             "uint32_t": 4, "int32_t": 4, "float": 4, "uint64_t": 8, "int64_t": 8,
             "double": 8}
    types = dict(zip(cls.fieldnames, cls.fieldtypes, strict=True))
    lengths = dict(zip(cls.ordered_fieldnames, cls.array_lengths, strict=True))
    at = 10
    for name in cls.ordered_fieldnames:
        if name == "time_usec":
            return at
        at += sizes[types[name]] * max(lengths[name], 1)
    return -1


class FrameRecorder(McapOutput):
    """The frame half of :class:`~tfl_mav.flightlog.recorder.Recorder`."""

    def _init_frames(self, sim_time_messages: Iterable[str],
                     decoded_period_s: float = 0.0) -> None:
        names = set(sim_time_messages)
        self._sim_time_ids = {mav_id for mav_id, cls in mav.mavlink_map.items()
                              if cls.msgname in names and "time_usec" in cls.fieldnames}
        self._decoder = PayloadDecoder()
        # (sysid, compid, msgid) bytes as on the wire (raw[5:10]) → channel; per direction
        self._mav: dict[bool, dict[bytes, _MavChannel | None]] = {True: {}, False: {}}
        self._texts = Reassembler()      # STATUSTEXT chunks → whole /log entries
        self._raw_emit: Any = None
        self._sim_ns = 0
        self._sim_known = False
        self._decoded_period_ns = max(round(decoded_period_s * 1e9) - 1000, 0)

    def on_frame(self, direction: str, raw: bytes, msg: Any, time_s: float) -> None:
        """The :class:`~tfl_mav.link.transport.Link` frame hook (``on_frame``): record one
        frame. ``msg`` is the decoded message, or None for a rejected rx frame or a
        ``send_raw`` tx frame; only whether it is None matters, the fields are decoded
        from ``raw``. ``time_s`` is the receipt time (s) on the recorder's clock."""
        self.on_frames(((None, time_s, direction, raw, msg is not None),))

    def on_frames(self, frames: Iterable[tuple[Any, float, str, bytes, bool]]) -> None:
        """Record many frames: (anything, ``time_s``, direction, raw, accepted) each (a
        hand-off batch's frame items). Consecutive frames of one direction and one receipt
        time (one datagram's) make one ``/mavlink/raw`` message."""
        raw_emit = self._raw_emit
        if raw_emit is None:
            raw_emit = self._raw_emit = self._channel("/mavlink/raw", *protos.schema(
                protos.FRAMES), "protobuf")
        st = self.stats
        out: list[tuple[Any, bytes, int]] = []       # written in order, under one lock
        raws: list[bytes] = []                       # the datagram in hand
        refused: list[int] = []
        due: list[tuple[_MavChannel, bytes]] = []
        key: tuple[str, Any] | None = None
        tx = False
        for _, time_s, direction, raw, accepted in frames:
            if (direction, time_s) != key:
                if raws:
                    self._datagram(raw_emit, key[1], tx, raws, refused, due, out)
                    raws, refused, due = [], [], []
                tx = direction == "tx"
                if not tx and direction != "rx":
                    self._bad(f"direction: expected 'rx' or 'tx', got {direction!r}")
                    key = None
                    continue
                key = (direction, time_s)
            if tx:
                st.frames_tx += 1
            else:
                st.frames_rx += 1
            raw = bytes(raw)
            chan = None
            if accepted and len(raw) >= 12:
                head = raw[5:10]
                table = self._mav[tx]
                chan = table.get(head) if head in table else self._new_channel(tx, head)
            elif not tx:
                st.frames_rejected += 1
                refused.append(len(raws))
            raws.append(raw)
            if chan is None:
                continue
            if chan.usec_at >= 0:
                at = chan.usec_at
                payload_end = len(raw) - (15 if raw[2] & 1 else 2)
                usec = _USEC.unpack(raw[at:min(at + 8, payload_end)].ljust(8, b"\0"))[0] \
                    if at < payload_end else 0
                if usec * 1000 <= MAX_NS:
                    self._sim_ns = usec * 1000
                    self._sim_known = True
            if chan.statustext or not self._sim_known or self._sim_ns >= chan.next_ns:
                chan.next_ns = min(self._sim_ns + self._decoded_period_ns, MAX_NS)
                due.append((chan, raw))
        if raws:
            self._datagram(raw_emit, key[1], tx, raws, refused, due, out)
        self._write_timed(out)

    def _datagram(self, raw_emit: Any, time_s: Any, tx: bool, raws: list[bytes],
                  refused: list[int], due: list[tuple[_MavChannel, bytes]],
                  out: list[tuple[Any, bytes, int]]) -> None:
        """One datagram's raw record and its frames' decoded records, at one log time."""
        try:
            log_ns = min(max(int(time_s * 1e9), 0), MAX_NS)
        except (TypeError, ValueError, OverflowError):
            log_ns = self._now_ns()
        if self._timeline_sim:
            log_ns = self._on_timeline(log_ns)
        out.append((raw_emit, protos.frames(raws, tx, refused), log_ns))
        for chan, raw in due:
            self._decoded(chan, raw, tx, log_ns, out)

    def _decoded(self, chan: _MavChannel, raw: bytes, tx: bool, log_ns: int,
                 out: list[tuple[Any, bytes, int]]) -> None:
        """The decoded record of an accepted frame (and a STATUSTEXT's ``/log`` entry), onto
        ``out``."""
        fields = self._decoder.fields(raw, chan.msgid)
        if fields is None:
            self._bad(f"frame: {chan.name} (#{chan.msgid}) did not decode from its wire "
                      "bytes")
            return
        out.append((chan.emit, fields_json(fields), log_ns))
        if chan.statustext:     # /log gets the whole text once its last chunk is here
            sysid, compid = raw[5], raw[6]
            direction = "tx" if tx else "rx"
            for text in self._texts.add((sysid, compid, direction), fields["text"],
                                        fields.get("id", 0), fields.get("chunk_seq", 0),
                                        log_ns * 1e-9):
                out.append((self._fg_channel("/log", "foxglove.Log"),
                            fg.log_entry(log_ns, fg.mav_severity_to_level(fields["severity"]),
                                         self._with_time(text),
                                         f"mavlink/{sysid}/{compid} {direction}"), log_ns))

    def _fg_channel(self, topic: str, type_name: str) -> Any:
        """The channel of a Foxglove well-known type (protobuf)."""
        emit = self._channels.get(topic)
        return emit if emit is not None else self._channel(topic, *fg.schema(type_name),
                                                           "protobuf")

    def _with_time(self, text: str) -> str:
        return f"[t={self._sim_ns * 1e-9:.3f}s] {text}" if self._sim_known else text

    def _new_channel(self, tx: bool, key: bytes) -> _MavChannel | None:
        """The decoded channel of frames with header bytes ``key`` (sysid, compid, msgid),
        made on first sight (None: a message this dialect does not know)."""
        sysid, compid, msgid = key[0], key[1], key[2] | key[3] << 8 | key[4] << 16
        cls = mav.mavlink_map.get(msgid)
        chan = None
        if cls is not None:
            topic = f"/mavlink/{sysid}/{compid}/{cls.msgname}"
            schema = schemas.mavlink_schema(msgid)
            emit = self._channel(topic, schema["title"], "jsonschema",
                                 schemas.schema_bytes(schema), "json")
            shared = self._mav[not tx].get(key)    # the same channel, other direction
            chan = _MavChannel(emit, cls.msgname, msgid, msgid == _STATUSTEXT_ID,
                               _usec_offset(cls) if msgid in self._sim_time_ids else -1)
            if shared is not None:
                chan = shared
        self._mav[tx][key] = chan
        return chan
