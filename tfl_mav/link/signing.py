"""MAVLink 2 message signing: the key file, outgoing timestamps, verify-then-advance.

Wire format (MAVLink 2 spec, "Message signing"): a signed frame has incompatibility flag
0x01 and ends in a 13-byte block ``link_id (1) | timestamp (6, little-endian) |
signature (6)``. ``signature`` is the first 48 bits of
``SHA-256(secret_key ‖ header ‖ payload ‖ crc ‖ link_id ‖ timestamp)`` (the header with its
0xFD magic, exactly the bytes before the signature) — the same construction as
pymavlink's ``MAVLink_message.sign_packet`` and the C library's ``mavlink_sign_packet``.
The timestamp counts 10 µs units since 2015-01-01T00:00:00Z.

Why our own receive side: pymavlink 2.4.50's ``MAVLink.check_signature`` stores a stream's
new timestamp *before* it checks the hash (bench/bench_signing.py shows it), so one forged
frame with a far-future timestamp and a victim's (sysid, compid, link_id) makes every later
genuine frame "too old" — a denial of service by anyone who can send one datagram.
:meth:`Signing.verify` checks the hash first and advances the stream only for a frame that
verifies. The pymavlink parser of a signed :class:`~tfl_mav.link.transport.Link` is left
without a key, so it never checks or advances anything itself.

Policy (docs/SIGNING.md says the same for users):

* Every frame must be signed; there is no unsigned exception, not even HEARTBEAT: in this
  project a HEARTBEAT is not inert (the vehicle starts its flight on the controller's first
  one, the daemon ends its run on a POWEROFF/EMERGENCY one, and the first one pins the
  peer).
* Per stream (sysid, compid, link_id) only strictly newer timestamps are accepted.
* A frame claiming our own (sysid, compid) is refused (``reflected``): replay state is kept
  only for streams we *receive*, so without this rule our own signed frames, which anyone
  can capture (signing does not encrypt), would verify when sent back to us.
* A timestamp more than ``window_s`` (default 60 s) ahead of our clock is refused, and so
  is a new stream's first timestamp more than ``window_s`` behind it (the spec's one-minute
  rule). The spec bounds only the past; bounding the future too means a peer whose clock
  (or timestamp counter) ran ahead cannot push a stream so far forward that, once it is
  corrected, its genuine frames are refused as replays until we restart. The price: the
  two clocks must agree within ``window_s`` (NTP does far better).
* Outgoing timestamps are ``max(previous + 1, wall clock)``: strictly increasing within a
  process, and, because they follow the wall clock, across a restart too (as long as a
  sender does not average more than 100 000 frames/s, the rate at which ``+1`` outruns the
  clock).

Signing authenticates; it does not encrypt. Anyone on the path can read every frame.
"""

from __future__ import annotations

import hashlib
import hmac
import os
import stat
import string
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

__all__ = [
    "KEY_LEN",
    "MAVLINK_EPOCH_UNIX_S",
    "SIGNATURE_BLOCK_LEN",
    "TIMESTAMP_UNITS_PER_S",
    "KeyFileError",
    "Signing",
    "load_key",
    "mavlink_timestamp",
    "parse_key",
    "signature48",
]

KEY_LEN = 32
SIGNATURE_BLOCK_LEN = 13           # link_id (1) + timestamp (6) + signature (6)
MAVLINK_EPOCH_UNIX_S = 1_420_070_400   # 2015-01-01T00:00:00Z
TIMESTAMP_UNITS_PER_S = 100_000    # one unit = 10 µs
_MAX_KEY_FILE_BYTES = 4096
_HEX = frozenset(string.hexdigits.encode())
_WHITESPACE = b" \t\r\n\v\f"
_IFLAG_SIGNED = 0x01


class KeyFileError(ValueError):
    """The key file cannot be used; the message names the option and what to do."""


def mavlink_timestamp(unix_s: float) -> int:
    """Unix seconds → MAVLink signing timestamp (10 µs units since 2015-01-01 UTC)."""
    return int((unix_s - MAVLINK_EPOCH_UNIX_S) * TIMESTAMP_UNITS_PER_S)


def signature48(key: bytes, signed_part: bytes) -> bytes:
    """The 6-byte signature of a frame: SHA-256 over key ‖ every byte before the signature
    (header, payload, crc, link_id, timestamp), first 48 bits."""
    return hashlib.sha256(key + signed_part).digest()[:6]


def parse_key(data: bytes, *, field: str = "--key-file") -> bytes:
    """A 32-byte secret from a key file's contents: 64 hex digits (whitespace and newlines
    anywhere are ignored) or exactly 32 raw bytes. KeyFileError naming ``field`` otherwise.

    Text made only of hex digits is always read as hex, so a short hex key (say 32 digits =
    16 bytes) is an error rather than silently becoming 32 weak ASCII bytes.
    """
    compact = data.translate(None, _WHITESPACE)
    if compact and all(b in _HEX for b in compact):
        if len(compact) != 2 * KEY_LEN:
            raise KeyFileError(f"{field}: {len(compact)} hex digits, expected {2 * KEY_LEN} "
                               f"({KEY_LEN} bytes)")
        key = bytes.fromhex(compact.decode("ascii"))
    elif not compact:
        raise KeyFileError(f"{field}: the file is empty; expected {2 * KEY_LEN} hex digits")
    elif len(data) == KEY_LEN:
        key = bytes(data)
    else:
        raise KeyFileError(f"{field}: expected {2 * KEY_LEN} hex digits or exactly {KEY_LEN} "
                           f"raw bytes, got {len(data)} bytes that are neither")
    if not any(key):
        raise KeyFileError(f"{field}: the key is all zeros (MAVLink treats that as 'no "
                           "signing'); generate a random one")
    return key


def load_key(path: str | os.PathLike[str], *, field: str = "--key-file") -> bytes:
    """Read and check a key file (see :func:`parse_key`).

    Refused, like ssh refuses a private key, if group or others may read or write it (on
    POSIX): a signing key is a password for the motors. KeyFileError naming ``field``.
    """
    p = Path(path)
    where = f"{field} {str(p)!r}"
    try:
        with open(p, "rb") as fh:
            mode = os.fstat(fh.fileno()).st_mode
            if not stat.S_ISREG(mode):
                raise KeyFileError(f"{where}: not a regular file")
            data = fh.read(_MAX_KEY_FILE_BYTES + 1)
    except OSError as exc:
        raise KeyFileError(f"{where}: cannot read it ({exc.strerror})") from None
    if os.name == "posix" and mode & 0o077:
        raise KeyFileError(f"{where}: group/others may access it (mode "
                           f"{stat.S_IMODE(mode):03o}); a signing key must be private, run: "
                           f"chmod 600 {p}")
    if len(data) > _MAX_KEY_FILE_BYTES:
        raise KeyFileError(f"{where}: larger than {_MAX_KEY_FILE_BYTES} bytes; expected "
                           f"{2 * KEY_LEN} hex digits or {KEY_LEN} raw bytes")
    return parse_key(data, field=where)


class Signing:
    """One endpoint's signing state: the secret, and the last accepted timestamp of every
    stream (sysid, compid, link_id) it has heard. Share one instance between the links of
    one system, so a frame captured on one link cannot be replayed into another.

    ``clock`` gives Unix seconds (default wall time); ``window_s`` is the accepted distance
    of a timestamp from that clock (see the module docstring). Not thread-safe.
    """

    def __init__(self, key: bytes, *, window_s: float = 60.0,
                 clock: Callable[[], float] = time.time) -> None:
        if len(key) != KEY_LEN:
            raise ValueError(f"key: must be {KEY_LEN} bytes, got {len(key)}")
        if not any(key):
            raise ValueError("key: all zeros means 'no signing' in MAVLink; use a random key")
        if not window_s > 0:
            raise ValueError(f"window_s: must be > 0 s, got {window_s}")
        self._key = bytes(key)
        self.window = round(window_s * TIMESTAMP_UNITS_PER_S)
        self.clock = clock
        self.streams: dict[tuple[int, int, int], int] = {}
        # (sysid, compid) of every packer we sign for: a frame claiming one of them is our
        # own, sent back (it verifies: our key signed it), never a peer's
        self.own: set[tuple[int, int]] = set()

    def now(self) -> int:
        """The current MAVLink timestamp by ``clock``."""
        return mavlink_timestamp(self.clock())

    # ------------------------------------------------------------------ receiving
    def verify(self, frame: bytes | bytearray) -> str | None:
        """Check one complete MAVLink 2 frame: None if accepted (and its stream advanced),
        else the reason, named as the :class:`~tfl_mav.link.transport.LinkStats` counter:
        ``unsigned``, ``bad_signature``, ``bad_timestamp`` (beyond the window),
        ``replayed`` (not newer than the stream's last accepted timestamp) or ``reflected``
        (it claims the (sysid, compid) of a packer this instance signs for: our own frame
        sent back, which verifies because our key signed it).

        Nothing is stored unless the signature verifies (verify, then advance).
        """
        if not frame[2] & _IFLAG_SIGNED:
            return "unsigned"
        if (frame[5], frame[6]) in self.own:
            return "reflected"
        expected = hashlib.sha256(self._key + frame[:-6]).digest()[:6]
        if not hmac.compare_digest(expected, bytes(frame[-6:])):
            return "bad_signature"
        timestamp = int.from_bytes(frame[-12:-6], "little")
        now = self.now()
        if timestamp > now + self.window:
            return "bad_timestamp"
        stream = (frame[5], frame[6], frame[-13])
        last = self.streams.get(stream)
        if last is None:
            if timestamp < now - self.window:
                return "bad_timestamp"
        elif timestamp <= last:
            return "replayed"
        self.streams[stream] = timestamp
        return None

    # ------------------------------------------------------------------ sending
    def configure_packer(self, packer: Any, link_id: int) -> None:
        """Make a pymavlink ``MAVLink`` packer sign every frame it packs with our key,
        ``link_id`` and a timestamp starting at the wall clock. Its ``pack`` implements
        the signature correctly (the tests check it against :func:`signature48`); call
        :meth:`stamp` before each pack so the timestamp keeps up with the clock."""
        if not 0 <= link_id <= 255:
            raise ValueError(f"link_id: must be 0-255, got {link_id}")
        self.own.add((packer.srcSystem, packer.srcComponent))
        sig = packer.signing
        sig.secret_key = self._key
        sig.link_id = link_id
        sig.sign_outgoing = True
        sig.timestamp = self.now()

    def stamp(self, packer: Any) -> None:
        """Before packing: timestamp = max(previous + 1, wall clock). pymavlink adds the
        +1 itself after every signed frame."""
        sig = packer.signing
        now = mavlink_timestamp(self.clock())
        if now > sig.timestamp:
            sig.timestamp = now
