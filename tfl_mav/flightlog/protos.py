"""The recorder's own protobuf messages: schemas (``FileDescriptorSet``) and encoders.

Why protobuf: a per-tick record of float64 values is 8 bytes a value, where JSON printed
~18 characters (and a reader had to parse text); every MCAP viewer (Foxglove, PlotJuggler,
Rerun) and ``protoc`` reads protobuf from the schema stored in the file, and the fields
keep the names the JSON had (``/sim/truth/state.position_m[0]`` is the same message path).

Messages (proto2, so a left-out field is *absent*, not 0; repeated numbers packed):

* ``tfl_mav.MavlinkFrames``: the frames of one datagram: ``frames`` (each one's wire
  bytes), ``tx`` (sent by the recording process; absent: received), ``rejected`` (the
  indexes in ``frames`` of received frames the link refused);
* ``tfl_mav.TruthState`` (one a tick: the rigid body, the true rotor thrusts, the attack as
  applied), ``tfl_mav.PathDistance``: simulator ground truth (units in the field names);
* a caller's record (the controller's ``/controller/state``) from its JSON-Schema-like
  description (:func:`~tfl_mav.flightlog.schemas.record_schema`): ``number`` → double,
  ``integer`` → sint64, ``boolean`` → bool, ``string`` → string, an array of numbers →
  packed repeated double, a property without a type (numbers nested in lists, e.g. ξ) →
  repeated ``tfl_mav.Doubles`` (one per inner list); a free key of a mapping record holding
  a mapping → its JSON text (a string; NaN/inf as null).

NaN and inf are plain doubles here (nothing is left out); None is an absent field.

Encoding is the protobuf wire format written with :mod:`struct` (the layouts are fixed: one
``pack`` per truth message, a few per record, no message objects built on the loop's
ticks); reading uses the ``protobuf`` library on the schema in the file
(:func:`message_class`), so a writer bug cannot hide behind a matching hand-written reader.
"""

from __future__ import annotations

import struct
from collections.abc import Callable, Mapping, Sequence
from functools import cache
from typing import Any

from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

__all__ = ["FRAMES", "PATH_DISTANCE", "TRUTH_STATE", "TRUTH_WIND",
           "RecordEncoder", "frames", "frames_fields", "message_class", "schema", "to_dict"]

PACKAGE = "tfl_mav"
FRAMES, TRUTH_STATE, PATH_DISTANCE, TRUTH_WIND = (
    f"{PACKAGE}.{n}" for n in ("MavlinkFrames", "TruthState", "PathDistance", "TruthWind"))

_F = descriptor_pb2.FieldDescriptorProto
_TYPES = {"double": _F.TYPE_DOUBLE, "sint64": _F.TYPE_SINT64, "uint32": _F.TYPE_UINT32,
          "bool": _F.TYPE_BOOL, "string": _F.TYPE_STRING, "bytes": _F.TYPE_BYTES,
          "doubles": _F.TYPE_DOUBLE, "nested": _F.TYPE_MESSAGE, "json": _F.TYPE_STRING,
          "byteses": _F.TYPE_BYTES, "uint32s": _F.TYPE_UINT32}
_WIRE = {"double": 1, "doubles": 2, "sint64": 0, "uint32": 0, "bool": 0, "string": 2,
         "bytes": 2, "nested": 2, "json": 2}
_REPEATED = ("doubles", "nested", "byteses", "uint32s")
_PACKED_KINDS = ("doubles", "uint32s")

# (name, kind) in field-number order (1, 2, ...); kinds as _TYPES
_FIXED: dict[str, tuple[str, tuple[tuple[str, str, str], ...]]] = {
    FRAMES: ("The MAVLink frames of one datagram exactly as they crossed the wire "
             "(replayable byte for byte)", (
                 ("frames", "byteses", "each frame's wire bytes (MAVLink 2, CRC and any "
                                       "signature)"),
                 ("tx", "bool", "sent by the recording process; absent: received"),
                 ("rejected", "uint32s", "indexes in frames of received frames the link "
                                         "refused (not decoded)"))),
    TRUTH_STATE: ("The simulator's truth at one tick: rigid-body state (world frame ENU, z "
                  "up; body frame x forward, z along thrust), true rotor thrusts, the attack "
                  "as applied", (
                      ("t_s", "double", "sim time (s)"),
                      ("position_m", "doubles", "position x_q (m), 3 values"),
                      ("velocity_mps", "doubles", "velocity v_q (m/s), 3 values"),
                      ("quaternion_wxyz", "doubles", "attitude body → world (w, x, y, z)"),
                      ("body_rates_radps", "doubles", "body rates (p, q, r) (rad/s)"),
                      ("thrust_n", "doubles", "true thrust of rotors 1-4 (N)"),
                      ("attack_rotor", "uint32", "attacked rotor 1-4, 0 = none"),
                      ("attack_applied_n", "double", "thrust forced on the rotor (N), "
                                                     "clamped to [0, f_max]"),
                      ("attack_requested_n", "double", "what the attack signal asked for "
                                                       "(N)"))),
    TRUTH_WIND: ("The air the simulator's vehicle flies in at one tick: the wind (mean, "
                 "Dryden turbulence and gust) its aerodynamic forces act against", (
                     ("t_s", "double", "sim time (s)"),
                     ("wind_mps", "doubles", "air velocity, world frame ENU z up (m/s), "
                                             "3 values"))),
    PATH_DISTANCE: ("Distance from the true position to the recorded path polyline", (
        ("t_s", "double", "sim time (s)"),
        ("distance_m", "double", "distance to the polyline given to Recorder.path (m)"))),
}
_DOUBLES = f"{PACKAGE}.Doubles"


def _message(name: str, fields: Sequence[tuple[str, str, str]]) -> descriptor_pb2.DescriptorProto:
    msg = descriptor_pb2.DescriptorProto(name=name.rsplit(".", 1)[-1])
    for number, (fname, kind, _doc) in enumerate(fields, 1):
        f = msg.field.add(name=fname, number=number, type=_TYPES[kind],
                          label=_F.LABEL_REPEATED if kind in _REPEATED else _F.LABEL_OPTIONAL)
        if kind in _PACKED_KINDS:
            f.options.packed = True
        elif kind == "nested":
            f.type_name = f".{_DOUBLES}"
    return msg


def _file(name: str, fields: Sequence[tuple[str, str, str]]) -> bytes:
    """The ``FileDescriptorSet`` of message ``name`` (and ``tfl_mav.Doubles``)."""
    fd = descriptor_pb2.FileDescriptorProto(name=f"{name}.proto", package=PACKAGE,
                                            syntax="proto2")
    fd.message_type.append(_message(name, fields))
    if any(kind == "nested" for _, kind, _ in fields):
        fd.message_type.append(_message(_DOUBLES, (("values", "doubles", ""),)))
    return descriptor_pb2.FileDescriptorSet(file=[fd]).SerializeToString()


@cache
def schema(name: str) -> tuple[str, str, bytes]:
    """(name, encoding, data) of one of the fixed messages (``FRAME``, ``TRUTH_*``, ...)."""
    return name, "protobuf", _file(name, _FIXED[name][1])


@cache
def message_class(name: str, data: bytes) -> Any:
    """The protobuf message class of ``name`` from a file's schema ``data`` (a reader's)."""
    pool = descriptor_pool.DescriptorPool()
    for fd in descriptor_pb2.FileDescriptorSet.FromString(data).file:
        pool.Add(fd)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(name))


def to_dict(msg: Any) -> dict[str, Any]:
    """A parsed message as plain values: set fields only, repeated as lists, nested
    ``Doubles`` as lists of floats (other nested messages as dicts)."""
    plan = _PLANS.get(msg.DESCRIPTOR)
    if plan is None:
        plan = _PLANS[msg.DESCRIPTOR] = {
            fd: (fd.name, (3 if [f.name for f in fd.message_type.fields] == ["values"]
                           else 2) if fd.message_type is not None else int(fd.is_repeated))
            for fd in msg.DESCRIPTOR.fields}
    out: dict[str, Any] = {}
    for fd, value in msg.ListFields():
        name, kind = plan[fd]
        if kind == 0:
            out[name] = value
        elif kind == 1:
            out[name] = list(value)
        elif kind == 3:
            out[name] = [list(v.values) for v in value] if fd.is_repeated \
                else list(value.values)
        else:
            out[name] = [to_dict(v) for v in value] if fd.is_repeated else to_dict(value)
    return out


_PLANS: dict[Any, dict[Any, tuple[str, int]]] = {}


# ---------------------------------------------------------------- writing
def _varint(n: int) -> bytes:
    out = bytearray()
    while n > 0x7F:
        out.append(n & 0x7F | 0x80)
        n >>= 7
    out.append(n)
    return bytes(out)


def _tag(number: int, wire: int) -> bytes:
    return _varint(number << 3 | wire)


_DATA, _TX, _REJECTED = _tag(1, 2), _tag(2, 0) + b"\x01", _tag(3, 2)
_LEN1 = [bytes([n]) for n in range(128)]


def frames(raws: Sequence[bytes], tx: bool, rejected: Sequence[int] = ()) -> bytes:
    """A ``tfl_mav.MavlinkFrames``: one datagram's frames, sent or received, and the
    indexes of those the link refused."""
    out = b"".join([_DATA + (_LEN1[len(r)] if len(r) < 128 else _varint(len(r))) + r
                    for r in raws])
    if tx:
        out += _TX
    if rejected:
        body = b"".join(map(_varint, rejected))
        out += _REJECTED + _len(len(body)) + body
    return out


def _read_varint(data: bytes, at: int) -> tuple[int, int]:
    n = shift = 0
    while True:
        b = data[at]
        at += 1
        n |= (b & 0x7F) << shift
        if not b & 0x80:
            return n, at
        shift += 7


def frames_fields(data: bytes) -> tuple[list[bytes], bool, list[int]] | None:
    """(frames, tx, rejected indexes) of a ``tfl_mav.MavlinkFrames`` as :func:`frames`
    writes it (a reader's shortcut past the library for the ~1000 datagrams a second of
    flight); None for any other layout (then decode it with the library)."""
    raws: list[bytes] = []
    at, end = 0, len(data)
    try:
        while at < end and data[at] == 0x0A:
            n, at = _read_varint(data, at + 1)
            raws.append(data[at:at + n])
            at += n
        tx = data[at:at + 2] == _TX
        if tx:
            at += 2
        rejected: list[int] = []
        if at < end and data[at] == 0x1A:
            n, at = _read_varint(data, at + 1)
            stop = at + n
            while at < stop:
                i, at = _read_varint(data, at)
                rejected.append(i)
    except IndexError:
        return None
    if at != end:
        return None
    return raws, tx, rejected


_TRUTH = struct.Struct("<Bd" + "BB3d" + "BB3d" + "BB4d" + "BB3d" + "BB4d" + "BB" + "Bd" + "Bd").pack
_PATH = struct.Struct("<BdBd").pack


def truth_state(t: float, p: Sequence[float], v: Sequence[float], q: Sequence[float],
                w: Sequence[float], thrust_n: Sequence[float], attack_rotor: int,
                attack_applied_n: float, attack_requested_n: float) -> bytes:
    """A ``tfl_mav.TruthState`` (one ``struct`` pack: the tags and lengths are constants)."""
    return _TRUTH(0x09, t, 0x12, 24, *p, 0x1A, 24, *v, 0x22, 32, *q, 0x2A, 24, *w,
                  0x32, 32, *thrust_n, 0x38, attack_rotor, 0x41, attack_applied_n,
                  0x49, attack_requested_n)


_WIND = struct.Struct("<BdBB3d").pack


def truth_wind(t: float, wind_mps: Sequence[float]) -> bytes:
    """A ``tfl_mav.TruthWind`` (one ``struct`` pack, as :func:`truth_state`)."""
    return _WIND(0x09, t, 0x12, 24, *wind_mps)


def path_distance(t: float, distance_m: float) -> bytes:
    return _PATH(0x09, t, 0x11, distance_m)


_D = struct.Struct("<d").pack
_PACKED: dict[int, tuple[bytes, Callable[..., bytes]]] = {}


def _doubles(values: Sequence[float]) -> bytes:
    """A packed run of doubles: its length (varint), then the values."""
    n = len(values)
    packer = _PACKED.get(n)
    if packer is None:
        packer = _PACKED[n] = (_len(8 * n), struct.Struct(f"<{n}d").pack)
    return packer[0] + packer[1](*values)


def _len(n: int) -> bytes:
    return _LEN1[n] if n < 128 else _varint(n)


def _kind(prop: Mapping[str, Any]) -> str:
    t = prop.get("type")
    if t == "array" and prop.get("items", {}).get("type") in ("number", "integer"):
        return "doubles"
    return {"number": "double", "integer": "sint64", "boolean": "bool",
            "string": "string"}.get(t, "nested")


def kind_of(value: Any) -> str:
    """The field kind of a value with no schema (a free key of a mapping record)."""
    v = _plain(value)
    if isinstance(v, bool):
        return "bool"
    if isinstance(v, int):
        return "sint64"
    if isinstance(v, float):
        return "double"
    if isinstance(v, str):
        return "string"
    if isinstance(v, (list, tuple)) and all(isinstance(x, (int, float)) for x in v):
        return "doubles"
    if isinstance(v, Mapping):
        return "json"
    return "nested"


class RecordEncoder:
    """A caller's record as protobuf: ``t_s``, then ``names`` (the order of a sequence
    record's values), then the schema's other properties; kinds from the JSON-Schema-like
    ``json_schema`` (a name it does not type: numbers nested in lists), or ``kinds``.
    :attr:`schema_data` is the schema; :meth:`encode` a sequence record, :meth:`encode_map`
    a mapping. A value of the wrong kind raises ValueError naming the field."""

    def __init__(self, json_schema: Mapping[str, Any], names: Sequence[str] = (),
                 kinds: Mapping[str, str] | None = None) -> None:
        props = {k: v for k, v in json_schema.get("properties", {}).items()
                 if not k.startswith("_")}
        order = ["t_s", *(n for n in names if n != "t_s")]
        order += [k for k in props if k not in order]
        order += [k for k in (kinds or {}) if k not in order]
        self.name = str(json_schema.get("title") or f"{PACKAGE}.Record")
        if "." not in self.name:
            self.name = f"{PACKAGE}.{self.name}"
        kinds = dict(kinds or {})
        self.fields = tuple((n, "double" if n == "t_s" else kinds.get(n) or _kind(
            props.get(n, {})), str(props.get(n, {}).get("description", ""))) for n in order)
        self.names = tuple(n for n, _, _ in self.fields)
        self.schema_data = _file(self.name, self.fields)
        self._writers = [_writer(_tag(i, _WIRE[k]), k) for i, (_, k, _) in
                         enumerate(self.fields, 1)]
        self._t = self._writers[0]
        self._seq = self._writers[1:1 + len([n for n in names if n != "t_s"])]

    def encode(self, t_s: float, values: Sequence[Any]) -> bytes:
        """``t_s`` and the values of ``names`` in order (None: left out)."""
        try:
            return self._t(t_s) + b"".join([w(v) for w, v in zip(self._seq, values,
                                                                 strict=True)
                                            if v is not None])
        except (TypeError, ValueError, struct.error, OverflowError):
            return self.encode_map({"t_s": t_s, **dict(zip(self.names[1:], values,
                                                           strict=True))})

    def encode_map(self, values: Mapping[str, Any]) -> bytes:
        """A mapping record (its keys among :attr:`names`; None: left out)."""
        parts = []
        for name, write in zip(self.names, self._writers, strict=True):
            v = values.get(name)
            if v is None:
                continue
            try:
                parts.append(write(v))
            except (TypeError, ValueError, struct.error, OverflowError) as exc:
                kind = self.fields[self.names.index(name)][1]
                raise ValueError(f"{name}: cannot record {v!r} as {kind} ({exc})") from None
        return b"".join(parts)


def _plain(v: Any) -> Any:
    return v.tolist() if hasattr(v, "tolist") else v


def _writer(tag: bytes, kind: str) -> Callable[[Any], bytes]:
    """The encoder of one field (its tag first) of ``kind``."""
    if kind == "double":
        return lambda v: tag + _D(v)
    if kind == "doubles":           # an empty packed field is left out, as protobuf does
        return lambda v: tag + _doubles(v) if len(v) else b""
    if kind == "bool":
        yes, no = tag + b"\x01", tag + b"\x00"

        def write_bool(v: Any) -> bytes:
            if v is True:
                return yes
            if v is False:
                return no
            if isinstance(_plain(v), (str, list, tuple, dict)):
                raise TypeError("not a flag")
            return yes if v else no
        return write_bool
    if kind == "string":
        def write_str(v: Any) -> bytes:
            b = (v if type(v) is str else str(v)).encode()
            return tag + _len(len(b)) + b
        return write_str
    if kind == "sint64":
        small = [tag + _LEN1[2 * n] for n in range(64)]

        def write_int(v: Any) -> bytes:
            if type(v) is int and 0 <= v < 64:      # a rotor number, a count
                return small[v]
            n = _plain(v)
            if not isinstance(n, int):
                raise TypeError("not an integer")
            if not -(2**63) <= n < 2**63:
                raise OverflowError("beyond 64 bits")
            return tag + _varint((n << 1) ^ (n >> 63))
        return write_int
    if kind == "json":
        def write_json(v: Any) -> bytes:
            import msgspec

            b = msgspec.json.encode(v, enc_hook=_plain)
            return tag + _varint(len(b)) + b
        return write_json
    return lambda v: _nested(tag, v)


def _nested(tag: bytes, v: Any) -> bytes:
    """Repeated ``tfl_mav.Doubles``: one submessage (``values``, packed) per inner list (a
    number alone: a list of one)."""
    try:
        parts = []
        for inner in v:
            body = _VALUES + _doubles(inner) if len(inner) else b""
            parts.append(tag + _len(len(body)) + body)
        return b"".join(parts)
    except TypeError:
        pass
    v = _plain(v)
    if not isinstance(v, (list, tuple)):
        raise TypeError("expected lists of numbers")
    return _nested(tag, [[float(x) for x in _plain(i)] if isinstance(_plain(i), (list, tuple))
                         else [float(i)] for i in v])


_VALUES = _tag(1, 2)
