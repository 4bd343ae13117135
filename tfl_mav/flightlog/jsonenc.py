"""Compact JSON for the recorder's JSON channels, with NaN/inf/None left out.

JSON has no NaN, and Foxglove wants no null in a number field: such a value (or a list
holding one) is left out of the message and its dotted key listed under ``_nonfinite``
(:data:`tfl_mav.flightlog.schemas.NONFINITE_KEY`).
"""

from __future__ import annotations

import base64
import json
import math
from collections.abc import Iterable, Mapping
from typing import Any

from tfl_mav.flightlog.schemas import NONFINITE_KEY

__all__ = ["JsonEncoder", "all_finite", "drop_nonfinite"]


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
