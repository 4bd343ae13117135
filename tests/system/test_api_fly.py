"""``tfl-mav fly --controller``: a user's flight software served over MAVLink, real
processes on loopback UDP (the ``tfl-mav sim`` vehicle and the ``tfl-mav fly`` daemon)."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

from tfl_mav.api import Environment, load_object
from tfl_mav.tools.harness.processes import CLI, Proc

EXAMPLE = Path(__file__).resolve().parents[2] / "docs" / "examples" / "own_controller.py"
NO_ATTACK = ["--set", "attack.rotor=0"]

FAILING = '''
class Boom:
    def reset(self, scenario):
        self.f = scenario.vehicle.mass_kg * scenario.vehicle.gravity_mps2 / 4.0

    def update(self, t_s, state, rpm):
        if t_s >= 0.5:
            raise RuntimeError("boom\\nsecond line")
        return [self.f] * 4
'''


def test_fly_serves_a_user_controller_and_flies_what_offline_flies(sim_factory, tmp_path):
    """The example PD for 3 s in lockstep over UDP lands where the same controller lands
    offline. The difference is the wire's: ODOMETRY carries float32 (a position's last bit
    at 8 m is 5e-7 m), which a 2 rad/s position loop does not amplify beyond 1e-4 m."""
    _sim, port = sim_factory([*NO_ATTACK, "--duration", "0"])
    summary = tmp_path / "fly.json"
    fly = Proc(["fly", "paper", *NO_ATTACK, "--vehicle", f"127.0.0.1:{port}", "--duration",
                "3", "--controller", f"{EXAMPLE}:PathPD", "--summary-json", str(summary)])
    try:
        assert fly.wait(120) == 0, fly.text()
    finally:
        fly.close()
    assert f"controller {EXAMPLE}:PathPD" in fly.stderr()
    result = json.loads(summary.read_text())
    assert result["reason"] == "duration reached" and result["stats"]["ticks"] >= 3000
    assert result["stats"]["fallback_ticks"] == 0
    offline = Environment("paper", load_object(f"{EXAMPLE}:PathPD")(),
                          settings=["attack.rotor=0"]).fly(3.001)
    assert offline.t_s[-1] == 3.0
    assert abs(result["final_path_distance_m"] - offline.software_distance_m[-1]) < 1e-4
    assert 0.01 < result["final_path_distance_m"] < 1.0      # flying towards the path


def test_a_controller_that_raises_ends_the_run_with_one_line(sim_factory, tmp_path):
    (tmp_path / "boom.py").write_text(FAILING)
    _sim, port = sim_factory([*NO_ATTACK, "--duration", "0"])
    fly = Proc(["fly", "paper", *NO_ATTACK, "--vehicle", f"127.0.0.1:{port}", "--duration",
                "3", "--controller", f"{tmp_path / 'boom.py'}:Boom"])
    try:
        assert fly.wait(120) == 1, fly.text()
    finally:
        fly.close()
    last = fly.stderr().splitlines()[-1]
    assert last == (f"tfl-mav fly: {tmp_path / 'boom.py'}:Boom failed at t = 0.500 s: "
                    "raised RuntimeError: boom second line")


def test_an_unknown_controller_is_a_usage_error_in_one_line():
    out = subprocess.run([*CLI, "fly", "paper", "--vehicle", "127.0.0.1:9", "--controller",
                          "no_such_module_q:Foo"], capture_output=True, text=True, timeout=60)
    assert out.returncode == 2
    assert out.stderr.strip().splitlines() == [
        "tfl-mav fly: controller 'no_such_module_q:Foo': cannot import 'no_such_module_q' "
        "(No module named 'no_such_module_q')"]
