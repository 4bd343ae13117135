"""``tfl-mav inspect`` and ``tfl-mav replay`` on recorded files (real files, real UDP)."""

from __future__ import annotations

import json
import math
import socket
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from tfl_mav.flightlog.logread import raw_frames
from tfl_mav.flightlog.recorder import Recorder
from tfl_mav.link.dialect import mav, new_mavlink
from tfl_mav.tools.cli.main import main as cli_main

RADIUS_M, HEIGHT_M = 2.0, 1.0
DT_S = 0.005
DURATION_S = 12.0
ATTACK_START_S, DETECT_S = 4.0, 4.015
E0_M, DECAY_S = 0.5, 2.0


def _offset_m(t: float) -> float:
    """Radial distance of the synthetic flight from its circular path."""
    return E0_M * math.exp(-t / DECAY_S)


class _Clock:
    """Log-time clock advancing with the synthetic flight (one clock for the file)."""

    def __init__(self) -> None:
        self.t = 1_700_000_000.0

    def __call__(self) -> float:
        return self.t


@pytest.fixture(scope="module")
def flight_file(tmp_path_factory) -> Path:
    """A synthetic flight: circle path, known distance, attack on rotor 2 at 4 s detected
    at 4.015 s, one early false alarm at 1 s, every 10th command saturated."""
    path = tmp_path_factory.mktemp("inspect") / "run.mcap"
    clock = _Clock()
    packer = new_mavlink(2, 1)
    s = np.linspace(0.0, 2.0 * math.pi, 721)
    with Recorder(path, clock=clock, rotor_xy_m=((0.25, 0.0), (0.0, -0.25), (-0.25, 0.0),
                                                  (0.0, 0.25)), thrust_max_n=8.0) as rec:
        rec.path(np.c_[RADIUS_M * np.cos(s), RADIUS_M * np.sin(s), np.full_like(s, HEIGHT_M)])
        n = round(DURATION_S / DT_S)
        for k in range(n + 1):
            t = k * DT_S
            clock.t = 1_700_000_000.0 + t
            r = RADIUS_M + _offset_m(t)
            a = 0.3 * t
            attacked = t >= ATTACK_START_S
            rec.truth(t, [r * math.cos(a), r * math.sin(a), HEIGHT_M], [0.0, 0.6, 0.0],
                      [1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [2.7, 1.0 if attacked else 2.7,
                                                              2.7, 2.7],
                      2 if attacked else 0, 1.0 if attacked else 0.0, 1.0)
            detected = 2 if t >= DETECT_S - 1e-9 else (3 if 1.0 <= t < 1.1 else 0)
            rec.controller(t, {"mode": "attacked" if detected == 2 else "nominal",
                               "detected_rotor": detected, "saturated": k % 10 == 0})
            hil = mav.MAVLink_hil_actuator_controls_message(
                round(t * 1e6), [1.0 if k % 10 == 0 else 0.4, 0.4, 0.4, 0.4] + [0.0] * 12,
                128, 1)
            raw = hil.pack(packer)
            packer.seq = (packer.seq + 1) & 0xFF
            rec.on_frame("tx", bytes(raw), hil, clock.t)
    return path


def _inspect_json(path: Path, capsys) -> dict:
    assert cli_main(["inspect", str(path), "--json"]) == 0
    return json.loads(capsys.readouterr().out)


def test_inspect_json_reports_channels_and_the_flight(flight_file, capsys):
    rep = _inspect_json(flight_file, capsys)
    n = round(DURATION_S / DT_S) + 1
    assert rep["complete"] and rep["read_error"] is None
    ch = rep["channels"]
    for topic in ("/sim/truth/state", "/controller/state", "/mavlink/raw"):
        assert ch[topic]["count"] == n, topic
        assert ch[topic]["sim_rate_hz"] == pytest.approx(1.0 / DT_S, rel=1e-6), topic
        assert ch[topic]["rate_hz"] == pytest.approx(1.0 / DT_S, rel=1e-6), topic
    # a decoded MAVLink channel: at most 50 Hz of sim time (every frame is raw)
    hil = ch["/mavlink/2/1/HIL_ACTUATOR_CONTROLS"]
    assert hil["count"] == round(DURATION_S * 50) + 1
    assert hil["sim_rate_hz"] == pytest.approx(50.0, rel=1e-6)
    assert ch["/tf"]["schema"] == "foxglove.FrameTransform"
    assert ch["/scene/vehicle"]["schema"] == "foxglove.SceneUpdate"
    assert ch["/tf"]["sim_rate_hz"] == pytest.approx(50.0, rel=1e-6)
    assert rep["frames"] == {"rx": 0, "tx": n, "rx_rejected": 0}
    assert rep["sim_time_span_s"] == pytest.approx(DURATION_S, abs=1e-9)
    f = rep["flight"]
    assert f["path_distance_source"].startswith("truth position")
    # polyline of 720 chords on r = 2 m: sag r(1 - cos(pi/720)) = 19 µm
    assert f["final_path_distance_m"] == pytest.approx(_offset_m(DURATION_S), abs=1e-4)
    assert f["max_path_distance_m"] == pytest.approx(E0_M, abs=1e-4)
    last = np.arange(DURATION_S - 10.0, DURATION_S + DT_S / 2, DT_S)
    rms = math.sqrt(float(np.mean([_offset_m(t) ** 2 for t in last])))
    assert f["rms_path_distance_last_10s_m"] == pytest.approx(rms, abs=1e-4)
    assert f["attack_rotor"] == 2 and f["attack_start_s"] == pytest.approx(ATTACK_START_S)
    assert f["detected_rotor"] == 2 and f["detection_correct"] is True
    assert f["detection_latency_s"] == pytest.approx(DETECT_S - ATTACK_START_S, abs=1e-9)
    assert f["false_alarms"] == 1
    assert f["saturated_fraction"] == pytest.approx(1 / 10, abs=1 / n)
    assert f["thrust_true_min_n"] == 1.0 and f["thrust_true_max_n"] == 2.7


def test_inspect_reads_a_truncated_file_and_recover_makes_it_whole(flight_file, tmp_path,
                                                                   capsys):
    cut = tmp_path / "cut.mcap"
    data = flight_file.read_bytes()
    cut.write_bytes(data[: len(data) * 2 // 3])
    rep = _inspect_json(cut, capsys)
    assert not rep["complete"] and rep["read_error"]
    assert rep["messages"] > 0
    fixed = tmp_path / "fixed.mcap"
    assert cli_main(["inspect", str(cut), "--recover", str(fixed), "--json"]) == 0
    rep_cut = json.loads(capsys.readouterr().out)
    rep_fixed = _inspect_json(fixed, capsys)
    assert rep_fixed["complete"] and rep_fixed["messages"] == rep_cut["messages"]
    assert cli_main(["inspect", str(cut), "--recover", str(cut)]) == 2   # not onto itself


def _recorded_frames(path: Path) -> list[tuple[str, bytes, int]]:
    return [("tx" if tx else "rx", raw, m.log_time_ns)
            for m, raw, tx, _rejected in raw_frames(path)]


class _Sink:
    """A UDP socket draining into a list from its own thread while a replay runs."""

    def __init__(self) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        # Room for a whole replay (2 401 datagrams, ~1 KiB of kernel memory each): this
        # thread shares the GIL with the replay it drains, and on a loaded machine the
        # default ~208 KiB overflowed (frames lost at ~1 000), which is the test's fault.
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 22)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(0.05)
        self.port = self.sock.getsockname()[1]
        self.got: list[bytes] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                data = self.sock.recv(65535)
            except TimeoutError:
                continue
            self.got.append(data)   # self.got read after recv: take() may swap it

    def take(self, n: int, timeout_s: float = 10.0) -> list[bytes]:
        """Wait for ``n`` datagrams (or the timeout) and return all received so far. They
        were sent before this is called and sit in the socket's 4 MiB queue; only our
        reader thread's turn is awaited, which a loaded machine can delay by far more than
        the 1 s this allowed before; a lost datagram still fails (after the timeout)."""
        deadline = time.monotonic() + timeout_s
        while len(self.got) < n and time.monotonic() < deadline:
            time.sleep(0.01)
        out, self.got = self.got, []
        return out

    def close(self) -> None:
        self._stop.set()
        self._thread.join()
        self.sock.close()


@pytest.mark.slow
def test_replay_sends_the_recorded_bytes(flight_file, tmp_path, capsys):
    # a file with both directions and a rejected frame
    path = tmp_path / "mixed.mcap"
    packer = new_mavlink(1, 1)
    frames = [bytes(mav.MAVLink_heartbeat_message(2, 3, 0, 0, 4, 3).pack(packer)),
              b"\x00garbage",
              bytes(mav.MAVLink_statustext_message(6, b"hello").pack(packer))]
    with Recorder(path) as rec:
        rec.on_frame("tx", frames[0], object(), 10.0)
        rec.on_frame("rx", frames[1], None, 10.01)
        rec.on_frame("rx", frames[2], object(), 10.02)
    sink = _Sink()
    to = f"127.0.0.1:{sink.port}"
    try:
        assert cli_main(["replay", str(path), "--to", to, "--speed", "0"]) == 0
        assert sink.take(3) == frames
        assert "sent 3 frames" in capsys.readouterr().out
        assert cli_main(["replay", str(path), "--to", to, "--speed", "0", "--direction", "rx",
                         "--accepted-only"]) == 0
        assert sink.take(1) == [frames[2]]
        capsys.readouterr()
        # the flight file, tx only, at 20x: 2401 frames over 12 s of log time -> 0.6 s
        recorded = [raw for d, raw, _ in _recorded_frames(flight_file) if d == "tx"]
        t0 = time.perf_counter()
        assert cli_main(["replay", str(flight_file), "--to", to, "--speed", "20",
                         "--direction", "tx"]) == 0
        elapsed = time.perf_counter() - t0
        got = sink.take(len(recorded))
    finally:
        sink.close()
    assert got == recorded
    assert DURATION_S / 20 <= elapsed <= DURATION_S / 20 + 0.5
    assert f"sent {len(recorded)} frames" in capsys.readouterr().out


def test_tools_refuse_a_file_that_is_not_mcap(tmp_path, capsys):
    junk = tmp_path / "junk.mcap"
    junk.write_text("not an mcap file\n")
    assert cli_main(["inspect", str(junk)]) == 3
    assert cli_main(["replay", str(junk), "--to", "127.0.0.1:9"]) == 3
    assert capsys.readouterr().err.count("not a readable MCAP file") == 2


def test_replay_rejects_bad_arguments(flight_file, capsys):
    assert cli_main(["replay", str(flight_file), "--to", "localhost"]) == 2
    assert cli_main(["replay", str(flight_file), "--to", "127.0.0.1:9", "--speed", "-1"]) == 2
    assert cli_main(["replay", "/no/such.mcap", "--to", "127.0.0.1:9"]) == 3
    err = capsys.readouterr().err
    assert "--to" in err and "--speed" in err and "/no/such.mcap" in err
