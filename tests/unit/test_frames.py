"""Paper frame (ENU/FLU, z up) ↔ MAVLink (NED/FRD): known rotations, signs and round trips."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tfl_mav.link.dialect import mav, new_mavlink
from tfl_mav.model.frames import (
    MAV_FRAME_BODY_FRD,
    MAV_FRAME_LOCAL_NED,
    P_ENU_TO_NED,
    Q_FLU_TO_FRD,
    body_to_inertial,
    enu_to_ned,
    flu_to_frd,
    frd_to_flu,
    ned_to_enu,
    odometry_from_paper,
    paper_from_odometry,
    quaternion_enu_flu_to_ned_frd,
    quaternion_ned_frd_to_enu_flu,
    rotation_enu_flu_to_ned_frd,
    rotation_ned_frd_to_enu_flu,
)
from tfl_mav.model.geometry import (
    euler_to_quaternion,
    euler_zyx_from_rotation,
    quaternion_from_rotation,
    quaternion_multiply,
    rotation_from_euler_zyx,
    rotation_from_quaternion,
    rotation_rows,
)

# float32 on the wire: relative resolution 2^-24 ≈ 6e-8; these states are O(10), so 1e-5
# absolute is generous for rounding and still catches any sign or axis error.
WIRE_TOL = 1e-5

angles = st.floats(-math.pi, math.pi, allow_nan=False)
pitches = st.floats(-1.5, 1.5, allow_nan=False)   # away from gimbal lock
coords = st.floats(-50.0, 50.0, allow_nan=False)


def wrap(a: float) -> float:
    return math.atan2(math.sin(a), math.cos(a))


def test_vectors_swap_axes_and_flip_z():
    assert enu_to_ned((1.0, 2.0, 3.0)).tolist() == [2.0, 1.0, -3.0]
    assert ned_to_enu((2.0, 1.0, -3.0)).tolist() == [1.0, 2.0, 3.0]
    assert flu_to_frd((1.0, 2.0, 3.0)).tolist() == [1.0, -2.0, -3.0]
    assert frd_to_flu((1.0, -2.0, -3.0)).tolist() == [1.0, 2.0, 3.0]


def test_level_vehicle_facing_east_is_ned_yaw_90_degrees():
    # Paper attitude identity: body forward = east. In NED that is heading +90°.
    q = quaternion_enu_flu_to_ned_frd((1.0, 0.0, 0.0, 0.0))
    assert np.allclose(q, [math.sqrt(0.5), 0.0, 0.0, math.sqrt(0.5)])
    roll, pitch, yaw = euler_zyx_from_rotation(rotation_from_quaternion(q))
    assert (roll, pitch) == pytest.approx((0.0, 0.0), abs=1e-12)
    assert yaw == pytest.approx(math.pi / 2, abs=1e-12)


def test_facing_north_is_ned_yaw_zero():
    q = quaternion_enu_flu_to_ned_frd(euler_to_quaternion(0.0, 0.0, math.pi / 2))
    assert euler_zyx_from_rotation(rotation_from_quaternion(q)) == pytest.approx(
        (0.0, 0.0, 0.0), abs=1e-12)


def test_positive_paper_pitch_is_nose_down_and_negative_ned_pitch():
    theta = 0.3
    R = rotation_from_euler_zyx(0.0, theta, 0.0)
    nose_enu = R @ [1.0, 0.0, 0.0]
    assert nose_enu[2] == pytest.approx(-math.sin(theta))      # nose below the horizon
    R_ned = rotation_enu_flu_to_ned_frd(R)
    nose_ned = R_ned @ [1.0, 0.0, 0.0]                          # FRD forward = FLU forward
    assert nose_ned[2] == pytest.approx(math.sin(theta))        # NED z down: below horizon
    _, pitch, _ = euler_zyx_from_rotation(R_ned)
    assert pitch == pytest.approx(-theta)


def test_positive_paper_roll_is_right_wing_down_and_positive_ned_roll():
    phi = 0.4
    R = rotation_from_euler_zyx(phi, 0.0, 0.0)
    right_wing_enu = R @ [0.0, -1.0, 0.0]                        # FLU: right is −b2
    assert right_wing_enu[2] < 0.0
    roll, _, _ = euler_zyx_from_rotation(rotation_enu_flu_to_ned_frd(R))
    assert roll == pytest.approx(phi)


@given(angles, pitches, angles)
@settings(max_examples=200, deadline=None)
def test_euler_angles_map_as_roll_minus_pitch_and_90_minus_yaw(phi, theta, psi):
    R_ned = rotation_enu_flu_to_ned_frd(rotation_from_euler_zyx(phi, theta, psi))
    roll, pitch, yaw = euler_zyx_from_rotation(R_ned)
    assert roll == pytest.approx(phi, abs=1e-9)
    assert pitch == pytest.approx(-theta, abs=1e-9)
    assert wrap(yaw - (math.pi / 2 - psi)) == pytest.approx(0.0, abs=1e-9)


@given(angles, pitches, angles)
@settings(max_examples=200, deadline=None)
def test_quaternion_and_matrix_conversions_agree_and_invert(phi, theta, psi):
    q_enu = euler_to_quaternion(phi, theta, psi)
    R_enu = rotation_from_euler_zyx(phi, theta, psi)
    assert np.allclose(rotation_from_quaternion(q_enu), R_enu, atol=1e-12)
    q_ned = quaternion_enu_flu_to_ned_frd(q_enu)
    assert np.linalg.norm(q_ned) == pytest.approx(1.0, abs=1e-12)
    assert np.allclose(rotation_from_quaternion(q_ned), rotation_enu_flu_to_ned_frd(R_enu),
                       atol=1e-12)
    assert np.allclose(quaternion_ned_frd_to_enu_flu(q_ned), q_enu, atol=1e-12)
    q_back = quaternion_from_rotation(R_enu)
    assert np.allclose(rotation_from_quaternion(q_back), R_enu, atol=1e-12)


def test_quaternion_from_rotation_handles_half_turns():
    for axis in np.eye(3):
        q = np.array([0.0, *axis])   # 180° about each axis: w = 0, the hard case
        R = rotation_from_quaternion(q)
        assert np.allclose(rotation_from_quaternion(quaternion_from_rotation(R)), R, atol=1e-12)


def test_quaternion_multiply_composes_rotations():
    a = euler_to_quaternion(0.1, 0.2, 0.3)
    b = euler_to_quaternion(-0.4, 0.5, 1.1)
    assert np.allclose(rotation_from_quaternion(quaternion_multiply(a, b)),
                       rotation_from_quaternion(a) @ rotation_from_quaternion(b), atol=1e-12)


def _wire(fields, time_usec=1234, child=MAV_FRAME_BODY_FRD):
    """Pack ODOMETRY and decode it again, exactly as it crosses the link."""
    tx, rx = new_mavlink(1, 1), new_mavlink(2, 1)
    msg = mav.MAVLink_odometry_message(time_usec, MAV_FRAME_LOCAL_NED, child, fields.x,
                                       fields.y, fields.z, fields.q, fields.vx, fields.vy,
                                       fields.vz, fields.rollspeed, fields.pitchspeed,
                                       fields.yawspeed, [0.0] * 21, [0.0] * 21)
    return rx.decode(bytearray(msg.pack(tx)))


@given(st.tuples(coords, coords, coords), st.tuples(coords, coords, coords),
       angles, pitches, angles, st.tuples(coords, coords, coords))
@settings(max_examples=200, deadline=None)
def test_odometry_round_trip_over_the_wire(pos, vel, phi, theta, psi, rates):
    q = euler_to_quaternion(phi, theta, psi)
    fields = odometry_from_paper(pos, vel, q, rates)
    state = paper_from_odometry(_wire(fields))
    assert state.time_usec == 1234
    assert np.allclose(state.position_m, pos, atol=WIRE_TOL * 10)
    assert np.allclose(state.velocity_mps, vel, atol=WIRE_TOL * 10)
    assert np.allclose(rotation_from_quaternion(state.quaternion_wxyz),
                       rotation_from_quaternion(q), atol=WIRE_TOL)
    assert np.allclose(state.body_rates_radps, rates, atol=WIRE_TOL * 10)


def test_odometry_twist_is_in_the_body_frd_frame():
    # Pitched nose down 90° (paper θ = π/2) and falling: inertial down is body forward.
    q = euler_to_quaternion(0.0, math.pi / 2, 0.0)
    f = odometry_from_paper((0.0, 0.0, 5.0), (0.0, 0.0, -2.0), q, (0.1, 0.2, 0.3))
    assert (f.vx, f.vy, f.vz) == pytest.approx((2.0, 0.0, 0.0), abs=1e-12)
    assert (f.rollspeed, f.pitchspeed, f.yawspeed) == pytest.approx((0.1, -0.2, -0.3))
    # Level and facing east, moving east at 1 m/s and up at 0.5 m/s: FRD forward 1, down −0.5.
    f = odometry_from_paper((1.0, 2.0, 3.0), (1.0, 0.0, 0.5), (1.0, 0.0, 0.0, 0.0), (0, 0, 0))
    assert (f.x, f.y, f.z) == (2.0, 1.0, -3.0)
    assert (f.vx, f.vy, f.vz) == pytest.approx((1.0, 0.0, -0.5), abs=1e-12)


def test_odometry_with_a_local_ned_twist_is_accepted():
    tx, rx = new_mavlink(1, 1), new_mavlink(2, 1)
    msg = mav.MAVLink_odometry_message(7, MAV_FRAME_LOCAL_NED, MAV_FRAME_LOCAL_NED, 2.0, 1.0,
                                       -3.0, [math.sqrt(0.5), 0, 0, math.sqrt(0.5)], 4.0, 5.0,
                                       -6.0, 0, 0, 0, [0.0] * 21, [0.0] * 21)
    state = paper_from_odometry(rx.decode(bytearray(msg.pack(tx))))
    assert np.allclose(state.velocity_mps, (5.0, 4.0, 6.0))
    assert np.allclose(state.quaternion_wxyz, (1.0, 0.0, 0.0, 0.0), atol=1e-7)


@pytest.mark.parametrize(("change", "field"), [
    ({"frame_id": 8}, "frame_id"),
    ({"child_frame_id": 8}, "child_frame_id"),
    ({"x": math.nan}, "ODOMETRY.x"),
    ({"yawspeed": math.inf}, "ODOMETRY.yawspeed"),
    ({"q": [1.0, 0.0, 0.0, math.nan]}, "ODOMETRY.q"),
    ({"q": [0.5, 0.0, 0.0, 0.0]}, "ODOMETRY.q"),
])
def test_bad_odometry_raises_naming_the_field(change, field):
    f = odometry_from_paper((0, 0, 1), (0, 0, 0), (1, 0, 0, 0), (0, 0, 0))
    msg = _wire(f)
    for key, value in change.items():
        setattr(msg, key, value)
    with pytest.raises(ValueError, match=field):
        paper_from_odometry(msg)


@given(st.lists(st.floats(-1e6, 1e6), min_size=9, max_size=9))
@settings(max_examples=200, deadline=None)
def test_the_attitude_conversion_is_p_r_q_moved_not_multiplied(entries):
    """P R Q for the signed permutations P and Q: numpy's product to the value (a product
    with 0 and ±1 entries is exact), each way."""
    R = np.array(entries).reshape(3, 3)
    expected = P_ENU_TO_NED @ R @ Q_FLU_TO_FRD
    assert np.array_equal(rotation_enu_flu_to_ned_frd(R), expected)
    assert np.array_equal(rotation_ned_frd_to_enu_flu(R), expected)
    assert np.array_equal(rotation_ned_frd_to_enu_flu(rotation_enu_flu_to_ned_frd(R)), R)


@settings(max_examples=300, deadline=None)
@given(q=st.lists(st.floats(-1.0, 1.0), min_size=4, max_size=4).filter(
           lambda c: sum(x * x for x in c) > 1e-3),
       v=st.lists(st.floats(-1e6, 1e6), min_size=3, max_size=3))
def test_body_to_inertial_sums_each_row_left_to_right(q, v):
    """R v is (r₀ v₀ + r₁ v₁) + r₂ v₂ for each row, each operation rounded: the same bits
    on every IEEE machine, whatever BLAS numpy has (which fuses multiply-adds in an order
    of its own)."""
    rows = rotation_rows(q)
    got = body_to_inertial(rows, v)
    assert [float.hex(g) for g in got] == [
        float.hex((r[0] * v[0] + r[1] * v[1]) + r[2] * v[2]) for r in rows]


def test_body_to_inertial_is_not_a_fused_multiply_add():
    """A row where a fused multiply-add (one rounding for r₀ v₀ + r₁ v₁) and the plain
    sum part: 1 + 2⁻²⁷ squared is 1 + 2⁻²⁶ + 2⁻⁵⁴, whose last term only the fused form
    keeps, so the plain form (what runs here) gives 0 and a fused one 2⁻⁵⁴."""
    e = 1.0 + 2.0 ** -27
    rows = [[e, -1.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
    assert body_to_inertial(rows, [e, e * e, 0.0]) == [0.0, e * e, 0.0]


@settings(max_examples=300, deadline=None)
@given(q=st.lists(st.floats(-1.0, 1.0), min_size=4, max_size=4).filter(
           lambda c: sum(x * x for x in c) > 1e-3),
       v=st.lists(st.floats(-1e6, 1e6), min_size=3, max_size=3))
def test_the_daemons_velocity_is_body_to_inertial_of_rotation_rows(q, v):
    """paper_from_odometry_fields writes the body-FRD velocity's rotation out (every tick):
    the same bits as body_to_inertial(rotation_rows(q_enu_flu), Q v)."""
    from tfl_mav.model.frames import paper_from_odometry_fields

    n = math.sqrt(sum(c * c for c in q))
    q_ned = [c / n for c in q]
    state = paper_from_odometry_fields(1, 0.0, 0.0, 0.0, *q_ned, *v, 0.0, 0.0, 0.0,
                                       MAV_FRAME_LOCAL_NED, MAV_FRAME_BODY_FRD)
    expected = body_to_inertial(rotation_rows(state.quaternion_wxyz), frd_to_flu(v).tolist())
    assert [float.hex(c) for c in state.velocity_mps] == [float.hex(c) for c in expected]


_ODOMETRY_VALUES = st.one_of(st.floats(-1e3, 1e3), st.sampled_from([math.nan, math.inf, 0.0]))


@settings(max_examples=300, deadline=None)
@given(pos=st.lists(_ODOMETRY_VALUES, min_size=3, max_size=3),
       q=st.lists(st.floats(-1.0, 1.0, allow_nan=False), min_size=4, max_size=4),
       twist=st.lists(_ODOMETRY_VALUES, min_size=6, max_size=6),
       frames=st.tuples(st.sampled_from([MAV_FRAME_LOCAL_NED, MAV_FRAME_BODY_FRD, 8]),
                        st.sampled_from([MAV_FRAME_LOCAL_NED, MAV_FRAME_BODY_FRD, 8])))
def test_the_daemons_tuple_path_is_the_attribute_path(pos, q, twist, frames):
    """What the daemon does with the link's ODOMETRY (its tuple's first 16 items to
    paper_from_odometry_fields) is what paper_from_odometry makes of pymavlink's message:
    the same State to the bit, or the same error."""
    from tfl_mav.controller.daemon_intake import ODOMETRY_FIELDS, RxOdometry
    from tfl_mav.link.transport import Link
    from tfl_mav.model.frames import paper_from_odometry_fields

    msg = mav.MAVLink_odometry_message(
        99, frames[0], frames[1], *pos, q, *twist, [0.5] * 21, [0.25] * 21)
    raw = bytes(msg.pack(new_mavlink(1, 1)))
    full = new_mavlink(2, 1).decode(bytearray(raw))
    with Link.listen(("127.0.0.1", 0), src_system=2, src_component=1,
                     peer=("127.0.0.1", 9), peer_sysid=1) as link:
        got: list = []
        link.receiver.ingest(raw, ("127.0.0.1", 9), got)
    (lite,) = got
    assert type(lite) is RxOdometry
    assert lite.pose_covariance == [0.5] * 21 and lite.velocity_covariance == [0.25] * 21
    try:
        expected = paper_from_odometry(full)
    except ValueError as exc:
        with pytest.raises(ValueError) as caught:
            paper_from_odometry_fields(*lite[:ODOMETRY_FIELDS])
        assert str(caught.value) == str(exc)
        return
    state = paper_from_odometry_fields(*lite[:ODOMETRY_FIELDS])
    assert repr(state) == repr(expected)
