"""Precompiled JSON for a caller's per-tick record (``/controller/state``).

Why: the daemon hands its recorder child one compact tuple a tick (``tick_state``: mode,
rotor, estimates, thrusts, the chains ξ and η, CUSUM, reason ...). Naming it as a dict and
running ``json`` over it cost the child ~20-25 µs a tick, mostly printing ~25 floats. A
record keeps its shape from tick to tick, so :func:`record_plan` writes, for the shape of
one sample record, a small function that checks the shape (lengths, types), prints all
numbers with one msgspec call (:func:`~tfl_mav.flightlog.jsonenc._numbers_json`, the same
text as ``repr``/``json``), the strings with ``json``'s own ``encode_basestring_ascii``,
and fills one ``%`` template: the bytes ``JsonEncoder.dumps({**record, "t_s": t})`` writes.
NaN/inf/None values (a nominal flight's attack estimate is NaN every tick) are left out
and listed under ``_nonfinite`` by a template per pattern of such keys, as the dict path
does. Any record it cannot print exactly (another shape, numpy values, a NaN time)
returns None: the caller takes the careful path.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from json.encoder import encode_basestring_ascii
from typing import Any

from msgspec import Raw

from tfl_mav.flightlog.jsonenc import JsonEncoder, NullMasks, _numbers_json, _numbers_json_nulls
from tfl_mav.flightlog.jsonobj import ObjectJson
from tfl_mav.flightlog.jsonobj import encode as encode_obj

__all__ = ["record_plan"]

RecordEncoder = Callable[[Sequence[Any], float], "bytes | None"]


def _is_number(v: Any) -> bool:
    return type(v) in (int, float)


def _text(v: Any) -> bytes | None:
    return encode_basestring_ascii(v).encode() if type(v) is str else None


_TEXTS_MAX = 256                # texts kept (a tick's mode and reason repeat)


def _texts() -> tuple[dict[str, tuple[Raw, bytes, int]],
                      Callable[[Any], tuple[Raw, bytes, int] | None]]:
    """A cache of a plan's texts: str → (its JSON as a ``msgspec.Raw``, as bytes, how many
    ``e`` it holds), and the function that fills it (None: not a str)."""
    cache: dict[str, tuple[Raw, bytes, int]] = {}

    def entry(v: Any) -> tuple[Raw, bytes, int] | None:
        b = _text(v)
        if b is None:
            return None
        if len(cache) >= _TEXTS_MAX:
            cache.clear()
        out = cache[v] = (Raw(b), b, b.count(b"e"))
        return out

    return cache, entry


def _flag(v: Any) -> bytes | None:
    return b"true" if v is True else b"false" if v is False else None


def record_plan(fields: Sequence[str], sample: Sequence[Any]) -> RecordEncoder | None:
    """``encode(record, t_s) -> bytes | None`` for records shaped like ``sample`` (values
    named by ``fields``), or None if the sample holds something it does not print (None,
    numpy values, dicts, deeper nesting). NaN/inf/None values: the record without their
    keys, listed under ``_nonfinite`` (:class:`~tfl_mav.flightlog.jsonenc.NullMasks`, one
    template per pattern, each checked against the dict encoder on first use)."""
    if len(sample) != len(fields):
        return None
    checks = [f"len(r) == {len(sample)}"]
    exprs: list[str] = []          # expressions of the numbers, in output order
    count = 0                      # how many numbers they make
    args: list[str] = []           # the template's arguments, in output order
    pieces: list[str] = []
    texts: list[str] = []          # statements computing text/flag arguments
    text_args: list[str] = []
    keys: list[tuple[str, bytes, list[int]]] = []   # NullMasks: key, value, arg indices
    owner: list[int] = []
    obj_args: list[str] = []       # the Struct's values (jsonobj), one per key
    leaves: list[str] = []         # every printed value, in output order (for reprint)
    obj_texts: list[str] = []      # statements checking the values for the Struct
    text_e: list[str] = []         # the e's of its texts
    n_flags = 0

    def numbers(expr: str, n: int) -> str:
        nonlocal count
        exprs.append(expr)
        args.extend(f"p[{count + j}]" for j in range(n))
        owner.extend([len(keys)] * n)
        keys.append(("", b"", list(range(count, count + n))))   # completed below
        count += n
        return ",".join(["%s"] * n)

    for i, (name, v) in enumerate(zip(fields, sample, strict=True)):
        key = encode_basestring_ascii(name).replace("%", "%%")
        if _is_number(v):
            val = numbers(f"r[{i}]", 1)
            obj_args.append(f"r[{i}]")
            leaves.append(f"r[{i}]")
        elif type(v) in (bool, str):
            fn = "_flag" if type(v) is bool else "_text"
            texts.append(f"a{i} = {fn}(r[{i}])\n    if a{i} is None:\n        return None")
            args.append(f"a{i}")
            text_args.append(f"a{i}")
            keys.append(("", b"", [-len(text_args)]))
            val = "%s"
            if type(v) is bool:        # msgspec prints it as json does: one e either way
                n_flags += 1
                obj_texts.append(f"if type(r[{i}]) is not bool:\n        return None")
                obj_args.append(f"r[{i}]")
                leaves.append(f"r[{i}]")
            else:                      # printed once as json does, then a Raw
                obj_texts.append(f"x{i} = _tc.get(r[{i}]) if type(r[{i}]) is str else None\n"
                                 f"    if x{i} is None:\n"
                                 f"        x{i} = _text_entry(r[{i}])\n"
                                 f"        if x{i} is None:\n            return None")
                obj_args.append(f"x{i}[0]")
                leaves.append(f"x{i}[1]")
                text_e.append(f"x{i}[2]")
        elif type(v) in (list, tuple) and all(map(_is_number, v)):
            checks.append(f"len(r[{i}]) == {len(v)}")
            val = f"[{numbers(f'*r[{i}]', len(v))}]"
            obj_args.append(f"r[{i}]")
            leaves.append(f"*r[{i}]")
        elif (type(v) in (list, tuple) and all(type(u) in (list, tuple) for u in v)
              and all(_is_number(x) for u in v for x in u)):
            checks.append(f"len(r[{i}]) == {len(v)}")
            rows = []
            first = len(keys)
            for k, u in enumerate(v):
                checks.append(f"len(r[{i}][{k}]) == {len(u)}")
                rows.append(f"[{numbers(f'*r[{i}][{k}]', len(u))}]")
                leaves.append(f"*r[{i}][{k}]")
            obj_args.append(f"r[{i}]")
            refs = [j for _, _, rr in keys[first:] for j in rr]
            del keys[first:]
            owner[len(owner) - len(refs):] = [first] * len(refs)
            keys.append(("", b"", refs))
            val = "[" + ",".join(rows) + "]"
        else:
            return None
        pieces.append(f"{key}:{val}")
        keys[-1] = (name, val.encode(), keys[-1][2])
    val = numbers("t", 1)
    obj_args.append("t")
    leaves.append("t")
    pieces.append(f'"t_s":{val}')
    keys[-1] = ("t_s", val.encode(), keys[-1][2])
    # text arguments come after the numbers in the masked argument list
    keys = [(k, v, [count - j - 1 if j < 0 else j for j in refs]) for k, v, refs in keys]
    template = ("{" + ",".join(pieces) + "}").encode()
    try:                           # the whole object by one msgspec call (jsonobj)
        obj = ObjectJson([*fields, "t_s"], obj_args, literal_e=n_flags)
    except (ValueError, TypeError):
        obj = None
    e_count = " + ".join([str(obj.key_e if obj else 0), *text_e])
    src = (f"def encode(r, t):\n"
           f"    if not ({' and '.join(checks)}):\n        return None\n"
           + ("".join(f"    {s}\n" for s in texts) if obj is None else
              "".join(f"    {s}\n" for s in obj_texts) +
              f"    try:\n"
              f"        out = _enc(_S({', '.join(obj_args)}))\n"
              f"    except (TypeError, ValueError, OverflowError):\n"
              f"        out = b'null'\n"
              f"    if b'null' not in out:\n"
              f"        if out.count(b'e') == {e_count} and b'0.0000' not in out:\n"
              f"            return out\n"
              f"        out = _reprint(out, ({', '.join(leaves)},))\n"
              f"        if out is not None:\n"
              f"            return out\n"
              + "".join(f"    {s}\n" for s in texts))
           + f"    v = ({', '.join(exprs)},)\n"
           f"    p = _numbers_json(v)\n"
           f"    if p is None or len(p) != {count}:\n"
           f"        return _masked(r, t, v, ({''.join(a + ', ' for a in text_args)}))\n"
           f"    return _T % ({', '.join(args)},)\n")
    tcache, tentry = _texts()
    env: dict[str, Any] = {"_numbers_json": _numbers_json, "_text": _text, "_flag": _flag,
                           "_T": template, "_Raw": Raw, "_enc": encode_obj,
                           "_S": obj.struct if obj else None, "_reprint": ObjectJson.reprint,
                           "_tc": tcache, "_text_entry": tentry,
                           "_masked": _masked_encoder(fields, NullMasks(keys, owner), count)}
    try:
        exec(compile(src, "<record_plan>", "exec"), env)   # our own generated code
    except (SyntaxError, ValueError):
        return None
    encode: RecordEncoder = env["encode"]
    return encode


def _masked_encoder(fields: Sequence[str], masks: NullMasks, count: int) -> Callable[
        [Sequence[Any], float, tuple[Any, ...], tuple[bytes, ...]], bytes | None]:
    """The NaN/inf/None case of a plan: its record without those keys (``_nonfinite``)."""
    checked: dict[tuple[int, ...], bool] = {}
    t_key = len(masks.keys) - 1
    dumps = JsonEncoder().dumps

    def masked(r: Sequence[Any], t: float, v: tuple[Any, ...],
               texts: tuple[bytes, ...]) -> bytes | None:
        q = _numbers_json_nulls(v)
        if q is None or len(q) != count:
            return None
        mask = masks.mask(q)
        if not mask or t_key in mask:     # a NaN time: the careful path says so
            return None
        ok = checked.get(mask)
        if ok is False:
            return None
        data = masks.encode(mask, (*q, *texts))
        if ok is None:                    # first use of this pattern: checked once
            ok = checked[mask] = data == dumps({**dict(zip(fields, r, strict=True)),
                                                "t_s": t})
        return data if ok else None

    return masked
