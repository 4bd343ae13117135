"""A UDP fault relay between the controller daemon and the vehicle (issue 5, "Faults").

The library; ``tfl-mav relay`` (:mod:`tfl_mav.tools.cli.relay`) is its command line.

::

    tfl-mav fly --vehicle RELAY ──► [ relay: drop / duplicate / reorder / delay ] ──► tfl-mav sim
                                ◄──                                              ◄──

:class:`Relay` listens on one port for the daemon (``listen``) and talks to the vehicle's
control port (``vehicle``) from a second socket of its own, so the vehicle pins one stable
peer address. Every datagram passes through the :class:`Faults` of its direction
(``to_vehicle``: daemon → vehicle, ``to_daemon``: vehicle → daemon):

* **drop** with probability ``drop``;
* **duplicate** with probability ``duplicate`` (the copy gets its own delay);
* **reorder** with probability ``reorder``: the datagram is held back and sent right after
  the next datagram of its direction (a datagram that arrives while another is held is the
  one it swaps with and is never held itself, so the held fraction is p/(1+p) of a steady
  stream), or after ``max_hold_s`` if no successor comes;
* **delay** every datagram by ``delay_s`` plus a uniform ``[0, jitter_s]`` draw. Jitter larger
  than the packet spacing reorders on its own (as netem does); ``in_order=True`` keeps each
  direction first-in first-out instead (one queue, variable delay).

Each datagram draws the same five numbers from its direction's ``random.Random`` whatever the
outcome, so a seed fixes every decision and the two directions never disturb each other's
sequence. Delays run on one timer heap, never a sleep per packet, so a relay with jitter
still forwards tens of thousands of datagrams a second. Everything it does is counted in
:class:`RelayStats`; no datagram, socket error or peer can raise out of the loop.

The daemon side is whoever sent the latest datagram to ``listen`` (a restarted daemon on a
new port is followed at once); the vehicle side accepts only the vehicle's address
(others are counted as ``foreign``). This is a test tool: it pins nothing for security.
"""

from __future__ import annotations

import contextlib
import heapq
import math
import random
import select
import socket
import threading
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from typing import Any

from tfl_mav.link.transport import Address

__all__ = ["DirectionStats", "Faults", "Relay", "RelayError", "RelayStats"]

TO_VEHICLE, TO_DAEMON = "to_vehicle", "to_daemon"
_MAX_DATAGRAM = 65535
_BATCH = 64                 # datagrams read per socket per loop turn: neither side starves
_IDLE_WAIT_S = 0.05         # longest select(): bounds the reaction to stop()
_SOCKET_BUFFER_BYTES = 1 << 20   # bursts must not overflow the kernel queue unseen


class RelayError(Exception):
    """The relay cannot start (bad address, port in use); the message says what to do."""


@dataclass(frozen=True)
class Faults:
    """What to do to the datagrams of one direction. Probabilities in [0, 1]; times in
    seconds of wall clock."""

    drop: float = 0.0
    duplicate: float = 0.0
    reorder: float = 0.0
    delay_s: float = 0.0
    jitter_s: float = 0.0
    in_order: bool = False      # jitter keeps the order (FIFO) instead of reordering

    def __post_init__(self) -> None:
        for name in ("drop", "duplicate", "reorder"):
            p = getattr(self, name)
            if not (isinstance(p, (int, float)) and math.isfinite(p) and 0.0 <= p <= 1.0):
                raise ValueError(f"{name}: a probability must be in [0, 1], got {p!r}")
        for name in ("delay_s", "jitter_s"):
            s = getattr(self, name)
            if not (isinstance(s, (int, float)) and math.isfinite(s) and 0.0 <= s <= 60.0):
                raise ValueError(f"{name}: must be in [0, 60] seconds, got {s!r}")

    @property
    def delays(self) -> bool:
        return self.delay_s > 0.0 or self.jitter_s > 0.0

    def describe(self) -> str:
        parts = [f"{name} {100 * getattr(self, name):g} %" for name in
                 ("drop", "duplicate", "reorder") if getattr(self, name)]
        if self.delay_s:
            parts.append(f"delay {1000 * self.delay_s:g} ms")
        if self.jitter_s:
            parts.append(f"jitter 0-{1000 * self.jitter_s:g} ms"
                         + (" in order" if self.in_order else ""))
        return ", ".join(parts) or "none"


@dataclass
class DirectionStats:
    """Counters of one direction. Every received datagram is dropped, forwarded (once, or
    twice if duplicated) or still pending; ``latency_*`` are wall seconds from receipt to
    send of forwarded datagrams."""

    received: int = 0
    received_bytes: int = 0
    dropped: int = 0
    duplicated: int = 0
    reordered: int = 0          # held back to go after the next datagram
    hold_expired: int = 0       # held, but no successor came within max_hold_s
    forwarded: int = 0          # datagrams sent, duplicates included
    forwarded_bytes: int = 0
    no_destination: int = 0     # to the daemon before any daemon had spoken
    overflow: int = 0           # timer heap full (max_pending): dropped
    send_errors: int = 0
    latency_min_s: float = math.inf
    latency_max_s: float = 0.0
    latency_sum_s: float = 0.0

    @property
    def latency_mean_s(self) -> float:
        return self.latency_sum_s / self.forwarded if self.forwarded else math.nan

    def as_dict(self) -> dict[str, Any]:
        out = asdict(self)
        out["latency_mean_s"] = self.latency_mean_s
        return {k: (v if not isinstance(v, float) or math.isfinite(v) else None)
                for k, v in out.items()}


@dataclass
class RelayStats:
    """Both directions plus what arrived on the vehicle side from anyone else."""

    to_vehicle: DirectionStats = field(default_factory=DirectionStats)
    to_daemon: DirectionStats = field(default_factory=DirectionStats)
    foreign: int = 0            # vehicle-side datagrams not from the vehicle: dropped
    recv_errors: int = 0
    daemon_changes: int = 0     # the daemon side's address changed (a restarted daemon)
    tap_errors: int = 0         # the tap callback raised

    def as_dict(self) -> dict[str, Any]:
        return {"to_vehicle": self.to_vehicle.as_dict(), "to_daemon": self.to_daemon.as_dict(),
                "foreign": self.foreign, "recv_errors": self.recv_errors,
                "daemon_changes": self.daemon_changes, "tap_errors": self.tap_errors}

    def summary(self) -> str:
        def one(name: str, d: DirectionStats) -> str:
            lat = (f", latency {1000 * d.latency_mean_s:.2f} ms mean / "
                   f"{1000 * d.latency_max_s:.2f} ms max" if d.forwarded else "")
            return (f"{name}: received {d.received}, forwarded {d.forwarded}, dropped "
                    f"{d.dropped}, duplicated {d.duplicated}, reordered {d.reordered}{lat}")
        return (f"{one(TO_VEHICLE, self.to_vehicle)}; {one(TO_DAEMON, self.to_daemon)}; "
                f"foreign {self.foreign}")


class Relay:
    """The fault relay. See the module docstring.

    Use it in-process (``with Relay(...) as relay:`` runs it on its own thread) or blocking
    (:meth:`run`, as ``tfl-mav relay`` does). ``listen``: daemon-side address to bind (port
    0 = any free, see :attr:`listen_address`); ``bind``: the vehicle-side socket's address.
    ``max_pending`` bounds the datagrams waiting on the timer heap. ``tap(direction, data,
    monotonic_s)`` sees every datagram as it arrives, before any fault (tests measure the
    flight from the vehicle's own ODOMETRY this way); it runs on the relay's thread, so keep
    it short. An exception in it is counted (``tap_errors``), never raised.
    """

    def __init__(self, vehicle: Address, *, listen: Address = ("127.0.0.1", 0),
                 bind: Address | None = None, to_vehicle: Faults | None = None,
                 to_daemon: Faults | None = None, seed: int = 0, max_hold_s: float = 0.01,
                 max_pending: int = 100_000,
                 tap: Callable[[str, bytes, float], None] | None = None) -> None:
        if not (math.isfinite(max_hold_s) and max_hold_s > 0):
            raise ValueError(f"max_hold_s: must be > 0 s, got {max_hold_s}")
        self.vehicle = _resolve(vehicle, "vehicle address")
        if bind is None:
            bind = ("127.0.0.1" if self.vehicle[0].startswith("127.") else "0.0.0.0", 0)
        self.faults = {TO_VEHICLE: to_vehicle or Faults(), TO_DAEMON: to_daemon or Faults()}
        self.max_hold_s = max_hold_s
        self.max_pending = max_pending
        self.tap = tap
        self.stats = RelayStats()
        self.daemon: Address | None = None
        self._rng = {d: random.Random(f"{seed}:{d}") for d in (TO_VEHICLE, TO_DAEMON)}
        self._front = _bound_socket(listen, "listen address")
        try:
            self._back = _bound_socket(bind, "bind address")
        except RelayError:
            self._front.close()
            raise
        self._dir_stats = {TO_VEHICLE: self.stats.to_vehicle, TO_DAEMON: self.stats.to_daemon}
        # heap of (due_s, seq, direction, data, received_s); seq keeps FIFO among equal dues
        self._heap: list[tuple[float, int, str, bytes, float]] = []
        self._seq = 0
        # direction → (data, received_s, own due_s) of the datagram held for reordering
        self._held: dict[str, tuple[bytes, float, float] | None] = {TO_VEHICLE: None,
                                                                      TO_DAEMON: None}
        self._last_due = {TO_VEHICLE: 0.0, TO_DAEMON: 0.0}
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._closed = False

    # ------------------------------------------------------------------ lifecycle
    @property
    def listen_address(self) -> Address:
        """Where the daemon should send (``tfl-mav fly --vehicle`` this)."""
        host, port = self._front.getsockname()[:2]
        return host, port

    @property
    def vehicle_side_address(self) -> Address:
        """The address the vehicle sees as its controller."""
        host, port = self._back.getsockname()[:2]
        return host, port

    @property
    def listen_buffer_bytes(self) -> int:
        """The kernel's receive budget of the daemon-side socket (what ``SO_RCVBUF`` reads
        back: the request doubled, capped by ``net.core.rmem_max``). Datagrams arriving
        while it is full are dropped by the kernel, unseen by :class:`RelayStats`."""
        return self._front.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF)

    @property
    def native_thread_id(self) -> int | None:
        """The OS id of the thread :meth:`start` runs the relay on (None before), e.g. to
        raise its scheduling priority."""
        return self._thread.native_id if self._thread is not None else None

    @property
    def pending(self) -> int:
        """Datagrams received but not yet sent or dropped (on the heap or held)."""
        return len(self._heap) + sum(h is not None for h in self._held.values())

    def set_faults(self, *, to_vehicle: Faults | None = None,
                   to_daemon: Faults | None = None) -> None:
        """Change the faults while running (e.g. ``Faults(drop=1.0)`` silences a side).
        Safe from another thread: each direction's Faults is swapped whole."""
        if to_vehicle is not None:
            self.faults[TO_VEHICLE] = to_vehicle
        if to_daemon is not None:
            self.faults[TO_DAEMON] = to_daemon

    def start(self) -> Relay:
        """Run on a background thread until :meth:`stop`/:meth:`close`."""
        if self._thread is None:
            self._thread = threading.Thread(target=self.run, name="relay", daemon=True)
            self._thread.start()
        return self

    def request_stop(self) -> None:
        """Ask :meth:`run` to end soon, without waiting: safe from a signal handler that
        runs on the relay's own thread."""
        self._stop.set()

    def stop(self) -> None:
        """End :meth:`run` soon (within ~50 ms). Safe from a signal handler or thread."""
        self._stop.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=5.0)

    def close(self) -> None:
        self.stop()
        if not self._closed:
            self._closed = True
            self._front.close()
            self._back.close()

    def __enter__(self) -> Relay:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ------------------------------------------------------------------ main loop
    def run(self, duration_s: float = math.inf) -> RelayStats:
        """Relay until :meth:`stop` or ``duration_s`` wall seconds; returns the counters.
        Datagrams still pending at the end are not sent (they count as neither)."""
        end = time.monotonic() + duration_s
        front, back = self._front, self._back
        fds = [front, back]
        heap = self._heap
        while not self._stop.is_set():
            now = time.monotonic()
            if now >= end:
                break
            self._flush(now)
            wait = min(_IDLE_WAIT_S, end - now)
            if heap:
                wait = min(wait, heap[0][0] - now)
            for held in self._held.values():
                if held is not None:
                    wait = min(wait, held[1] + self.max_hold_s - now)
            try:
                ready, _, _ = select.select(fds, [], [], max(0.0, wait))
            except (OSError, ValueError):   # closed under us: the relay is over
                break
            for sock in ready:
                self._drain(sock, front)
        return self.stats

    def _drain(self, sock: socket.socket, front: socket.socket) -> None:
        for _ in range(_BATCH):
            try:
                data, addr = sock.recvfrom(_MAX_DATAGRAM)
            except BlockingIOError:
                return
            except OSError:
                self.stats.recv_errors += 1
                return
            now = time.monotonic()
            addr = (addr[0], addr[1])
            if sock is front:
                if addr != self.daemon:
                    if self.daemon is not None:
                        self.stats.daemon_changes += 1
                    self.daemon = addr
                self._ingest(TO_VEHICLE, data, now)
            elif addr == self.vehicle:
                self._ingest(TO_DAEMON, data, now)
            else:
                self.stats.foreign += 1

    def _ingest(self, direction: str, data: bytes, now: float) -> None:
        """Decide one datagram's fate: drop, or schedule it (and maybe a copy, maybe held)."""
        st = self._dir_stats[direction]
        st.received += 1
        st.received_bytes += len(data)
        if self.tap is not None:
            try:
                self.tap(direction, data, now)
            except Exception:   # a broken observer must not take the link down
                self.stats.tap_errors += 1
        f = self.faults[direction]
        r = self._rng[direction].random
        u_drop, u_dup, u_reorder, u_delay1, u_delay2 = r(), r(), r(), r(), r()
        if u_drop < f.drop:
            st.dropped += 1
            return
        due = now + f.delay_s + u_delay1 * f.jitter_s
        if f.in_order:
            due = self._last_due[direction] = max(due, self._last_due[direction])
        held = self._held[direction]
        if held is not None:
            # This datagram is the successor the held one was waiting for: it goes first.
            self._held[direction] = None
            self._schedule(direction, data, now, due)
            self._schedule(direction, held[0], held[1], max(held[2], due))
        elif u_reorder < f.reorder:
            st.reordered += 1
            self._held[direction] = (data, now, due)
        else:
            self._schedule(direction, data, now, due)
        if u_dup < f.duplicate:
            st.duplicated += 1
            self._schedule(direction, data, now, now + f.delay_s + u_delay2 * f.jitter_s)

    def _schedule(self, direction: str, data: bytes, received_s: float, due_s: float) -> None:
        if due_s <= received_s and not self._heap:
            self._send(direction, data, received_s, time.monotonic())   # fast path: no delay
            return
        if len(self._heap) >= self.max_pending:
            self._dir_stats[direction].overflow += 1
            return
        self._seq += 1
        heapq.heappush(self._heap, (due_s, self._seq, direction, data, received_s))

    def _flush(self, now: float) -> None:
        """Send every datagram that is due, and release holds that waited too long."""
        for direction, held in self._held.items():
            if held is not None and now - held[1] >= self.max_hold_s:
                self._held[direction] = None
                self._dir_stats[direction].hold_expired += 1
                self._seq += 1
                heapq.heappush(self._heap, (max(held[2], now), self._seq, direction, held[0],
                                            held[1]))
        heap = self._heap
        while heap and heap[0][0] <= now:
            _due, _seq, direction, data, received_s = heapq.heappop(heap)
            self._send(direction, data, received_s, now)

    def _send(self, direction: str, data: bytes, received_s: float, now: float) -> None:
        st = self._dir_stats[direction]
        if direction == TO_VEHICLE:
            sock, dest = self._back, self.vehicle
        else:
            sock, dest = self._front, self.daemon
            if dest is None:
                st.no_destination += 1
                return
        try:
            sock.sendto(data, dest)
        except OSError:
            st.send_errors += 1
            return
        st.forwarded += 1
        st.forwarded_bytes += len(data)
        latency = now - received_s
        st.latency_sum_s += latency
        st.latency_min_s = min(st.latency_min_s, latency)
        st.latency_max_s = max(st.latency_max_s, latency)


def _resolve(address: Address, field: str) -> Address:
    host, port = address
    try:
        infos = socket.getaddrinfo(host, port, socket.AF_INET, socket.SOCK_DGRAM)
    except socket.gaierror as exc:
        raise RelayError(f"{field}: cannot resolve host {host!r} ({exc.strerror})") from None
    ip, resolved_port = infos[0][4][:2]
    return ip, resolved_port


def _bound_socket(address: Address, field: str) -> socket.socket:
    host, port = _resolve(address, field)
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        sock.bind((host, port))
    except OSError as exc:
        sock.close()
        raise RelayError(f"cannot bind UDP {host}:{port} ({field}): {exc.strerror}") from None
    for opt in (socket.SO_RCVBUF, socket.SO_SNDBUF):
        # The OS default still works if refused, just with less slack for bursts.
        with contextlib.suppress(OSError):
            sock.setsockopt(socket.SOL_SOCKET, opt, _SOCKET_BUFFER_BYTES)
    sock.setblocking(False)
    return sock
