"""A MAVLink 2 link over UDP: one socket, one pinned peer, one packer, one parser.

Small and explicit on purpose (unlike pymavlink's ``mavutil``, which hides sockets, peers and
retries behind one object):

* **One peer.** Either fixed (:meth:`Link.connect`) or learned from the first valid
  ``HEARTBEAT`` that reaches a listening socket (:meth:`Link.listen`) and that ``admit``
  (if given) accepts; refused ones are counted (``refused_peer``). Datagrams from any
  other address are counted (``foreign``) and dropped; nothing is sent anywhere but the
  peer, except by :meth:`Link.send_to` (e.g. telling a refused sender why). Once the
  peer's system id is known (from its first HEARTBEAT, or pinned), frames
  with another sysid are dropped too (``wrong_sysid``).
* **Never itself.** A frame that claims this link's own (sysid, compid) is our own traffic
  sent back (a loop, or an attacker reflecting it: our frames travel in clear, so a
  reflected frame even carries a valid signature). It is dropped and counted
  (``reflected``) before anything else looks at it, so it can neither pin the peer nor its
  system id (ArduPilot's ``MAVLink_routing::check_and_forward`` does not process such a
  "loopback of our own messages" either).
* **MAVLink 2 only.** Frames with the MAVLink 1 magic (0xFE) are rejected and counted
  (``mavlink1``): accepting them would let anyone downgrade a signed link to an unsigned
  one later.
* **One datagram at a time** (:mod:`tfl_mav.link.receive`). Each datagram is framed
  there and every frame is handed to pymavlink's ``decode`` (which checks length and CRC;
  never the signature, see below), except the per-tick messages, which
  :mod:`tfl_mav.link.codec` packs into the very same bytes and which the receive loop
  decodes itself, with the same checks, into a light message read like pymavlink's
  (:class:`~tfl_mav.link.codec.LiteMessage`: the unpacked wire tuple, fields as properties).
  Nothing is carried over between datagrams, so a truncated datagram cannot swallow the
  start of the next good one, as happens when datagrams are concatenated into one stream
  parser (``parse_buffer``). Every rejection is counted by reason in :class:`LinkStats`;
  nothing a peer sends can raise out of :meth:`Link.recv`.
* **Recorder hook.** ``on_frame(direction, raw, msg, time_s)`` sees every frame in both
  directions with the exact wire bytes: ``direction`` is ``"rx"`` or ``"tx"``, ``msg`` is
  the decoded message, or ``None`` for a received datagram (or the unparsed rest of one)
  that was rejected, and for :meth:`Link.send_raw`. ``time_s`` comes from ``clock``
  (default wall time, ``time.time``). Exceptions raised by the hook propagate: a broken
  recorder is a bug to see, not traffic to count.
* **Signing** (``signing=``, a :class:`~tfl_mav.link.signing.Signing`): every outgoing
  frame is signed (pymavlink's packer, timestamp kept up with the wall clock) and every
  received frame must carry a valid signature with a fresh timestamp, checked by our own
  verify-then-advance code *before* pymavlink decodes it (pymavlink's own check advances
  the stream before verifying, measured in bench/bench_signing.py). Rejections are counted
  as ``unsigned``, ``bad_signature``, ``replayed`` and ``bad_timestamp``. Only verified
  frames can pin the peer or its system id. Without ``signing`` (the default) signed frames
  from others are accepted unchecked, like any key-less MAVLink receiver does, and nothing
  is signed.

Not thread-safe, by design: packing mutates the sequence number and the signing timestamp.
Use one link from one thread.
"""

from __future__ import annotations

import errno
import math
import socket
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import asdict, dataclass
from typing import Any

from tfl_mav.link.codec import FastCodec
from tfl_mav.link.dialect import new_mavlink
from tfl_mav.link.receive import Receiver
from tfl_mav.link.signing import Signing

__all__ = [
    "Address",
    "FrameHook",
    "FramesHook",
    "Link",
    "LinkError",
    "LinkStats",
    "finite_fields",
    "nonfinite_field",
    "parse_address",
]

Address = tuple[str, int]
FrameHook = Callable[[str, bytes, Any, float], None]
FramesHook = Callable[[str, Sequence[bytes], Any, float], None]
Admit = Callable[[Any, "Address"], "str | None"]
"""``admit(heartbeat, sender) -> None`` (may pin) or the reason it may not."""

_DONTWAIT = socket.MSG_DONTWAIT   # Linux/macOS: this read/send never blocks
_CODEC = FastCodec()      # stateless: the hot messages' compiled layouts, shared (packing)


class LinkError(Exception):
    """The link cannot work (bad address, port in use); the message says what to do."""


@dataclass
class LinkStats:
    """Counters of one link. Every received datagram ends in exactly one place: accepted
    frames in ``rx_frames``, everything else in one of the rejection counters."""

    rx_datagrams: int = 0
    rx_bytes: int = 0
    rx_frames: int = 0          # accepted, decoded frames
    tx_frames: int = 0
    tx_bytes: int = 0
    # rejections, by reason
    garbage: int = 0            # first byte is not a MAVLink magic
    mavlink1: int = 0           # MAVLink 1 frame (0xFE): downgrade protection
    truncated: int = 0          # shorter than its header says
    bad_flags: int = 0          # unknown incompatibility flags
    bad_crc: int = 0
    bad_signature: int = 0      # signed link: signature does not verify (forged, wrong key)
    unsigned: int = 0           # signed link: frame carries no signature
    replayed: int = 0           # signed link: timestamp not newer than the stream's last
    bad_timestamp: int = 0      # signed link: timestamp > 60 s from our clock (skew, old capture)
    malformed: int = 0          # decodes badly for another reason (length, payload)
    unknown_id: int = 0         # message id not in the dialect
    foreign: int = 0            # datagram from an address that is not the peer
    wrong_sysid: int = 0        # from the peer's address, but another system id
    no_peer: int = 0            # listening, peer not learned yet, and not a HEARTBEAT
    reflected: int = 0          # claims our own (sysid, compid): our own frame sent back
    refused_peer: int = 0       # HEARTBEAT from a would-be peer that ``admit`` refused
    # local trouble
    recv_errors: int = 0
    send_errors: int = 0
    unsent_no_peer: int = 0     # send() before any peer was known

    #: The counters of frames/datagrams dropped (the others: traffic and local trouble).
    REJECTIONS = ("garbage", "mavlink1", "truncated", "bad_flags", "bad_crc",
                  "bad_signature", "unsigned", "replayed", "bad_timestamp", "malformed",
                  "unknown_id", "foreign", "wrong_sysid", "no_peer", "refused_peer",
                  "reflected")

    @property
    def rejected(self) -> int:
        """Frames/datagrams dropped for any reason."""
        return sum(getattr(self, name) for name in self.REJECTIONS)

    def as_dict(self) -> dict[str, int]:
        return asdict(self)

    def summary(self) -> str:
        """One line: traffic, then only the counters that are not zero."""
        parts = [f"rx {self.rx_frames} tx {self.tx_frames}"]
        parts += [f"{k} {v}" for k, v in self.as_dict().items()
                  if v and k not in ("rx_datagrams", "rx_bytes", "rx_frames", "tx_frames",
                                     "tx_bytes")]
        return ", ".join(parts)


def parse_address(text: str, field: str) -> Address:
    """``"HOST:PORT"`` → (host, port); ValueError naming ``field`` if malformed."""
    host, sep, port_text = text.rpartition(":")
    if not sep or not host:
        raise ValueError(f"{field}: expected HOST:PORT, got {text!r}")
    try:
        port = int(port_text)
    except ValueError:
        raise ValueError(f"{field}: port must be an integer, got {port_text!r}") from None
    if not 0 <= port <= 65535:
        raise ValueError(f"{field}: port must be 0-65535, got {port}")
    return host, port


def _resolve(address: Address, field: str) -> Address:
    """Numeric IPv4 (host, port), so it compares equal to what ``recvfrom`` reports."""
    host, port = address
    try:
        infos = socket.getaddrinfo(host, port, socket.AF_INET, socket.SOCK_DGRAM)
    except socket.gaierror as exc:
        raise LinkError(f"{field}: cannot resolve host {host!r} ({exc.strerror}); "
                        "give an IPv4 address such as 127.0.0.1") from None
    ip, resolved_port = infos[0][4][:2]
    return ip, resolved_port


def nonfinite_field(msg: Any, names: Iterable[str]) -> str | None:
    """The first field of ``msg`` among ``names`` holding NaN/inf (``"controls[2]"``), or
    None if all are finite. Array fields are checked element by element."""
    for name in names:
        value = getattr(msg, name)
        if isinstance(value, (list, tuple)):
            for i, v in enumerate(value):
                if isinstance(v, float) and not math.isfinite(v):
                    return f"{name}[{i}]"
        elif isinstance(value, float) and not math.isfinite(value):
            return name
    return None


def finite_fields(msg: Any, names: Iterable[str]) -> bool:
    """Gate for NaN/inf: True iff every named field (and array element) is finite."""
    return nonfinite_field(msg, names) is None


class Link:
    """One UDP socket talking MAVLink 2 to exactly one peer. See the module docstring."""

    def __init__(self, sock: socket.socket, *, src_system: int, src_component: int,
                 peer: Address | None = None, peer_sysid: int | None = None,
                 on_frame: FrameHook | None = None,
                 clock: Callable[[], float] = time.time,
                 max_datagrams_per_recv: int = 256,
                 signing: Signing | None = None, link_id: int = 0,
                 admit: Admit | None = None, skim_ids: Iterable[int] = ()) -> None:
        """Wrap a bound UDP socket (made blocking here: :meth:`recv` waits in ``recvfrom``
        with ``SO_RCVTIMEO``; every other read and every send passes ``MSG_DONTWAIT``).

        ``peer``: fixed peer address, or None to learn it from the first valid HEARTBEAT.
        ``peer_sysid``: pin the peer's system id; None learns it from its first HEARTBEAT.
        ``max_datagrams_per_recv`` bounds one :meth:`recv` so a flood cannot starve the caller.
        ``signing``: sign everything sent (with ``link_id``, 0-255) and accept only frames
        that verify; None (default): neither.
        ``admit(msg, addr)``: asked before a HEARTBEAT pins the peer (or its sysid); returns
        None to accept or the reason it is refused (counted ``refused_peer``, not pinned).
        ``skim_ids``: message ids this receiver only routes or records, never reads: their
        frames get every check and count a decode gets, but are handed out undecoded
        (:class:`~tfl_mav.link.codec.SkimmedMessage`, fields decoded on first read).
        """
        sock.setblocking(True)
        self._sock = sock
        self.packer = new_mavlink(src_system, src_component)
        # the hooks every frame sent or received is reported to (its users set them at any
        # time): on_frame(direction, raw, msg, time_s); on_frames(direction, raws, msgs,
        # time_s), when set beside on_frame, a datagram's frames in one call (the settled
        # receive path's and send_many's; msgs None: all accepted), e.g. a RecorderProcess's
        # on_frames: one hand-off a datagram, not one a frame
        self.on_frame = on_frame
        self.on_frames: FramesHook | None = None
        self.clock = clock
        self.stats = LinkStats()
        self._codec = _CODEC
        self.signing = signing
        # the receive path, and the peer it learns and pins
        self.receiver = Receiver(sock, self, self.stats,
                                 own_identity=(src_system, src_component), peer=peer,
                                 peer_sysid=peer_sysid,
                                 max_datagrams_per_recv=max_datagrams_per_recv,
                                 signing=signing, admit=admit, skim_ids=frozenset(skim_ids))
        if signing is not None:
            signing.configure_packer(self.packer, link_id)

    # ------------------------------------------------------------------ construction
    @classmethod
    def listen(cls, bind: Address, *, src_system: int, src_component: int,
               peer: Address | None = None, **kw: Any) -> Link:
        """Bind ``bind`` and wait for a peer: the first valid HEARTBEAT's sender, unless
        ``peer`` pins it. Raises :class:`LinkError` (e.g. port in use)."""
        sock = _bound_socket(bind, "listen address")
        pinned = _resolve(peer, "peer address") if peer is not None else None
        return cls(sock, src_system=src_system, src_component=src_component, peer=pinned, **kw)

    @classmethod
    def connect(cls, peer: Address, *, src_system: int, src_component: int,
                bind: Address | None = None, **kw: Any) -> Link:
        """Talk to the fixed ``peer``, from ``bind`` (default: an ephemeral port on
        127.0.0.1 for a loopback peer, else on all interfaces)."""
        resolved = _resolve(peer, "peer address")
        if bind is None:
            bind = ("127.0.0.1" if resolved[0].startswith("127.") else "0.0.0.0", 0)
        sock = _bound_socket(bind, "bind address")
        return cls(sock, src_system=src_system, src_component=src_component, peer=resolved,
                   **kw)

    @property
    def peer(self) -> Address | None:
        """The peer's (host, port): given, or learned from its first valid HEARTBEAT (None:
        not yet). Setting it (None: learn again) goes to the receive path, which owns it."""
        return self.receiver.peer

    @peer.setter
    def peer(self, value: Address | None) -> None:
        self.receiver.set_peer(value)

    @property
    def peer_sysid(self) -> int | None:
        """The peer's pinned system id (None: learned from its next HEARTBEAT)."""
        return self.receiver.peer_sysid

    @peer_sysid.setter
    def peer_sysid(self, value: int | None) -> None:
        self.receiver.set_peer_sysid(value)

    def recv(self, timeout_s: float = 0.0, *, drain: bool = True) -> list[Any]:
        """Accepted messages from datagrams that arrive within ``timeout_s`` (0 = poll):
        :meth:`Receiver.recv <tfl_mav.link.receive.Receiver.recv>`."""
        return self.receiver.recv(timeout_s, drain=drain)

    @property
    def local_address(self) -> Address:
        host, port = self._sock.getsockname()[:2]
        return host, port

    def fileno(self) -> int:
        return self._sock.fileno()

    def close(self) -> None:
        self._sock.close()

    def __enter__(self) -> Link:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ------------------------------------------------------------------ sending
    def send(self, msg: Any) -> int:
        """Pack ``msg`` (MAVLink 2, next sequence number) and send it to the peer.

        Returns the bytes sent; 0 (counted) if no peer is known yet or the OS refused.
        """
        packer = self.packer
        if self.signing is not None:
            self.signing.stamp(packer)
        raw = self._codec.pack(msg, packer) or msg.pack(packer)
        packer.seq = (packer.seq + 1) & 0xFF
        return self._sendto(raw, msg)

    def send_many(self, msgs: Sequence[Any]) -> int:
        """Pack ``msgs`` (consecutive sequence numbers) into ONE datagram to the peer.

        Why: on loopback every ``sendto`` also wakes the receiver, which costs more than
        packing (10-25 µs here); a lockstep tick's ODOMETRY + ESC_TELEMETRY in one datagram
        saves one per tick on each side. Receivers that read a datagram as a byte stream
        (this class, pymavlink, MAVProxy, QGroundControl; ArduPilot batches the same way)
        see the frames one by one. ``on_frame`` still sees each frame on its own (``on_frames``,
        when set beside it, sees the datagram's frames in one call). Keep the
        total under the UDP limit (65 507 bytes; a MAVLink 2 frame is at most 280).
        Returns the bytes sent; 0 (counted per frame) if no peer is known or the OS refused.
        """
        packer = self.packer
        if self.signing is not None:
            self.signing.stamp(packer)
        frames = self._codec.pack_many(msgs, packer)
        st = self.stats
        peer = self.receiver.peer
        if peer is None:
            st.unsent_no_peer += len(frames)
            return 0
        try:
            n = self._sock.sendto(b"".join(frames), _DONTWAIT, peer)
        except OSError:
            st.send_errors += 1
            return 0
        st.tx_frames += len(frames)
        st.tx_bytes += n
        if self.on_frame is not None:
            now = self.clock()
            if self.on_frames is not None:      # the datagram's frames in one call
                self.on_frames("tx", frames, msgs, now)
            else:
                for raw, msg in zip(frames, msgs, strict=True):
                    self.on_frame("tx", raw, msg, now)
        return n

    def send_to(self, address: Address, msg: Any) -> int:
        """Send ``msg`` to ``address`` instead of the peer (e.g. to tell a refused sender
        why). Returns the bytes sent, 0 if the OS refused."""
        packer = self.packer
        if self.signing is not None:
            self.signing.stamp(packer)
        raw = msg.pack(packer)
        packer.seq = (packer.seq + 1) & 0xFF
        try:
            n = self._sock.sendto(raw, _DONTWAIT, address)
        except OSError:
            self.stats.send_errors += 1
            return 0
        self.stats.tx_frames += 1
        self.stats.tx_bytes += n
        if self.on_frame is not None:
            self.on_frame("tx", raw, msg, self.clock())
        return n

    def send_raw(self, raw: bytes) -> int:
        """Send bytes exactly as given (tests, replays). Returns the bytes sent, 0 if not."""
        return self._sendto(bytes(raw), None)

    def _sendto(self, raw: bytes, msg: Any) -> int:
        st = self.stats
        peer = self.receiver.peer
        if peer is None:
            st.unsent_no_peer += 1
            return 0
        try:
            n = self._sock.sendto(raw, _DONTWAIT, peer)
        except OSError:
            st.send_errors += 1
            return 0
        st.tx_frames += 1
        st.tx_bytes += n
        if self.on_frame is not None:
            self.on_frame("tx", raw, msg, self.clock())
        return n


def _bound_socket(bind: Address, field: str) -> socket.socket:
    host, port = _resolve(bind, field)
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        sock.bind((host, port))
    except OSError as exc:
        sock.close()
        hint = ("another process is using it: stop it or pick another port"
                if exc.errno == errno.EADDRINUSE else "check the address")
        raise LinkError(f"cannot bind UDP {host}:{port} ({field}): {exc.strerror}; "
                        f"{hint}") from None
    return sock
