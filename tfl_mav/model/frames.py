"""The ONE place where the paper frame (z up) and MAVLink's NED/FRD frames meet.

Frame-free rotation math (quaternions, rotation matrices, Euler) is in
:mod:`tfl_mav.model.geometry`.

Paper frame (physics and controller): inertial x, y, z with z **up**, treated as ENU
(x = east, y = north, z = up); body b1 forward, b2 left, b3 up (FLU). Attitude is the
rotation body (FLU) → inertial (ENU), ``R_enu_flu``; the Euler chart is the paper's ZYX
(eq. (1): R = Rz(ψ) Ry(θ) Rx(φ)).

MAVLink (on the wire): ``MAV_FRAME_LOCAL_NED`` (x = north, y = east, z = down) for position
and velocity, ``MAV_FRAME_BODY_FRD`` for the body (forward, right, down).

    vectors:      (x, y, z)_ENU  ↔  (y, x, −z)_NED          v_ned = P v_enu
    body vectors: (a, b, c)_FLU  ↔  (a, −b, −c)_FRD          w_frd = Q w_flu
    attitude:     R_ned_frd = P · R_enu_flu · Q
    quaternion:   q_ned_frd = ((w+z), (x+y), (x−y), (w−z)) / √2   for q_enu_flu = (w, x, y, z)

with P = [[0,1,0],[1,0,0],[0,0,−1]] (a proper rotation: 180° about (1,1,0)/√2) and
Q = diag(1, −1, −1) (180° about b1). Both are their own inverses, so every conversion here is
an involution: the same formula goes either way. Note the sign flip of pitch: in FLU a
positive θ about b2 (left) puts the nose **down**; in FRD a positive pitch puts it **up**.

Everything here is scalar float arithmetic in a fixed order, with no matrix product (numpy's
BLAS chooses its own order and fuses multiply-adds, so its bits depend on the library and
the processor). P and Q are signed permutations, so each entry of a converted vector or
matrix is ± one entry of the input, exact. The one genuine product, R(q) v in
:func:`paper_from_odometry_fields` and :func:`body_to_inertial`, is summed left to right:
``(r₀ v₀ + r₁ v₁) + r₂ v₂``, rounded after every operation, the same on any IEEE machine.

``ODOMETRY`` carries the twist (linear velocity and body rates) in ``child_frame_id``
(MAVLink spec, ROS REP 147). With ``child_frame_id = MAV_FRAME_BODY_FRD`` the velocity is
therefore body-frame FRD, not NED; :func:`odometry_from_paper` and :func:`paper_from_odometry`
get this right in both directions (and the latter also accepts a LOCAL_NED twist).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any, NamedTuple

import numpy as np

from tfl_mav.model.state import State

__all__ = [
    "MAV_FRAME_BODY_FRD",
    "MAV_FRAME_LOCAL_NED",
    "P_ENU_TO_NED",
    "Q_FLU_TO_FRD",
    "OdometryFields",
    "body_to_inertial",
    "enu_to_ned",
    "flu_to_frd",
    "frd_to_flu",
    "ned_to_enu",
    "odometry_from_paper",
    "paper_from_odometry",
    "paper_from_odometry_fields",
    "quaternion_enu_flu_to_ned_frd",
    "quaternion_ned_frd_to_enu_flu",
    "rotation_enu_flu_to_ned_frd",
    "rotation_ned_frd_to_enu_flu",
]

MAV_FRAME_LOCAL_NED = 1
MAV_FRAME_BODY_FRD = 12

P_ENU_TO_NED = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
Q_FLU_TO_FRD = np.diag([1.0, -1.0, -1.0])

_SQRT1_2 = math.sqrt(0.5)
_ODOMETRY_FLOATS = ("x", "y", "z", "vx", "vy", "vz", "rollspeed", "pitchspeed", "yawspeed")


# ---------------------------------------------------------------------------- vectors
def enu_to_ned(v_enu: Sequence[float]) -> np.ndarray:
    """Inertial vector ENU (x east, y north, z up) → NED: (x, y, z) ↦ (y, x, −z)."""
    return np.array([v_enu[1], v_enu[0], -v_enu[2]], dtype=float)


def ned_to_enu(v_ned: Sequence[float]) -> np.ndarray:
    """Inertial vector NED → ENU: (n, e, d) ↦ (e, n, −d)."""
    return np.array([v_ned[1], v_ned[0], -v_ned[2]], dtype=float)


def flu_to_frd(w_flu: Sequence[float]) -> np.ndarray:
    """Body vector FLU → FRD, e.g. body rates (p, q, r) ↦ (p, −q, −r)."""
    return np.array([w_flu[0], -w_flu[1], -w_flu[2]], dtype=float)


def frd_to_flu(w_frd: Sequence[float]) -> np.ndarray:
    """Body vector FRD → FLU: (a, b, c) ↦ (a, −b, −c)."""
    return np.array([w_frd[0], -w_frd[1], -w_frd[2]], dtype=float)


# ---------------------------------------------------------------------------- attitude
def _p_r_q(R: np.ndarray) -> np.ndarray:
    """P · R · Q by moving entries: P swaps rows 0 and 1 and negates row 2, Q negates
    columns 1 and 2 (row 2 thus keeps columns 1 and 2 and negates column 0)."""
    (a, b, c), (d, e, f), (g, h, i) = np.asarray(R, dtype=float).tolist()
    return np.array([[d, -e, -f], [a, -b, -c], [-g, h, i]])


def rotation_enu_flu_to_ned_frd(R_enu_flu: np.ndarray) -> np.ndarray:
    """R_ned_frd = P · R_enu_flu · Q (3×3, body → world)."""
    return _p_r_q(R_enu_flu)


def rotation_ned_frd_to_enu_flu(R_ned_frd: np.ndarray) -> np.ndarray:
    """R_enu_flu = P · R_ned_frd · Q (P, Q are involutions)."""
    return _p_r_q(R_ned_frd)


def quaternion_enu_flu_to_ned_frd(q_enu_flu: Sequence[float]) -> np.ndarray:
    """(w, x, y, z) of body FLU → ENU  ↦  (w, x, y, z) of body FRD → NED.

    q_P ⊗ q ⊗ q_Q with q_P = (0, 1, 1, 0)/√2 and q_Q = (0, 1, 0, 0), simplified.
    """
    w, x, y, z = q_enu_flu
    s = _SQRT1_2
    return np.array([s * (w + z), s * (x + y), s * (x - y), s * (w - z)])


def quaternion_ned_frd_to_enu_flu(q_ned_frd: Sequence[float]) -> np.ndarray:
    """Inverse of :func:`quaternion_enu_flu_to_ned_frd` (the same involution)."""
    return quaternion_enu_flu_to_ned_frd(q_ned_frd)


# ---------------------------------------------------------------------------- ODOMETRY
class OdometryFields(NamedTuple):
    """The frame-dependent fields of ODOMETRY with ``frame_id = LOCAL_NED`` and
    ``child_frame_id = BODY_FRD``: NED position (m), quaternion body FRD → NED, body-FRD
    velocity (m/s) and body-FRD rates (rad/s). A NamedTuple: built every control tick."""

    x: float
    y: float
    z: float
    q: tuple[float, float, float, float]
    vx: float
    vy: float
    vz: float
    rollspeed: float
    pitchspeed: float
    yawspeed: float


def odometry_from_paper(position_m: Sequence[float], velocity_mps: Sequence[float],
                        quaternion_wxyz: Sequence[float],
                        body_rates_radps: Sequence[float]) -> OdometryFields:
    """Paper-frame state (ENU/FLU) → ODOMETRY fields (NED pose, body-FRD twist).

    Plain float arithmetic: this runs every control tick in the simulator's hot path.
    ``velocity_mps`` is inertial ENU; it is sent as the body-FRD velocity Q Rᵀ v because
    ODOMETRY's twist is expressed in ``child_frame_id`` (BODY_FRD).
    """
    px, py, pz = position_m
    vx, vy, vz = velocity_mps
    w, x, y, z = quaternion_wxyz
    p, q, r = body_rates_radps
    # Rᵀ v with R = R(q) body FLU → ENU: body-frame velocity in FLU.
    vb1 = (1 - 2 * (y * y + z * z)) * vx + 2 * (x * y + w * z) * vy + 2 * (x * z - w * y) * vz
    vb2 = 2 * (x * y - w * z) * vx + (1 - 2 * (x * x + z * z)) * vy + 2 * (y * z + w * x) * vz
    vb3 = 2 * (x * z + w * y) * vx + 2 * (y * z - w * x) * vy + (1 - 2 * (x * x + y * y)) * vz
    s = _SQRT1_2
    return OdometryFields(
        py, px, -pz,
        (s * (w + z), s * (x + y), s * (x - y), s * (w - z)),
        vb1, -vb2, -vb3,
        p, -q, -r,
    )


_sqrt = math.sqrt


def body_to_inertial(rows: Sequence[Sequence[float]], v: Sequence[float]) -> list[float]:
    """R v for R given by its ``rows`` (:func:`~tfl_mav.model.geometry.rotation_rows`): each row's
    products summed left to right, ``(r₀ v₀ + r₁ v₁) + r₂ v₂`` (the order
    :func:`paper_from_odometry_fields` uses)."""
    (a, b, c), (d, e, f), (g, h, i) = rows
    x, y, z = v
    return [a * x + b * y + c * z, d * x + e * y + f * z, g * x + h * y + i * z]


def paper_from_odometry(msg: object) -> State:
    """A decoded ODOMETRY message → :class:`~tfl_mav.model.state.State` (ENU/FLU, SI units).

    Accepts ``frame_id = MAV_FRAME_LOCAL_NED`` and a twist in ``child_frame_id`` =
    ``MAV_FRAME_BODY_FRD`` (what our simulator sends) or ``MAV_FRAME_LOCAL_NED``. Raises
    ValueError naming the field for any other frame, a non-finite value, or a quaternion
    that is not (close to) unit length; the caller counts and drops the message.
    """
    m: Any = msg
    qw, qx, qy, qz = m.q
    return paper_from_odometry_fields(
        int(m.time_usec), float(m.x), float(m.y), float(m.z), float(qw), float(qx),
        float(qy), float(qz), float(m.vx), float(m.vy), float(m.vz), float(m.rollspeed),
        float(m.pitchspeed), float(m.yawspeed), m.frame_id, m.child_frame_id)


def paper_from_odometry_fields(time_usec: int, px: float, py: float, pz: float, qw: float,
                               qx: float, qy: float, qz: float, vx: float, vy: float,
                               vz: float, p: float, q: float, r: float, frame_id: int,
                               child: int) -> State:
    """:func:`paper_from_odometry` from ODOMETRY's fields in wire order up to
    ``child_frame_id`` (Python floats and ints, as a decode gives them): the daemon's hot
    path passes the received tuple's items, with no attribute read. Same checks, errors and
    result to the bit."""
    # One sum tells whether all nine are finite (NaN/inf propagate); only a failure, or a
    # finite sum that overflowed, walks the fields to name the culprit.
    if not math.isfinite(px + py + pz + vx + vy + vz + p + q + r):
        for name, value in zip(_ODOMETRY_FLOATS, (px, py, pz, vx, vy, vz, p, q, r),
                               strict=True):
            if not math.isfinite(value):
                raise ValueError(f"ODOMETRY.{name}: not finite ({value})")
    if frame_id != MAV_FRAME_LOCAL_NED:
        raise ValueError(f"ODOMETRY.frame_id: expected MAV_FRAME_LOCAL_NED (1), got {frame_id}")
    if not (math.isfinite(qw) and math.isfinite(qx) and math.isfinite(qy)
            and math.isfinite(qz)):
        raise ValueError(f"ODOMETRY.q: not finite ({[qw, qx, qy, qz]})")
    norm = math.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)   # summed in this order
    if abs(norm - 1.0) > 1e-3:
        raise ValueError(f"ODOMETRY.q: not a unit quaternion (|q| = {norm:.6f})")
    w, x, y, z = qw / norm, qx / norm, qy / norm, qz / norm
    s = _SQRT1_2
    q_enu_flu = (s * (w + z), s * (x + y), s * (x - y), s * (w - z))   # the involution
    # Floats, not 3-vectors: this runs every tick in the daemon.
    if child == MAV_FRAME_BODY_FRD:
        # body_to_inertial(rotation_rows(q_enu_flu), (vx, -vy, -vz)), written out (every
        # tick, the same operations in the same order): R(q) with the quaternion
        # normalised again, as rotation_rows does
        a, b, c, d = q_enu_flu
        n = _sqrt(a * a + b * b + c * c + d * d)
        a, b, c, d = a / n, b / n, c / n, d / n
        left, up = -vy, -vz                     # the FRD twist in FLU
        velocity = [
            (1 - 2 * (c * c + d * d)) * vx + 2 * (b * c - a * d) * left
            + 2 * (b * d + a * c) * up,
            2 * (b * c + a * d) * vx + (1 - 2 * (b * b + d * d)) * left
            + 2 * (c * d - a * b) * up,
            2 * (b * d - a * c) * vx + 2 * (c * d + a * b) * left
            + (1 - 2 * (b * b + c * c)) * up]
    elif child == MAV_FRAME_LOCAL_NED:
        velocity = [vy, vx, -vz]
    else:
        raise ValueError("ODOMETRY.child_frame_id: expected MAV_FRAME_BODY_FRD (12) or "
                         f"MAV_FRAME_LOCAL_NED (1), got {child}")
    return State((py, px, -pz), velocity, q_enu_flu, (p, -q, -r), time_usec)
