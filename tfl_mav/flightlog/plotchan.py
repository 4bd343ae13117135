"""Plot channels: numbers a person plots, in an encoding every viewer reads without a script.

Each ``/plot/...`` channel carries one ROS 2 ``std_msgs/msg/Float64MultiArray`` per sample
(CDR, schema encoding ``ros2msg``): Rerun's MCAP importer turns that type into
``Scalars`` (a time series per value), Foxglove and PlotJuggler read ROS 2 messages in MCAP
natively (``.data[0]``…). The protobuf records (truth, controller) stay the complete
record; Rerun imports those as structs, not time series, which is why these exist. The array's one
dimension is labelled with the values' names (``x_m,y_m,z_m``), so a reader sees what
``data[i]`` is. Written at the scene rate (≤ 50 Hz of sim time), the rate a person looks
at.

CDR as ROS 2 writes it (XCDR1, little endian): the 4-byte encapsulation header
``00 01 00 00``, then each field aligned to its size from the end of that header; a string
is a uint32 length (with its NUL) and the bytes; a sequence a uint32 count and the items.
"""

from __future__ import annotations

import struct
from collections.abc import Callable, Sequence

__all__ = ["FLOAT64_MULTI_ARRAY", "SCHEMA_ENCODING", "SCHEMA_TEXT", "encode", "labels"]

FLOAT64_MULTI_ARRAY = "std_msgs/msg/Float64MultiArray"
SCHEMA_ENCODING = "ros2msg"
MESSAGE_ENCODING = "cdr"
# The MCAP ros2msg schema: the type's .msg text, then each dependency after a separator line.
SCHEMA_TEXT = "\n".join([
    "# This was originally provided as an example message.",
    "MultiArrayLayout  layout",
    "float64[]         data",
    "=" * 80,
    "MSG: std_msgs/MultiArrayLayout",
    "MultiArrayDimension[] dim",
    "uint32 data_offset",
    "=" * 80,
    "MSG: std_msgs/MultiArrayDimension",
    "string label",
    "uint32 size",
    "uint32 stride",
    ""]).encode()

_HEADER = b"\x00\x01\x00\x00"


def labels(names: Sequence[str]) -> bytes:
    """The message bytes before the values, for one dimension labelled ``names`` (the part
    that is the same in every sample of a channel), padded so the float64 values that
    follow are aligned to 8 from the end of the encapsulation header."""
    label = ",".join(names).encode() + b"\x00"
    n = len(names)
    body = struct.pack("<II", 1, len(label)) + label        # dim: 1 entry; its label
    body += b"\x00" * (-len(body) % 4)                       # size: aligned to 4
    body += struct.pack("<IIII", n, n, 0, n)                 # size, stride, data_offset, count
    body += b"\x00" * (-len(body) % 8)
    return _HEADER + body


_PACK: dict[int, Callable[..., bytes]] = {}


def encode(head: bytes, values: Sequence[float]) -> bytes:
    """A Float64MultiArray: ``head`` (from :func:`labels`, for ``len(values)`` names), then
    the values as float64."""
    n = len(values)
    pack = _PACK.get(n)
    if pack is None:
        pack = _PACK[n] = struct.Struct(f"<{n}d").pack
    return head + pack(*values)
