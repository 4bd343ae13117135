"""The recorder's whole-object JSON (:mod:`~tfl_mav.flightlog.jsonobj`, issue #13) prints
exactly what ``JsonEncoder.dumps`` of the dict prints, through the paths that run:

* MAVLink frames through ``Recorder.on_frames`` into a real MCAP file, read back with the
  ``mcap`` reader: every decoded message vs the dict encoder on the frame's own fields,
  for random values across msgspec's other notations (exponents, 0.0000x), NaN/inf;
* every all-number message of the dialect has a whole-object printer (checked at plan
  build against the template path);
* a record plan with texts that look like numbers.
"""

from __future__ import annotations

import math
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from mcap.reader import make_reader

from tfl_mav.flightlog.jsonenc import JsonEncoder, MavPlan
from tfl_mav.flightlog.jsonobj import ObjectJson
from tfl_mav.flightlog.recorder import Recorder
from tfl_mav.flightlog.recordplan import record_plan
from tfl_mav.link.dialect import mav, new_mavlink
from tfl_mav.link.payload import PayloadDecoder

_floats = st.one_of(st.floats(width=32), st.sampled_from([0.0, -0.0, math.nan, math.inf]))
# doubles around where msgspec's notation and repr's part (1e-5, 1e-4, 1e16; see jsonenc)
_doubles = st.builds(lambda m, e: m * 10.0**e, st.floats(-10, 10), st.integers(-7, 17))
_finite32 = st.builds(lambda m, e: m * 10.0**e, st.floats(-10, 10, width=32),
                      st.integers(-9, 12))


def test_every_all_number_message_has_a_whole_object_printer() -> None:
    plans = [MavPlan(cls) for cls in mav.mavlink_map.values()]
    assert all(p.obj is not None for p in plans if p.simple)
    assert sum(p.simple for p in plans) > 100


@settings(max_examples=40, deadline=None)
@given(st.lists(st.lists(_finite32 | _floats, min_size=60, max_size=60), min_size=3,
                max_size=3))
def test_frames_read_back_as_the_dict_encoder_prints_them(tmp_path_factory: Any,
                                                          vs: list[list[float]]) -> None:
    mv = new_mavlink(1, 1)
    raws: list[bytes] = []
    for k, v in enumerate(vs * 2):           # each channel's first frame: the careful path
        usec = 20_000 * (k + 1)              # 20 ms apart: every one decoded (50 Hz)
        for msg in (
                mav.MAVLink_odometry_message(usec, 1, 12, v[0], v[1], v[2], v[3:7], v[7], v[8],
                                             v[9], v[10], v[11], v[12], v[13:34], v[34:55],
                                             0, 6, 100),
                mav.MAVLink_hil_actuator_controls_message(usec, v[40:56], 128, 1),
                mav.MAVLink_actuator_output_status_message(usec, 15, v[20:52]),
                mav.MAVLink_attitude_message(usec // 1000, *v[54:60])):
            raws.append(bytes(msg.pack(mv)))
    path = tmp_path_factory.mktemp("obj") / "f.mcap"
    with Recorder(path, clock=lambda: 1.0) as rec:
        rec.on_frames([(None, 1.0 + 0.001 * i, "rx", raw, True)
                       for i, raw in enumerate(raws)])
    enc, dec = JsonEncoder(), PayloadDecoder()
    with open(path, "rb") as fh:
        got = [m.data for _s, ch, m in make_reader(fh).iter_messages(log_time_order=False)
               if ch.topic.startswith("/mavlink/1/1/")]
    want = [enc.dumps(dec.fields(raw, raw[7] | raw[8] << 8 | raw[9] << 16)) for raw in raws]
    assert got == want


_FIELDS = ("mode", "estimate", "flag", "thrust", "xi", "reason", "cusum")


@settings(max_examples=300, deadline=None)
@given(st.lists(_doubles | st.sampled_from([math.nan, None, 7, -0.0]), min_size=12,
                max_size=12), st.floats(0, 1e4),
       st.sampled_from(["", "tilt error 0 deg", "1e5, 0.00001 null", "x:0.0000[1e-7]"]))
def test_record_plan_texts_that_look_like_numbers(v: list[Any], t: float,
                                                  reason: str) -> None:
    enc = JsonEncoder()
    sample = ("nominal", 0.5, False, [1.0] * 4, ((0.1, 0.2), (0.3, 0.4)), "", (0.0, 1.0))
    plan = record_plan(_FIELDS, sample)
    assert plan is not None
    record = ("attacked", v[0], True, v[1:5], ((v[5], v[6]), (v[7], v[8])), reason,
              (v[9], v[10]))
    got = plan(record, t)
    assert got == enc.dumps({**dict(zip(_FIELDS, record, strict=True)), "t_s": t})


@pytest.mark.parametrize("key", ['a"b', "x,y", "nullable", "k:v", "é"])
def test_keys_it_cannot_check_are_refused(key: str) -> None:
    with pytest.raises(ValueError, match="key"):
        ObjectJson(["t_s", key], ["t[0]", "t[1]"])


def test_record_plan_refuses_another_shape_without_raising() -> None:
    sample = ("nominal", 0.5, False, [1.0] * 4, ((0.1, 0.2), (0.3, 0.4)), "", (0.0, 1.0))
    plan = record_plan(_FIELDS, sample)
    assert plan is not None
    for bad in ((["unhashable"], *sample[1:]), (*sample[:2], 1, *sample[3:]),
                (*sample[:5], b"bytes", sample[6])):
        assert plan(bad, 1.0) is None
