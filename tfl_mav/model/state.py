"""The vehicle state every part of tfl-mav passes around, in the paper frame.

Physics produces it (``tfl_mav.sitl.simulator``), the wire decodes into it
(:func:`tfl_mav.model.frames.paper_from_odometry`), the flight computer and the law consume it.
One type, so a field means the same thing wherever it is read.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

__all__ = ["State"]


@dataclass(frozen=True, slots=True, init=False)
class State:
    """Measured vehicle state, paper frame (§III): inertial ENU with z **up**, body FLU.

    ``position_m``/``velocity_mps``: inertial (x, y, z) and its rate; ``quaternion_wxyz``:
    body FLU → inertial ENU (unit); ``body_rates_radps``: (p, q, r) about b1, b2, b3;
    ``time_usec``: the sim time it was sampled at (µs, the wire's ``time_usec``; 0 when the
    caller keeps time itself).
    """

    position_m: Sequence[float]
    velocity_mps: Sequence[float]
    quaternion_wxyz: Sequence[float]
    body_rates_radps: Sequence[float]
    time_usec: int = 0

    def __init__(self, position_m: Sequence[float], velocity_mps: Sequence[float],
                 quaternion_wxyz: Sequence[float], body_rates_radps: Sequence[float],
                 time_usec: int = 0) -> None:
        # What the generated __init__ of a frozen dataclass does, through the slots'
        # descriptors instead of object.__setattr__ by name: ~1/3 cheaper, and a State is
        # built several times a tick (simulator, wire, state filter).
        _set_position(self, position_m)
        _set_velocity(self, velocity_mps)
        _set_quaternion(self, quaternion_wxyz)
        _set_rates(self, body_rates_radps)
        _set_time(self, time_usec)

    @property
    def time_s(self) -> float:
        return self.time_usec * 1e-6


_set_position = State.position_m.__set__            # type: ignore[attr-defined]
_set_velocity = State.velocity_mps.__set__          # type: ignore[attr-defined]
_set_quaternion = State.quaternion_wxyz.__set__     # type: ignore[attr-defined]
_set_rates = State.body_rates_radps.__set__         # type: ignore[attr-defined]
_set_time = State.time_usec.__set__                 # type: ignore[attr-defined]
