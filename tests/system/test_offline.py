"""Closed-loop flights of the TFL law on the sitl physics (one claim a test).

Every flight is the real controller sampled at 1 kHz (zero-order hold) on the real plant;
the runner tells the controller which rotor is attacked and its thrust measured from rpm
(the paper's assumption). The bounds are the issue's requirements, not tuned numbers; the
measured values are in bench/bench_offline.py's table (well inside these bounds).
"""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from tfl_mav.flightlog.flight import summarize
from tfl_mav.offline import fly_offline
from tfl_mav.scenario import load_scenario

NOISE = {"sensors.velocity_noise_std_mps": 0.01, "sensors.rate_noise_std_radps": 0.005}


def _fly(name: str, **overrides):
    log = fly_offline(load_scenario(name).replace(**overrides))
    return log, summarize(log)


@pytest.mark.slow
def test_exact_model_converges_below_1mm_within_the_thrust_limits():
    """The paper's A is ≈ 0 twice in the first 15 s (the dead-rotor stretch, flown by the
    reduced-attitude law); after the last hand-back (~14.6 s) the TFL chains settle with
    poles at −2.5/−4 s⁻¹, so 10 s later the error is far below 1 mm. The applied commands
    stay in [0, f_max] (the requests may leave it while a rotor is dead: logged honestly)."""
    log, m = _fly("paper-exact", **{"controller.law": "robust"})
    assert not m["crashed"]
    late = log["t_s"] >= 25.0
    assert np.max(log["path_distance_m"][late]) < 1e-3
    cmd = log["thrust_cmd_n"]
    assert np.min(cmd) >= 0.0 and np.max(cmd) <= 8.0


@pytest.mark.parametrize("mass_scale", [0.98, 1.02])
@pytest.mark.parametrize("inertia_scale", [0.9, 1.1])
@pytest.mark.slow
def test_model_error_corners_with_noise_stay_within_5mm(mass_scale, inertia_scale):
    """Past the paper: ±2 % mass × ±10 % inertia, sensor noise, 1 kHz sampled control."""
    _, m = _fly("paper", **{"controller.model_mass_scale": mass_scale,
                            "controller.model_inertia_scale": inertia_scale, **NOISE})
    assert not m["crashed"], m["crash_reason"]
    assert m["max_path_distance_last_10s_m"] < 5e-3


@pytest.mark.parametrize("rotor", [1, 3, 4])
@pytest.mark.slow
def test_attack_on_any_rotor_converges(rotor):
    _, m = _fly("paper", **{"attack.rotor": rotor, "run.duration_s": 20.0})
    assert not m["crashed"], m["crash_reason"]
    assert m["final_path_distance_m"] < 5e-3
    assert m["fallback_fraction"] == 0.0


@pytest.mark.parametrize("name", ["circle", "helix", "figure8"])
@pytest.mark.slow
def test_other_paths_converge_under_attack(name):
    log, m = _fly(name, **{"run.duration_s": 20.0})
    assert not m["crashed"], m["crash_reason"]
    assert m["final_path_distance_m"] < 5e-3
    assert np.nanmax(log["attack_true_n"]) > 0.0   # the attack really was on


def test_baseline_that_ignores_the_attack_crashes():
    # the law alone (no supervisor to take over from it): the paper's point
    _, m = _fly("paper", **{"controller.aware_of_attack": False, "run.duration_s": 5.0,
                            "controller.supervisor": "tfl"})
    assert m["crashed"]


@pytest.mark.slow
def test_plain_paper_law_is_still_flyable_and_worse():
    """The paper's law without the robust add-ons survives the 2 %/10 % model error but
    sits centimetres off the path (the controller issue's prototype saw 6–7 cm)."""
    _, m = _fly("paper", **{"controller.law": "paper"})
    assert not m["crashed"]
    assert 0.01 < m["max_path_distance_last_10s_m"] < 0.2


@pytest.mark.slow
def test_same_seed_same_trajectory():
    a, _ = _fly("paper", **{"run.duration_s": 2.0, **NOISE})
    b, _ = _fly("paper", **{"run.duration_s": 2.0, **NOISE})
    assert np.array_equal(a["position_m"], b["position_m"])
    c, _ = _fly("paper", **{"run.duration_s": 2.0, "run.seed": 1, **NOISE})
    assert not np.array_equal(a["position_m"], c["position_m"])


@pytest.mark.slow
def test_offline_cli_json_and_plots(tmp_path):
    out = subprocess.run(
        [sys.executable, "-m", "tfl_mav.tools.cli", "offline", "paper", "--duration", "3", "--json",
         "--plot", str(tmp_path)], capture_output=True, text=True, timeout=120, check=True)
    m = json.loads(out.stdout)
    for key in ("crashed", "sim_time_s", "final_path_distance_m", "max_path_distance_last_10s_m",
                "rms_path_distance_last_10s_m", "thrust_min_n", "thrust_max_n",
                "saturated_fraction", "attack_min_n", "attack_max_n", "max_yaw_rate_radps",
                "wall_time_s"):
        assert key in m
    assert m["sim_time_s"] == pytest.approx(3.0, abs=0.01)
    pngs = sorted(p.name for p in tmp_path.glob("*.png"))
    assert len(pngs) >= 6
    assert all((tmp_path / p).stat().st_size > 10_000 for p in pngs)


@pytest.mark.slow
def test_offline_cli_bad_override_names_the_key():
    out = subprocess.run(
        [sys.executable, "-m", "tfl_mav.tools.cli", "offline", "paper", "--set",
         "vehicle.mass_kg=-1"],
        capture_output=True, text=True, timeout=60)
    assert out.returncode == 2
    assert "vehicle.mass_kg" in out.stderr


def test_offline_start_up_does_not_load_the_link_stack():
    """`tfl-mav offline` imports only its own subcommand: no pymavlink, MCAP or daemon."""
    code = ("import contextlib, io, sys\n"
            "from tfl_mav.tools.cli.main import main\n"
            "with contextlib.redirect_stdout(io.StringIO()):\n"
            "    main(['offline', 'nominal', '--json', '--duration', '0.01'])\n"
            "print(sorted(m for m in ('pymavlink', 'mcap', 'tfl_mav.controller.daemon',\n"
            "                         'matplotlib')\n"
            "             if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True, timeout=120)
    assert out.stdout.strip() == "[]"
