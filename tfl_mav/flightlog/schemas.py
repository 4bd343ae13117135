"""JSON Schemas of every channel the recorder writes (MCAP ``jsonschema`` encoding).

Three families, all written by the project (docs/design.md, "The flight log"):

* ``mavlink.<MSG>``: one schema per MAVLink message type, generated from pymavlink's field
  metadata (``fieldnames``, ``fieldtypes``, ``array_lengths``, units, enums). ``char[N]`` is
  a string; integers carry their C range.
* ``foxglove.FrameTransform``, ``foxglove.SceneUpdate``, ``foxglove.Log``: Foxglove's
  well-known types, fully inlined the way Foxglove's own JSON schemas are, so its panels
  recognise the channels by schema name.
* ``tfl_mav.*``: raw wire frames, simulator ground truth, controller state.

NaN/inf: JSON has no such numbers, and Foxglove's JSON-schema reader accepts one plain
``type`` per property (no ``["number", "null"]``, no property without ``type``; see its
``parseJsonSchema``). So a float that is not finite, or an array holding one, is *left out*
of the message and its key listed in ``_nonfinite``; float fields are therefore optional,
everything else is required. The raw frame keeps the wire value.

Schemas are plain dicts; :func:`schema_bytes` is what goes into the file.
"""

from __future__ import annotations

import json
from functools import cache
from typing import Any

from tfl_mav.link.dialect import mav

__all__ = [
    "CONTROLLER_STATE",
    "FOXGLOVE_SCHEMAS",
    "NONFINITE_KEY",
    "PATH_DISTANCE",
    "RAW_FRAME",
    "TRUTH_ATTACK",
    "TRUTH_STATE",
    "TRUTH_THRUSTS",
    "mavlink_schema",
    "mavlink_schema_name",
    "schema_bytes",
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


def _time(description: str) -> Schema:
    return {"type": "object", "title": "time", "description": description,
            "properties": {"sec": {"type": "integer", "minimum": 0},
                           "nsec": {"type": "integer", "minimum": 0, "maximum": 999_999_999}}}


def _duration(description: str) -> Schema:
    return {"type": "object", "title": "duration", "description": description,
            "properties": {"sec": {"type": "integer"},
                           "nsec": {"type": "integer", "minimum": 0, "maximum": 999_999_999}}}


def _vector3(description: str) -> Schema:
    return _obj("foxglove.Vector3", description,
                {a: _num(f"{a} coordinate length") for a in "xyz"})


def _point3(description: str = "A point representing a position in 3D space") -> Schema:
    return _obj("foxglove.Point3", description,
                {a: _num(f"{a} coordinate position") for a in "xyz"})


def _quaternion(description: str) -> Schema:
    return _obj("foxglove.Quaternion", description, {a: _num(f"{a} value") for a in "xyzw"})


def _pose(description: str) -> Schema:
    return _obj("foxglove.Pose", description, {
        "position": _vector3("Point denoting position in 3D space"),
        "orientation": _quaternion("Quaternion denoting orientation in 3D space")})


def _color(description: str) -> Schema:
    names = {"r": "Red", "g": "Green", "b": "Blue", "a": "Alpha"}
    return _obj("foxglove.Color", description,
                {k: _num(f"{v} value between 0 and 1") for k, v in names.items()})


def _enum(title: str, description: str, values: list[tuple[str, int, str]]) -> Schema:
    return {"title": title, "description": description,
            "oneOf": [{"title": n, "const": v, "description": d} for n, v, d in values]}


def _indices() -> Schema:
    return _array({"type": "integer", "minimum": 0},
                  "Indices into the `points` and `colors` attribute arrays")


# ---------------------------------------------------------------- Foxglove well-known types
def _scene_entity() -> Schema:
    pose = _pose
    primitives: dict[str, Schema] = {
        "arrows": _obj("foxglove.ArrowPrimitive", "A primitive representing an arrow", {
            "pose": pose("Position of the arrow's tail and orientation of the arrow"),
            "shaft_length": _num("Length of the arrow shaft"),
            "shaft_diameter": _num("Diameter of the arrow shaft"),
            "head_length": _num("Length of the arrow head"),
            "head_diameter": _num("Diameter of the arrow head"),
            "color": _color("Color of the arrow")}),
        "cubes": _obj("foxglove.CubePrimitive", "A primitive representing a cube or "
                      "rectangular prism", {
                          "pose": pose("Position of the center of the cube and its orientation"),
                          "size": _vector3("Size of the cube along each axis"),
                          "color": _color("Color of the cube")}),
        "spheres": _obj("foxglove.SpherePrimitive", "A primitive representing a sphere or "
                        "ellipsoid", {
                            "pose": pose("Position of the center of the sphere"),
                            "size": _vector3("Size (diameter) of the sphere along each axis"),
                            "color": _color("Color of the sphere")}),
        "cylinders": _obj("foxglove.CylinderPrimitive", "A primitive representing a cylinder, "
                          "elliptic cylinder, or truncated cone", {
                              "pose": pose("Center of the cylinder; flat faces normal to z"),
                              "size": _vector3("Size of the cylinder's bounding box"),
                              "bottom_scale": _num("0-1, ratio of the bottom face diameter"),
                              "top_scale": _num("0-1, ratio of the top face diameter"),
                              "color": _color("Color of the cylinder")}),
        "lines": _obj("foxglove.LinePrimitive", "A primitive representing a series of points "
                      "connected by lines", {
                          "type": _enum("foxglove.LineType", "Drawing primitive to use for lines",
                                        [("LINE_STRIP", 0, "Connected line segments"),
                                         ("LINE_LOOP", 1, "Closed polygon"),
                                         ("LINE_LIST", 2, "Individual line segments")]),
                          "pose": pose("Origin of lines relative to reference frame"),
                          "thickness": _num("Line thickness"),
                          "scale_invariant": {"type": "boolean", "description":
                                              "thickness in screen pixels (true) or world units"},
                          "points": _array(_point3(), "Points along the line"),
                          "color": _color("Solid color for the whole line"),
                          "colors": _array(_color("A color in RGBA format"), "Per-point colors"),
                          "indices": _indices()}),
        "triangles": _obj("foxglove.TriangleListPrimitive", "A primitive representing a set "
                          "of triangles or a surface tiled by triangles", {
                              "pose": pose("Origin of triangles relative to reference frame"),
                              "points": _array(_point3(), "Vertices, as triples"),
                              "color": _color("Solid color for the whole shape"),
                              "colors": _array(_color("A color in RGBA format"),
                                               "Per-vertex colors"),
                              "indices": _indices()}),
        "texts": _obj("foxglove.TextPrimitive", "A primitive representing a text label", {
            "pose": pose("Position of the center of the text box"),
            "billboard": {"type": "boolean", "description": "Always face the camera"},
            "font_size": _num("Font size (height of one line of text)"),
            "scale_invariant": {"type": "boolean", "description": "font_size in pixels"},
            "color": _color("Color of the text"),
            "text": {"type": "string", "description": "Text"}}),
        "models": _obj("foxglove.ModelPrimitive", "A primitive representing a 3D model file", {
            "pose": pose("Origin of model relative to reference frame"),
            "scale": _vector3("Scale factor to apply to the model along each axis"),
            "color": _color("Solid color if override_color is true"),
            "override_color": {"type": "boolean", "description": "Use color, not materials"},
            "url": {"type": "string", "description": "URL pointing to model file"},
            "media_type": {"type": "string", "description": "Media type of embedded model"},
            "data": {"type": "string", "contentEncoding": "base64",
                     "description": "Embedded model"}}),
    }
    props: dict[str, Schema] = {
        "timestamp": _time("Timestamp of the entity"),
        "frame_id": {"type": "string", "description": "Frame of reference"},
        "id": {"type": "string", "description": "Identifier for the entity; replaces any "
               "prior entity on the same topic with the same id"},
        "lifetime": _duration("Time after which the entity is removed; zero = never"),
        "frame_locked": {"type": "boolean", "description": "Follow frame_id as it moves"},
        "metadata": _array(_obj("foxglove.KeyValuePair", "A key with its associated value", {
            "key": {"type": "string", "description": "Key"},
            "value": {"type": "string", "description": "Value"}}), "Additional metadata"),
    }
    for name, item in primitives.items():
        props[name] = _array(item, f"{name.capitalize()} primitives")
    return _obj("foxglove.SceneEntity", "A visual element in a 3D scene", props)


def _scene_update() -> Schema:
    deletion = _obj("foxglove.SceneEntityDeletion", "Command to remove published entities", {
        "timestamp": _time("Only matching entities earlier than this are deleted"),
        "type": _enum("foxglove.SceneEntityDeletionType", "Type of deletion action",
                      [("MATCHING_ID", 0, "Delete the entity with the provided id"),
                       ("ALL", 1, "Delete all existing entities on the same topic")]),
        "id": {"type": "string", "description": "Identifier which must match for MATCHING_ID"}})
    return _obj("foxglove.SceneUpdate", "An update to the entities displayed in a 3D scene", {
        "deletions": _array(deletion, "Scene entities to delete"),
        "entities": _array(_scene_entity(), "Scene entities to add or replace")})


def _frame_transform() -> Schema:
    return _obj("foxglove.FrameTransform", "A transform between two reference frames in 3D "
                "space: the pose of the child frame in the parent frame", {
                    "timestamp": _time("Timestamp of transform"),
                    "parent_frame_id": {"type": "string", "description": "Parent frame"},
                    "child_frame_id": {"type": "string", "description": "Child frame"},
                    "translation": _vector3("Child frame origin in the parent frame"),
                    "rotation": _quaternion("Child frame orientation in the parent frame")})


def _log() -> Schema:
    return _obj("foxglove.Log", "A log message", {
        "timestamp": _time("Timestamp of log message"),
        "level": _enum("foxglove.LogLevel", "Log level",
                       [("UNKNOWN", 0, "Unknown log level"), ("DEBUG", 1, "Debug log level"),
                        ("INFO", 2, "Info log level"), ("WARNING", 3, "Warning log level"),
                        ("ERROR", 4, "Error log level"), ("FATAL", 5, "Fatal log level")]),
        "message": {"type": "string", "description": "Log message"},
        "name": {"type": "string", "description": "Process or node name"},
        "file": {"type": "string", "description": "Filename"},
        "line": {"type": "integer", "minimum": 0, "description": "Line number in the file"}})


FOXGLOVE_SCHEMAS: dict[str, Schema] = {
    "foxglove.FrameTransform": _frame_transform(),
    "foxglove.SceneUpdate": _scene_update(),
    "foxglove.Log": _log(),
}

# ---------------------------------------------------------------- project channels
_T_S = {"type": "number", "description": "sim time (s)"}


def _vec(n: int, description: str) -> Schema:
    return _array({"type": "number"}, description, n)


def _project(title: str, description: str, properties: dict[str, Schema],
             required: list[str]) -> Schema:
    return _obj(title, description, {**properties, NONFINITE_KEY: _NONFINITE}, required)


RAW_FRAME: Schema = _obj(
    "tfl_mav.MavlinkFrame", "One MAVLink frame exactly as it crossed the wire; name, msgid, "
    "sysid, compid and seq are present when the frame was decoded", {
        "direction": {"type": "string", "enum": ["rx", "tx"],
                      "description": "received or sent by the recording process"},
        "accepted": {"type": "boolean", "description": "rx: the link decoded and accepted it; "
                     "tx: it was sent"},
        "name": {"type": "string", "description": "message name"},
        "msgid": {"type": "integer", "minimum": 0},
        "sysid": {"type": "integer", "minimum": 0, "maximum": 255},
        "compid": {"type": "integer", "minimum": 0, "maximum": 255},
        "seq": {"type": "integer", "minimum": 0, "maximum": 255},
        "len": {"type": "integer", "minimum": 0, "description": "wire bytes"},
        "data": {"type": "string", "contentEncoding": "base64",
                 "description": "the wire bytes, base64 (replayable byte for byte)"}},
    ["direction", "accepted", "len", "data"])

TRUTH_STATE: Schema = _project(
    "tfl_mav.TruthState", "True rigid-body state from the simulator, paper frame "
    "(ENU, z up; body b3 along thrust)", {
        "t_s": _T_S,
        "position_m": _vec(3, "position x_q (m)"),
        "velocity_mps": _vec(3, "velocity v_q (m/s)"),
        "quaternion_wxyz": _vec(4, "attitude, body to world (w, x, y, z)"),
        "body_rates_radps": _vec(3, "body rates (p, q, r) (rad/s)")}, ["t_s"])

TRUTH_ATTACK: Schema = _project(
    "tfl_mav.TruthAttack", "The attack as the simulator applies it", {
        "t_s": _T_S,
        "rotor": {"type": "integer", "minimum": 0, "maximum": 4,
                  "description": "attacked rotor 1-4, 0 = none"},
        "active": {"type": "boolean"},
        "applied_n": {"type": "number", "description": "thrust forced on the rotor (N), "
                      "clamped to [0, f_max]"},
        "requested_n": {"type": "number", "description": "what the attack signal asked "
                        "for (N)"}}, ["t_s", "rotor", "active"])

TRUTH_THRUSTS: Schema = _project(
    "tfl_mav.TruthThrusts", "True rotor thrusts (N), rotors 1-4 in the paper's + layout", {
        "t_s": _T_S,
        "thrust_n": _vec(4, "true thrust of rotors 1-4 (N)"),
        "attack_rotor": {"type": "integer", "minimum": 0, "maximum": 4}},
    ["t_s", "attack_rotor"])

PATH_DISTANCE: Schema = _project(
    "tfl_mav.PathDistance", "Distance from the true position to the recorded path polyline", {
        "t_s": _T_S,
        "distance_m": {"type": "number", "description": "distance to the polyline given to "
                       "Recorder.path (m)"}}, ["t_s"])

CONTROLLER_STATE: Schema = _project(
    "tfl_mav.ControllerState", "Controller state at sim time t_s; the keys below are the "
    "ones the tools and the layout read, any other key may be added", {
        "t_s": _T_S,
        "mode": {"type": "string", "description": "nominal, attacked or failsafe"},
        "detected_rotor": {"type": "integer", "minimum": 0, "maximum": 4,
                           "description": "rotor the detector isolated, 0 = none"},
        "attack_estimate_n": {"type": "number", "description": "estimated attack thrust (N)"},
        "path_distance_m": {"type": "number", "description": "distance to the path (m)"},
        "saturated": {"type": "boolean", "description": "a rotor command hit 0 or f_max"},
        "rotor_thrust_cmd_n": _array({"type": "number"}, "rotor thrust commands 1-4 (N)")},
    ["t_s"])


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
