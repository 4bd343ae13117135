"""Scalar helpers the laws and the scenario expressions share.

One definition each, so that a law, its compiled step (the accelerator seam inlines the
call) and a scenario's ``clip(...)`` clamp alike.
"""

from __future__ import annotations

__all__ = ["clamp"]


def clamp(x: float, lo: float, hi: float) -> float:
    """``min(max(x, lo), hi)`` written out: the same result, NaN and ties included (a NaN
    ``x`` stays NaN; for ``lo > hi``, ``hi``)."""
    x = lo if lo > x else x
    return hi if hi < x else x
