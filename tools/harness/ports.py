"""Free loopback ports for tests and benchmarks.

Most endpoints bind port 0 and report the port they got (``tfl-mav sim`` prints it), which
is race-free. A few must be told a fixed address in advance (a restartable daemon's
``--bind``, a vehicle restarted on the same port); for those, :func:`free_udp_port` gives a
port that was free a moment ago. Another process can take it in between: callers that
bind it retry (see :func:`tfl_mav.tools.harness.processes.start_sim_on`).
"""

from __future__ import annotations

import socket

from tfl_mav.link.transport import Address

__all__ = ["LOOPBACK", "free_udp_address", "free_udp_port"]

LOOPBACK: Address = ("127.0.0.1", 0)
"""Bind here for "any free loopback port"."""


def free_udp_port(host: str = "127.0.0.1") -> int:
    """A UDP port on ``host`` that was free a moment ago."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind((host, 0))
        return s.getsockname()[1]


def free_udp_address(host: str = "127.0.0.1") -> Address:
    """``(host, port)`` of a UDP port that was free a moment ago."""
    return host, free_udp_port(host)
