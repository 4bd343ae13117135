"""The compiled ODOMETRY conversion (frames_native) gives the Python path's values to the bit,
declines (None) every case the Python path rejects or does not take as floats, and the
daemon's intake flies it on a real decoded ODOMETRY."""

from __future__ import annotations

import math
import random

import pytest

from tfl_mav import frames_native
from tfl_mav.frames import (
    MAV_FRAME_BODY_FRD,
    MAV_FRAME_LOCAL_NED,
    odometry_from_paper,
    paper_from_odometry_fields,
)
from tfl_mav.link.dialect import mav
from tfl_mav.state import State


@pytest.fixture(scope="module")
def core():
    mp = pytest.MonkeyPatch()
    mp.setenv("TFL_MAV_NATIVE", "sync")
    got: list = []
    frames_native.attach(got.append)
    mp.undo()
    if not got:
        pytest.skip("no compiled ODOMETRY conversion here (no compiler)")
    return got[0]


def _bits(state: State) -> tuple:
    vecs = (state.position_m, state.velocity_mps, state.quaternion_wxyz,
            state.body_rates_radps)
    return (*(tuple(float.hex(float(v)) for v in vec) for vec in vecs), state.time_usec,
            type(state.velocity_mps))


def _random_odometry(rng: random.Random, k: int) -> tuple:
    q = [rng.gauss(0.0, 1.0) for _ in range(4)]
    nq = math.sqrt(sum(c * c for c in q))
    mag = 10.0 ** rng.uniform(-6.0, 6.0)       # every exponent range of a velocity
    return (k, rng.uniform(-50, 50), rng.uniform(-50, 50), rng.uniform(-50, 5),
            *(c / nq for c in q), *(rng.gauss(0.0, mag) for _ in range(3)),
            rng.gauss(0, 5), rng.gauss(0, 5), rng.gauss(0, 60), MAV_FRAME_LOCAL_NED,
            MAV_FRAME_BODY_FRD)


def test_random_states_are_the_python_paths_bits(core):
    rng = random.Random(2026)
    for k in range(20000):
        msg = _random_odometry(rng, k)
        state, ref = core(msg, State), paper_from_odometry_fields(*msg)
        assert type(state) is State and state == ref and _bits(state) == _bits(ref), msg


def test_signed_zeros_and_a_level_vehicle(core):
    for vel in ((0.0, 0.0, 0.0), (-0.0, -0.0, -0.0), (0.0, -0.0, 0.0), (1.0, -0.0, -1.0)):
        msg = (5, 0.0, -0.0, 0.0, 1.0, 0.0, 0.0, 0.0, *vel, -0.0, 0.0, -0.0,
               MAV_FRAME_LOCAL_NED, MAV_FRAME_BODY_FRD)
        assert _bits(core(msg, State)) == _bits(paper_from_odometry_fields(*msg))


@pytest.mark.parametrize("index, value", [
    (1, math.nan), (9, math.inf), (4, math.nan),      # not finite: the Python path names it
    (4, 2.0),                                          # not a unit quaternion
    (14, 8), (15, MAV_FRAME_LOCAL_NED), (15, 3),       # other frames (LOCAL_NED: Python's)
    (2, 1), (7, 0),                                    # an int where a float is expected
])
def test_what_the_fast_path_does_not_cover_is_declined(core, index, value):
    msg = list(_random_odometry(random.Random(index), 1))
    msg[index] = value
    assert core(tuple(msg), State) is None


def test_a_short_tuple_or_another_object_is_declined(core):
    assert core((1, 2.0), State) is None
    assert core([0] * 16, State) is None
    assert core(_random_odometry(random.Random(1), 1), int) is None   # not the State class


def test_a_decoded_odometry_float32_on_the_wire(core):
    """A real ODOMETRY, packed and decoded (float32 values, as the daemon receives them)."""
    n = math.sqrt(0.9 ** 2 + 0.1 ** 2 + 0.2 ** 2 + 0.3 ** 2)
    odo = odometry_from_paper((1.0, 2.0, 3.0), (0.3, -0.2, 0.1),
                              (0.9 / n, 0.1 / n, -0.2 / n, 0.3 / n), (0.5, -0.4, 12.0))
    conn = mav.MAVLink(None, srcSystem=1, srcComponent=1)
    msg = mav.MAVLink_odometry_message(
        123456, MAV_FRAME_LOCAL_NED, MAV_FRAME_BODY_FRD, odo.x, odo.y, odo.z, list(odo.q),
        odo.vx, odo.vy, odo.vz, odo.rollspeed, odo.pitchspeed, odo.yawspeed, [0.0] * 21,
        [0.0] * 21, 0, 0, 100)
    d = conn.decode(bytearray(msg.pack(conn)))
    fields = (d.time_usec, d.x, d.y, d.z, *d.q, d.vx, d.vy, d.vz, d.rollspeed, d.pitchspeed,
              d.yawspeed, d.frame_id, d.child_frame_id)
    assert _bits(core(fields, State)) == _bits(paper_from_odometry_fields(*fields))
