"""What a user sees of a recorded flight: ``report`` and ``inspect`` output, exit codes.

One real lockstep flight (``tfl-mav demo``: ``sim`` and ``fly`` subprocesses over loopback
UDP, both recording MCAP) is shared by the module; every check runs the real command on
its files.
"""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import pytest

from harness.processes import CLI

pytestmark = pytest.mark.slow
DURATION_S = 1.0


@pytest.fixture(scope="module")
def flight(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("flight")
    done = subprocess.run([*CLI, "demo", "paper", "--duration", str(DURATION_S), "--out",
                           str(out), "--no-plots", "--json"], capture_output=True, text=True,
                          timeout=300)
    assert done.returncode == 1, done.stderr      # 1 s is too short to converge
    return out


def _cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([*CLI, *args], capture_output=True, text=True, timeout=120)


def test_report_writes_its_summary_and_names_the_directory_once(flight: Path,
                                                                tmp_path: Path) -> None:
    rep = tmp_path / "rep"
    done = _cli("report", str(flight / "run.mcap"), "--out", f"{rep}/")
    assert done.returncode == 0, done.stderr
    assert f"in {rep}/ " in done.stdout and "//" not in done.stdout, done.stdout
    summary = json.loads((rep / "summary.json").read_text())
    assert summary["sim_time_s"] == pytest.approx(DURATION_S, abs=0.002)
    assert sorted(Path(p).name for p in summary["plots"]) == sorted(
        p.name for p in rep.glob("*.png")) and len(summary["plots"]) == 6


def test_report_of_a_controller_log_is_a_usage_error_not_a_failed_flight(
        flight: Path, tmp_path: Path) -> None:
    done = _cli("report", str(flight / "ctl.mcap"), "--out", str(tmp_path / "rep"))
    assert done.returncode == 2, done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and "vehicle's log" in lines[0], lines
