"""Option values every command checks the same way, at parse time (argparse ``type=``).

A bad value is a usage error: argparse prints the usage line and
``tfl-mav CMD: error: argument --duration: ...``, exit code 2, before anything starts.
"""

from __future__ import annotations

import argparse
import math

__all__ = ["MAX_DURATION_S", "duration_s"]

MAX_DURATION_S = 86400.0
"""The longest run (s of sim time), as ``run.duration_s`` accepts it."""


def duration_s(text: str) -> float:
    """A run length in sim seconds: finite, > 0 and at most :data:`MAX_DURATION_S`."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number of seconds, got {text!r}") \
            from None
    if not (math.isfinite(value) and 0 < value <= MAX_DURATION_S):
        raise argparse.ArgumentTypeError(
            f"must be > 0 and <= {MAX_DURATION_S:g} seconds of sim time, got {text!r}")
    return value
