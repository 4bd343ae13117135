"""Compact JSON for the recorder's JSON channels, with NaN/inf/None left out.

JSON has no NaN, and Foxglove wants no null in a number field: such a value (or a list
holding one) is left out of the message and its dotted key listed under ``_nonfinite``
(:data:`tfl_mav.flightlog.schemas.NONFINITE_KEY`).
"""

from __future__ import annotations

import base64
import contextlib
import json
import math
import re
from collections.abc import Iterable, Mapping
from json.encoder import encode_basestring_ascii
from operator import itemgetter
from typing import Any

from tfl_mav.flightlog.jsonobj import ObjectJson
from tfl_mav.flightlog.jsonobj import encode as _encode_obj
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
# tests/contract/test_recorder_fast.py. Without msgspec installed everything takes the ``repr``
# path.
try:
    from msgspec.json import Encoder as _MsgspecEncoder

    _encode_numbers: Any = _MsgspecEncoder().encode
except ImportError:                      # pragma: no cover - msgspec is a dependency
    def _encode_numbers(values: Any) -> bytes:
        if not all(type(v) in (int, float) and math.isfinite(v) for v in values):
            raise ValueError("not finite plain numbers")
        return ("[" + ",".join(map(repr, values)) + "]").encode()




def _numbers_json(values: tuple[Any, ...]) -> list[bytes] | None:
    """The JSON text of each number of ``values`` (ints and floats, no bools) as ``repr``
    prints it: msgspec's, with the values whose notation differs (see above) re-printed
    by ``repr``; None if a value is NaN/inf or not a plain number."""
    try:
        b = _encode_numbers(values)
    except (TypeError, ValueError, OverflowError):
        return None
    body = b[1:-1]
    parts = body.split(b",")
    if b"e" in b or b"l" in b or b"0.0000" in b or b'"' in b:
        if b"l" in b or b'"' in b or b"t" in b or len(parts) != len(values):
            return None                  # NaN/inf (null), text, bools, nested lists
        _reprint_odd(body, parts, values)
    return parts


def _reprint_odd(body: bytes, parts: list[bytes], values: tuple[Any, ...]) -> None:
    """Re-print with ``repr`` the few values msgspec writes in another notation (above):
    those with an exponent, and those printed ``0.0000x`` (positional below 1e-4). Found
    with ``bytes.find`` (C), one Python step per such value: a regular expression over the
    whole text cost ~20 µs a message, more than the rest of its encoding."""
    odd: set[int] = set()
    find, count = body.find, body.count
    i = find(b"e")
    while i >= 0:                            # an exponent: its field, then the next field
        odd.add(count(b",", 0, i))
        i = find(b",", i)
        if i < 0:
            break
        i = find(b"e", i)
    i = find(b"0.0000")
    while i >= 0:                            # only at a field's start, after an optional -
        j = i - 1 if i and body[i - 1] == 45 else i   # 45: "-"
        if j == 0 or body[j - 1] == 44:               # 44: ","
            odd.add(count(b",", 0, i))
        i = find(b"0.0000", i + 6)
    for k in odd:
        parts[k] = repr(values[k]).encode()


def _numbers_json_nulls(values: tuple[Any, ...]) -> list[bytes] | None:
    """:func:`_numbers_json`, but NaN/inf/None print as ``b"null"`` (for the caller to
    leave out, as :func:`drop_nonfinite` does); None if a value is not a plain number."""
    try:
        b = _encode_numbers(values)
    except (TypeError, ValueError, OverflowError):
        return None
    body = b[1:-1]
    parts = body.split(b",")
    if (b'"' in b or b"t" in b or b"a" in b or b"[" in body or b"{" in b
            or len(parts) != len(values)):
        return None                      # text, bools, nested lists
    if b"e" in b or b"0.0000" in b:
        _reprint_odd(body, parts, values)
    return parts


_NULL = b"null"


class NullMasks:
    """One JSON object's templates with the keys holding a NaN/inf/None left out and
    listed under ``_nonfinite``, as :func:`drop_nonfinite` writes them: one template per
    pattern of such keys, built on first sight. Why: a real PX4's ODOMETRY has NaN
    covariances ("unknown"), a nominal flight's tick record a NaN attack estimate, every
    tick; the dict path costs ~20 µs a message.

    ``keys``: per key in output order, (its JSON text, its value's ``%s`` template, the
    indices of its values in the argument list); ``owner[i]``: the key of number part
    ``i`` (number parts come first in the argument list)."""

    _MAX = 64                            # patterns kept (then None: the careful path)

    def __init__(self, keys: list[tuple[str, bytes, list[int]]], owner: list[int]) -> None:
        self.keys = keys
        self.owner = owner
        last = {k: max((j for j in refs if j < len(owner)), default=0)
                for k, (_, _, refs) in enumerate(keys)}
        self._end = [last[k] + 1 for k in owner]   # past the last number of i's key
        self._masks: dict[tuple[int, ...], tuple[bytes, Any]] = {}

    def mask(self, parts: list[bytes]) -> tuple[int, ...]:
        """The keys (indices) whose number parts hold a ``null``: one scan (C) per such
        key, skipping the rest of its values."""
        owner, end = self.owner, self._end
        out: list[int] = []
        i = 0
        try:
            while True:
                i = parts.index(_NULL, i)
                out.append(owner[i])
                i = end[i]
        except (ValueError, IndexError):
            return tuple(out)

    def encode(self, mask: tuple[int, ...], args: Any) -> bytes | None:
        """The object without the keys of ``mask``; ``args``: every value's text."""
        entry = self._masks.get(mask)
        if entry is None:
            if len(self._masks) >= self._MAX:
                return None
            entry = self._masks[mask] = self._build(mask)
        fmt, get = entry
        return fmt % get(args)

    def _build(self, mask: tuple[int, ...]) -> tuple[bytes, Any]:
        pieces: list[bytes] = []
        order: list[int] = []
        for k, (key, value, refs) in enumerate(self.keys):
            if k not in mask:
                pieces.append(encode_basestring_ascii(key).replace("%", "%%").encode()
                              + b":" + value)
                order += refs
        listed = json.dumps([self.keys[k][0] for k in mask], separators=(",", ":"))
        pieces.append(json.dumps(NONFINITE_KEY).encode() + b":"
                      + listed.replace("%", "%%").encode())
        get = itemgetter(*order) if len(order) > 1 else (
            (lambda a: (a[order[0]],)) if order else (lambda a: ()))
        return b"{" + b",".join(pieces) + b"}", get


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
        self.bfmt = ("{" + ",".join(parts) + "}").encode()

    @property
    def pieces(self) -> tuple[bytes, ...]:
        """The text between the values (one more than the values): the C path's form of
        :attr:`bfmt` (:func:`~tfl_mav.flightlog.frames_c` ``records``)."""
        return tuple(p.replace(b"%%", b"%") for p in self.bfmt.split(b"%s"))

    def encode(self, values: tuple[Any, ...]) -> bytes | None:
        """The JSON of ``values`` (numbers, in format order), or None if one is NaN/inf."""
        parts = _numbers_json(values)
        return None if parts is None else self.bfmt % tuple(parts)


_MISSING: Any = object()
_CHAR_CACHE_MAX = 1024           # char-field texts kept per message type


class MavPlan:
    """One message class, precompiled (see :class:`MavJson`): ``unpack`` the payload
    (``size`` bytes), then :meth:`json` of the wire tuple. ``time_index``: where
    ``time_usec`` sits in the tuple (None: no such field)."""

    def __init__(self, cls: Any) -> None:
        self.unpack = cls.unpacker.unpack
        self.size = cls.unpacker.size
        lengths = cls.lengths            # values per wire-ordered field ('10s' counts 1)
        self.time_index: int | None = None
        chars = [t == "char" for t in cls.fieldtypes]
        numeric: list[int] = []          # tuple indices of the numbers, fieldnames order
        self.char_index: list[int] = []  # tuple indices of the char fields
        slots: list[tuple[str, list[int]]] = []
        for i, name in enumerate(cls.fieldnames):
            tip = sum(lengths[:cls.orders[i]])
            count = lengths[cls.orders[i]]
            if chars[i]:
                self.char_index.append(tip)
                slots.append((name, [-len(self.char_index)]))
                continue
            if name == "time_usec" and count == 1:
                self.time_index = tip
            slots.append((name, list(range(len(numeric), len(numeric) + count))))
            numeric += range(tip, tip + count)
        n_num = len(numeric)
        order: list[int] = []
        parts = []
        keys: list[tuple[str, bytes, list[int]]] = []
        owner = [0] * n_num
        for name, refs in slots:
            refs = [n_num - r - 1 if r < 0 else r for r in refs]   # chars after numbers
            order += refs
            # as PayloadDecoder: a list only for count > 1
            value = "%s" if len(refs) == 1 else "[" + ",".join(["%s"] * len(refs)) + "]"
            parts.append(f'"{name}":{value}')
            for r in refs:
                if r < n_num:
                    owner[r] = len(keys)
            keys.append((name, value.encode(), refs))
        self._masks = NullMasks(keys, owner)
        self.numbers = itemgetter(*numeric) if n_num > 1 else (
            (lambda t: (t[numeric[0]],)) if numeric else (lambda t: ()))
        self.order = itemgetter(*order) if len(order) > 1 else lambda p: (p[0],)
        self.bfmt = ("{" + ",".join(parts) + "}").encode()
        self._chars: dict[bytes, bytes] = {}
        self.simple = not self.char_index   # numbers only
        # numbers only: the whole object by one msgspec call (jsonobj), checked here once
        self.obj: ObjectJson | None = None
        if self.simple:
            with contextlib.suppress(ValueError):
                self.obj = ObjectJson(list(cls.fieldnames), [
                    f"t[{tip}]" if n == 1 else f"t[{tip}:{tip + n}]"
                    for tip, n in ((sum(lengths[:o]), lengths[o]) for o in cls.orders)])
            if self.obj is not None and not self._obj_agrees(cls.unpacker.format):
                self.obj = None

    def _obj_agrees(self, fmt: str) -> bool:
        """:attr:`obj` prints what :meth:`json` prints, on a made-up tuple of this layout:
        plain values, then values msgspec prints in another notation."""
        codes = [c for n, c in re.findall(r"(\d*)([a-zA-Z?])", fmt)
                 for _ in range(1 if c == "s" else int(n or 1))]
        for odd in (False, True):
            t = tuple(0.25 * (k + 1) * (1e-7 if odd and k % 3 == 0 else
                                       3e-5 if odd and k % 3 == 1 else 1.0)
                      if c in "fd" else (k % 100) + 1 for k, c in enumerate(codes))
            out = _encode_obj(self.obj.build(t))
            if not self.obj.clean(out):
                out = self.obj.reprint(out, self.numbers(t))
            if out != self.json(t):
                return False
        return True

    def _char_texts(self, t: tuple[Any, ...]) -> list[bytes]:
        out = []
        cache = self._chars
        for i in self.char_index:
            raw = t[i]
            text = cache.get(raw)
            if text is None:          # as PayloadDecoder + JsonEncoder (ensure_ascii)
                text = encode_basestring_ascii(
                    raw.split(b"\x00", 1)[0].decode("ascii", "replace")).encode()
                if len(cache) >= _CHAR_CACHE_MAX:
                    cache.clear()
                cache[raw] = text
            out.append(text)
        return out

    def json(self, t: tuple[Any, ...]) -> bytes | None:
        """The message's JSON from its wire tuple ``t`` (NaN/inf fields left out and listed
        under ``_nonfinite``, as the dict path writes them)."""
        parts = _numbers_json(self.numbers(t))
        if parts is None:            # NaN/inf: left out, listed (NullMasks)
            parts = _numbers_json_nulls(self.numbers(t))
            mask = self._masks.mask(parts) if parts is not None else ()
            if not mask:
                return None
            if self.char_index:
                parts += self._char_texts(t)
            return self._masks.encode(mask, parts)
        if self.char_index:
            parts += self._char_texts(t)
        return self.bfmt % self.order(parts)


class MavJson:
    """JSON of a MAVLink 2 frame's fields from its wire bytes, byte-identical to
    ``JsonEncoder.dumps(PayloadDecoder.fields(raw, msgid))`` (fields in ``fieldnames``
    order, arrays as lists, char fields as text), without building the dict; NaN/inf
    fields left out and listed as :func:`drop_nonfinite` does. A payload that does not
    unpack is not encoded here (None): the caller takes the careful path."""

    def __init__(self) -> None:
        self._plans: dict[int, MavPlan | None] = {}

    def plan(self, msgid: int) -> MavPlan | None:
        """The precompiled plan of ``msgid`` (None: not in the dialect)."""
        plan = self._plans.get(msgid, _MISSING)
        if plan is _MISSING:
            cls = mav.mavlink_map.get(msgid)
            plan = self._plans[msgid] = MavPlan(cls) if cls is not None else None
        return plan

    def encode(self, raw: bytes, msgid: int) -> tuple[bytes, int | None] | None:
        """(JSON, ``time_usec`` or None if the message has none), or None (see class)."""
        plan = self.plan(msgid)
        if plan is None:
            return None
        try:
            t = plan.unpack(frame_payload(raw, plan.size))
        except Exception:   # struct.error: the careful path counts it
            return None
        data = plan.json(t)
        if data is None:
            return None
        return data, (t[plan.time_index] if plan.time_index is not None else None)
