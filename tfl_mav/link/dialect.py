"""The one MAVLink dialect of the project, imported once, explicitly.

``pymavlink.dialects.v20.ardupilotmega`` is a superset of ``common`` that also carries
``ESC_TELEMETRY_1_TO_4`` (pymavlink 2.4.50). Importing the dialect module directly, instead
of going through ``mavutil``, avoids its process-wide choice of dialect and wire version made from
environment variables at import time: everything here speaks MAVLink 2.
"""

from __future__ import annotations

from pymavlink.dialects.v20 import ardupilotmega as mav

__all__ = ["MAVLink", "MAVLinkMessage", "mav", "new_mavlink"]

MAVLink = mav.MAVLink
MAVLinkMessage = mav.MAVLink_message


def new_mavlink(sysid: int, compid: int) -> mav.MAVLink:
    """A packer/parser with no file attached; the caller owns the socket.

    ``sysid``/``compid`` (1-255) become the source ids of every frame it packs. Not
    thread-safe: packing mutates the sequence number (and, later, signing timestamps).
    """
    if not 1 <= sysid <= 255:
        raise ValueError(f"sysid: must be 1-255, got {sysid}")
    if not 0 <= compid <= 255:
        raise ValueError(f"compid: must be 0-255, got {compid}")
    return mav.MAVLink(None, srcSystem=sysid, srcComponent=compid)
