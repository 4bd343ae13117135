"""Foxglove's official schemas in the files and on the live WebSocket.

The scene, ``/tf`` and ``/log`` are protobuf from Foxglove's SDK; here every such message in
a real MCAP file, and every message a real WebSocket client receives from a running
``tfl-mav sim --foxglove`` flown by ``tfl-mav fly``, is decoded with the *official* protobuf
classes (``foxglove-schemas-protobuf``), independent of the SDK that wrote it.
"""

from __future__ import annotations

import base64
import itertools
import json
import math
import socket
import struct
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from foxglove_schemas_protobuf.FrameTransform_pb2 import FrameTransform
from foxglove_schemas_protobuf.Log_pb2 import Log
from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate
from google.protobuf.descriptor_pb2 import FileDescriptorSet
from mcap.reader import make_reader
from websockets.exceptions import ConnectionClosed

from tfl_mav.flightlog.recorder import Recorder

REPO = Path(__file__).resolve().parents[2]
OFFICIAL = {"foxglove.FrameTransform": FrameTransform, "foxglove.SceneUpdate": SceneUpdate,
            "foxglove.Log": Log}
ROTORS = ((0.25, 0.0), (0.0, -0.25), (-0.25, 0.0), (0.0, 0.25))


def _check_schema(name: str, data: bytes) -> None:
    """The schema is a FileDescriptorSet that defines exactly the official message."""
    fds = FileDescriptorSet.FromString(data)
    pkg_types = {f"{f.package}.{m.name}" for f in fds.file for m in f.message_type}
    assert name in pkg_types
    assert OFFICIAL[name].DESCRIPTOR.full_name == name


def test_every_foxglove_message_in_the_file_decodes_with_the_official_classes(tmp_path):
    path = tmp_path / "run.mcap"
    with Recorder(path, rotor_xy_m=ROTORS, thrust_max_n=8.0) as rec:
        rec.path(np.c_[np.linspace(0, 5, 20), np.zeros(20), np.full(20, 2.0)])
        for k in range(100):
            rec.truth(k * 1e-3, [0.01 * k, 0.0, 2.0], [0.0] * 3, [1.0, 0.0, 0.0, 0.0],
                      [0.0] * 3, [2.0, 1.0, 2.0, 2.0], 2 if k >= 40 else 0, 1.0, 1.0)
        rec.log("warning", "ATTACK on rotor 2", 0.04)
    seen: dict[str, int] = {}
    scenes = 0
    with open(path, "rb") as f:
        for sc, ch, m in make_reader(f).iter_messages():
            if ch.topic.startswith("/plot/"):        # ROS 2 Float64MultiArray (plotchan)
                assert (ch.message_encoding, sc.encoding, sc.name) == (
                    "cdr", "ros2msg", "std_msgs/msg/Float64MultiArray")
                continue
            if sc.name.startswith("tfl_mav."):     # the recorder's own (test_recorder_protos)
                assert ch.message_encoding == sc.encoding == "protobuf"
                continue
            if not sc.name.startswith("foxglove."):
                assert ch.message_encoding == "json" and sc.encoding == "jsonschema"
                continue
            assert ch.message_encoding == sc.encoding == "protobuf"
            _check_schema(sc.name, sc.data)
            msg = OFFICIAL[sc.name].FromString(m.data)      # raises if not that message
            seen[ch.topic] = seen.get(ch.topic, 0) + 1
            if ch.topic == "/tf":
                assert (msg.parent_frame_id, msg.child_frame_id) == ("world", "base_link")
                assert msg.timestamp.ToNanoseconds() == m.log_time
            elif ch.topic == "/scene/path":
                assert len(msg.entities[0].lines[0].points) == 20
            elif ch.topic == "/scene/vehicle":
                ent = msg.entities[0]
                assert len(ent.arrows) == 4 and len(ent.cylinders) == 4
                # drawn at t = 0, 20, 40, ... ms: attacked from the third on
                assert len(ent.spheres) == (1 if scenes >= 2 else 0)
                scenes += 1
            elif ch.topic == "/log":
                assert msg.level == Log.WARNING and msg.message.endswith("ATTACK on rotor 2")
    # 100 ticks of 1 ms at 50 Hz scene rate: t = 0, 20, ..., 80 ms
    assert seen == {"/scene/path": 1, "/tf": 5, "/scene/vehicle": 5, "/log": 1}


def _free_port(kind: int = socket.SOCK_STREAM) -> int:
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _cli(*args: str, **kw) -> subprocess.Popen[str]:
    return subprocess.Popen([sys.executable, "-m", "tfl_mav.tools.cli", *args], cwd=REPO, text=True,
                            **kw)


def test_a_port_in_use_is_a_one_line_error(tmp_path):
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        proc = _cli("sim", "--listen", "127.0.0.1:0", "--foxglove", f"127.0.0.1:{port}",
                    stdout=subprocess.PIPE, stderr=subprocess.PIPE)
        out, err = proc.communicate(timeout=60)
    assert proc.returncode == 3, (out, err)
    # Pre-flight feasibility warnings may precede it; the error itself is one line.
    lines = [ln for ln in err.strip().splitlines() if ": warning: " not in ln]
    assert len(lines) == 1 and f"--foxglove 127.0.0.1:{port}" in lines[0], err
    assert "Traceback" not in err


def test_the_scene_is_advertised_on_connect_and_is_the_channel_the_recorder_gets():
    """A viewer that connects before anything is written already has the scene channels
    (channels made mid-connection can be refused by foxglove-sdk, see
    :mod:`tfl_mav.flightlog.live`); the recorder's later ``channel()`` for one of them is that
    same channel: what is logged on it reaches the viewer's subscription."""
    from websockets.sync.client import connect

    from tfl_mav.flightlog import foxglove as fg
    from tfl_mav.flightlog.live import SCENE_TOPICS, LiveServer

    server = LiveServer("127.0.0.1", 0)
    try:
        with connect(f"ws://127.0.0.1:{server.port}", open_timeout=10,
                     subprotocols=["foxglove.websocket.v1", "foxglove.sdk.v1"]) as ws:
            ops = [json.loads(ws.recv(timeout=10)) for _ in range(2)]
            assert [op["op"] for op in ops] == ["serverInfo", "advertise"]
            channels = {ch["topic"]: ch for ch in ops[1]["channels"]}
            assert channels.keys() == SCENE_TOPICS.keys()
            for topic, name in SCENE_TOPICS.items():
                assert channels[topic]["schemaName"] == name
                _check_schema(name, base64.b64decode(channels[topic]["schema"]))
            ws.send(json.dumps({"op": "subscribe", "subscriptions": [
                {"id": 7, "channelId": channels["/tf"]["id"]}]}))
            tf = server.channel("/tf", *fg.schema("foxglove.FrameTransform"), "protobuf")
            data = fg.frame_transform(123, [1.0, 2.0, 3.0], [1.0, 0.0, 0.0, 0.0])
            deadline = time.monotonic() + 10.0
            while True:                         # the subscription lands asynchronously
                assert time.monotonic() < deadline, "nothing on /tf"
                tf.log(data, log_time=123)
                try:
                    msg = ws.recv(timeout=0.1)
                except TimeoutError:
                    continue
                assert isinstance(msg, bytes), msg     # a status here: refused
                break
            assert struct.unpack_from("<BIQ", msg) == (1, 7, 123) and msg[13:] == data
    finally:
        server.close()


def _subscribe_and_collect(ws, channels: dict, topics: dict[int, str], until, feed,
                           timeout_s: float = 10.0) -> dict[str, list[tuple[int, bytes]]]:
    """Subscribe to ``topics`` (id → topic); call ``feed()`` until ``until(got)`` holds (the
    subscription lands asynchronously). A status message (an error) fails."""
    ws.send(json.dumps({"op": "subscribe", "subscriptions": [
        {"id": i, "channelId": channels[t]["id"]} for i, t in topics.items()]}))
    got: dict[str, list[tuple[int, bytes]]] = {t: [] for t in topics.values()}
    deadline = time.monotonic() + timeout_s
    while not until(got):
        assert time.monotonic() < deadline, {t: len(v) for t, v in got.items()}
        feed()
        try:
            msg = ws.recv(timeout=0.1)
        except TimeoutError:
            continue
        except ConnectionClosed:
            pytest.fail(f"server gone (flight over?): {({t: len(v) for t, v in got.items()})}")
        if isinstance(msg, str):               # new channels may be advertised meanwhile
            assert json.loads(msg)["op"] != "status", msg      # e.g. refused
            continue
        op, sub_id, ts_ns = struct.unpack_from("<BIQ", msg)
        assert op == 1
        got[topics[sub_id]].append((ts_ns, msg[13:]))
    return got


def test_the_controllers_live_view_draws_its_estimate():
    """``tfl-mav fly --foxglove`` has no truth: its server draws ``/tf`` from the ODOMETRY
    the controller receives (its state estimate) and ``/scene/vehicle`` from its record
    (commanded thrusts, detected rotor). The pose round-trips exactly: an ENU/FLU pose
    sent as NED/FRD ODOMETRY comes back on ``/tf`` as that pose (float rounding); a message
    it cannot use is counted, never raised, and the next one draws."""
    from websockets.sync.client import connect

    from tfl_mav.flightlog import foxglove as fg
    from tfl_mav.flightlog.live import EstimateScene, LiveServer
    from tfl_mav.model.frames import odometry_from_paper

    scene = EstimateScene(ROTORS, 8.0)
    server = LiveServer("127.0.0.1", 0, scene)
    odo_ch = server.channel("/mavlink/1/1/ODOMETRY", "ODOMETRY", "jsonschema", b"{}", "json")
    from tfl_mav.controller.daemon_wire import TICK_FIELDS, TICK_SCHEMA
    from tfl_mav.flightlog.protos import RecordEncoder

    record = RecordEncoder(TICK_SCHEMA, TICK_FIELDS)
    ctl_ch = server.channel("/controller/state", record.name, "protobuf", record.schema_data,
                            "protobuf")
    pos, quat = [1.5, -2.0, 3.25], [math.cos(0.3), 0.0, 0.0, math.sin(0.3)]   # 0.6 rad yaw
    odo = odometry_from_paper(pos, [0.0] * 3, quat, [0.0] * 3)
    odo_json = json.dumps({"time_usec": 1000, "frame_id": 1, "child_frame_id": 12,
                           **{k: v for k, v in odo._asdict().items()}}).encode()
    log_ns = [1_000_000_000]

    def feed() -> None:                 # 100 Hz of log time: every other one is drawn
        log_ns[0] += 10_000_000
        odo_ch.log(odo_json, log_time=log_ns[0])

    try:
        with connect(f"ws://127.0.0.1:{server.port}", open_timeout=10,
                     subprotocols=["foxglove.websocket.v1", "foxglove.sdk.v1"]) as ws:
            ops = [json.loads(ws.recv(timeout=10)) for _ in range(2)]
            channels = {ch["topic"]: ch for ch in ops[1]["channels"]}
            # a frame it cannot use (q left out: non-finite) is counted, not drawn
            odo_ch.log(odo_json.replace(b'"q"', b'"q_"'), log_time=log_ns[0])
            assert server.estimate.errors == 1 and server.estimate.drawn == 0
            ctl_ch.log(record.encode_map({"t_s": 0.0, "detected_rotor": 2, "rotor_thrust_cmd_n":
                                          [2.0, 0.0, 4.0, 1.0]}), log_time=log_ns[0])
            got = _subscribe_and_collect(
                ws, channels, {1: "/tf", 2: "/scene/vehicle"},
                lambda g: len(g["/tf"]) >= 3 and len(g["/scene/vehicle"]) >= 3, feed)
    finally:
        server.close()
    assert server.estimate.errors == 1
    for ts_ns, data in got["/tf"]:
        tf = FrameTransform.FromString(data)
        assert tf.timestamp.ToNanoseconds() == ts_ns
        assert (tf.parent_frame_id, tf.child_frame_id) == (fg.WORLD, fg.BODY)
        t, r = tf.translation, tf.rotation
        assert [t.x, t.y, t.z] == pytest.approx(pos, abs=1e-12)
        assert [r.w, r.x, r.y, r.z] == pytest.approx(quat, abs=1e-12)
    # at most one drawing per 20 ms of log time, though ODOMETRY came every 10 ms
    stamps = [ts for ts, _ in got["/tf"]]
    assert all(b - a >= 20_000_000 for a, b in itertools.pairwise(stamps))
    ent = SceneUpdate.FromString(got["/scene/vehicle"][-1][1]).entities[0]
    assert ent.frame_id == fg.BODY and len(ent.cylinders) == 4
    assert [tx.text for tx in ent.texts] == ["detected: rotor 2"] and len(ent.spheres) == 1
    # arrows ∝ commanded thrust (rotor 2 commands 0 N: no arrow); shaft = 0.75 of length
    lengths = [a.shaft_length / 0.75 for a in ent.arrows]
    arm = 0.25
    assert lengths == pytest.approx([f / 8.0 * 2 * arm for f in (2.0, 4.0, 1.0)])


@pytest.mark.slow
def test_live_websocket_serves_the_scene_while_it_flies(tmp_path):
    """A real Foxglove WebSocket client on a running flight (``tfl-mav sim --foxglove``
    flown by ``tfl-mav fly``, lockstep: a loaded machine cannot crash it by falling behind
    the wall clock), connected before the flight starts, as a viewer waiting for it is: the
    scene channels are advertised on connect (not mid-flight, where foxglove-sdk can refuse
    an immediate subscription, see :mod:`tfl_mav.flightlog.live`) with the official schemas;
    subscribed at once, as Foxglove subscribes, their messages decode with the official
    protobuf classes and follow the flight, and the server reports no error."""
    from websockets.sync.client import connect

    ws_port, seconds = _free_port(), 60.0      # ended by SIGTERM once the client has seen it
    sim = _cli("sim", "--listen", "127.0.0.1:0", "--duration", f"{seconds:g}",
               "--foxglove", f"127.0.0.1:{ws_port}", stdout=subprocess.PIPE,
               stderr=subprocess.DEVNULL)
    fly = None
    statuses: list[dict] = []                   # the server's status messages (errors)
    try:
        assert sim.stdout is not None
        line = sim.stdout.readline()
        assert "listening on" in line, line
        udp_port = int(line.split("listening on ")[1].split()[0].rsplit(":", 1)[1])
        # Foxglove's WebSocket protocol: "foxglove.websocket.v1" is its historical name;
        # foxglove-sdk >= 0.30 negotiates it as "foxglove.sdk.v1" (same messages)
        with connect(f"ws://127.0.0.1:{ws_port}", open_timeout=10,
                     subprotocols=["foxglove.websocket.v1", "foxglove.sdk.v1"]) as ws:
            assert ws.subprotocol in ("foxglove.websocket.v1", "foxglove.sdk.v1")
            channels: dict[str, dict] = {}

            def text(msg: str) -> dict:
                op = json.loads(msg)
                if op["op"] == "advertise":
                    channels.update((ch["topic"], ch) for ch in op["channels"])
                elif op["op"] == "status":
                    statuses.append(op)
                return op

            # on connect: serverInfo, then one advertise of every channel there is (batches
            # of 100); the flight has not started, yet the scene is there
            while text(ws.recv(timeout=20))["op"] != "advertise":
                pass
            assert {"/tf", "/scene/vehicle", "/scene/path"} <= channels.keys(), sorted(channels)
            fly = _cli("fly", "--vehicle", f"127.0.0.1:{udp_port}", "--duration",
                       f"{seconds:g}", "--quiet", stdout=subprocess.DEVNULL,
                       stderr=subprocess.DEVNULL)
            for topic, name in (("/tf", "foxglove.FrameTransform"),
                                ("/scene/vehicle", "foxglove.SceneUpdate"),
                                ("/scene/path", "foxglove.SceneUpdate")):
                ch = channels[topic]
                assert (ch["schemaName"], ch["encoding"]) == (name, "protobuf")
                _check_schema(name, base64.b64decode(ch["schema"]))
            subs = {1: "/tf", 2: "/scene/vehicle", 3: "/scene/path"}
            got: dict[str, list] = {t: [] for t in subs.values()}
            ws.send(json.dumps({"op": "subscribe", "subscriptions": [
                {"id": i, "channelId": channels[t]["id"]} for i, t in subs.items()]}))
            # /tf and the vehicle at 50 Hz of sim time, the path with every flush (1 s); in
            # lockstep the flight runs faster than real time and a slow client loses the
            # oldest messages (the SDK's per-client queue, 1024), never a whole channel
            deadline = time.monotonic() + 30.0
            while not (len(got["/tf"]) >= 20 and got["/scene/vehicle"] and got["/scene/path"]):
                assert time.monotonic() < deadline, ({t: len(v) for t, v in got.items()},
                                                     statuses)
                msg = ws.recv(timeout=20)
                if isinstance(msg, str):
                    text(msg)
                    continue
                op, sub_id, ts_ns = struct.unpack_from("<BIQ", msg)
                assert op == 1
                topic = subs[sub_id]
                cls = FrameTransform if topic == "/tf" else SceneUpdate
                got[topic].append((ts_ns, cls.FromString(msg[13:])))
    finally:
        for p in (fly, sim):
            if p is not None and p.poll() is None:
                p.terminate()                   # a clean stop (SIGTERM): exit 143
                p.wait(timeout=60)
    assert not statuses, statuses               # e.g. "Unknown channel ID: 2"
    tfs = got["/tf"]
    assert all(tf.child_frame_id == "base_link" for _, tf in tfs)
    # the vehicle moves: positions are finite and the log times increase
    assert all(math.isfinite(tf.translation.z) for _, tf in tfs)
    assert [ts for ts, _ in tfs] == sorted(ts for ts, _ in tfs)
    ent = got["/scene/vehicle"][0][1].entities[0]
    assert ent.frame_id == "base_link" and len(ent.arrows) + len(ent.spheres) >= 3
    assert len(got["/scene/path"][0][1].entities[0].lines[0].points) >= 2


def _moved_m(tfs: list[tuple[int, bytes]]) -> float:
    """Distance (m) between the first and the last ``/tf`` translation received."""
    if len(tfs) < 2:
        return 0.0
    a, b = (FrameTransform.FromString(tfs[i][1]).translation for i in (0, -1))
    return math.dist((a.x, a.y, a.z), (b.x, b.y, b.z))


@pytest.mark.slow
def test_fly_foxglove_shows_the_vehicle_moving_from_the_controllers_estimate(tmp_path):
    """``tfl-mav fly --foxglove`` on a lockstep flight (no viewer on the simulator): a real
    client subscribed to the controller's ``/tf`` and ``/scene/vehicle`` sees the vehicle
    move (the estimate from ODOMETRY) with its four commanded thrusts, and no status."""
    from websockets.exceptions import InvalidHandshake
    from websockets.sync.client import connect

    ws_port, seconds = _free_port(), 60.0      # ended by SIGTERM once the client has seen it
    sim = _cli("sim", "--listen", "127.0.0.1:0", "--duration", f"{seconds:g}",
               stdout=subprocess.PIPE, stderr=subprocess.DEVNULL)
    fly = None
    try:
        assert sim.stdout is not None
        line = sim.stdout.readline()
        assert "listening on" in line, line
        udp_port = int(line.split("listening on ")[1].split()[0].rsplit(":", 1)[1])
        fly = _cli("fly", "--vehicle", f"127.0.0.1:{udp_port}", "--duration", f"{seconds:g}",
                   "--quiet", "--foxglove", f"127.0.0.1:{ws_port}",
                   stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        deadline = time.monotonic() + 60.0     # the server is up once fly's recorder child is
        while True:
            try:
                ws = connect(f"ws://127.0.0.1:{ws_port}", open_timeout=10,
                             subprotocols=["foxglove.websocket.v1", "foxglove.sdk.v1"])
                break
            except (OSError, InvalidHandshake):
                assert time.monotonic() < deadline and fly.poll() is None, "no live view"
                time.sleep(0.1)
        with ws:
            channels: dict[str, dict] = {}
            while not {"/tf", "/scene/vehicle"} <= channels.keys():
                op = json.loads(ws.recv(timeout=20))
                if op["op"] == "advertise":
                    channels.update((ch["topic"], ch) for ch in op["channels"])
            got = _subscribe_and_collect(
                ws, channels, {1: "/tf", 2: "/scene/vehicle"},
                lambda g: _moved_m(g["/tf"]) > 0.05 and g["/scene/vehicle"], lambda: None,
                timeout_s=60.0)
    finally:
        for p in (fly, sim):
            if p is not None and p.poll() is None:
                p.terminate()                   # a clean stop (SIGTERM): exit 143
                p.wait(timeout=60)
    tfs = [FrameTransform.FromString(d) for _ts, d in got["/tf"]]
    stamps = [ts for ts, _ in got["/tf"]]
    assert stamps == sorted(stamps)
    pos = np.array([[tf.translation.x, tf.translation.y, tf.translation.z] for tf in tfs])
    quat = np.array([[tf.rotation.w, tf.rotation.x, tf.rotation.y, tf.rotation.z]
                     for tf in tfs])
    assert np.isfinite(pos).all()
    assert np.abs(np.linalg.norm(quat, axis=1) - 1.0).max() < 1e-6   # float32 ODOMETRY q
    # it moved (waited for above: a lockstep flight's pace in wall time is the machine's)
    assert np.linalg.norm(pos[-1] - pos[0]) > 0.05, pos[[0, -1]]
    ent = SceneUpdate.FromString(got["/scene/vehicle"][-1][1]).entities[0]
    assert ent.frame_id == "base_link" and len(ent.cylinders) == 4
    # flying: thrust from at least two rotors (after the attack is isolated the law may
    # command one rotor to 0 N: no arrow); the detector's rotor is labelled, not "attack"
    assert 2 <= len(ent.arrows) <= 4
    assert all(tx.text.startswith("detected: rotor ") for tx in ent.texts)
