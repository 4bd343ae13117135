"""Foxglove well-known messages (as JSON-ready dicts) for the vehicle, its path and logs.

Frames: Foxglove's 3-D panel is z-up; the paper frame is ENU z-up too, so positions and
attitude go in unchanged under ``world`` (docs/design.md, "Frames"). ``base_link`` is the body frame
(b1 forward, b3 along thrust). Rotor positions in the body follow the paper's "+" layout as
fixed by the mixer rows ``τ_p = l(f4 − f2)``, ``τ_q = l(f3 − f1)``: rotor 1 on +b1, 2 on −b2,
3 on −b1, 4 on +b2.

Timestamps inside these messages are the *log* time (the clock Foxglove plays by), so
transforms and entities line up with the playback cursor; sim time is in ``publish_time``.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

__all__ = [
    "LOG_LEVELS",
    "ROTOR_DIRECTIONS",
    "frame_transform",
    "log_entry",
    "mav_severity_to_level",
    "path_scene",
    "stamp",
    "vehicle_scene",
]

WORLD = "world"
BODY = "base_link"
ROTOR_DIRECTIONS = ((1.0, 0.0), (0.0, -1.0), (-1.0, 0.0), (0.0, 1.0))   # unit (b1, b2)

LOG_LEVELS = {"unknown": 0, "debug": 1, "info": 2, "warning": 3, "error": 4, "fatal": 5}

_IDENTITY = {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}
_ZERO_DURATION = {"sec": 0, "nsec": 0}
_RED = {"r": 1.0, "g": 0.05, "b": 0.05, "a": 1.0}
_BODY_COLOR = {"r": 0.25, "g": 0.25, "b": 0.3, "a": 1.0}
_PATH_COLOR = {"r": 0.1, "g": 0.8, "b": 1.0, "a": 1.0}


def stamp(ns: int) -> dict[str, int]:
    """Nanoseconds → Foxglove ``time`` {sec, nsec} (never negative)."""
    sec, nsec = divmod(max(ns, 0), 1_000_000_000)
    return {"sec": sec, "nsec": nsec}


def _vec(x: float, y: float, z: float) -> dict[str, float]:
    return {"x": x, "y": y, "z": z}


def _pose(x: float, y: float, z: float) -> dict[str, Any]:
    return {"position": _vec(x, y, z), "orientation": _IDENTITY}


def frame_transform(ns: int, position_m: Sequence[float],
                    quaternion_wxyz: Sequence[float]) -> dict[str, Any]:
    """``world`` → ``base_link``: the body's position (m, ENU) and attitude (body → world)."""
    w, x, y, z = quaternion_wxyz
    return {"timestamp": stamp(ns), "parent_frame_id": WORLD, "child_frame_id": BODY,
            "translation": _vec(*position_m), "rotation": {"x": x, "y": y, "z": z, "w": w}}


def _thrust_color(fraction: float) -> dict[str, float]:
    """Blue at 0 thrust → yellow at f_max (red is kept for the attacked rotor)."""
    u = min(max(fraction, 0.0), 1.0)
    return {"r": u, "g": 0.4 + 0.5 * u, "b": 1.0 - u, "a": 1.0}


def _entity(ns: int, frame_id: str, entity_id: str, **primitives: list[Any]) -> dict[str, Any]:
    out: dict[str, Any] = {
        "timestamp": stamp(ns), "frame_id": frame_id, "id": entity_id,
        "lifetime": _ZERO_DURATION, "frame_locked": True, "metadata": [],
        "arrows": [], "cubes": [], "spheres": [], "cylinders": [], "lines": [],
        "triangles": [], "texts": [], "models": []}
    out.update(primitives)
    return out


def vehicle_scene(ns: int, arm_m: float, rotor_thrust_n: Sequence[float],
                  thrust_max_n: float, attack_rotor: int) -> dict[str, Any]:
    """The quadrotor in ``base_link``: a body, four arms and four rotor discs, each rotor
    coloured by its thrust fraction of ``thrust_max_n``; the attacked rotor (1-4) red."""
    arm_w, disc_d = 0.02, 0.35 * arm_m * 2.0
    cubes = [{"pose": _pose(0.0, 0.0, 0.0), "size": _vec(0.12, 0.12, 0.05),
              "color": _BODY_COLOR}]
    cylinders = []
    for i, (dx, dy) in enumerate(ROTOR_DIRECTIONS):
        color = _RED if attack_rotor == i + 1 else _thrust_color(rotor_thrust_n[i] / thrust_max_n)
        half = 0.5 * arm_m
        cubes.append({"pose": _pose(dx * half, dy * half, 0.0),
                      "size": _vec(arm_m if dx else arm_w, arm_m if dy else arm_w, 0.015),
                      "color": color})
        cylinders.append({"pose": _pose(dx * arm_m, dy * arm_m, 0.02),
                          "size": _vec(disc_d, disc_d, 0.01), "bottom_scale": 1.0,
                          "top_scale": 1.0, "color": {**color, "a": 0.6}})
    return {"deletions": [], "entities": [_entity(ns, BODY, "vehicle", cubes=cubes,
                                                  cylinders=cylinders)]}


def path_scene(ns: int, points_m: Sequence[Sequence[float]]) -> dict[str, Any]:
    """The path as one line strip in ``world`` (points in m, ENU)."""
    line = {"type": 0, "pose": _pose(0.0, 0.0, 0.0), "thickness": 3.0,
            "scale_invariant": True, "points": [_vec(*p) for p in points_m],
            "color": _PATH_COLOR, "colors": [], "indices": []}
    return {"deletions": [], "entities": [_entity(ns, WORLD, "path", lines=[line])]}


def log_entry(ns: int, level: int, message: str, name: str) -> dict[str, Any]:
    return {"timestamp": stamp(ns), "level": level, "message": message, "name": name,
            "file": "", "line": 0}


def mav_severity_to_level(severity: int) -> int:
    """MAV_SEVERITY (0 EMERGENCY … 7 DEBUG) → foxglove.LogLevel."""
    if severity <= 1:
        return LOG_LEVELS["fatal"]
    if severity <= 3:
        return LOG_LEVELS["error"]
    if severity == 4:
        return LOG_LEVELS["warning"]
    if severity <= 6:
        return LOG_LEVELS["info"]
    return LOG_LEVELS["debug"]
