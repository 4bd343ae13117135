"""The receive path of a :class:`~tfl_mav.link.transport.Link`: datagram → checked messages.

:class:`Receiver` is an object the link owns: the socket's reading side, the parser, and
the peer it learns (or was given) and pins. This is the path every tick of both processes
takes (the vehicle reads the daemon's command, the daemon the vehicle's state), and it is
written for that. One call, :meth:`Receiver.ingest`, walks a datagram frame by frame with
everything it needs bound once per datagram: framing (magic, length, incompatibility
flags), the signature (:meth:`~tfl_mav.link.signing.Signing.verify`, verify then advance),
then, for the per-tick messages of :mod:`tfl_mav.link.codec`, the CRC and the unpack written
out in the loop and the :class:`~tfl_mav.link.codec.LiteMessage` built directly: no Python
call per frame but the recorder's ``on_frame`` hook. Every other frame goes through
:meth:`Receiver._decode_other` (skimmed, or pymavlink's ``decode``), as before.

The decisions and counters are the ones :meth:`FastCodec.decode_lite
<tfl_mav.link.codec.FastCodec.decode_lite>` and pymavlink make (tests/contract/test_codec.py,
tests/test_link*.py, and tests/system/test_fuzz.py, which predicts every counter of hostile
input): a bad CRC is ``bad_crc``, a signed frame counts on the parser's ``sig_count``, a
short payload is zero-extended and a long one (unknown extensions) cut.

**Draining.** :meth:`Receiver.recv` waits for one datagram in ``recvfrom`` itself, then
drains what is already queued. Whether more is queued is asked with ``poll`` (timeout 0)
rather than by a ``recvfrom`` that fails with EAGAIN: for a socket read by one thread,
``poll`` reports it readable exactly when such a ``recvfrom`` would return a datagram or a
pending socket error, so the same datagrams are read in the same order and the same errors
counted, but the usual answer ("nothing") costs no exception (~0.4 µs instead of ~1.5 µs
here). The check itself cannot be skipped: only the kernel knows whether a resend, a
duplicate or a reordered newer state is queued behind the datagram just read, and the
daemon acts on the newest state of what it drained (docs/design.md, "Time").
"""

from __future__ import annotations

import math
import select
import socket
import struct
from typing import Any

from tfl_mav.link.codec import FastCodec, _crc16, skim
from tfl_mav.link.dialect import mav, new_mavlink

__all__ = ["MAGIC_V1", "MAGIC_V2", "Receiver"]

MAGIC_V2 = 0xFD
MAGIC_V1 = 0xFE
_HEADER_LEN_V2 = 10
_CRC_LEN = 2
_SIGNATURE_LEN = 13
_IFLAG_SIGNED = 0x01
_MIN_FRAME_V2 = _HEADER_LEN_V2 + _CRC_LEN
_MAX_DATAGRAM = 65535
_HEARTBEAT_ID = mav.MAVLINK_MSG_ID_HEARTBEAT
_DONTWAIT = socket.MSG_DONTWAIT   # Linux/macOS: this read never blocks
_POLLIN = select.POLLIN
_ZEROS = bytes(256)               # a trimmed payload's zeros (a MAVLink 2 payload ≤ 255)
_new_tuple = tuple.__new__

# msgid → (LiteMessage class, crc_extra as bytes, payload size, unpack, unpack_from): the
# codec's compiled layouts, flattened so one dict lookup gives everything a frame needs.
_HOT: dict[int, tuple[Any, bytes, int, Any, Any]] = {
    msgid: (lay.rx_lite, lay.crc_extra_byte, lay.size, lay.rx_unpack, lay.rx_unpack_from)
    for msgid, lay in FastCodec().by_id.items()}


class Receiver:
    """The receive path of one :class:`~tfl_mav.link.transport.Link` (module docstring).

    ``hooks``: the link, whose public ``on_frame``, ``on_frames`` and ``clock`` (which its
    users may set at any time) every accepted or rejected frame is reported to; ``stats``
    its counters (this path counts the receive side). ``peer``, ``peer_sysid``,
    ``signing``, ``admit``, ``skim_ids``, ``max_datagrams_per_recv``: as the link's
    constructor says. The peer is this object's: learned from the first valid HEARTBEAT,
    read by the link's send path, set through :meth:`set_peer` / :meth:`set_peer_sysid`.
    """

    def __init__(self, sock: socket.socket, hooks: Any, stats: Any, *,
                 own_identity: tuple[int, int], peer: Any, peer_sysid: int | None,
                 max_datagrams_per_recv: int, signing: Any, admit: Any,
                 skim_ids: frozenset[int]) -> None:
        self._sock = sock
        self._hooks = hooks
        self.stats = stats
        self.own_identity = own_identity
        # the parser of everything not decoded here (pymavlink's; its signing state counts
        # the signed frames, as pymavlink's own receive would)
        self.parser = new_mavlink(*own_identity)
        self._decode = self.parser.decode
        self.peer = peer                          # (host, port), None until learned
        self.peer_sysid = peer_sysid              # pinned system id, None until learned
        self.max_datagrams_per_recv = max_datagrams_per_recv
        self.signing = signing
        self.admit = admit
        self.skim_ids = skim_ids
        self._timeout_ms = 0          # SO_RCVTIMEO now set (0: none yet)
        self._poll = select.poll()    # "is anything queued?" without an exception
        self._poll.register(sock.fileno(), _POLLIN)

    def set_peer(self, peer: Any) -> None:
        """Talk to ``peer`` ((host, port) as ``recvfrom`` reports it; None: learn it from the
        next valid HEARTBEAT)."""
        self.peer = peer

    def set_peer_sysid(self, sysid: int | None) -> None:
        """Pin the peer's system id (None: learn it from its next HEARTBEAT)."""
        self.peer_sysid = sysid

    def recv(self, timeout_s: float = 0.0, *, drain: bool = True) -> list[Any]:
        """Accepted messages from datagrams that arrive within ``timeout_s`` (0 = poll).

        Waits at most ``timeout_s`` (rounded up to whole milliseconds) for the first
        datagram, then drains whatever else is already queued (up to
        ``max_datagrams_per_recv``) without waiting; ``drain=False`` returns after the
        first datagram (a caller that loops anyway saves the check that finds the queue
        empty). May return an empty list even before the timeout if only rejected traffic
        arrived.

        The wait is the ``recvfrom`` itself (the socket blocks, with ``SO_RCVTIMEO`` set
        once per distinct timeout): one system call, no ``poll`` before it; reads that must
        not wait pass ``MSG_DONTWAIT``, and the drain asks ``poll`` first (module docstring).
        """
        out: list[Any] = []
        sock = self._sock
        try:
            if timeout_s > 0.0:
                ms = math.ceil(timeout_s * 1000.0)
                if ms != self._timeout_ms:
                    self._set_timeout_ms(ms)
                data, addr = sock.recvfrom(_MAX_DATAGRAM)
            else:
                data, addr = sock.recvfrom(_MAX_DATAGRAM, _DONTWAIT)
        except BlockingIOError:
            return out
        except OSError:
            self.stats.recv_errors += 1
            return out
        if not drain:
            self.ingest(data, addr, out)
            return out
        ready = self._poll.poll
        for _ in range(self.max_datagrams_per_recv):
            self.ingest(data, addr, out)
            if not ready(0):
                break
            try:
                data, addr = sock.recvfrom(_MAX_DATAGRAM, _DONTWAIT)
            except BlockingIOError:
                break
            except OSError:
                self.stats.recv_errors += 1
                break
        return out

    def _set_timeout_ms(self, ms: int) -> None:
        """How long a waiting ``recvfrom`` blocks (``SO_RCVTIMEO``; ≥ 1 ms, 0 would mean
        forever)."""
        ms = max(1, ms)
        self._sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVTIMEO,
                              struct.pack("ll", ms // 1000, (ms % 1000) * 1000))
        self._timeout_ms = ms

    def _reject(self, reason: str, raw: bytes) -> None:
        setattr(self.stats, reason, getattr(self.stats, reason) + 1)
        hooks = self._hooks
        if hooks.on_frame is not None:
            hooks.on_frame("rx", raw, None, hooks.clock())

    def ingest(self, data: bytes, addr: Any, out: list[Any]) -> None:
        """Split one datagram into frames; append accepted messages to ``out``."""
        st = self.stats
        st.rx_datagrams += 1
        n = len(data)
        st.rx_bytes += n
        addr = (addr[0], addr[1])
        if self.peer is not None and addr != self.peer:
            self._reject("foreign", data)
            return
        if n == 0:   # a zero-length datagram holds no frame: count it, like a cut-off one
            self._reject("truncated", data)
            return
        if type(data) is not bytes:
            data = bytes(data)
        i = 0
        now = None                   # the hook's receipt time: one clock read a datagram
        peer_sysid = self.peer_sysid
        if peer_sysid is not None and self.signing is None and self.peer is not None:
            # a peer sharing our sysid (a companion computer's): our own compid is a
            # reflection, left to the general loop (-1 matches no compid byte)
            own_sysid, own_compid = self.own_identity
            if own_sysid != peer_sysid:
                own_compid = -1
            # The settled link's per-tick frames (unsigned, hot, from the peer's sysid): the
            # checks below in the general loop's order, fewer of them. Anything else (a
            # failed check included) leaves this loop at the frame's start, untouched, and
            # the general loop decides and counts it.
            hooks = self._hooks
            on_frame = hooks.on_frame
            batch: list[bytes] | None = None
            if on_frame is not None and hooks.on_frames is not None:
                batch, on_frame = [], None
            hot = _HOT.get
            crc16 = _crc16
            while i < n:
                end = n - i
                if end < _MIN_FRAME_V2 or data[i] != MAGIC_V2 or data[i + 2]:
                    break
                end = i + _MIN_FRAME_V2 + data[i + 1]
                if end > n:
                    break
                layout = hot(data[i + 7] | data[i + 8] << 8 | data[i + 9] << 16)
                if layout is None or data[i + 5] != peer_sysid or data[i + 6] == own_compid:
                    break
                lite, crc_extra, size, unpack, unpack_from = layout
                pend = end - _CRC_LEN
                if crc16(crc_extra, crc16(data[i + 1:pend], 0xFFFF)) \
                        != data[pend] | data[pend + 1] << 8:
                    break
                raw = data if end == n and not i else data[i:end]
                if pend - i - _HEADER_LEN_V2 >= size:    # whole (or longer: extensions cut)
                    msg: Any = _new_tuple(lite, (*unpack_from(data, i + _HEADER_LEN_V2), raw))
                else:                                    # MAVLink 2 trimmed trailing zeros
                    msg = _new_tuple(lite, (*unpack(
                        data[i + _HEADER_LEN_V2:pend] + _ZEROS[:size + _HEADER_LEN_V2 + i - pend]),
                        raw))
                i = end
                st.rx_frames += 1
                if on_frame is not None:
                    if now is None:
                        now = hooks.clock()
                    on_frame("rx", raw, msg, now)
                elif batch is not None:
                    batch.append(raw)
                out.append(msg)
            if batch:
                now = hooks.clock()
                hooks.on_frames("rx", batch, None, now)
            if i == n:
                return
        self._ingest_general(data, i, n, addr, out, now)

    def _ingest_general(self, data: bytes, i: int, n: int, addr: Any, out: list[Any],
                        now: float | None) -> None:
        """:meth:`ingest` from byte ``i`` of ``data``: every frame, every check."""
        st = self.stats
        hooks = self._hooks
        on_frame = hooks.on_frame
        signing = self.signing
        own_sysid, own_compid = self.own_identity
        hot = _HOT.get
        crc16 = _crc16
        while i < n:
            magic = data[i]
            if magic != MAGIC_V2:
                # Cannot resynchronise inside a datagram: reject the rest of it.
                self._reject("mavlink1" if magic == MAGIC_V1 else "garbage", data[i:])
                return
            if n - i < _MIN_FRAME_V2:
                self._reject("truncated", data[i:])
                return
            incompat = data[i + 2]
            if incompat & ~_IFLAG_SIGNED:
                self._reject("bad_flags", data[i:])
                return
            end = i + _MIN_FRAME_V2 + data[i + 1] + (_SIGNATURE_LEN if incompat else 0)
            if end > n:
                self._reject("truncated", data[i:])
                return
            raw = data[i:end]            # the whole datagram itself if one frame
            i = end
            if raw[5] == own_sysid and raw[6] == own_compid:
                # Our own identity: our frame sent back. First, so that it can never pin
                # the peer or its sysid, signed or not (our signed frames verify: the key
                # is ours, and they travel in clear for anyone to reflect).
                self._reject("reflected", raw)
                continue
            if signing is not None:
                reason = signing.verify(raw)
                if reason is not None:
                    self._reject(reason, raw)
                    continue
            layout = hot(raw[7] | raw[8] << 8 | raw[9] << 16)
            if layout is not None:       # a per-tick message: FastCodec.decode_lite inline
                lite, crc_extra, size, unpack, unpack_from = layout
                pend = len(raw) - _CRC_LEN - (_SIGNATURE_LEN if incompat else 0)
                if crc16(crc_extra, crc16(raw[1:pend], 0xFFFF)) != raw[pend] | raw[pend + 1] << 8:
                    self._reject("bad_crc", raw)
                    continue
                if incompat:
                    self.parser.signing.sig_count += 1
                if pend - _HEADER_LEN_V2 >= size:    # whole (or longer: extensions cut)
                    msg: Any = _new_tuple(lite, (*unpack_from(raw, _HEADER_LEN_V2), raw))
                else:                                # MAVLink 2 trimmed trailing zeros
                    msg = _new_tuple(lite, (*unpack(
                        raw[_HEADER_LEN_V2:pend] + _ZEROS[:size + _HEADER_LEN_V2 - pend]),
                        raw))
                msgid = lite.MSG_ID
            else:
                msg = self._decode_other(raw)
                if msg is None:
                    continue
                msgid = -1               # read below only while the peer is not settled
            sysid = raw[5]
            peer_sysid = self.peer_sysid
            if peer_sysid is None or self.peer is None:
                is_heartbeat = (msgid if msgid >= 0 else msg.get_msgId()) == _HEARTBEAT_ID
                if self.peer is None and (not is_heartbeat or (
                        peer_sysid is not None and sysid != peer_sysid)):
                    self._reject("no_peer", raw)
                    continue
                if is_heartbeat and self.admit is not None and self.admit(msg, addr):
                    self._reject("refused_peer", raw)
                    continue
                if self.peer is None:
                    self.peer = addr
                if is_heartbeat:
                    self.peer_sysid = sysid
            elif sysid != peer_sysid:
                self._reject("wrong_sysid", raw)
                continue
            st.rx_frames += 1
            if on_frame is not None:
                if now is None:
                    now = hooks.clock()
                on_frame("rx", raw, msg, now)
            out.append(msg)

    def _decode_other(self, raw: bytes) -> Any:
        """Decode one complete, verified MAVLink 2 frame of a message that is not a per-tick
        one (skimmed if in ``skim_ids``, else pymavlink's message), or count why not and
        return None."""
        try:
            if self.skim_ids and raw[7] | raw[8] << 8 | raw[9] << 16 in self.skim_ids:
                msg = skim(raw, self.parser)
                if msg is not None:
                    return msg
            msg = self._decode(bytearray(raw))
        except mav.MAVError as exc:
            text = exc.message
            reason = ("bad_crc" if "CRC" in text
                      else "bad_signature" if "signature" in text else "malformed")
            self._reject(reason, raw)
            return None
        except Exception:  # struct/ctor errors on hostile payloads must not escape
            self._reject("malformed", raw)
            return None
        if isinstance(msg, mav.MAVLink_unknown):
            self._reject("unknown_id", raw)
            return None
        return msg
