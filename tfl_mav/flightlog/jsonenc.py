"""Compact JSON for the recorder's JSON channels, with NaN/inf/None left out.

JSON has no NaN, and Foxglove wants no null in a number field: such a value (or a list
holding one) is left out of the message and its dotted key listed under ``_nonfinite``
(:data:`tfl_mav.flightlog.schemas.NONFINITE_KEY`).
"""

from __future__ import annotations

import base64
import json
import math
import re
import struct
from collections.abc import Iterable, Mapping
from operator import itemgetter
from typing import Any

from tfl_mav.flightlog.schemas import NONFINITE_KEY
from tfl_mav.link.dialect import mav
from tfl_mav.link.payload import frame_payload

__all__ = ["JsonEncoder", "MavJson", "RecordFormat", "all_finite", "drop_nonfinite"]


def _jsonable(obj: Any) -> Any:
    """``default`` hook of the encoder: numpy arrays/scalars, tuple-likes, bytes."""
    if hasattr(obj, "tolist"):
        return obj.tolist()
    if isinstance(obj, (bytes, bytearray)):
        return base64.b64encode(obj).decode("ascii")
    if isinstance(obj, Iterable):
        return list(obj)
    raise TypeError(f"{type(obj).__name__} is not JSON serialisable")


def all_finite(value: Any) -> bool:
    """No NaN, inf or None anywhere in ``value`` (JSON would need null for them)."""
    if isinstance(value, float):
        return math.isfinite(value)
    if value is None:
        return False
    if isinstance(value, Mapping):
        return all(all_finite(v) for v in value.values())
    if isinstance(value, (list, tuple)):
        try:                                        # flat list of numbers: the usual case
            return all(map(math.isfinite, value))
        except (TypeError, OverflowError):
            return all(all_finite(v) for v in value)
    if hasattr(value, "tolist"):
        return all_finite(value.tolist())
    return True


def drop_nonfinite(obj: Mapping[str, Any], prefix: str = "",
                   dropped: list[str] | None = None) -> dict[str, Any]:
    """A copy of ``obj`` without NaN/inf/None: such a value, or a list holding one, is left
    out and its dotted key listed under ``_nonfinite``."""
    top = dropped is None
    dropped = [] if dropped is None else dropped
    out: dict[str, Any] = {}
    for k, v in obj.items():
        if isinstance(v, Mapping):
            out[k] = drop_nonfinite(v, f"{prefix}{k}.", dropped)
        elif all_finite(v):
            out[k] = v
        else:
            dropped.append(f"{prefix}{k}")
    if top and dropped:
        out[NONFINITE_KEY] = dropped
    return out


class JsonEncoder:
    """``dumps`` for one-off messages; ``dumps_sticky`` for a channel that remembers whether
    NaN showed up last time (ODOMETRY's unknown covariances do, every frame) to skip the
    wasted first pass."""

    def __init__(self) -> None:
        self._encode = json.JSONEncoder(separators=(",", ":"), default=_jsonable).encode

    def dumps(self, obj: Mapping[str, Any]) -> bytes:
        """Compact JSON; the second pass runs only when the fast one printed NaN, Infinity
        or null (or such text)."""
        s = self._encode(obj)
        if "NaN" in s or "Infinity" in s or "null" in s:
            s = self._encode(drop_nonfinite(obj))
        return s.encode()

    def dumps_sticky(self, fields: Mapping[str, Any], nonfinite: bool) -> tuple[bytes, bool]:
        """(JSON, whether NaN/inf was seen) for a channel that saw NaN last time or not."""
        if nonfinite:
            clean = drop_nonfinite(fields)
            return self._encode(clean).encode(), NONFINITE_KEY in clean
        s = self._encode(fields)
        if "NaN" in s or "Infinity" in s:
            return self._encode(drop_nonfinite(fields)).encode(), True
        return s.encode(), False


# ------------------------------------------------------------------ precompiled encoders
# Why: the recorder children encode ~12 messages per 1 ms tick; json.JSONEncoder on a dict
# costs ~4-8 µs each, and even a precompiled ``%r`` format of the values is dominated by
# printing the floats (~0.4-1 µs each: ``float.__repr__``, David Gay's shortest digits).
# msgspec prints a whole tuple of numbers in one C call, ~10x faster per float, with the
# same shortest round-trip digits; only its notation differs from ``repr`` (and so from
# ``json``) in places that show in the output: exponents (``1e-9`` vs ``1e-09``), values in
# [1e-5, 1e-4) printed positionally (``0.00001234`` vs ``1.234e-05``), and NaN/inf as
# ``null``. So its output is used only when it holds no ``e``, no ``l`` and no ``0.0000``
# (numbers only: a false alarm such as ``10.00001`` just takes the slower path); otherwise
# the values are printed with ``repr``, byte-identical to JsonEncoder's (JSON prints a
# finite float as ``float.__repr__`` and an int as ``int.__repr__``). Checked against
# ``repr`` on ~1.5 million floats across every decade and the notation thresholds, and by
# tests/test_recorder_fast.py. Without msgspec installed everything takes the ``repr`` path.
try:
    from msgspec.json import Encoder as _MsgspecEncoder

    _encode_numbers: Any = _MsgspecEncoder().encode
except ImportError:                      # pragma: no cover - msgspec is a dependency
    def _encode_numbers(values: Any) -> bytes:
        return b"e"                      # "suspect": always the repr path


def _numbers_json(values: tuple[Any, ...]) -> list[bytes] | None:
    """The JSON text of each number of ``values`` as ``repr`` prints it, via msgspec; None
    when its notation may differ (see above) or a value is not a plain number."""
    try:
        b = _encode_numbers(values)
    except (TypeError, ValueError, OverflowError):
        return None
    if b"e" in b or b"l" in b or b"0.0000" in b:
        return None
    return b[1:-1].split(b",")


class RecordFormat:
    """A JSON object of fixed keys whose values are numbers (scalars or fixed-length lists)
    or fixed literals. ``items``: (key, n) with n = 0 for a number, n ≥ 1 for a list of n
    numbers, or a ``str``: JSON text written as it is (``true``, ``"text"``)."""

    def __init__(self, items: Iterable[tuple[str, int | str]]) -> None:
        parts = []
        for key, n in items:
            if isinstance(n, str):
                parts.append(f'"{key}":{n.replace("%", "%%")}')
            elif n == 0:
                parts.append(f'"{key}":%s')
            else:
                parts.append(f'"{key}":[{",".join(["%s"] * n)}]')
        self.fmt = "{" + ",".join(parts) + "}"
        self.bfmt = self.fmt.encode()

    def encode(self, values: tuple[Any, ...]) -> bytes | None:
        """The JSON of ``values`` (numbers, in format order), or None if one is NaN/inf."""
        parts = _numbers_json(values)
        if parts is not None:
            return self.bfmt % tuple(parts)
        if not all(map(math.isfinite, values)):
            return None
        return (self.fmt % tuple(map(repr, values))).encode()


_MISSING: Any = object()
_ARRAY_CACHE_MAX = 256           # formatted arrays kept per message type (constants hit)


def _element_offsets(fmt: str) -> list[int]:
    """Byte offset of every value of a little-endian ``struct`` format (no padding), plus
    the end."""
    offsets, at = [], 0
    for count, code in re.findall(r"(\d*)([a-zA-Z?])", fmt):
        n = int(count or 1)
        if code == "s":
            offsets.append(at)
            at += n
        else:
            size = struct.calcsize("<" + code)
            for _ in range(n):
                offsets.append(at)
                at += size
    return [*offsets, at]


_GROUP = 8                       # array values per cached piece (see _MavPlan)


class _MavPlan:
    """One message class, precompiled (see :class:`MavJson`): the whole JSON object is one
    ``str.format`` template over the unpacked wire tuple (``{i!r}``: fields in
    ``fieldnames`` order, whatever the wire order). Arrays of 8 or more values are printed
    in pieces of up to 8, each cached by its wire bytes: covariances, padding and unused
    channels (zeros) repeat every tick, and printing a float costs ~0.3-0.8 µs; such a piece
    comes in pre-printed, as an extra argument after the tuple."""

    def __init__(self, cls: Any) -> None:
        self.unpack = cls.unpacker.unpack
        self.size = cls.unpacker.size
        offsets = _element_offsets(cls.unpacker.format)
        lengths = cls.lengths            # values per wire-ordered field
        n_values = sum(lengths)
        parts: list[str] = []
        # cached pieces: (byte start, byte end, first value, end value, "%r,..." format)
        self.pieces: list[tuple[int, int, int, int, str]] = []
        self.time_index: int | None = None
        for i, name in enumerate(cls.fieldnames):
            wire = cls.orders[i]
            tip = sum(lengths[:wire])
            count = lengths[wire]
            if count == 1:
                parts.append(f'"{name}":{{{tip}!r}}')
                if name == "time_usec":
                    self.time_index = tip
            elif count < _GROUP:      # as PayloadDecoder: a list only for count > 1
                parts.append(f'"{name}":[' + ",".join(f"{{{j}!r}}" for j in
                                                       range(tip, tip + count)) + "]")
            else:
                refs = []
                for lo in range(tip, tip + count, _GROUP):
                    hi = min(lo + _GROUP, tip + count)
                    refs.append(f"{{{n_values + len(self.pieces)}}}")
                    self.pieces.append((offsets[lo], offsets[hi], lo, hi,
                                        ",".join(["%r"] * (hi - lo))))
                parts.append(f'"{name}":[' + ",".join(refs) + "]")
        self.template = "{{" + ",".join(parts) + "}}"
        self.format = self.template.format
        self.letters = self.format(*[0] * n_values, *[""] * len(self.pieces)).count("n")
        # the msgspec path: every value a %s, in fieldnames order
        order: list[int] = []
        bparts = []
        for i, name in enumerate(cls.fieldnames):
            tip = sum(lengths[:cls.orders[i]])
            count = lengths[cls.orders[i]]
            order += range(tip, tip + count)
            bparts.append(f'"{name}":%s' if count == 1
                          else f'"{name}":[' + ",".join(["%s"] * count) + "]")
        self.getter = itemgetter(*order) if len(order) > 1 else lambda p: (p[0],)
        self.bfmt = ("{" + ",".join(bparts) + "}").encode()
        self.cache: dict[bytes, str] = {}


class MavJson:
    """JSON of a MAVLink 2 frame's fields from its wire bytes, byte-identical to
    ``JsonEncoder.dumps(PayloadDecoder.fields(raw, msgid))`` (fields in ``fieldnames``
    order, arrays as lists), without building the dict. Messages with char fields, NaN/inf
    values or a payload that does not unpack are not encoded here (None): the caller takes
    the careful path."""

    def __init__(self) -> None:
        self._plans: dict[int, _MavPlan | None] = {}

    def encode(self, raw: bytes, msgid: int) -> tuple[bytes, int | None] | None:
        """(JSON, ``time_usec`` or None if the message has none), or None (see class)."""
        plan = self._plans.get(msgid, _MISSING)
        if plan is _MISSING:
            cls = mav.mavlink_map.get(msgid)
            plan = self._plans[msgid] = (_MavPlan(cls) if cls is not None
                                         and "char" not in cls.fieldtypes else None)
        if plan is None:
            return None
        payload = frame_payload(raw, plan.size)
        try:
            t = plan.unpack(payload)
        except Exception:   # struct.error: the careful path counts it
            return None
        parts = _numbers_json(t)
        if parts is not None:
            return (plan.bfmt % plan.getter(parts),
                    t[plan.time_index] if plan.time_index is not None else None)
        if plan.pieces:
            cache = plan.cache
            texts = []
            for a, b, lo, hi, fmt in plan.pieces:
                key = payload[a:b]
                text = cache.get(key)
                if text is None:
                    text = fmt % t[lo:hi]
                    if "n" in text:          # NaN/inf: the careful path
                        return None
                    if len(cache) >= _ARRAY_CACHE_MAX:
                        cache.clear()
                    cache[key] = text
                texts.append(text)
            s = plan.format(*t, *texts)
        else:
            s = plan.format(*t)
        if s.count("n") != plan.letters:
            return None
        return s.encode(), (t[plan.time_index] if plan.time_index is not None else None)
