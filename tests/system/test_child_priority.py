"""The recorder child's CPU priority: idle in lockstep, promoted when it falls behind.

Real child processes; their policy and nice value read back from the kernel. A child that
gets no CPU at all (``SIGSTOP``) stands in for one starved by a busy machine: its pipe
fills and the flight's sends wait, exactly what a starved idle child does.
"""

from __future__ import annotations

import os
import signal
import time
from pathlib import Path

import pytest

from tfl_mav.flightlog.child_priority import NICE_INCREMENT, can_promote
from tfl_mav.flightlog.logread import raw_frames
from tfl_mav.flightlog.recorder_process import BEHIND_S, RecorderProcess

pytestmark = pytest.mark.skipif(not hasattr(os, "SCHED_IDLE"), reason="Linux scheduling")


def _threads(pid: int) -> list[int]:
    return [int(t) for t in os.listdir(f"/proc/{pid}/task")]


def _policies(pid: int) -> set[int]:
    return {os.sched_getscheduler(tid) for tid in _threads(pid)}


def _expected_nice() -> int:
    return min(19, os.getpriority(os.PRIO_PROCESS, 0) + NICE_INCREMENT)


def test_lockstep_child_is_idle_on_every_thread_and_niced(tmp_path: Path) -> None:
    with RecorderProcess(tmp_path / "a.mcap") as rec:
        pid = rec.pid
        assert len(_threads(pid)) >= 2        # the child's recorder has its flush thread
        assert os.getpriority(os.PRIO_PROCESS, pid) == _expected_nice()
        if can_promote(_expected_nice()):
            assert rec.priority.idle
            assert _policies(pid) == {os.SCHED_IDLE}
        else:                                 # it could never be promoted back: stays niced
            assert not rec.priority.idle
            assert _policies(pid) == {os.SCHED_OTHER}
    assert not rec.priority.idle              # closing promotes: the user waits for it


def test_realtime_child_is_only_niced(tmp_path: Path) -> None:
    # in real time a starved child drops records: it must never be idle
    with RecorderProcess(tmp_path / "a.mcap", realtime=True) as rec:
        pid = rec.pid
        assert not rec.priority.idle
        assert _policies(pid) == {os.SCHED_OTHER}
        assert os.getpriority(os.PRIO_PROCESS, pid) == _expected_nice()


@pytest.mark.slow
def test_a_child_that_gets_no_cpu_is_promoted_and_loses_nothing(tmp_path: Path) -> None:
    if not can_promote(_expected_nice()):
        pytest.skip("this process may not promote a SCHED_IDLE child (RLIMIT_NICE, "
                    "CAP_SYS_NICE): the child is never made idle")
    path = tmp_path / "starved.mcap"
    rec = RecorderProcess(path, batch_s=0.005)
    pid = rec.pid
    assert rec.priority.idle
    os.kill(pid, signal.SIGSTOP)
    try:
        # ~200 KB of frames: more than a pipe holds (64 KiB), less than the queue's room,
        # so the sender thread waits on the full pipe while this thread goes on
        n = 200
        for i in range(n):           # distinct frames (pickle would send one shared copy)
            rec.on_frame("rx", i.to_bytes(2, "big") * 500, None, float(i))
        t0 = time.monotonic()
        while rec.priority.idle and time.monotonic() - t0 < 30 * BEHIND_S:
            time.sleep(0.01)
        waited = time.monotonic() - t0
        assert not rec.priority.idle, "still idle after its sends waited 30x the threshold"
        assert rec.priority.promoted
        assert waited >= BEHIND_S * 0.5      # not at the first full pipe
        assert _policies(pid) == {os.SCHED_OTHER}
        assert os.getpriority(os.PRIO_PROCESS, pid) == _expected_nice()
    finally:
        os.kill(pid, signal.SIGCONT)
    rec.close()
    assert rec.error is None
    assert rec.stats.dropped == 0
    raws = [raw for _m, raw, _tx, _rejected in raw_frames(path)]
    # every frame, in order, though the child was stopped while they were sent
    assert raws == [i.to_bytes(2, "big") * 500 for i in range(n)]


def test_env_switch_keeps_a_lockstep_child_niced_only(tmp_path: Path,
                                                      monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("TFL_MAV_RECORDER_IDLE", "0")
    with RecorderProcess(tmp_path / "a.mcap") as rec:
        assert not rec.priority.idle
        assert _policies(rec.pid) == {os.SCHED_OTHER}


def test_env_switch_bad_value_warns_and_keeps_the_default(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.setenv("TFL_MAV_RECORDER_IDLE", "maybe")
    with RecorderProcess(tmp_path / "a.mcap") as rec:
        assert rec.priority.idle == can_promote(_expected_nice())
    err = capsys.readouterr().err
    assert "TFL_MAV_RECORDER_IDLE='maybe': expected 0 or 1" in err
