"""A dead peer under ``tfl-mav demo``: the vehicle or the controller SIGKILLed mid-flight.

The demo notices within seconds, stops the other (cleanly: its files are finished), says so
in one line, exits 3 (link error: a peer died) and leaves no process behind, the children's
recorders included. Real processes killed for real; ``/proc`` lists the demo's tree.
``bench/bench_peer_death.py`` measures the same over many trials and both clocks.
"""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

pytestmark = pytest.mark.slow

CLI = [sys.executable, "-m", "tfl_mav.tools.cli"]
# The demo polls every 0.1 s, stops the survivor with SIGTERM (a clean shutdown finishes
# its MCAP, ~1-3 s on a loaded machine) and waits for the recorders to finish theirs.
EXIT_LIMIT_S = 15.0


def _children(pid: int) -> list[int]:
    out = []
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                with open(f"/proc/{entry}/stat") as fh:
                    if int(fh.read().rsplit(")", 1)[1].split()[1]) == pid:
                        out.append(int(entry))
            except (OSError, ValueError, IndexError):
                continue
    return out


def _tree(pid: int) -> list[int]:
    out, todo = [], [pid]
    while todo:
        kids = _children(todo.pop())
        out += kids
        todo += kids
    return out


def _cmdline(pid: int) -> str:
    try:
        with open(f"/proc/{pid}/cmdline", "rb") as fh:
            return fh.read().replace(b"\0", b" ").decode(errors="replace")
    except OSError:
        return ""


def _alive(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as fh:
            return fh.read().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="reads /proc")
@pytest.mark.parametrize(("victim", "word"), [("sim", "the vehicle (tfl-mav sim)"),
                                              ("fly", "the controller (tfl-mav fly)")])
def test_demo_ends_with_one_line_when_a_child_dies(victim, word, tmp_path):
    out = tmp_path / "demo"
    demo = subprocess.Popen([*CLI, "demo", "paper", "--duration", "60", "--no-plots",
                             "--out", str(out)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 90
        ctl = out / "ctl.mcap"
        while not (ctl.exists() and ctl.stat().st_size > 20_000):   # the flight is on
            assert time.monotonic() < deadline and demo.poll() is None, demo.stderr.read()
            time.sleep(0.05)
        tree = _tree(demo.pid)
        target = [p for p in _children(demo.pid) if f"tfl_mav.tools.cli {victim} " in _cmdline(p)]
        assert len(target) == 1
        assert len(tree) >= 4       # sim, fly and their recorder children at least
        t_kill = time.monotonic()
        os.kill(target[0], signal.SIGKILL)
        _, err = demo.communicate(timeout=60)
        took = time.monotonic() - t_kill
    finally:
        if demo.poll() is None:
            demo.kill()
            demo.wait()
    left = [p for p in tree if _alive(p)]
    for p in left:
        os.kill(p, signal.SIGKILL)
    assert demo.returncode == 3, err
    words = [line for line in err.splitlines() if line.strip() and not line.startswith("  [")
             and not line.startswith("tfl-mav demo: warning:")]
    assert len(words) == 1, err
    assert words[0].startswith(f"tfl-mav demo: {word} ended (killed by SIGKILL)")
    assert "no flight report" in words[0] and str(out) in words[0]
    assert "Traceback" not in err
    assert took < EXIT_LIMIT_S
    assert left == [], [_cmdline(p) for p in left]


def test_a_killed_vehicle_leaves_no_recorder_traceback(tmp_path):
    """SIGKILL of ``tfl-mav sim --mcap`` mid-flight (``tfl-mav fly`` flying it), often
    mid-message to its recorder child: the child sees its parent gone, finishes the file
    and exits without a word."""
    from tfl_mav.tools.harness.processes import Proc, start_sim

    sim, port = start_sim(["--mcap", str(tmp_path / "run.mcap"), "--duration", "60"],
                          new_session=True)
    fly = Proc(["fly", "paper", "--vehicle", f"127.0.0.1:{port}", "--duration", "60",
                "--quiet"], new_session=True)
    try:
        time.sleep(4.0)                  # flying, recording
        tree = _tree(sim.pid)
        assert tree, "the sim has no recorder child"
        sim.kill()
        deadline = time.monotonic() + 10.0
        while any(_alive(p) for p in tree) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert not any(_alive(p) for p in tree), "the recorder outlived its parent by 10 s"
    finally:
        for p in (fly, sim):
            p.close()
            with contextlib.suppress(ProcessLookupError):
                os.killpg(p.pid, signal.SIGKILL)
    time.sleep(0.2)
    assert "Traceback" not in sim.stderr(), sim.stderr()


@pytest.mark.parametrize("victim", ["fly", "sim"])
def test_standalone_peer_timeout_ends_the_survivor_with_exit_3(victim):
    """``--peer-timeout 2`` (lockstep): the survivor of a SIGKILLed peer ends 2 s later
    (plus a poll), with exit 3 and a line that says why."""
    from tfl_mav.tools.harness.processes import Proc, start_sim

    sim, port = start_sim(["--gcs", "none", "--duration", "60", "--peer-timeout", "2"],
                          new_session=True)
    fly = Proc(["fly", "paper", "--vehicle", f"127.0.0.1:{port}", "--duration", "60",
                "--peer-timeout", "2"], new_session=True)
    dead, survivor = (fly, sim) if victim == "fly" else (sim, fly)
    try:
        sim.wait_for(r"connected: flight starts", 60)
        time.sleep(1.0)
        t_kill = dead.kill()
        code = survivor.wait(20)
        took = time.monotonic() - t_kill
    finally:
        for p in (fly, sim):
            p.close()
            with contextlib.suppress(ProcessLookupError):
                os.killpg(p.pid, signal.SIGKILL)
    assert code == 3, survivor.text()
    assert 2.0 <= took < 2.0 + 5.0        # the timeout, then a clean stop on a busy machine
    said = ("the controller went silent: no HIL_ACTUATOR_CONTROLS for" if victim == "fly"
            else "vehicle silent for 2 s (gone)")
    assert said in survivor.text()
    assert "Traceback" not in survivor.text()
