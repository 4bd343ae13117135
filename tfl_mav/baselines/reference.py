"""From a path to a tracking reference: closest point, tangent × speed, curvature feedforward.

The TFL law makes the path invariant and needs no time parameterisation; a trajectory
tracker needs a reference point, velocity and acceleration every tick. The reference here is
the one the project's safe law already flies (:mod:`tfl_mav.control.safe.recovery`): the closest
point p* of the path to the vehicle (:class:`~tfl_mav.control.safe.recovery.PathProjector`,
warm-started Newton on ⟨y − σ(λ), σ'(λ)⟩ = 0), the velocity v* = s T (unit tangent T
towards increasing λ, the direction TFL flies, at the path speed s), and the acceleration
of a point moving along the path at constant speed, a* = s² κN (κN the curvature vector).
Because p* is the *closest* point, the position error p* − y is normal to the path: the
trackers are judged only on the distance they keep, as TFL is, never on a schedule.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import NamedTuple

from tfl_mav.control.path.paths import Path
from tfl_mav.control.safe.recovery import PathProjector
from tfl_mav.control.tfl.law_types import ModelParams
from tfl_mav.from_scenario import model_params, scenario_path
from tfl_mav.scenario import Scenario

__all__ = ["PathReference", "Reference", "controller_model"]

Vec3 = tuple[float, float, float]


class Reference(NamedTuple):
    """One reference sample, paper frame (z up)."""

    position_m: Vec3          # p*: the closest point of the path
    velocity_mps: Vec3        # v* = s T
    acceleration_mps2: Vec3   # a* = s² κN
    tangent: Vec3             # T, unit
    distance_m: float         # |y − p*|


class PathReference:
    """The reference for a vehicle at ``position_m`` on ``path`` flown at ``speed_mps``."""

    def __init__(self, path: Path, speed_mps: float) -> None:
        self.path = path
        self.speed_mps = float(speed_mps)
        self.projector = PathProjector(path)

    @classmethod
    def for_scenario(cls, scenario: Scenario) -> PathReference:
        return cls(scenario_path(scenario), scenario.path.speed_mps)

    @property
    def lam(self) -> float | None:
        """λ of the last closest point (None: the next call searches the whole path)."""
        return self.projector.lam

    def start_at(self, lam: float | None) -> None:
        """The next closest-point search starts at ``lam`` (None: a global search)."""
        self.projector.lam = lam

    def at(self, position_m: Sequence[float]) -> Reference | None:
        """The reference for ``position_m`` (m), or None if the projection fails (the state
        is not finite); the next call then searches the whole path again."""
        y = tuple(float(c) for c in position_m)
        if not all(math.isfinite(c) for c in y):
            self.projector.forget()
            return None
        proj = self.projector.project(y)
        if proj is None:
            self.projector.forget()
            return None
        p, t, k, dist = proj
        s = self.speed_mps
        s2 = s * s
        return Reference(p, (s * t[0], s * t[1], s * t[2]), (s2 * k[0], s2 * k[1], s2 * k[2]),
                         t, dist)


def controller_model(scenario: Scenario) -> ModelParams:
    """The vehicle model every controller gets: the scenario's vehicle with the model error
    of its ``[controller]`` section (mass × ``model_mass_scale``, inertia ×
    ``model_inertia_scale``), exactly the TFL law's."""
    return model_params(scenario)
