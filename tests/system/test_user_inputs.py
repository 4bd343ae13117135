"""Inputs a user can type that once ended in a traceback, a hang or silence: each is now one
line (or flown, with a warning that says what happened and when). Real processes of the
installed ``tfl-mav``, real files.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from tfl_mav.flightlog.recorder import Recorder
from tfl_mav.link.dialect import mav, new_mavlink

CLI = [sys.executable, "-m", "tfl_mav.tools.cli"]


def _run(*args: str, cwd: Path | None = None, timeout: float = 120.0
         ) -> subprocess.CompletedProcess[str]:
    return subprocess.run([*CLI, *args], capture_output=True, text=True, timeout=timeout,
                          cwd=cwd)


def _no_traceback(p: subprocess.CompletedProcess[str]) -> None:
    assert "Traceback" not in p.stderr and "Warning:" not in p.stderr, p.stderr


@pytest.mark.parametrize(("cmd", "value"), [("offline", "-3"), ("offline", "nan"),
                                            ("offline", "inf"), ("demo", "0"),
                                            ("demo", "-1"), ("fly", "nan")])
def test_a_bad_duration_is_a_usage_error_before_anything_starts(cmd, value, tmp_path):
    p = _run(cmd, "paper", "--duration", value, cwd=tmp_path, timeout=60)
    assert p.returncode == 2
    _no_traceback(p)
    assert f"argument --duration: must be > 0 and <= 86400 seconds of sim time, got " \
           f"'{value}'" in p.stderr.splitlines()[-1]
    assert not (tmp_path / "tfl-mav-demo").exists()      # nothing started, nothing written


def _path_file(tmp_path: Path, name: str, s: list[str], sigma: list[str]) -> Path:
    f = tmp_path / f"{name}.toml"
    f.write_text(f'name = "{name}"\n[path]\nkind = "expr"\n'
                 f"s = {s!r}\nsigma = {sigma!r}\n".replace("'", '"'))
    return f


@pytest.mark.parametrize(("s", "sigma", "says"), [
    (["y - 1/x", "z - 8"], ["t", "1/t", "8"], "path.sigma: not finite at t = 0 (a pole"),
    (["y", "z - 8"], ["t*t*t", "0", "8"], "path.sigma: sigma'(t) = 0 at t = 0: not regular"),
])
def test_a_singular_path_is_one_line_and_no_numpy_warning(s, sigma, says, tmp_path):
    f = _path_file(tmp_path, "singular", s, sigma)
    p = _run("offline", str(f), "--duration", "2")
    assert p.returncode == 2
    _no_traceback(p)
    assert p.stderr.count("\n") == 1, p.stderr
    assert says in p.stderr
    assert "RuntimeWarning" not in p.stderr and "> 0.00 N" not in p.stderr


@pytest.mark.slow
def test_an_expression_path_in_a_short_flight_prints_its_summary(tmp_path):
    """A straight line as expressions, flown 2 s: the path distance is not finite for part
    of the window (said as such), never a TypeError."""
    f = _path_file(tmp_path, "exprline", ["y", "z - 8"], ["t", "0", "8"])
    p = _run("offline", str(f), "--duration", "2")
    _no_traceback(p)
    assert p.returncode == 0, p.stderr
    assert "path distance: final" in p.stdout


@pytest.mark.slow
@pytest.mark.parametrize(("signal", "t_nan"), [("sqrt(0.5 - t)", "0.50"),
                                                ("log(t - 1)", "0.000")])
def test_an_attack_expression_that_turns_nan_is_flown_and_said(signal, t_nan):
    p = _run("offline", "paper", "--duration", "1", "--json", "--set",
             f'attack.signal="{signal}"')
    _no_traceback(p)
    assert p.returncode == 0, p.stderr
    line = [x for x in p.stderr.splitlines() if "attack.signal" in x]
    assert len(line) == 1, p.stderr
    assert f"is not finite (nan) at t = {t_nan}" in line[0]
    assert "rotor 2 gets 0 N while it is" in line[0]


@pytest.mark.slow
def test_a_key_the_attack_signal_never_reads_is_warned_about():
    p = _run("offline", "paper", "--duration", "0.2", "--json", "--set", "attack.rate_nps=0")
    assert p.returncode == 0
    assert ("warning: attack.rate_nps = 0 is not read by attack.signal 'paper' (only by ramp"
            in p.stderr)
    ramp = _run("offline", "paper", "--duration", "0.2", "--json", "--set",
                "attack.rate_nps=0", "--set", "attack.signal=ramp")
    assert "rate_nps" not in ramp.stderr


@pytest.mark.parametrize(("setting", "says"), [
    ("vehicle.thrust_max_n=1e300", "must be in (0, 10000] N, got 1e+300"),
    ("vehicle.thrust_max_n=500", "beyond the 65535 rpm ESC telemetry carries: must be in "
                                 "(0, 376.8] N for this k_f"),
    ("vehicle.mass_kg=1e9", "must be in (0, 1000] kg"),
    ("vehicle.gravity_mps2=1e6", "must be in (0, 100] m/s^2"),
])
def test_absurd_physical_values_are_refused_with_the_accepted_range(setting, says):
    p = _run("offline", "paper", "--duration", "0.2", "--set", setting)
    assert p.returncode == 2
    _no_traceback(p)
    assert says in p.stderr and p.stderr.count("\n") == 1, p.stderr


def _small_mcap(path: Path) -> None:
    packer = new_mavlink(1, 1)
    t = [0.0]

    def clock() -> float:
        t[0] += 0.001
        return t[0]

    with Recorder(path, clock=clock) as rec:
        for i in range(200):
            hb = mav.MAVLink_heartbeat_message(2, 12, 0, 0, 4, 3).pack(packer)
            rec.on_frame("tx" if i % 2 else "rx", bytes(hb), object(), clock())


@pytest.mark.parametrize("args", [["inspect", "{mcap}"], ["inspect", "{mcap}", "--json"],
                                  ["scenarios"]])
def test_a_reader_that_goes_away_ends_the_command_quietly(args, tmp_path):
    """``tfl-mav inspect run.mcap | head``: the reader closes the pipe first."""
    mcap = tmp_path / "run.mcap"
    _small_mcap(mcap)
    p = subprocess.Popen([*CLI, *(a.format(mcap=mcap) for a in args)],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    assert p.stdout is not None and p.stderr is not None
    p.stdout.close()
    err = p.stderr.read()
    assert p.wait(timeout=60) == 141
    assert err == ""


@pytest.mark.slow
def test_the_readme_quick_look_is_not_a_failure_and_names_its_windows(tmp_path):
    """``demo --duration 3`` (the README's quick look, shorter): the paper flight needs
    ~11 s to converge, so convergence is shown, not judged; the max/rms line names the span
    it covers (the whole 3 s flight, not "the last 10 s")."""
    p = _run("demo", "paper", "--duration", "3", "--no-plots", "--out", str(tmp_path / "d"))
    _no_traceback(p)
    assert p.returncode == 0, p.stdout + p.stderr
    first = p.stdout.splitlines()[0]
    assert first.startswith("tfl-mav demo: quick look, 3 s of the scenario's 30 s: "
                            "convergence not judged (not converged: "), first
    assert "over the last 1.5 s" in first
    assert "over the whole flight max" in p.stdout and "last 10 s" not in p.stdout
