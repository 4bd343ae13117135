"""The recorder's protobuf records are what the protobuf library writes, and its hot paths
write what the careful ones do.

* every fixed message (:mod:`~tfl_mav.flightlog.protos`: raw frames, truth) byte for byte
  the library's ``SerializeToString`` of the same values, on the schema stored in the file
  (NaN, inf, -0.0 and extreme values included);
* a caller's record (:class:`~tfl_mav.flightlog.protos.RecordEncoder`, the controller's)
  likewise, from a tuple and from a mapping, and read back by :meth:`LogMessage.decode`;
* ``RecorderProcess.on_frames`` (one call per datagram) writes what ``on_frame`` does;
* the MCAP file's writes reach the kernel in bounded pieces.
"""

from __future__ import annotations

import io
import math
import random
from typing import Any

from hypothesis import given, settings
from hypothesis import strategies as st
from mcap.reader import make_reader

from tfl_mav.controller.daemon_wire import TICK_FIELDS, TICK_SCHEMA
from tfl_mav.flightlog import protos
from tfl_mav.flightlog.logread import LogReader, raw_frames
from tfl_mav.flightlog.recorder import Recorder
from tfl_mav.flightlog.recorder_process import RecorderProcess
from tfl_mav.link.dialect import mav, new_mavlink

_DOUBLES = st.floats(allow_nan=True, allow_infinity=True, width=64)


def _library(name: str, data: bytes) -> Any:
    """The protobuf library's class of ``name`` from a schema's FileDescriptorSet."""
    from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

    pool = descriptor_pool.DescriptorPool()
    for fd in descriptor_pb2.FileDescriptorSet.FromString(data).file:
        pool.Add(fd)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(name))


def _cls(name: str) -> Any:
    return _library(name, protos.schema(name)[2])


@settings(max_examples=200, deadline=None)
@given(st.lists(_DOUBLES, min_size=20, max_size=20), st.integers(0, 4),
       st.binary(min_size=0, max_size=300), st.booleans(), st.booleans())
def test_fixed_messages_are_the_librarys_bytes(v: list[float], rotor: int, raw: bytes,
                                               tx: bool, rejected: bool) -> None:
    State, Dist, Frames = (_cls(n) for n in (protos.TRUTH_STATE, protos.PATH_DISTANCE,
                                             protos.FRAMES))
    assert protos.truth_state(v[0], v[1:4], v[4:7], v[7:11], v[11:14], v[14:18], rotor, v[18],
                              v[19]) == State(
        t_s=v[0], position_m=v[1:4], velocity_mps=v[4:7], quaternion_wxyz=v[7:11],
        body_rates_radps=v[11:14], thrust_n=v[14:18], attack_rotor=rotor,
        attack_applied_n=v[18], attack_requested_n=v[19]).SerializeToString()
    assert protos.path_distance(v[0], v[1]) == Dist(t_s=v[0], distance_m=v[1]) \
        .SerializeToString()
    assert protos.truth_wind(v[0], v[1:4]) == _cls(protos.TRUTH_WIND)(
        t_s=v[0], wind_mps=v[1:4]).SerializeToString()
    raws = [raw, raw[:5], b"", raw * 2]
    refused = [1, 3] if rejected else []
    lib = Frames(frames=raws, rejected=refused)
    if tx:
        lib.tx = True
    assert protos.frames(raws, tx, refused) == lib.SerializeToString()
    assert protos.frames_fields(lib.SerializeToString()) == (raws, tx, refused)
    assert protos.frames_fields(lib.SerializeToString()[:-1]) is None     # cut short


_RECORD = st.tuples(st.sampled_from(["nominal", "attacked", "fällback"]),
                    st.integers(-(2**63), 2**63 - 1), _DOUBLES | st.none(), _DOUBLES,
                    st.booleans(), st.lists(_DOUBLES, min_size=4, max_size=4),
                    st.lists(st.lists(_DOUBLES, max_size=5), max_size=3),
                    st.lists(_DOUBLES, max_size=40), _DOUBLES, st.booleans(),
                    st.text(max_size=30), st.lists(_DOUBLES, max_size=4))


@settings(max_examples=200, deadline=None)
@given(_DOUBLES, _RECORD)
def test_records_are_the_librarys_bytes(t: float, record: tuple[Any, ...]) -> None:
    enc = protos.RecordEncoder(TICK_SCHEMA, TICK_FIELDS)
    Cls = _library(enc.name, enc.schema_data)
    lib = Cls(t_s=t)
    for name, value in zip(TICK_FIELDS, record, strict=True):
        if value is None:
            continue
        if name == "xi":
            for inner in value:
                lib.xi.add(values=inner)
        elif isinstance(value, list):
            getattr(lib, name).extend(value)
        else:
            setattr(lib, name, value)
    assert enc.encode(t, record) == lib.SerializeToString()
    assert enc.encode_map({"t_s": t, **dict(zip(TICK_FIELDS, record, strict=True))}) \
        == lib.SerializeToString()


def test_records_read_back_through_the_file(tmp_path: Any) -> None:
    """Written by the recorder, read by ``LogReader`` with the schema in the file."""
    record = ("attacked", 2, math.nan, 0.25, False, [2.0, 0.0, 2.5, 3.0],
              ((0.1, 0.2), (0.0, 1.0)), (1.0, 0.5), -0.0, True, "", ())
    path = tmp_path / "ctl.mcap"
    with Recorder(path, controller_fields=TICK_FIELDS, controller_schema=TICK_SCHEMA) as rec:
        rec.controller(0.5, record)
        rec.controller(0.501, (*record[:2], None, *record[3:]))
    a, b = [m.decode() for m in LogReader(path).messages({"/controller/state"})]
    assert a["xi"] == [[0.1, 0.2], [0.0, 1.0]] and math.isnan(a["attack_estimate_n"])
    assert math.copysign(1.0, a["mass_estimate_kg"]) == -1.0 and "cusum" not in a
    assert "attack_estimate_n" not in b and b["t_s"] == 0.501 and b["mode"] == "attacked"


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
    # every frame raw (100 accepted, 7 rejected), a datagram a message; decoded at most
    # every 20 ms of sim time (the scene rate): ODOMETRY and HIL_ACTUATOR_CONTROLS at 0, 20
    # and 40 ms
    raw = [m for m in got[0] if m[0] == "/mavlink/raw"]
    assert len(raw) == 50
    frames = list(raw_frames(files[0]))
    assert len(frames) == 50 * 2 + 7 and sum(f[3] for f in frames) == 4    # refused: rx
    assert [f[1] for f in frames] == [r for _d, raws, _m in _frames() for r in raws]
    decoded = sorted((m.topic, m.decode()["time_usec"]) for m in LogReader(files[0]).messages()
                     if m.topic != "/mavlink/raw")
    assert decoded == sorted((topic, ms * 1000) for ms in (0, 20, 40)
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
    from tfl_mav.flightlog.mcapout import WRITE_PIECE_BYTES, PiecewiseFile

    raw = _Syscalls()
    f = PiecewiseFile(io.BufferedWriter(raw, buffer_size=8192), lambda exc: None)
    rng = random.Random(7)
    parts = [rng.randbytes(n) for n in (5, 300_000, WRITE_PIECE_BYTES, 1, 70_001, 0, 9000)]
    parts.append(memoryview(bytearray(rng.randbytes(4 * 20_000))).cast("I"))   # non-byte view
    for p in parts:
        assert f.write(p) == memoryview(p).nbytes
    f.flush()
    assert bytes(raw.data) == b"".join(bytes(memoryview(p).cast("B")) for p in parts)
    assert max(raw.sizes) <= WRITE_PIECE_BYTES
