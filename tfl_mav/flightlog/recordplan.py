"""Precompiled JSON for a caller's per-tick record (``/controller/state``), issue #13.

Why: the daemon hands its recorder child one compact tuple a tick (``tick_state``: mode,
rotor, estimates, thrusts, the chains ξ and η, CUSUM, reason ...). Naming it as a dict and
running ``json`` over it cost the child ~20-25 µs a tick, mostly printing ~25 floats. A
record keeps its shape from tick to tick, so :func:`record_plan` writes, for the shape of
one sample record, a small function that checks the shape (lengths, types), prints all
numbers with one msgspec call (:func:`~tfl_mav.flightlog.jsonenc._numbers_json`, the same
text as ``repr``/``json``), the strings with ``json``'s own ``encode_basestring_ascii``,
and fills one ``%`` template: the bytes ``JsonEncoder.dumps({**record, "t_s": t})`` writes.
Any record it cannot print exactly (another shape, NaN/inf, None, numpy values) returns
None: the caller takes the careful path (which leaves NaN out and lists it).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from json.encoder import encode_basestring_ascii
from typing import Any

from tfl_mav.flightlog.jsonenc import _numbers_json

__all__ = ["record_plan"]

RecordEncoder = Callable[[Sequence[Any], float], "bytes | None"]


def _is_number(v: Any) -> bool:
    return type(v) in (int, float)


def _text(v: Any) -> bytes | None:
    return encode_basestring_ascii(v).encode() if type(v) is str else None


def _flag(v: Any) -> bytes | None:
    return b"true" if v is True else b"false" if v is False else None


def record_plan(fields: Sequence[str], sample: Sequence[Any]) -> RecordEncoder | None:
    """``encode(record, t_s) -> bytes | None`` for records shaped like ``sample`` (values
    named by ``fields``), or None if the sample holds something it does not print (None,
    numpy values, dicts, deeper nesting)."""
    if len(sample) != len(fields):
        return None
    checks = [f"len(r) == {len(sample)}"]
    exprs: list[str] = []          # expressions of the numbers, in output order
    count = 0                      # how many numbers they make
    args: list[str] = []           # the template's arguments, in output order
    pieces: list[str] = []
    texts: list[str] = []          # statements computing text/flag arguments

    def numbers(expr: str, n: int) -> str:
        nonlocal count
        exprs.append(expr)
        args.extend(f"p[{count + j}]" for j in range(n))
        count += n
        return ",".join(["%s"] * n)

    for i, (name, v) in enumerate(zip(fields, sample, strict=True)):
        key = encode_basestring_ascii(name).replace("%", "%%")
        if _is_number(v):
            pieces.append(f"{key}:{numbers(f'r[{i}]', 1)}")
        elif type(v) in (bool, str):
            fn = "_flag" if type(v) is bool else "_text"
            texts.append(f"a{i} = {fn}(r[{i}])\n    if a{i} is None:\n        return None")
            args.append(f"a{i}")
            pieces.append(f"{key}:%s")
        elif type(v) in (list, tuple) and all(map(_is_number, v)):
            checks.append(f"len(r[{i}]) == {len(v)}")
            pieces.append(f"{key}:[{numbers(f'*r[{i}]', len(v))}]")
        elif (type(v) in (list, tuple) and all(type(u) in (list, tuple) for u in v)
              and all(_is_number(x) for u in v for x in u)):
            checks.append(f"len(r[{i}]) == {len(v)}")
            rows = []
            for k, u in enumerate(v):
                checks.append(f"len(r[{i}][{k}]) == {len(u)}")
                rows.append(f"[{numbers(f'*r[{i}][{k}]', len(u))}]")
            pieces.append(f"{key}:[" + ",".join(rows) + "]")
        else:
            return None
    pieces.append(f'"t_s":{numbers("t", 1)}')
    template = ("{" + ",".join(pieces) + "}").encode()
    src = (f"def encode(r, t):\n"
           f"    if not ({' and '.join(checks)}):\n        return None\n"
           + "".join(f"    {s}\n" for s in texts)
           + f"    p = _numbers_json(({', '.join(exprs)},))\n"
           f"    if p is None or len(p) != {count}:\n        return None\n"
           f"    return _T % ({', '.join(args)},)\n")
    env: dict[str, Any] = {"_numbers_json": _numbers_json, "_text": _text, "_flag": _flag,
                           "_T": template}
    try:
        exec(compile(src, "<record_plan>", "exec"), env)   # our own generated code
    except (SyntaxError, ValueError):
        return None
    encode: RecordEncoder = env["encode"]
    return encode
