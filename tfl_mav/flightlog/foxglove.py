"""Foxglove well-known messages for the vehicle, its path and logs, built with Foxglove's SDK.

Nothing here is a hand-written schema: every message is a ``foxglove.messages`` class of
the official ``foxglove-sdk`` and goes into the file (and onto the live server) as the
protobuf bytes its ``encode()`` gives, under the schema its ``get_schema()`` gives (a
protobuf ``FileDescriptorSet`` named ``foxglove.<Type>``), so any Foxglove-aware reader
decodes it with the official classes (``foxglove-schemas-protobuf``).

Frames: Foxglove's 3-D panel is z-up; the recorder's world frame is ENU z-up too, so
positions and attitude go in unchanged under ``world``. ``base_link`` is the body frame
(x forward, z along thrust). Where the rotors sit is the caller's knowledge
(``rotor_xy_m``, body frame, m); this module only draws them.

Timestamps inside these messages are the *log* time (the clock Foxglove plays by), so
transforms and entities line up with the playback cursor (in lockstep, the flight's start
+ sim time: docs/design.md, "Time on the timeline").
"""

from __future__ import annotations

import math
from collections.abc import Sequence

from foxglove import messages as fm

__all__ = [
    "LOG_LEVELS",
    "SCHEMA_TYPES",
    "frame_transform",
    "log_entry",
    "mav_severity_to_level",
    "mean_thrust_entity",
    "path_scene",
    "schema",
    "stamp",
    "vehicle_scene",
]

WORLD = "world"
BODY = "base_link"

LOG_LEVELS = {"unknown": 0, "debug": 1, "info": 2, "warning": 3, "error": 4, "fatal": 5}
_LEVEL = {int(lv.value): lv for lv in (fm.LogLevel.Unknown, fm.LogLevel.Debug,
                                       fm.LogLevel.Info, fm.LogLevel.Warning,
                                       fm.LogLevel.Error, fm.LogLevel.Fatal)}

SCHEMA_TYPES = {"foxglove.FrameTransform": fm.FrameTransform,
                "foxglove.SceneUpdate": fm.SceneUpdate, "foxglove.Log": fm.Log}

_IDENTITY = fm.Quaternion(x=0.0, y=0.0, z=0.0, w=1.0)
_UP = fm.Quaternion(x=0.0, y=-math.sqrt(0.5), z=0.0, w=math.sqrt(0.5))   # +x → +z
_ZERO_DURATION = fm.Duration(sec=0, nsec=0)
_RED_RGB = (1.0, 0.05, 0.05)
_RED = fm.Color(r=1.0, g=0.05, b=0.05, a=1.0)
_BODY_COLOR = fm.Color(r=0.25, g=0.25, b=0.3, a=1.0)
_PATH_COLOR = fm.Color(r=0.1, g=0.8, b=1.0, a=1.0)
_MEAN_COLOR = fm.Color(r=0.1, g=0.9, b=0.2, a=1.0)


def schema(name: str) -> tuple[str, str, bytes]:
    """(name, encoding, data) of the official schema ``name`` (a key of SCHEMA_TYPES)."""
    s = SCHEMA_TYPES[name].get_schema()
    return s.name, s.encoding, bytes(s.data)


_MAX_SEC = 2**32 - 1


def stamp(ns: int) -> fm.Timestamp:
    """Nanoseconds → Foxglove ``Timestamp`` (never negative)."""
    sec, nsec = divmod(max(ns, 0), 1_000_000_000)
    if sec > _MAX_SEC:              # a time beyond the type's range (uint32 s): its end
        sec, nsec = _MAX_SEC, 999_999_999
    return fm.Timestamp(sec=sec, nsec=nsec)


def _vec(x: float, y: float, z: float) -> fm.Vector3:
    return fm.Vector3(x=x, y=y, z=z)


def _pose(x: float, y: float, z: float, q: fm.Quaternion = _IDENTITY) -> fm.Pose:
    return fm.Pose(position=_vec(x, y, z), orientation=q)


def frame_transform(ns: int, position_m: Sequence[float],
                    quaternion_wxyz: Sequence[float]) -> bytes:
    """``world`` → ``base_link``: the body's position (m, ENU) and attitude (body → world)."""
    w, x, y, z = quaternion_wxyz
    return fm.FrameTransform(timestamp=stamp(ns), parent_frame_id=WORLD, child_frame_id=BODY,
                             translation=_vec(*position_m),
                             rotation=fm.Quaternion(x=x, y=y, z=z, w=w)).encode()


def _thrust_rgb(fraction: float) -> tuple[float, float, float]:
    """Blue at 0 thrust → yellow at f_max (red is kept for the attacked rotor)."""
    u = min(max(fraction, 0.0), 1.0)
    return u, 0.4 + 0.5 * u, 1.0 - u


class _Airframe:
    """The parts of :func:`vehicle_scene` fixed by the rotor layout (poses, sizes, the
    body), built once per layout: the SDK's objects cost ~1-2 µs each, and a scene is
    drawn 50 times a second. Values are the ones the scene always drew."""

    def __init__(self, rotor_xy_m: tuple[tuple[float, float], ...]) -> None:
        arm = max(math.hypot(*xy) for xy in rotor_xy_m)
        arm_w, disc_d = 0.02, 0.7 * arm
        self.arm = arm
        self.body = fm.CubePrimitive(pose=_pose(0.0, 0.0, 0.0), size=_vec(0.12, 0.12, 0.05),
                                     color=_BODY_COLOR)
        self.rotors = []
        for x, y in rotor_xy_m:
            yaw = math.atan2(y, x)
            self.rotors.append((
                _pose(0.5 * x, 0.5 * y, 0.0, fm.Quaternion(x=0.0, y=0.0, z=math.sin(yaw / 2),
                                                           w=math.cos(yaw / 2))),
                _vec(math.hypot(x, y), arm_w, 0.015),           # the arm
                _pose(x, y, 0.02), _vec(disc_d, disc_d, 0.01),  # the disc
                _pose(x, y, 0.03, _UP),                         # the thrust arrow
                _pose(x, y, 0.25 * arm), _vec(0.08, 0.08, 0.08),   # the attack marker
                _pose(x, y, 0.25 * arm + 0.08)))                # its label


_AIRFRAMES: dict[tuple[tuple[float, float], ...], _Airframe] = {}


def _airframe(rotor_xy_m: Sequence[Sequence[float]]) -> _Airframe:
    key = tuple((float(x), float(y)) for x, y in rotor_xy_m)
    frame = _AIRFRAMES.get(key)
    if frame is None:
        if len(_AIRFRAMES) >= 16:
            _AIRFRAMES.clear()
        frame = _AIRFRAMES[key] = _Airframe(key)
    return frame


def _x_to(u: Sequence[float]) -> fm.Quaternion:
    """The rotation taking +x to the unit vector ``u`` (the arrow primitive points along x)."""
    ux, uy, uz = u
    w = 1.0 + ux
    if w < 1e-9:                       # u = −x: half a turn about z
        return fm.Quaternion(x=0.0, y=0.0, z=1.0, w=0.0)
    n = math.sqrt(w * w + uz * uz + uy * uy)
    return fm.Quaternion(x=0.0, y=-uz / n, z=uy / n, w=w / n)


def mean_thrust_entity(ns: int, position_m: Sequence[float],
                       mean_thrust_n: Sequence[float], thrust_max_n: float
                       ) -> fm.SceneEntity | None:
    """The mean thrust axis in ``world``: an arrow from the vehicle along the thrust
    averaged over the last revolutions (N, world; its length |F̄|/(2 f_max) m), labelled
    with |F̄| and its angle from the vertical. A spinning vehicle's body sweeps a cone
    ten times a second; this is the axis the spin law steers (n̄, the relaxed hover's mean
    thrust). None where there is no thrust to draw."""
    fx, fy, fz = mean_thrust_n
    norm = math.sqrt(fx * fx + fy * fy + fz * fz)
    if not (norm > 1e-6 and math.isfinite(norm)):
        return None
    u = (fx / norm, fy / norm, fz / norm)
    length = norm / (2.0 * thrust_max_n)
    px, py, pz = position_m
    arrow = fm.ArrowPrimitive(pose=_pose(px, py, pz, _x_to(u)), shaft_length=0.8 * length,
                              shaft_diameter=0.03, head_length=0.2 * length,
                              head_diameter=0.08, color=_MEAN_COLOR)
    tilt = math.degrees(math.acos(max(-1.0, min(1.0, u[2]))))
    text = fm.TextPrimitive(
        pose=_pose(px + u[0] * length, py + u[1] * length, pz + u[2] * length + 0.05),
        billboard=True, font_size=14.0, scale_invariant=True, color=_MEAN_COLOR,
        text=f"mean thrust {norm:.1f} N, {tilt:.0f} deg from vertical")
    return fm.SceneEntity(timestamp=stamp(ns), frame_id=WORLD, id="mean_thrust",
                          lifetime=_ZERO_DURATION, frame_locked=True, arrows=[arrow],
                          texts=[text])


def vehicle_scene(ns: int, rotor_xy_m: Sequence[Sequence[float]],
                  rotor_thrust_n: Sequence[float], thrust_max_n: float,
                  attack_rotor: int, label: str = "attack",
                  mean_thrust: tuple[Sequence[float], Sequence[float]] | None = None) -> bytes:
    """The vehicle in ``base_link``: a body, an arm, disc and thrust arrow per rotor
    (arrow length ∝ thrust, colour by thrust fraction of ``thrust_max_n``), and the
    attacked rotor (1-based, 0 = none) drawn red with a red marker sphere and the text
    "``label``: rotor N" (the controller's view says "detected": it knows no truth).
    ``mean_thrust`` = (position m, mean thrust N), both world: a second entity,
    :func:`mean_thrust_entity`."""
    frame = _airframe(rotor_xy_m)
    arm = frame.arm
    cubes = [frame.body]
    cylinders, arrows, spheres, texts = [], [], [], []
    for i, (arm_pose, arm_size, disc_pose, disc_size, arrow_pose, mark_pose, mark_size,
            text_pose) in enumerate(frame.rotors):
        frac = rotor_thrust_n[i] / thrust_max_n
        attacked = attack_rotor == i + 1
        r, g, b = _RED_RGB if attacked else _thrust_rgb(frac)
        color = fm.Color(r=r, g=g, b=b, a=1.0)
        cubes.append(fm.CubePrimitive(pose=arm_pose, size=arm_size, color=color))
        cylinders.append(fm.CylinderPrimitive(
            pose=disc_pose, size=disc_size, bottom_scale=1.0, top_scale=1.0,
            color=fm.Color(r=r, g=g, b=b, a=0.6)))
        length = max(min(frac, 1.5), 0.0) * 2.0 * arm
        if length > 0.0:
            arrows.append(fm.ArrowPrimitive(
                pose=arrow_pose, shaft_length=0.75 * length, shaft_diameter=0.015,
                head_length=0.25 * length, head_diameter=0.04, color=color))
        if attacked:
            spheres.append(fm.SpherePrimitive(pose=mark_pose, size=mark_size, color=_RED))
            texts.append(fm.TextPrimitive(pose=text_pose, billboard=True, font_size=14.0,
                                          scale_invariant=True, color=_RED,
                                          text=f"{label}: rotor {attack_rotor}"))
    entity = fm.SceneEntity(timestamp=stamp(ns), frame_id=BODY, id="vehicle",
                            lifetime=_ZERO_DURATION, frame_locked=True, cubes=cubes,
                            cylinders=cylinders, arrows=arrows, spheres=spheres, texts=texts)
    entities = [entity]
    if mean_thrust is not None:
        mean = mean_thrust_entity(ns, mean_thrust[0], mean_thrust[1], thrust_max_n)
        if mean is not None:
            entities.append(mean)
    return fm.SceneUpdate(entities=entities).encode()


def path_scene(ns: int, points_m: Sequence[Sequence[float]]) -> bytes:
    """The path as one line strip in ``world`` (points in m, ENU)."""
    line = fm.LinePrimitive(type=fm.LinePrimitiveLineType.LineStrip, pose=_pose(0.0, 0.0, 0.0),
                            thickness=3.0, scale_invariant=True,
                            points=[fm.Point3(x=p[0], y=p[1], z=p[2]) for p in points_m],
                            color=_PATH_COLOR)
    entity = fm.SceneEntity(timestamp=stamp(ns), frame_id=WORLD, id="path",
                            lifetime=_ZERO_DURATION, frame_locked=True, lines=[line])
    return fm.SceneUpdate(entities=[entity]).encode()


def log_entry(ns: int, level: int, message: str, name: str) -> bytes:
    return fm.Log(timestamp=stamp(ns), level=_LEVEL.get(level, fm.LogLevel.Unknown),
                  message=message, name=name, file="", line=0).encode()


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
