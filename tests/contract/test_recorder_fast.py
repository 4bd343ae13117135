"""The recorder's fast paths write exactly what the careful ones do.

* :class:`~tfl_mav.flightlog.mcapfast.FastWriter` vs mcap's own ``Writer``: the same file,
  byte for byte (chunks, message indexes, statistics, summary), across chunk boundaries,
  flushes and a channel registered mid-file.
* :class:`~tfl_mav.flightlog.jsonenc.MavJson` vs ``JsonEncoder.dumps(PayloadDecoder
  .fields(...))`` on random hot messages (NaN/inf/-0.0 included: left out and listed).
* the truth channels' precompiled formats vs ``JsonEncoder.dumps`` of the dict.
* a record plan (``/controller/state``) vs ``JsonEncoder.dumps`` with NaN/inf/None values.
* ``RecorderProcess.on_frames`` (one call per datagram) writes what ``on_frame`` does.
"""

from __future__ import annotations

import io
import math
import random
from typing import Any

from hypothesis import given, settings
from hypothesis import strategies as st
from mcap.reader import make_reader
from mcap.writer import CompressionType, IndexType, Writer

from tfl_mav.flightlog.jsonenc import JsonEncoder, MavJson
from tfl_mav.flightlog.mcapfast import FastWriter
from tfl_mav.flightlog.recorder import _TRUTH_ATTACK, _TRUTH_STATE, _TRUTH_THRUSTS
from tfl_mav.flightlog.recorder_process import RecorderProcess
from tfl_mav.flightlog.recordplan import record_plan
from tfl_mav.link.dialect import mav, new_mavlink
from tfl_mav.link.payload import PayloadDecoder


def _write(cls: type, seed: int, **kw: Any) -> bytes:
    out = io.BytesIO()
    kw.setdefault("compression", CompressionType.ZSTD)
    w = cls(out, chunk_size=1 << 14,
            index_types=IndexType.CHUNK | IndexType.MESSAGE | IndexType.METADATA, **kw)
    w.start("tfl-mav", "test")
    sid = w.register_schema("s", "jsonschema", b"{}")
    cids = [w.register_channel(f"/t{i}", "json", sid) for i in range(4)]
    rnd = random.Random(seed)
    for i in range(5000):
        if i == 2500:
            cids.append(w.register_channel("/late", "json", sid))
        if i % 1700 == 0:
            w.flush()
        log = 10**9 + i * 1000 + rnd.randint(-5000, 5000)      # not monotonic
        if i % 3 == 0:                 # a frame's two records (FastWriter: one call)
            a, b = rnd.choice(cids), rnd.choice(cids)
            da, db = b"r" * rnd.randint(1, 300), b"d" * rnd.randint(1, 300)
            if cls is FastWriter:
                w.add_pair(a, da, b, db, log, i)
            else:
                w.add_message(a, log, da, i)
                w.add_message(b, log, db, i)
            continue
        w.add_message(rnd.choice(cids), log, b"x" * rnd.randint(1, 300), i)
    w.finish()
    return out.getvalue()


def test_fast_writer_is_byte_identical_to_mcap_writer() -> None:
    for seed in range(3):
        assert _write(FastWriter, seed) == _write(Writer, seed)


def _messages(data: bytes) -> list[tuple[str, int, int, bytes]]:
    reader = make_reader(io.BytesIO(data))
    return [(c.topic, m.log_time, m.publish_time, m.data)
            for _s, c, m in reader.iter_messages(log_time_order=False)]


def test_other_compressions_read_back_the_same_messages() -> None:
    """The recorder's zstd level 1 (and lz4, none) change the chunk bytes, not a message."""
    ref = _messages(_write(Writer, 7))
    assert len(ref) == 5000 + 5000 // 3 + 1
    for kw in ({"zstd_level": 1}, {"compression": CompressionType.LZ4},
               {"compression": CompressionType.NONE}):
        assert _messages(_write(FastWriter, 7, **kw)) == ref


_floats = st.one_of(st.floats(width=32), st.sampled_from([0.0, -0.0, math.nan, math.inf]))
# doubles around where msgspec's notation and repr's part (1e-5, 1e-4, 1e16; see jsonenc)
_doubles = st.builds(lambda m, e: m * 10.0**e, st.floats(-10, 10), st.integers(-7, 17))


@settings(max_examples=150, deadline=None)
@given(st.lists(_floats | _doubles, min_size=60, max_size=60), st.integers(0, 2**63 - 1))
def test_mav_json_is_byte_identical_to_the_dict_encoder(v: list[float], usec: int) -> None:
    mv = new_mavlink(1, 1)
    msgs = [
        mav.MAVLink_odometry_message(usec, 1, 12, v[0], v[1], v[2], v[3:7], v[7], v[8], v[9],
                                     v[10], v[11], v[12], v[13:34], [0.0] * 21, 0, 6, 100),
        mav.MAVLink_hil_actuator_controls_message(usec, v[40:56], 128, 1),
        mav.MAVLink_actuator_output_status_message(usec, 15, v[20:52]),
        mav.MAVLink_esc_telemetry_1_to_4_message([20] * 4, [1600] * 4, [1, 2, 3, 4],
                                                 [0] * 4, [9000, 0, 1, 65535], [7] * 4),
        mav.MAVLink_heartbeat_message(18, 8, 128, 0, 4, 3),
        # char fields (the daemon's law telemetry; STATUSTEXT with non-ASCII bytes)
        mav.MAVLink_named_value_float_message(usec % 2**32, b"sigma", v[14]),
        mav.MAVLink_named_value_float_message(usec % 2**32, b"ten_chars_", v[15]),
        mav.MAVLink_debug_float_array_message(usec, b"law\x00x", 7, v[0:58]),
        mav.MAVLink_statustext_message(4, b'rotor "2" \xff\\ lost', 3, 0),
    ]
    enc, dec, fast = JsonEncoder(), PayloadDecoder(), MavJson()
    for msg in msgs:
        raw = bytes(msg.pack(mv))
        mid = msg.get_msgId()
        fields = dec.fields(raw, mid)
        got = fast.encode(raw, mid)
        # NaN/inf fields (a real PX4's unknown covariances): left out and listed under
        # _nonfinite, the same bytes as the dict path (JSON has no NaN)
        assert got is not None
        assert got[0] == enc.dumps(fields)
        assert got[1] == fields.get("time_usec")


def _numbers(fields: dict) -> list[float]:
    out: list[float] = []
    for value in fields.values():
        out += value if isinstance(value, list) else [value]
    return out


@settings(max_examples=150, deadline=None)
@given(st.lists(_floats, min_size=17, max_size=17), st.integers(0, 4))
def test_truth_formats_match_the_dict_encoder(v: list[float], rotor: int) -> None:
    enc = JsonEncoder()
    t, pos, vel, quat, rates, thrust = v[0], v[1:4], v[4:7], v[7:11], v[11:14], v[13:17]
    cases = [
        (_TRUTH_STATE.encode((t, *pos, *vel, *quat, *rates)),
         {"t_s": t, "position_m": pos, "velocity_mps": vel, "quaternion_wxyz": quat,
          "body_rates_radps": rates}),
        (_TRUTH_ATTACK["true" if rotor else "false"].encode((t, rotor, v[1], v[2])),
         {"t_s": t, "rotor": rotor, "active": rotor != 0, "applied_n": v[1],
          "requested_n": v[2]}),
        (_TRUTH_THRUSTS.encode((t, *thrust, rotor)),
         {"t_s": t, "thrust_n": thrust, "attack_rotor": rotor}),
    ]
    for got, ref in cases:
        finite = all(math.isfinite(x) for x in _numbers(ref) if not isinstance(x, bool))
        assert (got == enc.dumps(ref)) if finite else got is None


_FIELDS = ("mode", "estimate", "distance", "flag", "thrust", "xi", "eta", "mass", "cusum")
_maybe = st.one_of(_doubles, st.sampled_from([math.nan, math.inf, -math.inf, None, 7, -0.0]))


@settings(max_examples=300, deadline=None)
@given(st.lists(_maybe, min_size=20, max_size=20), st.floats(0, 1e4))
def test_record_plans_with_nonfinite_values_match_the_dict_encoder(v: list[Any],
                                                                   t: float) -> None:
    """NaN/inf/None (a nominal flight's unknown attack estimate): the plan leaves the key
    out and lists it under _nonfinite, as the dict path does; never other bytes."""
    enc = JsonEncoder()
    sample = ("nominal", 0.5, 1.0, False, [1.0] * 4, ((0.1, 0.2), (0.3, 0.4)), (0.0, 1.0),
              1.1, (0.0, 0.0, 0.0, 0.0))
    plan = record_plan(_FIELDS, sample)
    assert plan is not None
    record = ("attack", v[0], v[1], True, v[2:6], ((v[6], v[7]), (v[8], v[9])),
              (v[10], v[11]), v[12], tuple(v[13:17]))
    got = plan(record, t)
    assert got is None or got == enc.dumps({**dict(zip(_FIELDS, record, strict=True)),
                                            "t_s": t})
    assert got is not None          # plain numbers, NaN, inf and None are all printed


def _frames() -> list[tuple[str, list[bytes], list[Any]]]:
    """Datagrams of a few ticks: accepted frames, a rejected one, NaN covariances."""
    mv = new_mavlink(1, 1)
    out = []
    for k in range(50):
        odo = mav.MAVLink_odometry_message(
            1000 * k, 1, 12, 0.1 * k, 2.0, 3.0, [1.0, 0.0, 0.0, 0.0], 0.1, 0.2, 0.3, 0.01,
            0.02, 0.03, [math.nan] + [0.0] * 20, [0.5] * 21, 0, 6, 100)
        hil = mav.MAVLink_hil_actuator_controls_message(1000 * k, [0.5] * 16, 128, 1)
        raws = [bytes(odo.pack(mv)), bytes(hil.pack(mv))]
        msgs: list[Any] = [odo, hil]
        if k % 7 == 3:
            raws.append(raws[0][:-3] + b"xyz")       # a bad CRC: rejected
            msgs.append(None)
        out.append(("rx" if k % 2 else "tx", raws, msgs))
    return out


def test_on_frames_writes_what_on_frame_does(tmp_path: Any) -> None:
    """The batch entry (one call per datagram) and the frame hook give the same file."""
    files = []
    for batch in (False, True):
        path = tmp_path / f"{batch}.mcap"
        with RecorderProcess(path) as rec:
            for k, (direction, raws, msgs) in enumerate(_frames()):
                t = 100.0 + 0.001 * k
                if batch:
                    rec.on_frames(direction, raws, None if None not in msgs else msgs, t)
                else:
                    for raw, msg in zip(raws, msgs, strict=True):
                        rec.on_frame(direction, raw, msg, t)
        # rx frames with no message are rejected; tx ones are raw sends (k = 3, 17, 31, 45)
        assert rec.error is None and rec.stats.frames_rejected == 4
        files.append(path)
    got = []
    for path in files:
        with open(path, "rb") as fh:
            got.append([(ch.topic, m.log_time, m.publish_time, m.data)
                        for _s, ch, m in make_reader(fh).iter_messages()])
    assert got[0] == got[1]
    # every frame raw (100 accepted, 7 rejected); decoded at most every 20 ms of sim time
    # (the scene rate): ODOMETRY and HIL_ACTUATOR_CONTROLS at 0, 20 and 40 ms
    raw = [m for m in got[0] if m[0] == "/mavlink/raw"]
    decoded = [(m[0], m[2]) for m in got[0] if m[0] != "/mavlink/raw"]
    assert len(raw) == 50 * 2 + 7
    assert sorted(decoded) == sorted((topic, ms * 1_000_000) for ms in (0, 20, 40)
                                     for topic in ("/mavlink/1/1/ODOMETRY",
                                                   "/mavlink/1/1/HIL_ACTUATOR_CONTROLS"))
    assert sum(b'"_nonfinite":["pose_covariance"]' in m[3] for m in got[0]) == 3


class _Syscalls(io.RawIOBase):
    """A raw file that keeps what each write (one system call on a real file) got."""

    def __init__(self) -> None:
        self.sizes: list[int] = []
        self.data = bytearray()

    def writable(self) -> bool:
        return True

    def write(self, b: Any) -> int:
        self.sizes.append(len(b))
        self.data += bytes(b)
        return len(b)


def test_mcap_file_writes_reach_the_kernel_in_bounded_pieces() -> None:
    # a finished chunk is ~0.3 MB; the kernel must see it in pieces (mcapout's docstring)
    from tfl_mav.flightlog.mcapout import WRITE_PIECE_BYTES, _PiecewiseWrites

    raw = _Syscalls()
    f = _PiecewiseWrites(io.BufferedWriter(raw, buffer_size=8192))
    rng = random.Random(7)
    parts = [rng.randbytes(n) for n in (5, 300_000, WRITE_PIECE_BYTES, 1, 70_001, 0, 9000)]
    parts.append(memoryview(bytearray(rng.randbytes(4 * 20_000))).cast("I"))   # non-byte view
    for p in parts:
        assert f.write(p) == memoryview(p).nbytes
    f.flush()
    assert bytes(raw.data) == b"".join(bytes(memoryview(p).cast("B")) for p in parts)
    assert max(raw.sizes) <= WRITE_PIECE_BYTES
