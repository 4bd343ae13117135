"""Data that must not be lost: a log cut short by a kill or a full disk is made readable by
the standard ``mcap`` reader, the run says where it ends, and no one summarises it as a
whole flight; summaries are written whole or not at all; reading a flight back streams.

Every file here is a real MCAP file written by the recorder and read back with
``mcap.reader.make_reader(...).iter_messages()`` (the reader a user's tool uses); kills are
real SIGKILLs, the full disk a real tmpfs (root only) or the kernel's file-size limit.
"""

from __future__ import annotations

import json
import math
import os
import shutil
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest
from mcap.exceptions import McapError
from mcap.reader import make_reader

from tfl_mav.controller.daemon import TICK_FIELDS, TICK_SCHEMA
from tfl_mav.flightlog.flight import SERIES, summarize
from tfl_mav.flightlog.from_mcap import flight_log_from_mcap, log_metadata
from tfl_mav.flightlog.logread import LogReader
from tfl_mav.flightlog.mcaprepair import cut_short, read_back, repair
from tfl_mav.flightlog.metrics import flight_verdict
from tfl_mav.flightlog.recorder import Recorder
from tfl_mav.scenario import load_scenario
from tfl_mav.tools.harness.processes import LISTEN_RE, Proc

REPO = Path(__file__).resolve().parents[2]


def _messages(path: Path) -> list[tuple[str, int, bytes]]:
    """(topic, log time, data) of every message, through make_reader, in file order."""
    with open(path, "rb") as f:
        return [(ch.topic, m.log_time, m.data) for _, ch, m in
                make_reader(f, validate_crcs=True).iter_messages(log_time_order=False)]


def _record(rec: Recorder, k: int, *, t_s: float | None = None, x: float = 0.0) -> None:
    """One tick of a flight: the truth and the controller's record (the daemon's fields)."""
    t = k * 1e-3 if t_s is None else t_s
    rec.set_sim_time(t)
    rec.truth(t, [x, 0.1 * t, 5.0], [0.0, 0.1, 0.0], [1.0, 0.0, 0.0, 0.0],
              [0.0, 0.0, 0.01 * k], [2.7, 2.8, 2.7, 2.8], 2 if t >= 0.5 else 0,
              1.0 if t >= 0.5 else 0.0, 1.0 if t >= 0.5 else 0.0)
    rec.controller(t, {"mode": "attacked" if t >= 0.6 else "nominal",
                       "detected_rotor": 2 if t >= 0.6 else 0,
                       "attack_estimate_n": 1.0 if t >= 0.6 else math.nan,
                       "path_distance_m": 0.01, "saturated": k % 7 == 0,
                       "rotor_thrust_cmd_n": [2.7, 2.8, 2.7, 2.8 + 1e-3 * (k % 5)]})


def _write_flight(path: Path, ticks: int, **kw) -> None:
    clock = [1.7e9]

    def now() -> float:
        clock[0] += 1e-3
        return clock[0]

    with Recorder(path, clock=now, timeline="sim", chunk_size_bytes=32 * 1024,
                  controller_fields=TICK_FIELDS, controller_schema=TICK_SCHEMA, **kw) as rec:
        rec.metadata("scenario", {"name": "paper", "role": "vehicle"})
        for k in range(ticks):
            _record(rec, k)


# ------------------------------------------------------------------ repair, any cut
def test_repair_makes_any_cut_of_a_log_readable_by_the_mcap_reader(tmp_path):
    """A killed writer leaves a prefix of its file: cut one at 40 places (inside chunks,
    headers, message indexes, the summary), repair each, read it back with make_reader."""
    whole = tmp_path / "whole.mcap"
    _write_flight(whole, 3000)
    full = _messages(whole)
    data = whole.read_bytes()
    cuts = sorted({int(len(data) * i / 40) for i in range(1, 40)} | {len(data) - 30})
    kept_before = 0
    for at in cuts:
        cut = tmp_path / "cut.mcap"
        cut.write_bytes(data[:at])
        with open(cut, "rb") as f, pytest.raises((McapError, Exception)):
            list(make_reader(f).iter_messages())        # no footer: the reader refuses
        rep = repair(cut, "test cut")
        assert rep.readable and rep.repaired, rep
        got = _messages(cut)
        assert len(got) == rep.messages
        # what reads is exactly the messages written before the cut, in order
        assert [g[2] for g in got] == [f[2] for f in full[:len(got)]]
        assert len(got) >= kept_before      # a later cut never keeps less
        kept_before = len(got)
        md = cut_short(log_metadata(cut))
        assert md is not None and md["reason"] == "test cut"
        again = repair(cut)                 # idempotent: a finished file is left alone
        assert again.readable and not again.repaired and again.messages == rep.messages
    assert kept_before > 0.9 * len(full)


def test_repair_of_a_whole_file_changes_nothing(tmp_path):
    whole = tmp_path / "whole.mcap"
    _write_flight(whole, 500)
    before = whole.read_bytes()
    rep = repair(whole)
    assert rep.readable and not rep.repaired
    assert whole.read_bytes() == before
    assert cut_short(log_metadata(whole)) is None


# ------------------------------------------------------------------ reading streams
def _whole_read(run: Path, sc, ctl: Path):
    """The flight read the old way: every truth record decoded into memory first."""
    from tfl_mav.flightlog import from_mcap as fm

    truth, texts = {}, []
    for m in LogReader(run).messages(fm.TRUTH_TOPICS | {"/log"}):
        if m.topic == "/log":
            texts.append(fm.log_texts(m.data))
        else:
            fm.add_truth(truth, m.topic, m.decode())
    return flight_log_from_mcap(run, sc, ctl, truth=truth, texts=texts)


def test_streamed_flight_is_the_whole_read_flight_to_the_bit(tmp_path):
    sc = load_scenario("paper")
    run, ctl = tmp_path / "run.mcap", tmp_path / "ctl.mcap"
    clock = [1.7e9]

    def now() -> float:
        clock[0] += 1e-3
        return clock[0]

    with Recorder(run, clock=now, timeline="sim") as r, \
            Recorder(ctl, clock=now, timeline="sim", controller_fields=TICK_FIELDS,
                     controller_schema=TICK_SCHEMA) as c:
        for k in range(1500):
            _record(r, k, x=math.nan if k == 700 else 0.0)     # a diverged sample
            _record(c, k)
            if k == 900:
                _record(r, k, x=0.5)        # the same tick again: the last one counts
            if k % 3 == 0 and k > 1000:
                continue                    # ticks the controller did not record
    a = flight_log_from_mcap(run, sc, ctl)
    b = _whole_read(run, sc, ctl)
    assert len(a["t_s"]) == 1499
    for key in SERIES:
        assert a[key].shape == b[key].shape and a[key].tobytes() == b[key].tobytes(), key
    assert np.array_equal(a.detected_rotor, b.detected_rotor)
    assert json.dumps(summarize(a), sort_keys=True) == json.dumps(summarize(b),
                                                                  sort_keys=True)


# ------------------------------------------------------------------ write errors
_FULL_CHILD = textwrap.dedent("""
    import json, math, resource, signal, sys
    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
    resource.setrlimit(resource.RLIMIT_FSIZE, ({limit}, {limit}))
    from tfl_mav.flightlog.recorder import Recorder
    from tfl_mav.flightlog.atomic import write_text_atomic
    rec = Recorder({path!r}, timeline="sim", chunk_size_bytes=8192)
    for k in range(20000):
        t = k * 1e-3
        rec.set_sim_time(t)
        rec.truth(t, [0.0, 0.0, t], [0.0] * 3, [1.0, 0.0, 0.0, 0.0], [0.0] * 3,
                  [2.0] * 4, 0, 0.0, 0.0)
    rec.close()
    try:
        write_text_atomic({summary!r}, "x" * (2 * {limit}))
        wrote = None
    except OSError as exc:
        wrote = exc.strerror
    print(json.dumps({{"error": rec.error, "repair": rec.repair, "summary_error": wrote}}))
""")


def test_a_write_error_keeps_what_was_written_readable_and_summaries_whole(tmp_path):
    """The kernel's file-size limit (EFBIG, RLIMIT_FSIZE) fails the writes as a full disk
    does: the recording stops, what it wrote is repaired and reads; a summary that does not
    fit leaves the old file as it was (no 0-byte file, no temporary left)."""
    path, summary = tmp_path / "full.mcap", tmp_path / "summary.json"
    summary.write_text('{"old": true}')
    limit = 200 * 1024
    code = _FULL_CHILD.format(limit=limit, path=str(path), summary=str(summary))
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=120, cwd=REPO)
    assert out.returncode == 0, out.stderr
    assert "os error" not in out.stderr          # no raw writer error string
    result = json.loads(out.stdout.splitlines()[-1])
    assert "File too large" in result["error"] and "repaired" in result["error"]
    assert result["repair"]["readable"] and result["repair"]["messages"] > 100
    assert path.stat().st_size <= limit
    n, err = read_back(path)
    assert err is None and n == result["repair"]["messages"]
    assert result["summary_error"] == "File too large"
    assert json.loads(summary.read_text()) == {"old": True}
    assert sorted(p.name for p in tmp_path.iterdir()) == ["full.mcap", "summary.json"]


# ------------------------------------------------------------------ a killed recorder
@pytest.mark.slow
def test_a_killed_recorder_child_is_said_at_once_and_its_file_repaired(tmp_path):
    from tfl_mav.flightlog.recorder_process import RecorderProcess

    path = tmp_path / "run.mcap"
    said: list[tuple[float, str]] = []
    rec = RecorderProcess(path, timeline="sim", say=lambda s: said.append((time.monotonic(), s)))
    k = 0
    t0 = time.monotonic()
    while time.monotonic() - t0 < 2.0:      # ~4x real time, as a lockstep flight runs
        for _ in range(8):
            rec.truth(k * 1e-3, [0.0, 0.0, 5.0], [0.0] * 3, [1.0, 0.0, 0.0, 0.0],
                      [0.0] * 3, [2.7] * 4, 0, 0.0, 0.0)
            k += 1
        time.sleep(0.002)
    t_kill, sim_at_kill = time.monotonic(), k * 1e-3
    os.kill(rec.pid, signal.SIGKILL)
    while time.monotonic() - t_kill < 1.5:  # the flight goes on
        rec.truth(k * 1e-3, [0.0, 0.0, 5.0], [0.0] * 3, [1.0, 0.0, 0.0, 0.0], [0.0] * 3,
                  [2.7] * 4, 0, 0.0, 0.0)
        k += 1
        time.sleep(0.0005)
    rec.close()
    assert said and "recording cut short" in said[0][1] and "SIGKILL" in said[0][1]
    assert said[0][0] - t_kill < 1.0, "said at once, not at exit"
    r = rec.recording
    assert r["complete"] is False and r["readable"] is True
    last = r["last_sim_time_s"]
    # lost: at most the last flush interval (0.5 s of sim time, or 1 s of wall time)
    assert sim_at_kill - 1.0 <= last <= sim_at_kill
    assert any("repaired" in s for _, s in said)
    n, err = read_back(path)
    assert err is None and n == r["repair"]["messages"]
    assert cut_short(log_metadata(path))["reason"].startswith("recorder process died")


# ------------------------------------------------------------------ sim + fly
def _pair(tmp_path: Path, duration_s: float, run: Path, ctl: Path, fly_json: Path,
          sim_extra: tuple[str, ...] = ()) -> tuple[Proc, Proc]:
    common = ["--duration", f"{duration_s:g}"]
    sim = Proc(["sim", "paper", "--listen", "127.0.0.1:0", "--gcs", "none", "--legacy-ports",
                "--mcap", str(run), *sim_extra, *common], new_session=True)
    _, m = sim.wait_for(LISTEN_RE.pattern, 60.0)
    fly = Proc(["fly", "paper", "--vehicle", f"127.0.0.1:{m.group(2)}", "--mcap", str(ctl),
                "--summary-json", str(fly_json), "--progress", *common], new_session=True)
    return sim, fly


def _recorder_child(pid: int) -> int:
    for child in Path(f"/proc/{pid}/task/{pid}/children").read_text().split():
        if b"spawn_main" in Path(f"/proc/{child}/cmdline").read_bytes() and \
                b"resource_tracker" not in Path(f"/proc/{child}/cmdline").read_bytes():
            return int(child)
    raise AssertionError("no recorder child")


@pytest.mark.slow
def test_a_flight_whose_vehicle_log_was_cut_is_not_judged_whole(tmp_path):
    """The vehicle's recorder dies 1.5 s into a 5 s flight: the sim says so during the
    flight and in --json, run.mcap reads with make_reader, and the flight read back from
    it is not judged (converged or not) as if it were the whole flight."""
    run, ctl, fly_json, sim_json = (tmp_path / n for n in ("run.mcap", "ctl.mcap", "fly.json",
                                                            "sim.json"))
    sim, fly = _pair(tmp_path, 5.0, run, ctl, fly_json, ("--json", str(sim_json)))
    try:
        fly.wait_for(r"^progress 1\.", 60.0)
        t_kill = time.monotonic()
        os.kill(_recorder_child(sim.pid), signal.SIGKILL)
        t_said, _ = sim.wait_for("recording cut short", 10.0)
        assert t_said - t_kill < 1.0
        assert fly.wait(120) == 0 and sim.wait(120) == 0
    finally:
        sim.close()
        fly.close()
    said = [ln for ln in sim.stderr().splitlines() if "recording cut short" in ln]
    assert len(said) == 1 and "Traceback" not in sim.stderr()
    rec = json.loads(sim_json.read_text())["recording"]
    assert rec["complete"] is False and rec["readable"] is True
    assert 0.5 <= rec["last_sim_time_s"] < 4.0
    n, err = read_back(run)
    assert err is None and n > 1000
    sc = load_scenario("paper")
    log = flight_log_from_mcap(run, sc, ctl)
    log.duration_s = 5.0
    assert log.log_cut and log.log_cut[0]["file"] == "run.mcap"
    assert log.log_cut[0]["at_s"] == pytest.approx(rec["last_sim_time_s"], abs=2e-3)
    verdict = flight_verdict(log)
    assert verdict["converged"] is False
    assert verdict["convergence"].startswith("not judged: the vehicle's log run.mcap was cut")
    assert verdict["log_cut_short"][0]["role"] == "vehicle"


def _mount_tmpfs(where: Path, size: str) -> bool:
    where.mkdir()
    if shutil.which("mount") is None or os.geteuid() != 0:
        return False
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(where)],
                       capture_output=True)
    return r.returncode == 0


@pytest.mark.slow
def test_fly_on_a_full_disk_exits_3_with_one_line_and_keeps_what_it_wrote(tmp_path):
    """A real full disk (a 2 MiB tmpfs). First ctl.mcap fills it: the recording stops, the
    flight goes on, the file is repaired and reads with make_reader, fly exits 3 (link or
    file error, as --help says) with one line on it. Then the disk is full before the
    flight and only --summary-json goes there: exit 3, one line, no 0-byte JSON, no
    temporary file left. Never a traceback or the writer's raw error text."""
    disk = tmp_path / "disk"
    if not _mount_tmpfs(disk, "2m"):
        pytest.skip("needs root to mount a tmpfs")
    try:
        run, ctl, fly_json = tmp_path / "run.mcap", disk / "ctl.mcap", disk / "fly.json"
        sim, fly = _pair(tmp_path, 8.0, run, ctl, fly_json)
        try:
            code = fly.wait(120)
            sim.wait(120)
        finally:
            sim.close()
            fly.close()
        err = fly.stderr()
        assert code == 3, err[-2000:]
        assert "Traceback" not in err and "os error" not in err
        last = err.splitlines()[-1]
        assert last.startswith(("tfl-mav fly: --mcap", "tfl-mav fly: --summary-json")), last
        n, read_error = read_back(ctl)
        assert read_error is None and n > 1000
        assert cut_short(log_metadata(ctl))["reason"].startswith("writing failed")
        if fly_json.exists():       # written (the repair freed room): whole, and says so
            rec = json.loads(fly_json.read_text())["recording"]
            assert rec["write_error"] and rec["readable"] and not rec["complete"]

        for f in disk.iterdir():
            f.unlink()
        filler = disk / "filler"
        with open(filler, "wb") as fh, pytest.raises(OSError):
            while True:             # the disk full to the last byte
                fh.write(b"\0" * 65536)
                fh.flush()
        sim, fly = _pair(tmp_path, 2.0, tmp_path / "run2.mcap", tmp_path / "ctl2.mcap",
                         fly_json)
        try:
            code = fly.wait(120)
            sim.wait(120)
        finally:
            sim.close()
            fly.close()
        err = fly.stderr()
        assert code == 3, err[-2000:]
        assert "Traceback" not in err
        last = err.splitlines()[-1]
        assert last.startswith("tfl-mav fly: --summary-json") and "No space left" in last
        assert sorted(p.name for p in disk.iterdir()) == ["filler"]   # no JSON, no temp
    finally:
        subprocess.run(["umount", str(disk)], check=False)


_DIES_STARTING = textwrap.dedent("""
    import os, threading, time
    from tfl_mav.flightlog.recorder_process import RecorderProcess

    if __name__ == "__main__":
        threading.Timer(0.05, lambda: os._exit(0)).start()   # gone while the child starts
        RecorderProcess({path!r}, timeline="sim")
        time.sleep(60)
""")


@pytest.mark.slow
def test_a_flight_process_killed_while_its_recorder_starts_leaves_no_traceback(tmp_path):
    path = tmp_path / "run.mcap"
    script = tmp_path / "parent.py"
    script.write_text(_DIES_STARTING.format(path=str(path)))
    with open(tmp_path / "stderr", "w") as err:
        subprocess.run([sys.executable, str(script)], stderr=err, timeout=60, cwd=REPO)
    deadline = time.monotonic() + 30.0
    while read_back(path)[1] is not None:       # the orphaned child finishes the file
        assert time.monotonic() < deadline, read_back(path)
        time.sleep(0.1)
    time.sleep(0.5)                             # and exits, having said all it says
    assert "Traceback" not in (tmp_path / "stderr").read_text()
    assert cut_short(log_metadata(path))["reason"].startswith("the flight process ended")
