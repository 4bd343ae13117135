"""Every script in docs/examples/ runs, as a user runs it: a fresh interpreter, short flights."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

from tfl_mav.tools.harness.processes import CLI

EXAMPLES = Path(__file__).resolve().parents[2] / "docs" / "examples"


def _run(*args: str) -> str:
    out = subprocess.run([sys.executable, *args], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    return out.stdout


def test_every_example_is_tested():
    assert sorted(p.name for p in EXAMPLES.glob("*.py")) == [
        "own_attack.py", "own_controller.py", "read_mcap.py"]


def test_own_controller_flies_towards_the_path():
    text = _run(str(EXAMPLES / "own_controller.py"), "4")
    assert "crashed: False, failed: None" in text
    end = float(re.search(r"end ([\d.]+) m after 4.0 s", text).group(1))
    assert end < 0.2                      # from 3.85 m


def test_own_attack_is_found_from_rpm():
    text = _run(str(EXAMPLES / "own_attack.py"), "3")
    assert "attack on rotor 3 from t = 1.0 s; detected: rotor 3 at t = 1.0" in text
    assert "crashed: False" in text


def test_read_mcap_reads_a_recorded_flight(tmp_path):
    demo = subprocess.run([*CLI, "demo", "--out", str(tmp_path), "--duration", "1",
                           "--no-plots"], capture_output=True, text=True, timeout=300)
    # 1 s does not reach the path: the demo's verdict fails (exit 1), its recording is whole
    assert demo.returncode in (0, 1) and (tmp_path / "ctl.mcap").exists(), demo.stderr
    text = _run(str(EXAMPLES / "read_mcap.py"), str(tmp_path / "run.mcap"))
    assert "scenario 'paper': 1001 samples, t = 0.000 .. 1.000 s" in text
    assert "position_m (1001, 3)" in text and "thrust_cmd_n (1001, 4)" in text
    assert re.search(r"detected rotor 2 at t = 0\.0\d\d s", text)
