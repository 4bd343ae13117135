"""What a user sees of a recorded flight: ``report`` and ``inspect`` output, exit codes, and
the logs' timeline (sim time in lockstep).

One real lockstep flight (``tfl-mav demo``: ``sim`` and ``fly`` subprocesses over loopback
UDP, both recording MCAP) is shared by the module; every check runs the real command on
its files.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import struct
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
from mcap.reader import make_reader

from tfl_mav.tools.harness.processes import CLI

pytestmark = pytest.mark.slow
DURATION_S = 1.0


@pytest.fixture(scope="module")
def flight(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("flight")
    done = subprocess.run([*CLI, "demo", "paper", "--duration", str(DURATION_S), "--out",
                           str(out), "--no-plots", "--json"], capture_output=True, text=True,
                          timeout=300)
    # 1 s is too short to converge: a quick look, convergence not judged (exit 0)
    assert done.returncode == 0, done.stderr
    summary = json.loads(done.stdout)
    assert summary["converged"] is False and "not judged" in summary["quick_look"]
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


def _timeline(path: Path) -> tuple[Any, dict[str, str], list[Any]]:
    """(statistics, the 'timeline' metadata, messages) of ``path``: the mcap library's
    own reader on its summary and indexes."""
    with open(path, "rb") as f:
        reader = make_reader(f)
        stats = reader.get_summary().statistics
        meta = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
        msgs = [(c.topic, m) for _s, c, m in reader.iter_messages(log_time_order=False)]
    return stats, meta["timeline"], msgs


def _t_s(data: bytes) -> float:
    """``t_s`` of a recorder record: field 1, a double (tests/contract/test_recorder_protos.py)."""
    assert data[0] == 0x09
    return struct.unpack_from("<d", data, 1)[0]


def test_a_lockstep_flight_is_on_the_timeline_at_sim_time(flight: Path) -> None:
    """However fast the machine flew it, a viewer's timeline shows the flight's 1 s: from
    sim time 0 on, log_time = the flight's wall-clock start + sim time (a record's t_s), in
    both files, and the two files start the flight at the same instant."""
    starts = []
    for name, topic in (("run.mcap", "/sim/truth/state"), ("ctl.mcap", "/controller/state")):
        stats, tl, msgs = _timeline(flight / name)
        start_ns = int(tl["flight_start_ns"])
        assert start_ns == pytest.approx(float(tl["flight_start_unix_s"]) * 1e9, abs=1000)
        sim_s = float(tl["sim_time_s"])
        assert tl["log_time"] == "sim" and sim_s == pytest.approx(DURATION_S, abs=0.0011)
        # the flight's span on the timeline is its sim duration, not its wall time
        assert (stats.message_end_time - start_ns) * 1e-9 == pytest.approx(sim_s, abs=1e-6)
        assert float(tl["wall_time_s"]) > 0 and float(tl["real_time_factor"]) > 0
        records = [m for t, m in msgs if t == topic]
        assert len(records) > 900
        for m in records:      # every tick's record at its sim time on the timeline
            assert abs(m.log_time - start_ns - _t_s(m.data) * 1e9) < 1000   # ns rounding
        # before sim time starts (the vehicle waits for its controller) the wall clock,
        # so the file's messages stay in order: none of them after the flight started
        assert stats.message_start_time <= start_ns
        starts.append(start_ns)
    assert abs(starts[0] - starts[1]) < 50_000_000      # one flight, two files: aligned


def test_inspect_says_what_the_log_knows_and_nothing_it_does_not(flight: Path) -> None:
    done = _cli("inspect", str(flight / "run.mcap"))
    assert done.returncode == 0, done.stderr
    text = done.stdout
    assert "sim time 1.000 s (the timeline's" in text and "x real time)" in text
    assert "Hz(log)" not in text              # one rate: log time is sim time here
    lines = text.splitlines()
    flight_lines = lines[lines.index("  flight:") + 1:]
    assert not [ln for ln in flight_lines if ln.split()[-1] in ("-", "0.000")], flight_lines
    assert not [ln for ln in flight_lines if " m" in ln and "0.0" in ln.split()[-2]
                and ln.split()[-1] == "m"], flight_lines     # small distances in mm/µm
    assert any(ln.split()[-1] in ("mm", "µm") for ln in flight_lines)
    report = json.loads(_cli("inspect", str(flight / "run.mcap"), "--json").stdout)
    wall = report["flight"]["wall_time_s"]          # the log's own wall clock (metadata)
    assert 0 < wall < 120 and report["flight"]["real_time_factor"] > 0
    assert report["timeline"] == "sim"


_RRD_CHUNK = re.compile(r"with (\d+) rows \([^)]*\) - (\S+) - data columns: \[([^\]]*)\]")


def _rerun(*args: str) -> str:
    """The rerun CLI that rerun-sdk installs (the viewer's own MCAP importer)."""
    exe = shutil.which("rerun") or str(Path(sys.executable).with_name("rerun"))
    done = subprocess.run([exe, *args], capture_output=True, text=True, timeout=300,
                          env={**os.environ, "RERUN_ANALYTICS": "0"})
    assert done.returncode == 0, done.stderr
    return done.stdout


def _entities(rrd: Path) -> dict[str, tuple[set[str], int]]:
    """Entity path → (archetypes of its data columns, rows) in an .rrd, as rerun prints it."""
    out: dict[str, tuple[set[str], int]] = {}
    for rows, entity, columns in _RRD_CHUNK.findall(_rerun("rrd", "print", str(rrd))):
        kinds = {c.split(":")[0] for c in columns.split()}
        if kinds & {"McapChannel", "McapSchema"}:        # the channel's description row
            continue
        seen, n = out.get(entity, (set(), 0))
        out[entity] = (seen | kinds, n + int(rows))
    return out


def test_rerun_converts_a_flight_into_poses_scalars_and_text(flight: Path,
                                                             tmp_path: Path) -> None:
    """`rerun mcap convert` (rerun-sdk) on both logs: the pose (/tf) becomes Transform3D,
    the events TextLog, and the truth, rotor and controller numbers Scalars, a row per
    sample at the scene rate (50 Hz of sim time)."""
    run, ctl = tmp_path / "run.rrd", tmp_path / "ctl.rrd"
    _rerun("mcap", "convert", str(flight / "run.mcap"), "-o", str(run))
    _rerun("mcap", "convert", str(flight / "ctl.mcap"), "-o", str(ctl))
    veh, con = _entities(run), _entities(ctl)
    assert "Transform3D" in veh["/tf"][0]
    assert "TextLog" in veh["/log"][0] and "TextLog" in con["/log"][0]
    samples = round(DURATION_S * 50) + 1
    for entity in ("/plot/truth/position_m", "/plot/truth/rotor_thrust_n",
                   "/plot/truth/attack_n", "/plot/truth/path_distance_m"):
        assert veh[entity] == ({"Scalars"}, samples), entity
    for field in ("path_distance_m", "attack_estimate_n", "detected_rotor", "cusum",
                  "rotor_thrust_cmd_n", "xi", "eta"):
        kinds, rows = con[f"/plot/controller/{field}"]
        assert kinds == {"Scalars"} and abs(rows - samples) <= 1, field
    # the per-tick protobuf records arrive decoded, by their schema in the file
    assert veh["/sim/truth/state"][0] == {"tfl_mav.TruthState"}
    assert con["/controller/state"][0] == {"tfl_mav.ControllerState"}
