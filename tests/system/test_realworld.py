"""The real world through the command line and the API: a scenario file with wind and an
attacker that moves between rotors; seeded wind replays the same flight."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from tfl_mav.harness.offline import fly_offline
from tfl_mav.scenario import load_scenario

SCHEDULE = """
name = "moving-attacker"
[attack]
value_n = 1.5
[[attack.phases]]
rotor = 2
signal = "constant"
start_s = 1.0
[[attack.phases]]
rotor = 0
start_s = 3.0
[[attack.phases]]
rotor = 3
signal = "constant"
start_s = 4.0
[wind]
mean_mps = [2.0, 0.0, 0.0]
turbulence = "light"
[run]
duration_s = 6.0
"""


@pytest.mark.slow
def test_cli_flies_a_moving_attacker_in_wind_and_reports_each_move(tmp_path):
    path = tmp_path / "moving.toml"
    path.write_text(SCHEDULE)
    out = subprocess.run([sys.executable, "-m", "tfl_mav.cli", "offline", str(path),
                          "--attack-info", "detector"],
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    lines = [line.split("s  ", 1)[1] for line in out.stdout.splitlines() if "t = " in line]
    said = [t for t in lines if t.startswith(("attacker", "attack detected", "rotor obeys"))]
    assert said == ["attacker seizes rotor 2", "attack detected on rotor 2",
                    "attacker lets go",
                    "rotor obeys its commands again: attack over, four-rotor law",
                    "attacker seizes rotor 3", "attack detected on rotor 3"]


def test_seeded_wind_replays_the_flight_bit_for_bit():
    sc = load_scenario("paper").replace(**{"wind.mean_mps": [3.0, 0.0, 0.0],
                                           "wind.turbulence": "moderate",
                                           "run.duration_s": 1.5})
    a, b = fly_offline(sc), fly_offline(sc)
    for key in ("position_m", "quaternion_wxyz", "thrust_cmd_n", "wind_mps"):
        assert a[key].tobytes() == b[key].tobytes()
    c = fly_offline(sc.replace(**{"run.seed": 1}))
    assert not np.array_equal(a["wind_mps"], c["wind_mps"])
    assert a["wind_mps"].shape == (len(a["t_s"]), 3)
