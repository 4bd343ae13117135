"""Campaigns: the run is the offline flight bit for bit, executors agree, resume, failures.

Flights are 0.5-2 s of sim time: long enough to exercise the detector (it alarms within a few
ticks of the paper attack) and short enough for a loaded 2-core machine. ``success`` uses a
loose ``success_max_distance_m`` where a test needs successes: a 1 s flight has not
converged (the paper case needs ~10 s), which is not what these tests are about.
"""

from __future__ import annotations

import csv
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tfl_mav.flightlog.flight import summarize
from tfl_mav.flightlog.metrics import detection, detection_from_alarms
from tfl_mav.offline import fly_offline
from tfl_mav.scenario import apply_overrides, load_scenario
from tfl_mav.tools.cli.main import main
from tfl_mav.tools.harness.campaign import load_spec, run_campaign, run_outcome
from tfl_mav.tools.harness.campaign.executors import run_local
from tfl_mav.tools.harness.campaign.results import read_results
from tfl_mav.tools.harness.campaign.run import execute, run_isolated
from tfl_mav.tools.harness.campaign.spec import Run

SMALL = """
name = "small"
base = "paper"
seeds = 2
duration_s = 0.5
success_max_distance_m = 10.0
[grid]
"controller.model_mass_scale" = [0.95, 1.05]
"attack.rotor" = [1, 3]
"""


def _spec(tmp_path: Path, text: str, name: str = "spec.toml") -> Path:
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return path


def _table(out: Path, drop: tuple[str, ...] = ("wall_time_s",)) -> list[dict[str, str]]:
    with (out / "results.csv").open(encoding="utf-8") as f:
        rows = [{k: v for k, v in r.items() if k not in drop} for r in csv.DictReader(f)]
    return sorted(rows, key=lambda r: r["run_id"])


def test_offline_run_is_fly_offline_bit_for_bit() -> None:
    settings = ("controller.model_mass_scale=0.95", "attack.rotor=3", "run.duration_s=1.0",
                "sensors.position_noise_std_m=0.001", "run.seed=1")
    run = Run("000000", "paper", settings, {}, 1, attack_info="detector")
    sc = apply_overrides(load_scenario("paper"), list(settings))
    direct = summarize(fly_offline(sc, attack_info="detector"))
    for row in (execute(run), run_isolated(run)):
        for key, value in row.items():
            if key in direct and key != "wall_time_s":
                assert value == direct[key], key        # exact: same flight, same floats
        assert row["detected_rotor"] == 3 and row["false_alarms"] == 0
        assert 0.0 <= row["detection_latency_s"] < 0.05   # alarms within a few 1 ms ticks


def test_offline_and_mavlink_runs_judge_detection_alike() -> None:
    """An offline campaign run reads the detector's alarms (events) with the definition the
    MAVLink demo uses on the per-tick series: the first alarm at or after the attack."""
    alarms = [(0.5, 3), (2.1, 2), (5.0, 1)]          # early, right, later wrong
    from_alarms = detection_from_alarms(alarms, 2, 2.0)
    t = [i * 0.1 for i in range(61)]
    series = [next((r for ta, r in reversed(alarms) if ta <= ti + 1e-12 and ti < ta + 0.3), 0)
              for ti in t]
    assert from_alarms == detection(t, series, 2, 2.0)
    assert from_alarms["detected_rotor"] == 2 and from_alarms["false_alarms"] == 2
    assert from_alarms["detection_latency_s"] == pytest.approx(0.1)


def test_run_outcome_reasons() -> None:
    sc = load_scenario("paper")          # rotor 2 attacked
    good = {"crashed": False, "max_path_distance_last_10s_m": 0.01, "detected_rotor": 2,
            "false_alarms": 0}
    assert run_outcome(good, sc) == (True, "")
    assert not run_outcome({**good, "crashed": True, "crash_reason": "hit the ground"}, sc)[0]
    ok, reason = run_outcome({**good, "max_path_distance_last_10s_m": 0.2}, sc)
    assert not ok and "0.2 m" in reason
    ok, reason = run_outcome({**good, "detected_rotor": 4}, sc)
    assert not ok and "wrong rotor" in reason
    assert run_outcome({**good, "detected_rotor": None}, sc) == (True, "")   # oracle runs
    assert run_outcome({**good, "max_path_distance_last_10s_m": 0.2}, sc,
                       max_distance_m=0.5) == (True, "")


@pytest.mark.parametrize(("text", "key"), [
    ('bogus = 1\n', "bogus"),
    ('[grid]\n"controller.model_mass_scale" = [1.0, 9.0]\n', "controller.model_mass_scale"),
    ('[grid]\n"vehicle.no_such_key" = [1]\n', "vehicle.no_such_key"),
    ('[grid]\n"nosection.key" = [1]\n', "nosection.key"),
    ('[random]\nsamples = 3\n"attack.rotor" = [3, 1]\n', "random.attack.rotor"),
    ('[grid]\n"path.kind" = ["paper", "nope"]\n', "path.kind"),
    ('[grid]\n"run.seed" = [1, 2]\n', "run.seed"),
    ('mode = "mavlink"\nattack_info = "oracle"\n', "attack_info"),
    ('seeds = 0\n', "seeds"),
])
def test_bad_spec_exits_2_with_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                        text: str, key: str) -> None:
    spec = _spec(tmp_path, 'name = "bad"\nduration_s = 0.5\n' + text)
    assert main(["campaign", str(spec), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and key in err, err
    assert not (tmp_path / "out").exists()          # nothing ran


def test_random_points_are_seeded_and_in_range() -> None:
    from tfl_mav.tools.harness.campaign.spec import spec_from_dict

    data = {"duration_s": 0.5, "grid": {"attack.rotor": [1, 2]},
            "random": {"samples": 5, "seed": 7, "controller.model_inertia_scale": [0.8, 1.2],
                       "vehicle.motor_time_constant_s": [0.0, 0.05]}, "seeds": 2}
    runs = spec_from_dict(data).runs()
    assert len(runs) == 2 * 5 * 2
    assert [r.values for r in runs] == [r.values for r in spec_from_dict(data).runs()]
    inertia = {r.values["controller.model_inertia_scale"] for r in runs}
    assert len(inertia) == 5 and all(0.8 <= v <= 1.2 for v in inertia)
    assert [r.seed for r in runs[:4]] == [0, 1, 0, 1]


@pytest.mark.slow   # two worker processes, ten flights, a PNG: ~2.8 s CPU, 5-6 s loaded
def test_local_campaign_resume_and_report(tmp_path: Path) -> None:
    spec = load_spec(_spec(tmp_path, SMALL))
    out = tmp_path / "c"
    first = run_campaign(spec, out, workers=2, progress=False)
    assert (first["runs"], first["flown_now"]) == (8, 8)
    table = _table(out)
    assert [r["run_id"] for r in table] == [f"{i:06d}" for i in range(8)]
    assert {r["detected_rotor"] for r in table} == {"1", "3"}
    # seeds of a noiseless scenario fly the same flight
    assert table[0]["max_path_distance_last_10s_m"] == table[1]["max_path_distance_last_10s_m"]

    # a killed campaign: the last two rows lost, a torn line at the end
    lines = (out / "results.csv").read_text().splitlines(keepends=True)
    (out / "results.csv").write_text("".join(lines[:-2]) + lines[-2][:25])
    again = run_campaign(spec, out, workers=2, progress=False)
    assert (again["runs"], again["flown_now"], again["resumed_from"]) == (8, 2, 6)
    assert _table(out) == table
    assert run_campaign(spec, out, workers=2, progress=False)["flown_now"] == 0

    # the report, redrawn from the CSV alone
    for f in ("report.md", "campaign.json", "spec.toml", "summary.json"):
        (out / f).unlink()
    for png in out.glob("*.png"):
        png.unlink()
    assert main(["campaign", "report", str(out)]) == 0
    assert "controller.model_mass_scale" in (out / "report.md").read_text()
    pngs = list(out.glob("map_*.png"))
    assert len(pngs) == 1 and pngs[0].stat().st_size > 10_000


def test_other_spec_into_same_dir_is_refused(tmp_path: Path,
                                            capsys: pytest.CaptureFixture[str]) -> None:
    one = _spec(tmp_path, SMALL.replace("[0.95, 1.05]", "[1.0]").replace("seeds = 2",
                                                                         "seeds = 1"), "a.toml")
    assert main(["campaign", str(one), "--out", str(tmp_path / "c"), "--quiet"]) == 0
    other = _spec(tmp_path, SMALL, "b.toml")
    assert main(["campaign", str(other), "--out", str(tmp_path / "c")]) == 2
    assert "different runs" in capsys.readouterr().err


def test_failing_runs_are_rows_with_reasons(tmp_path: Path) -> None:
    # 4 x 2 N cannot hold 1.1 kg (10.8 N) and the attacked rotor's share: down in < 2 s
    crash = load_spec(_spec(tmp_path, 'name = "crash"\nduration_s = 2.0\n'
                                      '[grid]\n"vehicle.thrust_max_n" = [2.0]\n', "c.toml"))
    run_campaign(crash, tmp_path / "c", workers=1, progress=False)
    row = read_results(tmp_path / "c" / "results.csv")[1][0]
    assert row["crashed"] is True and row["success"] is False
    assert row["reason"].startswith("crashed: ") and " at t = " in row["reason"]

    # 30 s of flight cost seconds of CPU even at the offline loop's best (~6 simulated s
    # per CPU s, bench/bench_controller.py): never done within 0.3 s, so it must time out.
    slow = load_spec(_spec(tmp_path, 'name = "slow"\nduration_s = 30.0\ntimeout_s = 0.3\n',
                           "t.toml"))
    t0 = time.monotonic()
    run_campaign(slow, tmp_path / "t", workers=1, progress=False)
    assert time.monotonic() - t0 < 30          # killed, not flown out
    row = read_results(tmp_path / "t" / "results.csv")[1][0]
    assert row["reason"] == "timed out after 0.3 s" and row["success"] is False

    # the base scenario file vanished after the campaign was planned: the run raises
    rows: list[dict] = []
    missing = Run("000000", str(tmp_path / "gone.toml"), ("run.duration_s=0.5",), {}, 0)
    run_local([missing], 1, lambda run, row: rows.append(row))
    assert rows[0]["reason"].startswith("ScenarioError: cannot read scenario file")
    assert rows[0]["success"] is False


def _descendants() -> set[int]:
    """Live descendant pids of this process (from /proc; Linux)."""
    children: dict[int, list[int]] = {}
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                stat = Path(f"/proc/{entry}/stat").read_text()
            except OSError:
                continue
            fields = stat.rsplit(")", 1)[1].split()
            if fields[0] != "Z":
                children.setdefault(int(fields[1]), []).append(int(entry))
    out, todo = set(), [os.getpid()]
    while todo:
        for c in children.get(todo.pop(), []):
            out.add(c)
            todo.append(c)
    return out


@pytest.mark.slow
def test_ray_executor_gives_the_local_table(tmp_path: Path) -> None:
    pytest.importorskip("ray")
    spec = load_spec(_spec(tmp_path, SMALL))
    before = _descendants()
    run_campaign(spec, tmp_path / "local", workers=2, progress=False, report=False)
    summary = run_campaign(spec, tmp_path / "ray", executor="ray", workers=2, progress=False,
                           report=False)
    assert summary["executor"] == "ray" and summary["ray_cpus"] == 2
    assert _table(tmp_path / "ray") == _table(tmp_path / "local")
    deadline = time.monotonic() + 30            # Ray's processes exit after shutdown
    while _descendants() - before and time.monotonic() < deadline:
        time.sleep(0.5)
    assert not _descendants() - before


@pytest.mark.slow
def test_mavlink_run_over_udp(tmp_path: Path) -> None:
    spec = load_spec(_spec(tmp_path, 'name = "udp"\nmode = "mavlink"\nduration_s = 1.0\n'
                                     'success_max_distance_m = 10.0\n'))
    summary = run_campaign(spec, tmp_path / "m", workers=1, progress=False, report=False)
    row = read_results(tmp_path / "m" / "results.csv")[1][0]
    assert summary["succeeded"] == 1, row["reason"]
    assert row["detected_rotor"] == 2 and row["sim_time_s"] > 0.9
    assert not (tmp_path / "m" / "runs" / "000000").exists()     # logs not kept by default


def test_cli_help_lists_builtin_specs() -> None:
    out = subprocess.run([sys.executable, "-m", "tfl_mav.tools.cli", "campaign", "--help"],
                         capture_output=True, text=True, check=True).stdout
    assert "paper-envelope" in out and "attacks" in out


def test_unwritable_out_is_one_line_exit_3(tmp_path: Path,
                                           capsys: pytest.CaptureFixture[str]) -> None:
    blocker = tmp_path / "file"
    blocker.write_text("not a directory")
    assert main(["campaign", str(_spec(tmp_path, SMALL)), "--out", str(blocker / "c")]) == 3
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--out" in err and "Errno" not in err, err


def test_a_stop_asked_between_waits_ends_the_campaign_as_ctrl_c_does(tmp_path: Path) -> None:
    """The CLI's SIGTERM handler only records the signal (an exception raised from a handler
    that lands in a fork's at-fork callback is printed and dropped: the campaign flew on);
    the executor asks ``stop`` between waits and stops with the runs that finished."""
    spec = load_spec(_spec(tmp_path, SMALL.replace("seeds = 2", "seeds = 4")))    # 16 runs
    out = tmp_path / "c"
    t0 = time.monotonic()
    summary = run_campaign(spec, out, workers=1, progress=False,
                           stop=lambda: len(read_results(out / "results.csv")[1]) >= 2)
    rows = read_results(out / "results.csv")[1]
    assert summary["interrupted"] is True and 2 <= len(rows) < 16
    assert summary["not_flown"] == 16 - len(rows)
    assert time.monotonic() - t0 < 60


@pytest.mark.slow   # a campaign subprocess flying one run at a time until it is stopped
def test_an_interrupted_campaign_writes_the_report_of_what_finished(tmp_path: Path) -> None:
    spec = _spec(tmp_path, SMALL.replace("seeds = 2", "seeds = 4"))     # 16 runs
    out = tmp_path / "c"
    proc = subprocess.Popen([sys.executable, "-m", "tfl_mav.tools.cli", "campaign", str(spec),
                             "--out", str(out), "--workers", "1", "--quiet"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 120
        while len(read_results(out / "results.csv")[1]) < 2:
            assert proc.poll() is None and time.monotonic() < deadline, proc.communicate()
            time.sleep(0.1)
        proc.send_signal(signal.SIGTERM)
        stdout, stderr = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 128 + signal.SIGTERM, stderr
    assert "INTERRUPTED" in stdout and "the same command resumes" in stdout
    summary = json.loads((out / "summary.json").read_text())
    rows = read_results(out / "results.csv")[1]
    assert summary["interrupted"] is True and summary["runs"] == len(rows) >= 2
    assert summary["not_flown"] == 16 - len(rows) > 0
    assert f"{len(rows)} of 16 runs flown" in (out / "report.md").read_text()
