"""A JSON object of fixed keys printed whole by one msgspec call.

Why: the recorder children print ~12 JSON objects per 1 ms tick. The precompiled ``%``
templates of :mod:`~tfl_mav.flightlog.jsonenc` print the numbers with one msgspec call but
then split that text into one ``bytes`` per number and fill a template of one ``%s`` per
number: ~6 µs for ODOMETRY's 61 numbers, most of a frame's cost. Here the object is a
``msgspec.Struct`` (one per shape, keys renamed to the JSON keys), built from the values
by a generated one-line function and encoded in one C call: ~1.8 µs for ODOMETRY.

The text must stay what ``json`` prints (:class:`~tfl_mav.flightlog.jsonenc.JsonEncoder`).
msgspec prints the same shortest round-trip digits as ``repr`` but another notation in
places (see :mod:`~tfl_mav.flightlog.jsonenc`): an exponent (``1e-9`` for ``1e-09``),
``0.0000x`` for values in [1e-5, 1e-4), and ``null`` for NaN/inf. The keys are fixed, so
one ``count`` of ``e`` (against the keys' own) and two scans find out whether a printed
object holds any of them (rare); :meth:`ObjectJson.reprint` then re-prints those values
with ``repr``; ``null`` is the caller's (its ``_nonfinite`` path). Values are numbers,
lists of numbers, bools and JSON literals (``msgspec.Raw``); never a str (msgspec escapes
text otherwise than ``json``'s ``ensure_ascii``).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import msgspec

__all__ = ["ObjectJson", "encode"]

encode = msgspec.json.Encoder().encode
"""msgspec's JSON encoder: a Struct built by :attr:`ObjectJson.build` → its JSON bytes."""

_DIGITS = frozenset(b"0123456789")
_VALUE_START = frozenset(b",:[")


class ObjectJson:
    """``build(t)``: the Struct (:attr:`struct`) of one object whose keys are ``keys`` (in
    order) and whose values are the Python expressions ``args`` over ``t`` (and the names
    in ``env``); ``encode(build(t))`` prints it. ``key_e``: how many ``e`` a clean print
    holds: the keys' own plus ``literal_e``, those of the values that are not numbers (a
    bool prints one: ``true``, ``false``). Raises ValueError for keys it cannot print
    (text that a number's check would mistake)."""

    def __init__(self, keys: Sequence[str], args: Sequence[str],
                 env: dict[str, Any] | None = None, literal_e: int = 0) -> None:
        if len(keys) != len(args) or len(set(keys)) != len(keys):
            raise ValueError("keys and args differ in length, or a key repeats")
        for k in keys:
            if not (k.isascii() and k.isprintable()) or any(c in k for c in '"\\,:[]{}') \
                    or "null" in k or "0.0000" in k:
                raise ValueError(f"key {k!r}: not printed here")
        self.struct = msgspec.defstruct("_Object", [(f"f{i}", Any) for i in range(len(keys))],
                                        rename={f"f{i}": k for i, k in enumerate(keys)})
        names = {"_S": self.struct, **(env or {})}
        self.build = eval(f"lambda t: _S({', '.join(args)})", names)  # our own code
        self.key_e = sum(k.count("e") for k in keys) + literal_e

    def clean(self, out: bytes) -> bool:
        """No value of ``out`` is printed otherwise than ``json`` does (the usual case)."""
        return out.count(b"e") == self.key_e and b"0.0000" not in out and b"null" not in out

    @staticmethod
    def reprint(out: bytes, values: Sequence[Any]) -> bytes | None:
        """``out`` with the values msgspec printed in another notation re-printed by
        ``float.__repr__`` (as ``json``); ``values``: one per comma-separated piece of
        ``out``, in order (each number, bool or literal of the object; only floats are
        re-printed). None if ``out`` holds a ``null``
        (NaN/inf: the caller leaves them out) or the pieces do not match ``values``."""
        if b"null" in out:
            return None
        parts = out.split(b",")
        if len(parts) != len(values):
            return None
        find, count = out.find, out.count
        odd: set[int] = set()
        i = find(b"e")
        while i >= 0:                   # an exponent follows a digit (a key's e: below)
            if out[i - 1] in _DIGITS:
                odd.add(count(b",", 0, i))
            i = find(b"e", i + 1)
        i = find(b"0.0000")
        while i >= 0:                   # at a value's start, after an optional -
            j = i - 1 if out[i - 1] == 45 else i      # 45: "-"
            if out[j - 1] in _VALUE_START:
                odd.add(count(b",", 0, i))
            i = find(b"0.0000", i + 6)
        for k in odd:
            x = values[k]
            if not isinstance(x, float):   # an int, bool or text: printed as json does
                continue
            p = parts[k]
            start = max(p.rfind(b":"), p.rfind(b"[")) + 1
            end = len(p.rstrip(b"]}"))
            v = p[start:end]
            if b"e" in v or v.startswith((b"0.0000", b"-0.0000")):
                parts[k] = p[:start] + float.__repr__(x).encode() + p[end:]
        return b",".join(parts)
