"""MCAP recorder: real links on loopback UDP, real files, real processes killed mid-run."""

from __future__ import annotations

import base64
import inspect
import json
import math
import os
import signal
import socket
import struct
import subprocess
import sys
import time
from collections import defaultdict
from pathlib import Path

import jsonschema
import numpy as np
import pytest
from mcap.exceptions import McapError
from mcap.reader import make_reader

from tfl_mav.flightlog.logread import LogReader
from tfl_mav.flightlog.recorder import Recorder, RecorderError
from tfl_mav.link.dialect import mav, new_mavlink
from tfl_mav.link.transport import Link
from tfl_mav.tools.cli.main import main as cli_main

REPO = Path(__file__).resolve().parents[2]
NAN = float("nan")
ROTORS = ((0.25, 0.0), (0.0, -0.25), (-0.25, 0.0), (0.0, 0.25))   # + layout, 0.25 m arms
TICKS = 150


def _odometry(k: int) -> mav.MAVLink_odometry_message:
    """A state at tick k (1 ms ticks), unknown covariances (NaN first element, MAVLink's
    convention) and a velocity that is not a round float32."""
    cov = [NAN] + [0.0] * 20
    return mav.MAVLink_odometry_message(
        k * 1000, mav.MAV_FRAME_LOCAL_NED, mav.MAV_FRAME_BODY_FRD, 0.1 * k, -0.2, -1.5,
        [1.0, 0.0, 0.0, 0.0], 0.1, 0.2, 0.3, 0.01, 0.02, 0.03, cov, cov, 0, 0, 100)


def _esc(k: int) -> mav.MAVLink_esc_telemetry_1_to_4_message:
    rpm = [6000 + k % 7, 6100, 6200, 6300]
    return mav.MAVLink_esc_telemetry_1_to_4_message([30] * 4, [1600] * 4, [500] * 4,
                                                    [10] * 4, rpm, [k & 0xFFFF] * 4)


def _fly_link_pair(tmp_path: Path) -> tuple[Path, Path, Link, Link, float, float]:
    """Vehicle ⇄ controller over loopback UDP for TICKS lockstep ticks, each side recording
    its own file; plus garbage, a MAVLink 1 frame, a truncated frame and a foreign sender."""
    veh_file, ctl_file = tmp_path / "veh.mcap", tmp_path / "ctl.mcap"
    t_start = time.time()
    with Link.listen(("127.0.0.1", 0), src_system=1, src_component=1) as veh, \
            Link.connect(veh.local_address, src_system=2, src_component=1) as ctl, \
            Recorder(veh_file, rotor_xy_m=ROTORS, thrust_max_n=8.0) as rec_v, \
            Recorder(ctl_file) as rec_c, \
            socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as stranger:
        rec_v.attach(veh)
        rec_c.attach(ctl)
        ctl.send(mav.MAVLink_heartbeat_message(mav.MAV_TYPE_ONBOARD_CONTROLLER, 8, 0, 0, 4, 3))
        assert veh.recv(1.0), "vehicle never heard the controller's HEARTBEAT"
        veh.send(mav.MAVLink_heartbeat_message(mav.MAV_TYPE_QUADROTOR, 8, 128, 0, 4, 3))
        veh.send(mav.MAVLink_statustext_message(mav.MAV_SEVERITY_WARNING,
                                                b"attack \xff on rotor 2"))
        rec_v.path(np.c_[np.linspace(0, 5, 50), np.cos(np.linspace(0, 5, 50)),
                         np.full(50, 8.0)])
        for k in range(TICKS):
            veh.send(_odometry(k))
            veh.send(_esc(k))
            got = []
            deadline = time.monotonic() + 1.0
            while not any(m.get_type() == "ESC_TELEMETRY_1_TO_4" for m in got):
                assert time.monotonic() < deadline, f"no ESC_TELEMETRY at tick {k}"
                got += ctl.recv(0.2)
            odo = next(m for m in got if m.get_type() == "ODOMETRY")
            ctl.send(mav.MAVLink_hil_actuator_controls_message(
                odo.time_usec, [0.43, 0.45, 1.0, 0.0] + [0.0] * 12, 128, 1))
            assert veh.recv(1.0), f"no HIL_ACTUATOR_CONTROLS at tick {k}"
            t = k * 1e-3
            rec_v.truth(t, [0.1 * k, 0.2, 8.0], [1.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0],
                        [0.0, 0.0, 0.0], [2.7, 2.6, 2.8, 2.7], 2 if k > 50 else 0,
                        1.5 if k > 50 else 0.0, NAN if k == 60 else 1.5)
            rec_c.controller(t, {"mode": "nominal", "xi": np.arange(4.0),
                                 "attack_estimate_n": NAN, "detected_rotor": 0})
        rec_c.log("warning", "link check done", TICKS * 1e-3)
        ctl.send_raw(b"\x00not mavlink")
        ctl.send_raw(b"\xfe\x09\x00\x01\x01\x00" + bytes(11))         # MAVLink 1
        ctl.send_raw(bytes(_odometry(0).pack(new_mavlink(2, 1)))[:20])  # truncated
        stranger.sendto(b"\xfdhello", veh.local_address)              # foreign sender
        time.sleep(0.05)
        veh.recv(0.2)
    return veh_file, ctl_file, veh, ctl, t_start, time.time()


@pytest.fixture(scope="module")
def flight(tmp_path_factory):
    return _fly_link_pair(tmp_path_factory.mktemp("flight"))


def _decode(sc, ch, data: bytes) -> tuple[str, dict]:
    """(schema text, message as a dict): JSON channels as they are; Foxglove's protobuf
    channels decoded with the official classes (foxglove-schemas-protobuf), the schema as
    ``protobuf:<name>``."""
    if ch.message_encoding == "json":
        return sc.data.decode(), json.loads(data)
    if ch.message_encoding == "cdr":     # plot channels: the MCAP project's ROS 2 decoder
        from mcap_ros2.decoder import DecoderFactory

        msg = DecoderFactory().decoder_for("cdr", sc)(data)
        return f"ros2msg:{sc.name}", {"labels": msg.layout.dim[0].label,   # NaN as text:
                                      "data": [v if v == v else "NaN" for v in msg.data]}
    from google.protobuf import descriptor_pb2, descriptor_pool, message_factory
    from google.protobuf.json_format import MessageToDict

    assert ch.message_encoding == "protobuf" and sc.encoding == "protobuf"
    if sc.name.startswith("foxglove."):
        module = __import__(f"foxglove_schemas_protobuf.{sc.name.split('.')[1]}_pb2",
                            fromlist=["x"])
        cls = getattr(module, sc.name.split(".")[1])
    else:           # the recorder's own: the protobuf library on the schema in the file
        pool = descriptor_pool.DescriptorPool()
        for fd in descriptor_pb2.FileDescriptorSet.FromString(sc.data).file:
            pool.Add(fd)
        cls = message_factory.GetMessageClass(pool.FindMessageTypeByName(sc.name))
    return f"protobuf:{sc.name}", MessageToDict(cls.FromString(data),
                                                preserving_proto_field_name=True,
                                                use_integers_for_enums=True,
                                                always_print_fields_with_no_presence=True)


def _read_all(path: Path) -> list[tuple[str, str, dict, int, int]]:
    """(topic, schema, message, log_time, publish_time) in log-time order, via the
    mcap reader (which refuses unfinished files)."""
    with open(path, "rb") as f:
        reader = make_reader(f)
        return [(ch.topic, *_decode(sc, ch, m.data), m.log_time, m.publish_time)
                for sc, ch, m in reader.iter_messages(log_time_order=False)]


def _finite(value) -> bool:
    values = value if isinstance(value, list) else [value]
    return all(not isinstance(v, float) or math.isfinite(v) for v in values)


@pytest.mark.parametrize("side", ["veh", "ctl"])
def test_counts_match_link_stats(flight, side):
    veh_file, ctl_file, veh, ctl, *_ = flight
    path, link = (veh_file, veh) if side == "veh" else (ctl_file, ctl)
    raw = [m for topic, _, m, _, _ in _read_all(path) if topic == "/mavlink/raw"]
    st = link.stats
    rx = [f for f in raw if not f.get("tx")]
    assert sum(len(f["frames"]) - len(f.get("rejected", [])) for f in rx) == st.rx_frames
    assert sum(len(f.get("rejected", [])) for f in rx) == st.rejected
    assert sum(len(f["frames"]) for f in raw if f.get("tx")) == st.tx_frames
    assert st.rx_frames >= TICKS and st.tx_frames >= TICKS
    if side == "veh":
        assert st.rejected == 4   # garbage, MAVLink 1, truncated, foreign
        assert st.garbage == st.mavlink1 == st.truncated == st.foreign == 1


@pytest.mark.parametrize("side", ["veh", "ctl"])
def test_raw_bytes_reparse_to_the_decoded_messages(flight, side):
    path = flight[0] if side == "veh" else flight[1]
    msgs = _read_all(path)
    decoded: dict[str, list[dict]] = defaultdict(list)
    for topic, _, m, _, _ in msgs:
        if topic.startswith("/mavlink/") and topic != "/mavlink/raw":
            decoded[topic].append(m)
    # Every frame is raw, a datagram a message; a decoded record (at most one per channel
    # every 20 ms of sim time) follows its datagram's raw record at the same time: the
    # decoded of a raw frame is the next record of its channel when one was written for it.
    cursor: dict[str, int] = defaultdict(int)
    parser = new_mavlink(200, 1)
    checked = 0
    for k, (topic, _, f, log_ns, _pub_ns) in enumerate(msgs):
        if topic != "/mavlink/raw":
            continue
        # the datagram's decoded records follow it, at its log time, in its frames' order
        after = [t for t, _, _, lt, _ in msgs[k + 1:k + 1 + len(f["frames"])]
                 if lt == log_ns and t.startswith("/mavlink/") and t != "/mavlink/raw"]
        for i, data in enumerate(f["frames"]):
            if i in f.get("rejected", []):
                continue
            try:
                wire = parser.decode(bytearray(base64.b64decode(data)))
            except Exception:                            # sent with send_raw: not MAVLink
                continue
            chan = (f"/mavlink/{wire.get_srcSystem()}/{wire.get_srcComponent()}/"
                    f"{wire.get_type()}")
            if not after or after[0] != chan:
                continue                                 # decoded less often than raw
            after.pop(0)
            rec = decoded[chan][cursor[chan]]
            cursor[chan] += 1
            for name in wire.get_fieldnames():
                value = getattr(wire, name)
                if _finite(value):
                    assert rec[name] == value, (chan, name, rec[name])
                else:   # NaN/inf: left out of the JSON and listed
                    assert name not in rec and name in rec["_nonfinite"], (chan, name)
            checked += 1
    assert checked >= 2 * TICKS // 20 if side == "veh" else checked >= TICKS // 20
    assert all(cursor[t] == len(v) for t, v in decoded.items()), "decoded without raw"


@pytest.mark.parametrize("side", ["veh", "ctl"])
def test_every_message_validates_against_its_channel_schema(flight, side):
    path = flight[0] if side == "veh" else flight[1]
    validators: dict[str, jsonschema.protocols.Validator] = {}
    topics = set()
    for topic, schema, m, _, _ in _read_all(path):
        topics.add(topic)
        if schema.startswith(("protobuf:", "ros2msg:")):   # decoded by the official
            continue                                       # classes/decoder: typed
        v = validators.get(schema)
        if v is None:
            s = json.loads(schema)
            jsonschema.validators.validator_for(s).check_schema(s)
            v = validators[schema] = jsonschema.validators.validator_for(s)(s)
        v.validate(m)
    expected = ({"/mavlink/raw", "/mavlink/1/1/ODOMETRY", "/mavlink/1/1/ESC_TELEMETRY_1_TO_4",
                 "/mavlink/2/1/HIL_ACTUATOR_CONTROLS", "/mavlink/1/1/STATUSTEXT", "/log",
                 "/sim/truth/state", "/tf",
                 "/scene/vehicle", "/scene/path", "/sim/truth/path_distance"}
                if side == "veh" else {"/controller/state", "/log", "/mavlink/raw"})
    assert expected <= topics


def _foxglove_accepts(schema: dict, where: str = "") -> None:
    """The rules of Foxglove's JSON-schema reader (``parseJsonSchema`` in foxglove/studio
    packages/mcap-support): an object with properties; each property has a single ``type``
    (or a ``oneOf`` of numeric consts); strings may be base64; array items typed likewise."""
    assert schema.get("type") == "object", f"{where}: not an object"
    for name, field in schema["properties"].items():
        at = f"{where}.{name}"
        if isinstance(field.get("oneOf"), list):
            assert all(isinstance(alt.get("const"), int) for alt in field["oneOf"]), at
            continue
        kind = field.get("type")
        if kind == "string":
            assert field.get("contentEncoding") in (None, "base64"), at
        elif kind == "object":
            _foxglove_accepts(field, at)
        elif kind == "array":
            item = field["items"]
            if item.get("type") == "object":
                _foxglove_accepts(item, at)
            else:
                assert item.get("type") in ("boolean", "string", "number", "integer"), at
                assert "contentEncoding" not in item, at
        else:
            assert kind in ("boolean", "number", "integer"), f"{at}: type {kind!r}"


def test_every_schema_is_one_foxglove_can_read(flight):
    from tfl_mav.controller.daemon import TICK_SCHEMA
    from tfl_mav.flightlog import schemas

    seen = {sc for path in flight[:2] for _, sc, *_ in _read_all(path)
            if not sc.startswith(("protobuf:", "ros2msg:"))}
    everything = [json.loads(sc) for sc in seen] + [TICK_SCHEMA] + [
        schemas.mavlink_schema(i) for i in mav.mavlink_map]
    for sc in everything:
        _foxglove_accepts(sc, sc["title"])


def test_times_and_foxglove_content(flight):
    veh_file, _, _, _, t_start, t_end = flight
    msgs = _read_all(veh_file)
    for topic, _, m, log_ns, pub_ns in msgs:
        assert t_start - 1e-3 <= log_ns * 1e-9 <= t_end + 1e-3, topic
        assert pub_ns == log_ns                              # the SDK's publish_time
        if topic == "/mavlink/1/1/ODOMETRY":
            assert m["_nonfinite"] == ["pose_covariance", "velocity_covariance"]
            assert m["vx"] == pytest.approx(0.1, abs=1e-8) and m["vx"] != 0.1  # float32 wire
    truth = [m for t, _, m, _, _ in msgs if t == "/sim/truth/state"]
    at_60 = [a for a in truth if a["t_s"] == pytest.approx(0.06)]
    assert len(at_60) == 1 and at_60[0]["attack_requested_n"] == "NaN"   # kept, as protobuf
    assert at_60[0]["attack_applied_n"] == 1.5 and at_60[0]["attack_rotor"] == 2
    assert at_60[0]["thrust_n"] == [2.7, 2.6, 2.8, 2.7]
    logs = [m["message"] for t, _, m, _, _ in msgs if t == "/log"]
    assert any("attack \ufffd on rotor 2" in text for text in logs)
    scenes = [m for t, _, m, _, _ in msgs if t == "/scene/vehicle"]
    ent = scenes[-1]["entities"][0]
    assert ent["frame_id"] == "base_link" and len(ent["cubes"]) == 5
    assert ent["cubes"][2]["color"]["r"] == 1.0 and ent["cubes"][2]["color"]["g"] < 0.1
    # attacked rotor 2 (on -y): red marker sphere over it; one thrust arrow per rotor
    assert [(s["pose"]["position"]["x"], s["pose"]["position"]["y"]) for s in ent["spheres"]] \
        == [(0.0, -0.25)]
    assert len(ent["arrows"]) == 4
    tfs = [m for t, _, m, _, _ in msgs if t == "/tf"]
    assert tfs[-1]["translation"]["x"] == pytest.approx(0.1 * (TICKS - 1), abs=0.1 * 20 + 1e-9)
    # /tf and /scene/vehicle follow scene_hz (50 Hz sim time) over 0.149 s of sim: 8 each
    assert len(tfs) == len(scenes) == math.floor((TICKS - 1) * 1e-3 * 50) + 1


def test_path_distance_channel_is_distance_to_the_polyline(flight):
    msgs = _read_all(flight[0])
    dist = [m for t, _, m, _, _ in msgs if t == "/sim/truth/path_distance"]
    xs = np.linspace(0.0, 5.0, 50001)     # the path: (s, cos s, 8), s in [0, 5]
    assert len(dist) == 8
    for d in dist:   # truth: (100 t, 0.2, 8), same height as the path
        x = 100.0 * d["t_s"]
        exact = float(np.min(np.hypot(xs - x, np.cos(xs) - 0.2)))
        # 50 samples: chord sag <= h^2/8 * max|cos''| = 0.102^2/8 = 1.3 mm
        assert d["distance_m"] == pytest.approx(exact, abs=2e-3)


CHILD = r"""
import json, os, struct, time
from tfl_mav.link.dialect import mav
from tfl_mav.link.transport import Link
from tfl_mav.flightlog.recorder import Recorder
from tfl_mav.flightlog.recorder_process import RecorderProcess
rec = {cls}({path!r}, flush_interval_s={interval})
with Link.listen(("127.0.0.1", 0), src_system=1, src_component=1) as a, \
        Link.connect(a.local_address, src_system=2, src_component=1) as b:
    rec.attach(a)
    b.send(mav.MAVLink_heartbeat_message(18, 8, 0, 0, 4, 3))
    a.recv(1.0)
    print("ready", flush=True)
    last = os.open({path!r} + ".last", os.O_WRONLY | os.O_CREAT)
    k = 0
    t0 = time.monotonic()
    while time.monotonic() - t0 < {duration}:
        os.pwrite(last, struct.pack("<dq", time.time(), k), 0)   # before this tick's calls
        a.send(mav.MAVLink_hil_actuator_controls_message(k, [0.5] * 16, 128, 1))
        rec.truth(k * 1e-3, [0.0, 0.0, 1.0], [0.0] * 3, [1.0, 0.0, 0.0, 0.0], [0.0] * 3,
                  [2.0] * 4, 0, 0.0, 0.0)
        b.recv(0.0)
        k += 1
        time.sleep(0.0005)
print(json.dumps({{"error": rec.error, "stats": rec.stats.as_dict(), "ticks": k}}), flush=True)
"""


def _last_tick(path: Path) -> tuple[float, int]:
    """Wall time (s) and number of the last tick the child began (stamped just before its
    calls): what it had logged by its kill is at least everything before. A loss measured
    from here is the recorder's, not how long a loaded machine left the child unscheduled
    before the kill (a loss measured from the kill counted that too)."""
    return struct.unpack("<dq", Path(f"{path}.last").read_bytes())


def _last_tick_s(path: Path) -> float:
    return _last_tick(path)[0]


def _start_child(path: Path, *, interval: float, duration: float, preexec=None,
                 cls: str = "Recorder") -> subprocess.Popen:
    code = CHILD.format(path=str(path), interval=interval, duration=duration, cls=cls)
    return subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, cwd=REPO, preexec_fn=preexec)


@pytest.mark.slow
def test_sigkill_leaves_a_readable_file_missing_at_most_the_last_second(tmp_path):
    path = tmp_path / "killed.mcap"
    proc = _start_child(path, interval=1.0, duration=30.0)
    assert proc.stdout.readline().strip() == "ready", proc.stderr.read()
    time.sleep(2.6)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait(5)
    # Read once it is dead: a clock read before os.kill can precede the flight's last tick
    # (the signal lands a few µs later; seen in CI: 9 µs).
    t_dead = time.time()
    with open(path, "rb") as f, pytest.raises(McapError):   # unfinished: no summary
        list(make_reader(f).iter_messages())
    reader = LogReader(path)
    last = max(m.log_time_ns for m in reader.messages()) * 1e-9
    assert not reader.complete
    # flush every 1.0 s, inline at the first write after it is due (ticks are ~1 ms), the
    # next one due 1.0 s after the previous *ended*: at most the interval plus one flush
    # (a kill that tears a chunk loses that interval, no more); 0.4 s for a flush the
    # scheduler interrupts on 2 shared cores
    lost = _last_tick_s(path) - last
    assert lost <= 1.0 + 0.4, f"lost {lost:.2f} s"
    assert t_dead >= _last_tick_s(path)
    # --recover rewrites it as a valid file with everything readable
    out = tmp_path / "recovered.mcap"
    assert cli_main(["inspect", str(path), "--recover", str(out), "--json"]) == 0
    with open(out, "rb") as f:
        r = make_reader(f)
        summary = r.get_summary()
        n = sum(1 for _ in r.iter_messages())
    assert n == summary.statistics.message_count == sum(1 for _ in LogReader(path).messages())
    assert n > 1000


@pytest.mark.slow
def test_write_error_mid_run_is_counted_and_flight_goes_on(tmp_path):
    """A file-size limit (RLIMIT_FSIZE, the kernel's EFBIG) stands in for a full disk."""
    import resource

    def limit() -> None:
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (16 * 1024, 16 * 1024))

    path = tmp_path / "full.mcap"
    proc = _start_child(path, interval=0.1, duration=2.0, preexec=limit)
    out, err = proc.communicate(timeout=20)
    assert proc.returncode == 0, err
    result = json.loads(out.splitlines()[-1])
    assert result["stats"]["write_errors"] == 1
    assert result["stats"]["dropped"] > 0
    assert str(path) in result["error"] and "File too large" in result["error"]
    assert result["ticks"] > 500                    # kept flying after the error
    assert path.stat().st_size <= 16 * 1024
    assert sum(1 for _ in LogReader(path).messages()) > 0


def test_unwritable_path_raises_a_clear_error(tmp_path):
    missing = tmp_path / "no" / "such" / "dir" / "run.mcap"
    with pytest.raises(RecorderError, match=str(missing)):
        Recorder(missing)
    with pytest.raises(RecorderError, match=str(tmp_path)):
        Recorder(tmp_path)                          # a directory
    if os.path.exists("/dev/full"):
        with pytest.raises(RecorderError, match=r"/dev/full.*No space left"):
            Recorder("/dev/full")
    with pytest.raises(OSError):                    # RecorderError is an OSError
        Recorder(missing)


def test_bad_input_is_counted_never_raised(tmp_path):
    path = tmp_path / "bad.mcap"
    with Recorder(path) as rec:
        rec.truth(0.0, [1.0, 2.0], [0.0] * 3, [1, 0, 0, 0], [0] * 3, [1] * 4, 0, 0.0, 0.0)
        rec.truth(NAN, [0.0] * 3, [0.0] * 3, [1, 0, 0, 0], [0] * 3, [1] * 4, 0, 0.0, 0.0)
        rec.truth(0.0, [0.0] * 3, [0.0] * 3, [1, 0, 0, 0], [0] * 3, [1] * 4, 7, 0.0, 0.0)
        rec.truth(0.0, [NAN] * 3, [0.0] * 3, [1, 0, 0, 0], [0] * 3, [1] * 4, 0, 0.0, 0.0)
        rec.on_frame("sideways", b"\xfd", None, 0.0)
        rec.controller(0.1, {"bad": object()})
        rec.log("loud", "text", 0.1)
        rec.set_sim_time(float("inf"))
        assert rec.stats.bad_input == 8
        assert rec.last_bad_input.startswith("time_s")
        with pytest.raises(ValueError, match="points_m"):
            rec.path([[0.0, 0.0, NAN], [1.0, 1.0, 1.0]])       # setup call: raises
    msgs = _read_all(path)
    state = [m for t, _, m, _, _ in msgs if t == "/sim/truth/state"]
    assert len(state) == 1 and state[0]["position_m"] == ["NaN"] * 3   # recorded as it was
    assert not [t for t, *_ in msgs if t == "/tf"]             # NaN pose: no scene
    assert [m["level"] for t, _, m, _, _ in msgs if t == "/log"] == [0]


def test_controller_state_keeps_free_keys_and_nan_and_leaves_out_none(tmp_path):
    path = tmp_path / "ctl.mcap"
    state = {"mode": "attacked", "detected_rotor": np.int64(2), "attack_estimate_n": None,
             "path_distance_m": np.float32(0.25), "saturated": np.bool_(False),
             "rotor_thrust_cmd_n": np.array([2.0, 0.0, 2.5, 3.0]),
             "xi": [[0.1, NAN], [0.0, 1.0]], "cusum": (0.0, 1.5), "reason": "ok",
             "nested": {"a": float("inf"), "b": 1}}
    with Recorder(path) as rec:
        rec.controller(1.25, state)
    (msg,) = [m for t, _, m, _, _ in _read_all(path) if t == "/controller/state"]
    assert msg == {"mode": "attacked", "detected_rotor": "2", "path_distance_m": 0.25,
                   "saturated": False, "rotor_thrust_cmd_n": [2.0, 0.0, 2.5, 3.0],
                   "xi": [{"values": [0.1, "NaN"]}, {"values": [0.0, 1.0]}],
                   "cusum": [0.0, 1.5], "reason": "ok", "nested": '{"a":null,"b":1}',
                   "t_s": 1.25}        # MessageToDict: int64 as text, NaN as "NaN"


def test_controller_record_is_named_by_the_callers_fields(tmp_path):
    """The compact per-tick record (a tuple) is named by ``controller_fields`` in the
    recorder, described by the caller's schema; a wrong length is counted, not raised."""
    from tfl_mav.controller.daemon import TICK_FIELDS, TICK_SCHEMA

    path = tmp_path / "ctl.mcap"
    record = ("attacked", 2, NAN, 0.25, False, [2.0, 0.0, 2.5, 3.0], ((0.1, 0.2), (0.0, 1.0)),
              (1.0, 0.5), 1.1, True, "", (0.0, 1.5, 0.0, 0.0))
    with Recorder(path, controller_fields=TICK_FIELDS, controller_schema=TICK_SCHEMA) as rec:
        rec.controller(0.5, record)
        rec.controller(0.6, record[:3])
        assert rec.stats.bad_input == 1 and "expected 12 values" in rec.last_bad_input
    ((_, schema, msg, _, _),) = [r for r in _read_all(path) if r[0] == "/controller/state"]
    assert schema == "protobuf:tfl_mav.ControllerState"
    assert msg["detected_rotor"] == "2" and msg["xi"] == [{"values": [0.1, 0.2]},
                                                          {"values": [0.0, 1.0]}]
    assert msg["attack_estimate_n"] == "NaN" and msg["t_s"] == 0.5 and msg["fine_gains"]
    (rec,) = [m.decode() for m in LogReader(path).messages({"/controller/state"})]
    assert rec["xi"] == [[0.1, 0.2], [0.0, 1.0]] and math.isnan(rec["attack_estimate_n"])
    assert rec["cusum"] == [0.0, 1.5, 0.0, 0.0] and rec["detected_rotor"] == 2


def test_background_flush_makes_quiet_data_readable_while_open(tmp_path):
    path = tmp_path / "quiet.mcap"
    with Recorder(path, flush_interval_s=0.2, rotor_xy_m=ROTORS) as rec:
        for k in range(10):
            rec.truth(k * 1e-3, [0.0] * 3, [0.0] * 3, [1, 0, 0, 0], [0] * 3, [1] * 4, 0, 0.0,
                      0.0)
        # No more writes: only the flusher thread can flush. It does so every 0.2 s when
        # idle; wait for that event (a fixed 0.6 s sleep failed when a loaded machine held
        # the thread off longer), up to 10 s = 50 intervals: a flusher that does not run
        # still fails here.
        deadline = time.monotonic() + 10.0
        while rec.stats.flushes < 1 and time.monotonic() < deadline:
            time.sleep(0.05)
        assert rec.stats.flushes >= 1
        seen = [m for m in LogReader(path).messages() if m.topic == "/sim/truth/state"]
        assert len(seen) == 10
    assert rec.error is None
    rec.truth(1.0, [0.0] * 3, [0.0] * 3, [1, 0, 0, 0], [0] * 3, [1] * 4, 0, 0.0, 0.0)
    # after close: the truth, tf, scene and the three truth plots
    assert rec.stats.dropped == 6


# ---------------------------------------------------------------- RecorderProcess
class _StepClock:
    """A deterministic clock: 1 ms per reading."""

    def __init__(self) -> None:
        self.t = 1_000.0

    def __call__(self) -> float:
        self.t += 1e-3
        return self.t


def _feed(rec) -> None:
    """The same calls, in the same order, for an in-process and a child-process recorder."""
    packer = new_mavlink(1, 1)
    rec.path([[0.0, 0.0, 1.0], [1.0, 0.0, 1.0], [2.0, 1.0, 1.0]])
    for k in range(300):
        for msg in (_odometry(k), _esc(k)):
            raw = bytes(msg.pack(packer))
            packer.seq = (packer.seq + 1) & 0xFF
            rec.on_frame("tx", raw, msg, rec.clock())
        rec.on_frame("rx", b"\x00junk", None, rec.clock())
        rec.truth(k * 1e-3, np.array([0.01 * k, 0.5, 1.0]), [0.0] * 3, [1.0, 0.0, 0.0, 0.0],
                  [0.0] * 3, np.array([2.0, 2.1, 2.2, 2.3]), 1, 2.0, NAN)
        rec.controller(k * 1e-3, {"mode": "nominal", "xi": np.arange(3.0), "e": NAN})
    rec.log("info", "done", 0.3)
    rec.metadata("scenario", {"name": "test"})
    rec.truth(0.0, [1.0], [0.0] * 3, [1, 0, 0, 0], [0] * 3, [1] * 4, 0, 0.0, 0.0)  # bad


def test_recorder_process_writes_what_the_in_process_recorder_writes(tmp_path):
    from tfl_mav.flightlog.recorder_process import RecorderProcess

    a, b = tmp_path / "inproc.mcap", tmp_path / "child.mcap"
    with Recorder(a, clock=_StepClock()) as rec_a:
        _feed(rec_a)
    with RecorderProcess(b, clock=_StepClock()) as rec_b:
        _feed(rec_b)
    assert rec_b.error is None and rec_a.error is None
    assert rec_b.stats.bad_input == rec_a.stats.bad_input == 1
    assert rec_b.last_bad_input == rec_a.last_bad_input

    def content(path):   # path re-sends depend on flush timing: keep the first only
        out, seen_path = [], False
        for topic, _, m, log_ns, pub_ns in _read_all(path):
            if topic == "/scene/path":
                if seen_path:
                    continue
                seen_path = True
            out.append((topic, m, log_ns, pub_ns))
        return sorted(out, key=lambda x: (x[2], x[0], json.dumps(x[1])))

    ca, cb = content(a), content(b)
    assert len(ca) == len(cb) > 1500     # per tick: 2 datagrams, a truth, a controller record
    assert ca == cb
    with open(b, "rb") as f:
        assert {m.name for m in make_reader(f).iter_metadata()} == {"tfl-mav", "scenario"}


@pytest.mark.slow
def test_recorder_process_finishes_the_file_when_the_flight_process_is_killed(tmp_path):
    path = tmp_path / "child.mcap"
    proc = _start_child(path, interval=1.0, duration=30.0, cls="RecorderProcess")
    assert proc.stdout.readline().strip() == "ready", proc.stderr.read()
    time.sleep(1.5)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait(5)
    t_dead = time.time()        # after it died: see the SIGKILL test above
    deadline = time.monotonic() + 15.0
    while True:    # the orphaned recorder child reads end-of-file and finishes the file
        try:
            with open(path, "rb") as f:
                summary = make_reader(f).get_summary()
            if summary is not None:
                break
        except McapError:
            pass
        assert time.monotonic() < deadline, "the recorder child never finished the file"
        time.sleep(0.1)
    # Lost: the calls the flight process had not yet written to the pipe when killed (what
    # is in the pipe still reaches the child). Idle that is batch_s = 10 ms of calls. When
    # the child (niced, on a loaded machine) cannot keep up, the queue grows to its bound,
    # BACKLOG_BATCHES × batch_max calls (+1: then the flight thread sends itself and
    # waits), while the sender thread may hold as many popped and half-written to a full
    # pipe: at most 2 × (BACKLOG_BATCHES × batch_max + 1) calls, 2 a tick (a frame, a
    # truth). Seen at load 10 with 8 batches: 320-880 ticks.
    with open(path, "rb") as f:
        ticks = [round(_decode(sc, ch, m.data)[1]["t_s"] * 1000) for sc, ch, m
                 in make_reader(f).iter_messages(topics=["/sim/truth/state"])]
    t_last, k_last = _last_tick(path)
    from tfl_mav.flightlog.recorder_process import BACKLOG_BATCHES, RecorderProcess

    batch_max = inspect.signature(RecorderProcess).parameters["batch_max"].default
    bound = BACKLOG_BATCHES * batch_max + 1
    assert k_last - ticks[-1] <= bound, f"lost {k_last - ticks[-1]} ticks"
    assert ticks == list(range(len(ticks)))      # nothing lost before the end
    assert t_dead >= t_last and len(ticks) > 1000


@pytest.mark.slow
def test_recorder_process_unwritable_path(tmp_path):
    from tfl_mav.flightlog.recorder_process import RecorderProcess

    missing = tmp_path / "missing" / "run.mcap"
    with pytest.raises(RecorderError, match=str(missing)):
        RecorderProcess(missing)
    with pytest.raises(ValueError, match="flush_interval_s"):
        RecorderProcess(tmp_path / "x.mcap", flush_interval_s=0)
