"""JSON Schemas of the decoded MAVLink channels, and the description of a caller's record.

* ``mavlink.<MSG>`` (MCAP ``jsonschema`` encoding): one schema per MAVLink message type,
  generated from pymavlink's field metadata (``fieldnames``, ``fieldtypes``,
  ``array_lengths``, units, enums). ``char[N]`` is a string; integers carry their C range.
* :func:`record_schema`: a caller's own record (the controller's state) described in JSON
  Schema terms; the recorder writes it as protobuf made from that description
  (:class:`~tfl_mav.flightlog.protos.RecordEncoder`).

Raw frames and the simulator's truth are protobuf (:mod:`tfl_mav.flightlog.protos`), the
Foxglove well-known types (``/tf``, the scene, ``/log``) from Foxglove's own SDK
(:mod:`tfl_mav.flightlog.foxglove`).

NaN/inf in a decoded MAVLink message: JSON has no such numbers, and Foxglove's JSON-schema
reader accepts one plain ``type`` per property (no ``["number", "null"]``, no property
without ``type``; see its ``parseJsonSchema``). So a float that is not finite, or an array
holding one, is *left out* of the message and its key listed in ``_nonfinite``; float
fields are therefore optional, everything else is required. The raw frame keeps the wire value.

Schemas are plain dicts; :func:`schema_bytes` is what goes into the file.
"""

from __future__ import annotations

import json
from functools import cache
from typing import Any

from tfl_mav.link.dialect import mav

__all__ = [
    "NONFINITE_KEY",
    "mavlink_schema",
    "mavlink_schema_name",
    "record_schema",
    "schema_bytes",
    "vec",
]

Schema = dict[str, Any]

# ---------------------------------------------------------------- building blocks
NONFINITE_KEY = "_nonfinite"
_NONFINITE: Schema = {"type": "array", "items": {"type": "string"},
                      "description": "keys left out because they held NaN, inf or null"}
_INT_RANGES = {
    "uint8_t": (0, 2**8 - 1), "int8_t": (-(2**7), 2**7 - 1),
    "uint16_t": (0, 2**16 - 1), "int16_t": (-(2**15), 2**15 - 1),
    "uint32_t": (0, 2**32 - 1), "int32_t": (-(2**31), 2**31 - 1),
    "uint64_t": (0, 2**64 - 1), "int64_t": (-(2**63), 2**63 - 1),
}


def _num(description: str) -> Schema:
    return {"type": "number", "description": description}


def _obj(title: str, description: str, properties: dict[str, Schema],
         required: list[str] | None = None) -> Schema:
    return {"title": title, "description": description, "type": "object",
            "properties": properties,
            "required": list(properties) if required is None else required}


def _array(items: Schema, description: str, length: int | None = None) -> Schema:
    out: Schema = {"type": "array", "items": items, "description": description}
    if length is not None:
        out["minItems"] = out["maxItems"] = length
    return out


# ---------------------------------------------------------------- a caller's records
_T_S = {"type": "number", "description": "sim time (s)"}


def _project(title: str, description: str, properties: dict[str, Schema],
             required: list[str]) -> Schema:
    return _obj(title, description, {**properties, NONFINITE_KEY: _NONFINITE}, required)


def record_schema(title: str, description: str, properties: dict[str, Schema],
                  required: list[str]) -> Schema:
    """A caller's own record described as a JSON Schema (e.g. the controller's
    ``/controller/state``), with the ``t_s`` the recorder adds (``_nonfinite`` is kept for
    a JSON reader of it; the protobuf record carries NaN as it is)."""
    return _project(title, description, {"t_s": _T_S, **properties}, ["t_s", *required])


def vec(n: int | None, description: str) -> Schema:
    """An array of ``n`` numbers (any length if None)."""
    return _array({"type": "number"}, description, n)


# ---------------------------------------------------------------- MAVLink messages
def mavlink_schema_name(msg_name: str) -> str:
    return f"mavlink.{msg_name}"


def _field_schema(ctype: str, length: int, unit: str, enum: str) -> Schema:
    notes = [f"{ctype}[{length}]" if length else ctype]
    if unit:
        notes.append(f"unit {unit}")
    if enum:
        notes.append(f"enum {enum}")
    description = ", ".join(notes)
    if ctype == "char":
        return {"type": "string", "maxLength": max(length, 1), "description": description}
    if ctype in ("float", "double"):
        item: Schema = {"type": "number"}
    else:
        lo, hi = _INT_RANGES[ctype]
        item = {"type": "integer", "minimum": lo, "maximum": hi}
    if length:
        return _array(item, description, length)
    return {**item, "description": description}


@cache
def mavlink_schema(msg_id: int) -> Schema:
    """The JSON Schema of decoded message ``msg_id`` (fields in pymavlink's display order)."""
    cls = mav.mavlink_map[msg_id]
    lengths = dict(zip(cls.ordered_fieldnames, cls.array_lengths, strict=True))
    props = {
        name: _field_schema(ctype, lengths[name], cls.fieldunits_by_name.get(name, ""),
                            cls.fieldenums_by_name.get(name, ""))
        for name, ctype in zip(cls.fieldnames, cls.fieldtypes, strict=True)}
    required = [n for n, t in zip(cls.fieldnames, cls.fieldtypes, strict=True)
                if t not in ("float", "double")]
    return _obj(mavlink_schema_name(cls.msgname),
                f"MAVLink message #{cls.id} {cls.msgname} (pymavlink ardupilotmega dialect)",
                {**props, NONFINITE_KEY: _NONFINITE}, required)


def schema_bytes(schema: Schema) -> bytes:
    return json.dumps(schema, separators=(",", ":")).encode()
