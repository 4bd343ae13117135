"""The recorder's MAVLink frames: ``/mavlink/raw`` and ``/mavlink/{sysid}/{compid}/{MSG}``.

Every frame makes two messages: the raw record (wire bytes as base64, direction, whether
the link accepted it) and, for an accepted frame, its fields decoded from the wire bytes.
See :mod:`~tfl_mav.flightlog.recorder` for the channels and the time stamps.

Why a module of its own: frames are most of what a recorder child does (4-5 a
1 ms tick per side). :meth:`FrameRecorder.on_frames` takes a whole hand-off batch: for a
(direction, sysid, compid, msgid) seen before whose fields print by the precompiled
:class:`~tfl_mav.flightlog.jsonenc.MavPlan`, a frame costs one unpack, one msgspec call
that prints the whole object (:mod:`~tfl_mav.flightlog.jsonobj`; the few values msgspec
writes in another notation re-printed in place), one ``%`` format of the raw record and
the two records appended to the chunk in progress right here (as
:meth:`FastWriter.add_pair` would), under one lock for the batch; NaN/inf fields (a real
PX4's unknown covariances) by the plan's template for that pattern
(:class:`~tfl_mav.flightlog.jsonenc.NullMasks`).
Everything else (first sight of a channel, rejected frames, STATUSTEXT, a failed file)
takes :meth:`FrameRecorder._on_frame`, the careful path, which writes the same bytes.
"""

from __future__ import annotations

import base64
import time
from binascii import b2a_base64
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

from tfl_mav.flightlog import foxglove as fg
from tfl_mav.flightlog import frames_c, schemas
from tfl_mav.flightlog.jsonenc import JsonEncoder, MavJson, MavPlan
from tfl_mav.flightlog.jsonobj import encode as _encode_obj
from tfl_mav.flightlog.mcapfast import MESSAGE_FIXED, MESSAGE_HEADER, MESSAGE_OPCODE
from tfl_mav.flightlog.mcapout import MAX_NS, McapOutput
from tfl_mav.link.dialect import mav
from tfl_mav.link.payload import PayloadDecoder
from tfl_mav.link.statustext import Reassembler

__all__ = ["FrameRecorder"]

_STATUSTEXT_ID = mav.MAVLINK_MSG_ID_STATUSTEXT


@dataclass
class _MavChannel:
    channel_id: int
    name: str
    sim_time: bool          # time_usec of this message is sim time
    statustext: bool
    nonfinite: bool = False  # NaN/inf seen on this channel: check before encoding


# (direction, raw[5:10] = sysid, compid, msgid) → what the hot path needs
_Fast = tuple[_MavChannel, MavPlan, bytes, bool, int]   # channel, plan, raw JSON head, rx,
                                                        # the raw channel's id


class FrameRecorder(McapOutput):
    """The frame half of :class:`~tfl_mav.flightlog.recorder.Recorder`."""

    def _init_frames(self, sim_time_messages: Iterable[str],
                     decoded_period_s: float = 0.0) -> None:
        names = set(sim_time_messages)
        self._sim_time_ids = {mav_id for mav_id, cls in mav.mavlink_map.items()
                              if cls.msgname in names and "time_usec" in cls.fieldnames}
        self._json = JsonEncoder()
        self._decoder = PayloadDecoder()
        self._mav = MavJson()
        self._mav_channels: dict[tuple[int, int, int], _MavChannel] = {}
        self._texts = Reassembler()      # STATUSTEXT chunks → whole /log entries
        self._frame_fast: dict[tuple[str, bytes], _Fast] = {}
        # the same channels for the C hot path (frames_c): frame key → what it needs
        self._frame_fast_c: dict[int, tuple[bytes, bytes, bool, int, int, int, int]] = {}
        self._frames_c: Any = frames_c.obtain(self._c_ready)
        self._sim_ns = 0
        self._sim_known = False
        # decoded MAVLink channels: at most one record a period of sim time each (a person
        # looks at 50 Hz; /mavlink/raw keeps every frame for decoding on read). channel id
        # → the sim time (ns) from which the next may be written.
        self._decoded_next: dict[int, int] = {}
        self._decoded_period_ns = max(round(decoded_period_s * 1e9) - 1000, 0)

    def on_frame(self, direction: str, raw: bytes, msg: Any, time_s: float) -> None:
        """The :class:`~tfl_mav.link.transport.Link` frame hook (``on_frame``): record one
        frame. ``msg`` is the decoded message, or None for a rejected rx frame or a
        ``send_raw`` tx frame; only whether it is None matters, the fields are decoded
        from ``raw``. ``time_s`` is the receipt time (s) on the recorder's clock."""
        if msg is None or (direction, raw[5:10]) not in self._frame_fast:
            self._on_frame(direction, raw, msg, time_s)
        else:
            self.on_frames(((None, time_s, direction, raw, True),))

    def _c_ready(self, fn: Any) -> None:
        self._frames_c = fn          # a background build is done (frames_c.obtain)

    def on_frames(self, frames: Iterable[tuple[Any, float, str, bytes, bool]]) -> None:
        """Record many frames: (anything, ``time_s``, direction, raw, accepted) each, as
        :meth:`on_frame` would one by one (a hand-off batch's frame items)."""
        c = self._frames_c
        w = self._writer
        if c is None or self._live is not None or not (self._open and getattr(w, "_fast",
                                                                              False)):
            self._frames_py(frames)
        else:
            self._frames_native(c, frames if type(frames) in (list, tuple) else list(frames))
        if time.monotonic() >= self._next_flush:
            try:
                self._flush()
            except Exception as exc:
                self._failed(exc)

    def _frames_native(self, c: Any, items: Any) -> None:
        """:meth:`on_frames` by the C hot path (:mod:`frames_c`); the frames it leaves
        (first sight, NaN/inf values, rejected) one by one by :meth:`_frames_py`."""
        w = self._writer
        i, n = 0, len(items)
        while i < n:
            epoch = self._epoch_ns
            state = [self._sim_ns, self._sim_known, 0, 0, n,
                     -1 if epoch is None else epoch, 1 if self._timeline_sim else 0,
                     self._decoded_period_ns, 0]
            failed: Exception | None = None
            with self._lock:
                if not self._open:
                    break
                try:
                    i = c(items, i, self._frame_fast_c, w.chunk, w.end_chunk, w.chunk_limit,
                          state, _encode_obj, self._decoded_next)
                except Exception as exc:      # a write failed: the file stops here
                    failed = exc
                finally:
                    self._sim_ns, self._sim_known = state[0], state[1]
                    if state[5] >= 0:
                        self._epoch_ns = state[5]
                    st = self.stats
                    st.frames_rx += state[2]
                    st.frames_tx += state[3]
                    st.messages += state[2] + state[3] + state[8]
                    self._pending += state[2] + state[3] + state[8]
            if failed is not None:
                self._failed(failed)
                i = state[4] + 1
                break
            if i < n:
                self._frames_py(items[i:i + 1])
                i += 1
        for f in items[i:]:                    # after a failure: counted as dropped
            self._on_frame(f[2], f[3], True if f[4] else None, f[1])

    def _frames_py(self, frames: Iterable[tuple[Any, float, str, bytes, bool]]) -> None:
        """:meth:`on_frames` in Python, every frame."""
        w = self._writer
        if not (self._open and getattr(w, "_fast", False)):
            for f in frames:
                self._on_frame(f[2], f[3], True if f[4] else None, f[1])
            return
        get = self._frame_fast.get
        encode_obj = _encode_obj
        # the chunk in progress, appended to here as FastWriter.add_pair does (one call a
        # frame less); reloaded after a chunk ends
        chunk, limit = w.chunk, w.chunk_limit
        buf, index = chunk.buf, chunk.index
        pack = MESSAGE_HEADER.pack
        live = self._live_channels if self._live is not None else None
        n_rx = n_tx = written = 0
        decoded_next, period = self._decoded_next, self._decoded_period_ns
        todo = iter(frames)
        with self._lock:
            try:
                for f in todo:
                    _, time_s, direction, raw, accepted = f
                    fast = get((direction, raw[5:10])) if accepted and self._open else None
                    t = None
                    if fast is not None:
                        chan, plan, head, rx, raw_cid = fast
                        n = len(raw)
                        payload = raw[10:n - 15 if raw[2] & 1 else n - 2]
                        if len(payload) != plan.size:     # as frame_payload
                            k = plan.size - len(payload)
                            payload = payload + bytes(k) if k > 0 else payload[:plan.size]
                        try:
                            t = plan.unpack(payload)
                            log_ns = int(time_s * 1e9)
                        except Exception:     # struct.error, a bad stamp: the careful path
                            t = None
                    if t is None or not 0 <= log_ns <= MAX_NS:
                        self._on_frame(direction, raw, True if accepted else None, time_s)
                        buf, index = chunk.buf, chunk.index   # it may have ended a chunk
                        continue
                    if chan.sim_time and t[plan.time_index] * 1000 <= MAX_NS:
                        self._sim_ns = t[plan.time_index] * 1000
                        self._sim_known = True
                    if self._timeline_sim:
                        log_ns = self._on_timeline(log_ns)
                    pub_ns = self._sim_ns
                    cid = chan.channel_id
                    # the decoded record at most every decoded period of sim time (the raw
                    # one always); before sim time is known, every one
                    keep = not self._sim_known or pub_ns >= decoded_next.get(cid, -1)
                    data = None
                    if keep:
                        try:
                            obj = plan.obj
                            if obj is not None:   # numbers only: one msgspec call (jsonobj)
                                data = encode_obj(obj.build(t))
                                if not (data.count(b"e") == obj.key_e
                                        and b"0.0000" not in data and b"null" not in data):
                                    data = (obj.reprint(data, plan.numbers(t))
                                            or plan.json(t))   # NaN/inf: left out, listed
                            else:
                                data = plan.json(t)
                        except Exception:     # the careful path (it writes both records)
                            data = None
                        if data is None:
                            self._on_frame(direction, raw, True if accepted else None,
                                           time_s)
                            buf, index = chunk.buf, chunk.index
                            continue
                        decoded_next[cid] = min(pub_ns + period, MAX_NS)
                        if chan.nonfinite:
                            chan.nonfinite = False
                    raw_json = b'%s%d,"len":%d,"data":"%s"}' % (
                        head, raw[4], n, b2a_base64(raw, newline=False))
                    flat = index.get(raw_cid)
                    if flat is None:
                        flat = index[raw_cid] = []
                    flat += (log_ns, len(buf))
                    buf += pack(MESSAGE_OPCODE, MESSAGE_FIXED + len(raw_json), raw_cid, 0,
                                log_ns, pub_ns)
                    buf += raw_json
                    if len(buf) > limit:
                        w.end_chunk()
                        buf, index = chunk.buf, chunk.index
                    if data is not None:
                        flat = index.get(cid)
                        if flat is None:
                            flat = index[cid] = []
                        flat += (log_ns, len(buf))
                        buf += pack(MESSAGE_OPCODE, MESSAGE_FIXED + len(data), cid, 0, log_ns,
                                    pub_ns)
                        buf += data
                        if len(buf) > limit:
                            w.end_chunk()
                            buf, index = chunk.buf, chunk.index
                        written += 1
                    if rx:
                        n_rx += 1
                    else:
                        n_tx += 1
                    if live is not None:
                        for lc, d in ((raw_cid, raw_json), (cid, data)):
                            if d is not None and lc in live:
                                live[lc].log(d, log_time=log_ns)
            except Exception as exc:          # a write failed: the file stops here
                self._failed(exc)
            finally:
                st = self.stats
                st.frames_rx += n_rx
                st.frames_tx += n_tx
                st.messages += n_rx + n_tx + written
                self._pending += n_rx + n_tx + written
        for f in todo:                        # after a failure: counted as dropped
            self._on_frame(f[2], f[3], True if f[4] else None, f[1])

    def _on_frame(self, direction: str, raw: bytes, msg: Any, time_s: float) -> None:
        """:meth:`on_frame`, every case (first sight of a channel, rejected frames)."""
        try:
            log_ns = min(max(int(time_s * 1e9), 0), MAX_NS)
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
            log_ns = self._on_timeline(log_ns)
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
        # precompiled JSON of the fields (all finite; STATUSTEXT also makes a /log entry)
        fast = (self._mav.encode(raw, msgid) if chan is not None and not chan.statustext
                else None)
        if fast is not None:
            fields = None
            usec = fast[1]
            if chan.sim_time and usec * 1000 <= MAX_NS:
                self._sim_ns = usec * 1000
                self._sim_known = True
        else:
            fields = self._decoder.fields(raw, msgid) if chan is not None else None
            if fields is not None and chan.sim_time:
                usec = fields["time_usec"]
                if usec * 1000 <= MAX_NS:
                    self._sim_ns = usec * 1000
                    self._sim_known = True
        pub_ns = self._sim_ns
        log_ns = self._on_timeline(log_ns)
        name = chan.name if chan is not None else f"#{msgid}"
        head = (f'{{"direction":"{direction}","accepted":true,"name":"{name}",'
                f'"msgid":{msgid},"sysid":{sysid},"compid":{compid},"seq":')
        self._write(self._raw_channel(),
                    f'{head}{raw[4]},"len":{len(raw)},"data":"{data}"}}'.encode(),
                    log_ns, pub_ns)
        # the decoded record at most once a period of sim time, as the hot paths (a
        # STATUSTEXT always: it is also the /log entry)
        keep = chan is not None and (chan.statustext or not self._sim_known or pub_ns
                                     >= self._decoded_next.get(chan.channel_id, -1))
        if keep:
            self._decoded_next[chan.channel_id] = min(pub_ns + self._decoded_period_ns, MAX_NS)
        if fast is not None:
            chan.nonfinite = False
            if keep:
                self._write(chan.channel_id, fast[0], log_ns, pub_ns)
            plan = self._mav.plan(msgid)
            if plan is not None and (plan.time_index is not None or not chan.sim_time):
                self._frame_fast[(direction, raw[5:10])] = (
                    chan, plan, head.encode(), direction == "rx", self._raw_channel())
                lay = frames_c.layout(mav.mavlink_map[msgid]) if plan.simple else None
                if lay is not None and (lay[1] is not None or not chan.sim_time):
                    self._frame_fast_c[frames_c.frame_key(direction == "rx", raw[5:10])] = (
                        lay[0], head.encode(), direction == "rx", self._raw_channel(),
                        chan.channel_id, lay[1] if chan.sim_time else -1, plan.size)
            return
        if fields is None:
            self._bad(f"frame: {name} (#{msgid}) did not decode from its wire bytes")
            return
        if not keep:
            return
        data, chan.nonfinite = self._json.dumps_sticky(fields, chan.nonfinite)
        self._write(chan.channel_id, data, log_ns, pub_ns)
        if chan.statustext:     # /log gets the whole text once its last chunk is here
            for text in self._texts.add((sysid, compid, direction), fields["text"],
                                        fields.get("id", 0), fields.get("chunk_seq", 0)):
                self._write(self._fg_channel("/log", "foxglove.Log"),
                            fg.log_entry(log_ns, fg.mav_severity_to_level(fields["severity"]),
                                         self._with_time(text),
                                         f"mavlink/{sysid}/{compid} {direction}"),
                            log_ns, pub_ns)

    def _with_time(self, text: str) -> str:
        return f"[t={self._sim_ns * 1e-9:.3f}s] {text}" if self._sim_known else text

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
